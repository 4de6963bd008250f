"""The Madgwick and Mahony filters of ``ahrs`` as liemef baselines (liemef.filters.baselines._ahrs): their frames
against
ahrs's own references, the sample convention against ahrs called directly, tracking on a noise-free synthetic
log, missing samples, the failure status, bad inputs, and BROAD (real data, skipped when absent): a short slice by
default, BROAD's published per-trial numbers in a slow test."""

import dataclasses
import math

import ahrs
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from liemef.filters import CAUSES, FilterState
from liemef.filters.baselines._ahrs import Madgwick, Mahony, quat_mul
from liemef.groups import R3, SO3, TSO3
from liemef.metrics import attitude_error
from liemef.studies import datasets
from liemef.systems import Noise, Sensor, SensorSystem, attitude_gyro_bias, planar_localization
from liemef.systems import attitude_bias as ab
from tolerances import ROUNDOFF

NONFINITE, OK = CAUSES.NONFINITE.code, CAUSES.OK.code

RATE = 100.0
DIP = ab.DIP
SYSTEM = attitude_gyro_bias(dip=DIP)
FILTERS = {"madgwick": lambda s=SYSTEM, **kw: Madgwick(s, **kw), "mahony": lambda s=SYSTEM, **kw: Mahony(s, **kw)}
REALDATA = datasets.realdata_dir()


def _tso3(R, b):
    q = Rotation.from_matrix(R).as_quat()[..., [3, 0, 1, 2]]
    return TSO3((SO3(jnp.asarray(q)), R3(jnp.asarray(np.broadcast_to(b, q.shape[:-1] + (3,))))))


def _outputs(system, g):
    """The system's own output maps at every state of a batch: noise-free acc and mag directions."""
    return np.asarray(jax.vmap(lambda gg: system.output(gg, 0.0))(g))


def _angle_deg(R_true, g_hat):
    return np.degrees(attitude_error(R_true, np.asarray(g_hat.factors[0].as_matrix())))


def simulate(duration=15.0, bias=(0.0, 0.0, 0.0), w_max=2.0):
    """A noise-free IMU log at RATE Hz: the truth turns at the gyro sample's rate over each interval (exact
    exponential steps, liemef's sample convention), gyro = rate + constant bias, acc and mag from the system's
    output maps."""
    N = int(duration * RATE) + 1
    ts = np.arange(N) / RATE
    f = np.array([0.31, 0.23, 0.17])
    w = w_max / math.sqrt(3.0) * np.stack([np.sin(2 * np.pi * f[0] * ts), np.sin(2 * np.pi * f[1] * ts + 1.0),
                                           np.cos(2 * np.pi * f[2] * ts)], axis=1)
    steps = Rotation.from_rotvec(w[:-1] / RATE).as_matrix()
    R = np.empty((N, 3, 3))
    R[0] = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    for k in range(N - 1):
        R[k + 1] = R[k] @ steps[k]
    b = np.asarray(bias, dtype=np.float64)
    ys = _outputs(SYSTEM, _tso3(R, b))
    return ts, w + b, ys, R


@pytest.fixture(scope="module")
def log():
    return simulate()


def _off(R, angle_deg, axis):
    """R turned by ``angle_deg`` about the world ``axis`` (an initial error)."""
    return Rotation.from_rotvec(math.radians(angle_deg) * np.asarray(axis) / np.linalg.norm(axis)).as_matrix() @ R


