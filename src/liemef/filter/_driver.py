r"""The driver shared by every filter of the library: its state, trajectory, health checks and compiled loop.

A filter is an :class:`AbstractFilter` that says how one sample interval ``[t, t + dt]`` advances its state
(``_interval``). The driver gives it :meth:`~AbstractFilter.init`, the online :meth:`~AbstractFilter.step`,
the checked :meth:`~AbstractFilter.run` over a whole log (padded to a length bucket, so that one compilation
serves every log of a bucket and every weight set) and the traceable :meth:`~AbstractFilter.scan`. The
minimum-energy filter (:class:`~liemef.MinimumEnergyFilter`) and the baselines (:mod:`liemef.baselines`) are
such filters: they share the sample conventions (a sample at ``ts[k]`` is used over ``[ts[k], ts[k+1])``, NaN
is missing), the status and the outputs.
"""

from __future__ import annotations

import abc
import collections
import functools
import math
import os
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .. import _side, _validate
from ..groups import LieGroup
from ._riccati import information_in_force
from ._status import ASYMMETRIC, DEFINITE_TOL, GATE, INDEFINITE, NONFINITE, OK, SYMMETRY_TOL, Status


class FilterState(eqx.Module):
    """The filter's state: the estimate $\\hat g$, the gain K (n x n), the last input (held over missing input
    samples) and the :class:`~liemef.filter.Status` of the run so far."""

    g_hat: LieGroup
    K: Float[Array, "n n"]
    u_last: Float[Array, " m"]
    status: Status


class Trajectory(eqx.Module):
    """A filter run: ``g_hat[k]`` and ``K[k]`` at ``ts[k]`` (``g_hat`` has batch shape (N,)).

    ``status`` says whether the run failed, where, when and why (:class:`~liemef.filter.Status`); the states
    after a failure are NaN, so that nothing downstream can mistake them for estimates, and ``final`` is the
    last good state (the state at ``ts[-1]`` when the run is healthy), from which a run can continue.
    With ``keep_every = M`` the history holds every M-th sample (``ts = log ts[::M]``).
    """

    ts: Float[Array, " N"]
    g_hat: LieGroup
    K: Float[Array, "N n n"]
    status: Status
    final: FilterState

    @property
    def finite(self) -> Bool[Array, ""]:
        """True if the run did not fail (kept under its old name: a failed run has NaN states)."""
        return self.status.code == OK

    def coords(self) -> Float[Array, "N c"]:
        """The estimate in the group's coordinates (e.g. theta, x, y, omega, vx, vy for TSE(2))."""
        return self.g_hat.coords()



TRACES: collections.Counter = collections.Counter()
"""How many times each compiled entry point was traced (= compiled): ``TRACES["run"]``, ``TRACES["step"]``."""


def positive_definite(S: Float[Array, "n n"]) -> Bool[Array, ""]:
    """Whether the symmetric ``S`` has a Cholesky factor, by an unrolled factorization: on the CPU a LAPACK call
    costs more than the whole filter step for these small matrices."""
    n = S.shape[0]
    L = [[None] * n for _ in range(n)]
    ok = jnp.asarray(True)
    for j in range(n):
        d = S[j, j] - sum((L[j][k] ** 2 for k in range(j)), jnp.asarray(0.0))
        ok = ok & (d > 0)
        L[j][j] = jnp.sqrt(jnp.where(d > 0, d, 1.0))
        for i in range(j + 1, n):
            L[i][j] = (S[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), jnp.asarray(0.0))) / L[j][j]
    return ok


def bucket(n: int) -> int:
    """The padded number of intervals for a log of ``n`` intervals: the next power of two (at least 64), so
    that logs of different lengths share one compilation per bucket."""
    return max(64, 1 << max(0, (n - 1).bit_length()))


def sensor_layout(system, Wy) -> tuple[tuple, tuple[bool, ...], bool]:
    """The sensor layout a filter needs: the system's blocks, per output component whether it has sample
    meaning, and whether the information matrix ``Wy`` is diagonal (a missing component is then dropped by
    zeroing its row and column; otherwise the filter forms the marginal information, DESIGN.md §6)."""
    blocks = system.blocks()
    sample = [False] * system.output_dim
    for b in blocks:
        sample[b.start:b.stop] = [b.sample] * b.dim
    Wy = np.asarray(Wy)
    return blocks, tuple(sample), bool(np.array_equal(Wy, np.diag(np.diag(Wy))))


