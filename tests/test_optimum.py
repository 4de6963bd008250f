"""The exact minimum-energy estimate (:mod:`liemef.studies.optimum`): GTSAM's conventions against liemef's, iSAM2's
per-step MAP against the JAX batch solver on prefixes, the linear reduction to the Kalman filter, and the
boundary checks."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef.filters import information_in_force
from liemef.groups import R3, SE2, SO3, TSO3, Rn
from liemef.studies import optimum
from liemef.studies.experiments import localization as loc
from liemef.systems import Noise, Sensor, SensorSystem, System, attitude_gyro_bias, planar_localization

gtsam = pytest.importorskip("gtsam")

ROUNDOFF = 1e-12
"""GTSAM's Pose2/Rot3 operations against liemef's at the same points (float64 formulas, angles < pi)."""
MAP = 1e-6
"""iSAM2 (relinearization threshold 1e-7, updates repeated until none is needed) against the batch
Levenberg-Marquardt minimizer (steps below 1e-10): group distance of the same minimizer found twice."""
KALMAN = 1e-9
"""The batch MAP on a linear system against filterpy's Kalman filter: one exact Gauss-Newton step, the floor
(1e-6 std) far below the process noise."""

PERM = [1, 2, 0]  # GTSAM's Pose2 tangent (x, y, theta) from liemef's (omega, v_x, v_y)


def _pose2_coords(p):
    return np.array([p.theta(), p.x(), p.y()])


def _pose2(g: SE2):
    c = np.asarray(g.coords())
    return gtsam.Pose2(c[1], c[2], c[0])


# --- conventions ----------------------------------------------------------------------------------------------
@jax.jit
def _se2_ops(xi, eta, d):
    a, b = SE2.exp(xi), SE2.exp(eta)
    return a.coords(), a.rplus(d).coords(), (a @ b).coords(), a.between(b).coords(), b.rminus(a)


@jax.jit
def _so3_ops(xi, d):
    return SO3.exp(xi).as_matrix(), SO3.exp(xi).rplus(d).as_matrix(), SO3.exp(xi).log()


def test_pose2_convention_is_liemef_se2():
    """Pose2's Expmap, retract, compose, between, Logmap and localCoordinates are liemef's SE2 exp, rplus, @,
    between and rminus with the tangent reordered (x, y, theta) <-> (omega, v_x, v_y)."""
    rng = np.random.default_rng(0)
    xi, eta, d = rng.uniform(-2.5, 2.5, (3, 20, 3))
    exp, rplus, comp, betw, rminus = map(np.asarray, _se2_ops(xi, eta, d))
    for i in range(20):
        pa, pb = gtsam.Pose2.Expmap(xi[i, PERM]), gtsam.Pose2.Expmap(eta[i, PERM])
        np.testing.assert_allclose(_pose2_coords(pa), exp[i], atol=ROUNDOFF)
        np.testing.assert_allclose(_pose2_coords(pa.retract(d[i, PERM])), rplus[i], atol=ROUNDOFF)
        np.testing.assert_allclose(_pose2_coords(pa.compose(pb)), comp[i], atol=ROUNDOFF)
        np.testing.assert_allclose(_pose2_coords(pa.between(pb)), betw[i], atol=ROUNDOFF)
        np.testing.assert_allclose(gtsam.Pose2.Logmap(pa.between(pb)), rminus[i, PERM], atol=1e-10)
        np.testing.assert_allclose(pa.localCoordinates(pb), rminus[i, PERM], atol=1e-10)


def test_rot3_convention_is_liemef_so3():
    """Rot3's Expmap, retract (body-frame perturbation) and Logmap are liemef's SO3 exp, rplus and log."""
    rng = np.random.default_rng(1)
    xi, d = rng.uniform(-1.5, 1.5, (2, 20, 3))
    exp, rplus, log = map(np.asarray, _so3_ops(xi, d))
    for i in range(20):
        R = gtsam.Rot3.Expmap(xi[i])
        np.testing.assert_allclose(R.matrix(), exp[i], atol=ROUNDOFF)
        np.testing.assert_allclose(R.retract(d[i]).matrix(), rplus[i], atol=ROUNDOFF)
        np.testing.assert_allclose(gtsam.Rot3.Logmap(R), log[i], atol=1e-10)


# --- localization: iSAM2 per step against the batch solver on prefixes --------------------------------------
@pytest.fixture(scope="module")
def localization_log():
    """A 4 s ukfm-style log: 100 Hz odometry, a fix every 0.5 s, 45 deg initial heading error, exact position
    (the scenario's draws and log, with its truth in closed form: theta_n = n omega dt, p_n a polygon)."""
    c = loc.LocalizationConfig(duration=4.0, gps_period=0.5, steady=0.0)
    n = np.arange(c.n_states)
    vx, _, w = loc.true_input(c)
    theta = n * w * c.dt
    steps = vx * c.dt * np.stack([np.cos(theta), np.sin(theta)], 1)
    p = np.concatenate([np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)])
    truth = SE2.from_coords(np.concatenate([theta[:, None], p], 1))
    log, g0 = loc.sensor_log(c, truth, loc.jax_draws(c, jax.random.key(3)))
    vstd, lstd, wstd = c.odometry_std
    system = planar_localization(odometry_std=(wstd, vstd, lstd), odometry_rate=1.0 / c.dt, gps_std=c.gps_std)
    P0 = np.diag([c.theta0_std**2, 0.0, 0.0])
    return system, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys), g0, P0, truth


