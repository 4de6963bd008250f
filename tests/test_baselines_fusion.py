"""x-io's Fusion AHRS (the imufusion package) as a liemef baseline: its frame and units are liemef's ENU, rad/s
and m/s^2 (pinned on a synthetic log whose truth is known), its gyro offset is a liemef gyro bias, its indexing,
missing samples and refusals. Which samples its estimate k has seen on BROAD: tests/test_broad.py."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from liemef.filters.baselines import Fusion
from liemef.groups import R3, SO3, TSO3
from liemef.systems import attitude_bias as ab
from liemef.systems import attitude_gyro_bias, attitude_imu

RATE = 100.0
EXAMPLE = {"gyroscope_range": 2000.0, "acceleration_rejection": 10.0, "magnetic_rejection": 10.0,
           "rejection_timeout": 5.0, "bias": True}
"""The settings of Fusion's advanced_example.py (gain 0.5, its default)."""


def _log(seconds=20.0, seed=0, bias=(0.0, 0.0, 0.0), turn=0.3):
    """A body at rest in a known attitude, then turning about up at ``turn`` rad/s after 5 s: the truth and a raw
    IMU log whose gyro reads the rate plus ``bias``."""
    rng = np.random.default_rng(seed)
    N = int(seconds * RATE)
    ts = np.arange(N) / RATE
    wz = np.where(ts > 5.0, turn, 0.0)
    R0 = Rotation.from_rotvec([0.3, -0.2, 0.8])
    R = R0 * Rotation.from_rotvec(np.outer(np.cumsum(wz) / RATE - wz / RATE, [0.0, 0.0, 1.0]))
    up = R.inv().apply([0.0, 0.0, 9.81])
    mag = R.inv().apply(43.0 * np.array(ab.magnetic_reference(ab.DIP)))
    gyr = np.outer(wz, [0.0, 0.0, 1.0]) + np.asarray(bias) + 0.001 * rng.standard_normal((N, 3))
    return ts, gyr, up + 0.01 * rng.standard_normal((N, 3)), mag + 0.1 * rng.standard_normal((N, 3)), R


def _g0():
    return TSO3((SO3.identity(), R3(jnp.zeros(3))))


@pytest.mark.parametrize("settings", [{}, EXAMPLE], ids=["defaults", "example"])
def test_fusion_estimates_liemef_s_enu_attitude(settings):
    ts, gyr, acc, mag, R = _log()
    ts, us, ys = ab.imu_log(gyr, acc, mag, RATE, norms=True)
    flt = Fusion(attitude_imu(imu_rate=RATE), **settings)
    traj = flt.run(flt.init(_g0()), ts, us, ys)
    assert traj.status.ok
    q = np.asarray(traj.g_hat.factors[0].wxyz)
    est = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    # state k + 1 is Fusion after sample k: compare it with the truth at sample k; it starts from the identity,
    # 49 deg away, and its start-up (3 s) brings it in
    err = np.degrees((est[1:] * R[:-1].inv()).magnitude())
    assert np.degrees(R[0].magnitude()) > 45 and np.sqrt(np.mean(err[-500:] ** 2)) < 1.0
    np.testing.assert_array_equal(q[0], [1.0, 0.0, 0.0, 0.0])          # state 0 is g0


def test_fusion_s_gyro_offset_is_the_liemef_gyro_bias():
    b = np.array([0.01, -0.015, 0.02])  # rad/s, below its 3 deg/s threshold of rest
    ts, gyr, acc, mag, _ = _log(seconds=60.0, bias=b, turn=0.0)
    ts, us, ys = ab.imu_log(gyr, acc, mag, RATE)
    traj = (flt := Fusion(attitude_gyro_bias(imu_rate=RATE), **EXAMPLE)).run(flt.init(_g0()), ts, us, ys)
    np.testing.assert_allclose(np.asarray(traj.g_hat.factors[1].x)[-1], b, atol=0.002)
    without = Fusion(attitude_gyro_bias(imu_rate=RATE)).run(flt.init(_g0()), ts, us, ys)
    assert np.all(np.asarray(without.g_hat.factors[1].x) == 0.0)     # no estimator: no bias


def test_broad_indexing_is_one_sample_ahead_and_missing_samples_are_skipped():
    ts, gyr, acc, mag, R = _log(seconds=8.0)
    ts, us, ys = ab.imu_log(gyr, acc, mag, RATE)
    system = attitude_gyro_bias(imu_rate=RATE)
    a = Fusion(system).run(Fusion(system).init(_g0()), ts, us, ys)
    flt = Fusion(system, broad_indexing=True)
    b = flt.run(flt.init(_g0()), ts, us, ys)
    np.testing.assert_array_equal(np.asarray(a.g_hat.factors[0].wxyz)[1:], np.asarray(b.g_hat.factors[0].wxyz)[:-1])
    gappy = ys.copy()
    gappy[400:500, :3] = np.nan  # 1 s without the accelerometer, then 1 s without the magnetometer
    gappy[500:600, 3:6] = np.nan
    c = flt.run(flt.init(_g0()), ts, us, gappy)
    q = np.asarray(c.g_hat.factors[0].wxyz)
    err = np.degrees((Rotation.from_quat(q[:, [1, 2, 3, 0]]) * R.inv()).magnitude())
    assert c.status.ok and np.all(np.isfinite(q)) and err[-1] < 2.0
    assert not np.array_equal(q[400:600], np.asarray(b.g_hat.factors[0].wxyz)[400:600])


def test_fusion_s_refusals_name_the_argument():
    ts, gyr, acc, mag, _ = _log(seconds=2.0)
    ts, us, ys = ab.imu_log(gyr, acc, mag, RATE)
    flt = Fusion(attitude_gyro_bias(imu_rate=RATE))
    with pytest.raises(ValueError, match="^step:"):
        flt.step(flt.init(_g0()), 0.0, us[0], ys[0], 0.01)
    with pytest.raises(ValueError, match="^ts: expected a uniform clock for Fusion"):
        flt.run(flt.init(_g0()), ts ** 1.01, us, ys)
    for kw, name in (({"gain": 0.0}, "gain"), ({"magnetic_rejection": -1.0}, "magnetic_rejection"),
                     ({"bias": "yes"}, "bias"), ({"broad_indexing": 1}, "broad_indexing")):
        with pytest.raises(ValueError, match=f"^{name}:"):
            Fusion(attitude_gyro_bias(), **kw)
    assert "gain=0.5" in repr(flt)
