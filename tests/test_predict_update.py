"""Separate ``predict`` and ``update`` with the per-step log-likelihood (issue 34; docs/concepts.md, "Predict and
update"), on every filter of :class:`~liemef.filters.AbstractFilter`:

* ``predict`` is ``step`` with every output missing, bit for bit, by either engine;
* ``update`` then ``predict`` is ``step`` to round-off (the Kalman baselines, and the minimum-energy filter with
  ``updates="discrete"``), gates and their counters included, and a failure in the update is step's;
* on a linear-Gaussian system the update is filterpy's ``KalmanFilter.update`` (x, P, innovation, S and
  ``log_likelihood``), and a filterpy loop of predict and update is the filters' loop;
* the log-likelihood is the Gaussian density of the innovation (scipy), on a nonlinear system with a wrapped
  angle too, over the present components;
* bad input is refused at the boundary, naming the argument (and a density sensor's sample, naming the sensor).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.stats import multivariate_normal

import liemef
from liemef.filters import CAUSES, MinimumEnergyFilter, UpdateResult
from liemef.filters.baselines import ExtendedKalmanFilter, invariant_ekf, local_ekf, ukf_m
from liemef.groups import SE2, Rn
from liemef.systems import Noise, Sensor, SensorSystem
from liemef.systems.localization import gps_position, odometry_dynamics
from refusals import raises as _raises
from tolerances import EXPORTED_C_RUN

ROOT = Path(__file__).resolve().parents[1]
R2 = Rn[2]
TIGHT = 1e-10  # against filterpy and scipy (measured: 2e-15 and below, see the tests)


def _leaves(x):
    return [np.asarray(a) for a in jax.tree_util.tree_leaves(x)]


def _max_diff(a, b) -> float:
    la, lb = _leaves(a), _leaves(b)
    assert len(la) == len(lb)
    return max(float(np.max(np.abs(p.astype(float) - q.astype(float)), initial=0.0)) for p, q in zip(la, lb,
                                                                                                      strict=True))


def _bits_equal(a, b) -> bool:
    return all(np.array_equal(p, q, equal_nan=True) for p, q in zip(_leaves(a), _leaves(b), strict=True))


# --- a linear-Gaussian system: a random walk on R^2 driven by an input, two sample sensors -------------------------
G_IN = np.array([[1.0], [-0.5]])
H_POS = np.array([[1.0, 0.5]])
H_VEL = np.array([[-0.3, 2.0]])
SIGMA = np.array([0.4, 0.7])
Q_WALK = np.array([0.3, 0.2])
X0, P0 = np.array([0.3, -0.2]), np.array([[1.0, 0.3], [0.3, 2.0]])


def _walk(g, u, t):
    return jnp.asarray(G_IN) @ u


LINEAR = SensorSystem(R2, _walk, (Sensor("a", lambda g, t: jnp.asarray(H_POS) @ g.x, Noise.sample(SIGMA[:1])),
                                  Sensor("b", lambda g, t: jnp.asarray(H_VEL) @ g.x, Noise.sample(SIGMA[1:]))),
                      Noise.density(Q_WALK), inputs=("u",))
H_ALL = np.vstack([H_POS, H_VEL])

LINEAR_FILTERS = {
    "mef-second-discrete": lambda s: MinimumEnergyFilter(s, updates="discrete"),
    "mef-first-discrete": lambda s: MinimumEnergyFilter(s, order="first", updates="discrete"),
    "mef-hold": lambda s: MinimumEnergyFilter(s),  # update is the hybrid filter's whatever `updates`
    "iekf": invariant_ekf,
    "ekf-right": lambda s: ExtendedKalmanFilter(s, "right"),
    "ukf": lambda s: ukf_m(s, spread=0.5),  # spread 1e-3 adds ~1e-6 of round-off amplification (5.7e-11 here)
}


def _filterpy(x, P, y):
    """filterpy's update with the present components of y; returns the KalmanFilter after it."""
    ok = np.isfinite(y)
    kf = KalmanFilter(dim_x=2, dim_z=int(ok.sum()))
    kf.x, kf.P, kf.H, kf.R = x.copy(), P.copy(), H_ALL[ok], np.diag(SIGMA[ok] ** 2)
    kf.update(y[ok])
    return kf


