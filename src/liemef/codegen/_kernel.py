r"""The C engine: a filter's sample interval as a compiled C kernel whose parameters are run-time data.

:func:`export_c` writes a standalone filter with its weights folded in as constants, for a flight computer.
The engine needs the opposite: one build that serves every weight set, initial state and log, so that a
parameter sweep never recompiles ("parameters are data"). Here the jaxpr of ``flt.interval`` is traced with
the filter's array leaves (weights, noise levels, system parameters, connection coefficients, ``alpha``) as
*inputs*: the scalar translator folds only their **zero pattern** (the structural zeros of a diagonal
weight, of a connection on a torus, of ``alpha = 0``), and reads every other element at run time. One kernel
serves a filter structure (its static fields) and zero pattern; a weight set with other zeros builds a second
one, once.

Each interval is the very computation :meth:`~liemef.filters.AbstractFilter.step` compiles with XLA (the same
jaxpr: terms, derivatives as traced, adaptive sub-steps, screening, health checks), in C straight-line code:
20-40 times faster than XLA's per-operation dispatch for these small matrices. The kernel's C functions:

* ``kernel_advance``: one interval on a packed state (every leaf of :class:`~liemef.filters.FilterState` as
  doubles, integers exactly), and ``kernel_step``, the same with the samples packed in one vector (the
  online step, infinite samples rejected);
* ``kernel_scan``: a whole log, keeping every M-th state, stopping at the first failure (a failed state is
  final); ``kernel_history``, the same keeping the states leaf by leaf in the caller's arrays (``run``'s
  history, written where JAX takes it over);
* ``kernel_batch``: ``kernel_scan`` over a range of trials (one parameter vector, or one per trial).

The *batch kernel* (a second library, built on first use: :meth:`Kernel.lanes`) runs :data:`LANES` trials
of one interval at once in SIMD (:meth:`ScalarTranslator.emit_lanes`). :meth:`Kernel.batch` calls it from one
Python thread per core (ctypes releases the GIL), each on its own range of trials.

Builds are cached in the process (by structure and zero pattern) and on disk (by the hash of the jaxpr, the
zero pattern, the generator's code, the compiler and its flags: ``$LIEMEF_CACHE_DIR``, default
``~/.cache/liemef/kernels``), so that a new process pays only the trace. The disk cache is a private folder,
and every library is checked against the manifest its build wrote before it is loaded (:mod:`._cache`).
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import hashlib
import itertools
import math
import os
import platform
import tempfile
import threading
import time
import weakref
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _side, _validate
from .._cachedirs import host
from .._jax import dce_jaxpr, eager_context
from ..filters import TRACES, AbstractFilter, FilterState, check_samples, check_time
from . import _cache, _elf, _fast
from ._cache import Library, cache_dir
from ._export import compiler, quick_compiler, run_compiler
from ._fast import FALLBACK
from ._primitives import HELPERS, UnsupportedPrimitive, ctype, helpers_used
from ._scalar_c import ScalarTranslator, scalar_jaxpr_to_c, structural_zero
from ._scalar_nodes import lane_type, lane_typedefs

NATIVE = ("-march=native", "-mno-fma", "-mno-avx512f") \
    if platform.machine().lower() in ("x86_64", "amd64", "i386", "i686") else ("-march=native",)
"""Flags for the host's instruction set, without fused multiply-adds: ISO C contracts none across statements,
but GCC 12's SLP vectorizer emits ``vfmaddsub`` for pairs like ``a * b - c * d`` and ``a * b + c * d`` even
with ``-ffp-contract=off`` (the Chaplygin sleigh's kernel then differed from its -O0 build in the 12th digit).
On a CPU with AVX-512 (an AMD EPYC here), ``-mno-fma`` leaves AVX-512F's own fused multiply-adds to the
vectorizer, and the Chaplygin sleigh's kernel again differed from its -O0 build: AVX-512 is off too (the
kernels' lanes are AVX2-wide). A compiler that refuses them builds without them."""

KERNEL_CFLAGS = ("-std=c99", "-O2", *NATIVE, "-fno-math-errno")
"""The kernel's compiler flags: -O2 (as the tested export) for the host's instruction set (on x86-64 with AVX,
three-operand instructions: a TSE(2) step in 1.04-1.16 us against 1.41-1.46 us, the same numbers bit for bit);
``-fno-math-errno`` lets ``sqrt`` be one instruction (the kernel never reads errno; results are
IEEE-identical)."""

QUICK_CFLAGS = ("-std=c99", "-O0", "-fno-math-errno", "-ffp-contract=off")
"""The first build's flags: on TSE(2) -O0 compiles in 0.3 s against 1.2 s, and runs a step in 3.0 us against
1.0 us. Both are ISO C without contraction: the same numbers, bit for bit (tested). ``-ffp-contract=off`` is
GCC's default in ISO C mode but not Clang's, which builds the quick kernels where it is on the PATH
(:func:`~._export.quick_compiler`): on a target with FMA in its baseline (AArch64) Clang could otherwise fuse
a multiply and an add within one expression."""

OPTIMIZE_AFTER_S = 2.0
"""Seconds of C calls (``scan``, ``history``, ``batch``) that the quick build serves in a process before the
-O2 build starts beside it: a ski-rental rule. The -O2 build costs about as much compiling as this (1.2 s for
TSE(2), more for larger systems) and saves about two thirds of every later call, so a process that
has spent this long on the quick build has work enough to repay it; one that filters a few short logs
(a test, one ``liemef run`` of a minute of samples) never pays it, and does not wait for it at its exit.
An online filter (:meth:`Kernel.fast_ctl`) and :meth:`Kernel.wait` start it at once."""


@dataclass(frozen=True)
class Slot:
    """Where a leaf lives in a packed vector: offset, shape and dtype."""

    offset: int
    shape: tuple
    dtype: np.dtype

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))


def _slots(leaves) -> tuple[tuple[Slot, ...], int]:
    out, off = [], 0
    for x in leaves:
        x = np.asarray(x)
        out.append(Slot(off, tuple(x.shape), x.dtype))
        off += x.size
    return tuple(out), off


def _title(flt) -> str:
    try:
        return repr(flt)
    except jax.errors.ConcretizationTypeError:  # a traced alpha: the structure only
        return type(flt).__name__


def _known(x) -> np.ndarray:
    """A parameter's value, or for one traced (a weight vmapped over, inside jit) ones of its shape: no zero is
    then structural, and the kernel serves any value."""
    return np.ones(np.shape(x)) if isinstance(x, jax.core.Tracer) else np.asarray(x)


