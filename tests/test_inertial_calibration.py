"""The inertial-navigation system's mount and sensor calibration states (liemef.systems.inertial): the lever arm
of the position fixes' point from the IMU and the gyro's calibration errors M (the gyro reads (I + M) w + b_g).

* The outputs and the dynamics are the model's formulas: ``gnss`` is p + R r, the gyro is (I + M)^-1 (w - b_g)
  with M diagonal ("scale") or full ("matrix").
* On a simulated flight whose gyro has known scale-factor and cross-axis errors and whose fixes are taken at a
  known lever arm, the minimum-energy filter recovers them, within 3 of its own standard deviations and within a
  millimetre and 0.1 %.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from liemef.filters import MinimumEnergyFilter
from liemef.groups import SE23, SO3, Product, Rn
from liemef.systems import inertial_navigation

G = Product[SE23, Rn[12]]
GM = Product[SE23, Rn[18]]


def _state(R, v, p, z, group=G):
    return group((SE23.from_rotation_velocity_position(SO3.from_matrix(jnp.asarray(R)), jnp.asarray(v),
                                                   jnp.asarray(p)), Rn[len(z)](jnp.asarray(z))))


def test_the_fix_is_the_mounted_point_and_the_gyro_is_scaled():
    s = inertial_navigation(biases=True, lever_arm=True, gyro_calibration="scale", gnss_std=0.01)
    assert s.group is G and s.group.tangent_dim == 21
    assert s.state_names[-6:] == ("rx_arm", "ry_arm", "rz_arm", "sgx", "sgy", "sgz")
    R = np.asarray(SO3.exp(jnp.array([0.3, -0.2, 0.5])).as_matrix())
    r, scale, bg = np.array([0.01, -0.02, 0.03]), np.array([0.01, -0.02, 0.005]), np.array([1e-3, 2e-3, -1e-3])
    g = _state(R, [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], np.concatenate([bg, np.zeros(3), r, scale]))
    np.testing.assert_allclose(np.asarray(s.output(g, 0.0)), [4.0, 5.0, 6.0] + R @ r, atol=1e-14)
    u = jnp.array([0.4, -0.3, 0.2, 0.0, 0.0, 9.81])
    lam = np.asarray(s.dynamics(g, u, 0.0))
    np.testing.assert_allclose(lam[:3], (np.asarray(u[:3]) - bg) / (1.0 + scale), atol=1e-14)
    assert np.all(lam[9:] == 0.0)  # biases, lever arm and scale factors are constants
    M = np.array([[0.01, 0.004, -0.003], [-0.002, -0.02, 0.005], [0.006, -0.001, 0.005]])
    sm = inertial_navigation(biases=True, lever_arm=True, gyro_calibration="matrix", gnss_std=0.01)
    assert sm.group is GM and sm.state_names[-9:-6] == ("mgxx", "mgxy", "mgxz")
    gm = _state(R, [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], np.concatenate([bg, np.zeros(3), r, M.reshape(-1)]), GM)
    lam = np.asarray(sm.dynamics(gm, u, 0.0))
    np.testing.assert_allclose((np.eye(3) + M) @ lam[:3], np.asarray(u[:3]) - bg, atol=1e-14)
    np.testing.assert_allclose(np.asarray(sm.output(gm, 0.0)), [4.0, 5.0, 6.0] + R @ r, atol=1e-14)
    plain = inertial_navigation(biases=True, gnss_std=0.01)
    assert plain.group.tangent_dim == 15  # unchanged without the new states
    with pytest.raises(ValueError, match="lever_arm"):
        inertial_navigation(lever_arm=True, gnss_std=None, mag_std=0.05)
    with pytest.raises(ValueError, match="gyro_calibration"):
        inertial_navigation(gyro_calibration="full")


def _flight(M, seconds=40.0, rate=100.0, fix_rate=10.0, r=(0.02, -0.01, 0.03), bg=(0.002, -0.001, 0.003),
            ba=(0.05, -0.03, 0.02), gravity=9.81):
    """A body that turns about every axis and moves on a smooth loop; the gyro reads (I + M) omega + b_g, the
    accelerometer R^T (a - g) + b_a (noise-free: the test is of the model's states, not of the noise), the fixes
    p + R r at ``fix_rate``. Returns ts, us (filter convention: us[k] over [t_k, t_k+1]), ys, the truth."""
    n = int(seconds * rate)
    dt = 1.0 / rate
    ts = np.arange(n) * dt
    tm = ts + 0.5 * dt  # the interval's midpoint: the rate and acceleration over [t_k, t_k+1]
    omega = np.stack([0.8 * np.sin(0.7 * tm), 0.6 * np.cos(0.45 * tm), 0.5 + 0.3 * np.sin(0.3 * tm)], axis=1)
    Rs = np.empty((n, 3, 3))
    Rs[0] = np.eye(3)
    step = np.asarray(SO3.exp(jnp.asarray(omega[:-1] * dt)).as_matrix())
    for k in range(n - 1):
        Rs[k + 1] = Rs[k] @ step[k]
    w1, w2 = 0.4, 0.25
    pos = lambda t: np.stack([np.sin(w1 * t), np.cos(w2 * t) - 1.0, 0.2 * np.sin(2 * w2 * t)], axis=1)  # noqa: E731
    acc = lambda t: np.stack([-w1**2 * np.sin(w1 * t), -w2**2 * np.cos(w2 * t),  # noqa: E731
                              -0.8 * w2**2 * np.sin(2 * w2 * t)], axis=1)
    Rm = np.concatenate([Rs[:-1] @ np.asarray(SO3.exp(jnp.asarray(omega[:-1] * dt / 2)).as_matrix()), Rs[-1:]])
    f = np.einsum("nji,nj->ni", Rm, acc(tm) - [0.0, 0.0, -gravity])
    us = np.concatenate([omega @ (np.eye(3) + M).T + bg, f + ba], axis=1)
    ys = np.full((n, 3), np.nan)
    every = int(round(rate / fix_rate))
    ys[::every] = pos(ts[::every]) + np.einsum("nij,j->ni", Rs[::every], r)
    v0 = np.array([w1, 0.0, 0.4 * w2])
    return ts, us, ys, Rs, pos(ts), v0


# the 27-state matrix model (its kernel: 20 MB of C) in make test-slow; the 21-state scale model here
@pytest.mark.parametrize("kind", ["scale", pytest.param("matrix", marks=pytest.mark.slow)])
def test_the_filter_recovers_a_known_lever_arm_and_gyro_calibration(kind):
    r = np.array([0.02, -0.01, 0.03])
    M = np.diag([0.01, -0.015, 0.02])
    if kind == "matrix":
        M = M + np.array([[0.0, 0.004, -0.003], [-0.002, 0.0, 0.005], [0.006, -0.004, 0.0]])
    ts, us, ys, Rs, pos, v0 = _flight(M, r=r)
    s = inertial_navigation(gyro_std=1e-3, acc_std=1e-2, imu_rate=100.0, biases=True, gnss_std=0.002,
                            lever_arm=True, gyro_calibration=kind)
    flt = MinimumEnergyFilter(s, order="first", updates="discrete", error="left")
    m = 3 if kind == "scale" else 9
    g0 = _state(np.eye(3), v0, pos[0], np.zeros(9 + m), Product[SE23, Rn[9 + m]])
    K0 = np.diag([0.02**2] * 3 + [0.05**2] * 3 + [0.01**2] * 3 + [0.005**2] * 3 + [0.1**2] * 3 + [0.05**2] * 3
                 + [0.02**2] * m)
    traj = flt.run(flt.init(g0, K0), ts, us, ys)
    assert int(traj.status.code) == 0
    z = np.asarray(traj.g_hat.factors[1].x)[-1]
    sd = np.sqrt(np.diag(np.asarray(traj.K)[-1]))
    truth = np.diag(M) if kind == "scale" else M.reshape(-1)
    err_r, err_m = z[6:9] - r, z[9:] - truth
    assert np.all(np.abs(err_r) < 3 * sd[15:18]) and np.all(np.abs(err_m) < 3 * sd[18:]), (err_r, err_m, sd[15:])
    assert np.max(np.abs(err_r)) < 1e-3 and np.max(np.abs(err_m)) < 1e-3, (err_r, err_m)
    # and the prior's spread has shrunk: the flight observes them
    assert np.all(sd[15:18] < 0.05 / 10) and np.all(sd[18:] < 0.02 / 10)
    R_end = np.asarray(traj.g_hat.factors[0].rotation().as_matrix())[-1]
    assert math.degrees(np.linalg.norm(np.asarray(SO3.from_matrix(jnp.asarray(R_end.T @ Rs[-1])).log()))) < 0.1


def test_the_3x3_solve_of_the_calibration_is_numpy_s():
    """The gyro calibration's (I + M)^-1 w is a closed-form 3x3 solve (Cramer's rule, which every engine compiles,
    batched): equal to LAPACK's to roundoff."""
    from liemef._linalg import solve3

    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 3, 3)) + 3.0 * np.eye(3)
    b = rng.standard_normal((50, 3))
    np.testing.assert_allclose(np.asarray(solve3(jnp.asarray(A), jnp.asarray(b))),
                               np.linalg.solve(A, b[..., None])[..., 0], rtol=0, atol=1e-13)