@pytest.mark.parametrize("name", list(LINEAR_FILTERS))
@pytest.mark.parametrize("y", [np.array([0.7, -1.1]), np.array([np.nan, 2.5])], ids=["both", "one-missing"])
def test_update_is_filterpys_kalman_update_on_a_linear_gaussian_system(name, y):
    """x, P, the innovation, S, the NIS and the log-likelihood agree with filterpy's, with a correlated prior and
    with one sensor's sample missing (measured 4.4e-16; the UKF with spread 0.5, 1.8e-15)."""
    flt = LINEAR_FILTERS[name](LINEAR)
    state, res = flt.update(flt.init(R2(jnp.asarray(X0)), P0), 0.0, y)
    kf = _filterpy(X0, P0, y)
    ok = np.isfinite(y)
    assert isinstance(res, UpdateResult) and bool(state.status.code == 0)
    assert np.abs(np.asarray(state.g_hat.x) - kf.x).max() < TIGHT
    assert np.abs(np.asarray(state.K) - kf.P).max() < TIGHT
    assert abs(float(res.log_likelihood) - kf.log_likelihood) < TIGHT
    assert np.abs(np.asarray(res.innovation)[ok] - kf.y).max() < TIGHT
    assert np.all(np.isnan(np.asarray(res.innovation)[~ok]))
    S = np.asarray(res.S)
    assert np.abs(S[np.ix_(ok, ok)] - kf.S).max() < TIGHT
    assert np.all(np.isnan(S[~ok])) and np.all(np.isnan(S[:, ~ok]))
    assert abs(float(res.nis) - kf.mahalanobis**2) < TIGHT
    assert np.asarray(res.sensors_used).tolist() == ok.tolist()


@pytest.mark.parametrize("name", ["mef-second-discrete", "iekf"])
def test_a_filterpy_loop_of_predict_and_update_is_the_filters_loop(name):
    """filterpy's predict (F = I, B = G dt, Q = diag(q^2) dt: the walk's exact discretization) and update over
    uneven times with missing components, against the filter's predict and update: priors, posteriors and the
    summed log-likelihood agree to 1e-10 (measured over 25 samples: 1.4e-15 in the states, 6e-14 in a sum of
    -367)."""
    rng = np.random.default_rng(3)
    N = 25
    ts = np.cumsum(np.concatenate([[0.0], rng.uniform(0.05, 0.3, N - 1)]))
    us, ys = rng.standard_normal((N, 1)), 2.0 * rng.standard_normal((N, 2))
    ys[rng.random((N, 2)) < 0.3] = np.nan
    flt = LINEAR_FILTERS[name](LINEAR)
    state = flt.init(R2(jnp.asarray(X0)), P0)
    x, P = X0.copy(), P0.copy()
    ours = theirs = 0.0
    for k in range(N):
        if k > 0:
            dt = ts[k] - ts[k - 1]
            state = flt.predict(state, ts[k - 1], us[k - 1], dt, engine="xla")
            kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=1)
            kf.x, kf.P, kf.F, kf.B, kf.Q = x, P, np.eye(2), G_IN * dt, np.diag(Q_WALK**2) * dt
            kf.predict(u=us[k - 1])
            x, P = kf.x.copy(), kf.P.copy()
        assert np.abs(np.asarray(state.g_hat.x) - x).max() < TIGHT and np.abs(np.asarray(state.K) - P).max() < TIGHT
        state, res = flt.update(state, ts[k], ys[k])
        if np.isfinite(ys[k]).any():
            kf = _filterpy(x, P, ys[k])
            x, P = kf.x.copy(), kf.P.copy()
            theirs += kf.log_likelihood
        else:
            assert float(res.log_likelihood) == 0.0 and float(res.nis) == 0.0
        ours += float(res.log_likelihood)
    assert abs(ours - theirs) < TIGHT * max(1.0, abs(theirs))
    assert np.abs(np.asarray(state.g_hat.x) - x).max() < TIGHT and np.abs(np.asarray(state.K) - P).max() < TIGHT