class _hot_path:
    """A method read off a filter as a plain ``functools.partial``: equinox builds a bound-method Module at each
    read of an ordinary method (tens of microseconds), too slow for :meth:`AbstractFilter.step` in a robot's
    loop."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, cls=None):
        return self.fn if obj is None else functools.partial(self.fn, obj)


class AbstractFilter(eqx.Module):
    """A filter on a liemef system: :meth:`init`, :meth:`step`, :meth:`run` and :meth:`scan` over the
    sample intervals of a log, with the status of the run (:class:`~liemef.filter.Status`).

    A concrete filter holds ``system``, ``weights`` (the system's nominal :class:`~liemef.filter.Weights`),
    ``blocks``, ``sample`` and ``diagonal`` (the sensor layout, see :func:`sensor_layout`) and ``symmetric``
    (whether K must stay symmetric), and implements ``_interval(state, t, dt, u0, u1, y0, y1, gap)``: advance
    over ``[t, t + dt]`` from the samples at its two ends (NaN = missing), with :meth:`_samples` and
    :meth:`_finish` for the shared conventions.
    """

    @abc.abstractmethod
    def _interval(self, state: FilterState, t, dt, u0, u1, y0, y1, gap) -> FilterState:
        """Advance over ``[t, t + dt]``."""

    def __hash__(self) -> int:
        # The structure only (static fields and non-array leaves), never the arrays: filters equal as pytrees
        # hash equal, and ``jax.jit(flt.vector_field)`` works (equality still compares the arrays).
        leaves, treedef = jax.tree_util.tree_flatten(self)
        return hash((treedef, tuple(x for x in leaves if not eqx.is_array(x))))


    @property
    def n(self) -> int:
        """The dimension n of the group's algebra (K is n x n)."""
        return self.system.group.tangent_dim

    # --- initialisation -----------------------------------------------------------------------------------
    def init(self, g0: LieGroup, K0: ArrayLike | None = None, *, X0: ArrayLike | None = None,
             u0: ArrayLike | None = None) -> FilterState:
        """Initial state: ``g_hat = g0`` (argmin of m0) and ``K = K0``, or ``K = X0^{-1}`` with X0 the
        left-trivialized Hessian of m0. K0 may be singular (positive semidefinite), as in Rigo et al. 2023,
        eq. (63). ``u0`` is the input held until the first present input sample (default zeros)."""
        self._check_element("g0", g0)
        n, m = self.n, self.system.input_dim
        if (K0 is None) == (X0 is None):
            raise ValueError("init: expected exactly one of K0 (initial gain) or X0 (Hessian of m0), got "
                             f"{'both' if K0 is not None else 'neither'}")
        if K0 is not None:
            K = _validate.symmetric_psd("K0", K0, n, definite=False)
        else:
            K = np.linalg.inv(_validate.symmetric_psd("X0", X0, n))
        u = np.zeros(m) if u0 is None else _validate.array("u0", u0, (m,))
        return FilterState(g_hat=g0, K=jnp.asarray(K), u_last=jnp.asarray(u), status=Status.initial(len(self.blocks)))


    def _samples(self, state: FilterState, dt, u0, u1, y0, y1, gap):
        """The interval's data under the shared conventions: a missing input sample holds the last one; a missing
        measurement component has no weight; density samples are not held across a gap. Returns the inputs
        ``u0, u1``, whether ``u0`` was present, the measurements ``y0, y1`` (zeros where missing), the mask of
        present components of ``y0``, the information in force ``Wy`` and whether the interval is a gap."""
        sample = jnp.asarray(self.sample, dtype=bool)
        u_ok = jnp.isfinite(u0)
        u0 = jnp.where(u_ok, u0, state.u_last)
        u1 = jnp.where(jnp.isfinite(u1), u1, u0)
        is_gap = dt > gap
        mask = jnp.isfinite(y0) & ~(is_gap & ~sample)
        dense = mask & jnp.isfinite(y1) & ~sample
        y0 = jnp.where(mask, y0, 0.0)
        y1 = jnp.where(dense, y1, y0)
        Wy = information_in_force(self.weights.Wy, sample, mask, dt, diagonal=self.diagonal)
        return u0, u1, u_ok, y0, y1, mask, Wy, is_gap

    def _finish(self, state: FilterState, g1, K1, *, t, dt, u0, u_ok, is_gap, rejected, consecutive,
                n_sub=1, capped=False, asymmetric=None) -> FilterState:
        """The state after an interval: checks ``(g1, K1)`` (:meth:`_health`) and updates the status; a failing
        interval keeps the state before it, and a state that had failed stays as it was. ``asymmetric``: the
        filter's own verdict that K cannot stay symmetric (in place of checking K1's symmetry)."""
        st = state.status
        code = self._health(g1, K1, consecutive, asymmetric)
        new_fail = code != OK
        g_out = jax.tree_util.tree_map(lambda a, b: jnp.where(new_fail, a, b), state.g_hat, g1)
        K_out = jnp.where(new_fail, state.K, K1)
        n_sub = jnp.asarray(n_sub, jnp.int32)
        status = Status(
            code=code, index=jnp.where(new_fail, st.steps, st.index), time=jnp.where(new_fail, t, st.time),
            steps=st.steps + 1, rejected=rejected, consecutive=consecutive,
            substeps_max=jnp.maximum(st.substeps_max, n_sub), substeps_total=st.substeps_total + n_sub,
            substeps_capped=st.substeps_capped + capped, gaps=st.gaps + is_gap,
            longest_gap=jnp.maximum(st.longest_gap, dt), inputs_held=st.inputs_held + jnp.any(~u_ok))
        out = FilterState(g_hat=g_out, K=K_out, u_last=jnp.where(new_fail, state.u_last, u0), status=status)
        # A failed state is final: later intervals leave all of it unchanged (estimate, gain, held input and the
        # status with its counters, which describe the run up to and including the failing interval).
        return jax.tree_util.tree_map(lambda a, b: jnp.where(st.code != OK, a, b), state, out)

    @property
    def _screens_samples(self) -> bool:
        """Whether a sensor has a gate, a robust loss or a time-varying weight (static)."""
        return any(b.gate_threshold is not None or b.robust is not None or b.weight_fn is not None
                   for b in self.blocks)

    def _sensor_scale(self, nu, HKH, t, dt, mask, Wy, st):
        """Per-component weight factors from the sensors' gates, robust losses and time-varying weights, and
        the updated rejection counters, from the innovation ``nu = y - h(g_hat)`` and its covariance from the
        state, ``HKH`` = Dh K Dh^T (the sample's own covariance is added here)."""
        p = self.system.output_dim
        rejected, consecutive = st.rejected, st.consecutive
        if not self._screens_samples:
            return jnp.ones((p,)), rejected, consecutive
        # per block: its factor, its rejection and its run of rejections, stacked at the end (whole arrays, no
        # scatter: the same program in XLA and in the C kernel)
        factors, new_rejected, new_consecutive = [], [], []
        for i, b in enumerate(self.blocks):
            sl = slice(b.start, b.stop)
            factor = jnp.asarray(1.0)
            rej, cons = rejected[i], consecutive[i]
            if b.gate_threshold is not None or b.robust is not None:
                present = jnp.all(mask[sl])
                # the sample's covariance: its information over the interval, times the interval
                info = jnp.where(present, Wy[sl, sl] * dt, jnp.eye(b.dim))
                S = HKH[sl, sl] + jnp.linalg.inv(info)
                d2 = nu[sl] @ jnp.linalg.solve(S, nu[sl])
                d2 = jnp.where(jnp.isfinite(d2), d2, jnp.inf)
                if b.gate_threshold is not None:
                    reject = present & (d2 > b.gate_threshold)
                    factor = jnp.where(reject, 0.0, factor)
                    rej = rej + reject.astype(rej.dtype)
                    cons = jnp.where(reject, cons + 1, jnp.where(present, 0, cons))
                if b.robust is not None:
                    d = jnp.sqrt(jnp.maximum(d2, 1e-300))
                    c = b.robust_scale
                    w = jnp.minimum(1.0, c / d) if b.robust == "huber" else 1.0 / (1.0 + (d / c) ** 2)
                    factor = factor * jnp.where(present, w, 1.0)
            if b.weight_fn is not None:
                factor = factor * jnp.asarray(b.weight_fn(t), dtype=jnp.float64)
            factors.append(factor)
            new_rejected.append(rej)
            new_consecutive.append(cons)
        owner = np.full(p, len(self.blocks))  # the block of each component (none: factor 1)
        for i, b in enumerate(self.blocks):
            owner[b.start:b.stop] = i
        scale = jnp.stack([*factors, jnp.asarray(1.0)])[owner]
        return (scale, jnp.stack(new_rejected).astype(rejected.dtype),
                jnp.stack(new_consecutive).astype(consecutive.dtype))

    def _health(self, g, K, consecutive, asymmetric=None):
        """The cause code of a state just computed (:data:`~liemef.filter.CAUSES`)."""
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves((g, K))]))
        Kf = jnp.where(finite, K, jnp.eye(K.shape[0]))
        big = jnp.max(jnp.abs(Kf))
        asym = jnp.max(jnp.abs(Kf - Kf.T)) > SYMMETRY_TOL * jnp.maximum(1.0, big) if asymmetric is None \
            else asymmetric
        Ks = 0.5 * (Kf + Kf.T) + DEFINITE_TOL * jnp.maximum(big, 1e-300) * jnp.eye(K.shape[0])
        definite = positive_definite(Ks)
        gate = jnp.asarray(False)
        for i, b in enumerate(self.blocks):
            if b.max_rejections is not None:
                gate = gate | (consecutive[i] > b.max_rejections)
        code = jnp.where(~finite, NONFINITE, jnp.where(asym & self.symmetric, ASYMMETRIC,
                                                        jnp.where(~definite, INDEFINITE, jnp.where(gate, GATE, OK))))
        return code.astype(jnp.int32)

    # --- drivers ------------------------------------------------------------------------------------------
    def scan(self, state: FilterState, ts, us, ys, *, gap=jnp.inf, n_valid=None, keep_every: int = 1,
             engine: str | None = "xla") -> Trajectory:
        """Traceable core of :meth:`run` (no checks): one ``lax.scan`` over the sample intervals.

        ``n_valid``: only the first ``n_valid`` samples are data (the rest is padding, skipped);
        ``keep_every`` (static): keep every M-th state in the history (memory flat in the log length).
        ``engine``: ``"xla"`` (the default: differentiable, any transformation) or ``"c"``/``"auto"``/None (as
        in :meth:`run`; the experiments' trials pass None): the C kernel through ``jax.pure_callback``, with
        the parameters and states still traced data; under ``vmap`` one call for the whole batch, shared among
        the cores in SIMD groups (:meth:`run_batch`); not differentiable."""
        if engine != "xla":
            kern = self._kernel(engine)
            if kern is not None:
                return _scan_c(self, kern, state, ts, us, ys, gap, n_valid, keep_every)
        N = ts.shape[0]
        n_valid = N if n_valid is None else n_valid
        xs = (jnp.arange(N - 1), ts[:-1], jnp.diff(ts), us[:-1], us[1:], ys[:-1], ys[1:])

        def advance(st, x):
            k, t, dt, u0, u1, y0, y1 = x
            return jax.lax.cond(k + 1 < n_valid, lambda s: self._interval(s, t, dt, u0, u1, y0, y1, gap),
                                lambda s: s, st)

        def emit(st):
            bad = st.status.code != OK
            nan = lambda a: jnp.where(bad, jnp.nan, a)  # noqa: E731
            return jax.tree_util.tree_map(nan, st.g_hat), nan(st.K)

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

    def run(self, state: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *,
            gap: float | None = None, keep_every: int = 1, engine: str | None = None) -> Trajectory:
        """Filter a whole log: ``ts`` (N,) strictly increasing, ``us`` (N, m), ``ys`` (N, p).

        Sample k is used over ``[ts[k], ts[k+1])``; the result holds the state at every ``ts[k]`` (every
        ``keep_every``-th), the first being ``state``. NaN in ``ys`` marks a missing sample; NaN in ``us`` holds
        the last input. An interval longer than ``gap`` (default: 10 times the median interval) is predicted
        through without holding density measurements, and a warning says so (``gap=math.inf``: no interval is
        a gap, as in :meth:`step`). Logs are padded to a length bucket (:func:`bucket`): one compilation serves
        every log of a bucket and every weight set.

        ``engine``: ``"c"`` (the filter's interval as a compiled C kernel, :mod:`liemef.codegen._kernel`: one
        build per structure and zero pattern of the weights, no padding), ``"xla"`` (the jitted :meth:`scan`)
        or ``"auto"`` (the default, or ``$LIEMEF_ENGINE``): C where it is available (:func:`engine_of`).
        """
        self._check_state(state)
        self._check_element("state.g_hat", state.g_hat)
        _validate.square("state.K", state.K, self.n)
        ts = _validate.sorted_times("ts", ts)
        N = ts.shape[0]
        if N < 2:
            raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
        m, p = self.system.input_dim, self.system.output_dim
        us = np.zeros((N, 0)) if us is None and m == 0 else _validate.array("us", us, (N, m), missing=True)
        ys = _validate.array("ys", ys, (N, p), missing=True)
        if not (isinstance(keep_every, int) and keep_every >= 1):
            raise ValueError(f"keep_every: expected an integer >= 1, got {keep_every!r}")
        dts = np.diff(ts)
        if gap is None:
            gap = 10.0 * float(np.median(dts))
        elif not (isinstance(gap, int | float | np.number) and gap == math.inf):  # inf: no gaps, as in step()
            gap = float(_validate.nonnegative("gap", gap))
        kern = self._kernel(engine)
        if kern is not None:
            traj = self._run_c(kern, state, ts, us, ys, float(gap), keep_every)
        else:
            traj = self._run_xla(state, ts, us, ys, gap, keep_every)
        gaps = int(traj.status.gaps)
        if gaps:
            warnings.warn(f"run: {gaps} sample interval(s) longer than the gap threshold {gap:.4g} s (longest "
                          f"{float(traj.status.longest_gap):.4g} s) were predicted through without holding "
                          "density measurements", LogGapWarning, stacklevel=2)
        return traj

    def run_batch(self, states: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *,
                  gap: float | None = None, keep_every: int = 1, engine: str | None = None,
                  threads: int | None = None) -> Trajectory:
        """Filter B logs on one time grid (Monte Carlo trials): ``states`` a FilterState with a leading trial
        axis (B,) on every leaf (``jax.tree_util.tree_map(lambda *a: jnp.stack(a), *states)``), ``ts`` (N,),
        ``us`` (B, N, m), ``ys`` (B, N, p). Returns a Trajectory with the trial axis first (``K`` (B, R, n, n),
        ``status`` and ``final`` batched); each trial is its own :meth:`run` (to rounding).

        By the C engine the trials are shared among ``threads`` threads (default: every CPU this process may
        use), in groups of SIMD lanes where the kernel has them; by XLA, one ``vmap`` of :meth:`scan`."""
        # NumPy from here on: indexing a JAX array would compile an XLA gather for each new shape
        states_np = jax.tree_util.tree_map(np.asarray, states)
        leaves = jax.tree_util.tree_leaves(states_np)
        B = int(np.shape(leaves[0])[0]) if np.ndim(leaves[0]) else 0
        for path, leaf in jax.tree_util.tree_flatten_with_path(states_np)[0]:
            if np.ndim(leaf) == 0 or np.shape(leaf)[0] != B or B < 1:
                raise ValueError(f"states: expected a leading trial axis of one length B >= 1 on every leaf, got "
                                 f"shape {np.shape(leaf)} at {jax.tree_util.keystr(path)} (B = {B})")
        self._check_state(jax.tree_util.tree_map(lambda a: a[0], states_np))
        ts = _validate.sorted_times("ts", ts)
        N = ts.shape[0]
        if N < 2:
            raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
        m, p = self.system.input_dim, self.system.output_dim
        us = np.zeros((B, N, 0)) if us is None and m == 0 else _validate.array("us", us, (B, N, m), missing=True)
        ys = _validate.array("ys", ys, (B, N, p), missing=True)
        if not (isinstance(keep_every, int) and keep_every >= 1):
            raise ValueError(f"keep_every: expected an integer >= 1, got {keep_every!r}")
        if threads is not None and not (isinstance(threads, int) and threads >= 1):
            raise ValueError(f"threads: expected an integer >= 1 (or None: every CPU), got {threads!r}")
        for leaf in jax.tree_util.tree_leaves(states_np.g_hat):
            _validate.array("states.g_hat", leaf)
        if gap is None:
            gap = 10.0 * float(np.median(np.diff(ts)))
        elif not (isinstance(gap, int | float | np.number) and gap == math.inf):
            gap = float(_validate.nonnegative("gap", gap))
        kern = self._kernel(engine)
        if kern is not None:
            x = np.concatenate([a.reshape(B, -1).astype(np.float64) for a in leaves], axis=1)
            kern.check_packed(x, states_np, "states")
            rows, xf, _ = kern.batch(self._theta(kern), x, ts, _c_array(us), _c_array(ys), float(gap), keep_every,
                                     threads=threads)
            traj = self._trajectory(kern, ts, rows, xf, keep_every, lead=(B,))
        else:
            nb = -(-bucket(N - 1) // keep_every) * keep_every
            pad = nb + 1 - N
            tsp = np.concatenate([ts, np.full(pad, ts[-1])])
            usp = np.concatenate([us, np.full((B, pad, m), np.nan)], axis=1)
            ysp = np.concatenate([ys, np.full((B, pad, p), np.nan)], axis=1)
            tr = _run_batch_jit(self, states, tsp, usp, ysp, np.asarray(N, np.int32), np.asarray(gap), keep_every)
            kept = -(-N // keep_every)
            traj = Trajectory(ts=jnp.asarray(ts[::keep_every]), g_hat=jax.tree_util.tree_map(lambda a: a[:, :kept],
                                                                                              tr.g_hat),
                              K=tr.K[:, :kept], status=tr.status, final=tr.final)
        gaps = int(np.sum(traj.status.gaps))
        if gaps:
            warnings.warn(f"run_batch: {gaps} sample interval(s) longer than the gap threshold {gap:.4g} s over the "
                          "trials were predicted through without holding density measurements", LogGapWarning,
                          stacklevel=2)
        return traj

    def _trajectory(self, kern, ts, rows, xf, keep_every, lead=()) -> Trajectory:
        """The Trajectory of the kernel's kept rows (lead + (R, S)) and final packed states (lead + (S,)): NaN
        after a failure, as :meth:`scan` emits."""
        hist = jax.tree_util.tree_unflatten(kern.sdef, kern.unpack(rows, rows.shape[:-1]))
        bad = np.asarray(hist.status.code) != OK
        bad[..., 0] = False  # the first state is the one given, as in scan
        any_bad = bool(bad.any())

        def nan(a):
            a = np.array(a) if any_bad else _contiguous(a)
            if any_bad:
                a[bad] = np.nan
            return _to_jax(a)

        final = jax.tree_util.tree_unflatten(kern.sdef, [_to_jax(_contiguous(a)) for a in kern.unpack(xf, lead)])
        return Trajectory(ts=_to_jax(_contiguous(ts[::keep_every])), g_hat=jax.tree_util.tree_map(nan, hist.g_hat),
                          K=nan(hist.K), status=final.status, final=final)

    def _run_xla(self, state, ts, us, ys, gap, keep_every) -> Trajectory:
        N, m, p = ts.shape[0], us.shape[1], ys.shape[1]
        nb = bucket(N - 1)
        nb = -(-nb // keep_every) * keep_every
        pad = nb + 1 - N
        tsp = np.concatenate([ts, np.full(pad, ts[-1])])
        usp = np.concatenate([us, np.full((pad, m), np.nan)])
        ysp = np.concatenate([ys, np.full((pad, p), np.nan)])
        traj = _run_jit(self, state, tsp, usp, ysp, np.asarray(N, np.int32), np.asarray(gap), keep_every)
        kept = -(-N // keep_every) if keep_every > 1 else N
        return Trajectory(ts=jnp.asarray(ts[::keep_every]), g_hat=traj.g_hat[:kept], K=traj.K[:kept],
                          status=traj.status, final=traj.final)

    def _run_c(self, kern, state, ts, us, ys, gap, keep_every) -> Trajectory:
        """``run`` by the C kernel: the same states as :meth:`scan` (to rounding), NaN after a failure."""
        rows, xf = kern.scan(self._theta(kern), kern.packed(state), np.ascontiguousarray(ts, np.float64),
                             _c_array(us), _c_array(ys), gap, keep_every)
        return self._trajectory(kern, ts, rows, xf, keep_every)

    # --- the C engine -------------------------------------------------------------------------------------
    _c_engine = False
    """Whether ``engine="auto"`` runs this filter class by the C kernel (the minimum-energy filter does; other
    filters run by C only when asked, ``engine="c"``)."""

    def _kernel(self, engine: str | None):
        """The C kernel the engine choice gives (None: XLA), kept beside the instance (liemef._side)."""
        engine = engine_of(engine)
        if engine == "xla" or (engine == "auto" and not type(self)._c_engine):
            return None
        cached = _side.get(self, "kernel")
        if cached is not None:
            if cached[0] is None and engine == "c":
                raise cached[3]  # "auto" fell back earlier: "c" says why, as on a first call
            return cached[0]
        from ..codegen import _kernel as kmod  # the codegen imports this module

        error = None
        try:
            kern = kmod.kernel_for(self)
        except Exception as err:  # noqa: BLE001 - auto falls back to XLA, saying why; "c" raises
            if engine == "c":
                raise
            warnings.warn(f"the C engine is not available for {type(self).__name__} ({type(err).__name__}: "
                          f"{str(err).splitlines()[0] if str(err) else ''}); running with XLA", EngineWarning,
                          stacklevel=3)
            kern, error = None, err
        if any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(self)):
            return kern  # a traced filter (scan under a transformation): its parameters come as data
        theta = kern.theta(self) if kern is not None else None
        _side.put(self, "kernel", (kern, theta, theta.ctypes.data if kern is not None else None, error))
        return kern

    def _theta(self, kern) -> np.ndarray:
        return _side.get(self, "kernel")[1]

    def online(self, state: FilterState, *, engine: str | None = None):
        """The online filter of a robot's loop (:class:`~liemef.filter.OnlineFilter`): steps from ``state``
        kept packed in the C kernel, each one C call returning the status code; the state is read when asked
        for. By XLA (``engine="xla"`` or no C compiler) the same interface over :meth:`step`."""
        from ._online import OnlineFilter

        return OnlineFilter(self, state, engine)

    @_hot_path
    def step(self, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float, *,
             u_next: ArrayLike | None = None, y_next: ArrayLike | None = None, gap: float = math.inf,
             engine: str | None = None) -> FilterState:
        """Advance one sample interval ``[t, t + dt]`` (online use). NaN in ``y`` marks a missing component,
        NaN in ``u`` holds the last input; ``u_next``/``y_next`` are the samples at ``t + dt`` for
        ``interpolation="linear"`` (default: held). On a failure the returned state is the input state with a
        failed ``status`` (see :class:`~liemef.filter.Status`), and later steps leave it unchanged.

        ``engine`` as in :meth:`run`: by the C kernel, the state's leaves are NumPy arrays (the next step reads
        the packed vector they came from)."""
        # the hot path of a robot loop: methods are reached through the class, since reading a method off an
        # equinox Module builds a bound-method Module each time (microseconds)
        cls = type(self)
        t, dt = check_time(t, dt)
        kern = cls._kernel(self, engine)
        if kern is not None:  # the samples are checked as the kernel copies them in, infinities by the C step
            if not kern.made(state):
                cls._check_state(self, state)
            return kern.step(_side.get(self, "kernel")[2], state, t, dt, float(gap), u, y, u_next, y_next)
        cls._check_state(self, state)
        u, y, u1, y1 = check_samples(self.system.input_dim, self.system.output_dim, u, y, u_next, y_next)
        fn, leaves = _fast_parts(self)
        z = np.concatenate([[float(t), dt, float(gap)], u, u1, y, y1])
        out = fn(leaves, jax.tree_util.tree_leaves(state), z)
        return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(state), out)

    # --- checks -------------------------------------------------------------------------------------------
    def _check_state(self, state):
        # cheap structural checks only: step() is the online hot path
        if not isinstance(state, FilterState):
            raise ValueError(f"state: expected a FilterState (from init or step), got {type(state).__name__}")
        G = self.system.group
        n = G.tangent_dim
        if type(state.g_hat) is not G or getattr(state.K, "shape", None) != (n, n):
            raise ValueError(f"state: expected g_hat in {G.__name__} and K of shape ({n}, {n}), got "
                             f"{type(state.g_hat).__name__} and {getattr(state.K, 'shape', None)}")

    def _check_element(self, name, g):
        check_element(self.system.group, name, g)

    @staticmethod
    def _check_dt(dt) -> float:
        return check_dt(dt)

    @staticmethod
    def _check_sample(name, v, n, missing: bool = False) -> np.ndarray:
        return _validate.array(name, np.zeros(0) if v is None and n == 0 else v, (n,), missing=missing)



def check_element(G: type[LieGroup], name: str, g) -> None:
    """``g`` is a single element of ``G`` with finite parameters (ValueError naming ``name`` otherwise): the
    boundary check of every filter's initial and given states."""
    if not isinstance(g, G):
        raise ValueError(f"{name}: expected an element of {G.__name__}, got {type(g).__name__}")
    if g.batch_shape != ():
        raise ValueError(f"{name}: expected a single element (no batch axes), got batch shape {g.batch_shape}")
    for leaf in jax.tree_util.tree_leaves(g):
        _validate.array(name, leaf)


def check_dt(dt) -> float:
    """A finite time step > 0, as a float (ValueError naming ``dt`` otherwise, also for a non-number)."""
    try:
        value = float(dt)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"dt: expected a finite time step > 0, got {dt}")
    return value


ENGINES = ("auto", "c", "xla")
"""How :meth:`~AbstractFilter.run` and :meth:`~AbstractFilter.step` compute: ``"c"`` (a compiled C kernel of
the interval, :mod:`liemef.codegen._kernel`), ``"xla"`` (jitted JAX) or ``"auto"`` (C for the minimum-energy
filter where a C compiler is found, else XLA with an :class:`EngineWarning`)."""


def engine_of(engine: str | None) -> str:
    """The engine a call uses: ``engine``, else ``$LIEMEF_ENGINE``, else ``"auto"`` (ValueError naming the
    argument if unknown); ``"auto"`` without a C compiler is ``"xla"``."""
    if engine is None:
        engine = os.environ.get("LIEMEF_ENGINE") or "auto"
        where = "LIEMEF_ENGINE"
    else:
        where = "engine"
    if engine not in ENGINES:
        raise ValueError(f"{where}: expected one of {list(ENGINES)}, got {engine!r}")
    if engine == "auto" and _no_compiler():
        return "xla"
    return engine


@functools.cache
def _no_compiler() -> bool:
    from ..codegen._export import compiler
    return compiler() is None


def check_time(t, dt) -> tuple[float, float]:
    """An online step's finite time ``t`` and time step ``dt`` > 0, as floats (ValueError naming either)."""
    dt = check_dt(dt)
    if not math.isfinite(t):
        raise ValueError(f"t: expected a finite time, got {t}")
    return float(t), dt


def check_samples(m: int, p: int, u, y, u_next=None, y_next=None) -> tuple[np.ndarray, ...]:
    """One interval's samples ``u``, ``y``, ``u_next``, ``y_next`` (None: held) as float64 arrays of shapes
    (m,), (p,), (m,), (p,), checked in that order, each for its shape and then for infinities (NaN: missing;
    None for an input of dimension 0): the one check of both engines, so that they name the same sample."""
    return tuple(AbstractFilter._check_sample(name, v, n, missing=True) for name, v, n in (
        ("u", u, m), ("y", y, p), ("u_next", u if u_next is None else u_next, m),
        ("y_next", y if y_next is None else y_next, p)))


def _to_jax(a: np.ndarray) -> jax.Array:
    """A NumPy array as a JAX array by a plain transfer (``jnp.asarray`` stages a conversion that compiles a small
    program per shape and dtype: a tenth of a second on a first run)."""
    return jax.device_put(a)


def _contiguous(a: np.ndarray) -> np.ndarray:
    """``a``, or a C-ordered copy of it (of the same shape, 0-d included)."""
    return a if a.flags.c_contiguous else a.copy()


def _c_array(a) -> np.ndarray:
    """A float64 C-contiguous array for the kernel (a one-element one for an empty sample: never read)."""
    a = np.ascontiguousarray(a, np.float64)
    return a if a.size else np.zeros(1)


class EngineWarning(UserWarning):
    """The C engine was asked for by ``"auto"`` but could not be built; the filter runs with XLA."""


class LogGapWarning(UserWarning):
    """A log had sample intervals longer than the gap threshold; the filter predicted through them."""


# --- compiled entry points, shared by every filter of the same structure --------------------------------------
@eqx.filter_jit
def _run_jit(flt, state, ts, us, ys, n_valid, gap, keep_every):
    TRACES["run"] += 1
    return flt.scan(state, ts, us, ys, gap=gap, n_valid=n_valid, keep_every=keep_every)



def _scan_c(flt, kern, state, ts, us, ys, gap, n_valid, keep_every) -> Trajectory:
    """:meth:`AbstractFilter.scan` by the C kernel: the packed rows come back from a ``pure_callback``
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
    bad = (hist.status.code != OK).at[0].set(False)  # the first state is the one given

    def nan(a):
        return jnp.where(bad.reshape((R,) + (1,) * (a.ndim - 1)), jnp.nan, a)

    final = jax.tree_util.tree_unflatten(kern.sdef, unpack(xf, ()))
    return Trajectory(ts=ts[::M], g_hat=jax.tree_util.tree_map(nan, hist.g_hat), K=nan(hist.K), status=final.status,
                      final=final)


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


@eqx.filter_jit
def _run_batch_jit(flt, states, ts, us, ys, n_valid, gap, keep_every):
    TRACES["run_batch"] += 1
    return eqx.filter_vmap(lambda st, u, y: flt.scan(st, ts, u, y, gap=gap, n_valid=n_valid, keep_every=keep_every)
                           )(states, us, ys)


def _step_leaves(static, leaves, state_leaves, z):
    # Online step on flat arrays: jit dispatch flattens nested modules in Python (~20 us); lists of arrays and
    # one packed sample vector z = (t, dt, gap, u, u_next, y, y_next) take the C++ fast path.
    TRACES["step"] += 1
    flt = eqx.combine(jax.tree_util.tree_unflatten(static[0], leaves), static[1])
    m, p = flt.system.input_dim, flt.system.output_dim
    state = jax.tree_util.tree_unflatten(static[2], state_leaves)
    o = 3
    u0, u1, y0, y1 = z[o:o + m], z[o + m:o + 2 * m], z[o + 2 * m:o + 2 * m + p], z[o + 2 * m + p:]
    return jax.tree_util.tree_leaves(flt._interval(state, z[0], z[1], u0, u1, y0, y1, z[2]))


_STEP_JIT: dict = {}


def _fast_parts(flt: AbstractFilter):
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
