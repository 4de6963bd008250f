"""Attitude with gyro bias on TSO(3) from an IMU (liemef.systems.attitude_bias): the weights its noise levels
give, its helpers (dip, TRIAD, logs), a synthetic fast-rotation log, and BROAD trial 01 (real data, skipped when
absent)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from liemef.filters import CAUSES, MinimumEnergyFilter
from liemef.groups import R3, SO3, TSO3
from liemef.metrics import attitude_error
from liemef.studies import datasets
from liemef.systems import Noise, attitude_gyro_bias
from liemef.systems import attitude_bias as ab
from liemef.systems import imu_rest as ab_rest
from tolerances import ROUNDOFF

OK = CAUSES.OK.code

RATE = ab.IMU_RATE
K0 = np.diag([0.05**2] * 3 + [0.02**2] * 3)
"""(0.05 rad)^2 on the rotation, (0.02 rad/s)^2 on the bias (the synthetic bias has norm 0.027 rad/s)."""


# --- the model and its weights ---------------------------------------------------------------------------------
def test_weights_follow_the_documented_noise_mapping():
    s = attitude_gyro_bias(gyro_std=0.004, imu_rate=200.0, bias_walk=2e-4, acc_std=0.03, mag_std=0.07,
                           dip=math.radians(60.0))
    # B = diag(gyro sample std / sqrt(rate), bias walk density), R = I; D = diag(direction stds), Q = I
    np.testing.assert_allclose(s.B, np.diag([0.004 / math.sqrt(200.0)] * 3 + [2e-4] * 3), rtol=ROUNDOFF)
    np.testing.assert_allclose(s.R, np.eye(6), rtol=0, atol=0)
    np.testing.assert_allclose(s.D, np.diag([0.03] * 3 + [0.07] * 3), rtol=ROUNDOFF)
    np.testing.assert_allclose(s.Q, np.eye(6), rtol=0, atol=0)
    assert [(b.name, b.start, b.stop, b.sample) for b in s.blocks()] == [("acc", 0, 3, True), ("mag", 3, 6, True)]
    assert s.input_names == ("gyro_x", "gyro_y", "gyro_z")
    assert s.output_names == ("acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z")
    assert s.state_names == ("rx", "ry", "rz", "bx", "by", "bz")
    # a gyro density (imu_rate=None) is used as given; "density" directions are held at the IMU rate
    np.testing.assert_allclose(attitude_gyro_bias(gyro_std=3e-4, imu_rate=None).B[0, 0], 3e-4, rtol=ROUNDOFF)
    held = attitude_gyro_bias(acc_std=0.02, mag_std=0.05, directions="density")
    np.testing.assert_allclose(held.D, np.diag([0.02 / math.sqrt(RATE)] * 3 + [0.05 / math.sqrt(RATE)] * 3),
                               rtol=ROUNDOFF)
    assert [b.sample for b in held.blocks()] == [False, False]
    # new noise levels keep the structure (no recompilation)
    louder = s.with_noise(acc=Noise.sample(0.1))
    np.testing.assert_allclose(louder.D[0, 0], 0.1, rtol=ROUNDOFF)


def test_defaults_are_the_documented_ones():
    s = attitude_gyro_bias()
    np.testing.assert_allclose(np.diag(s.B), [0.005 / math.sqrt(285.714)] * 3 + [1e-4] * 3, rtol=ROUNDOFF)
    np.testing.assert_allclose(np.diag(s.D), [0.02] * 3 + [0.05] * 3, rtol=ROUNDOFF)
    # the mag sensor's reference direction carries the default dip
    g = TSO3.identity()
    np.testing.assert_allclose(s.output(g, 0.0), [0, 0, 1, 0, math.cos(ab.DIP), -math.sin(ab.DIP)], atol=ROUNDOFF)


def test_dynamics_and_outputs():
    s = attitude_gyro_bias(dip=0.3)
    R = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    b = np.array([0.01, -0.02, 0.03])
    g = TSO3((SO3.from_matrix(jnp.asarray(R)), R3(jnp.asarray(b))))
    u = np.array([1.0, 2.0, -3.0])
    np.testing.assert_allclose(s.dynamics(g, u, 0.0), np.concatenate([u - b, np.zeros(3)]), atol=ROUNDOFF)
    m_ref = np.array([0.0, math.cos(0.3), -math.sin(0.3)])
    np.testing.assert_allclose(s.output(g, 0.0), np.concatenate([R.T @ [0, 0, 1], R.T @ m_ref]), atol=ROUNDOFF)


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(dip=2.0), "dip"), (dict(dip=float("nan")), "dip"), (dict(directions="held"), "directions"),
    (dict(directions="density", imu_rate=None), "imu_rate"), (dict(acc_std=0.0), "std"),
    (dict(gyro_std=(0.1, 0.2)), "gyro_std"), (dict(acc_gate=1.5), "gate"),
])
def test_bad_arguments_name_themselves(kwargs, match):
    with pytest.raises(ValueError, match=match):
        attitude_gyro_bias(**kwargs)


# --- helpers ------------------------------------------------------------------------------------------------------
def _directions(R, dip):
    up = np.einsum("nji,j->ni", R, np.array(ab.E_UP))
    mag = np.einsum("nji,j->ni", R, np.array(ab.magnetic_reference(dip)))
    return up, mag


def test_dip_triad_initial_estimate_and_measured_state():
    rng = np.random.default_rng(3)
    R = Rotation.random(50, random_state=4).as_matrix()
    dip = math.radians(66.0)
    up, mag = _directions(R, dip)
    acc, field = 9.81 * up, 43.0 * mag  # any units
    assert ab_rest.magnetic_dip(acc, field) == pytest.approx(dip, abs=1e-12)
    np.testing.assert_allclose(ab_rest.triad(acc, field), R, atol=1e-12)
    g = ab_rest.initial_estimate(acc[:1], field[:1], bias=(0.1, 0.2, 0.3))
    np.testing.assert_allclose(g.factors[0].as_matrix(), R[0], atol=1e-12)
    np.testing.assert_allclose(g.factors[1].x, [0.1, 0.2, 0.3])
    # measured state: the rotation vector where both directions are present, NaN elsewhere and for the bias
    ys = np.concatenate([up, mag], axis=1)
    ys[5, 4] = np.nan
    q = ab.measured_state(ys)
    np.testing.assert_allclose(Rotation.from_rotvec(q[:5, :3]).as_matrix(), R[:5], atol=1e-12)
    assert np.isnan(q[5]).all() and np.isnan(q[:, 3:]).all() and np.isfinite(q[6:, :3]).all()
    # a log from raw columns: uniform clock, normalized directions, a zero vector is missing
    gyr = rng.standard_normal((50, 3))
    acc[7] = 0.0
    ts, us, ys2 = ab.imu_log(gyr, acc, field, 200.0, t0=1.0)
    np.testing.assert_allclose(ts, 1.0 + np.arange(50) / 200.0, rtol=ROUNDOFF)
    np.testing.assert_array_equal(us, gyr)
    assert np.isnan(ys2[7, :3]).all() and np.isfinite(ys2[7, 3:]).all()
    ok = np.arange(50) != 7
    np.testing.assert_allclose(np.linalg.norm(ys2[ok, :3], axis=1), 1.0, rtol=ROUNDOFF)
    with pytest.raises(ValueError, match="rate"):
        ab.imu_log(gyr, acc, field, 0.0)
    with pytest.raises(ValueError, match="mag"):
        ab.imu_log(gyr, acc, field[:10], 200.0)
    with pytest.raises(ValueError, match="acc, mag"):
        ab_rest.initial_estimate([0.0, 0.0, 1.0], [0.0, 0.0, 2.0])


def test_attitude_error_is_the_rotation_angle():
    A = Rotation.random(20, random_state=1)
    small = Rotation.from_rotvec(np.outer(np.geomspace(1e-9, 3.0, 20), [0.6, 0.0, 0.8]))
    e = attitude_error(A.as_matrix(), (small * A).as_matrix())
    np.testing.assert_allclose(e, small.magnitude(), rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("azimuth_deg", [0.0, 178.5])
def test_the_field_against_the_reference_finds_a_turn_and_a_dip_that_last(azimuth_deg):
    """A field that turns by 3 deg about the vertical and steepens by 2 deg in motion, seen by a body in random
    attitudes: the offsets come back exactly, across the azimuth's wrap; nothing where no reference is."""
    from liemef.metrics import field_against_reference

    def field(az, dip):
        az, dip = np.radians(az), np.radians(dip)
        return 45.0 * np.array([np.cos(dip) * np.cos(az), np.cos(dip) * np.sin(az), np.sin(dip)])

    n, rest_n = 400, 100
    ref = Rotation.random(n, random_state=3)
    world = np.where(np.arange(n)[:, None] < rest_n, field(azimuth_deg, -68.0), field(azimuth_deg + 3.0, -70.0))
    mag = ref.inv().apply(world)  # body = R^T world
    quat = ref.as_quat()[:, [3, 0, 1, 2]]
    rest, moving = np.arange(n) < rest_n, np.arange(n) >= rest_n
    got = field_against_reference(mag, quat, rest, moving)
    assert got["azimuth"] == pytest.approx(3.0, abs=1e-9) and got["azimuth_p90"] == pytest.approx(3.0, abs=1e-9)
    assert got["dip"] == pytest.approx(-2.0, abs=1e-9)
    agree = field_against_reference(ref.inv().apply(np.tile(field(azimuth_deg, -68.0), (n, 1))), quat, rest, moving)
    assert max(abs(v) for v in agree.values()) < 1e-9
    quat[:rest_n] = np.nan  # no reference at rest: nothing to compare with
    assert field_against_reference(mag, quat, rest, moving) == {"azimuth": None, "azimuth_p90": None, "dip": None}