def _factor(std, params, y):
    return params[0]  # the sample's information times this factor


def test_the_sensors_own_noise_model_is_the_samples_noise():
    """A sensor whose noise model ``scale`` quarters the information (std doubled) updates and scores the
    sample as filterpy with R = (2 sigma)^2."""
    sensor = Sensor("a", lambda g, t: jnp.asarray(H_ALL) @ g.x, Noise.sample(SIGMA), scale=_factor,
                    scale_params=[0.25])
    system = SensorSystem(R2, _walk, (sensor,), Noise.density(Q_WALK), inputs=("u",))
    flt = MinimumEnergyFilter(system, updates="discrete")
    y = np.array([0.7, -1.1])
    state, res = flt.update(flt.init(R2(jnp.asarray(X0)), P0), 0.0, y)
    kf = KalmanFilter(dim_x=2, dim_z=2)
    kf.x, kf.P, kf.H, kf.R = X0.copy(), P0.copy(), H_ALL, np.diag((2 * SIGMA) ** 2)
    kf.update(y)
    assert abs(float(res.log_likelihood) - kf.log_likelihood) < TIGHT
    assert np.abs(np.asarray(state.K) - kf.P).max() < TIGHT


# --- a nonlinear system: SE(2) with odometry, GPS (gated) and a landmark's range and bearing (an angle) -------------
LANDMARK = jnp.array([-2.65, -1.72])  # behind the robot: its bearing wraps during the log


def range_bearing(g, t):
    c, s, x, y = g.cos_sin_xy
    d = LANDMARK - jnp.stack([x, y])
    return jnp.stack([jnp.linalg.norm(d), jnp.arctan2(d[1], d[0]) - jnp.arctan2(s, c)])


def robot(gate=0.99, max_rejections=None, gps_noise=None):
    return SensorSystem(
        SE2, odometry_dynamics,
        (Sensor("gps", gps_position, gps_noise or Noise.sample([0.5, 0.5]), gate=gate, max_rejections=max_rejections),
         Sensor("rb", range_bearing, Noise.sample([0.2, 0.05]), angles=[1])),
        Noise.density([0.05, 0.1, 0.1]), inputs=("vx", "vy", "w"))


G0, K0 = SE2.from_coords(jnp.array([0.3, 0.5, -0.2])), np.diag([0.1, 0.5, 0.5])
ROBOT_FILTERS = {
    "mef-second": lambda s: MinimumEnergyFilter(s, updates="discrete"),
    "mef-first": lambda s: MinimumEnergyFilter(s, order="first", updates="discrete"),
    "mef-exact-curvature": lambda s: MinimumEnergyFilter(s, updates="discrete", curvature="exact"),
    "iekf": invariant_ekf,
    "ekf-local": local_ekf,
    "ukf": ukf_m,
}


def _robot_log(N=24, seed=0):
    """Samples along the robot's turn (1 m/s forward, 0.1 m/s lateral, 0.3 rad/s) from ``G0``: GPS missing every
    4th time and an outlier at k = 10 (the gate rejects it), the bearing wrapping from -pi to pi on the way,
    one range missing."""
    rng = np.random.default_rng(seed)
    ts = 0.1 * np.arange(N)
    us = np.tile([1.0, 0.1, 0.3], (N, 1))
    ys = np.empty((N, 4))
    g = G0
    for k in range(N):
        h = np.concatenate([np.asarray(gps_position(g, 0.0)), np.asarray(range_bearing(g, 0.0))])
        ys[k] = h + rng.standard_normal(4) * [0.5, 0.5, 0.2, 0.05]
        g = g @ SE2.exp(jnp.asarray([us[k, 2], us[k, 0], us[k, 1]]) * 0.1)
    ys[:, 3] = (ys[:, 3] + math.pi) % (2 * math.pi) - math.pi  # as a sensor reports it, in [-pi, pi)
    ys[::4, :2] = np.nan
    ys[10, :2] = [50.0, 50.0]
    ys[7, 2] = np.nan
    return ts, us, ys


