r"""``liemef export-c``: a standalone C99 filter (header + source) from a liemef filter, and a ctypes loader.

The C is the translation (:mod:`liemef.codegen._jaxpr_c`) of the jaxpr of one online step, the very
computation :meth:`liemef.filters.AbstractFilter.step` compiles: Theorem 4.1's terms with their derivatives as
traced (``jacfwd`` for the Jacobians, forward-over-forward for the Hessian), the integrator with its adaptive
sub-steps, the sensor screening and the health checks. The filter's weights, connection and parameters are
constants of the source (export again for new ones: it takes seconds). No heap, no library but libm.

Why the jaxpr, not SymPy/SymForce: the jaxpr *is* the filter (one definition, no second derivation that could
drift), it exists for every system a user writes in JAX, and it carries the control flow (sub-steps, missing
samples, failure codes) that a symbolic expression of the terms alone would not.
"""

from __future__ import annotations

import ctypes
import math
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import dce_jaxpr
from .._names import C_BACKENDS
from ..filters import DEFINITE_TOL, FILTER_CAUSES, AbstractFilter, FilterState
from . import _cache
from ._jaxpr_c import Translator, jaxpr_to_c
from ._primitives import ctype, helpers_used, literal
from ._scalar_c import ScalarTranslator, scalar_jaxpr_to_c

CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic")
"""The flags the exported C is tested with, by GCC and by Clang (warning-free ISO C99)."""


@dataclass(frozen=True)
class Field:
    """A member of the exported state struct: a leaf of :class:`~liemef.filters.FilterState`."""

    name: str
    shape: tuple
    dtype: np.dtype

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def scalar(self) -> bool:
        return self.shape == ()

    def decl(self) -> str:
        return f"{ctype(self.dtype)} {self.name}" + ("" if self.scalar else f"[{max(self.size, 1)}]")

    def ref(self, obj: str) -> str:
        return f"&{obj}->{self.name}" if self.scalar else f"{obj}->{self.name}"


@dataclass(frozen=True)
class ExportedC:
    """The files :func:`export_c` wrote, the layout of its state struct and the translator ``backend`` that
    wrote them (``"scalar"`` or ``"array"``, ``"auto"`` resolved)."""

    header: Path
    source: Path
    prefix: str
    fields: tuple[Field, ...]
    n: int
    input_dim: int
    output_dim: int
    group_params: int
    coords_dim: int
    backend: str

    def api_summary(self, system) -> str:
        """The exported C API with its sizes, the state's members, the status codes and the order of u and y
        (``system``'s input and output names), as ``liemef export-c`` prints it."""
        P, U = self.prefix, self.prefix.upper()
        n, m, p = self.n, self.input_dim, self.output_dim
        members = []
        for f in self.fields:
            size = "" if f.scalar else f"[{f.size}]"
            members.append(f"{f.name}{size}" + (f" ({n} x {n}, row-major)" if f.name == "K" else ""))
        codes = ", ".join(f"{i} {U}_{re.sub(r'[^A-Z]', '_', cause.upper()).strip('_')} ({cause})"
                          for i, cause in enumerate(FILTER_CAUSES))
        return "\n".join([
            f"C API ({P}.h; n = {n}, m = {m} inputs, p = {p} outputs, {self.group_params} group parameters, "
            f"{self.coords_dim} coordinates):",
            f"  {P}_state s;  /* {', '.join(members)} */",
            f"  int  {P}_init({P}_state *s, const double *g0, const double *K0);  /* 0, or {U}_BAD_ARGUMENT (-1) */",
            f"  int  {P}_step({P}_state *s, double t, double dt, const double *u, const double *y, const int *mask);",
            f"  int  {P}_run({P}_state *s, int n, const double *ts, const double *us, const double *ys, "
            "double *g_out, double *K_out);",
            f"  void {P}_from_coords(const double *q, double *g);",
            f"  void {P}_coords(const double *g, double *q);",
            f"Status codes ({P}_step, {P}_run, s.code): {codes}",
            f"u = ({', '.join(system.input_names) or 'none'})",
            f"y = ({', '.join(system.output_names)}); mask[i] = 0 or a NaN in y: a missing component",
            f"Build: cc -std=c99 -O2 -c {P}.c (link with -lm); no heap, no library but libm",
        ])


def _field_name(path) -> str:
    parts = []
    for k in path:
        s = getattr(k, "name", None) or getattr(k, "key", None) or str(getattr(k, "idx", k))
        parts.append(str(s))
    name = "_".join(parts)
    name = re.sub(r"[^0-9A-Za-z_]", "_", name)
    return {"status_code": "code"}.get(name, name)