@pytest.fixture(scope="module")
def localization_isam2(localization_log):
    system, ts, us, ys, g0, P0, _ = localization_log
    return optimum.map_estimates(system, ts, us, ys, g0, P0)


@pytest.mark.parametrize("k", [260, 301, 351, 400])
def test_isam2_localization_is_the_batch_map_of_each_prefix(localization_log, localization_isam2, k):
    """iSAM2's estimate at step k is the last state of the batch minimizer of the log truncated at k (both use
    the samples before t_k): fixes at 250, 300 and 350 included, the one at 400 not yet."""
    system, ts, us, ys, g0, P0, _ = localization_log
    m = localization_isam2
    assert m.g.batch_shape == (ts.size,) and "iSAM2" in m.solver
    b = optimum.batch_map(system, ts[: k + 1], us[: k + 1], ys[: k + 1], g0, P0)
    assert bool(b.converged) and "levenberg-marquardt" in b.solver
    assert float(optimum.distance(m.g[k], b.last)) < MAP
    if k == ts.size - 1:  # the whole log: the smoothed trajectories agree too
        assert float(jnp.max(optimum.distance(m.smoothed, b.g))) < MAP


def test_isam2_dogleg_and_every_give_the_same_estimates(localization_log, localization_isam2):
    """Powell's dogleg steps, and estimates at every 50th step only, give the same minimizers."""
    system, ts, us, ys, g0, P0, _ = localization_log
    m = optimum.map_estimates(system, ts, us, ys, g0, P0, solver="isam2-dogleg", every=50)
    idx = np.append(np.arange(0, ts.size, 50), ts.size - 1)  # and the last
    np.testing.assert_array_equal(np.asarray(m.ts), ts[idx])
    assert float(jnp.max(optimum.distance(m.g, localization_isam2.g[idx]))) < MAP


def test_map_beats_dead_reckoning_and_improves_with_fixes(localization_log, localization_isam2):
    """A sanity check of the model: after the fixes, the MAP's heading error to the truth is far below the
    initial 45 deg-scale error."""
    *_, truth = localization_log
    d = jax.jit(optimum.distance_components)(truth, localization_isam2.g)
    assert float(d["heading"][0]) > 0.05
    assert float(d["heading"][-1]) < 0.1


# --- the linear reduction: the per-step MAP is the Kalman filter's prediction ---------------------------------
A = np.array([[0.0, 1.0], [-0.5, -0.2]])
G = np.array([[0.0], [1.0]])
Q_DENSITY = np.array([0.3, 0.5])
SIGMA = 0.4
DT = 0.05


def _linear(g, u, t):
    return jnp.asarray(A) @ g.x + jnp.asarray(G) @ u


def _position(g, t):
    return g.x[:1]


@pytest.mark.parametrize("meaning", ["sample", "density"])
def test_linear_system_map_is_the_kalman_filter(meaning):
    """On x_{k+1} = x_k + (A x_k + G u_k) dt + w_k, w_k ~ N(0, diag(q^2) dt), the MAP of x_k given the samples
    before t_k is filterpy's prior x_{k|k-1} (update with y_k, predict with u_k), and the batch Laplace
    covariance of the last state is its P; a density sensor of std s weighs dt / s^2 per interval."""
    from filterpy.kalman import KalmanFilter

    noise = Noise.sample(SIGMA) if meaning == "sample" else Noise.density(SIGMA)
    system = SensorSystem(Rn[2], _linear, (Sensor("pos", _position, noise),), Noise.density(Q_DENSITY),
                          inputs=("a",))
    rng = np.random.default_rng(2)
    N = 41
    ts = np.arange(N) * DT
    us = rng.standard_normal((N, 1))
    ys = np.full((N, 1), np.nan)
    ys[::3, 0] = rng.standard_normal(ys[::3].shape[0])
    x0, P0 = np.array([0.5, -0.3]), np.diag([1.0, 2.0])
    m = optimum.map_estimates(system, ts, us, ys, Rn[2](x0), P0, solver="jax", every=4)

    kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=1)
    kf.x, kf.P, kf.H = x0.copy(), P0.copy(), np.array([[1.0, 0.0]])
    kf.R = np.array([[SIGMA**2 if meaning == "sample" else SIGMA**2 / DT]])
    kf.F, kf.B, kf.Q = np.eye(2) + A * DT, G * DT, np.diag(Q_DENSITY**2) * DT
    priors = [x0.copy()]
    for k in range(N - 1):
        if np.isfinite(ys[k, 0]):
            kf.update(ys[k])
        kf.predict(u=us[k])
        priors.append(kf.x.copy())
    np.testing.assert_allclose(np.asarray(m.g.x), np.array(priors)[::4], atol=KALMAN)
    b = optimum.batch_map(system, ts, us, ys, Rn[2](x0), P0)
    np.testing.assert_allclose(np.asarray(b.last.x), priors[-1], atol=KALMAN)
    np.testing.assert_allclose(np.asarray(b.P_last), kf.P, rtol=1e-8, atol=KALMAN)