# By XLA in make test: the second order, the IEKF and the UKF (three tolerances); the other three in make test-slow
_XLA_SLOW = ("mef-first", "mef-exact-curvature", "ekf-local")


@pytest.mark.parametrize(("name", "engine"), [
    pytest.param(name, engine, marks=[pytest.mark.slow] if engine == "xla" and name in _XLA_SLOW else [])
    for name in ROBOT_FILTERS for engine in ("xla", "c")])
def test_predict_after_update_is_step(name, engine):
    """``predict(update(state, t, y), t, u, dt)`` against ``step(state, t, u, y, dt)`` along a log, from step's
    states: estimate, K and the status (gate counters included) agree to round-off. By XLA, measured 0 for the
    minimum-energy filter, 4e-16 for the EKFs and 3e-14 for the UKF (its weight w0 ~ -1e6 amplifies round-off).
    By C, step's update is the C kernel's and update's is XLA's, so the difference is the engines' (measured up
    to 1.5e-10, the exact curvature's Newton iterations at one sample, and 2.6e-10 for the UKF; the C step
    against the XLA step differs by as much): held to EXPORTED_C_RUN."""
    flt = ROBOT_FILTERS[name](robot())
    ts, us, ys = _robot_log()
    state, worst, rejected = flt.init(G0, K0), 0.0, 0
    for k in range(ts.size - 1):
        dt = ts[k + 1] - ts[k]
        stepped = flt.step(state, ts[k], us[k], ys[k], dt, engine=engine)
        updated, res = flt.update(state, ts[k], ys[k])
        split = flt.predict(updated, ts[k], us[k], dt, engine=engine)
        worst = max(worst, _max_diff(stepped, split))
        rejected += int(np.isfinite(ys[k, 0]) and not bool(res.sensors_used[0]))
        state = stepped
    assert np.abs(np.diff(ys[:, 3])).max() > 6.0  # the bearing wrapped
    assert worst < (1e-12 if engine == "xla" else EXPORTED_C_RUN), worst
    assert bool(state.status.code == 0)
    assert int(state.status.rejected[0]) == rejected >= 1  # the outlier at k = 10, at least


@pytest.mark.parametrize("engine", ["xla", "c"])
@pytest.mark.parametrize("name", ["mef-hold", "mef-linear", "iekf"])
def test_predict_is_step_with_every_output_missing_bit_for_bit(name, engine):
    """The defined relation, by both engines, for the held samples' filter (its default ``updates="hold"``), the
    linear interpolation with ``u_next`` and a Kalman baseline."""
    flt = {"mef-hold": lambda s: MinimumEnergyFilter(s), "iekf": invariant_ekf,
           "mef-linear": lambda s: MinimumEnergyFilter(s, interpolation="linear")}[name](robot())
    state = flt.init(G0, K0)
    nan = np.full(4, np.nan)
    for k, (u, u_next) in enumerate([([1.0, 0.1, 0.3], [0.8, 0.0, 0.5]), ([np.nan] * 3, None)]):
        a = flt.predict(state, 0.1 * k, u, 0.1, u_next=u_next, gap=0.05, engine=engine)
        b = flt.step(state, 0.1 * k, u, nan, 0.1, u_next=u_next, gap=0.05, engine=engine)
        assert _bits_equal(a, b)
        assert int(a.status.gaps) == k + 1 and int(a.status.inputs_held) == k  # gap and held input counted
        state = a


