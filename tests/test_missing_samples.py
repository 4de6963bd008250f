"""Missing samples are a mask, not a branch (docs/weights.md), and the mask is exact.

A NaN in ``y`` removes that component's information over the interval that follows it: the filter equals, over
that interval, the filter of the system built without the component (for correlated components: the system of
their marginal). A NaN in ``u`` holds the last input. All on SO(2) x R (angle and gyro bias, n = 2), whose
outputs are nonlinear, so the second-order terms are exercised too.
"""

import math
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef.engines import LogGapWarning
from liemef.groups import R1, SO2, SO2R1
from liemef.systems import Noise, Sensor, SensorSystem, System
from tolerances import MARGINAL, ROUNDOFF

DT, N = 0.05, 64  # 64 samples: every run of this file, whole log or window, fits one length bucket


def dynamics(g, u, t):
    """theta_dot = u - b (gyro minus bias), b_dot = 0."""
    return jnp.concatenate([u - g.factors[1].x, jnp.zeros(1)])


def direction_a(g, t):
    """X^T (1, 0): the vector measurement of Zamani et al."""
    c, s = g.factors[0].cos_sin[0], g.factors[0].cos_sin[1]
    return jnp.stack([c, -s])


def direction_b(g, t):
    """X^T (0, 1)."""
    c, s = g.factors[0].cos_sin[0], g.factors[0].cos_sin[1]
    return jnp.stack([s, c])


def state(theta, b):
    return SO2R1((SO2.from_angle(jnp.asarray(theta)), R1(jnp.array([b]))))


G0, K0 = state(0.6, -0.2), np.array([[0.5, 0.05], [0.05, 0.3]])


def log(seed=0):
    """Truth theta(t) with rate sin(2t), bias 0.3; gyro with noise, both directions with noise."""
    rng = np.random.default_rng(seed)
    ts = DT * np.arange(N)
    theta = (1 - np.cos(2 * ts)) / 2
    us = (np.sin(2 * ts) + 0.3 + 0.05 * rng.standard_normal(N))[:, None]
    ya = np.column_stack([np.cos(theta), -np.sin(theta)]) + 0.1 * rng.standard_normal((N, 2))
    yb = np.column_stack([np.sin(theta), np.cos(theta)]) + 0.2 * rng.standard_normal((N, 2))
    return ts, us, ya, yb


PROCESS = Noise.density([0.05, 0.02])
SENSOR_A = Sensor("a", direction_a, Noise.sample(0.1), ("c", "s"))
SENSOR_B = Sensor("b", direction_b, Noise.density(0.02), ("s", "c"))


@pytest.fixture(scope="module")
def two_sensors():
    return liemef.MinimumEnergyFilter(SensorSystem(SO2R1, dynamics, (SENSOR_A, SENSOR_B), PROCESS, inputs=("w",)))


@pytest.fixture(scope="module")
def only_a():
    return liemef.MinimumEnergyFilter(SensorSystem(SO2R1, dynamics, (SENSOR_A,), PROCESS, inputs=("w",)))


def _x(traj):
    return np.asarray(traj.coords())


def _close(a, b, tol, what=""):
    (xa, Ka), (xb, Kb) = a, b
    dx, dK = np.abs(xa - xb).max(), np.abs(Ka - Kb).max()
    assert dx <= tol and dK <= tol, f"{what}: max |dx| = {dx:.3g}, max |dK| = {dK:.3g}"
    return dx, dK


def test_absent_sensor_equals_the_system_without_it(two_sensors, only_a):
    """Sensor b NaN over the whole log: the run equals the run of the system without b (to round-off)."""
    ts, us, ya, yb = log()
    ys = np.column_stack([ya, np.full_like(yb, np.nan)])
    a = two_sensors.run(two_sensors.init(G0, K0), ts, us, ys)
    b = only_a.run(only_a.init(G0, K0), ts, us, ya)
    assert a.status.ok and b.status.ok
    _close((_x(a), np.asarray(a.K)), (_x(b), np.asarray(b.K)), ROUNDOFF, "b absent")


def test_missing_window_equals_the_system_without_it_there(two_sensors, only_a):
    """Sensor b NaN over samples [k1, k2): over those intervals the two-sensor run equals the run of the system
    without b started from the two-sensor state at k1, and b's information matters elsewhere (the runs with and
    without the window differ)."""
    ts, us, ya, yb = log(1)
    k1, k2 = 20, 45
    yb_cut = yb.copy()
    yb_cut[k1:k2] = np.nan
    full = two_sensors.run(two_sensors.init(G0, K0), ts, us, np.column_stack([ya, yb]))
    cut = two_sensors.run(two_sensors.init(G0, K0), ts, us, np.column_stack([ya, yb_cut]))
    g_k1 = cut.g_hat[k1]
    part = only_a.run(only_a.init(g_k1, np.asarray(cut.K[k1])), ts[k1:k2 + 1], us[k1:k2 + 1], ya[k1:k2 + 1])
    assert full.status.ok and cut.status.ok and part.status.ok
    _close((_x(cut)[k1:k2 + 1], np.asarray(cut.K)[k1:k2 + 1]), (_x(part), np.asarray(part.K)), ROUNDOFF, "window")
    # the window is not a no-op: b's information changes the gain there
    assert np.abs(np.asarray(full.K)[k2] - np.asarray(cut.K)[k2]).max() > 1e-4