# --- frames -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "north"), [("madgwick", (1.0, 0.0)), ("mahony", (0.0, 1.0))])
def test_converted_truth_matches_ahrs_references(name, north, log):
    # ahrs's quaternions are sensor -> earth with earth z up; Madgwick's magnetometer reference is (b_x, 0, b_z)
    # (north on +x: north-west-up), Mahony's (0, b_xy, b_z) (north on +y: ENU). At the converted truth the
    # measured directions must be exactly the references each ahrs filter builds.
    flt = FILTERS[name]()
    _, _, ys, R = log                                  # directions from the system's output maps, 1501 attitudes
    R, ys = R[::75], ys[::75]
    g = _tso3(R, np.zeros(3))
    for k in range(R.shape[0]):
        q_ahrs, _ = flt._split(g[k])
        D = ahrs.Quaternion(q_ahrs).to_DCM()                     # ahrs: v_earth = D v_sensor
        np.testing.assert_allclose(D.T @ [0.0, 0.0, 1.0], ys[k, 0:3], atol=ROUNDOFF)
        field = D @ ys[k, 3:6]
        np.testing.assert_allclose(field, [*(math.cos(DIP) * np.asarray(north)), -math.sin(DIP)], atol=ROUNDOFF)
    # and back: liemef -> ahrs -> liemef is the identity
    q_ahrs, b = flt._split(g)
    np.testing.assert_allclose(flt._join(q_ahrs, b).factors[0].wxyz, g.factors[0].wxyz, atol=ROUNDOFF)


def test_mahony_at_the_truth_is_pure_gyro_propagation(log):
    # noise-free directions at the converted truth: Mahony's error e (measured x estimated) vanishes, so one step
    # is the gyro step (a sign or frame error would give a correction of order k_P * dt)
    ts, us, ys, R = log
    flt = Mahony(SYSTEM, k_P=5.0, k_I=1.0)
    s0 = flt.init(_tso3(R[7], np.array([0.01, -0.02, 0.03])))
    dt = ts[8] - ts[7]
    full = flt.step(s0, ts[7], us[7] + [0.01, -0.02, 0.03], ys[7], dt)
    gyro = flt.step(s0, ts[7], us[7] + [0.01, -0.02, 0.03], np.full(6, np.nan), dt)
    np.testing.assert_allclose(full.g_hat.factors[0].wxyz, gyro.g_hat.factors[0].wxyz, atol=1e-14)
    np.testing.assert_allclose(full.g_hat.factors[1].x, [0.01, -0.02, 0.03], atol=1e-14)
    assert _angle_deg(R[8], full.g_hat)[()] < 1e-4


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_a_heading_error_is_corrected_in_the_right_direction(name):
    # at rest, 10 deg of heading error: every step turns the estimate back (a frame error of 90 deg about up would
    # turn it away, or along the wrong axis)
    R = Rotation.from_rotvec([0.2, -0.4, 0.9]).as_matrix()
    y = np.asarray(SYSTEM.output(_tso3(R, np.zeros(3)), 0.0))
    flt = FILTERS[name]()
    state = flt.init(_tso3(_off(R, 10.0, [0, 0, 1]), np.zeros(3)))
    errors = [10.0]
    for k in range(40):
        state = flt.step(state, k / RATE, np.zeros(3), y, 1 / RATE)   # exactly-zero gyro: still corrected
        errors.append(float(_angle_deg(R, state.g_hat)))
    assert np.all(np.diff(errors) < 0)
    assert errors[-1] < 9.9