def _still(g, u, t):
    return jnp.zeros(3)


def _identity_output(g, t):
    return g.x


def test_measurement_weights_are_information_in_force():
    """The cost's W_k is the filter's information in force over the interval times dt_k, with a correlated
    measurement noise, a missing component and mixed sample / density sensors."""
    D = np.array([[0.5, 0.0, 0.0], [0.2, 0.7, 0.0], [0.1, -0.1, 0.3]])
    system = System(group_type=Rn[3], dynamics_fn=_still, output_fn=_identity_output, B=np.eye(3), D=D,
                    Q=np.eye(3), R=np.eye(3))
    ts = np.array([0.0, 0.1, 0.35, 0.4])
    ys = np.array([[1.0, np.nan, 2.0], [1.0, 1.0, 1.0], [np.nan, np.nan, np.nan], [0.0, 0.0, 0.0]])
    dts, _, W = optimum._weights(system, ts, ys, optimum.FLOOR_STD)
    sample = jnp.zeros(3, bool)
    for k in range(3):
        ref = information_in_force(system.information(), sample, jnp.isfinite(jnp.asarray(ys[k])), dts[k]) * dts[k]
        np.testing.assert_allclose(W[k], ref, atol=ROUNDOFF)


# --- attitude with gyro bias ----------------------------------------------------------------------------------
def _imu_log(system, N=61, rate=100.0, seed=0):
    rng = np.random.default_rng(seed)
    ts = np.arange(N) / rate
    w = np.stack([0.5 * np.sin(ts), 0.3 * np.cos(0.7 * ts), 0.4 + 0.0 * ts], 1)
    R = [np.eye(3)]
    for k in range(N - 1):
        R.append(R[-1] @ np.asarray(SO3.exp(w[k] / rate).as_matrix()))
    R = np.array(R)
    us = w + np.array([0.01, -0.02, 0.015]) + 0.005 * rng.standard_normal((N, 3))
    ys = np.concatenate([np.einsum("kji,j->ki", R, np.array(s.fn.v)) for s in system.sensors], 1)
    ys += np.concatenate([0.02 * rng.standard_normal((N, 3)), 0.05 * rng.standard_normal((N, 3))], 1)
    ys[1::3, 3:] = np.nan  # the magnetometer at two thirds of the rate
    return ts, us, ys


def test_isam2_attitude_is_the_batch_map_of_each_prefix():
    """Rot3 + bias variables with gyro and direction factors: iSAM2's estimate at k is the last state of the
    batch minimizer of the prefix, in rotation and bias."""
    system = attitude_gyro_bias(imu_rate=100.0)
    ts, us, ys = _imu_log(system)
    g0 = TSO3((SO3.exp(jnp.array([0.1, -0.05, 0.2])), R3(jnp.zeros(3))))
    P0 = np.diag([0.05**2] * 3 + [0.03**2] * 3)
    m = optimum.map_estimates(system, ts, us, ys, g0, P0, every=20)
    assert "Rot3" in m.solver
    for i, k in ((2, 40), (3, 60)):
        assert float(m.ts[i]) == ts[k]
        b = optimum.batch_map(system, ts[: k + 1], us[: k + 1], ys[: k + 1], g0, P0)
        d = optimum.distance_components(m.g[i], b.last)
        assert bool(b.converged)
        assert float(d["total"]) < MAP and float(d["0.angle"]) < MAP and float(d["1.norm"]) < MAP


