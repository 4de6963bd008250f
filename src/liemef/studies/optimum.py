r"""The exact minimum-energy estimate: the batch MAP of the discretized cost the filters approximate.

A filter's estimate at $t_k$ is the cheap, recursive approximation of the minimizer of the cost of all data up to
$t_k$. This module computes that minimizer itself, so that a filter can be measured by its *distance to
optimality*. On the sample grid $t_0 < \dots < t_K$ with $\Delta_k = t_{k+1} - t_k$, the states $x_0..x_K \in G$
minimize

$$
J = \tfrac12\|x_0 \ominus g_0\|^2_{P_0^{-1}}
  + \tfrac12\sum_{k<K}\|x_{k+1} \ominus x_k\exp(\lambda(x_k, u_k, t_k)\Delta_k)\|^2_{Q_k^{-1}}
  + \tfrac12\sum_{k<K}\|y_k - h(x_k, t_k)\|^2_{W_k},
$$

with $a \ominus b = \log(b^{-1}a)$ (:meth:`~liemef.groups.LieGroup.rminus`, liemef's left error coordinates),
$Q_k = B R^{-1} B^\top \Delta_k$ (the process-noise density on the algebra over the interval: a per-sample std
$s$ at rate $f$ held over $\Delta$ has density $s^2/f$, hence the increment std $s\Delta$ at $\Delta = 1/f$),
and $W_k$ the measurement information in force over $[t_k, t_{k+1})$ times $\Delta_k$
(:func:`~liemef.filters.information_in_force`): the per-sample information of a ``Noise.sample`` sensor, the
density's information times $\Delta_k$ for a ``Noise.density`` one, zero for a missing (NaN) component.

**Which data the estimate at $t_k$ uses.** The filter's convention (:meth:`~liemef.MinimumEnergyFilter.run`):
sample $k$ is used over $[t_k, t_{k+1})$, so the estimate at $t_k$ has seen $y_0..y_{k-1}$ and $u_0..u_{k-1}$.
The MAP "of the current state" at $t_k$ here is the minimizer's last state $x_k$ for the cost above with $K = k$:
the same information set. A log's last rows ``us[K]``, ``ys[K]`` therefore never enter.

**Floors.** $P_0$ may be singular (ukfm's localization: $P_0 = \mathrm{diag}(\theta_0^2, 0, 0)$, an exactly known
position); so may $Q_k$ (a zero column of the noise map). Their eigenvalues are raised to ``floor_std**2``
(default :data:`FLOOR_STD` = 1e-6, in the coordinates' units: rad, m, rad/s): a coordinate known exactly is known
to 1e-6.

Solvers:

* :func:`map_estimates`: the per-step MAP $x_k$ at every $k$, incrementally, with GTSAM's iSAM2, for the planar
  localization (:func:`~liemef.systems.planar_localization`: Pose2 between-factors, position-fix factors) and
  the attitude + gyro bias system (:func:`~liemef.systems.attitude_gyro_bias`: Rot3 and bias variables,
  gyro and direction factors). Every iSAM2 update is iterated until no variable needs relinearization, so that
  the estimates are the minimizers, not one Gauss-Newton step towards them. ``solver="jax"`` gives the same
  numbers from :func:`batch_map` on every prefix (quadratic cost in the log length: short logs and tests).
* :func:`batch_map`: Levenberg-Marquardt-damped Gauss-Newton in JAX over the whole horizon for *any* liemef
  system, each step's block-tridiagonal normal equations solved exactly by block elimination forward and
  substitution backward (a Kalman-smoother pass in information form, linear in the log length). Its last
  state is the MAP of the current state; its trajectory the smoothed one.
* :func:`distance`, :func:`distance_components`, :func:`distance_summary`: the group distance
  $\|\log(g_a^{-1} g_b)\|$ per step, per component (heading and position for SE(2), angle for SO(3)), and its
  time average and rms over the whole log and a steady-state window.

GTSAM's conventions: Pose2's tangent is ordered $(x, y, \theta)$, liemef's se(2) $(\omega, v_x, v_y)$, so the
covariances are permuted; Pose2's and Rot3's ``Expmap``, ``retract``, ``Logmap`` and ``localCoordinates`` are
liemef's ``exp``, ``rplus``, ``log`` and ``rminus`` (body-frame perturbations; ``tests/test_optimum.py``), so
GTSAM's between-factor error is the cost's process residual. iSAM2 factorizes by QR: its Cholesky reports the
floored prior as an indeterminate system.

Robust losses, gates and time-varying sensor weights (:class:`~liemef.systems.Sensor`) are not part of the
cost: it is the Gaussian one.
"""

