r"""Run a filter's sample intervals: over a whole log (:func:`run`), B logs on one time grid
(:func:`run_batch`), inside a JAX program (:func:`scan`), one online step (:func:`step`) or a robot's loop
(:func:`online`), by XLA or by the C kernel (:func:`~liemef.engines.engine_of`).

Every filter of the library (:class:`~liemef.filters.AbstractFilter`) says how one interval advances its
state; these functions are the only ones that loop over intervals. They check their arguments at the
boundary (a ValueError naming the argument, before anything is compiled), pick the engine, and return a
:class:`~liemef.filters.Trajectory` whose states after a failure are NaN. The filters' methods of the same
names call them.
"""

from __future__ import annotations

import math
import warnings

import jax
import numpy as np
from jaxtyping import ArrayLike

from .. import _validate
from ..filters import FilterState, Trajectory, check_log, check_samples, check_time
from . import _c, _xla
from ._select import LAZY, _entry, fast_ctl, kernel


class LogGapWarning(UserWarning):
    """A log had sample intervals longer than the gap threshold; the filter predicted through them."""


def run(flt, state: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *, gap: float | None = None,
        keep_every: int = 1, engine: str | None = None) -> Trajectory:
    """Filter a whole log: ``ts`` (N,) strictly increasing, ``us`` (N, m), ``ys`` (N, p).

    Sample k is used over ``[ts[k], ts[k+1])``; the result holds the state at every ``ts[k]`` (every
    ``keep_every``-th), the first being ``state``. NaN in ``ys`` marks a missing sample; NaN in ``us`` holds
    the last input. An interval longer than ``gap`` (default: 10 times the median interval) is predicted
    through without holding density measurements, and a warning says so (``gap=math.inf``: no interval is
    a gap, as in :func:`step`). By XLA, logs are padded to a length bucket (:func:`~liemef.engines.bucket`):
    one compilation serves every log of a bucket and every weight set.

    ``engine``: ``"c"`` (the filter's interval as a compiled C kernel, :mod:`liemef.codegen`: one build per
    structure and zero pattern of the weights, no padding), ``"xla"`` (the jitted :func:`scan`) or ``"auto"``
    (the default, or ``$LIEMEF_ENGINE``): C where it is available (:func:`~liemef.engines.engine_of`).
    """
    flt.check_state(state)
    flt.check_element("state.g_hat", state.g_hat)
    _validate.square("state.K", state.K, flt.n)
    ts, us, ys, gap = check_log(flt, ts, us, ys, (), gap, keep_every)
    kern = kernel(flt, engine)
    if kern is not None:
        traj = _c.run(flt, kern, state, ts, us, ys, float(gap), keep_every)
    else:
        traj = _xla.run(flt, state, ts, us, ys, gap, keep_every)
    gaps = int(traj.status.gaps)
    if gaps:
        warnings.warn(f"run: {gaps} sample interval(s) longer than the gap threshold {gap:.4g} s (longest "
                      f"{float(traj.status.longest_gap):.4g} s) were predicted through without holding "
                      "density measurements", LogGapWarning, stacklevel=3)
    return traj