def _identifier(prefix: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", prefix):
        raise ValueError(f"name: expected a C identifier (letters, digits, _; not starting with a digit), got "
                         f"{prefix!r}")
    return prefix


BACKENDS = C_BACKENDS
"""The translators: ``"scalar"`` (straight-line code, with constants folded and zeros and common
subexpressions removed: the fast one, :mod:`._scalar_c`), ``"array"`` (loops over arrays: compact code whose
size grows with the number of operations, not of scalar operations, for large state dimensions;
:mod:`._jaxpr_c`) and ``"auto"``: scalar up to :data:`SCALAR_MAX_N`, array above."""
SCALAR_MAX_N = 15
"""The largest algebra dimension n that ``backend="auto"`` exports as scalar code (its size grows as n^3): 15
takes in inertial navigation with biases (SE_2(3) x R^6), whose scalar step has 28k lines (the
dense R^12's has 46k: the group's structural zeros fold away), where the array loops ran 43x slower than the C
engine's kernel, itself that same scalar code (benchmarks/bench_3d.py)."""


def export_c(flt: AbstractFilter, out_dir: str | os.PathLike, name: str = "liemef_filter", *,
             backend: str = "auto") -> ExportedC:
    """Write ``<name>.h`` and ``<name>.c`` into ``out_dir``: the filter ``flt`` as standalone C99.

    The C API (``P`` = ``name``)::

        P_state s;                      /* g_hat (group parameters), K (n x n, row-major), u_last, status */
        int P_init(P_state *s, const double *g0, const double *K0);   /* 0, or P_BAD_ARGUMENT */
        int P_step(P_state *s, double t, double dt, const double *u, const double *y, const int *mask);
        int P_run(P_state *s, int n, const double *ts, const double *us, const double *ys,
                  double *g_out, double *K_out);
        void P_from_coords(const double *q, double *g);  void P_coords(const double *g, double *q);

    ``P_step`` advances ``[t, t + dt]`` exactly as ``flt.step(state, t, u, y, dt)``: ``mask[i] = 0`` (or a
    NaN in ``y``) marks a missing component, a NaN in ``u`` holds the last input, ``mask`` may be NULL (all
    present). It returns the status code (0 healthy, else the cause ``P_NON_FINITE``, ...); a failed state is
    frozen, as in Python. Files are written completely or not at all. ``backend``: the translator
    (:data:`BACKENDS`).
    """
    if not isinstance(flt, AbstractFilter):
        raise ValueError(f"flt: expected a liemef filter (AbstractFilter), got {type(flt).__name__}")
    P = _identifier(name)
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {list(BACKENDS)}, got {backend!r}")
    if backend == "auto":
        backend = "scalar" if flt.n <= SCALAR_MAX_N else "array"
    translate = scalar_jaxpr_to_c if backend == "scalar" else jaxpr_to_c
    sysm = flt.system
    G, n, m, p = sysm.group, flt.n, sysm.input_dim, sysm.output_dim
    state = flt.init(G.identity(), np.eye(n))
    paths, treedef = jax.tree_util.tree_flatten_with_path(state)
    fields = tuple(Field(_field_name(path), tuple(np.shape(x)), np.dtype(np.asarray(x).dtype))
                   for path, x in paths)
    leaves = [np.asarray(x) for _, x in paths]
    g_fields = [f for f, (path, _) in zip(fields, paths, strict=True) if f.name.startswith("g_hat")]
    k_field = next(f for f in fields if f.name == "K")

    def step_fn(leaves_in, t, dt, u, y):
        st = jax.tree_util.tree_unflatten(treedef, leaves_in)
        return jax.tree_util.tree_leaves(flt.interval(st, t, dt, u, u, y, y, jnp.inf))

    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    closed = jax.make_jaxpr(step_fn)([jnp.asarray(x) for x in leaves], f64(0.0), f64(0.01), jnp.zeros(m), jnp.zeros(p))
    closed, used = dce_jaxpr(closed)
    in_names = [f"in_{f.name}" for f in fields] + ["t", "dt", "u", "y"]
    in_names = [a for a, keep in zip(in_names, used, strict=True) if keep]
    tr = ScalarTranslator() if backend == "scalar" else Translator()
    core, tr = translate(f"{P}_core", closed, in_names, [f"out_{f.name}" for f in fields], translator=tr)
    # coordinates <-> group parameters
    g_size = sum(f.size for f in g_fields)
    c = G.coords_dim

    def from_coords(q):
        return jnp.concatenate([jnp.ravel(x) for x in jax.tree_util.tree_leaves(G.from_coords(q))])

    def to_coords(gflat):
        parts, off = [], 0
        for f in g_fields:
            parts.append(gflat[off:off + f.size].reshape(f.shape))
            off += f.size
        g = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(G.identity()), parts)
        return g.coords()

    fc, tr = translate(f"{P}_from_coords_core", jax.make_jaxpr(from_coords)(jnp.zeros(c)), ["q"], ["g"], translator=tr)
    tc, tr = translate(f"{P}_coords_core", jax.make_jaxpr(to_coords)(jnp.zeros(g_size)), ["g"], ["q"], translator=tr)

    code_text = "\n".join([*tr.function_texts, core, fc, tc])
    tables = [ln for ln in tr.table_lines if re.search(rf"\b{ln.split()[3].split('[')[0]}\b", code_text)]
    U = P.upper()
    status_init = [(f, leaf) for f, leaf, (path, _) in zip(fields, leaves, paths, strict=True)
                   if getattr(path[0], "name", None) == "status"]
    causes = "\n".join(f"#define {U}_{re.sub(r'[^A-Z]', '_', cause.upper()).strip('_')} {i}  /* {cause} */"
                       for i, cause in enumerate(FILTER_CAUSES))
    header = f"""/* {P}.h: a liemef filter exported as standalone C99 (liemef export-c). No heap, no library but libm.
 *
 * Filter: {flt!r}
 * System: {type(sysm).__name__}; group {G.__name__} (algebra dimension n = {n}), input m = {m}, output p = {p}.
 * The weights, connection and parameters are constants of {P}.c: export again for new ones.
 *
 * The state: g_hat (the estimate, as the group's parameters: {', '.join(f.name for f in g_fields)}), the
 * gain K (n x n, row-major), the last input (held over missing input samples) and the status of the run.
 * {P}_step advances one sample interval [t, t + dt] exactly as liemef's step(): mask[i] = 0 (or a NaN in y)
 * marks a missing measurement component, a NaN in u holds the last input, mask may be NULL (all present).
 * It returns the status code: 0 while healthy; after a failure the state stays frozen at the last good one,
 * code says why, index and time say where.
 */
#ifndef {U}_H
#define {U}_H
#include <stdint.h>

#define {U}_N {n}
#define {U}_INPUT_DIM {m}
#define {U}_OUTPUT_DIM {p}
#define {U}_GROUP_PARAMS {g_size}
#define {U}_COORDS_DIM {c}
#define {U}_BAD_ARGUMENT (-1)  /* init: g0 or K0 not finite, K0 not symmetric positive semidefinite;
                                     step: t or dt not finite, dt <= 0, an infinite u or present y (state untouched) */
{causes}

typedef struct {{
{chr(10).join(f"    {f.decl()};" for f in fields)}
}} {P}_state;

/* The initial state: g_hat = g0 ({U}_GROUP_PARAMS parameters), K = K0 (n x n, symmetric positive
 * semidefinite), u_last = 0, a healthy status. Returns 0, or {U}_BAD_ARGUMENT (the state is then untouched). */
int {P}_init({P}_state *s, const double *g0, const double *K0);
/* One sample interval [t, t + dt]: u (m), y (p), mask (p, or NULL). Returns the status code, or
 * {U}_BAD_ARGUMENT (the state is then untouched). */
int {P}_step({P}_state *s, double t, double dt, const double *u, const double *y, const int *mask);
/* A whole log of n samples (ts: n, us: n x m, ys: n x p row-major, NaN = missing): the n - 1 intervals, the
 * estimate and gain after each written to g_out ((n-1) x {U}_GROUP_PARAMS) and K_out ((n-1) x n x n) when
 * not NULL. Stops at the first failure; returns the status code. */
int {P}_run({P}_state *s, int n, const double *ts, const double *us, const double *ys, double *g_out,
            double *K_out);
/* The group parameters of coordinates q ({U}_COORDS_DIM), and back. */
void {P}_from_coords(const double *q, double *g);
void {P}_coords(const double *g, double *q);

#endif
"""
    core_args = [f.ref("s") if f"in_{f.name}" in in_names else None for f in fields] + ["&t", "&dt", "u", "y"]
    names_all = [f"in_{f.name}" for f in fields] + ["t", "dt", "u", "y"]
    call_in = [a for a, nm in zip(core_args, names_all, strict=True) if nm in in_names]
    call_in = [a if a is not None else "0" for a in call_in]
    g_copy = "\n".join(f"    for (int i = 0; i < {f.size}; i++) s->{f.name}[i] = g0[{off} + i];"
                       for f, off in zip(g_fields, np.cumsum([0] + [f.size for f in g_fields[:-1]]), strict=True))
    g_check = f"for (int i = 0; i < {g_size}; i++) if (!isfinite(g0[i])) return {U}_BAD_ARGUMENT;"
    st_set = []
    for f, leaf in status_init:
        if f.scalar:
            st_set.append(f"    s->{f.name} = {literal(leaf, f.dtype)};")
        else:
            st_set.extend(f"    s->{f.name}[{i}] = {literal(v, f.dtype)};" for i, v in enumerate(leaf.ravel()))
    u_field = next(f for f in fields if f.name == "u_last")
    g_out = "\n".join(f"            for (int i = 0; i < {f.size}; i++) g_out[(size_t)k * {g_size} + {off} + i] = "
                      f"s->{f.name}[i];"
                      for f, off in zip(g_fields, np.cumsum([0] + [f.size for f in g_fields[:-1]]), strict=True))
    source = f"""/* {P}.c: generated by liemef export-c from the jaxpr of one filter step; see {P}.h. */
#include "{P}.h"
#include <math.h>
#include <stddef.h>
#include <string.h>
@HELPERS@
{chr(10).join(tables)}

{chr(10).join(tr.function_texts)}
{core}
{fc}
{tc}
int {P}_init({P}_state *s, const double *g0, const double *K0)
{{
    {g_check}
    for (int i = 0; i < {n * n}; i++) if (!isfinite(K0[i])) return {U}_BAD_ARGUMENT;
    for (int i = 0; i < {n}; i++)
        for (int j = 0; j < i; j++)
            if (fabs(K0[i * {n} + j] - K0[j * {n} + i]) > 1e-12 * (1.0 + fabs(K0[i * {n} + j])))
                return {U}_BAD_ARGUMENT;
    {{  /* positive semidefinite: K0 + 1e-9 max|K0| I has a Cholesky factor (the filter's own test) */
        double L[{n * n}], big = 0.0;
        for (int i = 0; i < {n * n}; i++) big = fabs(K0[i]) > big ? fabs(K0[i]) : big;
        for (int j = 0; j < {n}; j++) {{
            double d = K0[j * {n} + j] + {DEFINITE_TOL!r} * (big > 1e-300 ? big : 1e-300);
            for (int k = 0; k < j; k++) d -= L[j * {n} + k] * L[j * {n} + k];
            if (!(d > 0.0)) return {U}_BAD_ARGUMENT;
            L[j * {n} + j] = sqrt(d);
            for (int i = j + 1; i < {n}; i++) {{
                double v = K0[i * {n} + j];
                for (int k = 0; k < j; k++) v -= L[i * {n} + k] * L[j * {n} + k];
                L[i * {n} + j] = v / L[j * {n} + j];
            }}
        }}
    }}
{g_copy}
    for (int i = 0; i < {n * n}; i++) s->K[i] = K0[i];
    for (int i = 0; i < {max(m, 1)}; i++) s->u_last[i] = 0.0;
{chr(10).join(st_set)}
    return 0;
}}

int {P}_step({P}_state *s, double t, double dt, const double *u, const double *y, const int *mask)
{{
    double yy[{max(p, 1)}];
    double uu[{max(m, 1)}];
    {P}_state next;
    if (!isfinite(t) || !isfinite(dt) || !(dt > 0.0)) return {U}_BAD_ARGUMENT;
    for (int i = 0; i < {p}; i++) {{
        yy[i] = (mask == NULL || mask[i]) ? y[i] : NAN;
        if (isinf(yy[i])) return {U}_BAD_ARGUMENT;
    }}
    for (int i = 0; i < {m}; i++) {{
        uu[i] = u[i];
        if (isinf(uu[i])) return {U}_BAD_ARGUMENT;
    }}
    u = uu;
    y = yy;
    {P}_core({', '.join(call_in + [f.ref("(&next)") for f in fields])});
    *s = next;
    return (int)s->code;
}}

int {P}_run({P}_state *s, int n, const double *ts, const double *us, const double *ys, double *g_out,
            double *K_out)
{{
    for (int k = 0; k + 1 < n; k++) {{
        int code = {P}_step(s, ts[k], ts[k + 1] - ts[k], us + (size_t)k * {m}, ys + (size_t)k * {p}, NULL);
        if (g_out != NULL) {{
{g_out}
        }}
        if (K_out != NULL) memcpy(K_out + (size_t)k * {n * n}, s->K, sizeof(double) * {n * n});
        if (code != 0) return code;
    }}
    return (int)s->code;
}}

void {P}_from_coords(const double *q, double *g) {{ {P}_from_coords_core(q, g); }}
void {P}_coords(const double *g, double *q) {{ {P}_coords_core(g, q); }}
"""
    head, tail = source.split("@HELPERS@\n")
    source = head + helpers_used(tail) + "\n" + tail
    del u_field, k_field
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    h_path, c_path = out / f"{P}.h", out / f"{P}.c"
    staged = []  # both files written beside their places first, then renamed: a failure leaves neither
    try:
        for path, text in ((h_path, header), (c_path, source)):
            fd, tmp = tempfile.mkstemp(dir=out, prefix=f".{path.name}.", suffix=".tmp")
            staged.append((tmp, path))
            with os.fdopen(fd, "w") as fh:
                fh.write(text)
        for tmp, path in staged:
            os.replace(tmp, path)
    finally:
        for tmp, _ in staged:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return ExportedC(header=h_path, source=c_path, prefix=P, fields=fields, n=n, input_dim=m, output_dim=p,
                     group_params=g_size, coords_dim=c, backend=backend)