from __future__ import annotations

import math
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .. import _validate, smoothers
from ..filters import Weights
from ..groups import R3, SE2, SO3, TSO3, LieGroup
from ..integrators import LieEuler
from ..systems import AbstractSystem

FLOOR_STD = smoothers.FLOOR_STD
"""The smallest std of the prior and of the process noise per interval (:data:`liemef.smoothers.FLOOR_STD`)."""
SOLVERS = ("isam2", "isam2-dogleg", "jax")
"""The solvers of :func:`map_estimates`: iSAM2 with Gauss-Newton or Powell's dogleg steps, or :func:`batch_map`
on every prefix."""
WILDFIRE = 1e-10
"""iSAM2's wildfire threshold: back-substitution stops where the update changes less than this (GTSAM's default
1e-3 would leave the estimates that far from the minimizer; 0 back-substitutes the whole trajectory every step)."""
_BATCH_SOLVER = "levenberg-marquardt (jax), steps by block-tridiagonal elimination (Kalman-smoother pass)"


# --- boundary checks ------------------------------------------------------------------------------------------
def _check_log(system: AbstractSystem, ts, us, ys, g0, P0, floor_std):
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
    if not system.constant_process_noise:
        raise ValueError(f"system: expected a system with a constant noise map B, got {type(system).__name__}, whose "
                         "process noise depends on the state")
    G, n = system.group, system.group.tangent_dim
    ts = _validate.sorted_times("ts", ts)
    N = ts.shape[0]
    if N < 2:
        raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
    m, p = system.input_dim, system.output_dim
    us = np.zeros((N, 0)) if us is None and m == 0 else _validate.array("us", us, (N, m))
    ys = _validate.array("ys", ys, (N, p), missing=True)
    if not isinstance(g0, G):
        raise ValueError(f"g0: expected an element of {G.__name__}, got {type(g0).__name__}")
    if g0.batch_shape != ():
        raise ValueError(f"g0: expected a single element (no batch axes), got batch shape {g0.batch_shape}")
    for leaf in jax.tree_util.tree_leaves(g0):
        _validate.array("g0", leaf)
    P0 = _validate.symmetric_psd("P0", P0, n, definite=False)
    if not (isinstance(floor_std, int | float) and math.isfinite(floor_std) and floor_std > 0):
        raise ValueError(f"floor_std: expected a std > 0, got {floor_std!r}")
    return ts, us, ys, P0


def _weights(system: AbstractSystem, ts, ys, floor_std):
    """Per interval k < K: dt_k, Q_k (the process noise over dt_k, floored) and the measurement information W_k
    (the smoother's, :func:`liemef.smoothers.sample_information`, with the last row left out)."""
    weights = Weights.of(system)
    ys = np.array(ys, dtype=np.float64)
    ys[-1] = np.nan
    _, _, W = smoothers.sample_information(system, weights, ts, ys)
    dts = np.diff(ts)
    Qd = smoothers.floor_eigenvalues(np.asarray(weights.BRB)[None] * dts[:, None, None], floor_std)
    return dts, Qd, np.asarray(W[:-1])


