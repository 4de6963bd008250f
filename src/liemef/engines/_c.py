"""The C engine: a filter's interval as a compiled C kernel (:mod:`liemef.codegen`), over a log, a batch of
trials or inside a JAX program (a ``pure_callback``); the trajectory comes back with NaN after a failure by
the rule the XLA engine follows too (:func:`~liemef.filters._base.nan_after_failure`)."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..filters import Trajectory, nan_after_failure
from ._select import theta


def run(flt, kern, state, ts, us, ys, gap, keep_every) -> Trajectory:
    """A checked log by the C kernel: the same states as the XLA engine's (to rounding), NaN after a failure.
    The kernel writes the kept estimates, gains and status codes straight into the arrays JAX takes over (no
    packed rows to copy from: a TSE(2) log of 50,000 samples allocated and copied 42 MB, now 18 MB)."""
    R = 1 + (ts.shape[0] - 1) // keep_every
    kept, _ = _kept(kern)
    leaves = [_aligned_empty((R, *sl.shape)) if i in kept else None for i, sl in enumerate(kern.sslots)]
    xf = kern.history(theta(flt), kern.packed(state), np.ascontiguousarray(ts, np.float64), _c_array(us),
                      _c_array(ys), gap, keep_every, leaves)
    return _trajectory(kern, ts, leaves, xf, keep_every)


def run_batch(flt, kern, states_np, ts, us, ys, gap, keep_every, threads) -> Trajectory:
    """B checked logs on one time grid, shared among ``threads`` threads in groups of SIMD lanes."""
    leaves = jax.tree_util.tree_leaves(states_np)
    B = int(np.shape(leaves[0])[0])
    x = np.concatenate([a.reshape(B, -1).astype(np.float64) for a in leaves], axis=1)
    kern.check_packed(x, states_np, "states")
    rows, xf, _ = kern.batch(theta(flt), x, ts, _c_array(us), _c_array(ys), float(gap), keep_every, threads=threads)
    return trajectory(kern, ts, rows, xf, keep_every, lead=(B,))


def trajectory(kern, ts, rows, xf, keep_every, lead=()) -> Trajectory:
    """The Trajectory of the kernel's kept rows (lead + (R, S)) and final packed states (lead + (S,)): NaN
    after a failure, as the XLA engine emits. Only the leaves a Trajectory holds are cut from the rows (the
    estimates and gains copied once each, the status codes read in place)."""
    kept, code = _kept(kern)
    shape = rows.shape[:-1]
    leaves = []
    for i, sl in enumerate(kern.sslots):
        view = rows[..., sl.offset:sl.offset + sl.size].reshape(shape + sl.shape) if i in kept else None
        leaves.append(view if view is None or i == code else _aligned_copy(view))  # one copy each, not two
    return _trajectory(kern, ts, leaves, xf, keep_every, lead)


def _trajectory(kern, ts, leaves, xf, keep_every, lead=()) -> Trajectory:
    """The Trajectory of the kept leaves (float64 arrays, lead + (R,) + the leaf's shape; None for a leaf a
    Trajectory does not hold) and the final packed states, handed to JAX in one transfer."""
    kept, code = _kept(kern)
    for i in kept:
        if kern.sslots[i].dtype != np.float64 and i != code:
            leaves[i] = leaves[i].astype(kern.sslots[i].dtype)
    hist = jax.tree_util.tree_unflatten(kern.sdef, leaves)
    g_hat, K = nan_after_failure(np.asarray(hist.status.code), (hist.g_hat, hist.K), first_given=True)
    final = [_contiguous(a) for a in kern.unpack(xf, lead)]
    ts_kept, (g_hat, K), final = jax.device_put((_contiguous(ts[::keep_every]), (g_hat, K), final))
    final = jax.tree_util.tree_unflatten(kern.sdef, final)
    return Trajectory(ts=ts_kept, g_hat=g_hat, K=K, status=final.status, final=final)


def _kept(kern) -> tuple[frozenset, int]:
    """The indices of the state leaves whose history a Trajectory holds (the estimate's, the gain and the status
    code), and the status code's; computed once a kernel."""
    got = kern.__dict__.get("_trajectory_leaves")
    if got is None:
        marks = jax.tree_util.tree_unflatten(kern.sdef, list(range(len(kern.sslots))))
        kept = frozenset(jax.tree_util.tree_leaves((marks.g_hat, marks.K, marks.status.code)))
        got = kern._trajectory_leaves = (kept, marks.status.code)
    return got