def _trace(flt: AbstractFilter) -> _Traced:
    """The jaxpr of one sample interval of ``flt`` with its parameters and state as inputs."""
    dyn, static = eqx.partition(flt, eqx.is_array)
    pleaves, pdef = jax.tree_util.tree_flatten(dyn)
    pleaves = [_known(x) for x in pleaves]
    sysm = flt.system
    n, m, p = flt.n, sysm.input_dim, sysm.output_dim
    state = flt.init(sysm.group.identity(), np.eye(n))
    sleaves, sdef = jax.tree_util.tree_flatten(state)
    sleaves = [np.asarray(x) for x in sleaves]
    pslots, n_theta = _slots(pleaves)
    sslots, n_state = _slots(sleaves)

    def interval(params, leaves, t, dt, gap, u0, u1, y0, y1):
        f = eqx.combine(jax.tree_util.tree_unflatten(pdef, params), static)
        st = jax.tree_util.tree_unflatten(sdef, leaves)
        return jax.tree_util.tree_leaves(f.interval(st, t, dt, u0, u1, y0, y1, gap))

    # abstract arguments: the trace needs shapes and dtypes only (jnp.asarray of each leaf compiled a small XLA
    # conversion per shape and dtype: nine of them, 0.3-0.5 s of a first build)
    spec = lambda shape, dtype=jnp.float64: jax.ShapeDtypeStruct(shape, dtype)  # noqa: E731
    closed = jax.make_jaxpr(interval)([spec(x.shape, x.dtype) for x in pleaves],
                                      [spec(x.shape, x.dtype) for x in sleaves], spec(()), spec(()), spec(()),
                                      spec((m,)), spec((m,)), spec((p,)), spec((p,)))
    closed, used = dce_jaxpr(closed)
    return _Traced(closed, used, pleaves, sleaves, pslots, sslots, pdef, sdef, state, n_theta, n_state, m, p,
                   f"{_title(flt)} on {type(sysm).__name__}")


@dataclass
class _Traced:
    closed: object
    used: list
    pleaves: list
    sleaves: list
    pslots: tuple
    sslots: tuple
    pdef: object
    sdef: object
    state: FilterState
    n_theta: int
    n_state: int
    m: int
    p: int
    title: str

    @functools.cached_property
    def key(self) -> str:
        """The hash of everything the source depends on: the jaxpr and its constants, those of every jaxpr
        inside it too (a ``jit`` inside the filter, :func:`~liemef.filters.terms`, closes over a system's
        arrays: a landmark's position; the printed jaxpr names them, not their values), the zero pattern and
        the generator's own code (a new liemef writes new kernels). Kept: printing the jaxpr takes 0.1 s."""
        h = hashlib.sha256()
        h.update(str(self.closed.jaxpr).encode())
        for c in _all_consts(self.closed):
            c = np.asarray(c)
            h.update(str((c.dtype, c.shape)).encode() + c.tobytes())
        for x in self.pleaves:
            h.update(str(x.shape).encode() + structural_zero(x).tobytes())
        h.update(str(self.used).encode())
        h.update(_GENERATOR_HASH)
        return h.hexdigest()[:24]


def _all_consts(closed) -> list:
    """The constants of a closed jaxpr and of every closed jaxpr in its equations' parameters (``pjit``,
    ``cond``'s branches, ``while``'s body...), in one fixed order."""
    out = list(closed.consts)
    stack = [closed.jaxpr]
    while stack:
        jaxpr = stack.pop()
        for eqn in jaxpr.eqns:
            for param in eqn.params.values():
                for sub in param if isinstance(param, list | tuple) else (param,):
                    if hasattr(sub, "consts") and hasattr(sub, "jaxpr"):  # a ClosedJaxpr
                        out.extend(sub.consts)
                        stack.append(sub.jaxpr)
                    elif hasattr(sub, "eqns"):  # an open Jaxpr
                        stack.append(sub)
    return out


def _generator_hash() -> bytes:
    here = Path(__file__).parent
    h = hashlib.sha256()
    for path in sorted(here.glob("*.py")):  # every module of the translators and of the kernel's build
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.digest()


_GENERATOR_HASH = _generator_hash()