# --- the sample convention: ahrs called directly ------------------------------------------------------------------
def test_madgwick_run_is_ahrs_updates_of_each_sample_over_its_interval(log):
    ts, us, ys, R = log
    n = 300
    flt = Madgwick(SYSTEM, gain=0.1)
    g0 = _tso3(_off(R[0], 20.0, [1, 1, 0]), np.zeros(3))
    traj = flt.run(flt.init(g0), ts[:n], us[:n], ys[:n])
    # state k + 1 = ahrs update of state k with sample k and dt = ts[k+1] - ts[k], in ahrs's north-west-up frame
    c = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
    q = quat_mul(c * [1, -1, -1, -1], np.asarray(g0.factors[0].wxyz))
    ref = ahrs.filters.Madgwick(gain=0.1)
    Q = [q]
    for k in range(n - 1):
        q = ref.updateMARG(q, us[k], ys[k, :3], ys[k, 3:], dt=ts[k + 1] - ts[k])
        Q.append(q)
    np.testing.assert_allclose(traj.g_hat.factors[0].wxyz, quat_mul(c, np.array(Q)), atol=ROUNDOFF)
    np.testing.assert_array_equal(traj.g_hat.factors[1].x, 0.0)
    # step() is run() one interval at a time
    state = flt.init(g0)
    for k in range(5):
        state = flt.step(state, ts[k], us[k], ys[k], ts[k + 1] - ts[k])
    np.testing.assert_allclose(state.g_hat.factors[0].wxyz, traj.g_hat.factors[0].wxyz[5], atol=ROUNDOFF)
    assert int(state.status.steps) == 5
    # keep_every, as the minimum-energy filter's run
    thin = flt.run(flt.init(g0), ts[:n], us[:n], ys[:n], keep_every=7)
    np.testing.assert_array_equal(thin.ts, ts[:n:7])
    np.testing.assert_array_equal(thin.g_hat.factors[0].wxyz, traj.g_hat.factors[0].wxyz[::7])
    np.testing.assert_array_equal(thin.final.g_hat.factors[0].wxyz, traj.g_hat.factors[0].wxyz[-1])


def test_mahony_run_is_ahrs_batch_mode_shifted_by_one_sample(log):
    # ahrs's batch mode reaches Q[t] with sample t; liemef reaches state k + 1 with sample k: the same updates
    ts, us, ys, R = log
    n, b0 = 300, np.array([0.01, 0.0, -0.01])
    flt = Mahony(SYSTEM, k_P=1.5, k_I=0.5)
    g0 = _tso3(_off(R[0], 20.0, [1, 1, 0]), b0)
    traj = flt.run(flt.init(g0), ts[:n], us[:n], ys[:n])
    shift = lambda a: np.concatenate([a[:1], a[:-1]])  # noqa: E731
    ref = ahrs.filters.Mahony(gyr=shift(us[:n]), acc=shift(ys[:n, :3]), mag=shift(ys[:n, 3:]), frequency=RATE,
                              k_P=1.5, k_I=0.5, q0=np.asarray(g0.factors[0].wxyz), b0=b0.copy())
    np.testing.assert_allclose(traj.g_hat.factors[0].wxyz, ref.Q, atol=1e-12)
    np.testing.assert_allclose(traj.g_hat.factors[1].x[-1], ref.b, atol=1e-12)   # the integral term is the bias
    # with broad_indexing, run is ahrs's batch mode itself: state k from sample k (BROAD's indexing)
    flt = Mahony(SYSTEM, k_P=1.5, k_I=0.5, broad_indexing=True)
    traj = flt.run(flt.init(g0), ts[:n], us[:n], ys[:n])
    ref = ahrs.filters.Mahony(gyr=us[:n], acc=ys[:n, :3], mag=ys[:n, 3:], frequency=RATE, k_P=1.5, k_I=0.5,
                              q0=np.asarray(g0.factors[0].wxyz), b0=b0.copy())
    np.testing.assert_allclose(traj.g_hat.factors[0].wxyz, ref.Q, atol=1e-12)
    np.testing.assert_allclose(traj.g_hat.factors[1].x[-1], ref.b, atol=1e-12)
    with pytest.raises(ValueError, match="^broad_indexing:"):
        Madgwick(SYSTEM, broad_indexing="yes")


# --- tracking on synthetic data -----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_tracks_a_noise_free_synthetic_log_from_the_truth(name, log):
    # ahrs's default gains, up to 2 rad/s. Measured: Madgwick (0.041) 0.047 deg at most (its normalized gradient
    # step dithers about the truth), Mahony (1.0, 0.3) 0.0033 deg.
    ts, us, ys, R = log
    flt = FILTERS[name]()
    traj = flt.run(flt.init(_tso3(R[0], np.zeros(3))), ts, us, ys)
    assert traj.status.ok, traj.status.message(ts)
    assert traj.g_hat.batch_shape == (ts.shape[0],) and traj.K.shape == (ts.shape[0], 6, 6)
    np.testing.assert_array_equal(traj.K, 0.0)
    assert _angle_deg(R, traj.g_hat).max() < 0.2


