r"""The smoother of a whole log, as one problem or, for a log too long to hold, in windows with overlap.

**In chunks.** The log's states are cut into consecutive blocks of ``chunk`` samples. The estimates of block
$[a, b)$ are those of the minimizer of the cost of :mod:`._batch` over the window $[s, e]$,
$s = a - o_-$, $e = b - 1 + o_+$ (clipped to the log; ``overlap`` $= (o_-, o_+)$), whose prior is the filter's
state at $t_s$: its estimate and K, which carry every sample before $t_s$, as a fixed-lag window's prior does.
- On a linear system that prior is exact: a window that runs to the log's end gives the whole-log smoother's
  estimates and covariances on its block (``tests/test_smoother.py`` checks it against the RTS smoother to 1e-10).
- Otherwise a window leaves out the samples after $t_e$, and, on a nonlinear system, linearizes its prior at the
  filter's estimate rather than at the smoothed one. Both effects decay with the overlaps: on SE(2) localization
  the difference from the whole-log smoother falls as the overlap grows (the same test).
- **Memory** is that of one window, whatever the log's length: the filter runs from window to window and keeps
  its state, not its history; the log's arrays and the estimates (``g`` (N,) and ``P`` (N, n, n)) are the only
  things of the log's length. :func:`smooth_chunks` yields each block as it is done, for a caller that writes
  them away.
- **Cost** per window: each Levenberg-Marquardt iteration is linear in the window's length; the filter runs over
  the log about $1 + (o_- + o_+ + \text{chunk})/\text{chunk}$ times. Windows of one length share one length
  bucket, so the solver is compiled once (twice with a shorter last window).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Iterator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .. import _validate
from ..engines import LogGapWarning
from ..filters import CAUSES, AbstractFilter, FilterState
from ..groups import LieGroup
from ..integrators import AbstractIntegrator
from . import _batch
from ._batch import FLOOR_STD, Smoothed

_WORST = ("converged", "max-iterations", "stalled", "failed")  # a chunked run's status: its worst window's


def smooth(flt: AbstractFilter, state: FilterState, ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N m"] | None,
           ys: Float[ArrayLike, "N p"], *, gap: float | None = None, init: LieGroup | None = None,
           integrator: str | AbstractIntegrator | None = None, max_iterations: int = 200, tol: float = 1e-9,
           floor_std: float = FLOOR_STD, chunk: int | None = None,
           overlap: int | tuple[int, int] | None = None) -> Smoothed:
    r"""Smooth a whole log: the minimizer of the cost of the model ``flt`` runs (:mod:`liemef.smoothers`) over
    every state, with the marginal covariance of each.

    The log has the filter's layout and conventions (:meth:`~liemef.MinimumEnergyFilter.run`): ``ts`` (N,),
    ``us`` (N, m), ``ys`` (N, p); NaN in ``ys`` is a missing sample, NaN in ``us`` holds the last input; each
    sensor at its own rate, with its residual (angles wrap, directions and rotations on their manifolds), its
    gate or robust loss and its time-varying weight. The prior is the filter's initial state: ``state.g_hat``
    and the covariance ``state.K`` (singular allowed: floored at ``floor_std``). The weights are the filter's
    (``flt.weights``), so a tuned filter is smoothed with its own weights.

    Args:
        flt: the filter whose model is smoothed (:class:`~liemef.MinimumEnergyFilter` or a baseline).
        state: its initial state (:meth:`~liemef.MinimumEnergyFilter.init`), the prior.
        ts: (N,) strictly increasing sample times.
        us: (N, m) inputs (NaN: hold the last), or None for a system without inputs.
        ys: (N, p) samples (NaN: missing).
        gap: an interval longer than this holds no density sample, as in the filter (default: 10 times the
            median interval).
        init: the starting trajectory (batch (N,)); default: the filter's own run over the log (where that run
            failed, dead reckoning from its last good state).
        integrator: the process model's one step per interval (default: the filter's integrator, else RKMK4).
        max_iterations: the most Levenberg-Marquardt steps, accepted or not (per window, in chunks).
            Gauss-Newton converges quadratically where the residuals at the minimizer are small, and only
            linearly where they are large (samples that the model cannot fit): then it takes tens of steps.
        tol: converged when a step's largest component is below it (with little damping; the step is kept if
            the cost, to its round-off, does not rise).
        floor_std: the floor of the prior's and the process noise's stds (:data:`FLOOR_STD`).
        chunk: None (the default): the whole log is one problem. Else the number of states estimated per
            window, for a log too long to hold as one problem (:func:`smooth_chunks`): the memory is one
            window's, and the result approximates the whole-log minimizer, closer with larger overlaps.
        overlap: with ``chunk``, the samples a window adds before and after its block, a number for both or a
            pair ``(before, after)`` (default: ``chunk // 2`` each).

    Returns:
        :class:`Smoothed`. A run that does not converge says so in ``status`` and ``message``; one whose cost
        or covariances are not finite has status ``"failed"`` and NaN estimates: failures are values. In
        chunks, the status is the worst window's (any failed window fails the run, with NaN estimates),
        ``iterations`` the windows' total, ``gradient_norm`` the largest of the windows' own, and ``cost`` and
        ``cost_init`` the whole log's cost at the joined estimates and at the joined starting trajectory.
    """
    su = _batch.setup(flt, state, ts, us, ys, gap=gap, init=init, integrator=integrator,
                      max_iterations=max_iterations, tol=tol, floor_std=floor_std)
    if chunk is None and overlap is not None:
        raise ValueError(f"overlap: only with chunk (a number of states per window), got overlap={overlap!r} "
                         "and chunk=None")
    if chunk is None:
        return _batch.smooth_whole(flt, state, su, init)
    before, after = _overlaps(chunk, overlap)
    pieces = list(_pieces(flt, state, su, init, chunk, before, after))
    return _joined(flt, state, su, pieces, chunk, before, after)


def smooth_chunks(flt: AbstractFilter, state: FilterState, ts: Float[ArrayLike, " N"],
                  us: Float[ArrayLike, "N m"] | None, ys: Float[ArrayLike, "N p"], *, chunk: int,
                  overlap: int | tuple[int, int] | None = None, gap: float | None = None,
                  init: LieGroup | None = None, integrator: str | AbstractIntegrator | None = None,
                  max_iterations: int = 200, tol: float = 1e-9, floor_std: float = FLOOR_STD) -> Iterator[Smoothed]:
    """Smooth a log in windows (module docstring), yielding each block of ``chunk`` states as it is done: a
    :class:`Smoothed` of the block's times, estimates and covariances, with its window's cost, status and
    message. The arguments are :func:`smooth`'s; they are all checked before the first block is computed.

    Memory is one window's and one block's, whatever the log's length, for a caller that writes each block
    away. A block's status is its window's: a window whose prior cannot be had (the filter failed before it) is
    ``"failed"``, with NaN estimates, and so is every later one.
    """
    su = _batch.setup(flt, state, ts, us, ys, gap=gap, init=init, integrator=integrator,
                      max_iterations=max_iterations, tol=tol, floor_std=floor_std)
    before, after = _overlaps(chunk, overlap)

    def blocks():
        for piece in _pieces(flt, state, su, init, chunk, before, after):
            yield piece.smoothed

    return blocks()


def _overlaps(chunk, overlap) -> tuple[int, int]:
    """``chunk`` and ``overlap`` checked; the overlaps before and after a block."""
    chunk = _validate.integer("chunk", chunk, low=1)
    if overlap is None:
        return chunk // 2, chunk // 2
    pair = overlap if isinstance(overlap, tuple | list) else (overlap, overlap)
    if len(pair) != 2:
        raise ValueError(f"overlap: expected a number of samples or a pair (before, after), got {overlap!r}")
    return tuple(_validate.integer(f"overlap[{i}]" if pair is overlap else "overlap", v) for i, v in enumerate(pair))


def windows(N: int, chunk: int, before: int, after: int) -> list[tuple[int, int, int, int]]:
    """The blocks ``[a, b)`` of ``chunk`` states (a last block of one state joins the one before it) and their
    windows ``[s, e]``, each of at least 2 states: ``(a, b, s, e)``."""
    starts = list(range(0, N, chunk))
    if len(starts) > 1 and N - starts[-1] < 2:
        starts.pop()
    out = []
    for i, a in enumerate(starts):
        b = starts[i + 1] if i + 1 < len(starts) else N
        s, e = max(0, a - before), min(N - 1, b - 1 + after)
        if e == s:  # a block of one state with no overlap: the window takes the state after it, or before
            e, s = (e + 1, s) if e + 1 < N else (e, s - 1)
        out.append((a, b, s, e))
    return out


@dataclasses.dataclass(frozen=True)
class _Piece:
    a: int
    b: int
    smoothed: Smoothed  # the block's estimates, its window's cost, status and message
    start: LieGroup  # the block's starting trajectory


def _pieces(flt, state, su: _batch.Setup, init, chunk: int, before: int, after: int) -> Iterator[_Piece]:
    """Each block's smoothed estimates, from its window (module docstring)."""
    system, integ, ts, us, ys, held = su.system, su.integ, su.ts, su.us, su.ys, su.held
    cur, prior, dead = 0, state, None  # the filter's state at ts[cur], before sample cur acts
    for a, b, s, e in windows(ts.shape[0], chunk, before, after):
        where = f"window of samples {s}..{e} (states {a}..{b - 1})"
        if dead is None and s > cur:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LogGapWarning)  # said once, by the caller's own filter run
                tr = flt.run(prior, ts[cur:s + 1], us[cur:s + 1], ys[cur:s + 1], gap=su.gap)
            if not bool(tr.ok):
                k = cur + int(tr.status.index) - int(prior.status.steps)  # the status counts from its init
                dead = f"the filter that gives the window's prior failed at sample {k} " \
                       f"({CAUSES[int(tr.status.code)].message})"
            prior, cur = tr.final, s
        if dead is not None:
            result = _batch.failed(ts[a:b], state.g_hat, f"{where}: failed: {dead}")
            yield _Piece(a, b, result, result.g)
            continue
        w = slice(s, e + 1)
        if init is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LogGapWarning)
                start = flt.run(prior, ts[w], us[w], ys[w], gap=su.gap).g_hat
        else:
            start = init[s:e + 1]
        start = _batch._filled(system, integ, start, ts[w], held[w])
        sm = _batch.solve(system, flt.weights, ts[w], held[w], ys[w], prior.g_hat,
                          np.asarray(prior.K, dtype=np.float64), start, integ=integ, screens=su.screens, gap=su.gap,
                          floor_std=su.floor_std, max_iterations=su.max_iterations, tol=su.tol)
        k = slice(a - s, b - s)
        yield _Piece(a, b, dataclasses.replace(sm, ts=sm.ts[k], g=sm.g[k], P=sm.P[k],
                                               message=f"{where}: {sm.message}"), start[k])