# --- distances ------------------------------------------------------------------------------------------------
def test_distances():
    """distance(g, g exp(xi)) = |xi|; SE(2) components; the summary's windows."""
    rng = np.random.default_rng(4)
    a, xi = rng.uniform(-1, 1, (5, 3)), 0.3 * rng.standard_normal((5, 3))
    g, h, d = jax.jit(lambda a, xi: (SE2.exp(a), SE2.exp(a).rplus(xi),
                                     optimum.distance_components(SE2.exp(a), SE2.exp(a).rplus(xi))))(a, xi)
    np.testing.assert_allclose(d["total"], np.linalg.norm(xi, axis=1), atol=ROUNDOFF)
    np.testing.assert_allclose(d["heading"], np.abs(xi[:, 0]), atol=ROUNDOFF)
    np.testing.assert_allclose(d["position"], np.linalg.norm(h.translation() - g.translation(), axis=1),
                               atol=ROUNDOFF)
    s = optimum.distance_summary(np.arange(5.0), d, steady=3.0)
    assert s["heading"]["t>=3"]["mean"] == pytest.approx(float(np.mean(np.abs(xi[3:, 0]))))
    assert s["position"]["all"]["max"] == pytest.approx(float(np.max(d["position"])))
    assert set(s) == {"total", "heading", "position"}


# --- bad input ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_log():
    system = planar_localization()
    N = 5
    ts = np.arange(N) * 0.01
    us = np.tile([1.0, 0.0, 0.1], (N, 1))
    ys = np.full((N, 2), np.nan)
    return system, ts, us, ys, SE2.identity(), np.diag([0.1, 0.0, 0.0])


@pytest.mark.parametrize("fn", [optimum.map_estimates, optimum.batch_map])
@pytest.mark.parametrize(("change", "name"), [
    (lambda a: {**a, "us": a["us"][:, :2]}, "us"),
    (lambda a: {**a, "us": np.where(np.arange(5)[:, None] == 2, np.nan, a["us"])}, "us"),
    (lambda a: {**a, "ys": a["ys"][:-1]}, "ys"),
    (lambda a: {**a, "ys": np.full((5, 2), np.inf)}, "ys"),
    (lambda a: {**a, "ts": a["ts"][::-1]}, "ts"),
    (lambda a: {**a, "P0": np.diag([0.1, -1.0, 0.0])}, "P0"),
    (lambda a: {**a, "P0": np.eye(2)}, "P0"),
    (lambda a: {**a, "g0": SO3.identity()}, "g0"),
    (lambda a: {**a, "g0": SE2.identity((2,))}, "g0"),
])
def test_bad_input_names_the_argument(small_log, fn, change, name):
    system, ts, us, ys, g0, P0 = small_log
    args = change({"system": system, "ts": ts, "us": us, "ys": ys, "g0": g0, "P0": P0})
    with pytest.raises(ValueError, match=f"^{name}:"):
        fn(**args)


def test_bad_solver_and_system(small_log):
    system, ts, us, ys, g0, P0 = small_log
    with pytest.raises(ValueError, match="^solver:"):
        optimum.map_estimates(system, ts, us, ys, g0, P0, solver="ceres")
    with pytest.raises(ValueError, match="^every:"):
        optimum.map_estimates(system, ts, us, ys, g0, P0, every=0)
    with pytest.raises(ValueError, match="^floor_std:"):
        optimum.batch_map(system, ts, us, ys, g0, P0, floor_std=-1.0)
    other = SensorSystem(SE2, lambda g, u, t: jnp.stack([u[2], u[0], u[1]]),
                         (Sensor("gps", lambda g, t: g.translation(), Noise.sample(1.0), ("x", "y")),),
                         Noise.density([0.01, 0.01, 0.01]), inputs=("v_x", "v_y", "omega"))
    with pytest.raises(ValueError, match="^system:"):
        optimum.map_estimates(other, ts, us, ys, g0, P0)
    with pytest.raises(ValueError, match="^init:"):
        optimum.batch_map(system, ts, us, ys, g0, P0, init=SE2.identity((3,)))


@pytest.mark.slow
def test_isam2_on_the_40_s_scenario_is_the_batch_map():
    """The ukfm scenario (seed 0, 4000 steps): iSAM2's last estimate and smoothed trajectory are the batch
    minimizer's."""
    c = loc.LocalizationConfig()
    s = loc.setup(c)
    log, g0 = loc.sensor_log(c, s.truth, loc.jax_draws(c, jax.random.key(0)))
    args = (s.system, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys), g0,
            np.diag([c.theta0_std**2, 0.0, 0.0]))
    m = optimum.map_estimates(*args)
    b = optimum.batch_map(*args)
    assert bool(b.converged)
    assert float(optimum.distance(m.g[-1], b.last)) < MAP
    assert float(jnp.max(optimum.distance(m.smoothed, b.g))) < MAP