@pytest.mark.parametrize(("name", "gains"), [("madgwick", {}), ("mahony", {"k_P": 10.0, "k_I": 0.0})])
def test_converges_from_30_degrees_off(name, gains, log):
    # Mahony corrects heading slowly at a 68 deg dip (the field's horizontal part is cos(68 deg) = 0.37 of it):
    # from 30 deg off, ahrs's defaults (1.0, 0.3) are still 6 deg off after 14 s, (3, 0) 1.6 deg. Measured over
    # the last 2 s: Madgwick (0.041) 0.024 deg, Mahony (10, 0) 0.003 deg.
    ts, us, ys, R = log
    flt = FILTERS[name](**gains)
    traj = flt.run(flt.init(_tso3(_off(R[0], 30.0, [1, -2, 3]), np.zeros(3))), ts, us, ys)
    e = _angle_deg(R, traj.g_hat)
    assert e[0] == pytest.approx(30.0, abs=1e-6)
    assert e[ts >= ts[-1] - 2.0].max() < 0.2


def test_mahony_estimates_a_constant_gyro_bias():
    # ahrs's integral term has liemef's sign (u = omega + b, lambda = u - b): it is the state's bias. Measured after
    # 15 s with k_P = 2, k_I = 1: bias 2.4 % off, attitude 0.03 deg (ahrs's defaults (1, 0.3): 12 %, 0.38 deg).
    b = np.array([0.02, -0.015, 0.01])
    ts, us, ys, R = simulate(bias=b)
    flt = Mahony(SYSTEM, k_P=2.0, k_I=1.0)
    traj = flt.run(flt.init(_tso3(R[0], np.zeros(3))), ts, us, ys)
    b_hat = np.asarray(traj.g_hat.factors[1].x)
    assert np.linalg.norm(b_hat[-1] - b) < 0.05 * np.linalg.norm(b)
    assert _angle_deg(R, traj.g_hat)[-1] < 0.1


def _so3_system():
    """Attitude alone on SO(3): gyro input, the same acc and mag directions."""
    def direction(v):
        return lambda g, t: g.as_matrix().T @ jnp.asarray(v)
    sensors = (Sensor("acc", direction(ab.E_UP), Noise.sample(0.02), ("x", "y", "z")),
               Sensor("mag", direction(ab.magnetic_reference(DIP)), Noise.sample(0.05), ("x", "y", "z")))
    return SensorSystem(SO3, lambda g, u, t: u, sensors, Noise.density(0.01), inputs=("gx", "gy", "gz"))


def test_an_so3_system_works_and_madgwick_holds_a_given_bias(log):
    ts, us, ys, R = log
    so3 = _so3_system()
    traj = Madgwick(so3).run(Madgwick(so3).init(SO3(jnp.asarray(Rotation.from_matrix(R[0]).as_quat()[[3, 0, 1, 2]]))),
                             ts, us, ys)
    assert isinstance(traj.g_hat, SO3) and traj.status.ok
    assert np.degrees(attitude_error(R[-1], np.asarray(traj.g_hat.as_matrix())[-1])) < 0.3
    # Madgwick on TSO3 with a bias in g0: subtracted from every gyro sample, never changed
    b = np.array([0.05, 0.0, -0.05])
    flt = Madgwick(SYSTEM)
    traj = flt.run(flt.init(_tso3(R[0], b)), ts, us + b, ys)
    np.testing.assert_array_equal(traj.g_hat.factors[1].x, np.broadcast_to(b, (ts.shape[0], 3)))
    assert _angle_deg(R, traj.g_hat)[-1] < 0.3