# --- the generic batch solver (the smoother's, on the filter's information set) -------------------------------
class BatchMAP(eqx.Module):
    r"""The minimizer of the discretized cost (module docstring) over $[t_0, t_K]$.

    ``g`` (batch (K+1,)) is the smoothed trajectory; ``g[-1]`` is the MAP of the current state given the data
    up to $t_K$ (samples $k < K$). ``P_last`` is the Laplace covariance of $x_K$ (its marginal of the inverse
    Gauss-Newton Hessian, in the left error coordinates, the counterpart of the filter's K). ``solver`` names
    the method; ``converged`` says whether the last accepted step was below ``tol`` within ``max_iterations``.
    """

    ts: Float[Array, " N"]
    g: LieGroup
    P_last: Float[Array, "n n"]
    cost: Float[Array, ""]
    gradient_norm: Float[Array, ""]
    iterations: Int[Array, ""]
    converged: Bool[Array, ""]
    solver: str = eqx.field(static=True, default=_BATCH_SOLVER)

    @property
    def last(self) -> LieGroup:
        """The MAP of the current state, ``g[-1]``."""
        return self.g[-1]


def batch_map(system: AbstractSystem, ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N m"] | None,
              ys: Float[ArrayLike, "N p"], g0: LieGroup, P0: Float[ArrayLike, "n n"], *,
              init: LieGroup | None = None, max_iterations: int = 100, tol: float = 1e-10,
              floor_std: float = FLOOR_STD) -> BatchMAP:
    r"""The minimizer of the discretized cost (module docstring) over the whole log, for any liemef system.

    The smoother's solver (:mod:`liemef.smoothers`: Levenberg-Marquardt on the trajectory $x_0..x_K$, each
    step's block-tridiagonal normal equations solved by a Kalman smoother in information form, linear in K) on
    this module's cost: the system's nominal weights, one Lie-Euler step per interval, the Gaussian loss, and
    the last row's samples left out, so that ``g[-1]`` has the filter's information set.

    Args:
        system: any liemef system (:class:`~liemef.systems.AbstractSystem`) whose process noise is constant.
        ts: (N,) strictly increasing sample times.
        us: (N, m) inputs (finite), each held over its interval; row N-1 does not enter.
        ys: (N, p) outputs with NaN for missing samples; row N-1 does not enter.
        g0: the prior mean $g_0$.
        P0: the prior covariance of the left error $\xi$, $x_0 = g_0\exp\xi$ (positive semidefinite;
            eigenvalues floored at ``floor_std**2``).
        init: the starting trajectory (batch (N,)); default: dead reckoning from ``g0``.
        max_iterations: the most Levenberg-Marquardt steps (accepted or not).
        tol: convergence: an accepted step whose largest component is below ``tol``.
        floor_std: the floor of the stds of P0 and of the process noise per interval (:data:`FLOOR_STD`).

    Returns:
        :class:`BatchMAP`: the smoothed trajectory, its last state (the MAP of the current state), the Laplace
        covariance of that state, the cost, the convergence and the solver's name.
    """
    ts, us, ys, P0 = _check_log(system, ts, us, ys, g0, P0, floor_std)
    if not (isinstance(max_iterations, int) and max_iterations >= 1):
        raise ValueError(f"max_iterations: expected an integer >= 1, got {max_iterations!r}")
    tol = _validate.nonnegative("tol", tol)
    N = ts.shape[0]
    if init is not None and (not isinstance(init, system.group) or init.batch_shape != (N,)):
        raise ValueError(f"init: expected a {system.group.__name__} of batch shape ({N},), got "
                         f"{type(init).__name__} {getattr(init, 'batch_shape', None)}")
    integ = LieEuler()
    if init is None:
        init = smoothers.dead_reckoning(system, integ, g0, jnp.asarray(ts), jnp.asarray(us))
    sm = smoothers.solve(system, Weights.of(system), ts, us, ys, g0, P0, init, integ=integ, last_sample=False,
                         floor_std=floor_std, max_iterations=max_iterations, tol=tol)
    return BatchMAP(ts=sm.ts, g=sm.g, P_last=sm.P[-1], cost=sm.cost, gradient_norm=sm.gradient_norm,
                    iterations=jnp.asarray(sm.iterations), converged=jnp.asarray(sm.status == "converged"))


