"""Sensors -> Theorem 4.1: the weights a SensorSystem derives from noise levels, and what the engine does with them.

docs/weights.md and the docstring of ``liemef.systems._sensors``:

* ``Noise.density(s)``: a measurement weighs ``1/s^2`` per unit time; a process noise adds ``s^2`` per unit time;
* ``Noise.sample(sigma, rate=f)`` held as an input: density ``s^2 = sigma^2 / f``;
* ``Noise.sample(sigma)`` as a measurement: its information ``1/sigma^2`` once, i.e. ``1/(sigma^2 dt)`` over the
  interval ``dt`` that follows the sample.

The last three tests are about outliers on the SE(2) localization system (GPS at 1 Hz, odometry at 100 Hz): a
gate removes an outlier exactly, Huber and Cauchy losses shrink its effect.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef.filters import Weights, information_in_force
from liemef.groups import SE2, Rn
from liemef.systems import Noise, Sensor, SensorSystem, planar_localization
from liemef.systems.localization import gps_position, odometry_dynamics
from localization_scenario import K0 as K0_LOC
from localization_scenario import localization_log
from tolerances import ROUNDOFF, SUBSTEP_RK4

R1, R3 = Rn[1], Rn[3]


# --- the matrices -------------------------------------------------------------------------------------------------
def _three_state_system(process=None):
    sensors = (Sensor("pos", lambda g, t: g.x[:2], Noise.sample([0.5, 2.0]), ("x", "y")),
               Sensor("vel", lambda g, t: g.x[2], Noise.density(0.3)))
    noise_map = np.array([[1.0, 0.0], [0.0, 0.0], [0.5, 2.0]])
    process = Noise.density([0.1, 0.4]) if process is None else process
    return SensorSystem(R3, lambda g, u, t: jnp.zeros(3), sensors, process, noise_map=noise_map)


def test_matrices_follow_the_documented_formulas():
    """D = diag(std), Q = I, information = D^-T Q D^-1 = diag(1/std^2); B = noise_map diag(density std), R = I."""
    sys_ = _three_state_system()
    std = np.array([0.5, 2.0, 0.3])
    noise_map = np.array([[1.0, 0.0], [0.0, 0.0], [0.5, 2.0]])
    B = noise_map * np.array([0.1, 0.4])
    for got, want in ((sys_.D, np.diag(std)), (sys_.Q, np.eye(3)), (sys_.information(), np.diag(1 / std**2)),
                      (sys_.B, B), (sys_.R, np.eye(2))):
        np.testing.assert_allclose(np.asarray(got), want, rtol=ROUNDOFF, atol=0)
    w = Weights.of(sys_)
    np.testing.assert_allclose(np.asarray(w.Wy), np.diag(1 / std**2), rtol=ROUNDOFF, atol=0)
    np.testing.assert_allclose(np.asarray(w.BRB), B @ B.T, rtol=ROUNDOFF, atol=ROUNDOFF)
    assert [b.sample for b in sys_.blocks()] == [True, False]


def test_process_sample_at_rate_is_density_sigma2_over_f():
    """A process-noise sample of std sigma held over 1/f is the density sigma / sqrt(f): B R^-1 B^T = sigma^2 / f;
    without its rate it is refused."""
    sigma, f = np.array([0.2, 0.05]), 50.0
    sampled = _three_state_system(Noise.sample(sigma, rate=f))
    dense = _three_state_system(Noise.density(sigma / np.sqrt(f)))
    brb = lambda s: np.asarray(Weights.of(s).BRB)  # noqa: E731
    np.testing.assert_allclose(brb(sampled), brb(dense), rtol=ROUNDOFF, atol=ROUNDOFF)
    noise_map = np.array([[1.0, 0.0], [0.0, 0.0], [0.5, 2.0]])
    np.testing.assert_allclose(brb(sampled), noise_map @ np.diag(sigma**2 / f) @ noise_map.T, rtol=ROUNDOFF,
                               atol=ROUNDOFF)
    with pytest.raises(ValueError, match="needs its rate"):
        _three_state_system(Noise.sample(sigma))


def test_information_in_force_divides_samples_by_the_interval():
    """Over an interval dt the sample components weigh 1/(sigma^2 dt), the density ones 1/s^2, missing ones 0."""
    sys_ = _three_state_system()
    Wy = sys_.information()
    sample = np.array([True, True, False])
    for dt in (0.01, 0.5, 7.0):
        for mask in ([True, True, True], [True, False, True], [False, True, False]):
            mask = np.array(mask)
            want = np.diag(np.where(mask, np.array([1 / 0.25, 1 / 4.0, 1 / 0.09]) / np.where(sample, dt, 1.0), 0.0))
            for diagonal in (True, False):
                got = np.asarray(information_in_force(Wy, sample, mask, dt, diagonal=diagonal))
                np.testing.assert_allclose(got, want, rtol=ROUNDOFF, atol=0)


def test_with_noise_changes_only_leaves():
    """with_noise: the same structure (static fields, tree), new std leaves where asked, the others untouched;
    a change of meaning or rate (structure) is refused."""
    sys_ = _three_state_system()
    new = sys_.with_noise(pos=Noise.sample([0.7, 0.9]), vel=Noise.density(0.05),
                          process_noise=Noise.density([1.0, 2.0]))
    dyn0, static0 = eqx.partition(sys_, eqx.is_array)
    dyn1, static1 = eqx.partition(new, eqx.is_array)
    assert jax.tree_util.tree_structure(sys_) == jax.tree_util.tree_structure(new)
    assert jax.tree_util.tree_structure(dyn0) == jax.tree_util.tree_structure(dyn1)
    assert eqx.tree_equal(static0, static1) is True
    assert [b for b in sys_.blocks()] == [b for b in new.blocks()]
    np.testing.assert_array_equal(np.asarray(new.D), np.diag([0.7, 0.9, 0.05]))
    np.testing.assert_array_equal(np.asarray(new.B), np.array([[1.0, 0.0], [0.0, 0.0], [0.5, 4.0]]))
    np.testing.assert_array_equal(np.asarray(new.noise_map), np.asarray(sys_.noise_map))
    one = sys_.with_noise(vel=Noise.density(0.05))
    np.testing.assert_array_equal(np.asarray(one.D), np.diag([0.5, 2.0, 0.05]))
    with pytest.raises(ValueError, match="keep the meaning 'density'"):
        sys_.with_noise(vel=Noise.sample(0.05))
    with pytest.raises(ValueError, match="unknown sensor 'gps'"):
        sys_.with_noise(gps=Noise.sample(1.0))


# --- what the engine does with them: R^1, no dynamics, no process noise ----------------------------------------
SIGMA, S_DENSITY, K0, X0 = 0.8, 3.0, 2.0, 0.4


@pytest.fixture(scope="module")
def scalar():
    """R^1 with lambda = 0, B = 0 and two sensors of x: ``a`` one sample of std SIGMA, ``b`` density S_DENSITY.
    Then 1/K grows by exactly the information of an interval, and K^-1 x by that information times y."""
    sensors = (Sensor("a", lambda g, t: g.x, Noise.sample(SIGMA)),
               Sensor("b", lambda g, t: g.x, Noise.density(S_DENSITY)))
    sys_ = SensorSystem(R1, lambda g, u, t: jnp.zeros(1), sensors, Noise.density(1.0), noise_map=np.zeros((1, 1)))
    return liemef.MinimumEnergyFilter(sys_, substeps=256)


def _information_run(flt, ts, ys):
    state = flt.init(R1(jnp.array([X0])), np.array([[K0]]))
    traj = flt.run(state, ts, None, ys, gap=1e9)
    assert traj.status.ok
    info = 1.0 / np.asarray(traj.K)[:, 0, 0]
    return info, info * np.asarray(traj.g_hat.x)[:, 0]


def test_sample_information_counts_once_whatever_the_interval(scalar):
    """A sample of std sigma adds 1/sigma^2 to K^-1 (and y/sigma^2 to K^-1 x), over an interval of 0.01 s, 1 s
    or 100 s alike: the discrete Kalman update, spread over the interval (exact here: RK4 sub-steps only)."""
    dts = np.array([0.01, 1.0, 100.0, 0.3])
    ts = np.concatenate([[0.0], np.cumsum(dts)])
    y = np.array([1.0, -0.5, 2.0, 0.7, 0.0])
    ys = np.column_stack([y, np.full(5, np.nan)])
    info, info_x = _information_run(scalar, ts, ys)
    want = 1 / K0 + np.arange(5) / SIGMA**2
    want_x = X0 / K0 + np.concatenate([[0.0], np.cumsum(y[:4])]) / SIGMA**2
    np.testing.assert_allclose(info, want, rtol=SUBSTEP_RK4)
    np.testing.assert_allclose(info_x, want_x, rtol=SUBSTEP_RK4, atol=SUBSTEP_RK4)


def test_density_information_grows_with_the_interval(scalar):
    """A density measurement s, held over dt, adds dt/s^2 to K^-1 (and dt y/s^2 to K^-1 x)."""
    dts = np.array([0.01, 1.0, 20.0, 0.3])
    ts = np.concatenate([[0.0], np.cumsum(dts)])
    y = np.array([1.0, -0.5, 2.0, 0.7, 0.0])
    ys = np.column_stack([np.full(5, np.nan), y])
    info, info_x = _information_run(scalar, ts, ys)
    want = 1 / K0 + np.concatenate([[0.0], np.cumsum(dts)]) / S_DENSITY**2
    want_x = X0 / K0 + np.concatenate([[0.0], np.cumsum(dts * y[:4])]) / S_DENSITY**2
    assert want[3] - want[2] == pytest.approx(20 * (want[2] - want[1]))  # 20 s carry 20x the information of 1 s
    np.testing.assert_allclose(info, want, rtol=SUBSTEP_RK4)
    np.testing.assert_allclose(info_x, want_x, rtol=SUBSTEP_RK4, atol=SUBSTEP_RK4)


def test_sample_at_the_filter_rate_is_the_held_density(scalar):
    """A sensor sampled every dt = 1/f with std sigma is the zero-order hold of the density s = sigma / sqrt(f):
    the same run to round-off (with_noise sets s without a new filter structure)."""
    f = 100.0
    ts = np.arange(60) / f
    y = np.sin(3 * ts) + 0.1 * np.random.default_rng(0).standard_normal(ts.size)
    a = _information_run(scalar, ts, np.column_stack([y, np.full(ts.size, np.nan)]))
    flt_b = liemef.MinimumEnergyFilter(scalar.system.with_noise(b=Noise.density(SIGMA / np.sqrt(f))), substeps=256)
    b = _information_run(flt_b, ts, np.column_stack([np.full(ts.size, np.nan), y]))
    assert a[0][-1] > 50 * a[0][0]
    np.testing.assert_allclose(a[0], b[0], rtol=ROUNDOFF)
    np.testing.assert_allclose(a[1], b[1], rtol=ROUNDOFF, atol=ROUNDOFF)


# --- outliers: gate and robust losses on SE(2) localization -------------------------------------------------------
K_OUT = 1500  # the outlier: GPS fix at t = 15 s


def _coords_diff(a, b):
    """max |heading difference| (wrapped, rad) and max |position difference| (m) of two runs."""
    ca, cb = np.asarray(a.coords()), np.asarray(b.coords())
    dth = np.angle(np.exp(1j * (ca[:, 0] - cb[:, 0])))
    return np.abs(dth).max(), np.abs(ca[:, 1:] - cb[:, 1:]).max()


@pytest.fixture(scope="module")
def outlier_logs():
    ts, _, us, ys, th0 = localization_log(5, t_end=20.0)
    assert np.isfinite(ys[K_OUT]).all()
    ys_out, ys_nan = ys.copy(), ys.copy()
    ys_out[K_OUT, 0] += 1e4
    ys_nan[K_OUT] = np.nan
    return ts, us, ys_out, ys_nan, SE2.from_coords(jnp.array([th0, 0.0, 0.0]))


def test_gate_removes_an_outlier_exactly(outlier_logs):
    """planar_localization(gate=0.999): a 1e4 m error on one GPS fix is rejected (counted once) and the run
    equals, to round-off, the run where that fix is missing."""
    ts, us, ys_out, ys_nan, g0 = outlier_logs
    flt = liemef.MinimumEnergyFilter(planar_localization(gate=0.999))
    state = flt.init(g0, K0_LOC)
    gated, missing = flt.run(state, ts, us, ys_out), flt.run(state, ts, us, ys_nan)
    assert gated.status.ok and missing.status.ok
    assert int(gated.status.rejected[0]) == 1 and int(missing.status.rejected[0]) == 0
    dth, dp = _coords_diff(gated, missing)
    assert dth <= ROUNDOFF and dp <= ROUNDOFF, (dth, dp)
    np.testing.assert_allclose(np.asarray(gated.K), np.asarray(missing.K), rtol=0, atol=ROUNDOFF)


def test_robust_losses_shrink_an_outliers_effect(outlier_logs):
    """The same outlier without a gate, with a Huber and with a Cauchy loss (each against its own run without
    the fix). Measured: no gate moves the estimate by ~11 m (a 2nd-order filter: the huge residual also enters
    E), Huber by ~0.37 m, Cauchy by ~1e-4 m. The three GPS sensors share one system (the other two columns
    NaN: a missing sensor is the system without it, tests/test_missing_samples.py), so one compilation serves
    all three losses."""
    ts, us, ys_out, ys_nan, g0 = outlier_logs
    gps = {name: Sensor(f"gps_{name}", gps_position, Noise.sample(1.0), ("x", "y"), robust=robust)
           for name, robust in (("plain", None), ("huber", "huber"), ("cauchy", "cauchy"))}
    loc = planar_localization()
    sys_ = SensorSystem(SE2, odometry_dynamics, tuple(gps.values()), loc.process_noise, inputs=loc.inputs)
    flt = liemef.MinimumEnergyFilter(sys_)
    state = flt.init(g0, K0_LOC)
    effect = {}
    for i, name in enumerate(gps):
        def only(ys, i=i):
            out = np.full((ys.shape[0], 6), np.nan)
            out[:, 2 * i:2 * i + 2] = ys
            return out

        a, b = flt.run(state, ts, us, only(ys_out)), flt.run(state, ts, us, only(ys_nan))
        assert a.status.ok and b.status.ok, name
        effect[name] = _coords_diff(a, b)
    print({k: (f"{v[0]:.3g} rad", f"{v[1]:.3g} m") for k, v in effect.items()})
    assert effect["plain"][1] > 5.0
    assert effect["huber"][1] < 0.1 * effect["plain"][1] and effect["huber"][1] < 1.0
    assert effect["cauchy"][1] < 1e-3 and effect["cauchy"][0] < 1e-3
    assert effect["cauchy"][1] < effect["huber"][1]