def _translate(tr: _Traced) -> str:
    """The C source of a traced interval."""
    closed, used, pleaves, sleaves, pslots, sslots = tr.closed, tr.used, tr.pleaves, tr.sleaves, tr.pslots, tr.sslots
    m, p, n_theta, n_state = tr.m, tr.p, tr.n_theta, tr.n_state
    names = ([f"p{i}" for i in range(len(pleaves))] + [f"s{i}" for i in range(len(sleaves))]
             + ["t", "dt", "gap", "u0", "u1", "y0", "y1"])
    patterns = {f"p{i}": x for i, x in enumerate(pleaves) if x.dtype.kind == "f"}
    in_names = [a for a, keep in zip(names, used, strict=True) if keep]
    core, sc = scalar_jaxpr_to_c("kernel_core", closed, in_names, [f"o{i}" for i in range(len(sleaves))],
                                 translator=ScalarTranslator(), zero_patterns=patterns)

    # the arguments of the core, read from theta and the packed state (typed copies where not double)
    pre, post, call = [], [], []
    refs = {"t": "&t", "dt": "&dt", "gap": "&gap", "u0": "u0", "u1": "u1", "y0": "y0", "y1": "y1"}
    for prefix, vec, slots in (("p", "theta", pslots), ("s", "x", sslots)):
        for i, sl in enumerate(slots):
            nm = f"{prefix}{i}"
            if sl.dtype == np.float64:
                refs[nm] = f"{vec} + {sl.offset}"
            else:
                pre.append(f"    {ctype(sl.dtype)} {nm}[{max(sl.size, 1)}];")
                pre.append(f"    for (int i = 0; i < {sl.size}; i++) "
                           f"{nm}[i] = ({ctype(sl.dtype)}){vec}[{sl.offset} + i];")
                refs[nm] = nm
    outs = []
    for i, sl in enumerate(sslots):
        if sl.dtype == np.float64:
            outs.append(f"xo + {sl.offset}")
        else:
            pre.append(f"    {ctype(sl.dtype)} o{i}[{max(sl.size, 1)}];")
            post.append(f"    for (int i = 0; i < {sl.size}; i++) xo[{sl.offset} + i] = (double)o{i}[i];")
            outs.append(f"o{i}")
    call = [refs[a] for a in in_names] + outs
    code_slot = _code_slot(tr)
    S = n_state
    keep_leaves = "\n".join(f"    if (leaves[{i}] != NULL) memcpy(leaves[{i}] + r * {sl.size}, cur + {sl.offset}, "
                            f"sizeof(double) * {sl.size});" for i, sl in enumerate(sslots))
    source = f"""/* A liemef engine kernel (liemef.codegen._kernel), generated from the jaxpr of one sample interval of
 * {tr.title}. Parameters (theta: {n_theta}) are run-time data; only their zero pattern is folded. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
{helpers_used(core)}
{chr(10).join(sc.table_lines)}
{core}
#define S {S}
#define CODE {code_slot.offset}

/* one interval on the packed state x (S doubles) into xo; returns the status code */
int kernel_advance(const double *restrict theta, const double *restrict x, double *restrict xo, double t,
                   double dt, double gap, const double *u0, const double *u1, const double *y0, const double *y1)
{{
{chr(10).join(pre)}
    kernel_core({', '.join(call)});
{chr(10).join(post)}
    return (int)xo[CODE];
}}

/* one online step: the samples packed in z = (u0, u1, y0, y1); -2 (xo untouched) if one is infinite */
int kernel_step(const double *theta, const double *x, double *xo, double t, double dt, double gap, const double *z)
{{
    for (int i = 0; i < {2 * (m + p)}; i++)
        if (isinf(z[i])) return -2;
    return kernel_advance(theta, x, xo, t, dt, gap, z, z + {m}, z + {2 * m}, z + {2 * m + p});
}}

/* kept state r: the packed row into rows (when not NULL), and leaf i into leaves[i] (when leaves and leaves[i]
 * are not NULL: each leaf's kept values side by side, as doubles) */
static void keep_state(const double *cur, size_t r, double *rows, double *const *leaves)
{{
    if (rows != NULL) memcpy(rows + r * S, cur, sizeof(double) * S);
    if (leaves == NULL) return;
{keep_leaves}
}}

/* a log of n samples (ts: n, us: n x {m}, ys: n x {p}): intervals k = 0 .. n-2; the state at ts[0], ts[keep],
 * ts[2 keep], ... (1 + (n-1)/keep of them) is kept (keep_state); x receives the final state. A failed state
 * is final: the loop stops at the first failure and the kept states after it repeat the failed state. */
static int scan_states(const double *theta, double *x, int n, const double *ts, const double *us, const double *ys,
                       double gap, int keep, double *rows, double *const *leaves)
{{
    double a[S], b[S];
    double *cur = a, *nxt = b;
    memcpy(a, x, sizeof a);
    int code = (int)cur[CODE];
    keep_state(cur, 0, rows, leaves);
    for (int k = 0; k + 1 < n; k++) {{
        if (code == 0) {{
            code = kernel_advance(theta, cur, nxt, ts[k], ts[k + 1] - ts[k], gap, us + (size_t)k * {m},
                                  us + (size_t)(k + 1) * {m}, ys + (size_t)k * {p}, ys + (size_t)(k + 1) * {p});
            double *tmp = cur;
            cur = nxt;
            nxt = tmp;
        }}
        if ((k + 1) % keep == 0) keep_state(cur, (size_t)((k + 1) / keep), rows, leaves);
    }}
    memcpy(x, cur, sizeof a);
    return code;
}}

/* scan_states keeping packed rows (rows: 1 + (n-1)/keep rows of S, or NULL) */
int kernel_scan(const double *theta, double *x, int n, const double *ts, const double *us, const double *ys,
                double gap, int keep, double *rows)
{{
    return scan_states(theta, x, n, ts, us, ys, gap, keep, rows, NULL);
}}

/* scan_states keeping leaf by leaf (leaves: one pointer a state leaf, NULL for a leaf not kept): a run's
 * history goes straight into the arrays it is returned in */
int kernel_history(const double *theta, double *x, int n, const double *ts, const double *us, const double *ys,
                   double gap, int keep, double *const *leaves)
{{
    return scan_states(theta, x, n, ts, us, ys, gap, keep, NULL, leaves);
}}

/* trials lo .. hi-1 of a batch: theta + b * theta_stride (0: shared), x: B x S, us: B x n x {m}, ys: B x n x {p},
 * rows: B x rows_per x S (or NULL), codes: B. ts is shared. */
void kernel_batch(const double *theta, int theta_stride, int lo, int hi, double *x, int n, const double *ts,
                  const double *us, const double *ys, double gap, int keep, double *rows, int rows_per, int *codes)
{{
    for (int b = lo; b < hi; b++)
        codes[b] = kernel_scan(theta + (size_t)b * theta_stride, x + (size_t)b * S, n, ts,
                               us + (size_t)b * n * {m}, ys + (size_t)b * n * {p}, gap, keep,
                               rows != NULL ? rows + (size_t)b * rows_per * S : NULL);
}}
"""
    return source


LANES = 4
"""Trials per SIMD group in the batch kernel (4 doubles: one AVX2 register; two SSE2 registers without it)."""
LANE_CFLAGS = ("-std=gnu99", "-O3", *NATIVE, "-fno-math-errno", "-ffp-contract=off")
"""The batch kernel's flags: GNU C for the vector extensions, the host's SIMD (AVX2 where it has it), -O3 (on
TSE(2) 6 % more trial-steps than -O2 for 2 s more of compiling, once: measured 2.14e6 against 2.02e6 per s),
no fused multiply-adds (gnu99 would contract; the scalar kernel, in ISO C, does not: a lane then computes the
scalar kernel's values)."""