# --- per-step MAP with GTSAM's iSAM2 --------------------------------------------------------------------------
class MAPEstimates(eqx.Module):
    """Per-step MAP estimates: ``g[i]`` is the MAP of the state at ``ts[i]`` given the samples before it
    (module docstring; ``ts`` is the log's ``ts[::every]`` and its last time); ``smoothed`` the MAP of the whole
    trajectory given the whole log (the last problem's solution). ``updates[i]`` counts the solver's iterations
    for estimate i; ``elapsed`` is the wall time (s)."""

    ts: Float[Array, " N"]
    g: LieGroup
    smoothed: LieGroup
    updates: Int[Array, " N"]
    elapsed: float = eqx.field(static=True)
    solver: str = eqx.field(static=True)


def _se2_to_pose2(gtsam, c: np.ndarray):
    return gtsam.Pose2(float(c[2]), float(c[3]), math.atan2(float(c[1]), float(c[0])))


def _pose2_to_coords(p) -> np.ndarray:
    return np.array([p.theta(), p.x(), p.y()])


_PERM_SE2 = np.array([1, 2, 0])
"""GTSAM's Pose2 tangent (x, y, theta) from liemef's se(2) order (omega, v_x, v_y): ``xi_gtsam = xi[_PERM_SE2]``."""


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _which(system) -> str:
    from ..systems.attitude_bias import BodyDirection, gyro_bias_dynamics
    from ..systems.localization import gps_position, odometry_dynamics

    sensors = getattr(system, "sensors", None)
    dyn = getattr(system, "dynamics_fn", None)
    if system.group is SE2 and dyn is odometry_dynamics and sensors and all(s.fn is gps_position for s in sensors):
        return "localization"
    if system.group is TSO3 and dyn is gyro_bias_dynamics and sensors and all(
            isinstance(s.fn, BodyDirection) for s in sensors):
        return "attitude"
    raise ValueError("system: expected liemef.systems.planar_localization(...) or "
                     f"liemef.systems.attitude_gyro_bias(...), got {type(system).__name__} on "
                     f"{system.group.__name__} (use batch_map for other systems)")


def _isam(gtsam, solver, relinearize_threshold):
    params = gtsam.ISAM2Params()
    if solver == "isam2-dogleg":
        opt = gtsam.ISAM2DoglegParams()
    else:
        opt = gtsam.ISAM2GaussNewtonParams()
    opt.setWildfireThreshold(WILDFIRE)  # back-substitution stops below this change (GTSAM: 1e-3)
    params.setOptimizationParams(opt)
    params.setRelinearizeThreshold(relinearize_threshold)
    params.relinearizeSkip = 1
    params.setFactorization("QR")  # Cholesky reports the stiff floored prior (1e-6) as indeterminate
    return gtsam.ISAM2(params)


def _update(isam, graph, values, max_updates, t) -> int:
    """One iSAM2 update with the new factors, then bare updates while a variable still needs relinearizing."""
    try:
        res = isam.update(graph, values)
        it = 1
        while res.getVariablesRelinearized() > 0 and it < max_updates:
            res = isam.update()
            it += 1
    except RuntimeError as err:  # GTSAM's IndeterminateLinearSystemException and the like
        raise RuntimeError(f"map_estimates: iSAM2 failed at t = {t:.6g} s: {str(err).strip()}") from err
    return it


def _fix_factor(gtsam, key, y, W, rows):
    """A position fix on a Pose2: error ``p - y`` on the present components ``rows``, information ``W``."""
    noise = gtsam.noiseModel.Gaussian.Information(W)

    def error(this, values, H):
        p = values.atPose2(this.keys()[0])
        c, s = math.cos(p.theta()), math.sin(p.theta())
        e = np.array([p.x(), p.y()]) - y
        if H is not None:
            # d p(x exp(delta)) / d delta = [R, 0] in GTSAM's (x, y, theta)
            H[0] = np.array([[c, -s, 0.0], [s, c, 0.0]])[rows]
        return e[rows]

    return gtsam.CustomFactor(noise, [key], error)