# --- missing samples and failures ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_missing_samples(name, log):
    ts, us, ys, R = log
    n, b0 = 200, np.array([0.01, -0.02, 0.005])
    flt = FILTERS[name]()
    s0 = flt.init(_tso3(R[0], b0))
    # no direction at all: Euler propagation with u - b (ahrs's integration), the bias untouched
    traj = flt.run(s0, ts[:n], us[:n], np.full((n, 6), np.nan))
    q = np.asarray(s0.g_hat.factors[0].wxyz)
    for k in range(n - 1):
        q = q + 0.5 * quat_mul(q, [0.0, *(us[k] - b0)]) * (ts[k + 1] - ts[k])
        q = q / np.linalg.norm(q)
    np.testing.assert_allclose(traj.g_hat.factors[0].wxyz[-1], q, atol=1e-12)
    np.testing.assert_allclose(traj.g_hat.factors[1].x, np.broadcast_to(b0, (n, 3)), atol=0.0)
    # acc missing, mag present: the same (ahrs has no magnetometer-only update)
    acc_gone = ys[:n].copy()
    acc_gone[:, 1] = np.nan
    np.testing.assert_array_equal(flt.run(s0, ts[:n], us[:n], acc_gone).g_hat.factors[0].wxyz,
                                  traj.g_hat.factors[0].wxyz)
    # mag missing: gravity alone, i.e. the filter of an acc-only log differs from the full one in heading only
    mag_gone = ys[:n].copy()
    mag_gone[50:, 3:] = np.nan
    full = flt.run(s0, ts[:n], us[:n], ys[:n])
    part = flt.run(s0, ts[:n], us[:n], mag_gone)
    np.testing.assert_array_equal(part.g_hat.factors[0].wxyz[:51], full.g_hat.factors[0].wxyz[:51])
    assert part.status.ok and not np.array_equal(part.g_hat.factors[0].wxyz[-1], full.g_hat.factors[0].wxyz[-1])
    up_part = np.asarray(part.g_hat.factors[0].as_matrix())[:, 2, :]
    up_full = np.asarray(full.g_hat.factors[0].as_matrix())[:, 2, :]
    np.testing.assert_allclose(up_part, up_full, atol=2e-3)


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_an_overflowing_quaternion_is_a_failure_value(name, log):
    ts, us, ys, R = log
    n, k = 100, 40
    us = us[:n].copy()
    us[k] = [1e300, 0.0, 0.0]                       # finite, so accepted; the quaternion update overflows
    flt = FILTERS[name]()
    traj = flt.run(flt.init(_tso3(R[0], np.zeros(3))), ts[:n], us, ys[:n])
    st = traj.status
    assert int(st.code) == NONFINITE and int(st.index) == k and float(st.time) == ts[k]
    assert int(st.steps) == k + 1 and not st.ok
    q = np.asarray(traj.g_hat.factors[0].wxyz)
    assert np.isfinite(q[:k + 1]).all() and np.isnan(q[k + 1:]).all()
    assert np.isnan(np.asarray(traj.K)[k + 1:]).all() and (np.asarray(traj.K)[:k + 1] == 0).all()
    np.testing.assert_array_equal(traj.final.g_hat.factors[0].wxyz, q[k])
    assert f"interval {k}" in st.message(ts)
    # online: the failing step returns its input state, failed; later steps leave it unchanged
    state = flt.init(_tso3(R[0], np.zeros(3)))
    for j in range(k + 3):
        state = flt.step(state, ts[j], us[j], ys[j], ts[j + 1] - ts[j])
    assert int(state.status.code) == NONFINITE and int(state.status.index) == k
    np.testing.assert_allclose(state.g_hat.factors[0].wxyz, q[k], atol=ROUNDOFF)
    # a run from a failed state stays failed and NaN
    again = flt.run(traj.final, ts[:5], us[:5], ys[:5])
    assert int(again.status.code) == NONFINITE and np.isnan(np.asarray(again.g_hat.factors[0].wxyz)[1:]).all()


