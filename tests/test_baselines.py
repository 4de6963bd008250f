"""The Kalman baselines (liemef.filters.baselines): reduction to the discrete Kalman filter on R^n, the retractions and
their covariance conversion, missing samples, gates, failures as values, bad input, and the localization
scenario (the invariant EKF equals the left UKF-M; the local EKF is the worse one)."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

import liemef
from liemef import codegen
from liemef.engines import LogGapWarning
from liemef.filters import CAUSES, TRACES
from liemef.filters.baselines import (
    ExtendedKalmanFilter,
    UnscentedKalmanFilter,
    invariant_ekf,
    local_ekf,
    retraction,
    ukf_m,
)
from liemef.groups import SE2, TSE2, TSO3, Rn
from liemef.systems import Noise, Sensor, SensorSystem
from tolerances import ENGINES

R3 = Rn[3]
A = np.array([[0.0, 1.0, 0.0], [-0.5, -0.2, 0.3], [0.0, 0.0, -0.1]])
G = np.array([[0.0], [1.0], [0.5]])
Q_DENSITY = np.array([0.3, 0.5, 0.2])
POS_STD, VEL_DENSITY = 0.4, np.array([0.2, 0.3])
DT, N = 0.05, 120


def _dynamics(g, u, t):
    return jnp.asarray(A) @ g.x + jnp.asarray(G) @ u


SYSTEM = SensorSystem(R3, _dynamics, (Sensor("pos", lambda g, t: g.x[:1], Noise.sample(POS_STD)),
                                      Sensor("vel", lambda g, t: g.x[1:], Noise.density(VEL_DENSITY))),
                      Noise.density(Q_DENSITY), inputs=("a",))


def _log(seed=0, missing=True):
    rng = np.random.default_rng(seed)
    ts = np.arange(N) * DT
    us = np.sin(ts)[:, None] + 0.1 * rng.standard_normal((N, 1))
    ys = rng.standard_normal((N, 3))
    if missing:
        ys[rng.random(N) < 0.3, 0] = np.nan  # position samples missing
        ys[rng.random(N) < 0.2, 1:] = np.nan  # both velocity components missing
        ys[5, 2] = np.nan  # one component only
    return ts, us, ys


def _kalman_reference(ts, us, ys, x0, P0):
    """filterpy's KalmanFilter with the Lie-Euler discretization on R^n (F = I + A dt, B = G dt,
    Q_d = diag(q^2) dt) and the sample's covariance (sigma^2 for the sample sensor, s^2 / dt for the density
    one), updating with y_k then predicting with u_k; returns the priors at every t_k."""
    H_full = np.eye(3)
    R_full = np.diag([POS_STD**2, *(VEL_DENSITY**2 / DT)])
    kf = KalmanFilter(dim_x=3, dim_z=3, dim_u=1)
    kf.x, kf.P = x0.copy(), P0.copy()
    kf.F, kf.B, kf.Q = np.eye(3) + A * DT, G * DT, np.diag(Q_DENSITY**2) * DT
    xs, Ps = [kf.x.copy()], [kf.P.copy()]
    for k in range(len(ts) - 1):
        ok = np.isfinite(ys[k])
        if ok.any():
            kf.update(ys[k][ok], R=R_full[np.ix_(ok, ok)], H=H_full[ok])
        kf.predict(u=us[k])
        xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
    return np.array(xs), np.array(Ps)


@pytest.mark.parametrize("make", [lambda s: ExtendedKalmanFilter(s, "left"), lambda s: ExtendedKalmanFilter(s, "local"),
                                  lambda s: ExtendedKalmanFilter(s, "right"), lambda s: UnscentedKalmanFilter(s)],
                         ids=["ekf-left", "ekf-local", "ekf-right", "ukf"])
def test_on_a_linear_system_every_baseline_is_the_kalman_filter(make):
    ts, us, ys = _log()
    x0, P0 = np.array([0.5, -0.3, 0.2]), np.diag([1.0, 2.0, 0.5])
    flt = make(SYSTEM)
    traj = flt.run(flt.init(R3(x0), P0), ts, us, ys)
    assert int(traj.status.code) == 0
    xs, Ps = _kalman_reference(ts, us, ys, x0, P0)
    # the UKF's weights with a = 1e-3 cancel to about 1e-16 / a^2 relative
    tol = 1e-9 if isinstance(flt, ExtendedKalmanFilter) else 1e-6
    np.testing.assert_allclose(np.asarray(traj.g_hat.x), xs, rtol=0, atol=tol)
    np.testing.assert_allclose(np.asarray(traj.K), Ps, rtol=0, atol=tol)


@pytest.mark.parametrize("error", ["left", "right", "local"])
@pytest.mark.parametrize("G_", [SE2, TSE2, TSO3], ids=["SE2", "TSE2", "TSO3"])
def test_retractions_invert_and_the_covariance_is_reported_in_the_left_error(error, G_):
    plus, minus = retraction(error)
    rng = np.random.default_rng(1)
    n = G_.tangent_dim
    g = G_.exp(rng.standard_normal(n))
    e = 0.3 * rng.standard_normal(n)
    np.testing.assert_allclose(np.asarray(minus(plus(g, e), g)), e, atol=1e-12)
    np.testing.assert_allclose(np.asarray(minus(g, g)), np.zeros(n), atol=1e-12)
    # J = d(left error)/d(e) at 0, checked by a central difference of the left error of plus(g, e)
    sys = SensorSystem(G_, lambda gg, u, t: jnp.zeros(n),
                       (Sensor("s", lambda gg, t: gg.log(), Noise.sample(np.ones(n))),), Noise.density(np.ones(n)))
    J = np.asarray(ExtendedKalmanFilter(sys, error)._left_jacobian(g))
    h = 1e-6
    J_fd = np.stack([(np.asarray(plus(g, h * d).rminus(g)) - np.asarray(plus(g, -h * d).rminus(g))) / (2 * h)
                     for d in np.eye(n)], axis=1)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)
    if error == "left":
        np.testing.assert_allclose(J, np.eye(n), atol=1e-12)
    if error == "local" and G_ is SE2:  # p = p_hat + e_p: the body-frame error is R^T e_p
        R = np.asarray(g.rotation().as_matrix())
        np.testing.assert_allclose(J[1:, 1:], R.T, atol=1e-12)


def _localization(seconds=6.0, seed=0):
    from liemef.studies.experiments import localization as L

    c = L.LocalizationConfig(duration=seconds, steady=seconds / 2)
    s = L.setup(c)
    log, g0 = L.sensor_log(c, s.truth, L.jax_draws(c, jax.random.key(seed)))
    return c, s, log, g0


def test_on_the_localization_the_invariant_ekf_and_the_left_ukf_agree_and_the_local_ekf_differs():
    from liemef.studies.experiments import localization as L

    c, s, log, g0 = _localization()
    K0 = np.diag([c.theta0_std**2, 0.0, 0.0])
    runs = {}
    for flt in (invariant_ekf(s.system), ukf_m(s.system), local_ekf(s.system)):
        traj = flt.run(flt.init(g0, K0), np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys))
        assert int(traj.status.code) == 0, flt.name
        runs[flt.name] = np.asarray(L.series(s.truth, traj.g_hat, traj.K))
    # with a = 1e-3 the UKF-M is a central-difference linearization: the invariant EKF to O(a^2)
    np.testing.assert_allclose(runs["ukf-left"][:, :2], runs["iekf"][:, :2], atol=1e-3)
    assert np.max(np.abs(runs["ekf"][:, 0] - runs["iekf"][:, 0])) > 0.1  # deg: another filter
    late = np.asarray(log.ts) >= 3.0
    assert np.sqrt(np.mean(runs["iekf"][late, 0] ** 2)) < 10.0  # the 45-deg-class heading error is corrected


def test_missing_inputs_are_held_and_counted():
    ts, us, ys = _log(missing=False)
    flt = invariant_ekf(SYSTEM)
    state = flt.init(R3(np.zeros(3)), np.eye(3))
    held = us.copy()
    held[10:13] = np.nan
    ref = us.copy()
    ref[10:13] = us[9]
    a = flt.run(state, ts, held, ys)
    b = flt.run(state, ts, ref, ys)
    np.testing.assert_allclose(np.asarray(a.g_hat.x), np.asarray(b.g_hat.x), atol=1e-14)
    assert int(a.status.inputs_held) == 3


def test_a_gate_rejects_an_outlier_and_counts_it():
    gated = SensorSystem(R3, _dynamics, (Sensor("pos", lambda g, t: g.x[:1], Noise.sample(POS_STD), gate=0.999),
                                         Sensor("vel", lambda g, t: g.x[1:], Noise.density(VEL_DENSITY))),
                         Noise.density(Q_DENSITY), inputs=("a",))
    ts, us, ys = _log(missing=False)
    ys[60, 0] = 1e3
    for flt in (invariant_ekf(gated), ukf_m(gated)):
        traj = flt.run(flt.init(R3(np.zeros(3)), np.eye(3)), ts, us, ys)
        clean = ys.copy()
        clean[60, 0] = np.nan
        ref = flt.run(flt.init(R3(np.zeros(3)), np.eye(3)), ts, us, clean)
        assert int(traj.status.rejected[0]) >= 1
        np.testing.assert_allclose(np.asarray(traj.g_hat.x)[61:], np.asarray(ref.g_hat.x)[61:], atol=1e-12)


def test_a_non_finite_state_is_a_failure_value_with_where_and_when():
    def blows_up(g, u, t):
        return jnp.where(t >= 2.0, jnp.nan, 1.0) * jnp.asarray(A) @ g.x

    sys = SensorSystem(R3, blows_up, (Sensor("pos", lambda g, t: g.x[:1], Noise.sample(POS_STD)),),
                       Noise.density(Q_DENSITY), inputs=("a",))
    ts, us, ys = _log(missing=False)
    for flt in (invariant_ekf(sys), ukf_m(sys)):
        traj = flt.run(flt.init(R3(np.ones(3)), np.eye(3)), ts, us, ys[:, :1])
        k = int(np.argmax(ts >= 2.0 - 1e-12))
        assert CAUSES[int(traj.status.code)] == "non-finite"
        assert int(traj.status.index) == k and float(traj.status.time) == pytest.approx(ts[k])
        x = np.asarray(traj.g_hat.x)
        assert np.all(np.isfinite(x[:k + 1])) and np.all(np.isnan(x[k + 1:]))  # nothing after it passes for data
        np.testing.assert_allclose(np.asarray(traj.final.g_hat.x), x[k])


def test_new_noise_levels_reuse_the_compiled_run():
    ts, us, ys = _log()
    flt = invariant_ekf(SYSTEM)
    flt.run(flt.init(R3(np.zeros(3)), np.eye(3)), ts, us, ys)
    before = TRACES["run"]
    other = invariant_ekf(SYSTEM.with_noise(pos=Noise.sample(0.9), vel=Noise.density([0.5, 0.6])))
    traj = other.run(other.init(R3(np.ones(3)), 2 * np.eye(3)), ts, us, ys)
    assert TRACES["run"] == before
    assert int(traj.status.code) == 0


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="error"):
        ExtendedKalmanFilter(SYSTEM, "sideways")
    with pytest.raises(ValueError, match="substeps"):
        invariant_ekf(SYSTEM, substeps=0)
    with pytest.raises(ValueError, match="spread"):
        ukf_m(SYSTEM, spread=2.0)
    with pytest.raises(ValueError, match="system"):
        ExtendedKalmanFilter("not a system")
    flt = invariant_ekf(SYSTEM)
    with pytest.raises(ValueError, match="K0"):
        flt.init(R3(np.zeros(3)), -np.eye(3))
    ts, us, ys = _log()
    with pytest.raises(ValueError, match="ys"):
        flt.run(flt.init(R3(np.zeros(3)), np.eye(3)), ts, us, ys[:, :2])
    bad = us.copy()
    bad[3, 0] = np.inf
    with pytest.raises(ValueError, match="us"):
        flt.run(flt.init(R3(np.zeros(3)), np.eye(3)), ts, bad, ys)


def _assert_engines_agree(a, b):
    """Every leaf of two runs (trajectory, final state, status) equal to ENGINES relative, integers exactly."""
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype
        if x.dtype.kind in "iub":
            np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_array_equal(np.isnan(x), np.isnan(y))
            ok = ~np.isnan(x)
            scale = max(1.0, float(np.abs(y[ok]).max(initial=0)))
            np.testing.assert_allclose(x[ok], y[ok], rtol=0, atol=ENGINES * scale)


BASELINES = {"iekf": invariant_ekf, "ekf": local_ekf, "ukf-left": ukf_m}


@pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")
@pytest.mark.parametrize("make", list(BASELINES.values()), ids=list(BASELINES))
def test_auto_runs_every_baseline_by_its_c_kernel_as_xla_does(make):
    """The C engine serves the baselines through the filters' one path: engine="auto" builds their kernel, and its
    run (missing samples, held inputs, a gate, a gap) is XLA's to ENGINES, statuses and counters exactly."""
    gated = SensorSystem(R3, _dynamics, (Sensor("pos", lambda g, t: g.x[:1], Noise.sample(POS_STD), gate=0.999),
                                         Sensor("vel", lambda g, t: g.x[1:], Noise.density(VEL_DENSITY))),
                         Noise.density(Q_DENSITY), inputs=("a",))
    ts, us, ys = _log()
    us[20:23] = np.nan
    ys[60, 0] = 1e3
    ts[90:] += 1.0  # one interval longer than the gap threshold
    flt = make(gated)
    state = flt.init(R3(np.array([0.5, -0.3, 0.2])), np.diag([1.0, 2.0, 0.5]))
    assert liemef.engines.kernel(flt, "auto") is not None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        auto, c, xla = (flt.run(state, ts, us, ys, engine=e) for e in ("auto", "c", "xla"))
    assert int(xla.status.code) == 0 and int(xla.status.rejected[0]) >= 1 and int(xla.status.gaps) == 1
    _assert_engines_agree(c, xla)
    _assert_engines_agree(auto, c)


@pytest.mark.slow  # three XLA compilations on SE(2): over a minute
@pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")
def test_on_the_localization_the_c_engine_runs_the_baselines_as_xla_does():
    """On SE(2) (ukfm's localization, sparse GPS): the invariant EKF, the local EKF and the left UKF-M by C and by
    XLA agree to ENGINES; a step by C chains as the run does."""
    c, s, log, g0 = _localization(seconds=2.0)
    K0 = np.diag([c.theta0_std**2, 0.0, 0.0])
    args = (np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys))
    for flt in (invariant_ekf(s.system), local_ekf(s.system), ukf_m(s.system)):
        state = flt.init(g0, K0)
        _assert_engines_agree(flt.run(state, *args, engine="c"), flt.run(state, *args, engine="xla"))
        ts, us, ys = args
        st = state
        for k in range(3):
            st = flt.step(st, ts[k], us[k], ys[k], ts[k + 1] - ts[k], engine="c")
        run = flt.run(state, ts[:4], us[:4], ys[:4], engine="c")
        _assert_engines_agree(st, run.final)