def _localization(gtsam, system, ts, us, ys, g0, P0f, Qd, W, solver, thr, max_updates, every, progress):
    X = lambda k: gtsam.symbol("x", k)  # noqa: E731
    N = ts.shape[0]
    lam = np.asarray(jax.vmap(lambda u, t: system.dynamics(g0, u, t))(jnp.asarray(us), jnp.asarray(ts)))
    steps = np.asarray(SE2.exp(jnp.asarray(lam[:-1] * np.diff(ts)[:, None])).cos_sin_xy)
    P = np.eye(3)[_PERM_SE2]
    isam = _isam(gtsam, solver, thr)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose0 = _se2_to_pose2(gtsam, np.asarray(g0.cos_sin_xy))
    graph.add(gtsam.PriorFactorPose2(X(0), pose0, gtsam.noiseModel.Gaussian.Covariance(P @ P0f @ P.T)))
    values.insert(X(0), pose0)
    kept = _kept(N, every)
    out, updates = np.zeros((kept.size, 3)), np.zeros(kept.size, np.int64)
    updates[0] = _update(isam, graph, values, max_updates, ts[0])
    out[0] = _pose2_to_coords(isam.calculateEstimatePose2(X(0)))
    guess = isam.calculateEstimatePose2(X(0))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(1, N):
        step = _se2_to_pose2(gtsam, steps[k - 1])
        cov = P @ Qd[k - 1] @ P.T
        graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), step, gtsam.noiseModel.Gaussian.Covariance(cov)))
        rows = np.flatnonzero(np.isfinite(ys[k - 1]))
        if rows.size:
            graph.add(_fix_factor(gtsam, X(k - 1), ys[k - 1], W[k - 1][np.ix_(rows, rows)], rows))
        guess = guess.compose(step)
        values.insert(X(k), guess)
        if k % every == 0 or k == N - 1:
            i = int(np.searchsorted(kept, k))
            updates[i] = _update(isam, graph, values, max_updates, ts[k])
            guess = isam.calculateEstimatePose2(X(k))
            out[i] = _pose2_to_coords(guess)
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if progress and k % 500 == 0:
            print(f"map_estimates: {k}/{N}", file=sys.stderr, flush=True)
    est = isam.calculateEstimate()
    smoothed = np.array([_pose2_to_coords(est.atPose2(X(k))) for k in range(N)])
    return SE2.from_coords(out), SE2.from_coords(smoothed), updates


def _kept(N: int, every: int) -> np.ndarray:
    """The steps at which estimates are computed: 0, every, 2 every, ... and the last."""
    return np.unique(np.append(np.arange(0, N, every), N - 1))


def _so3_log_jr_inv(r):
    import gtsam

    return gtsam.Rot3.LogmapDerivative(r)