# --- a synthetic fast-rotation log -------------------------------------------------------------------------------
def simulate(duration=30.0, w_max=17.0, seed=0, fine=16):
    """A 286 Hz IMU log of a body turning at up to ``w_max`` rad/s (|omega|) with a constant gyro bias: the truth
    integrated with ``fine`` exact exponential steps per sample; gyro samples = the rate at the sample time +
    bias + noise; noisy unit directions; every noise level at the system's default."""
    rng = np.random.default_rng(seed)
    N = int(duration * RATE) + 1
    ts = np.arange(N) / RATE
    freq = np.array([0.31, 0.23, 0.17])

    def omega(t):
        return np.stack([np.sin(2 * np.pi * freq[0] * t), np.sin(2 * np.pi * freq[1] * t + 1.0),
                         np.cos(2 * np.pi * freq[2] * t)], axis=-1)

    h = 1.0 / RATE / fine
    tf = ts[:-1, None] + (np.arange(fine) + 0.5) * h       # midpoints of the fine steps, (N - 1, fine)
    scale = w_max / np.linalg.norm(omega(tf), axis=-1).max()
    step = Rotation.identity(N - 1)
    for j in range(fine):
        step = step * Rotation.from_rotvec(scale * omega(tf[:, j]) * h)
    step = step.as_matrix()
    R = np.empty((N, 3, 3))
    R[0] = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    for k in range(N - 1):
        R[k + 1] = R[k] @ step[k]
    b = np.array([0.02, -0.015, 0.01])
    us = scale * omega(ts) + b + ab.GYRO_STD * rng.standard_normal((N, 3))
    up, mag = _directions(R, ab.DIP)
    a = up + ab.ACC_STD * rng.standard_normal((N, 3))
    m = mag + ab.MAG_STD * rng.standard_normal((N, 3))
    ys = np.concatenate([a / np.linalg.norm(a, axis=1, keepdims=True), m / np.linalg.norm(m, axis=1, keepdims=True)],
                        axis=1)
    return ts, us, ys, R, b