def _translate_lanes(tr: _Traced, lanes: int = LANES) -> str:
    """The C source of the batch kernel: ``lanes`` trials of one interval at once (:meth:`ScalarTranslator.
    emit_lanes`), and the scan of groups of ``lanes`` trials over a shared time grid. A group's state stays in
    lane form (one vector a number, the trials side by side) from its first interval to its last: it is
    turned to and from the packed rows (a trial's numbers side by side) only where a row is read or kept, and
    the samples are read straight into lane form."""
    closed, used, sslots = tr.closed, tr.used, tr.sslots
    m, p, S = tr.m, tr.p, tr.n_state
    names = ([f"p{i}" for i in range(len(tr.pleaves))] + [f"s{i}" for i in range(len(tr.sleaves))]
             + ["t", "dt", "gap", "u0", "u1", "y0", "y1"])
    patterns = {f"p{i}": x for i, x in enumerate(tr.pleaves) if x.dtype.kind == "f"}
    in_names = [a for a, keep in zip(names, used, strict=True) if keep]
    shared = tuple(f"p{i}" for i in range(len(tr.pleaves))) + ("t", "dt", "gap")
    core, sc = scalar_jaxpr_to_c("lanes_core", closed, in_names, [f"o{i}" for i in range(len(tr.sleaves))],
                                 translator=ScalarTranslator(), zero_patterns=patterns, lanes=shared)
    params, refs = [], {"t": "&t", "dt": "&dt", "gap": "&gap"}
    for i, sl in enumerate(tr.pslots):
        if sl.dtype == np.float64:
            refs[f"p{i}"] = f"theta + {sl.offset}"
        else:
            params.append(f"    {ctype(sl.dtype)} p{i}[{max(sl.size, 1)}];")
            params.append(f"    for (int i = 0; i < {sl.size}; i++) "
                          f"p{i}[i] = ({ctype(sl.dtype)})theta[{sl.offset} + i];")
            refs[f"p{i}"] = f"p{i}"
    decl, load, keep_row, store, step = [], [], [], [], []
    pad = " " * 8
    for i, sl in enumerate(sslots):
        get, put = ("{src} != 0 ? -1 : 0", "s{i}[j][l] != 0") if sl.dtype == np.bool_ else \
            ("{src}", "(double)s{i}[j][l]")  # a boolean lane is a mask of -1 and 0
        loop = f"for (int j = 0; j < {sl.size}; j++) for (int l = 0; l < LANES; l++) "
        decl.append(f"{pad}{lane_type(sl.dtype)} s{i}[{max(sl.size, 1)}], o{i}[{max(sl.size, 1)}];")
        load.append(f"{pad}{loop}s{i}[j][l] = {get.format(src=f'x[(size_t)(b + l) * S + {sl.offset} + j]')};")
        keep_row.append(f"{pad}        {loop}row[(size_t)l * rows_per * S + {sl.offset} + j] = {put.format(i=i)};")
        store.append(f"{pad}{loop}x[(size_t)(b + l) * S + {sl.offset} + j] = {put.format(i=i)};")
        step.append(f"{pad}    memcpy(s{i}, o{i}, sizeof s{i});")
        refs[f"s{i}"] = f"s{i}"
    samples = []
    for nm, src, dim, k in (("u0", "us", m, "k"), ("u1", "us", m, "k + 1"),
                            ("y0", "ys", p, "k"), ("y1", "ys", p, "k + 1")):
        samples.append(f"{pad}    for (int j = 0; j < {dim}; j++) for (int l = 0; l < LANES; l++) "
                       f"{nm}[j][l] = {src}[((size_t)(b + l) * n + ({k})) * {dim} + j];")
        refs[nm] = nm
    call = [refs[a] for a in in_names] + [f"o{i}" for i in range(len(sslots))]
    code_slot = _code_slot(tr)
    nl = chr(10)
    return f"""/* The batch kernel (liemef.codegen._kernel): LANES trials of one sample interval at once, of
 * {tr.title}. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
{HELPERS}
{lane_typedefs(lanes)}
{nl.join(sc.table_lines)}
{core}
#define S {S}
#define CODE {code_slot.offset}

/* groups of LANES trials from lo (hi - lo a multiple of LANES), as kernel_batch with a shared theta */
void lanes_batch(const double *theta, int lo, int hi, double *x, int n, const double *ts, const double *us,
                 const double *ys, double gap, int keep, double *rows, int rows_per, int *codes)
{{
{nl.join(params)}
    for (int b = lo; b + LANES <= hi; b += LANES) {{
{nl.join(decl)}
        lane_f64 u0[{max(m, 1)}], u1[{max(m, 1)}], y0[{max(p, 1)}], y1[{max(p, 1)}];
{nl.join(load)}
        for (int l = 0; l < LANES; l++)
            if (rows != NULL)
                memcpy(rows + (size_t)(b + l) * rows_per * S, x + (size_t)(b + l) * S, sizeof(double) * S);
        for (int k = 0; k + 1 < n; k++) {{
{nl.join(samples)}
            const double t = ts[k], dt = ts[k + 1] - ts[k];
            lanes_core({', '.join(call)});
{nl.join(step)}
            if (rows != NULL && (k + 1) % keep == 0) {{
                double *row = rows + ((size_t)b * rows_per + (size_t)((k + 1) / keep)) * S;
{nl.join(keep_row)}
            }}
        }}
{nl.join(store)}
        for (int l = 0; l < LANES; l++) codes[b + l] = (int)x[(size_t)(b + l) * S + CODE];
    }}
}}
"""


def _code_slot(tr: _Traced) -> Slot:
    paths = jax.tree_util.tree_flatten_with_path(tr.state)[0]
    return tr.sslots[[i for i, (path, _) in enumerate(paths) if jax.tree_util.keystr(path).endswith(".status.code")][0]]


def _library(tr: _Traced, flags, kind: str, cc: str | None = None) -> Path:
    """Where the disk cache keeps the library of a traced interval built with ``flags`` (``kind``: "kernel",
    "quick" or "lanes") by ``cc`` (default :func:`_compiler_for` the kind): keyed by the jaxpr, the generator,
    the compiler, the flags and, for the host's SIMD, the CPU; in the checked cache folder
    (:func:`._cache.folder`)."""
    cc = cc or _compiler_for(kind)
    if cc is None:
        raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
    _elf.host()  # a system whose libraries the cache cannot check: refused by name, before anything is built
    parts = [tr.key, cc, *flags] + (["lanes", str(LANES)] if kind == "lanes" else []) + \
        ([host()] if "-march=native" in flags else [])
    return _cache.folder() / f"{kind}_{hashlib.sha256(chr(0).join(parts).encode()).hexdigest()[:24]}.so"


def build_args(flags) -> list[str]:
    """The compiler's arguments for a kernel library: ``kernel.c`` into ``kernel.so`` in the build folder, with
    ``flags`` (relative names: the same source gives the same bytes in any process)."""
    return [*flags, "-fPIC", "-shared", "-o", "kernel.so", "kernel.c", "-lm"]


def _compiler_for(kind: str) -> str | None:
    """The compiler of a kernel library: :func:`~._export.quick_compiler` for the quick build, else the
    system's (:func:`~._export.compiler`)."""
    return quick_compiler() if kind == "quick" else compiler()


def _cached(tr: _Traced, flags=KERNEL_CFLAGS, kind: str = "kernel") -> Library | None:
    """The library of a traced interval from the disk cache, if it is there and passes its manifest's check."""
    return _cache.read_verified(_library(tr, flags, kind), tr.key, kind)


def _build(tr: _Traced, flags=KERNEL_CFLAGS, kind: str = "kernel", source: str | None = None) -> Library:
    """The shared library of a traced interval (``kind`` "lanes": its batch kernel): from the disk cache if it
    passes its check (the translation is skipped too), else translated (unless ``source`` is given), built in
    a private folder and put in the cache with its manifest. A file that fails its check (truncated, zero
    bytes, changed, another filter's kernel) is replaced, never loaded."""
    cc = _compiler_for(kind)  # once: the compiler of the cache key is the one that builds
    lib = _library(tr, flags, kind, cc)
    got = _cache.read_verified(lib, tr.key, kind)
    if got is not None:
        return got
    if source is None:
        source = _translate_lanes(tr) if kind == "lanes" else _translate(tr)
    with tempfile.TemporaryDirectory(dir=lib.parent, prefix=".build.") as tmp:  # 0700
        Path(tmp, "kernel.c").write_text(source)
        args = build_args(flags)
        try:
            run_compiler(args, cwd=tmp, cc=cc)
        except RuntimeError:
            if "-march=native" not in flags:
                raise
            run_compiler([c for c in args if c not in NATIVE], cwd=tmp, cc=cc)  # without them (some ARM clangs)
        data = Path(tmp, "kernel.so").read_bytes()
    return _cache.install(lib, data, tr.key, kind, {"filter": tr.title, "compiler": cc, "flags": list(flags)})


def _open(lib: Library | Path, tr: _Traced):
    """The loaded library (ctypes) of checked bytes, or of a cache file checked now (RuntimeError if it fails)."""
    if not isinstance(lib, Library):
        path = Path(lib)
        lib = _cache.read_verified(path, tr.key, path.name.split("_", 1)[0])
        if lib is None:
            raise RuntimeError(f"{path}: not a library of this kernel's that passes its manifest's check")
    return _cache.load(lib)


_dp = ctypes.POINTER(ctypes.c_double)


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(_dp)