def _attitude(gtsam, system, ts, us, ys, g0, P0f, Qd, W, solver, thr, max_updates, every, progress):
    Rk = lambda k: gtsam.symbol("r", k)  # noqa: E731
    Bk = lambda k: gtsam.symbol("b", k)  # noqa: E731
    N = ts.shape[0]
    dts = np.diff(ts)
    directions = np.concatenate([np.asarray(s.fn.v, dtype=np.float64)[None] for s in system.sensors])
    isam = _isam(gtsam, solver, thr)
    R0 = gtsam.Rot3(np.asarray(g0.factors[0].as_matrix()))
    b0 = np.asarray(g0.factors[1].x, dtype=np.float64)

    def prior(this, values, H):
        R, b = values.atRot3(this.keys()[0]), values.atVector(this.keys()[1])
        rR = gtsam.Rot3.Logmap(R0.between(R))
        if H is not None:
            H[0] = np.vstack([_so3_log_jr_inv(rR), np.zeros((3, 3))])
            H[1] = np.vstack([np.zeros((3, 3)), np.eye(3)])
        return np.concatenate([rR, b - b0])

    def process(u, dt):
        def error(this, values, H):
            k = this.keys()
            Ra, ba, Rb, bb = values.atRot3(k[0]), values.atVector(k[1]), values.atRot3(k[2]), values.atVector(k[3])
            phi = -(u - ba) * dt
            M = Ra.between(Rb).matrix()
            Z = gtsam.Rot3.Expmap(phi).matrix() @ M
            r = gtsam.Rot3.Logmap(gtsam.Rot3(Z))
            if H is not None:
                Jinv = _so3_log_jr_inv(r)
                O, eye = np.zeros((3, 3)), np.eye(3)
                H[0] = np.vstack([-Jinv @ M.T, O])
                H[1] = np.vstack([Jinv @ M.T @ gtsam.Rot3.ExpmapDerivative(phi) * dt, -eye])
                H[2] = np.vstack([Jinv, O])
                H[3] = np.vstack([O, eye])
            return np.concatenate([r, bb - ba])
        return error

    def direction(y, v, rows):
        def error(this, values, H):
            Rt_v = values.atRot3(this.keys()[0]).matrix().T @ v
            if H is not None:
                H[0] = _skew(Rt_v)[rows]  # R^T v after R exp(delta): R^T v + [R^T v]_x delta
            return (Rt_v - y)[rows]
        return error

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(P0f), [Rk(0), Bk(0)], prior))
    values.insert(Rk(0), R0)
    values.insert(Bk(0), b0)
    kept = _kept(N, every)
    quats, biases, updates = np.zeros((kept.size, 4)), np.zeros((kept.size, 3)), np.zeros(kept.size, np.int64)

    def read(k):
        R, b = isam.calculateEstimateRot3(Rk(k)), np.asarray(isam.calculateEstimateVector(Bk(k)))
        q = R.toQuaternion()
        return R, b, np.array([q.w(), q.x(), q.y(), q.z()])

    updates[0] = _update(isam, graph, values, max_updates, ts[0])
    R, b, quats[0] = read(0)
    biases[0] = b
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(1, N):
        u, dt = us[k - 1], dts[k - 1]
        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(Qd[k - 1]),
                                     [Rk(k - 1), Bk(k - 1), Rk(k), Bk(k)], process(u, dt)))
        for j in range(len(system.sensors)):
            blk = slice(3 * j, 3 * j + 3)
            y = ys[k - 1, blk]
            rows = np.flatnonzero(np.isfinite(y))
            if rows.size:
                Wb = W[k - 1][blk, blk][np.ix_(rows, rows)]
                graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Information(Wb), [Rk(k - 1)],
                                             direction(np.nan_to_num(y), directions[j], rows)))
        R = R.compose(gtsam.Rot3.Expmap((u - b) * dt))
        values.insert(Rk(k), R)
        values.insert(Bk(k), b)
        if k % every == 0 or k == N - 1:
            i = int(np.searchsorted(kept, k))
            updates[i] = _update(isam, graph, values, max_updates, ts[k])
            R, b, quats[i] = read(k)
            biases[i] = b
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if progress and k % 500 == 0:
            print(f"map_estimates: {k}/{N}", file=sys.stderr, flush=True)
    est = isam.calculateEstimate()
    sq, sb = np.zeros((N, 4)), np.zeros((N, 3))
    for k in range(N):
        q = est.atRot3(Rk(k)).toQuaternion()
        sq[k] = [q.w(), q.x(), q.y(), q.z()]
        sb[k] = est.atVector(Bk(k))
    tso3 = lambda q, b: TSO3((SO3(jnp.asarray(q)), R3(jnp.asarray(b))))  # noqa: E731
    return tso3(quats, biases), tso3(sq, sb), updates