@pytest.fixture(scope="module")
def synthetic():
    ts, us, ys, R, b = simulate()
    assert np.linalg.norm(us - b, axis=1).max() == pytest.approx(17.0, abs=0.1)
    xi0 = 0.05 * np.array([1.0, -1.0, 1.0]) / math.sqrt(3.0)                 # 2.9 deg off, bias unknown
    g0 = TSO3((SO3.from_matrix(jnp.asarray(R[0] @ Rotation.from_rotvec(xi0).as_matrix())), R3(jnp.zeros(3))))
    return ts, us, ys, R, b, g0


def _errors(traj, R, b):
    e = np.degrees(attitude_error(R, np.asarray(traj.g_hat.factors[0].as_matrix())))
    eb = np.linalg.norm(np.asarray(traj.g_hat.factors[1].x) - b, axis=1)
    return e, eb


def _check_converged(traj, R, b, ts):
    assert traj.status.ok, traj.status.message(ts)
    assert np.isfinite(np.asarray(traj.K)).all()
    e, eb = _errors(traj, R, b)
    last20 = ts >= ts[-1] - 20.0
    # measured (RKMK4, auto sub-steps): final 1.30 deg, rms over the last 20 s 1.22 deg; bias error 0.027 rad/s
    # at the start, 0.0005 at the end. The attitude error is mostly the lag of a held sample against a state that
    # turns 3.4 deg per interval at 17 rad/s (with directions="density" and interpolation="linear": 0.10 deg).
    assert e[-1] < 3.0
    assert np.sqrt(np.mean(e[last20] ** 2)) < 2.0
    assert eb[-1] < 0.1 * eb[0]
    return e, eb


