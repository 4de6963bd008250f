from __future__ import annotations

import collections
import functools
import math
import warnings
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .. import _validate
from .._linalg import mm, mv
from ..connections import Connection, ConnectionFunction
from ..connections import connection as make_connection
from ..groups import LieGroup
from ..systems import AbstractSystem
from ._derivatives import left_jacobian
from ._integrators import AbstractIntegrator
from ._integrators import integrator as make_integrator
from ._riccati import Terms, Weights, information_in_force, riccati_rhs, terms
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


ORDERS = ("second", "first")
"""The filter orders: ``"second"`` (Theorem 4.1, the papers' filter) and ``"first"`` (without the Hessian
term of E and W: the continuous-time left-invariant EKF)."""
INTERPOLATIONS = ("hold", "linear")
"""How inputs and density measurements vary inside a sample interval: held (zero-order hold, the papers') or
linear between the interval's two samples (first-order hold, so that RKMK4's inner stages see current data)."""

# Sub-step budget per unit of stiffness (DESIGN.md §6): ||K E|| h, ||A|| h and the group step ||xi|| h.
_KE_BUDGET, _A_BUDGET, _XI_BUDGET = 0.5, 0.5, 0.5

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


class MinimumEnergyFilter(eqx.Module):
    r"""Second-order-optimal minimum-energy filter on a matrix Lie group (Saccon et al. 2016, Theorem 4.1).

    Args:
        system: the model (group, dynamics, output, B, D, Q, R), e.g. :class:`liemef.systems.PlanarRigidBody`,
            or a :class:`liemef.systems.SensorSystem` whose weights come from sensor noise levels.
        connection: ``"zero"`` (c = 1/2, torsion-free, the papers' default), ``"minus"`` (c = 0), ``"plus"``
            (c = 1), a Cartan-Schouten coefficient c, or a bilinear function ``omega(X, Y)``.
        order: ``"second"`` (the paper filter) or ``"first"`` (no Hessian term in E, W = 0: the continuous-time
            left-invariant EKF on the group).
        integrator: ``"rkmk4"`` (4th-order Runge-Kutta-Munthe-Kaas) or ``"lie-euler"``.
        alpha: forgetting factor, >= 0.
        interpolation: ``"hold"`` (inputs and density measurements held over each sample interval, the
            papers' zero-order hold) or ``"linear"`` (interpolated between the interval's two samples where
            both are present).
        substeps: ``"auto"`` (default): each sample interval is integrated in adaptive steps, each of size
            $h = \min(\text{rest}, 1/\rho)$ with the stiffness rate
            $\rho = \max(\|K E\|/0.5, \|A\|/0.5, \|\lambda + K r\|/0.5)$ (Frobenius norms) at the step's start,
            so that an impulsive sample or a large K0 does not make the explicit step unstable (K shrinks
            during an update, so the steps grow: their number is logarithmic in $\|K E\| \Delta$); an interval
            that is not stiff takes one step. Or a fixed number of equal steps per interval (1: the papers'
            scheme).
        max_substeps: the most steps ``"auto"`` takes in one interval (the last one finishes it).

    Samples: a NaN in ``y`` is a missing sample (that component carries no information over the interval);
    a NaN in ``u`` holds the last input. Sample-meaning sensors carry each sample's information once
    (:mod:`liemef.systems`). The filter is an immutable pytree: every weight, noise level and parameter is an
    array leaf, so a new weight set reuses the compiled code. :meth:`init`, :meth:`step` and :meth:`run`
    return new states; :meth:`scan` is the traceable, unchecked core of ``run`` for your own ``jit``/``vmap``.
    """

    system: AbstractSystem
    connection: Connection
    integrator: AbstractIntegrator
    alpha: Float[Array, ""]
    weights: Weights
    order: str = eqx.field(static=True)
    interpolation: str = eqx.field(static=True)
    substeps: str | int = eqx.field(static=True)
    max_substeps: int = eqx.field(static=True)
    symmetric: bool = eqx.field(static=True)
    sample: tuple[bool, ...] = eqx.field(static=True)
    blocks: tuple = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, connection: str | float | ConnectionFunction | Connection = "zero",
                 order: Literal["second", "first"] = "second", integrator: str | AbstractIntegrator = "rkmk4",
                 alpha: float = 0.0, *, interpolation: Literal["hold", "linear"] = "hold",
                 substeps: Literal["auto"] | int = "auto", max_substeps: int = 256):
        if not isinstance(system, AbstractSystem):
            raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
        _validate.choice("order", order, set(ORDERS))
        _validate.choice("interpolation", interpolation, set(INTERPOLATIONS))
        if substeps != "auto" and not (isinstance(substeps, int) and substeps >= 1):
            raise ValueError(f"substeps: expected 'auto' or an integer >= 1, got {substeps!r}")
        if not (isinstance(max_substeps, int) and max_substeps >= 1):
            raise ValueError(f"max_substeps: expected an integer >= 1, got {max_substeps!r}")
        self.system = system
        self.connection = make_connection(connection, system.group)
        self.order = order
        self.integrator = make_integrator(integrator)
        self.alpha = jnp.asarray(_validate.nonnegative("alpha", alpha))
        self.weights = Weights.of(system)
        self.interpolation, self.substeps, self.max_substeps = interpolation, substeps, max_substeps
        blocks = system.blocks()
        self.blocks = blocks
        sample = [False] * system.output_dim
        for b in blocks:
            sample[b.start:b.stop] = [b.sample] * b.dim
        self.sample = tuple(sample)
        # With a diagonal information matrix (independent components) a missing component is dropped by zeroing
        # its row and column; otherwise the engine forms the marginal information (DESIGN.md §6).
        Wy = np.asarray(self.weights.Wy)
        self.diagonal = bool(np.array_equal(Wy, np.diag(np.diag(Wy))))
        # K stays symmetric when E is (first order, or a torsion-free connection) (DESIGN.md §1).
        torsion = np.asarray(self.connection.Gamma - jnp.swapaxes(self.connection.Gamma, 1, 2) - self.connection.C)
        self.symmetric = order == "first" or bool(np.allclose(torsion, 0.0, atol=1e-12))

    def __hash__(self) -> int:
        # The structure only (static fields and non-array leaves), never the arrays: filters equal as pytrees
        # hash equal, and ``jax.jit(flt.vector_field)`` works (equality still compares the arrays).
        leaves, treedef = jax.tree_util.tree_flatten(self)
        return hash((treedef, tuple(x for x in leaves if not eqx.is_array(x))))

    def __repr__(self) -> str:
        return (f"MinimumEnergyFilter({type(self.system).__name__}, connection={self.connection.name!r}, "
                f"order={self.order!r}, integrator={self.integrator.name!r}, alpha={float(self.alpha)})")

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

    # --- the mathematics ----------------------------------------------------------------------------------
    def _terms(self, weights: Weights, g_hat, K, u, y, t) -> Terms:
        return terms(self.system, weights, self.connection, self.order == "second", g_hat, K, u, y, t)

    def terms(self, g_hat: LieGroup, K: ArrayLike, u: ArrayLike, y: ArrayLike, t: float = 0.0, *,
              dt: float | None = None) -> Terms:
        """r, A, E, W and B R^{-1} B^T of Theorem 4.1 at a state, to compare with the papers' printed forms.

        A NaN in ``y`` is a missing component; sample-meaning sensors need the interval ``dt`` their sample is
        spread over."""
        self._check_element("g_hat", g_hat)
        K = _validate.square("K", K, self.n)
        u = self._check_sample("u", u, self.system.input_dim)
        y = self._check_sample("y", y, self.system.output_dim, missing=True)
        if any(self.sample) and dt is None:
            raise ValueError("dt: expected the sample interval (sample-meaning sensors spread a sample over it), "
                             "got None")
        dt = 1.0 if dt is None else self._check_dt(dt)
        mask = np.isfinite(y)
        weights = Weights(Wy=information_in_force(self.weights.Wy, np.asarray(self.sample, bool), mask, dt,
                                                  diagonal=self.diagonal),
                          BRB=self.weights.BRB)
        return _terms_jit(self, weights, g_hat, jnp.asarray(K), u, jnp.where(mask, y, 0.0), jnp.asarray(float(t)))

    def vector_field(self, g_hat: LieGroup, K, u, y, t):
        r"""$(\hat g^{-1}\dot{\hat g}, \dot K)$ at a state with the nominal weights (every sample present;
        traceable)."""
        tm = self._terms(self.weights, g_hat, K, u, y, t)
        return tm.lam + mv(K, tm.r), riccati_rhs(tm, K, self.alpha)

    # --- one sample interval --------------------------------------------------------------------------------
    def _interval(self, state: FilterState, t, dt, u0, u1, y0, y1, gap) -> FilterState:
        """Advance over ``[t, t + dt]`` from the samples at its two ends (NaN = missing); checks the result."""
        st, g, K = state.status, state.g_hat, state.K
        sample = jnp.asarray(self.sample, dtype=bool)
        # inputs: a missing sample holds the last one
        u_ok = jnp.isfinite(u0)
        u0 = jnp.where(u_ok, u0, state.u_last)
        u1 = jnp.where(jnp.isfinite(u1), u1, u0)
        # measurements: a missing component has no weight; density samples are not held across a gap
        is_gap = dt > gap
        mask = jnp.isfinite(y0) & ~(is_gap & ~sample)
        dense = mask & jnp.isfinite(y1) & ~sample
        y0 = jnp.where(mask, y0, 0.0)
        y1 = jnp.where(dense, y1, y0)
        Wy = information_in_force(self.weights.Wy, sample, mask, dt, diagonal=self.diagonal)
        scale, rejected, consecutive = self._sensor_scale(g, K, t, dt, y0, mask, Wy, st)
        Wy = Wy * jnp.sqrt(scale)[:, None] * jnp.sqrt(scale)[None, :]
        weights = Weights(Wy=Wy, BRB=self.weights.BRB)

        def data(tau):
            if self.interpolation == "hold":
                return u0, y0
            s = (tau - t) / dt
            return u0 + s * (u1 - u0), y0 + s * (y1 - y0)

        def f(gg, KK, tau):
            u, y = data(tau)
            tm = self._terms(weights, gg, KK, u, y, tau)
            return tm.lam + mv(KK, tm.r), riccati_rhs(tm, KK, self.alpha)

        def field_and_rate(gg, KK, tau):
            # the vector field at a point, and its stiffness rate: the step h is budgeted so that
            # ||K E|| h, ||A|| h and ||lambda + K r|| h stay below their budgets (DESIGN.md §6)
            u, y = data(tau)
            tm = self._terms(weights, gg, KK, u, y, tau)
            xi = tm.lam + mv(KK, tm.r)
            fro = lambda M: jnp.sqrt(jnp.sum(M * M))  # noqa: E731
            rate = jnp.maximum(jnp.maximum(fro(mm(KK, tm.E)) / _KE_BUDGET, fro(tm.A) / _A_BUDGET),
                               jnp.linalg.norm(xi) / _XI_BUDGET)
            return (xi, riccati_rhs(tm, KK, self.alpha)), jnp.where(jnp.isfinite(rate), rate, 0.0)

        if self.substeps == "auto":
            # Adaptive sub-steps: each step's size comes from the stiffness where it starts, so an impulsive
            # sample with a large K takes small steps while K shrinks, then larger ones (a number of steps
            # logarithmic, not linear, in ||K E|| dt). The last allowed step finishes the interval.
            def sub(c):
                gg, KK, done, j, _ = c
                first, rate = field_and_rate(gg, KK, t + done)
                left = dt - done
                forced = (j + 1 >= self.max_substeps) & (rate * left > 1.0)  # the cap: finish, though stiff
                last = forced | (rate * left <= 1.0)
                h = jnp.where(last, left, 1.0 / rate)
                g2, K2 = self.integrator.step(f, gg, KK, t + done, h, first=first)
                return g2, K2, jnp.where(last, dt, done + h), j + 1, forced

            def more(c):
                return c[2] < dt

            # the first step is taken outside the loop (most intervals are not stiff: the loop then runs 0 times)
            first, rate = field_and_rate(g, K, t)
            forced = (self.max_substeps <= 1) & (rate * dt > 1.0)
            last = forced | (rate * dt <= 1.0)
            h = jnp.where(last, dt, 1.0 / rate)
            g1, K1 = self.integrator.step(f, g, K, t, h, first=first)
            g1, K1, _, n_sub, capped = jax.lax.while_loop(
                more, sub, (g1, K1, jnp.where(last, dt, h), jnp.asarray(1, jnp.int32), forced))
        else:
            n_sub, capped = jnp.asarray(self.substeps, jnp.int32), jnp.asarray(False)
            h = dt / self.substeps
            g1, K1 = self.integrator.step(f, g, K, t, h, first=field_and_rate(g, K, t)[0])
            if self.substeps > 1:
                g1, K1 = jax.lax.fori_loop(1, self.substeps, lambda j, gK: self.integrator.step(f, *gK, t + j * h, h),
                                           (g1, K1))

        code = self._health(g1, K1, consecutive)
        new_fail = code != OK
        g_out = jax.tree_util.tree_map(lambda a, b: jnp.where(new_fail, a, b), g, g1)
        K_out = jnp.where(new_fail, K, K1)
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

    def _sensor_scale(self, g, K, t, dt, y0, mask, Wy, st):
        """Per-component weight factors from the sensors' gates, robust losses and time-varying weights, and
        the updated rejection counters."""
        p = self.system.output_dim
        scale = jnp.ones((p,))
        rejected, consecutive = st.rejected, st.consecutive
        if not any(b.gate_threshold is not None or b.robust is not None or b.weight_fn is not None
                   for b in self.blocks):
            return scale, rejected, consecutive
        h0, Dh = left_jacobian(lambda gg: self.system.output(gg, t), g)
        nu = y0 - h0
        Ks = 0.5 * (K + K.T)
        for i, b in enumerate(self.blocks):
            sl = slice(b.start, b.stop)
            factor = jnp.asarray(1.0)
            if b.gate_threshold is not None or b.robust is not None:
                present = jnp.all(mask[sl])
                # the sample's covariance: its information over the interval, times the interval
                info = jnp.where(present, Wy[sl, sl] * dt, jnp.eye(b.dim))
                S = mm(Dh[sl], mm(Ks, Dh[sl].T)) + jnp.linalg.inv(info)
                d2 = nu[sl] @ jnp.linalg.solve(S, nu[sl])
                d2 = jnp.where(jnp.isfinite(d2), d2, jnp.inf)
                if b.gate_threshold is not None:
                    reject = present & (d2 > b.gate_threshold)
                    factor = jnp.where(reject, 0.0, factor)
                    rejected = rejected.at[i].add(reject.astype(jnp.int32))
                    consecutive = consecutive.at[i].set(
                        jnp.where(reject, consecutive[i] + 1, jnp.where(present, 0, consecutive[i])))
                if b.robust is not None:
                    d = jnp.sqrt(jnp.maximum(d2, 1e-300))
                    c = b.robust_scale
                    w = jnp.minimum(1.0, c / d) if b.robust == "huber" else 1.0 / (1.0 + (d / c) ** 2)
                    factor = factor * jnp.where(present, w, 1.0)
            if b.weight_fn is not None:
                factor = factor * jnp.asarray(b.weight_fn(t), dtype=jnp.float64)
            scale = scale.at[sl].multiply(factor)
        return scale, rejected, consecutive

    def _health(self, g, K, consecutive):
        """The cause code of a state just computed (:data:`~liemef.filter.CAUSES`)."""
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves((g, K))]))
        Kf = jnp.where(finite, K, jnp.eye(K.shape[0]))
        big = jnp.max(jnp.abs(Kf))
        asym = jnp.max(jnp.abs(Kf - Kf.T)) > SYMMETRY_TOL * jnp.maximum(1.0, big)
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
    def scan(self, state: FilterState, ts, us, ys, *, gap=jnp.inf, n_valid=None, keep_every: int = 1) -> Trajectory:
        """Traceable core of :meth:`run` (no checks): one ``lax.scan`` over the sample intervals.

        ``n_valid``: only the first ``n_valid`` samples are data (the rest is padding, skipped);
        ``keep_every`` (static): keep every M-th state in the history (memory flat in the log length)."""
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
            gap: float | None = None, keep_every: int = 1) -> Trajectory:
        """Filter a whole log: ``ts`` (N,) strictly increasing, ``us`` (N, m), ``ys`` (N, p).

        Sample k is used over ``[ts[k], ts[k+1])``; the result holds the state at every ``ts[k]`` (every
        ``keep_every``-th), the first being ``state``. NaN in ``ys`` marks a missing sample; NaN in ``us`` holds
        the last input. An interval longer than ``gap`` (default: 10 times the median interval) is predicted
        through without holding density measurements, and a warning says so (``gap=math.inf``: no interval is
        a gap, as in :meth:`step`). Logs are padded to a length bucket (:func:`bucket`): one compilation serves
        every log of a bucket and every weight set.
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
        nb = bucket(N - 1)
        nb = -(-nb // keep_every) * keep_every
        pad = nb + 1 - N
        tsp = np.concatenate([ts, np.full(pad, ts[-1])])
        usp = np.concatenate([us, np.full((pad, m), np.nan)])
        ysp = np.concatenate([ys, np.full((pad, p), np.nan)])
        traj = _run_jit(self, state, tsp, usp, ysp, np.asarray(N, np.int32), np.asarray(gap), keep_every)
        kept = -(-N // keep_every) if keep_every > 1 else N
        traj = Trajectory(ts=jnp.asarray(ts[::keep_every]), g_hat=traj.g_hat[:kept], K=traj.K[:kept],
                          status=traj.status, final=traj.final)
        gaps = int(traj.status.gaps)
        if gaps:
            warnings.warn(f"run: {gaps} sample interval(s) longer than the gap threshold {gap:.4g} s (longest "
                          f"{float(traj.status.longest_gap):.4g} s) were predicted through without holding "
                          "density measurements", LogGapWarning, stacklevel=2)
        return traj

    def step(self, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float, *,
             u_next: ArrayLike | None = None, y_next: ArrayLike | None = None, gap: float = math.inf) -> FilterState:
        """Advance one sample interval ``[t, t + dt]`` (online use). NaN in ``y`` marks a missing component,
        NaN in ``u`` holds the last input; ``u_next``/``y_next`` are the samples at ``t + dt`` for
        ``interpolation="linear"`` (default: held). On a failure the returned state is the input state with a
        failed ``status`` (see :class:`~liemef.filter.Status`), and later steps leave it unchanged."""
        self._check_state(state)
        m, p = self.system.input_dim, self.system.output_dim
        u = self._check_sample("u", u, m, missing=True)
        y = self._check_sample("y", y, p, missing=True)
        u1 = u if u_next is None else self._check_sample("u_next", u_next, m, missing=True)
        y1 = y if y_next is None else self._check_sample("y_next", y_next, p, missing=True)
        dt = self._check_dt(dt)
        if not np.isfinite(t):
            raise ValueError(f"t: expected a finite time, got {t}")
        fn, leaves = _fast_parts(self)
        z = np.concatenate([[float(t), dt, float(gap)], u, u1, y, y1])
        out = fn(leaves, jax.tree_util.tree_leaves(state), z)
        return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(state), out)

    # --- checks -------------------------------------------------------------------------------------------
    def _check_state(self, state):
        # cheap structural checks only: step() is the online hot path
        if not isinstance(state, FilterState):
            raise ValueError(f"state: expected a FilterState (from init or step), got {type(state).__name__}")
        G, n = self.system.group, self.n
        if type(state.g_hat) is not G or getattr(state.K, "shape", None) != (n, n):
            raise ValueError(f"state: expected g_hat in {G.__name__} and K of shape ({n}, {n}), got "
                             f"{type(state.g_hat).__name__} and {getattr(state.K, 'shape', None)}")

    def _check_element(self, name, g):
        G = self.system.group
        if not isinstance(g, G):
            raise ValueError(f"{name}: expected an element of {G.__name__}, got {type(g).__name__}")
        if g.batch_shape != ():
            raise ValueError(f"{name}: expected a single element (no batch axes), got batch shape {g.batch_shape}")
        for leaf in jax.tree_util.tree_leaves(g):
            _validate.array(name, leaf)

    @staticmethod
    def _check_dt(dt) -> float:
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: expected a finite time step > 0, got {dt}")
        return float(dt)

    @staticmethod
    def _check_sample(name, v, n, missing: bool = False) -> np.ndarray:
        return _validate.array(name, np.zeros(0) if v is None and n == 0 else v, (n,), missing=missing)


class LogGapWarning(UserWarning):
    """A log had sample intervals longer than the gap threshold; the filter predicted through them."""


# --- compiled entry points, shared by every filter of the same structure --------------------------------------
@eqx.filter_jit
def _run_jit(flt, state, ts, us, ys, n_valid, gap, keep_every):
    TRACES["run"] += 1
    return flt.scan(state, ts, us, ys, gap=gap, n_valid=n_valid, keep_every=keep_every)


@eqx.filter_jit
def _terms_jit(flt, weights, g, K, u, y, t):
    TRACES["terms"] += 1
    return flt._terms(weights, g, K, u, y, t)


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


def _fast_parts(flt: MinimumEnergyFilter):
    """The compiled step of the filter's structure (one per structure, shared) and its array leaves, cached on
    the instance."""
    cached = flt.__dict__.get("_fast")
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
        object.__setattr__(flt, "_fast", cached)
    return cached