def test_log_likelihood_is_the_density_of_the_wrapped_innovation():
    """On the robot, away from the estimate: the innovation is the residual with the bearing wrapped (the sample
    at +pi - 0.01 against a prediction near -pi), S = Dh K Dh^T + R with Dh the output's Jacobian at the
    estimate (here by jax.jacfwd through g exp(xi)), and the log-likelihood is scipy's Gaussian log-density of
    the innovation, over the present components only. (The robot's GPS gate passes the sample, sensors_used
    says: the filter of ROBOT_FILTERS, whose compiled update the other tests share.)"""
    flt = ROBOT_FILTERS["mef-second"](robot())
    lx, ly = (float(v) for v in LANDMARK)
    g = SE2.from_coords(jnp.array([0.0, lx + 1.0, ly + 0.02]))  # the landmark behind, bearing near -pi
    K = np.array([[0.05, 0.01, 0.0], [0.01, 0.3, 0.05], [0.0, 0.05, 0.2]])
    y = np.array([np.nan, ly + 0.1, 1.1, math.pi - 0.01])  # GPS x missing
    state, res = flt.update(flt.init(g, K), 1.0, y)
    ok = np.isfinite(y)
    h = np.concatenate([np.asarray(gps_position(g, 1.0)), np.asarray(range_bearing(g, 1.0))])
    nu = y - h
    nu[3] = (nu[3] + math.pi) % (2 * math.pi) - math.pi
    assert abs(y[3] - h[3]) > 6.0 and abs(nu[3]) < 0.1  # a wrap, and a small wrapped residual
    assert np.abs(np.asarray(res.innovation)[ok] - nu[ok]).max() < 1e-12
    Dh = np.asarray(jax.jacfwd(lambda xi: jnp.concatenate([gps_position(g.rplus(xi), 1.0),
                                                           range_bearing(g.rplus(xi), 1.0)]))(jnp.zeros(3)))
    R = np.diag([0.5, 0.5, 0.2, 0.05]) ** 2
    S = (Dh @ K @ Dh.T + R)[np.ix_(ok, ok)]
    assert np.abs(np.asarray(res.S)[np.ix_(ok, ok)] - S).max() < 1e-12
    ref = multivariate_normal.logpdf(nu[ok], mean=np.zeros(3), cov=S)
    assert abs(float(res.log_likelihood) - ref) < TIGHT
    assert abs(float(res.nis) - nu[ok] @ np.linalg.solve(S, nu[ok])) < TIGHT
    assert np.asarray(res.sensors_used).tolist() == [True, True]
    # the update moved the estimate towards the samples and shrank K
    assert np.trace(np.asarray(state.K)) < np.trace(K)


@pytest.mark.parametrize("name", ["mef-second", "iekf"])
def test_an_update_without_a_sample_is_the_identity_with_likelihood_zero(name):
    flt = ROBOT_FILTERS[name](robot())
    state = flt.init(G0, K0)
    out, res = flt.update(state, 0.0, np.full(4, np.nan))
    assert _bits_equal(out, state)
    assert float(res.log_likelihood) == 0.0 and float(res.nis) == 0.0
    assert np.all(np.isnan(np.asarray(res.innovation))) and np.all(np.isnan(np.asarray(res.S)))
    assert not np.asarray(res.sensors_used).any()


@pytest.mark.parametrize("name", ["mef-second", "iekf"])
def test_the_gate_screens_the_update_not_the_likelihood(name):
    """An outlier fix: the gate rejects it (counted in the status, GPS not used; the range and bearing still
    are), and its log-likelihood is the model's, the Gaussian density of the far innovation."""
    flt = ROBOT_FILTERS[name](robot())
    state = flt.init(G0, K0)
    y = np.array([50.0, 50.0, 5.0, 0.9])
    out, res = flt.update(state, 0.0, y)
    assert np.asarray(res.sensors_used).tolist() == [False, True]
    assert np.asarray(out.status.rejected).tolist() == [1, 0] and np.asarray(out.status.consecutive).tolist() == [1, 0]
    ok = np.ones(4, bool)
    ref = multivariate_normal.logpdf(np.asarray(res.innovation), mean=np.zeros(4), cov=np.asarray(res.S))
    assert ref < -1e3 and abs(float(res.log_likelihood) - ref) < TIGHT * abs(ref)
    # the same update without the fix: the gate removed exactly the GPS sample
    alone, _ = flt.update(state, 0.0, np.where(ok & (np.arange(4) >= 2), y, np.nan))
    assert _max_diff((out.g_hat, out.K), (alone.g_hat, alone.K)) < 1e-12