def test_synthetic_fast_rotation_default_filter(synthetic):
    ts, us, ys, R, b, g0 = synthetic
    flt = MinimumEnergyFilter(attitude_gyro_bias())   # second order, (0)-connection, RKMK4, substeps="auto"
    traj = flt.run(flt.init(g0, K0), ts, us, ys)
    _check_converged(traj, R, b, ts)
    assert int(traj.status.substeps_max) > 1          # the first samples needed sub-steps


@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "engine: Lie-Euler loses positive definiteness of K at 17 rad/s (interval 34) although substeps='auto' keeps "
    "||K E|| h and ||A|| h below 0.5; presumably the explicit step K + h (A K + K A' + ...) misses the h^2 A K A' "
    "of the exact flow, more than K's smallest eigenvalue once K is strongly correlated; it passes with 64 fixed "
    "sub-steps (test below) and with RKMK4"))
def test_synthetic_fast_rotation_lie_euler(synthetic):
    ts, us, ys, R, b, g0 = synthetic
    flt = MinimumEnergyFilter(attitude_gyro_bias(), integrator="lie-euler")
    _check_converged(flt.run(flt.init(g0, K0), ts, us, ys), R, b, ts)


@pytest.mark.slow
def test_synthetic_fast_rotation_lie_euler_with_small_steps(synthetic):
    ts, us, ys, R, b, g0 = synthetic
    flt = MinimumEnergyFilter(attitude_gyro_bias(), integrator="lie-euler", substeps=64)
    _check_converged(flt.run(flt.init(g0, K0), ts, us, ys), R, b, ts)


@pytest.mark.slow
def test_interpolated_directions_remove_the_lag_of_held_samples(synthetic):
    # measured: final 0.063 deg, rms over the last 20 s 0.096 deg (the default filter: 1.30 and 1.22 deg)
    ts, us, ys, R, b, g0 = synthetic
    flt = MinimumEnergyFilter(attitude_gyro_bias(directions="density"), interpolation="linear")
    traj = flt.run(flt.init(g0, K0), ts, us, ys)
    e, _ = _check_converged(traj, R, b, ts)
    assert np.sqrt(np.mean(e[ts >= ts[-1] - 20.0] ** 2)) < 0.3