def _prefix_maps(system, ts, us, ys, g0, P0, floor_std, every):
    """The last state of :func:`batch_map` on every kept prefix ``[t_0, t_k]`` (quadratic cost)."""
    N = ts.shape[0]
    kept = _kept(N, every)
    # One compilation: on the whole grid with the samples at and after t_k masked, the states after x_k are
    # free (their process terms vanish at the minimum), so x_k is the prefix's MAP.
    g, iters, smoothed = [g0], [0], g0
    for k in kept[1:]:
        yk = ys.copy()
        yk[k:] = np.nan
        res = batch_map(system, ts, us, yk, g0, P0, floor_std=floor_std)
        g.append(res.g[k])
        iters.append(int(res.iterations))
        smoothed = res.g
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *g)
    return stacked, smoothed, np.array(iters)


def map_estimates(system: AbstractSystem, ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N m"],
                  ys: Float[ArrayLike, "N p"], g0: LieGroup, P0: Float[ArrayLike, "n n"], *,
                  solver: str = "isam2", relinearize_threshold: float = 1e-7, max_updates: int = 50,
                  every: int = 1, floor_std: float = FLOOR_STD, progress: bool = False) -> MAPEstimates:
    r"""The MAP of the current state at every sample: ``g[k]`` minimizes the discretized cost of the samples
    before $t_k$ (module docstring), the exact counterpart of a filter's estimate at $t_k$.

    Args:
        system: :func:`~liemef.systems.planar_localization` (SE(2): odometry $u = (v_x, v_y, \omega)$ held over
            each interval, position fixes) or :func:`~liemef.systems.attitude_gyro_bias` (TSO(3): gyro, bias
            random walk, direction sensors), with any noise levels.
        ts: (N,) strictly increasing sample times.
        us: (N, m) inputs (finite).
        ys: (N, p) outputs with NaN for missing samples.
        g0: the prior mean.
        P0: the prior covariance of the left error (positive semidefinite, floored).
        solver: ``"isam2"`` (GTSAM's iSAM2 with Gauss-Newton steps; Pose2 between-factors for the odometry, a
            custom factor per fix; Rot3 and Vector3 variables with custom gyro and direction factors),
            ``"isam2-dogleg"`` (its Powell's dogleg variant) or ``"jax"`` (:func:`batch_map` on every prefix,
            any system, quadratic in N).
        relinearize_threshold: iSAM2 relinearizes a variable whose pending step exceeds this; every update is
            repeated (at most ``max_updates`` times) until none does, so that ``g[k]`` is the minimizer to about
            this precision.
        max_updates: the most iSAM2 updates per estimate.
        every: compute the estimate at every ``every``-th step only (and the last): the factors of the steps in
            between enter together. The estimates are the same; with dense measurements (the attitude case, where
            every sample moves the whole past and iSAM2 relinearizes it all) the cost falls by about ``every``.
        floor_std: the floor of the stds of P0 and of the process noise per interval (:data:`FLOOR_STD`).
        progress: print a line every 500 steps.

    Returns:
        :class:`MAPEstimates` with ``g`` at ``ts[::every]`` and ``ts[-1]``, the smoothed trajectory (batch (N,)),
        the iterations per estimate, the wall time and the solver.
    """
    ts, us, ys, P0 = _check_log(system, ts, us, ys, g0, P0, floor_std)
    _validate.choice("solver", solver, set(SOLVERS))
    if not (isinstance(max_updates, int) and max_updates >= 1):
        raise ValueError(f"max_updates: expected an integer >= 1, got {max_updates!r}")
    if not (isinstance(every, int | np.integer) and every >= 1):
        raise ValueError(f"every: expected an integer >= 1, got {every!r}")
    every = int(every)
    thr = _validate.nonnegative("relinearize_threshold", relinearize_threshold)
    t_start = time.perf_counter()
    if solver == "jax":
        g, smoothed, updates = _prefix_maps(system, ts, us, ys, g0, P0, floor_std, every)
        name = f"batch_map on every prefix: {_BATCH_SOLVER}"
    else:
        kind = _which(system)
        import gtsam

        _, Qd, W = _weights(system, ts, ys, floor_std)
        P0f = smoothers.floor_eigenvalues(P0, floor_std)
        run = _localization if kind == "localization" else _attitude
        g, smoothed, updates = run(gtsam, system, ts, us, ys, g0, P0f, Qd, W, solver, thr, max_updates, every,
                                   progress)
        step = "Powell's dogleg" if solver == "isam2-dogleg" else "Gauss-Newton"
        name = (f"gtsam iSAM2 ({step}, relinearize threshold {thr:g}, updates repeated until converged, "
                f"{'Pose2' if kind == 'localization' else 'Rot3 + Vector3'} variables)")
    elapsed = time.perf_counter() - t_start
    return MAPEstimates(ts=jnp.asarray(ts[_kept(ts.shape[0], every)]), g=g, smoothed=smoothed,
                        updates=jnp.asarray(updates), elapsed=elapsed, solver=name)