def compiler() -> str | None:
    """The system C compiler: ``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH (None if none)."""
    for cand in ([os.environ["CC"]] if os.environ.get("CC") else []) + ["cc", "gcc", "clang"]:
        if shutil.which(cand):
            return cand
    return None


def quick_compiler() -> str | None:
    """The compiler of the C engine's quick (-O0) kernels: ``$CC`` where it is set, else ``clang`` where it is
    on the PATH, else :func:`compiler`. At -O0 Clang built the kernels of TSE(2), the attitude with gyro bias
    and the inertial navigation 1.7-1.8x faster than GCC (benchmarks/bench_quick_build.py); both compile ISO
    C99 without contraction on the x86-64 baseline (no FMA), so the quick kernel computes the -O2 kernel's bits
    (tests/test_engine.py)."""
    if not os.environ.get("CC") and shutil.which("clang"):
        return "clang"
    return compiler()


def run_compiler(args, cwd: str | os.PathLike | None = None, cc: str | None = None) -> None:
    """Run the system C compiler (:func:`compiler`, or ``cc``) with ``args`` (in ``cwd``): the one compiler
    runner of :mod:`liemef.codegen` (exports, engine kernels, the fast step's extension). RuntimeError if there
    is no compiler, or with the command and the compiler's message if it fails."""
    cc = cc or compiler()
    if cc is None:
        raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
    cmd = [cc, *args]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr[-4000:]}")