def test_one_step_per_sample_fails_where_sub_steps_succeed(synthetic):
    # With K0 = (0.05 rad)^2 and 1/0.02^2 of information per acc sample, ||K E|| dt is about 10 on the first
    # interval: one explicit RKMK4 step per sample (the papers' scheme) is unstable there; measured: K loses
    # positive definiteness over interval 0.
    ts, us, ys, R, b, g0 = synthetic
    flt = MinimumEnergyFilter(attitude_gyro_bias(), substeps=1)
    traj = flt.run(flt.init(g0, K0), ts, us, ys)
    assert int(traj.status.code) != OK
    assert int(traj.status.index) == 0
    assert np.isnan(np.asarray(traj.K)[1:]).all()


# --- real data: BROAD trial 01 (Laidig et al. 2021, CC BY 4.0) -------------------------------------------------
REALDATA = datasets.realdata_dir()


def _broad_path(trial):
    if REALDATA is None:
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    path = datasets.broad_trials().get(trial)
    if path is None:
        pytest.skip(f"real data absent: BROAD trial {trial} not found in {REALDATA}")
    return path


def broad_errors(trial: datasets.BroadTrial, traj) -> tuple[float, float]:
    """Total and inclination rms (deg) over BROAD's movement mask where the optical truth is present."""
    ok = trial.movement & ~np.isnan(trial.quat_true).any(axis=1)
    R_true = np.asarray(ab.quaternion_to_tso3(trial.quat_true[ok]).factors[0].as_matrix())
    R_hat = np.asarray(traj.g_hat.factors[0].as_matrix())[ok]
    total = attitude_error(R_true, R_hat)
    incl = np.arccos(np.clip(np.einsum("ni,ni->n", R_hat[:, 2, :], R_true[:, 2, :]), -1.0, 1.0))
    rms = lambda x: float(np.degrees(np.sqrt(np.mean(x**2))))  # noqa: E731
    return rms(total), rms(incl)


def test_broad_trial_01_first_minute():
    # Measured on the first 60 s (34 s of rest, then slow rotation): total rms 3.69 deg, inclination 0.43 deg
    # (BROAD's Madgwick / Mahony baselines over the whole trial: 2.3 / 3.4 deg; this filter over the whole trial:
    # 2.35 deg). Compilation takes most of this test's time.
    trial = datasets.broad(_broad_path("01")).head(60.0)
    k = ab_rest.initial_rest(trial.gyr, trial.acc, trial.rate)  # from the IMU alone
    dip = ab_rest.magnetic_dip(trial.acc[:k], trial.mag[:k])
    assert math.degrees(dip) == pytest.approx(71.3, abs=0.1)
    log = datasets.broad_to_log(trial)
    flt = MinimumEnergyFilter(attitude_gyro_bias(dip=dip))
    g0 = ab_rest.initial_estimate(trial.acc[:50], trial.mag[:50])
    traj = flt.run(flt.init(g0, np.diag([0.05**2] * 3 + [0.01**2] * 3)), log.ts, log.us, log.ys, keep_every=1)
    assert traj.status.ok, traj.status.message(log.ts)
    total, incl = broad_errors(trial, traj)
    assert total < 4.5
    assert incl < 1.0
    # the z gyro bias seen at rest (0.0082 rad/s) is found
    assert float(traj.g_hat.factors[1].x[-1, 2]) == pytest.approx(trial.gyr[:k, 2].mean(), abs=0.003)