@eqx.filter_jit
def _cost(system, integ, screens, prob, xs):
    return _batch._cost(system, integ, screens, prob, xs)


def whole_costs(flt, state, su: _batch.Setup, start: LieGroup, blocks: list[tuple[int, int]],
                trajectories: list[LieGroup]) -> list[float]:
    """The whole log's cost at each of ``trajectories`` (batch (N,)), summed block by block so that only one
    block's terms are held at a time: the prior in the first block, and in block ``[a, b)`` the process terms
    from ``x_a`` to ``x_b`` and the samples at ``a..b-1`` (at the log's last state too, in the last block). Each
    block's terms are built once for all trajectories; a process noise that depends on the state is evaluated on
    ``start``, as the smoother evaluates it."""
    system, integ, ts, held, ys = su.system, su.integ, su.ts, su.held, su.ys
    N = ts.shape[0]
    totals = [0.0] * len(trajectories)
    for a, b in blocks:
        last = b == N
        seg = slice(a, N if last else b + 1)
        P0 = su.P0 if a == 0 else np.eye(system.group.tangent_dim)
        prob, _ = _batch.problem(system, flt.weights, ts[seg], held[seg], ys[seg], state.g_hat, P0,
                                 init=start[seg], integ=integ, gap=su.gap, last_sample=last, floor_std=su.floor_std)
        if a > 0:  # the prior is the first block's alone
            prob = eqx.tree_at(lambda p: p.P0inv, prob, jnp.zeros_like(prob.P0inv))
        M, m = prob.ts.shape[0], ts[seg].shape[0]
        for i, xs in enumerate(trajectories):
            x = xs[seg]
            if M > m:  # the padded states: free extrapolations, as the smoother pads (their terms vanish)
                tail = _batch.dead_reckoning(system, integ, x[-1], prob.ts[m - 1:], prob.us[m - 1:])
                x = jax.tree_util.tree_map(lambda u, v: jnp.concatenate([u, v[1:]]), x, tail)
            totals[i] += float(_cost(system, integ, su.screens, prob, x))
    return totals