ROWS_PER_BLOCK = 8
"""Online steps' new states per preallocated block (:meth:`Kernel._new_block`): a block's address costs 1.5 us once
(0.2 us a step), and a state kept alone keeps its whole block alive (8 rows of 600 bytes for TSE(2), about
what the state's 16 leaf objects take anyway), so that keeping every 100th state costs no more than keeping
every 8th."""


def fill_samples(z: np.ndarray, m: int, p: int, u, y, u_next, y_next) -> None:
    """Copy one interval's samples into ``z`` = (u0, u1, y0, y1), ``u_next``/``y_next`` None for held (ValueError
    naming the sample for a wrong shape or a non-number; None for an input of dimension 0)."""
    if (u_next is None and y_next is None and type(u) is np.ndarray and type(y) is np.ndarray
            and u.shape == (m,) and y.shape == (p,) and u.dtype.kind in "fiu" and y.dtype.kind in "fiu"):
        np.concatenate((u, u, y, y), out=z[:2 * (m + p)])  # the common case, in half the time
        return
    u0, y0, u1, y1 = check_samples(m, p, u, y, u_next, y_next)  # as the XLA engine checks them
    np.concatenate((u0, u1, y0, y1), out=z[:2 * (m + p)])


def reject_infinite(z: np.ndarray, m: int, p: int) -> None:
    """Raise the boundary check's ValueError for the first infinite sample in ``z`` (filled by
    :func:`fill_samples`: the C step found one and computed nothing; it takes NaN as missing, as the XLA engine
    does)."""
    for name, off, n in (("u", 0, m), ("y", 2 * m, p), ("u_next", m, m), ("y_next", 2 * m + p, p)):
        _validate.array(name, z[off:off + n], (n,), missing=True)


def _fields(td, obj) -> list[str]:
    """The fields of a state node that :func:`_state_reader` builds (an equinox Module without static fields),
    in the order of its children; UnsupportedPrimitive for any other node."""
    cls, aux = td.node_data()
    fields = [f.name for f in dataclasses.fields(cls)] if isinstance(obj, eqx.Module) else None
    if fields is None or len(aux) != 1 or aux[0] or len(fields) != len(td.children()):
        raise UnsupportedPrimitive(f"a state node {cls.__name__} with static fields")
    return fields


def _tree(td, obj, leaf_index) -> object:
    """The node description ``state`` of ``_fast_step.c`` builds ``td`` from: a leaf's index, (None, None, kids)
    for a tuple, (cls, field names, kids) for a Module."""
    if td.num_nodes == 1 and td.num_leaves == 1:
        return next(leaf_index)
    cls, kids = td.node_data()[0], td.children()
    if cls is tuple:
        return (None, None, tuple(_tree(c, o, leaf_index) for c, o in zip(kids, obj, strict=True)))
    fields = _fields(td, obj)
    return (cls, tuple(fields), tuple(_tree(c, vars(obj)[f], leaf_index) for c, f in zip(kids, fields, strict=True)))


def _state_reader(sslots: tuple[Slot, ...], sdef, template):
    """A function from one packed vector to its FilterState: generated for the layout, since the online step
    reads a state at each call and a loop over the slots, then ``sdef.unflatten``, cost three times as much.
    Float arrays are views, scalars NumPy scalars, integer leaves from one typed copy. The nodes are built as
    equinox builds them in its own unflatten (``object.__new__``, then each field set), for Modules without
    static fields and for tuples; any other node, or a result that is not the structure ``sdef`` with exactly
    these leaves (checked here on ``template``'s layout), falls back to ``sdef.unflatten``."""
    ints = [sl for sl in sslots if sl.dtype != np.float64]
    int_dtype = ints[0].dtype if ints else np.dtype(np.int32)
    if any(sl.dtype != int_dtype for sl in ints):
        raise UnsupportedPrimitive(f"state leaves of several integer dtypes: {sorted({str(sl.dtype) for sl in ints})}")
    exprs, k = [], 0
    for sl in sslots:
        src, start = ("x", sl.offset) if sl.dtype == np.float64 else ("xi", k)
        k += 0 if sl.dtype == np.float64 else sl.size
        exprs.append(f"{src}[{start}]" if sl.shape == () else
                     f"{src}[{start}:{start + sl.size}]" + (f".reshape({sl.shape})" if len(sl.shape) > 1 else ""))
    namespace = {"int_pos": np.array([sl.offset + i for sl in ints for i in range(sl.size)], np.intp),
                 "int_dtype": int_dtype, "new": object.__new__, "set": object.__setattr__}
    head = "def read(x):\n    xi = x[int_pos].astype(int_dtype)\n"
    exec(head + f"    return [{', '.join(exprs)}]\n", namespace)
    leaves = namespace["read"]
    fast = _fast.module()
    if fast is not None and int_dtype in (np.dtype(np.bool_), np.dtype(np.int32), np.dtype(np.int64)):
        # the leaves made in C (._fast_step.c's leaves): the same objects (checked below against the NumPy
        # expressions' on the probe), at a tenth of the cost
        namespace.update(c_leaves=fast.leaves, SPEC=tuple(
            ((0 if sl.shape else 1) if sl.dtype == np.float64 else (3 if sl.shape else 2), sl.offset, sl.shape,
             sl.dtype.num) for sl in sslots))
        head = f"def read(x):\n    {''.join(f'l{i}, ' for i in range(len(sslots)))}= c_leaves(x, SPEC)\n"
        exprs = [f"l{i}" for i in range(len(sslots))]
    lines, leaf_exprs = [], iter(exprs)

    def node(td, obj) -> str:  # the expression of one node (statements for it appended to lines)
        if td.num_nodes == 1 and td.num_leaves == 1:
            return next(leaf_exprs)
        cls, kids = td.node_data()[0], td.children()
        if cls is tuple:
            return "(" + "".join(node(c, o) + ", " for c, o in zip(kids, obj, strict=True)) + ")"
        fields = _fields(td, obj)
        values = [node(c, vars(obj)[f]) for c, f in zip(kids, fields, strict=True)]
        name = f"n{len(lines)}"
        namespace[f"C{len(lines)}"] = cls
        # the fields as one __dict__ (what setting them one by one leaves, in a third of the time)
        lines.append(f"    {name} = new(C{len(lines)})\n    set({name}, '__dict__', {{"
                     + ", ".join(f"{f!r}: {v}" for f, v in zip(fields, values, strict=True)) + "})\n")
        return name

    try:
        root = node(sdef, template)
        if "c_leaves" in namespace:  # the whole state made in C (._fast_step.c's state)
            namespace.update(c_state=_fast.module().state, TREE=_tree(sdef, template, itertools.count()))
            head, lines, root = "def read(x):\n", [], "c_state(x, SPEC, TREE)"
        exec(head + "".join(lines) + f"    return {root}\n", namespace)
        read = namespace["read"]
        read.c_state = (namespace["SPEC"], namespace["TREE"]) if "TREE" in namespace else None
        probe = np.arange(sum(sl.size for sl in sslots), dtype=np.float64)
        built, want = read(probe), sdef.unflatten(leaves(probe))
        same = jax.tree_util.tree_structure(built) == sdef and all(
            type(a) is type(b) and np.shape(a) == np.shape(b) and np.array_equal(a, b)
            for a, b in zip(jax.tree_util.tree_leaves(built), jax.tree_util.tree_leaves(want), strict=True))
        if same:
            return read
    except (UnsupportedPrimitive, TypeError, ValueError, StopIteration):
        pass
    return lambda x: sdef.unflatten(leaves(x))