def build_shared(exported: ExportedC, out: str | os.PathLike | None = None, flags=CFLAGS) -> Path:
    """Compile an export into a shared library (``cc -shared -fPIC`` with ``flags``); a RuntimeError with the
    compiler's message if it fails."""
    if compiler() is None:
        raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
    # a fresh name each time: the dynamic loader caches libraries by path, so a new export in the same place
    # must not be served the old one
    lib = Path(out) if out is not None else Path(tempfile.mkstemp(dir=exported.source.parent,
                                                                  prefix=f".{exported.prefix}.", suffix=".so")[1])
    run_compiler([*flags, "-fPIC", "-shared", "-o", str(lib), str(exported.source), "-lm"])
    return lib


_CT = {np.dtype(np.float64): ctypes.c_double, np.dtype(np.int32): ctypes.c_int32, np.dtype(np.int64): ctypes.c_int64,
       np.dtype(np.bool_): ctypes.c_bool}


class CFilter:
    """An exported filter loaded with ctypes: the C ``init``/``step``/``run`` on NumPy arrays.

    ``CFilter(exported)`` compiles it (:func:`build_shared`) unless ``library`` is given. ``state`` is the
    live C struct; :meth:`leaves` reads it as :class:`~liemef.filters.FilterState` leaves, in order.
    """

    def __init__(self, exported: ExportedC, library: str | os.PathLike | None = None, flags=CFLAGS):
        self.exported = exported
        lib_path = library if library is not None else build_shared(exported, flags=flags)
        self.lib = _cache.dlopen(lib_path)
        members = []
        for f in exported.fields:
            t = _CT[f.dtype]
            members.append((f.name, t if f.scalar else t * max(f.size, 1)))
        self.State = type(f"{exported.prefix}_state", (ctypes.Structure,), {"_fields_": members})
        self.state = self.State()
        P = exported.prefix
        dp = ctypes.POINTER(ctypes.c_double)
        self._init = getattr(self.lib, f"{P}_init")
        self._init.argtypes = [ctypes.POINTER(self.State), dp, dp]
        self._step = getattr(self.lib, f"{P}_step")
        self._step.argtypes = [ctypes.POINTER(self.State), ctypes.c_double, ctypes.c_double, dp, dp,
                               ctypes.POINTER(ctypes.c_int)]
        self._run = getattr(self.lib, f"{P}_run")
        self._run.argtypes = [ctypes.POINTER(self.State), ctypes.c_int, dp, dp, dp, dp, dp]
        self._from = getattr(self.lib, f"{P}_from_coords")
        self._from.argtypes = [dp, dp]
        self._to = getattr(self.lib, f"{P}_coords")
        self._to.argtypes = [dp, dp]

    @staticmethod
    def _ptr(a):
        return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def init(self, g0, K0) -> int:
        """``P_init`` from the group parameters ``g0`` (flat) and ``K0``; returns its code."""
        g0 = np.ascontiguousarray(g0, np.float64).ravel()
        K0 = np.ascontiguousarray(K0, np.float64)
        return int(self._init(ctypes.byref(self.state), self._ptr(g0), self._ptr(K0)))

    def set_leaves(self, leaves) -> None:
        """Set the C state from :class:`~liemef.filters.FilterState` leaves (in order)."""
        for f, x in zip(self.exported.fields, leaves, strict=True):
            x = np.asarray(x)
            if f.scalar:
                setattr(self.state, f.name, x.item())
            else:
                arr = getattr(self.state, f.name)
                for i, v in enumerate(x.ravel()):
                    arr[i] = v.item()

    def leaves(self) -> list[np.ndarray]:
        """The C state as FilterState leaves (copies)."""
        out = []
        for f in self.exported.fields:
            v = getattr(self.state, f.name)
            out.append(np.asarray(v, f.dtype).reshape(f.shape) if f.scalar else
                       np.ctypeslib.as_array(v)[:f.size].astype(f.dtype).reshape(f.shape))
        return out

    def step(self, t: float, dt: float, u, y, mask=None) -> int:
        """``P_step``; returns the status code."""
        u = np.ascontiguousarray(u, np.float64).ravel()
        y = np.ascontiguousarray(y, np.float64).ravel()
        mk = None if mask is None else (ctypes.c_int * len(mask))(*[int(bool(v)) for v in mask])
        return int(self._step(ctypes.byref(self.state), float(t), float(dt), self._ptr(u if u.size else np.zeros(1)),
                              self._ptr(y), mk))

    def run(self, ts, us, ys) -> tuple[int, np.ndarray, np.ndarray]:
        """``P_run`` over a log: (code, g after each interval (N-1, params), K after each interval)."""
        ts = np.ascontiguousarray(ts, np.float64)
        N = ts.shape[0]
        e = self.exported
        us = np.ascontiguousarray(np.zeros((N, 1)) if e.input_dim == 0 else us, np.float64)
        ys = np.ascontiguousarray(ys, np.float64)
        g = np.full((max(N - 1, 1), e.group_params), np.nan)
        K = np.full((max(N - 1, 1), e.n, e.n), np.nan)
        code = int(self._run(ctypes.byref(self.state), N, self._ptr(ts), self._ptr(us), self._ptr(ys), self._ptr(g),
                             self._ptr(K)))
        return code, g[:N - 1], K[:N - 1]

    def from_coords(self, q) -> np.ndarray:
        """The group parameters of coordinates ``q``."""
        q = np.ascontiguousarray(q, np.float64)
        g = np.zeros(self.exported.group_params)
        self._from(self._ptr(q), self._ptr(g))
        return g

    def coords(self, g) -> np.ndarray:
        """The coordinates of group parameters ``g``."""
        g = np.ascontiguousarray(g, np.float64)
        q = np.zeros(self.exported.coords_dim)
        self._to(self._ptr(g), self._ptr(q))
        return q


def state_leaves(state: FilterState) -> list[np.ndarray]:
    """A FilterState's leaves, in the order of the exported struct's members."""
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(state)]


__all__ = ["CFLAGS", "CFilter", "ExportedC", "Field", "build_shared", "compiler", "export_c", "state_leaves"]
_ = math