# --- the initial rest, from the IMU alone ------------------------------------------------------------------------
def _rest_then_motion(rate=100.0, rest_s=3.0, total_s=6.0, seed=0):
    """A log at rest (gyro bias 0.01 rad/s and noise, accelerometer noise 0.05 m/s^2) until ``rest_s``, then a
    rotation at 1 rad/s about x: gyro, accelerometer, magnetometer and the switch's sample."""
    rng = np.random.default_rng(seed)
    N, k = int(total_s * rate), int(rest_s * rate)
    w = np.zeros((N, 3))
    w[k:, 0] = 1.0
    R = Rotation.from_rotvec(np.cumsum(w, axis=0) / rate)
    gyr = w + 0.01 + 0.005 * rng.standard_normal((N, 3))
    acc = R.inv().apply([0.0, 0.0, 9.81]) + 0.05 * rng.standard_normal((N, 3))
    mag = R.inv().apply([0.0, 16.0, -40.0]) + 0.3 * rng.standard_normal((N, 3))
    return gyr, acc, mag, k


def test_initial_rest_ends_within_a_window_before_the_motion():
    rate = 100.0
    gyr, acc, mag, k = _rest_then_motion(rate)
    for window in (0.3, 0.5, 1.0):
        found = ab_rest.initial_rest(gyr, acc, rate, window=window)
        assert k - window * rate <= found <= k, window
    # an acceleration alone (no turn) ends the rest too: the accelerometer's spread
    acc2 = np.tile([0.0, 0.0, 9.81], (gyr.shape[0], 1))
    acc2[k:, 0] = 2.0
    assert k - 50 <= ab_rest.initial_rest(np.zeros_like(gyr), acc2, rate) <= k
    c = ab_rest.rest_constants(gyr, acc, mag, rate)
    assert c["rest_samples"] == ab_rest.initial_rest(gyr, acc, rate) and c["rest_s"] == c["rest_samples"] / rate
    assert c["gravity"] == pytest.approx(9.81, abs=0.05) and c["field"] == pytest.approx(math.hypot(16, 40), abs=0.3)
    assert math.degrees(c["dip"]) == pytest.approx(math.degrees(math.atan2(40, 16)), abs=0.5)
    # missing rows are skipped; a log at rest throughout is all rest, which the caller sees
    gyr[10:20] = np.nan
    assert k - 50 <= ab_rest.initial_rest(gyr, acc, rate) <= k
    assert ab_rest.initial_rest(gyr[: k - 10], acc[: k - 10], rate) == k - 10


def test_initial_rest_refuses_a_log_that_does_not_start_at_rest_by_name():
    rate = 100.0
    gyr, acc, _, k = _rest_then_motion(rate)
    with pytest.raises(ValueError, match=r"^gyr, acc: expected a log that starts at rest .* got 1\.0"):
        ab_rest.initial_rest(gyr[k:], acc[k:], rate)
    with pytest.raises(ValueError, match=r"^gyr, acc: expected a log of at least one window \(50 samples"):
        ab_rest.initial_rest(gyr[:10], acc[:10], rate)
    with pytest.raises(ValueError, match=r"^acc: expected shape \(600, 3\)"):
        ab_rest.initial_rest(gyr, acc[:-1], rate)
    for name, kw, words in (("rate", {"rate": 0.0}, "a sample rate > 0 in Hz"),
                            ("window", {"window": -1.0}, "a duration > 0 in s"),
                            ("gyro_tol", {"gyro_tol": math.nan}, "a tolerance > 0 in rad/s"),
                            ("acc_tol", {"acc_tol": True}, "a tolerance > 0 in m/s\\^2")):
        args = {"rate": rate, **kw}
        with pytest.raises(ValueError, match=f"^{name}: expected {words}"):
            ab_rest.initial_rest(gyr, acc, args.pop("rate"), **args)


@pytest.mark.parametrize("trial", ["01", "07", "10", "16", "24", "28", "33"])
def test_initial_rest_of_broad_ends_just_before_its_movement_annotation(trial):
    """The rest found from the IMU alone ends before BROAD's first annotated movement (the annotation is read here
    only to check it) and less than one window (0.5 s) before it."""
    tr = datasets.broad(_broad_path(trial))
    k = ab_rest.initial_rest(tr.gyr, tr.acc, tr.rate)
    first_movement = int(np.argmax(tr.movement))
    assert first_movement - ab_rest.REST_WINDOW * tr.rate <= k <= first_movement