def run_batch(flt, states: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *,
              gap: float | None = None, keep_every: int = 1, engine: str | None = None,
              threads: int | None = None) -> Trajectory:
    """Filter B logs on one time grid (Monte Carlo trials): ``states`` a FilterState with a leading trial
    axis (B,) on every leaf (``jax.tree_util.tree_map(lambda *a: jnp.stack(a), *states)``), ``ts`` (N,),
    ``us`` (B, N, m), ``ys`` (B, N, p). Returns a Trajectory with the trial axis first (``K`` (B, R, n, n),
    ``status`` and ``final`` batched); each trial is its own :func:`run` (to rounding).

    By the C engine the trials are shared among ``threads`` threads (default: every CPU this process may
    use), in groups of SIMD lanes where the kernel has them; by XLA, one ``vmap`` of :func:`scan`."""
    # NumPy from here on: indexing a JAX array would compile an XLA gather for each new shape
    states_np = jax.tree_util.tree_map(np.asarray, states)
    leaves = jax.tree_util.tree_leaves(states_np)
    B = int(np.shape(leaves[0])[0]) if np.ndim(leaves[0]) else 0
    for path, leaf in jax.tree_util.tree_flatten_with_path(states_np)[0]:
        if np.ndim(leaf) == 0 or np.shape(leaf)[0] != B or B < 1:
            raise ValueError(f"states: expected a leading trial axis of one length B >= 1 on every leaf, got "
                             f"shape {np.shape(leaf)} at {jax.tree_util.keystr(path)} (B = {B})")
    flt.check_state(jax.tree_util.tree_map(lambda a: a[0], states_np))
    ts, us, ys, gap = check_log(flt, ts, us, ys, (B,), gap, keep_every, threads=threads,
                                 g_hat=states_np.g_hat)
    kern = kernel(flt, engine)
    if kern is not None:
        traj = _c.run_batch(flt, kern, states_np, ts, us, ys, gap, keep_every, threads)
    else:
        traj = _xla.run_batch(flt, states, ts, us, ys, gap, keep_every)
    gaps = int(np.sum(traj.status.gaps))
    if gaps:
        warnings.warn(f"run_batch: {gaps} sample interval(s) longer than the gap threshold {gap:.4g} s over the "
                      "trials were predicted through without holding density measurements", LogGapWarning,
                      stacklevel=3)
    return traj


def scan(flt, state: FilterState, ts, us, ys, *, gap=np.inf, n_valid=None, keep_every: int = 1,
         engine: str | None = "xla") -> Trajectory:
    """Traceable core of :func:`run` (no checks): one ``lax.scan`` over the sample intervals.

    ``n_valid``: only the first ``n_valid`` samples are data (the rest is padding, skipped);
    ``keep_every`` (static): keep every M-th state in the history (memory flat in the log length).
    ``engine``: ``"xla"`` (the default: differentiable, any transformation) or ``"c"``/``"auto"``/None (as
    in :func:`run`; the experiments' trials pass None): the C kernel through ``jax.pure_callback``, with
    the parameters and states still traced data; under ``vmap`` one call for the whole batch, shared among
    the cores in SIMD groups (:func:`run_batch`); not differentiable."""
    if engine != "xla":
        kern = kernel(flt, engine)
        if kern is not None:
            return _c.scan(flt, kern, state, ts, us, ys, gap, n_valid, keep_every)
    return _xla.scan(flt, state, ts, us, ys, gap, n_valid, keep_every)


def step(flt, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float, *,
         u_next: ArrayLike | None = None, y_next: ArrayLike | None = None, gap: float = math.inf,
         engine: str | None = None) -> FilterState:
    """Advance one sample interval ``[t, t + dt]`` (online use). NaN in ``y`` marks a missing component,
    NaN in ``u`` holds the last input; ``u_next``/``y_next`` are the samples at ``t + dt`` for
    ``interpolation="linear"`` (default: held). On a failure the returned state is the input state with a
    failed ``status`` (see :class:`~liemef.filters.Status`), and later steps leave it unchanged.

    ``engine`` as in :func:`run`: by the C kernel, the state's leaves are NumPy arrays (the next step reads
    the packed vector they came from)."""
    # the hot path of a robot loop: methods are reached through the class, since reading a method off an
    # equinox Module builds a bound-method Module each time (microseconds)
    cls = type(flt)
    kern, _, address, _, ctl = _entry(flt, engine, check_time, (t, dt))
    if kern is not None:  # the state, time and samples are checked as the kernel takes them
        if ctl is LAZY:
            ctl = fast_ctl(flt)
        return kern.step(flt, address, ctl, state, t, dt, gap, u, y, u_next, y_next)
    t, dt = check_time(t, dt)
    cls.check_state(flt, state)
    u, y, u1, y1 = check_samples(flt.system.input_dim, flt.system.output_dim, u, y, u_next, y_next)
    return _xla.step(flt, state, t, dt, gap, u, y, u1, y1)


def online(flt, state: FilterState, *, engine: str | None = None):
    """The online filter of a robot's loop (:class:`~liemef.engines.OnlineFilter`): steps from ``state``
    kept packed in the C kernel, each one C call returning the status code; the state is read when asked
    for. By XLA (``engine="xla"`` or no C compiler) the same interface over :func:`step`."""
    from ._online import OnlineFilter

    return OnlineFilter(flt, state, engine)