@pytest.mark.parametrize("name", ["mef-second", "iekf"])
def test_a_failing_update_is_steps_failure(name):
    """A gate allowed one rejection in a row: the second outlier fails the update with cause ``gate`` at the
    interval that starts at its time, keeping the state given, as step fails; step counts the interval in
    ``steps``, update does not (it takes none). A failed state then stays as it is through update and predict."""
    flt = ROBOT_FILTERS[name](robot(max_rejections=1))
    outlier = np.array([50.0, 50.0, np.nan, np.nan])
    state = flt.step(flt.init(G0, K0), 0.0, [1.0, 0.0, 0.1], outlier, 0.1, engine="xla")
    assert bool(state.status.code == 0) and int(state.status.consecutive[0]) == 1
    failed, _ = flt.update(state, 0.1, outlier)
    stepped = flt.step(state, 0.1, [1.0, 0.0, 0.1], outlier, 0.1, engine="xla")
    assert int(failed.status.code) == CAUSES.GATE.code == int(stepped.status.code)
    assert int(failed.status.index) == int(stepped.status.index) == 1
    assert float(failed.status.time) == float(stepped.status.time) == 0.1
    assert _bits_equal((failed.g_hat, failed.K), (state.g_hat, state.K))
    assert _max_diff((failed.g_hat, failed.K), (stepped.g_hat, stepped.K)) == 0.0
    assert int(failed.status.steps) == 1 and int(stepped.status.steps) == 2
    again, res = flt.update(failed, 0.2, np.array([0.1, 0.2, 5.0, 0.9]))
    assert _bits_equal(again, failed) and bool(np.isfinite(res.log_likelihood))
    assert _bits_equal(flt.predict(failed, 0.2, [1.0, 0.0, 0.1], 0.1, engine="xla"), failed)


def test_update_compiles_once_per_filter_structure():
    from liemef.filters import TRACES

    flt = MinimumEnergyFilter(robot(), updates="discrete")
    state = flt.init(G0, K0)
    flt.update(state, 0.0, np.array([0.1, 0.2, 5.0, 0.9]))
    before = TRACES["update"]
    for k in range(3):  # new times, samples, missing components and a filter of new noise levels
        y = np.array([0.1 * k, np.nan, 5.0, 0.9])
        state, _ = flt.update(state, 0.1 * k, y)
    other = MinimumEnergyFilter(robot(gps_noise=Noise.sample([2.0, 3.0])), updates="discrete")
    other.update(other.init(G0, K0), 0.0, np.array([0.1, 0.2, 5.0, 0.9]))
    assert TRACES["update"] == before