# --- distances ------------------------------------------------------------------------------------------------
def distance(g_a: LieGroup, g_b: LieGroup) -> Float[Array, "..."]:
    r"""The group distance $\|\log(g_a^{-1} g_b)\|$ per element (batch shapes broadcast)."""
    return jnp.linalg.norm(g_b.rminus(g_a), axis=-1)


def _components(a: LieGroup, b: LieGroup, prefix: str = "") -> dict[str, Array]:
    if isinstance(a, SE2):
        dth = a.rotation().between(b.rotation()).log()[..., 0]
        return {f"{prefix}heading": jnp.abs(dth),
                f"{prefix}position": jnp.linalg.norm(b.translation() - a.translation(), axis=-1)}
    if isinstance(a, SO3):
        return {f"{prefix}angle": jnp.linalg.norm(a.between(b).log(), axis=-1)}
    if hasattr(a, "factors"):
        out = {}
        for i, (fa, fb) in enumerate(zip(a.factors, b.factors, strict=True)):
            out.update(_components(fa, fb, f"{prefix}{i}."))
        return out
    return {f"{prefix}norm": distance(a, b)}


def distance_components(g_a: LieGroup, g_b: LieGroup) -> dict[str, Float[Array, "..."]]:
    r"""Per-step distances by component: ``"total"`` = :func:`distance`; for SE(2) ``"heading"`` (rad,
    $|\theta_b - \theta_a|$ wrapped) and ``"position"`` ($\|p_b - p_a\|$, world frame); for SO(3) ``"angle"``
    (rad); for a product the factors' entries prefixed by their index (TSO(3): ``"0.angle"``, ``"1.norm"``, the
    bias difference); for $\mathbb R^n$ ``"norm"``."""
    if type(g_a) is not type(g_b):
        raise ValueError(f"g_b: expected an element of {type(g_a).__name__}, got {type(g_b).__name__}")
    return {"total": distance(g_a, g_b), **_components(g_a, g_b)}


def distance_summary(ts: Float[ArrayLike, " N"], distances: dict[str, ArrayLike] | ArrayLike,
                     steady: float | None = None) -> dict:
    """Time average (mean over the samples), rms and maximum of each distance series over the whole log and,
    if ``steady`` is given, over ``t >= steady``. JSON-ready floats."""
    ts = _validate.array("ts", ts, (None,))
    series = distances if isinstance(distances, dict) else {"distance": distances}
    windows = {"all": np.ones(ts.shape, bool)}
    if steady is not None:
        windows[f"t>={steady:g}"] = ts >= float(steady)
    out = {}
    for name, d in series.items():
        d = _validate.array(name, np.asarray(d), ts.shape, missing=True)
        out[name] = {w: {"mean": float(np.mean(d[m])), "rms": float(np.sqrt(np.mean(d[m] ** 2))),
                         "max": float(np.max(d[m]))} for w, m in windows.items() if m.any()}
    return out


__all__ = ["FLOOR_STD", "SOLVERS", "BatchMAP", "MAPEstimates", "batch_map", "map_estimates", "distance",
           "distance_components", "distance_summary"]