class Kernel:
    """A built kernel, loaded: pack and unpack states, and the C ``advance``/``scan``/``batch`` on NumPy arrays."""

    def __init__(self, lib: Library | Path, traced: _Traced):
        pslots, sslots, pdef, sdef = traced.pslots, traced.sslots, traced.pdef, traced.sdef
        input_dim, output_dim = traced.m, traced.p
        self.traced = traced
        self.paths = [jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_flatten_with_path(traced.state)[0]]
        self._lanes = None  # the batch kernel: built on first use (False: it has no lane form here)
        self.lanes_error: str | None = None
        self.pslots, self.sslots, self.pdef, self.sdef = pslots, sslots, pdef, sdef
        self.n_theta = sum(s.size for s in pslots)
        self.n_state = sum(s.size for s in sslots)
        self.m, self.p = input_dim, output_dim
        self._reader = None  # the state reader, made on first use (:meth:`state`)
        self._c_state = None  # (SPEC, TREE) of the reader made in C (._fast_step.c's state), once it is made
        self._optimizer: threading.Thread | None = None
        self._source: str | None = None  # the C source of the quick build, kept for the -O2 one
        self._served = 0.0  # seconds of C calls the quick build has served (OPTIMIZE_AFTER_S)
        self._start = threading.Lock()  # one -O2 build thread, whichever thread asks first
        self.optimize_error: str | None = None
        # where the fast step (._fast) finds kernel_step: a pointer each _load sets, so that states and online
        # filters made before the -O2 build run by it once it serves
        self._step_cell = ctypes.c_void_p()
        self._load(lib)
        self._fast = None  # the fast step's module (._fast), loaded on the first online step (fast_ctl)
        self._block = self._new_block()

    def _load(self, built: Library | Path) -> None:
        """Take the C functions from a built library, checked (a later, optimized build of the same source
        replaces the first one's: calls under way finish in the old library, which stays loaded)."""
        lib = _open(built, self.traced)
        scan, step, batch = lib.kernel_scan, lib.kernel_step, lib.kernel_batch
        scan.argtypes = [_dp, _dp, ctypes.c_int, _dp, _dp, _dp, ctypes.c_double, ctypes.c_int, _dp]
        scan.restype = ctypes.c_int
        vp = ctypes.c_void_p
        step.argtypes = [vp, vp, vp, ctypes.c_double, ctypes.c_double, ctypes.c_double, vp]
        step.restype = ctypes.c_int
        batch.argtypes = [_dp, ctypes.c_int, ctypes.c_int, ctypes.c_int, _dp, ctypes.c_int, _dp, _dp, _dp,
                          ctypes.c_double, ctypes.c_int, _dp, ctypes.c_int, ctypes.POINTER(ctypes.c_int)]
        batch.restype = None
        history = lib.kernel_history
        history.argtypes = [_dp, _dp, ctypes.c_int, _dp, _dp, _dp, ctypes.c_double, ctypes.c_int, ctypes.c_void_p]
        history.restype = ctypes.c_int
        self._history = history
        # c_step: the C kernel_step on addresses, (theta, x, xo, t, dt, gap, z) -> status code (-2: an infinite
        # sample, xo untouched), for an engine that keeps packed states of its own (the online filter)
        self.lib, self._scan, self.c_step, self._batch = lib, scan, step, batch
        self._step_cell.value = _fast.address(step)
        self.path = built.path if isinstance(built, Library) else Path(built)

    def _optimize(self, source: str | None) -> None:
        """Build ``source`` (None: translated again) with :data:`KERNEL_CFLAGS` in a thread (the compiler runs
        on another core) and load it when done; until then the quick build serves. A failure is kept in
        ``optimize_error`` (the quick build goes on serving). The thread is not a daemon: a process that ends
        first waits for it, so that the next one finds the -O2 build on disk. A child forked meanwhile starts
        its own (:func:`_after_fork`): it finds the parent's build on disk, or builds it."""
        self._source = source
        _PENDING.add(self)
        self._optimizer = threading.Thread(target=self._finish_optimizing, name="liemef-kernel-build")
        self._optimizer.start()

    def _optimize_soon(self, seconds: float) -> None:
        """Count ``seconds`` of C calls served by the quick build, and start the -O2 build once they reach
        :data:`OPTIMIZE_AFTER_S` (``inf``: at once); nothing for a kernel already optimized or optimizing."""
        if self._optimizer is not None or self.optimized or self.optimize_error is not None:
            return
        with self._start:
            self._served += seconds
            if self._optimizer is None and self._served >= OPTIMIZE_AFTER_S:
                self._optimize(self._source)

    def _finish_optimizing(self) -> None:
        try:
            self._load(_build(self.traced, KERNEL_CFLAGS, source=self._source))
        except Exception as err:  # noqa: BLE001 - kept for the caller, the quick build stays
            self.optimize_error = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
        else:
            self._source = None
        _PENDING.discard(self)

    @property
    def optimized(self) -> bool:
        """Whether the -O2 build serves (not only the quick first one)."""
        return self.path.name.startswith("kernel_")

    def wait(self) -> Kernel:
        """Wait for the -O2 build: start it if it has not started (:data:`OPTIMIZE_AFTER_S`), or build it here
        in a forked child whose build thread was the parent's."""
        self._optimize_soon(math.inf)
        if self._optimizer is not None:
            self._optimizer.join()
        if not self.optimized and self.optimize_error is None:
            self._finish_optimizing()
        return self

    # --- packing ----------------------------------------------------------------------------------------------
    def theta(self, flt: AbstractFilter) -> np.ndarray:
        """The filter's parameter vector (its array leaves, flattened)."""
        leaves = jax.tree_util.tree_leaves(eqx.filter(flt, eqx.is_array))
        return np.concatenate([np.ravel(np.asarray(x, np.float64)) for x in leaves] or [np.zeros(0)])

    def pack(self, state: FilterState) -> np.ndarray:
        """A state as the kernel's packed vector (a fresh array); ValueError if it is not a state of this
        kernel's filter (another filter's on the same group: other inputs or sensor blocks)."""
        x = np.concatenate([np.ravel(np.asarray(a, np.float64)) for a in jax.tree_util.tree_leaves(state)])
        self.check_packed(x, state, "state")
        return x

    def check_packed(self, x, state, name: str) -> None:
        """A packed state (or a batch of them) has this kernel's layout: ValueError naming ``name`` otherwise
        (the C code reads and writes exactly ``n_state`` numbers)."""
        shapes = [tuple(np.shape(a)) for a in jax.tree_util.tree_leaves(state)]
        want = [s.shape for s in self.sslots]
        lead = len(shapes[0]) - len(want[0]) if shapes and want else 0
        if (jax.tree_util.tree_structure(state) != self.sdef or np.shape(x)[-1] != self.n_state
                or [sh[lead:] for sh in shapes] != want):
            raise ValueError(f"{name}: expected a state of this filter ({self.n_state} numbers, leaf shapes {want}), "
                             f"got {np.shape(x)[-1]} numbers, leaf shapes {[sh[lead:] for sh in shapes]}")

    def unpack(self, x: np.ndarray, lead: tuple = ()) -> list[np.ndarray]:
        """The state leaves of packed vectors ``x`` (shape lead + (S,)): views where the leaf is float64."""
        out = []
        for s in self.sslots:
            a = x[..., s.offset:s.offset + s.size].reshape(lead + s.shape)
            out.append(a if s.dtype == np.float64 else a.astype(s.dtype))
        return out

    def state(self, x: np.ndarray, address: int | None = None) -> FilterState:
        """The FilterState of one packed vector (kept beside it, so that the next step need not pack it again;
        ``address``: where ``x`` is, if known)."""
        if self._reader is None:
            self._reader = _state_reader(self.sslots, self.sdef, self.traced.state)
            # the C reader's layout, for step's one-call path (None: the Python reader serves)
            self._c_state = getattr(self._reader, "c_state", None)
        st = self._reader(x)
        _side.put(st, "packed", (x, x.ctypes.data if address is None else address, self))
        return st

    def packed(self, state: FilterState) -> np.ndarray:
        """The packed vector of a state: the one it came from, if it is this kernel's state, else packed now."""
        got = _side.get(state, "packed")
        return got[0] if got is not None and got[2] is self else self.pack(state)

    def made(self, state) -> bool:
        """Whether ``state`` came from this kernel (then its structure needs no check)."""
        got = _side.get(state, "packed")
        return got is not None and got[2] is self

    def _new_block(self):
        """A preallocated block of rows for online steps (:meth:`step`): each row a new state, then its
        samples. The address of a new array costs over a microsecond (``ndarray.ctypes``), a block's is taken
        once; each row's state view and address are cut once for the whole block. A block lives while a state
        in it does (its leaves are views)."""
        block = np.empty((ROWS_PER_BLOCK, self.n_state + max(1, 2 * (self.m + self.p))))
        address, stride = block.ctypes.data, block.strides[0]
        return (list(block[:, :self.n_state]), [address + i * stride for i in range(ROWS_PER_BLOCK)],
                itertools.count(), block)

    def fast_ctl(self, theta_address: int) -> tuple | None:
        """The ``ctl`` of the fast step (:mod:`._fast`) for the parameter vector at ``theta_address``, or None
        where the extension is not available (the ctypes path serves)."""
        self._fast = _fast.module()  # built and cached on first use
        self._optimize_soon(math.inf)  # an online filter steps for as long as it runs: its kernel is worth -O2
        if self._fast is None:
            return None
        return (ctypes.addressof(self._step_cell), theta_address, self.n_state, self.m, self.p)

    def advance(self, ctl, theta_address: int, x: int, xo: int, z: np.ndarray, t, dt, gap, u, y, u_next, y_next
                ) -> int:
        """One online step from the packed state at address ``x`` into the buffer at ``xo`` (S + 2 (m + p)
        doubles, ``z`` the view of its samples part): by the fast step where it takes the arguments as they are,
        else with every argument checked here (ValueError naming the first bad one, as the XLA engine's step
        names it) and the ctypes call. Returns the kernel's status code; xo is untouched when it raises."""
        if ctl is not None and u_next is None and y_next is None:
            code = self._fast.step(ctl, x, xo, t, u, y, dt, gap)
            if code != FALLBACK:
                if code == -2:
                    reject_infinite(z, self.m, self.p)
                return code
        t, dt = check_time(t, dt)
        fill_samples(z, self.m, self.p, u, y, u_next, y_next)
        code = self.c_step(theta_address, x, xo, t, dt, float(gap), xo + 8 * self.n_state)
        if code == -2:
            reject_infinite(z, self.m, self.p)
        return code

    def step(self, flt, theta_address: int, ctl, state: FilterState, t, dt, gap, u, y, u_next, y_next
             ) -> FilterState:
        """One online step of ``flt`` from ``state`` (``theta_address``: where the parameter vector is, ``ctl``
        its :meth:`fast_ctl`; the state, time and samples as given, checked here): the C ``kernel_step``, and
        the new state, in a row of a preallocated block (:meth:`_new_block`)."""
        got = _side.get(state, "packed")
        if got is None or got[2] is not self:
            type(flt).check_state(flt, state)
            x = self.pack(state)
            got = (x, x.ctypes.data)
        xs, addresses, counter, block = self._block
        i = next(counter)
        if i >= ROWS_PER_BLOCK:
            xs, addresses, counter, block = self._block = self._new_block()
            i = next(counter)
        address = addresses[i]
        if ctl is not None and u_next is None and y_next is None:  # advance's fast step and state, inlined
            c_state = self._c_state
            if c_state is not None:  # the step and the new state in one call
                x = xs[i]
                st = self._fast.step_state(ctl, got[1], address, t, u, y, dt, gap, x, c_state[0], c_state[1])
                if type(st) is not int:
                    _side.put(st, "packed", (x, address, self))
                    return st
                code = st
            else:
                code = self._fast.step(ctl, got[1], address, t, u, y, dt, gap)
                if code >= 0:
                    return self.state(xs[i], address)
            ctl = None  # refused (or an infinite sample): the checked path says why
        self.advance(ctl, theta_address, got[1], address, block[i, self.n_state:], t, dt, gap, u, y, u_next,
                     y_next)
        return self.state(xs[i], address)

    # --- calls ------------------------------------------------------------------------------------------------
    def scan(self, theta, x, ts, us, ys, gap: float, keep: int) -> tuple[np.ndarray, np.ndarray]:
        """A whole log from packed state ``x``: (rows of kept packed states, final packed state)."""
        N = ts.shape[0]
        rows = np.empty((1 + (N - 1) // keep, self.n_state))
        x = np.array(x, np.float64)
        t0 = time.perf_counter()
        self._scan(_ptr(theta), _ptr(x), N, _ptr(ts), _ptr(us), _ptr(ys), gap, keep, _ptr(rows))
        self._optimize_soon(time.perf_counter() - t0)
        return rows, x

    def history(self, theta, x, ts, us, ys, gap: float, keep: int, leaves: list) -> np.ndarray:
        """A whole log from packed state ``x``, its kept states written leaf by leaf into ``leaves`` (one entry a
        state leaf: a C-ordered float64 array of shape (1 + (N-1)/keep,) + the leaf's shape, or None for a leaf
        not kept): no packed rows to copy from. Returns the final packed state."""
        R = 1 + (ts.shape[0] - 1) // keep
        if len(leaves) != len(self.sslots):
            raise ValueError(f"leaves: expected {len(self.sslots)} entries (one a state leaf), got {len(leaves)}")
        for a, sl in zip(leaves, self.sslots, strict=True):
            if a is not None and (a.dtype != np.float64 or a.shape != (R, *sl.shape) or not a.flags.c_contiguous):
                raise ValueError(f"leaves: expected C-ordered float64 arrays of shape {(R, *sl.shape)} or None, "
                                 f"got {a.dtype} {a.shape}")
        outs = (ctypes.c_void_p * max(1, len(leaves)))(*[None if a is None else a.ctypes.data for a in leaves])
        x = np.array(x, np.float64)
        t0 = time.perf_counter()
        self._history(_ptr(theta), _ptr(x), ts.shape[0], _ptr(ts), _ptr(us), _ptr(ys), gap, keep, outs)
        self._optimize_soon(time.perf_counter() - t0)
        return x

    def lanes(self):
        """The batch kernel (``lanes_batch``: :data:`LANES` trials at once in SIMD), built on first use; None
        where the interval has no lane form or the build fails (``lanes_error`` says why: the batch then runs
        one trial at a time)."""
        if self._lanes is None:
            try:
                lib = _open(_build(self.traced, LANE_CFLAGS, "lanes"), self.traced)
                fn = lib.lanes_batch
                fn.argtypes = [_dp, ctypes.c_int, ctypes.c_int, _dp, ctypes.c_int, _dp, _dp, _dp, ctypes.c_double,
                               ctypes.c_int, _dp, ctypes.c_int, ctypes.POINTER(ctypes.c_int)]
                fn.restype = None
                self._lanes = (lib, fn)
            except (UnsupportedPrimitive, RuntimeError, OSError) as err:
                self.lanes_error = f"{type(err).__name__}: {str(err).splitlines()[0]}"
                self._lanes = False
        return self._lanes[1] if self._lanes else None

    def batch(self, theta, x, ts, us, ys, gap: float, keep: int, *, keep_rows: bool = True,
              threads: int | None = None, lanes: bool = True) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """``scan`` over trials: ``theta`` (P,) shared or (B, P), ``x`` (B, S), ``us`` (B, N, m), ``ys`` (B, N, p);
        ``threads`` Python threads (default: the CPUs this process may use), each on a contiguous range of
        trials, in groups of :data:`LANES` by the batch kernel (``lanes``, with a shared theta) and the rest one
        at a time. Returns (rows (B, R, S) or None, final states (B, S), codes (B,))."""
        B, N = x.shape[0], ts.shape[0]
        R = 1 + (N - 1) // keep
        x = np.array(x, np.float64, order="C")
        rows = np.empty((B, R, self.n_state)) if keep_rows else None
        codes = np.zeros(B, np.int32)
        stride = self.n_theta if theta.ndim == 2 else 0
        if threads is None:
            threads = _validate.cpus()
        threads = max(1, min(B, threads))
        cp = codes.ctypes.data_as(ctypes.POINTER(ctypes.c_int))
        rp = _ptr(rows) if rows is not None else None
        us_p = us if us.size else np.zeros(1)
        simd = self.lanes() if lanes and stride == 0 and B >= LANES else None

        errors = []

        def work(lo, hi):
            try:
                mid = lo
                if simd is not None:
                    mid = lo + (hi - lo) // LANES * LANES
                    simd(_ptr(theta), lo, mid, _ptr(x), N, _ptr(ts), _ptr(us_p), _ptr(ys), gap, keep, rp, R, cp)
                self._batch(_ptr(theta), stride, mid, hi, _ptr(x), N, _ptr(ts), _ptr(us_p), _ptr(ys), gap, keep, rp,
                            R, cp)
            except BaseException as err:  # noqa: BLE001 - raised in the caller's thread below
                errors.append(err)

        # ranges of whole lane groups per thread (the last takes the remainder)
        groups = -(-B // LANES)
        bounds = [min(B, round(groups * j / threads) * LANES) for j in range(threads + 1)]
        bounds[-1] = B
        ranges = list(zip(bounds[:-1], bounds[1:], strict=True))
        pool = [threading.Thread(target=work, args=(lo, hi)) for lo, hi in ranges if hi > lo]
        t0 = time.perf_counter()
        for th in pool:
            th.start()
        for th in pool:
            th.join()
        # this kernel's share of the wall time: the batch kernel (-O3) served the whole lane groups
        alone = B if simd is None else sum((hi - lo) % LANES for lo, hi in ranges)
        self._optimize_soon((time.perf_counter() - t0) * alone / max(B, 1))
        if errors:
            raise errors[0]
        return rows, x, codes


_KERNELS: dict = {}
_LOCK = threading.Lock()
_PENDING: weakref.WeakSet = weakref.WeakSet()  # kernels whose -O2 build is under way


def _after_fork() -> None:
    """In a forked child: a fresh lock (the parent's may have been held by a thread that is not here), and the
    -O2 builds that the parent's threads were making, made (or found on disk) by threads of the child's."""
    global _LOCK
    _LOCK = threading.Lock()
    for kern in list(_PENDING):
        if not kern.optimized and kern.optimize_error is None:
            kern._optimize(kern._source)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


def kernel_for(flt: AbstractFilter) -> Kernel:
    """The kernel of ``flt``'s structure and zero pattern: built once per process (and found on disk after
    the first process). Raises :class:`~liemef.codegen.UnsupportedPrimitive` if the filter has a primitive the
    translator has no C for, RuntimeError if there is no C compiler or the build fails."""
    dyn, static = eqx.partition(flt, eqx.is_array)
    pleaves, pdef = jax.tree_util.tree_flatten(dyn)
    pattern = tuple(structural_zero(_known(x)) for x in pleaves)
    key = (pdef, static, tuple(x.tobytes() + bytes(str(x.shape), "ascii") for x in pattern))
    try:
        hash(key)
    except TypeError:  # a static field that is not hashable: no process cache, the disk cache still serves
        key = None
    with _LOCK:
        if key is not None and key in _KERNELS:
            return _KERNELS[key]
        TRACES["kernel"] += 1
        with eager_context():  # also when asked from inside a trace (scan under jit)
            tr = _trace(flt)
        # the -O2 build, else an earlier process's quick one (translated again only if -O2 is built)
        found = _cached(tr)
        if found is None:
            found = _cached(tr, QUICK_CFLAGS, "quick")
        if found is not None:
            kern = Kernel(found, tr)
        else:  # a quick build to start with, the -O2 one once it has served enough (OPTIMIZE_AFTER_S)
            source = _translate(tr)
            kern = Kernel(_build(tr, QUICK_CFLAGS, "quick", source), tr)
            kern._source = source
        if key is not None:
            _KERNELS[key] = kern
        return kern


__all__ = ["KERNEL_CFLAGS", "LANES", "LANE_CFLAGS", "NATIVE", "QUICK_CFLAGS", "Kernel", "cache_dir", "kernel_for"]