def test_the_gyro_scale_as_noise_grows_with_the_rate():
    """``gyro_scale_std`` s: the gyro's block of the process noise grows by s^2 |u_omega|^2 / f on its diagonal
    (liemef.systems._gyro_scale), with the calibration states or without; None builds the plain system."""
    from liemef.systems import SensorSystem

    plain = inertial_navigation(biases=True, lever_arm=True, gyro_calibration="matrix", imu_rate=200.0)
    assert type(plain) is SensorSystem and plain.constant_process_noise
    s = inertial_navigation(biases=True, lever_arm=True, gyro_calibration="matrix", imu_rate=200.0,
                            gyro_scale_std=0.01)
    g = _state(np.eye(3), [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], np.zeros(18), GM)
    u, t = jnp.asarray([0.5, -1.0, 2.0, 0.1, 0.0, 9.8]), jnp.asarray(0.0)
    BRB = s.B @ jnp.linalg.solve(s.R, s.B.T)
    add = np.zeros(27)
    add[:3] = 0.01**2 * 5.25 / 200.0
    np.testing.assert_allclose(s.process_noise_at(g, BRB, u, t), BRB + np.diag(add), rtol=1e-14, atol=0)
    np.testing.assert_array_equal(s.with_gyro_scale(0.0).process_noise_at(g, BRB, u, t), BRB)
    assert not s.constant_process_noise and s.with_gyro_scale(0.0).constant_process_noise
    np.testing.assert_array_equal(s.B, plain.B)
