"""The IMU noise model (liemef.systems.attitude_imu): the heteroscedastic direction sensors against the plain
model on a synthetic log whose truth is known (linear-acceleration bursts, a magnetic disturbance, a field whose
dip is off), the model's factors in closed form, and its parameters as leaves."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from imu_motion import turning
from liemef.filters import MinimumEnergyFilter
from liemef.groups import R3, SO3, TSO3
from liemef.metrics import attitude_error
from liemef.systems import attitude_bias as ab
from liemef.systems import attitude_gyro_bias, attitude_imu
from liemef.systems import bounded_velocity as ab_vel
from liemef.systems import imu_noise as ab_imu

RATE = 100.0
G = 9.81
B = 43.0
K0 = np.diag([0.05**2] * 3 + [0.01**2] * 3)


def simulate(seed=0, duration=40.0, bursts=True, magnet=True):
    """A 100 Hz IMU log: a body turning at about 1 rad/s, a constant gyro bias, white sensor noise at the system's
    default levels; linear-acceleration bursts (horizontal, 4 m/s^2, 0.5 s, every 2 s from t = 5 s) and a magnetic
    disturbance (0.4 B, fixed in the world, 20-30 s). Returns ts, us, ys (with norms), R (truth), the bias."""
    rng = np.random.default_rng(seed)
    N = int(duration * RATE) + 1
    ts, w, R = turning(RATE, N)
    bias = np.array([0.01, -0.008, 0.012])
    us = w + bias + ab.GYRO_STD * rng.standard_normal((N, 3))
    a_lin = np.zeros((N, 3))
    if bursts:
        phase = np.mod(ts - 5.0, 2.0)
        on = (ts >= 5.0) & (phase < 0.5)
        direction = np.stack([np.cos(0.7 * ts), np.sin(0.7 * ts), np.zeros(N)], axis=1)
        a_lin[on] = 4.0 * direction[on] * np.sin(np.pi * phase[on] / 0.5)[:, None]
    m_ref = B * np.array(ab.magnetic_reference(ab.DIP))
    d = np.zeros((N, 3))
    if magnet:
        d[(ts >= 20.0) & (ts < 30.0)] = 0.4 * B * np.array([1.0, 0.0, 0.3]) / math.hypot(1.0, 0.3)
    acc = np.einsum("nji,nj->ni", R, G * np.array([0.0, 0.0, 1.0]) + a_lin)
    mag = np.einsum("nji,nj->ni", R, m_ref + d)
    acc += G * ab.ACC_STD * 0.25 * rng.standard_normal((N, 3))
    mag += B * ab.MAG_STD * 0.25 * rng.standard_normal((N, 3))
    ts, us, ys = ab.imu_log(us, acc, mag, RATE, norms=True)
    return ts, us, ys, R, bias


def _rms_deg(traj, R):
    e = attitude_error(R, np.asarray(traj.g_hat.factors[0].as_matrix()))
    return float(np.degrees(np.sqrt(np.mean(e[200:] ** 2))))


@pytest.fixture(scope="module")
def log():
    return simulate()


def _g0(R):
    return TSO3((SO3.from_matrix(jnp.asarray(R[0])), R3(jnp.zeros(3))))


def test_the_imu_model_beats_the_plain_one_on_bursts_and_a_magnet(log):
    ts, us, ys, R, _ = log
    plain = MinimumEnergyFilter(attitude_gyro_bias(imu_rate=RATE))
    imu = MinimumEnergyFilter(attitude_imu(imu_rate=RATE, gravity=G, field=B))
    tp = plain.run(plain.init(_g0(R), K0), ts, us, ys[:, :6])
    ti = imu.run(imu.init(_g0(R), K0), ts, us, ys)
    assert tp.status.ok and ti.status.ok
    e_plain, e_imu = _rms_deg(tp, R), _rms_deg(ti, R)
    # measured (seed 0): plain 3.9 deg, IMU model 0.8 deg
    assert e_imu < 0.5 * e_plain, (e_imu, e_plain)


def test_without_disturbances_the_imu_model_costs_little():
    ts, us, ys, R, _ = simulate(bursts=False, magnet=False, duration=20.0)
    plain = MinimumEnergyFilter(attitude_gyro_bias(imu_rate=RATE))
    imu = MinimumEnergyFilter(attitude_imu(imu_rate=RATE, gravity=G, field=B))
    e_plain = _rms_deg(plain.run(plain.init(_g0(R), K0), ts, us, ys[:, :6]), R)
    e_imu = _rms_deg(imu.run(imu.init(_g0(R), K0), ts, us, ys), R)
    # the magnetometer informs the heading only: the tilt loses its (small) magnetic share
    assert e_imu < 1.5 * e_plain + 0.1, (e_imu, e_plain)


def test_the_noise_model_in_closed_form():
    acc = ab_imu.AccelerationNoise(norm=6, gravity=G)
    y = np.zeros(8)
    y[6] = 1.2 * G
    std = jnp.array([0.02])
    f = float(acc(std, jnp.array([math.sqrt(2.0), 0.03]), y))
    assert f == pytest.approx(0.02**2 / (0.02**2 + 2 * 0.04 / 0.23), rel=1e-9)
    y[6] = G
    assert float(acc(std, jnp.array([5.0, 0.03]), y)) == 1.0
    mag = ab_imu.MagneticNoise(acc=0, mag=3, norm=7, field=B, dip=ab.DIP)
    up = np.array([0.0, 0.0, 1.0])
    m = np.array(ab.magnetic_reference(ab.DIP))
    y = np.concatenate([up, m, [G, B]])
    T = np.asarray(mag(std, jnp.array([1.0, 0.1]), y))
    info = T.T @ T  # in units of the undisturbed information 1/sigma^2
    t1 = np.cross(up, m) / np.linalg.norm(np.cross(up, m))
    t2 = np.cross(m, t1)
    assert t1 @ info @ t1 == pytest.approx(1.0, abs=1e-9)                          # the heading: the full weight
    assert t2 @ info @ t2 == pytest.approx(0.02**2 / (0.02**2 + 0.1**2), rel=1e-9)  # the dip: sigma_dip added
    y[7] = 1.5 * B                                                                    # a disturbed norm
    T = np.asarray(mag(std, jnp.array([1.0, 0.1]), y))
    assert t1 @ (T.T @ T) @ t1 == pytest.approx(0.02**2 / (0.02**2 + 0.25), rel=1e-9)


def test_parameters_are_leaves_and_checked():
    s = attitude_imu()
    s2 = s.with_scale_params(acc=[3.0, 0.05], mag=[2.0, 0.3])
    assert float(s2.sensors[0].scale_params[0]) == 3.0 and float(s2.sensors[1].scale_params[1]) == 0.3
    with pytest.raises(ValueError, match="^with_scale_params:"):
        s.with_scale_params(norm=[1.0])
    with pytest.raises(ValueError, match="^acc_adapt:"):
        attitude_imu(acc_adapt=-1.0)
    with pytest.raises(ValueError, match="^field:"):
        attitude_imu(field=0.0)


def test_a_backward_gyro_sample_is_the_rate_over_the_interval_ending_at_its_time():
    rng = np.random.default_rng(3)
    gyr, acc, mag = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    _, fwd, ys_f = ab.imu_log(gyr, acc, mag, 100.0)
    _, bwd, ys_b = ab.imu_log(gyr, acc, mag, 100.0, gyro="backward")
    np.testing.assert_array_equal(fwd, gyr)
    np.testing.assert_array_equal(bwd[:4], gyr[1:])  # us[k] = sample k + 1: the rate over [t_k, t_k+1]
    np.testing.assert_array_equal(bwd[4], gyr[4])  # the last one held
    np.testing.assert_array_equal(ys_f, ys_b)  # the directions keep their own time
    with pytest.raises(ValueError, match="gyro"):
        ab.imu_log(gyr, acc, mag, 100.0, gyro="centred")


def simulate_translation(seed=0, duration=30.0, amp=0.25):
    """A 100 Hz IMU turning at about 1 rad/s while a hand moves it back and forth (position amp * sin at 3-5
    rad/s: up to 4 m/s^2 of linear acceleration, a bounded velocity of up to 1.2 m/s), an undisturbed field.
    Returns the raw columns, the truth and the true world velocity."""
    rng = np.random.default_rng(seed)
    N = int(duration * RATE) + 1
    ts, w, R = turning(RATE, N)
    gyr = w + np.array([0.01, -0.008, 0.012]) + ab.GYRO_STD * rng.standard_normal((N, 3))
    om, ph, axes = np.array([3.0, 4.0, 5.0]), np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.3])
    a_lin = -amp * om**2 * np.sin(om * ts[:, None] + ph) * axes
    v = amp * om * np.cos(om * ts[:, None] + ph) * axes
    acc = np.einsum("nji,nj->ni", R, G * np.array([0.0, 0.0, 1.0]) + a_lin) + 0.05 * rng.standard_normal((N, 3))
    m = np.broadcast_to(B * np.array(ab.magnetic_reference(ab.DIP)), (N, 3))
    mag = np.einsum("nji,nj->ni", R, m) + 0.01 * B * rng.standard_normal((N, 3))
    return ts, gyr, acc, mag, R, v


@pytest.mark.slow
def test_the_velocity_model_beats_the_direction_model_under_translation():
    from liemef.systems import attitude_velocity

    ts, gyr, acc, mag, R, v = simulate_translation()
    _, us, ys = ab.imu_log(gyr, acc, mag, RATE, norms=True)
    imu = MinimumEnergyFilter(attitude_imu(imu_rate=RATE, gravity=G, field=B), updates="discrete")
    ti = imu.run(imu.init(_g0(R), K0), ts, us, ys)
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, RATE)
    assert us.shape == (len(ts), 6) and ys.shape == (len(ts), 11) and np.all(ys[:, 8:] == 0.0)
    # the simulation's own gyro noise, and a velocity std of its motion's order (rms 0.53 m/s, period 1.3-2 s)
    vel = MinimumEnergyFilter(attitude_velocity(ab.GYRO_STD, RATE, velocity_std=0.5, gravity=G, field=B),
                              updates="discrete")
    g0 = ab_vel.attitude_velocity_state(_g0(R), v[0])
    tv = vel.run(vel.init(g0, np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3)), ts, us, ys)
    assert ti.status.ok and tv.status.ok
    e_imu, e_vel = _rms_deg(ti, R), _rms_deg(tv, R)
    # measured (seed 0): the direction model (attitude_imu) 7.5 deg, the velocity model 0.44 deg
    assert e_vel < 0.2 * e_imu, (e_vel, e_imu)
    v_hat = np.asarray(tv.g_hat.factors[2].x)
    # the velocity state follows the true velocity (rms 0.53 m/s; measured error 0.07 m/s)
    assert np.sqrt(np.mean((v_hat[200:] - v[200:]) ** 2)) < 0.25 * np.sqrt(np.mean(v[200:] ** 2))
    with pytest.raises(ValueError, match="velocity_std"):
        attitude_velocity(velocity_std=[1.0, 2.0])



# --- the bounded-position model: the velocity model and a position kept near where the IMU hovers -------------
KW_BOTH = dict(gyro_std=ab.GYRO_STD, imu_rate=RATE, gravity=G, field=B, acc_density=0.01, velocity_std=0.5,
               mag_std=0.02)
"""The noise levels the bounded-velocity and bounded-position models are compared at (every one they share)."""


def test_the_position_model_extends_the_velocity_model_block_by_block():
    """attitude_position is attitude_velocity with a position appended: its log, dynamics, outputs, process noise
    and weights are the velocity model's in their rows and blocks, then the position's (v its rate, the walk, the
    zero-position pseudo-measurement). A position placed in the wrong rows, a velocity not integrated, or a noise
    on the wrong block breaks it (no filter run: the structure only)."""
    from liemef.systems import attitude_position, attitude_velocity

    ts, gyr, acc, mag, R, v = simulate_translation(duration=0.2)
    vel, pos = attitude_velocity(**KW_BOTH), attitude_position(**KW_BOTH, position_std=0.3, position_walk=0.002)
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, RATE)
    _, us_p, ys_p = ab_vel.imu_position_log(gyr, acc, mag, RATE)
    np.testing.assert_array_equal(us_p, us)
    np.testing.assert_array_equal(ys_p[:, :11], ys)
    assert ys_p.shape == (len(ts), 14) and np.all(ys_p[:, 11:] == 0.0)
    g = ab_vel.attitude_position_state(_g0(R), v[5], (0.1, -0.2, 0.05))
    gv = ab_vel.attitude_velocity_state(TSO3(g.factors[:2]), v[5])
    lam_p, lam_v = (np.asarray(m.dynamics(x, jnp.asarray(us[5]), 0.0)) for m, x in ((pos, g), (vel, gv)))
    np.testing.assert_array_equal(lam_p[:9], lam_v)
    np.testing.assert_array_equal(lam_p[9:], v[5])  # the velocity is the position's rate
    h_p, h_v = np.asarray(pos.output(g, 0.0)), np.asarray(vel.output(gv, 0.0))
    np.testing.assert_array_equal(h_p[:11], h_v)
    np.testing.assert_array_equal(h_p[11:], [0.1, -0.2, 0.05])  # the position, measured as zero
    Q_p, Q_v = _nominal(pos), _nominal(vel)
    np.testing.assert_allclose(Q_p[:9, :9], Q_v, rtol=1e-15)
    np.testing.assert_allclose(Q_p[9:, 9:], 0.002**2 * np.eye(3), rtol=1e-12)
    assert not np.any(np.asarray(Q_p[:9, 9:]))
    W_p, W_v = np.asarray(pos.information()), np.asarray(vel.information())
    np.testing.assert_allclose(W_p[:11, :11], W_v, rtol=1e-15)
    np.testing.assert_allclose(np.diag(W_p)[11:], 1 / 0.3**2, rtol=1e-12)
    assert pos.state_names[-6:] == ("vx", "vy", "vz", "px", "py", "pz")
    with pytest.raises(ValueError, match="position_std"):
        attitude_position(position_std=[1.0, 2.0])
    with pytest.raises(ValueError, match="^p: "):
        ab_vel.attitude_position_state(_g0(R), p=(0.0, 1.0))


@pytest.mark.slow  # two filters' compiles, about 20 s from cold caches
def test_the_position_model_is_the_velocity_model_when_its_position_weighs_nothing():
    """With its pseudo-measurement weighing nothing, no output depends on the position and no dynamics reads it,
    so the filter's attitude, bias and velocity (and their block of K) are the velocity model's."""
    from liemef.systems import attitude_position, attitude_velocity

    ts, gyr, acc, mag, R, v = simulate_translation(duration=2.0)
    vel = MinimumEnergyFilter(attitude_velocity(**KW_BOTH), updates="discrete")
    pos = MinimumEnergyFilter(attitude_position(**KW_BOTH, position_std=1e7), updates="discrete")
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, RATE)
    _, us_p, ys_p = ab_vel.imu_position_log(gyr, acc, mag, RATE)
    tv = vel.run(vel.init(ab_vel.attitude_velocity_state(_g0(R), v[0]), ab_vel.K0_VELOCITY), ts, us, ys)
    tp = pos.run(pos.init(ab_vel.attitude_position_state(_g0(R), v[0]), ab_vel.K0_POSITION), ts, us_p, ys_p)
    assert tv.status.ok and tp.status.ok
    for i in range(3):
        np.testing.assert_allclose(tp.g_hat.factors[i].coords(), tv.g_hat.factors[i].coords(), rtol=0,
                                   atol=1e-9)
    np.testing.assert_allclose(tp.K[:, :9, :9], tv.K, rtol=1e-7, atol=1e-13)


@pytest.mark.slow
def test_the_position_model_keeps_heading_and_tilt_where_a_stiff_velocity_loses_them():
    """Under a hand's translation (simulate_translation: 0.25 m back and forth at 3-5 rad/s), the velocity
    model at its default stiffness (velocity_std 0.01, what BROAD's tune chose) explains the motion's velocity
    as attitude error; the position model at its defaults bounds the double integral instead, which such a motion
    keeps small. Loosened (position_std 0.1) it is near the velocity model at a velocity std fitted to this
    motion (0.5) and its position follows the true one."""
    from liemef.systems import attitude_position, attitude_velocity

    ts, gyr, acc, mag, R, v = simulate_translation()
    p = 0.25 * np.sin(np.array([3.0, 4.0, 5.0]) * ts[:, None] + np.array([0.0, 1.0, 2.0])) * np.array([1.0, 1.0, 0.3])
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, RATE)
    _, us_p, ys_p = ab_vel.imu_position_log(gyr, acc, mag, RATE)
    runs = {}
    for name, std in (("stiff", ab_vel.VELOCITY_STD), ("fitted", 0.5)):
        f = MinimumEnergyFilter(attitude_velocity(ab.GYRO_STD, RATE, velocity_std=std, gravity=G, field=B),
                                updates="discrete")
        runs[name] = f.run(f.init(ab_vel.attitude_velocity_state(_g0(R), v[0]), ab_vel.K0_VELOCITY), ts, us, ys)
    for name, std in (("position", ab_vel.POSITION_STD), ("loose position", 0.1)):
        f = MinimumEnergyFilter(attitude_position(ab.GYRO_STD, RATE, position_std=std, gravity=G, field=B),
                                updates="discrete")
        g0 = ab_vel.attitude_position_state(_g0(R), v[0], p[0])
        runs[name] = f.run(f.init(g0, ab_vel.K0_POSITION), ts, us_p, ys_p)
    assert all(t.status.ok for t in runs.values())
    e = {k: _rms_deg(t, R) for k, t in runs.items()}
    # measured (seed 0): stiff velocity 26.6 deg, position 0.84, loose position 0.49, fitted velocity 0.44
    assert e["position"] < 0.15 * e["stiff"], e
    assert e["loose position"] < 1.5 * e["fitted"] and e["loose position"] < e["position"], e
    p_hat = np.asarray(runs["loose position"].g_hat.factors[3].x)
    # the position follows the true one about its centre (rms 0.15 m; measured error 0.07 m)
    assert np.sqrt(np.mean((p_hat[200:] - p[200:]) ** 2)) < 0.6 * np.sqrt(np.mean(p[200:] ** 2))

# --- the gyro's scale-factor and cross-axis errors as a noise that grows with the rate --------------------------
U = jnp.asarray([1.0, -2.0, 0.5, 0.3, -0.2, 9.7])  # a gyro sample (rad/s) and a specific force (m/s^2)


def _nominal(s):
    return s.B @ jnp.linalg.solve(s.R, s.B.T)


def _plain_copy(s):
    """The same system without the rate-dependent noise: the SensorSystem the factory wraps."""
    from liemef.systems import SensorSystem

    return SensorSystem(s.group, s.dynamics_fn, s.sensors, s.process_noise, s.noise_map, inputs=s.inputs,
                        input_units=s.input_units, state_names=s.coord_names, state_units=s.coord_units)


def test_the_gyro_scale_noise_in_closed_form_and_as_a_leaf():
    from liemef.systems import attitude_velocity, right_error

    s = attitude_velocity(imu_rate=RATE, gyro_scale_std=0.02, gravity=G, field=B)
    g = ab_vel.attitude_velocity_state(TSO3((SO3.exp(jnp.asarray([0.3, -0.2, 1.1])), R3(jnp.asarray([0.01, 0, 0])))),
                                   (0.2, -0.1, 0.0))
    BRB, t = _nominal(s), jnp.asarray(0.0)
    # the gyro's block grows by s^2 |u_omega|^2 / f on its diagonal, isotropic; nothing else moves
    add = 0.02**2 * float(U[:3] @ U[:3]) / RATE
    np.testing.assert_allclose(s.process_noise_at(g, BRB, U, t), BRB + np.diag([add] * 3 + [0.0] * 6),
                               rtol=1e-14, atol=0)
    zero = s.with_gyro_scale(0.0)
    np.testing.assert_array_equal(zero.process_noise_at(g, BRB, U, t), BRB)
    assert zero.constant_process_noise and not s.constant_process_noise
    # a leaf: every value has the default's structure, so a filter of it reuses the compiled code
    import jax

    assert jax.tree_util.tree_structure(s) == jax.tree_util.tree_structure(attitude_velocity(imu_rate=RATE, gravity=G,
                                                                                          field=B))
    # the right error sees it too: Ad_{h^-1} (B R^-1 B^T)(g) Ad_{h^-1}^T at h = g^-1
    h = g.inverse()
    np.testing.assert_allclose(right_error(s).process_noise_at(h, BRB, U, t),
                               g.Ad() @ s.process_noise_at(g, BRB, U, t) @ g.Ad().T, rtol=1e-12, atol=1e-18)
    for bad in (-0.01, math.nan, [0.01, 0.02], True):
        with pytest.raises(ValueError, match="^gyro_scale_std:"):
            attitude_velocity(gyro_scale_std=bad)


def test_a_random_calibration_matrix_makes_the_isotropic_noise():
    """Monte Carlo: a gyro error M omega with M's nine entries independent of std s has the covariance
    s^2 |omega|^2 I, whatever the axis of omega (the model's justification, liemef.systems._gyro_scale)."""
    rng = np.random.default_rng(0)
    s, n = 0.01, 40000
    for w in (np.array([2.0, 0.0, 0.0]), np.array([0.3, -1.2, 0.8])):
        e = np.einsum("kij,j->ki", s * rng.standard_normal((n, 3, 3)), w)
        C = e.T @ e / n / (s**2 * (w @ w))
        np.testing.assert_allclose(C, np.eye(3), atol=0.03)  # 4 standard errors of a variance of 40000 draws


def test_the_filters_see_the_rate_dependent_noise():
    """The K rate of the minimum-energy filter grows by exactly the closed form at the input; the invariant EKF's
    prediction by it times dt, to the first order in dt."""
    from liemef.filters.baselines import invariant_ekf
    from liemef.systems import attitude_velocity

    s = attitude_velocity(imu_rate=RATE, gyro_scale_std=0.03, gravity=G, field=B)
    s0 = s.with_gyro_scale(0.0)
    g = ab_vel.attitude_velocity_state(TSO3((SO3.exp(jnp.asarray([0.3, -0.2, 1.1])), R3(jnp.zeros(3)))))
    K = np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3)
    add = np.diag([0.03**2 * float(U[:3] @ U[:3]) / RATE] * 3 + [0.0] * 6)
    dK = [np.asarray(MinimumEnergyFilter(x, error="left").vector_field(g, K, U, s.output(g, 0.0), 0.0)[1])
          for x in (s, s0)]
    np.testing.assert_allclose(dK[0] - dK[1], add, atol=1e-12 * np.abs(dK[1]).max())
    dt = 1e-4
    P = [np.asarray(invariant_ekf(x).predict(invariant_ekf(x).init(g, K), 0.0, U, dt, engine="xla").K)
         for x in (s, s0)]
    np.testing.assert_allclose((P[0] - P[1]) / dt, add, rtol=1e-3, atol=1e-6 * add.max())


def test_a_zero_gyro_scale_changes_no_bit_of_the_terms():
    """The default (0) gives the unwrapped model's Riccati terms, every bit, in both orders (the filters' only
    use of the process noise; compare broad's runs on real data were checked equal bit for bit)."""
    from liemef.connections import connection
    from liemef.filters import Weights, terms
    from liemef.systems import attitude_velocity

    s = attitude_velocity(imu_rate=RATE, gravity=G, field=B)
    plain = _plain_copy(s)
    g = ab_vel.attitude_velocity_state(TSO3((SO3.exp(jnp.asarray([0.3, -0.2, 1.1])), R3(jnp.asarray([0.01, 0, 0])))),
                                   (0.2, -0.1, 0.0))
    K = jnp.asarray(np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3))
    y = s.output(g, 0.0) + 0.01
    conn, t = connection("zero", s.group), jnp.asarray(0.0)
    for second in (True, False):
        a, b = (terms(x, Weights.of(x), conn, second, g, K, U, y, t) for x in (s, plain))
        for name in ("r", "A", "E", "W", "BRB"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.slow
def test_a_zero_gyro_scale_changes_no_bit_of_a_run():
    """The default (0) runs the unwrapped model's numbers, every bit: the MEF with samples at their own time (as
    compare broad's mef-vel) and the invariant EKF."""
    from liemef.filters.baselines import invariant_ekf
    from liemef.systems import attitude_velocity

    ts, gyr, acc, mag, R, v = simulate_translation(duration=0.5)
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, RATE, gyro="backward")
    s = attitude_velocity(imu_rate=RATE, gravity=G, field=B)
    g0 = ab_vel.attitude_velocity_state(_g0(R), v[0])
    K0 = np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3)
    for make in (lambda x: MinimumEnergyFilter(x, updates="discrete", curvature="exact", error="left"),
                 invariant_ekf):
        a, b = make(s), make(_plain_copy(s))
        ta, tb = (f.run(f.init(g0, K0), ts, us, ys) for f in (a, b))
        np.testing.assert_array_equal(ta.g_hat.factors[0].as_matrix(), tb.g_hat.factors[0].as_matrix())
        np.testing.assert_array_equal(ta.K, tb.K)
