"""The ready 3D systems: ``pose3d`` on SE(3) and ``inertial_navigation`` on SE_2(3) (x R^6 with biases).

* Their models are the stated kinematics: the left-trivialized dynamics equals ``g^-1 g_dot`` of a closed-form
  trajectory (finite differences), and the outputs are the stated functions.
* Their weights are the documented noise levels in sensor units.
* A filter started from a wrong state converges on synthetic data (fixed seeds), and the C engine's run equals
  the XLA engine's.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef import codegen
from liemef.engines import LogGapWarning
from liemef.groups import SE3, SE23, SO3, Product, Rn
from liemef.simulation import simulate
from liemef.systems import inertial_navigation, pose3d
from liemef.systems import rigid_body_3d as pose3d_module
from tolerances import FINITE_DIFF, ROUNDOFF
from trees import assert_trees_close

W0 = np.array([0.05, -0.03, 0.2])  # the closed-form trajectories' constant body rate (rad/s)


def _rot(t):
    return SO3.exp(t * jnp.asarray(W0))


def _circle(t, r=5.0, w=2 * math.pi / 30):
    """Position, velocity and acceleration of a 5 m circle in 30 s, with a slow climb."""
    c, s = jnp.cos(w * t), jnp.sin(w * t)
    p = jnp.stack([r * s, r * c, 0.1 * t])
    v = jnp.stack([r * w * c, -r * w * s, 0.1 + 0 * t])
    a = jnp.stack([-r * w * w * s, -r * w * w * c, 0 * t])
    return p, v, a


def _ins_truth(t, gravity=9.81):
    """``(g(t), u(t))`` of the closed-form inertial-navigation trajectory: R = exp(t W0), p on the circle,
    u = (W0, R^T (p_ddot - g))."""
    R = _rot(t)
    p, v, a = _circle(t)
    u = jnp.concatenate([jnp.asarray(W0), R.inverse().act(a - jnp.array([0.0, 0.0, -gravity]))])
    return SE23.from_rotation_velocity_position(R, v, p), u


# --- the models ----------------------------------------------------------------------------------------------
def _left_velocity_fd(g_of_t, t, h=1e-5):
    """``g^-1 g_dot`` by central differences of the matrix."""
    M = lambda s: np.asarray(g_of_t(s).as_matrix())  # noqa: E731
    return np.linalg.solve(M(t), (M(t + h) - M(t - h)) / (2 * h))


@pytest.mark.parametrize("biases", [False, True])
def test_ins_dynamics_is_the_imu_kinematics(biases):
    """lambda(g, u) = g^-1 g_dot on the closed-form trajectory whose IMU reads u (with biases added to u and
    stored in the state, the same lambda)."""
    sysm = inertial_navigation(biases=biases)
    b = np.array([0.01, -0.02, 0.03, 0.1, -0.2, 0.3])
    for t in (0.0, 3.7, 12.0):
        g, u = _ins_truth(t)
        if biases:
            state, u = Product[SE23, Rn[6]]((g, Rn[6](b))), u + b
        else:
            state = g
        lam = np.asarray(sysm.dynamics(state, u, t))
        want = _left_velocity_fd(lambda s: _ins_truth(s)[0], t)
        np.testing.assert_allclose(np.asarray(SE23.hat(lam[:9])), want, rtol=0, atol=FINITE_DIFF)
        if biases:
            assert np.all(lam[9:] == 0.0)


def test_pose3d_dynamics_is_the_body_twist():
    sysm = pose3d()
    u = np.array([0.1, -0.2, 0.3, 1.0, 0.5, -0.2])
    g = SE3.exp(np.array([0.4, -0.3, 1.0, 2.0, -1.0, 0.5]))
    np.testing.assert_array_equal(np.asarray(sysm.dynamics(g, u, 0.0)), u)
    step = g.rplus(1e-3 * u)  # p_dot = R v, R_dot = R [omega]
    np.testing.assert_allclose((np.asarray(step.translation()) - np.asarray(g.translation())) / 1e-3,
                               np.asarray(g.rotation().act(u[3:])), atol=1e-3)


def test_outputs_are_the_stated_functions():
    R = SO3.exp(np.array([0.3, -0.5, 0.8]))
    v, p = np.array([1.0, 2.0, -0.5]), np.array([3.0, -4.0, 5.0])
    g = SE23.from_rotation_velocity_position(R, v, p)
    Rm = np.asarray(R.as_matrix())
    lms = np.array([[0.0, 2.0, 2.0], [-2.0, -2.0, -2.0], [2.0, -2.0, -2.0]])
    dip = 1.1
    sysm = inertial_navigation(landmarks=lms, mag_std=0.05, dip=dip, baro_std=0.5)
    assert [s.name for s in sysm.sensors] == ["gnss", "landmarks", "mag", "baro"]
    y = np.asarray(sysm.output(g, 0.0))
    mref = np.array([0.0, math.cos(dip), -math.sin(dip)])
    want = np.concatenate([p, ((lms - p) @ Rm).reshape(-1), Rm.T @ mref, p[2:]])
    np.testing.assert_allclose(y, want, rtol=0, atol=ROUNDOFF)
    sysb = inertial_navigation(biases=True, landmarks=lms, mag_std=0.05, dip=dip, baro_std=0.5)
    gb = Product[SE23, Rn[6]]((g, Rn[6](np.ones(6))))
    np.testing.assert_allclose(np.asarray(sysb.output(gb, 0.0)), want, rtol=0, atol=ROUNDOFF)
    # pose3d: position, then the entries of R row by row; a pose fix perturbs R in the body frame
    gp = SE3.from_rotation_translation(R, p)
    y = np.asarray(pose3d(fixes="pose").output(gp, 0.0))
    np.testing.assert_allclose(y, np.concatenate([p, Rm.reshape(-1)]), rtol=0, atol=ROUNDOFF)
    eps = np.array([0.01, -0.02, 0.03])
    fix = np.asarray(pose3d_module.pose_fix(gp, eps, np.zeros(3)))
    np.testing.assert_allclose(fix[3:].reshape(3, 3), Rm @ np.asarray(SO3.exp(eps).as_matrix()), atol=ROUNDOFF)


def test_weights_are_the_documented_noise_levels():
    sysm = inertial_navigation(gyro_std=0.02, acc_std=0.05, imu_rate=200.0, biases=True, gyro_bias_walk=1e-4,
                               acc_bias_walk=2e-3, gnss_std=(1.0, 1.0, 3.0), landmarks=np.zeros((1, 3)),
                               landmark_std=0.2, mag_std=0.05, baro_std=0.5)
    BBt = np.asarray(sysm.B @ sysm.R @ sysm.B.T)
    want = np.diag(np.concatenate([[0.02**2 / 200] * 3, [0.05**2 / 200] * 3, [0.0] * 3, [1e-8] * 3,
                                   [4e-6] * 3]))
    np.testing.assert_allclose(BBt, want, rtol=ROUNDOFF, atol=0)
    np.testing.assert_allclose(np.diag(np.asarray(sysm.D)),
                               [1.0, 1.0, 3.0, 0.2, 0.2, 0.2, 0.05, 0.05, 0.05, 0.5], rtol=0, atol=0)
    assert all(b.sample for b in sysm.blocks())
    assert sysm.input_names == ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
    assert sysm.state_names[9:] == ("bgx", "bgy", "bgz", "bax", "bay", "baz")
    assert sysm.output_units == ("m",) * 6 + ("1",) * 3 + ("m",)
    # defaults: ukfm's IMU (0.01 rad/s, 0.01 m/s^2 per sample at 100 Hz), GNSS 1 m
    d = inertial_navigation()
    np.testing.assert_allclose(np.diag(np.asarray(d.B @ d.B.T))[:6], [1e-6] * 6, rtol=ROUNDOFF)
    assert d.group is SE23 and [s.name for s in d.sensors] == ["gnss"]
    # pose3d: twist densities, position std, and sqrt(2) sigma per attitude entry
    p = pose3d(twist_std=(0.02, 0.1), twist_rate=50.0, position_std=0.3, attitude_std=0.01, fixes="pose")
    np.testing.assert_allclose(np.diag(np.asarray(p.B @ p.B.T)), [4e-4 / 50] * 3 + [1e-2 / 50] * 3, rtol=ROUNDOFF)
    np.testing.assert_allclose(np.diag(np.asarray(p.D)), [0.3] * 3 + [0.01 * math.sqrt(2)] * 9, rtol=ROUNDOFF)


def test_attitude_entries_carry_the_attitude_information():
    """H^T D^-2 H of the nine entries at any R is I3 / sigma^2: the documented sqrt(2) sigma per entry."""
    sigma = 0.02
    sysm = pose3d(attitude_std=sigma, fixes="pose")
    g = SE3.exp(np.array([0.7, -1.2, 0.4, 1.0, 2.0, 3.0]))
    H = np.asarray(jax.jacfwd(lambda d: sysm.output(g.rplus(d), 0.0))(jnp.zeros(6)))
    info = H.T @ np.asarray(sysm.information()) @ H
    np.testing.assert_allclose(info[:3, :3], np.eye(3) / sigma**2, rtol=ROUNDOFF, atol=ROUNDOFF / sigma**2)


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(gnss_std=None), r"gnss_std, landmarks, mag_std, baro_std: expected at least one sensor"),
    (dict(landmarks=np.zeros((2, 2))), r"landmarks: expected"),
    (dict(gravity=-1.0), r"gravity: expected a gravity magnitude >= 0"),
    (dict(gyro_std=(0.1, 0.1)), r"gyro_std: expected 1 or 3 stds, got 2"),
    (dict(dip=3.0, mag_std=0.1), r"dip: expected a magnetic dip"),
    (dict(gnss_std=0.0), r"std: expected standard deviations > 0"),
])
def test_inertial_navigation_bad_arguments_name_themselves(kwargs, match):
    with pytest.raises(ValueError, match=match):
        inertial_navigation(**kwargs)


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(fixes="orientation"), r"fixes"),
    (dict(twist_std=(0.1, 0.2, 0.3)), r"twist_std: expected 1, 2 \(angular, linear\) or 6 stds, got 3"),
    (dict(fixes="pose", attitude_std=(0.1, 0.2, 0.3)), r"attitude_std: expected one std"),
])
def test_pose3d_bad_arguments_name_themselves(kwargs, match):
    with pytest.raises(ValueError, match=match):
        pose3d(**kwargs)


# --- filters on synthetic data ---------------------------------------------------------------------------------
RATE, DURATION = 100.0, 20.0
LANDMARKS = np.array([[0.0, 2.0, 2.0], [-2.0, -2.0, -2.0], [2.0, -2.0, -2.0]])  # ukfm's


def _ins_input(t):
    return _ins_truth(t)[1]


def _pose_input(t):
    return jnp.array([W0[0], W0[1], W0[2], 1.0, 0.0, 0.2 * jnp.sin(0.5 * t)])


def _thin(ys, every):
    """Keep every ``every``-th measurement row (a sensor at RATE / every), NaN elsewhere and at t = 0."""
    ys = np.array(ys)
    keep = np.zeros(ys.shape[0], bool)
    keep[every::every] = True
    ys[~keep] = np.nan
    return ys


def _scenario(sysm, g0, input_fn, input_std, seed, every):
    ts = np.arange(int(DURATION * RATE) + 1) / RATE
    truth, log = simulate(sysm, g0, input_fn, ts, jax.random.key(seed), input_noise=np.diag(input_std),
                          substeps=4)
    return truth, np.asarray(log.ts), np.asarray(log.us), _thin(log.ys, every)


def _wrong_start(G, g0, rot_deg, pos_m, seed):
    """g0 exp(xi) with a rotation error of rot_deg about a random axis and a position error of pos_m (the last
    three algebra coordinates of SE3 and SE23)."""
    rng = np.random.default_rng(seed)
    u, p_dir = rng.standard_normal(3), rng.standard_normal(3)
    xi = np.zeros(G.tangent_dim)
    xi[:3] = math.radians(rot_deg) * u / np.linalg.norm(u)
    xi[-3:] = pos_m * p_dir / np.linalg.norm(p_dir)
    return g0.rplus(xi)


def _errors(traj, truth):
    """Rotation angle (deg) and position error (m) per sample."""
    est, tru = traj.g_hat, truth.g
    if isinstance(est, Product):
        est, tru = est.factors[0], tru.factors[0]
    rot = np.degrees(np.linalg.norm(np.asarray(est.rotation().rminus(tru.rotation())), axis=-1))
    pos = np.linalg.norm(np.asarray(est.vectors()[..., -1, :] - tru.vectors()[..., -1, :]), axis=-1)
    return rot, pos


def _run(flt, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        return flt.run(*args, **kw)


@pytest.mark.slow  # 110 s on a busy 2-core machine, mostly compiling
def test_inertial_navigation_converges_from_a_wrong_start():
    """ukfm's landmarks at 1 Hz and GNSS at 1 Hz, IMU at 100 Hz: from 30 deg and 2 m off, the second-order filter
    is within 1 deg and 0.3 m over the last 5 s (measured 0.57 deg, 0.19 m; ukfm's filters reach 2.5 deg and
    0.25 m rms on their benchmark, without GNSS and from 15 deg)."""
    sysm = inertial_navigation(landmarks=LANDMARKS)
    g0, _ = _ins_truth(0.0)
    truth, ts, us, ys = _scenario(sysm, g0, _ins_input, [0.01] * 6, seed=0, every=100)
    g0_hat = _wrong_start(SE23, g0, 30.0, 2.0, seed=1)
    K0 = np.diag([0.5**2] * 3 + [0.1**2] * 3 + [2.0**2] * 3)
    flt = liemef.MinimumEnergyFilter(sysm)
    traj = _run(flt, flt.init(g0_hat, K0), ts, us, ys, engine="xla")
    assert bool(traj.ok)
    rot, pos = _errors(traj, truth)
    assert rot[0] > 29.0 and pos[0] > 1.9
    late = ts >= DURATION - 5.0
    assert rot[late].max() < 1.0 and pos[late].max() < 0.3, (rot[late].max(), pos[late].max())


@pytest.mark.slow  # 110 s on a busy 2-core machine, mostly compiling
def test_inertial_navigation_with_biases_converges_and_estimates_them():
    """GNSS (0.5 m) at 10 Hz and a magnetometer at 100 Hz, biased IMU: attitude within 1.5 deg, position within
    0.5 m and the gyro bias within 0.005 rad/s over the last 5 s, from 20 deg, 2 m and zero biases (measured
    0.72 deg and 0.38 m)."""
    sysm = inertial_navigation(biases=True, gnss_std=0.5, mag_std=0.02)
    b = np.array([0.02, -0.015, 0.01, 0.1, -0.05, 0.08])
    g0, _ = _ins_truth(0.0)
    G = sysm.group
    x0 = G((g0, Rn[6](b)))
    truth, ts, us, ys = _scenario(sysm, x0, lambda t: _ins_input(t) + jnp.asarray(b), [0.01] * 6, seed=2,
                                  every=1)
    ys[np.arange(ys.shape[0]) % 10 != 0, :3] = np.nan  # GNSS at 10 Hz, mag at 100 Hz
    ys[0] = np.nan
    g0_hat = G((_wrong_start(SE23, g0, 20.0, 2.0, seed=3), Rn[6](np.zeros(6))))
    K0 = np.diag([0.35**2] * 3 + [0.1**2] * 3 + [2.0**2] * 3 + [0.03**2] * 3 + [0.2**2] * 3)
    flt = liemef.MinimumEnergyFilter(sysm)
    traj = _run(flt, flt.init(g0_hat, K0), ts, us, ys, engine="xla")
    assert bool(traj.ok)
    rot, pos = _errors(traj, truth)
    late = ts >= DURATION - 5.0
    assert rot[late].max() < 1.5 and pos[late].max() < 0.5, (rot[late].max(), pos[late].max())
    b_hat = np.asarray(traj.g_hat.factors[1].x)
    assert np.abs(b_hat[late, :3] - b[:3]).max() < 0.005, np.abs(b_hat[late, :3] - b[:3]).max()


@pytest.mark.slow  # 65 s on a busy 2-core machine, mostly compiling
@pytest.mark.parametrize("fixes", ["position", "pose"])
def test_pose3d_converges_from_a_wrong_start(fixes):
    """Position (or pose) fixes at 10 Hz, twist at 100 Hz: from 30 deg and 2 m off, within 2 deg and 0.1 m over
    the last 5 s."""
    sysm = pose3d(fixes=fixes)
    g0 = SE3.identity()
    truth, ts, us, ys = _scenario(sysm, g0, _pose_input, [0.01] * 3 + [0.05] * 3, seed=4, every=10)
    g0_hat = _wrong_start(SE3, g0, 30.0, 2.0, seed=5)
    K0 = np.diag([0.5**2] * 3 + [2.0**2] * 3)
    flt = liemef.MinimumEnergyFilter(sysm)
    traj = _run(flt, flt.init(g0_hat, K0), ts, us, ys, engine="xla")
    assert bool(traj.ok)
    rot, pos = _errors(traj, truth)
    late = ts >= DURATION - 5.0
    assert rot[late].max() < 2.0 and pos[late].max() < 0.1, (rot[late].max(), pos[late].max())


def _range_inverse(g, t):
    """1 / (the height): infinite, and its derivatives too, on the plane z = 0."""
    return 1.0 / g.translation()[2:3]


@pytest.mark.parametrize("updates", ["hold", "discrete"])
def test_an_interval_without_a_sample_takes_no_output_derivative(updates):
    """Between the samples of a slower sensor no output carries information, so the interval is the prediction
    alone and the outputs are not differentiated there (at 100 Hz against 1 Hz landmarks they were two thirds of
    a step's arithmetic): a sensor whose output is infinite at the estimate leaves such an interval healthy and
    equal to the filter without that sensor; with its sample, the same interval fails as non-finite. (An
    interval with any sample in force differentiates every output.)"""
    from liemef.filters import CAUSES
    from liemef.systems import Noise, Sensor, SensorSystem
    from liemef.systems.rigid_body_3d import position, twist_dynamics

    fix = Sensor("position", position, Noise.sample(0.5), ("x", "y", "z"), ("m",) * 3)
    inverse = Sensor("inverse", _range_inverse, Noise.sample(0.1), ("r",), ("1/m",))
    process = Noise.density(np.full(6, 0.1))
    inputs = pose3d_module.INPUT_NAMES
    with_inverse = SensorSystem(SE3, twist_dynamics, [fix, inverse], process, inputs=inputs)
    without = SensorSystem(SE3, twist_dynamics, [fix], process, inputs=inputs)
    g0 = SE3.from_coords(jnp.array([0.1, -0.2, 0.3, 1.0, 2.0, 0.0]))  # on z = 0: 1/z is infinite
    K0 = np.diag([0.1] * 3 + [1.0] * 3)
    u = np.array([0.1, 0.0, 0.2, 1.0, 0.0, 0.0])
    a = liemef.MinimumEnergyFilter(with_inverse, updates=updates)
    b = liemef.MinimumEnergyFilter(without, updates=updates)
    none = a.step(a.init(g0, K0), 0.0, u, np.full(4, np.nan), 0.01)
    ref = b.step(b.init(g0, K0), 0.0, u, np.full(3, np.nan), 0.01)
    assert bool(none.status.ok), none.status.message()
    assert_trees_close((none.g_hat, none.K), (ref.g_hat, ref.K))
    sampled = a.step(a.init(g0, K0), 0.0, u, np.array([np.nan, np.nan, np.nan, 1.0]), 0.01)
    assert int(sampled.status.code) == CAUSES.NONFINITE.code, sampled.status.message()


# --- both engines --------------------------------------------------------------------------------------------
SYSTEMS_3D = {
    "pose3d-position": lambda: pose3d(),
    "pose3d-pose": lambda: pose3d(fixes="pose"),
    "ins-landmarks": lambda: inertial_navigation(landmarks=LANDMARKS),
    "ins-biases-all-sensors": lambda: inertial_navigation(biases=True, landmarks=LANDMARKS[:2], mag_std=0.05,
                                                          baro_std=0.5),
}


@pytest.mark.slow  # 90-330 s each on a busy 2-core machine: building the C kernel of a 9- or 15-dim interval
@pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")
@pytest.mark.parametrize("name", sorted(SYSTEMS_3D))
def test_c_engine_equals_xla(name):
    """Second order, (0)-connection, RKMK4 with adaptive sub-steps, over 60 IMU samples with sensors at 10 Hz and
    a few missing inputs: the whole trajectory, the final state and the status."""
    sysm = SYSTEMS_3D[name]()
    G = sysm.group
    rng = np.random.default_rng(7)
    g = G.from_coords(jnp.asarray(0.3 * rng.standard_normal(G.coords_dim)))
    n = 60
    ts = np.arange(n) / RATE
    us = 0.2 * rng.standard_normal((n, sysm.input_dim))
    us[:, 5] += 9.81 if sysm.input_dim == 6 and name.startswith("ins") else 0.0
    us[17::23] = np.nan
    ys = np.asarray(sysm.output(g, 0.0)) + 0.05 * rng.standard_normal((n, sysm.output_dim))
    ys[np.arange(n) % 10 != 0] = np.nan
    g0 = G.from_coords(jnp.asarray(np.asarray(g.coords()) + 0.1 * rng.standard_normal(G.coords_dim)))
    flt = liemef.MinimumEnergyFilter(sysm)
    state = flt.init(g0, np.eye(flt.n))
    c, x = _run(flt, state, ts, us, ys, engine="c"), _run(flt, state, ts, us, ys, engine="xla")
    assert bool(x.ok)
    assert_trees_close(c, x)


# --- the ready 3D systems from the command line -----------------------------------------------------------------
def _cli(*args):
    from click.testing import CliRunner

    from liemef.cli import cli

    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.parametrize(("name", "columns"), [
    ("pose3d", "t,omega_x,omega_y,omega_z,v_x,v_y,v_z,position_x,position_y,position_z"),
    ("inertial-navigation", "t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z,gnss_x,gnss_y,gnss_z"),
])
def test_ready_3d_systems_are_named_in_the_cli(name, columns):
    res = _cli("schema", name)
    assert res.exit_code == 0, res.output
    assert f"CSV header: {columns}" in res.output


@pytest.mark.slow  # builds the 9-dim filter's C kernel and its export: 1-2 min on a busy 2-core machine
def test_inertial_navigation_runs_and_exports_from_the_cli(tmp_path):
    """A 20 s log written as CSV (IMU at 100 Hz, GNSS at 1 Hz) filtered by `liemef run --system
    inertial-navigation` with fixes at their own time, from an initial position read off the first fix: the
    estimate ends within 1 m of the truth, and estimates.tum holds one pose per sample; `liemef export-c` writes
    the filter's C."""
    sysm = inertial_navigation()
    g0, _ = _ins_truth(0.0)
    truth, ts, us, ys = _scenario(sysm, g0, _ins_input, [0.01] * 6, seed=8, every=100)
    ys[0] = np.asarray(truth.g.vectors()[0, 1]) + np.array([0.3, -0.2, 0.1])  # a first fix, to start from
    rows = np.column_stack([ts, us, ys])
    header = "t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z,gnss_x,gnss_y,gnss_z"
    np.savetxt(tmp_path / "log.csv", rows, delimiter=",", header=header, comments="", fmt="%.17g")
    # the velocity is known at the start (the rotation vector is read as 0: the truth's attitude here)
    x0 = ",".join(f"{v:.17g}" for v in np.r_[np.zeros(3), np.asarray(g0.vectors()[0]), ys[0]])
    res = _cli("run", "--system", "inertial-navigation", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
               "--x0", x0, "--k0-diag", ",".join(["0.01"] * 3 + ["0.01"] * 3 + ["1"] * 3), "--updates", "discrete",
               "--tum", "--no-progress")
    assert res.exit_code == 0, res.output
    from liemef.reports import io

    t_tum, (positions, _) = io.read_tum(tmp_path / "o" / io.TUM_FILE)
    np.testing.assert_array_equal(t_tum, ts)
    assert np.linalg.norm(positions[-1] - np.asarray(truth.g.vectors()[-1, 1])) < 1.0
    res = _cli("export-c", "--system", "inertial-navigation", "--out", tmp_path / "c")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "c" / "inertial_navigation.c").is_file()