# --- the docs' loop -------------------------------------------------------------------------------------------------
def test_the_docs_loop_runs_and_its_priors_are_runs_states():
    """docs/concepts.md's filterpy-style loop runs as written; the same loop's priors are ``run``'s states (to
    1e-12, measured 2.7e-15) and its summed log-likelihood is finite and the sum of the updates'."""
    text = (ROOT / "docs" / "concepts.md").read_text()
    section = text.split("### Predict and update", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    ns: dict = {}
    exec(compile(block, "docs/concepts.md", "exec"), ns)  # noqa: S102
    flt, ts, us, ys = ns["flt"], ns["ts"], ns["us"], ns["ys"]
    assert math.isfinite(ns["log_likelihood"]) and ns["log_likelihood"] < 0.0
    state = flt.init(SE2.from_coords(np.zeros(3)), np.diag([0.1, 1.0, 1.0]))
    traj = flt.run(state, ts, us, ys, gap=math.inf)
    total = 0.0
    for k in range(ts.size):
        if k > 0:
            state = flt.predict(state, ts[k - 1], us[k - 1], ts[k] - ts[k - 1])
        prior = jax.tree_util.tree_map(lambda a, k=k: np.asarray(a)[k], (traj.g_hat, traj.K))
        assert _max_diff((state.g_hat, state.K), prior) < 1e-12
        state, res = flt.update(state, ts[k], ys[k])
        total += float(res.log_likelihood)
    assert total == ns["log_likelihood"]


# --- input checked at the boundary --------------------------------------------------------------------------------


def test_update_refuses_bad_input_naming_the_argument():
    flt = MinimumEnergyFilter(robot(), updates="discrete")
    state = flt.init(G0, K0)
    y = np.array([0.1, 0.2, 5.0, 0.9])
    _raises(lambda: flt.update("state", 0.0, y), "state", "FilterState", "str")
    other = MinimumEnergyFilter(LINEAR)
    _raises(lambda: flt.update(other.init(R2(jnp.asarray(X0)), P0), 0.0, y), "state", "SE2", "R2")
    for t in (math.nan, math.inf, "soon", None):
        _raises(lambda t=t: flt.update(state, t, y), "t:", "finite time", str(t))
    _raises(lambda: flt.update(state, 0.0, y[:3]), "y:", "shape (4,)", "(3,)")
    _raises(lambda: flt.update(state, 0.0, np.append(y, 1.0)[None]), "y:", "shape (4,)", "(1, 5)")
    _raises(lambda: flt.update(state, 0.0, [0.1, np.inf, 5.0, 0.9]), "y:", "finite values or NaN", "inf", "(1,)")
    _raises(lambda: flt.update(state, 0.0, np.array([1j, 0, 0, 0])), "y")
    _raises(lambda: flt.update(state, 0.0, ["a", "b", "c", "d"]), "y")


def test_update_refuses_a_density_sensors_sample_naming_the_sensor():
    """A density sensor has no per-sample information: its sample is refused (the message says to use step);
    the same sample with that sensor missing is updated."""
    system = SensorSystem(SE2, odometry_dynamics,
                          (Sensor("gps", gps_position, Noise.sample([0.5, 0.5])),
                           Sensor("compass", lambda g, t: g.cos_sin_xy[:2], Noise.density([0.01, 0.01]))),
                          Noise.density([0.05, 0.1, 0.1]), inputs=("vx", "vy", "w"))
    for flt in (MinimumEnergyFilter(system, updates="discrete"), invariant_ekf(system)):
        state = flt.init(G0, K0)
        _raises(lambda flt=flt, state=state: flt.update(state, 0.0, [0.1, 0.2, np.nan, 0.3]),
                "y:", "'compass'", "density", "index 3", "use step")
        out, res = flt.update(state, 0.0, [0.1, 0.2, np.nan, np.nan])
        assert np.asarray(res.sensors_used).tolist() == [True, False] and bool(out.status.code == 0)
    # a system of the papers' kind: one density block
    papers = liemef.systems.PlanarRigidBody()
    flt = MinimumEnergyFilter(papers)
    _raises(lambda: flt.update(flt.init(papers.group.identity(), np.eye(papers.group.tangent_dim)), 0.0,
                               np.zeros(papers.output_dim)), "y:", "density", "use step")


def test_predict_refuses_bad_input_as_step_does():
    flt = MinimumEnergyFilter(robot(), updates="discrete")
    state = flt.init(G0, K0)
    u = [1.0, 0.0, 0.1]
    _raises(lambda: flt.predict(state, 0.0, u, 0.0, engine="xla"), "dt:", "> 0", "0.0")
    _raises(lambda: flt.predict(state, 0.0, u, math.nan, engine="xla"), "dt:")
    for t in (math.inf, "soon"):  # a non-number too (step's check, which raised a TypeError for it before)
        _raises(lambda t=t: flt.predict(state, t, u, 0.1, engine="xla"), "t:", "finite time", t)
        _raises(lambda t=t: flt.step(state, t, u, np.full(4, np.nan), 0.1), "t:", "finite time", t)
    _raises(lambda: flt.predict(state, 0.0, u[:2], 0.1, engine="xla"), "u:", "shape (3,)", "(2,)")
    _raises(lambda: flt.predict(state, 0.0, u, 0.1, u_next=[1.0], engine="xla"), "u_next:", "shape (3,)")
    _raises(lambda: flt.predict(None, 0.0, u, 0.1, engine="xla"), "state", "FilterState")
    _raises(lambda: flt.predict(state, 0.0, u, 0.1, engine="gpu"), "engine")