def scan(flt, kern, state, ts, us, ys, gap, n_valid, keep_every) -> Trajectory:
    """:func:`liemef.engines.scan` by the C kernel: the packed rows come back from a ``pure_callback``
    (:func:`_scan_host`) and are unpacked, with NaN after a failure, in JAX."""
    N, M = ts.shape[0], keep_every
    R = 1 + -(-(N - 1) // M)
    f64 = jnp.float64
    theta = jnp.concatenate([jnp.ravel(x).astype(f64) for x in jax.tree_util.tree_leaves(eqx.filter(flt, eqx.is_array))]
                            or [jnp.zeros(0)])
    x = jnp.concatenate([jnp.ravel(a).astype(f64) for a in jax.tree_util.tree_leaves(state)])
    nv = jnp.asarray(N if n_valid is None else n_valid, jnp.int32)
    S = kern.n_state
    kern.check_packed(x, state, "state")
    rows, xf = jax.pure_callback(functools.partial(_scan_host, kern, M, R),
                                 (jax.ShapeDtypeStruct((R, S), f64), jax.ShapeDtypeStruct((S,), f64)),
                                 theta, x, jnp.asarray(ts, f64), jnp.asarray(us, f64), jnp.asarray(ys, f64),
                                 jnp.asarray(gap, f64), nv, vmap_method="broadcast_all")

    def unpack(v, lead):
        return [v[..., s.offset:s.offset + s.size].reshape(lead + s.shape).astype(s.dtype) for s in kern.sslots]

    hist = jax.tree_util.tree_unflatten(kern.sdef, unpack(rows, (R,)))
    g_hat, K = nan_after_failure(hist.status.code, (hist.g_hat, hist.K), first_given=True)
    final = jax.tree_util.tree_unflatten(kern.sdef, unpack(xf, ()))
    return Trajectory(ts=ts[::M], g_hat=g_hat, K=K, status=final.status, final=final)


def _scan_host(kern, keep, R, theta, x, ts, us, ys, gap, n_valid):
    """The host side of :func:`_scan_c`, on NumPy arrays with or without a leading trial axis (``vmap``'s
    ``broadcast_all``): the kept rows (R of them; past the last valid interval, the final state) and the final
    packed states. Trials with one time grid, length and gap go to :meth:`Kernel.batch` together."""
    theta, x, ts, us, ys = (np.ascontiguousarray(a, np.float64) for a in (theta, x, ts, us, ys))
    lead = ts.shape[:-1]  # () unbatched; one axis per vmap, flattened into trials
    theta, x, ts = theta.reshape(-1, theta.shape[-1]), x.reshape(-1, x.shape[-1]), ts.reshape(-1, ts.shape[-1])
    us, ys = us.reshape((-1,) + us.shape[-2:]), ys.reshape((-1,) + ys.shape[-2:])
    gap, n_valid = np.ravel(gap), np.maximum(np.ravel(n_valid), 1)
    B = ts.shape[0]
    rows = np.empty((B, R, kern.n_state))
    finals = np.empty((B, kern.n_state))
    nv = int(n_valid[0])
    shared = np.all(ts == ts[:1]) and np.all(n_valid == nv) and np.all(gap == gap[0])
    if shared:
        th = theta[0] if np.all(theta == theta[:1]) else theta
        got, finals[:], _ = kern.batch(th, x, np.ascontiguousarray(ts[0, :nv]), _c_array(us[:, :nv]),
                                       _c_array(ys[:, :nv]), float(gap[0]), keep)
        done = got.shape[1]
        rows[:, :done] = got
        rows[:, done:] = finals[:, None, :]
    else:
        for b in range(B):
            n = int(n_valid[b])
            got, finals[b] = kern.scan(theta[b], x[b], np.ascontiguousarray(ts[b, :n]), _c_array(us[b, :n]),
                                       _c_array(ys[b, :n]), float(gap[b]), keep)
            rows[b, :got.shape[0]] = got
            rows[b, got.shape[0]:] = finals[b]
    return rows.reshape(lead + rows.shape[1:]), finals.reshape(lead + finals.shape[1:])



def _contiguous(a: np.ndarray) -> np.ndarray:
    """``a``, or a C-ordered copy of it (of the same shape, 0-d included)."""
    return a if a.flags.c_contiguous else a.copy()


ALIGN = 64
"""The alignment at which JAX's CPU client takes a NumPy array without copying it (``device_put`` shares it)."""


def _aligned_empty(shape) -> np.ndarray:
    """An uninitialised C-ordered float64 array at an :data:`ALIGN`-byte boundary (``device_put`` shares it)."""
    size = int(np.prod(shape, dtype=np.int64)) * 8
    raw = np.empty(size + ALIGN, np.uint8)
    off = -raw.ctypes.data % ALIGN
    return raw[off:off + size].view(np.float64).reshape(shape)


def _aligned_copy(a: np.ndarray) -> np.ndarray:
    """A C-ordered copy of ``a`` at an :data:`ALIGN`-byte boundary: the kept states' history (a strided view of
    the kernel's packed rows) becomes JAX's array in one copy, where an unaligned one was copied twice (into
    C order, then by ``device_put``): on the batch benchmark's 256 trials, 18 MB a call."""
    raw = np.empty(a.nbytes + ALIGN, np.uint8)
    off = -raw.ctypes.data % ALIGN
    out = raw[off:off + a.nbytes].view(a.dtype).reshape(a.shape)
    np.copyto(out, a)
    return out


def _c_array(a) -> np.ndarray:
    """A float64 C-contiguous array for the kernel (a one-element one for an empty sample: never read)."""
    a = np.ascontiguousarray(a, np.float64)
    return a if a.size else np.zeros(1)