# --- bad inputs ---------------------------------------------------------------------------------------------------
def test_bad_systems_and_gains_raise_value_errors_naming_the_argument():
    acc_only = SensorSystem(TSO3, SYSTEM.dynamics_fn, SYSTEM.sensors[:1], SYSTEM.process_noise,
                            inputs=("gx", "gy", "gz"))
    with pytest.raises(ValueError, match=r"^system: expected sensors 'acc' and 'mag'.*got sensors \['acc \(3\)'\]"):
        Madgwick(acc_only)
    with pytest.raises(ValueError, match=r"^system: expected an attitude system on SO3 or TSO3, got one on SE2"):
        Mahony(planar_localization())
    with pytest.raises(ValueError, match=r"^system: expected a liemef attitude system"):
        Madgwick("attitude")
    east = Sensor("mag", ab.BodyDirection((1.0, 0.0, 0.0)), Noise.sample(0.05), ("x", "y", "z"))
    wrong = SensorSystem(TSO3, SYSTEM.dynamics_fn, (SYSTEM.sensors[0], east), SYSTEM.process_noise,
                         inputs=("gx", "gy", "gz"))
    with pytest.raises(ValueError, match=r"^system: expected 'acc' to read the world up .* pointing north"):
        Madgwick(wrong)
    for bad in (0.0, -0.1, math.nan, math.inf, "0.1", True):
        with pytest.raises(ValueError, match=r"^gain: expected a finite number > 0, got"):
            Madgwick(SYSTEM, gain=bad)
        with pytest.raises(ValueError, match=r"^k_P: expected a finite number > 0, got"):
            Mahony(SYSTEM, k_P=bad)
    with pytest.raises(ValueError, match=r"^k_I: expected a finite number >= 0, got -0.1"):
        Mahony(SYSTEM, k_I=-0.1)
    assert Mahony(SYSTEM, k_I=0.0).k_I == 0.0                         # BROAD's grid includes Ki = 0
    with pytest.raises(ValueError, match=r"^k_I: expected 0 on an SO3 system"):
        Mahony(_so3_system())


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_bad_logs_and_states_raise_value_errors_naming_the_argument(name, log):
    ts, us, ys, R = log
    ts, us, ys = ts[:10], us[:10].copy(), ys[:10]
    flt = FILTERS[name]()
    s0 = flt.init(_tso3(R[0], np.zeros(3)))
    bad_us = us.copy()
    bad_us[3, 1] = np.nan
    cases = [
        (lambda: flt.run(s0, ts, us[:, :2], ys), r"^us: expected shape \(10, 3\), got \(10, 2\)"),
        (lambda: flt.run(s0, ts, us[:9], ys), r"^us: expected shape \(10, 3\), got \(9, 3\)"),
        (lambda: flt.run(s0, ts, bad_us, ys), r"^us: expected finite values, got nan at index \(3, 1\)"),
        (lambda: flt.run(s0, ts, us, ys[:, :5]), r"^ys: expected shape \(10, 6\), got \(10, 5\)"),
        (lambda: flt.run(s0, ts, us, np.where(ys > 0.5, np.inf, ys)), r"^ys: expected finite values or NaN"),
        (lambda: flt.run(s0, ts[::-1], us, ys), r"^ts: expected strictly increasing"),
        (lambda: flt.run(s0, ts[:1], us[:1], ys[:1]), r"^ts: expected at least 2 time stamps, got 1"),
        (lambda: flt.run("state", ts, us, ys), r"^state: expected a FilterState"),
        (lambda: flt.run(s0, ts, us, ys, keep_every=0), r"^keep_every: expected an integer >= 1, got 0"),
        (lambda: flt.init(SO3.identity()), r"^g0: expected an element of .*, got SO3"),
        (lambda: flt.init(_tso3(R[:2], np.zeros(3))), r"^g0: expected a single element"),
        (lambda: flt.init(_tso3(R[0], np.zeros(3)), K0=np.eye(3)), r"^K0: expected shape \(6, 6\)"),
        (lambda: flt.step(s0, 0.0, [0.0, np.nan, 0.0], ys[0], 0.01), r"^u: expected finite values"),
        (lambda: flt.step(s0, 0.0, us[0], ys[0, :3], 0.01), r"^y: expected shape \(6,\)"),
        (lambda: flt.step(s0, 0.0, us[0], ys[0], 0.0), r"^dt: expected a finite time step > 0, got 0.0"),
        (lambda: flt.step(s0, math.nan, us[0], ys[0], 0.01), r"^t: expected a finite time"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()
    assert isinstance(flt.init(_tso3(R[0], np.zeros(3)), K0=np.eye(6)), FilterState)
    assert flt.has_covariance is False and flt.name == name
    assert int(s0.status.code) == OK and s0.status.rejected.shape == (2,)


# --- BROAD (Laidig et al. 2021, CC BY 4.0; skipped when the data are absent) ---------------------------------------
def _broad(trial):
    if REALDATA is None:
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    path = datasets.broad_trials().get(trial)
    if path is None:
        pytest.skip(f"real data absent: BROAD trial {trial} not found in {REALDATA}")
    return datasets.broad(path)


def broad_errors(q_est, q_ref, mask):
    """BROAD's total / heading / inclination rms (deg) over ``mask`` where the truth is present: the error
    quaternion q_est q_ref^-1 in the world frame (BROAD's ``calculateRMSE``, the data README's loader)."""
    ok = mask & ~np.isnan(q_ref).any(axis=1) & ~np.isnan(q_est).any(axis=1)
    e = quat_mul(q_est[ok], q_ref[ok] * [1.0, -1.0, -1.0, -1.0])
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    w, z = np.abs(e[:, 0]), e[:, 3]
    total = 2 * np.arccos(np.clip(w, 0, 1))
    heading = 2 * np.arctan(np.abs(z) / np.maximum(w, 1e-12))
    incl = 2 * np.arccos(np.clip(np.hypot(w, z), 0, 1))
    return tuple(float(np.degrees(np.sqrt(np.mean(x**2)))) for x in (total, heading, incl))


def _slice(trial, t0, t1):
    k = (trial.ts >= t0) & (trial.ts < t1)
    return dataclasses.replace(trial, **{f.name: getattr(trial, f.name)[k] for f in dataclasses.fields(trial)
                                         if f.name not in ("rate", "name")})


def broad_start(trial):
    """BROAD's example code's start: ``quatFromAccMag`` of the first acc and mag samples (its Madgwick/Mahony
    frame, north on +x) turned to ENU. It is not the first sample's TRIAD attitude (:func:`ab_rest.initial_estimate`):
    on trial 01 it is 4.7 deg from the truth, TRIAD 2.6 deg (it builds the earth -> sensor rotation where the
    filters want sensor -> earth, which is close only near the identity, where the trials start)."""
    z, m = trial.acc[0], trial.mag[0]
    x = np.cross(np.cross(z, -m), z)
    y = np.cross(z, x)
    R = np.column_stack([x / np.linalg.norm(x), y / np.linalg.norm(y), z / np.linalg.norm(z)])
    q = Rotation.from_matrix(R).as_quat()[[3, 0, 1, 2]]
    return ab.quaternion_to_tso3(quat_mul([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], q))


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_broad_fast_rotation_slice(name):
    # trial 07 from 25 s to 33 s (the first movement starts at 26.5 s, up to 24 rad/s), from the true attitude at
    # the slice's start, BROAD's gains. Measured total / heading / inclination rms over the movement samples:
    #   liemef's convention (state k at ts[k], after samples 0..k-1): Madgwick 4.34 / 1.22 / 4.17 deg,
    #                                                                  Mahony   4.22 / 1.28 / 4.03 deg;
    #   BROAD's (the estimate after sample k at ts[k] = state k + 1):   Madgwick 2.70 / 1.00 / 2.51 deg,
    #                                                                  Mahony   2.59 / 1.06 / 2.36 deg.
    # At 24 rad/s one sample is 4.8 deg: on this IMU the gyro sample k describes the rotation up to ts[k]. A wrong
    # frame conversion (90 deg about up) would show as a heading error near 90 deg.
    tr = _slice(_broad("07"), 25.0, 33.0)
    log = datasets.broad_to_log(tr)
    assert not np.isnan(tr.quat_true[0]).any() and tr.movement.mean() > 0.8
    flt = FILTERS[name](**{"madgwick": {"gain": 0.12}, "mahony": {"k_P": 0.74, "k_I": 0.0012}}[name])
    traj = flt.run(flt.init(ab.quaternion_to_tso3(tr.quat_true[0])), log.ts, log.us, log.ys)
    assert traj.status.ok, traj.status.message(log.ts)
    q = np.asarray(traj.g_hat.factors[0].wxyz)
    total, heading, incl = broad_errors(q, tr.quat_true, tr.movement)
    assert total < 5.0 and heading < 2.0 and incl < 5.0
    total_b, heading_b, incl_b = broad_errors(q[1:], tr.quat_true[:-1], tr.movement[:-1])
    assert total_b < 3.2 and heading_b < 1.5 and incl_b < 3.0


BROAD_GAINS = {"madgwick": {"gain": 0.12}, "mahony": {"k_P": 0.74, "k_I": 0.0012}}
"""BROAD's TAGP gains (the best common ones over its 39 trials)."""
PUBLISHED = {"01": {"madgwick": 2.3, "mahony": 3.4}, "07": {"madgwick": 5.0, "mahony": 5.2},
             "24": {"madgwick": 1.8, "mahony": 2.1}}
"""BROAD's published total rms (deg) with those gains (``example_code/out/*_average_rmse.json``)."""
MEASURED = {"01": {"madgwick": 3.256, "mahony": 3.422}, "07": {"madgwick": 4.507, "mahony": 5.233},
            "24": {"madgwick": 2.002, "mahony": 2.146}}
"""This wrapper in BROAD's setup (:func:`test_broad_published_numbers`), total rms (deg)."""


@pytest.mark.slow
@pytest.mark.parametrize("trial", ["01", "07", "24"])
@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_broad_published_numbers(trial, name):
    # BROAD's setup: its start (broad_start), bias 0, the estimate after the update with sample k compared with
    # the truth at k (= this trajectory's state k + 1), movement samples only. ahrs's Mahony is step for step
    # Madgwick's C code that BROAD runs (checked to 2e-16, up to the frame), and reproduces the published numbers
    # to their rounding. ahrs's Madgwick is that C code with twice its magnetometer reference: the C code computes
    # sqrt(h_x^2 + h_y^2) into a variable named _2bx and uses it as 2 b_x (Madgwick's report, eq. (29)), which
    # halves the field it predicts; ahrs follows the report. The magnetometer then weighs twice as much against
    # the accelerometer in ahrs's gradient, and the numbers differ (01: 3.26 against 2.3 deg).
    tr = _broad(trial)
    log = datasets.broad_to_log(tr)
    flt = FILTERS[name](**BROAD_GAINS[name])
    traj = flt.run(flt.init(broad_start(tr)), log.ts, log.us, log.ys)
    assert traj.status.ok
    q = np.asarray(traj.g_hat.factors[0].wxyz)
    total, _, _ = broad_errors(q[1:], tr.quat_true[:-1], tr.movement[:-1])
    assert total == pytest.approx(MEASURED[trial][name], abs=0.01)
    if name == "mahony":
        assert total == pytest.approx(PUBLISHED[trial][name], abs=0.05 + 1e-9)