def _joined(flt, state, su: _batch.Setup, pieces: list[_Piece], chunk: int, before: int, after: int) -> Smoothed:
    """The blocks joined into one :class:`Smoothed` of the whole log (:func:`smooth`'s Returns)."""
    cat = lambda *a: jnp.concatenate(a)  # noqa: E731
    g = jax.tree_util.tree_map(cat, *[p.smoothed.g for p in pieces])
    P = jnp.concatenate([p.smoothed.P for p in pieces])
    start = jax.tree_util.tree_map(cat, *[p.start for p in pieces])
    worst = max(pieces, key=lambda p: _WORST.index(p.smoothed.status)).smoothed
    iterations = sum(p.smoothed.iterations for p in pieces)
    gn = jnp.max(jnp.stack([p.smoothed.gradient_norm for p in pieces]))
    said = (f"{len(pieces)} windows of {chunk} states with overlaps {before} before and {after} after"
            if len(pieces) > 1 else f"one window of the whole log ({chunk} states asked per window)")
    if worst.status == "failed":
        return _batch.failed(su.ts, state.g_hat, f"failed: {said}; the first that failed: {worst.message}",
                             iterations)
    cost, cost_init = whole_costs(flt, state, su, start, [(p.a, p.b) for p in pieces], [g, start])
    if worst.status == "converged":
        most = max(p.smoothed.iterations for p in pieces)
        message = f"converged: {said}, each in at most {most} iteration(s), its last step below {su.tol:g}"
    else:
        message = f"{worst.status}: {said}; the first not converged: {worst.message}"
    return Smoothed(ts=jnp.asarray(su.ts), g=g, P=P, cost=jnp.asarray(cost), cost_init=jnp.asarray(cost_init),
                    gradient_norm=gn, iterations=iterations, status=worst.status, message=message)
