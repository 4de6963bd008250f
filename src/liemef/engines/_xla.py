"""The XLA engine: a filter's intervals in one ``lax.scan``, jitted once per structure and length bucket."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _side
from ..filters import TRACES, FilterState, Status, Trajectory, nan_after_failure


def bucket(n: int) -> int:
    """The padded number of intervals for a log of ``n`` intervals: the next power of two (at least 64), so
    that logs of different lengths share one compilation per bucket."""
    return max(64, 1 << max(0, (n - 1).bit_length()))


def scan(flt, state: FilterState, ts, us, ys, gap, n_valid, keep_every: int) -> Trajectory:
    """The filter's intervals over a log in one ``lax.scan`` (traceable, no checks; see
    :func:`liemef.engines.scan`)."""
    N = ts.shape[0]
    n_valid = N if n_valid is None else n_valid
    xs = (jnp.arange(N - 1), ts[:-1], jnp.diff(ts), us[:-1], us[1:], ys[:-1], ys[1:])

    def advance(st, x):
        k, t, dt, u0, u1, y0, y1 = x
        return jax.lax.cond(k + 1 < n_valid, lambda s: flt.interval(s, t, dt, u0, u1, y0, y1, gap),
                            lambda s: s, st)

    def emit(st):
        return nan_after_failure(st.status.code, (st.g_hat, st.K), first_given=False)

    M = keep_every
    if M == 1:
        def body(st, x):
            st = advance(st, x)
            return st, emit(st)

        final, (g_tr, K_tr) = jax.lax.scan(body, state, xs)
    else:
        n_chunks = -(-(N - 1) // M)
        pad = n_chunks * M - (N - 1)
        # the data padded with its last row; the indices run on, so the padding counts as invalid
        rows = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]).reshape((n_chunks, M) + a.shape[1:])  # noqa: E731
        xs = (jnp.arange(n_chunks * M).reshape(n_chunks, M), *jax.tree_util.tree_map(rows, xs[1:]))

        def chunk(st, xc):
            st = jax.lax.scan(lambda s, x: (advance(s, x), None), st, xc)[0]
            return st, emit(st)

        final, (g_tr, K_tr) = jax.lax.scan(chunk, state, xs)
    g_all = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), state.g_hat, g_tr)
    K_all = jnp.concatenate([state.K[None], K_tr])
    return Trajectory(ts=ts[::M], g_hat=g_all, K=K_all, status=final.status, final=final)


def run(flt, state, ts, us, ys, gap, keep_every) -> Trajectory:
    """A checked log by the jitted :func:`scan`, padded to its length bucket (:func:`bucket`)."""
    N = ts.shape[0]
    traj = _run_jit(flt, state, *_padded(ts, us, ys, keep_every), np.asarray(N, np.int32), np.asarray(gap),
                    keep_every)
    kept = -(-N // keep_every)
    return Trajectory(ts=jnp.asarray(ts[::keep_every]), g_hat=traj.g_hat[:kept], K=traj.K[:kept],
                      status=traj.status, final=traj.final)


def run_batch(flt, states, ts, us, ys, gap, keep_every) -> Trajectory:
    """B checked logs on one time grid by one ``vmap`` of the jitted :func:`scan`, padded as :func:`run`."""
    N = ts.shape[0]
    tr = _run_batch_jit(flt, states, *_padded(ts, us, ys, keep_every), np.asarray(N, np.int32), np.asarray(gap),
                        keep_every)
    kept = -(-N // keep_every)
    return Trajectory(ts=jnp.asarray(ts[::keep_every]), g_hat=jax.tree_util.tree_map(lambda a: a[:, :kept], tr.g_hat),
                      K=tr.K[:, :kept], status=tr.status, final=tr.final)


def _padded(ts, us, ys, keep_every):
    """A log of N samples (``us``, ``ys``: (..., N, m) and (..., N, p)) padded to ``bucket(N - 1)`` intervals,
    rounded up to whole chunks of ``keep_every``: the last time repeated, the samples NaN (skipped as invalid
    by :func:`scan`'s ``n_valid``)."""
    N = ts.shape[0]
    pad = -(-bucket(N - 1) // keep_every) * keep_every + 1 - N

    def nan(a):
        return np.concatenate([a, np.full(a.shape[:-2] + (pad, a.shape[-1]), np.nan)], axis=-2)

    return np.concatenate([ts, np.full(pad, ts[-1])]), nan(us), nan(ys)


def step(flt, state, t, dt, gap, u, y, u1, y1) -> FilterState:
    """One checked interval by the jitted step of the filter's structure."""
    fn, leaves = _fast_parts(flt)
    z = np.concatenate([[float(t), dt, float(gap)], u, u1, y, y1])
    out = fn(leaves, jax.tree_util.tree_leaves(state), z)
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(state), out)


# --- compiled entry points, shared by every filter of the same structure --------------------------------------
@eqx.filter_jit
def _run_jit(flt, state, ts, us, ys, n_valid, gap, keep_every):
    TRACES["run"] += 1
    return scan(flt, state, ts, us, ys, gap, n_valid, keep_every)


@eqx.filter_jit
def _run_batch_jit(flt, states, ts, us, ys, n_valid, gap, keep_every):
    TRACES["run_batch"] += 1
    return eqx.filter_vmap(lambda st, u, y: scan(flt, st, ts, u, y, gap, n_valid, keep_every))(states, us, ys)


def _step_leaves(static, leaves, state_leaves, z):
    # Online step on flat arrays: jit dispatch flattens nested modules in Python (~20 us); lists of arrays and
    # one packed sample vector z = (t, dt, gap, u, u_next, y, y_next) take the C++ fast path.
    TRACES["step"] += 1
    flt = eqx.combine(jax.tree_util.tree_unflatten(static[0], leaves), static[1])
    m, p = flt.system.input_dim, flt.system.output_dim
    state = jax.tree_util.tree_unflatten(static[2], state_leaves)
    o = 3
    u0, u1, y0, y1 = z[o:o + m], z[o + m:o + 2 * m], z[o + 2 * m:o + 2 * m + p], z[o + 2 * m + p:]
    return jax.tree_util.tree_leaves(flt.interval(state, z[0], z[1], u0, u1, y0, y1, z[2]))


_STEP_JIT: dict = {}


def _fast_parts(flt):
    """The compiled step of the filter's structure (one per structure, shared) and its array leaves, cached on
    the instance."""
    cached = _side.get(flt, "fast")
    if cached is None:
        dyn, static = eqx.partition(flt, eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dyn)
        n_blocks = len(flt.blocks)
        state_def = jax.tree_util.tree_structure(FilterState(flt.system.group.identity(), jnp.zeros((flt.n, flt.n)),
                                                             jnp.zeros(flt.system.input_dim),
                                                             Status.initial(n_blocks)))
        key = (treedef, static, state_def)
        if key not in _STEP_JIT:
            _STEP_JIT[key] = jax.jit(functools.partial(_step_leaves, key))
        cached = (_STEP_JIT[key], leaves)
        _side.put(flt, "fast", cached)
    return cached