def test_density_samples_are_not_held_across_a_gap(two_sensors):
    """An interval of 2.05 s in a 0.05 s log is a gap (default threshold: 10 median intervals): density sensor b
    is not held over it (the run equals the one with b missing at its start, and a LogGapWarning says so),
    sample sensor a still counts once. gap=math.inf holds b over the gap, as step() does."""
    ts, us, ya, yb = log(4)
    ts = ts + np.where(np.arange(N) >= 30, 2.0, 0.0)
    ys = np.column_stack([ya, yb])
    ys_b_missing = ys.copy()
    ys_b_missing[29, 2:] = np.nan
    state = two_sensors.init(G0, K0)
    with pytest.warns(LogGapWarning, match="1 sample interval"):
        gapped = two_sensors.run(state, ts, us, ys)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogGapWarning)
        missing = two_sensors.run(state, ts, us, ys_b_missing, gap=math.inf)
        held = two_sensors.run(state, ts, us, ys, gap=math.inf)
    assert int(gapped.status.gaps) == 1 and int(held.status.gaps) == 0
    _close((_x(gapped), np.asarray(gapped.K)), (_x(missing), np.asarray(missing.K)), ROUNDOFF, "gap")
    assert np.abs(np.asarray(held.K)[30] - np.asarray(gapped.K)[30]).max() > 1e-3


# --- correlated components: the marginal ----------------------------------------------------------------------
D_FULL = np.array([[0.10, 0.02, 0.00], [0.03, 0.15, 0.01], [-0.02, 0.04, 0.20]])
Q_FULL = np.array([[1.0, 0.3, 0.1], [0.3, 2.0, -0.2], [0.1, -0.2, 0.5]])
B_MAP = np.diag([0.05, 0.02])


def output3(g, t):
    c, s = g.factors[0].cos_sin[0], g.factors[0].cos_sin[1]
    return jnp.stack([c, -s, s + 0.5 * g.factors[1].x[0]])


def test_missing_correlated_component_is_the_marginal():
    """A generic System with full D and Q: component 1 NaN over the whole log equals the System of components
    (0, 2) whose D, Q give the marginal covariance Sigma_SS of Sigma = (D^-T Q D^-1)^-1 = D Q^-1 D^T; and over a
    window, from the state at its start."""
    full = System(group_type=SO2R1, dynamics_fn=dynamics, output_fn=output3, B=B_MAP, D=D_FULL, Q=Q_FULL, R=np.eye(2),
                  n_inputs=1)
    Sigma = D_FULL @ np.linalg.solve(Q_FULL, D_FULL.T)
    keep = [0, 2]
    marg = System(group_type=SO2R1, dynamics_fn=dynamics, output_fn=lambda g, t: output3(g, t)[jnp.array(keep)],
                  B=B_MAP, D=np.linalg.cholesky(Sigma[np.ix_(keep, keep)]), Q=np.eye(2), R=np.eye(2), n_inputs=1)
    f_full, f_marg = liemef.MinimumEnergyFilter(full), liemef.MinimumEnergyFilter(marg)
    assert not f_full.diagonal
    ts, us, ya, yb = log(2)
    y3 = np.column_stack([ya, yb[:, 0]])
    y_miss = y3.copy()
    y_miss[:, 1] = np.nan
    a = f_full.run(f_full.init(G0, K0), ts, us, y_miss)
    b = f_marg.run(f_marg.init(G0, K0), ts, us, y3[:, keep])
    assert a.status.ok and b.status.ok
    dx, dK = _close((_x(a), np.asarray(a.K)), (_x(b), np.asarray(b.K)), MARGINAL, "marginal, whole log")
    # zeroing the row and column instead of marginalizing would be wrong: it differs by far more
    Wy = np.linalg.inv(Sigma)
    assert np.abs(np.linalg.inv(Sigma[np.ix_(keep, keep)]) - Wy[np.ix_(keep, keep)]).max() > 1.0
    # over a window only
    k1, k2 = 15, 40
    y_win = y3.copy()
    y_win[k1:k2, 1] = np.nan
    c = f_full.run(f_full.init(G0, K0), ts, us, y_win)
    d = f_marg.run(f_marg.init(c.g_hat[k1], np.asarray(c.K[k1])), ts[k1:k2 + 1], us[k1:k2 + 1], y3[k1:k2 + 1, keep])
    _close((_x(c)[k1:k2 + 1], np.asarray(c.K)[k1:k2 + 1]), (_x(d), np.asarray(d.K)), MARGINAL, "marginal, window")


# --- inputs -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("interpolation", ["hold", "linear"])
def test_missing_input_holds_the_last_one(interpolation):
    """NaN inputs (one, a run of five, and the very first, which holds init's u0) equal the log with the last
    present value repeated, with either interpolation; status.inputs_held counts them."""
    flt = liemef.MinimumEnergyFilter(SensorSystem(SO2R1, dynamics, (SENSOR_A,), PROCESS, inputs=("w",)),
                                     interpolation=interpolation)
    ts, us, ya, _ = log(3)
    u0 = np.array([0.25])
    nan_at = [0, 1, 20, 40, 41, 42, 43, 44]
    us_nan, us_rep = us.copy(), us.copy()
    us_nan[nan_at] = np.nan
    last = u0
    for k in range(N):
        if k in nan_at:
            us_rep[k] = last
        last = us_rep[k]
    a = flt.run(flt.init(G0, K0, u0=u0), ts, us_nan, ya)
    b = flt.run(flt.init(G0, K0, u0=u0), ts, us_rep, ya)
    assert a.status.ok and b.status.ok
    np.testing.assert_array_equal(_x(a), _x(b))
    np.testing.assert_array_equal(np.asarray(a.K), np.asarray(b.K))
    assert int(a.status.inputs_held) == len(nan_at) and int(b.status.inputs_held) == 0
    # and holding matters: a log with zeros in those places differs
    us_zero = us.copy()
    us_zero[nan_at] = 0.0
    c = flt.run(flt.init(G0, K0, u0=u0), ts, us_zero, ya)
    assert np.abs(_x(c) - _x(a)).max() > 1e-4
