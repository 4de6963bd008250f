"""Magnetic disturbances with memory (liemef.systems.attitude_field): a magnet beside the path for two minutes
and one attached to the IMU, on synthetic logs whose truth is known; the disturbances' process noise in closed
form; its gains as leaves."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_motion import turning
from liemef.filters import MinimumEnergyFilter
from liemef.groups import R3, SO3, TSO3
from liemef.systems import attitude_bias as ab
from liemef.systems.attitude_field import K0_FIELD, attitude_field, attitude_field_state, imu_field_log

RATE, G, B = 50.0, 9.81, 43.0
ON = (30.0, 150.0)  # the disturbance: two minutes


def simulate(kind: str, seed: int = 0, duration: float = 180.0):
    """A 50 Hz IMU turning at about 1 rad/s with a constant gyro bias; the field disturbed during ``ON`` (2 s ramps
    in and out) by 0.4 B: ``"world"``, a field fixed near the path that turns slowly as the IMU passes it, or
    ``"body"``, a magnet attached to the IMU. Returns ts, gyro, acc, mag and the true rotations."""
    rng = np.random.default_rng(seed)
    N = int(duration * RATE) + 1
    ts, w, R = turning(RATE, N)
    gyr = w + np.array([0.01, -0.008, 0.012]) + 0.005 * rng.standard_normal((N, 3))
    ramp = np.clip(np.minimum(ts - ON[0], ON[1] - ts) / 2.0, 0.0, 1.0)[:, None]
    d, c = np.zeros((N, 3)), np.zeros((N, 3))
    if kind == "world":
        d = 0.4 * B * np.stack([np.cos(0.05 * ts), np.sin(0.05 * ts), 0.5 * np.ones(N)], 1) / math.hypot(1, 0.5) * ramp
    else:
        c = 0.4 * B * np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74]) * ramp
    acc = np.einsum("nji,j->ni", R, G * np.array([0.0, 0.0, 1.0])) + 0.05 * rng.standard_normal((N, 3))
    mag = np.einsum("nji,nj->ni", R, B * np.array(ab.magnetic_reference(ab.DIP)) + d) + c
    return ts, gyr, acc, mag + 0.3 * rng.standard_normal((N, 3)), R


def heading_deg(R, R_hat):
    q = Rotation.from_matrix(R_hat @ np.swapaxes(R, -1, -2)).as_quat()
    return np.degrees(2 * np.arctan(np.abs(q[:, 2]) / np.maximum(np.abs(q[:, 3]), 1e-12)))


def run_field(kind, **levels):
    ts, gyr, acc, mag, R = simulate(kind)
    _, us, ys = imu_field_log(gyr, acc, mag, RATE, gyro="forward")
    flt = MinimumEnergyFilter(attitude_field(0.005, RATE, gravity=G, field=B, **levels), order="first",
                              updates="discrete", error="left")
    g0 = TSO3((SO3.from_matrix(jnp.asarray(R[0])), R3(jnp.zeros(3))))
    traj = flt.run(flt.init(attitude_field_state(g0), K0_FIELD), ts, us, ys)
    assert traj.status.ok, traj.status.message(ts)
    h = heading_deg(R, np.asarray(traj.g_hat.factors[0].as_matrix()))
    return {name: float(np.sqrt(np.mean(h[(ts >= a) & (ts < b)] ** 2)))
            for name, (a, b) in {"before": (10, ON[0]), "during": ON, "after": (ON[1] + 5, ON[1] + 30),
                                 "first_5s_after": (ON[1], ON[1] + 5)}.items()}


@pytest.mark.parametrize("kind", ["world", "body"])
def test_a_lasting_disturbance_moves_the_state_not_the_heading(kind):
    memory = run_field(kind)
    # the same model with the disturbances' growth off (k = 0): a stiff field, every sample pulls the heading.
    # -0.0, not +0.0: a +0 leaf is a structural zero, folded into a C kernel of its own (another 9.6 MB build);
    # -0 is read at run time by the kernel of `memory` and gives the same numbers (k^2 = +0)
    stiff = run_field(kind, world_gain=-0.0)
    # measured (seed 0), heading rms during the disturbance: world 0.56 deg against 27.2; body 0.89 against 3.22
    assert memory["during"] < 1.0 and memory["during"] < 0.3 * stiff["during"], (memory, stiff)
    # the heading is back within seconds of the disturbance ending: measured 0.38 and 1.24 deg rms over the first
    # 5 s, 0.28 and 0.76 over the next 25 (the stiff model: 3.03 and 6.76, then 0.55 and 5.23)
    assert memory["first_5s_after"] < 1.5 and memory["after"] < 1.0, memory
    assert memory["after"] < stiff["after"], (memory, stiff)
    # and undisturbed the growth costs nothing: the same heading before the disturbance
    assert memory["before"] < 0.3 and abs(memory["before"] - stiff["before"]) < 0.01, (memory, stiff)


def test_the_process_noise_grows_with_the_unexplained_disturbance_in_closed_form():
    s = attitude_field(gravity=G, field=B, dip=1.2, world_density=0.01, body_density=0.02, world_gain=3.0,
                       body_gain=4.0, disturbance=2.0)
    nominal = jnp.diag(jnp.asarray(s.process_noise.std) ** 2)
    R = SO3.exp(jnp.asarray([0.3, -0.2, 1.1]))
    u, t = jnp.asarray([1.0, -2.0, 0.5, 0.1, 0.2, 9.8]), jnp.asarray(0.0)  # the noise does not depend on them
    ref = B * np.array(ab.magnetic_reference(1.2))
    # a heading-like world disturbance (the reference turned about up): no unexplained part, the nominal noise
    turned = Rotation.from_rotvec([0.0, 0.0, 0.4]).apply(ref) - ref
    g = attitude_field_state(TSO3((R, R3(jnp.zeros(3)))), w=turned)
    np.testing.assert_allclose(s.process_noise_at(g, nominal, u, t), nominal, atol=1e-12)
    # a world w and a body c: e^2 = (|f| - B)^2 + (f_up - ref_up)^2 with f = ref + w + R c
    w, c = np.array([1.0, -2.0, 3.0]), np.array([0.5, 0.25, -1.5])
    f = ref + w + np.asarray(R.as_matrix()) @ c
    e2 = (np.linalg.norm(f) - B) ** 2 + (f[2] - ref[2]) ** 2
    x = (e2 / 2.0**2) ** 2
    e2 = e2 * x / (1 + x)  # the growth's onset about e0 = 2 uT
    g = attitude_field_state(TSO3((R, R3(jnp.zeros(3)))), w=w, c=c)
    expect = np.asarray(nominal) + np.diag([0.0] * 9 + [9.0 * e2] * 3 + [16.0 * e2] * 3)
    np.testing.assert_allclose(s.process_noise_at(g, nominal, u, t), expect, rtol=1e-12)


def test_the_gains_are_leaves_and_checked():
    s = attitude_field(gravity=G, field=B)
    t = s.with_gains(world=1.0, body=2.0, disturbance=3.0)
    assert jax.tree_util.tree_structure(s) == jax.tree_util.tree_structure(t)
    np.testing.assert_allclose(t.gains, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(s.with_gains(body=0.5).gains, [5.0, 0.5, 12.0])  # the defaults kept
    for bad in (-1.0, math.nan, "1"):
        with pytest.raises(ValueError, match="world"):
            s.with_gains(world=bad)
    with pytest.raises(ValueError, match="disturbance"):
        attitude_field(disturbance=0.0)
    with pytest.raises(ValueError, match="world_tau"):
        attitude_field(world_tau=0.0)
    with pytest.raises(ValueError, match="dip"):
        attitude_field(dip=2.0)
    with pytest.raises(ValueError, match="body_density"):
        attitude_field(body_density=[1.0, 2.0])
    _, us, ys = imu_field_log(np.zeros((4, 3)), np.ones((4, 3)), np.array([[1.0, 2, 3]] * 3 + [[0.0, 0, 0]]), 10.0)
    assert us.shape == (4, 6) and ys.shape == (4, 9) and np.isnan(ys[3, 3:6]).all() and np.all(ys[:, 6:] == 0)
    np.testing.assert_allclose(ys[0, 3:6], [1.0, 2.0, 3.0])  # the raw field, in its units
