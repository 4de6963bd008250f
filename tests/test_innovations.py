"""The innovation monitor (liemef.metrics.innovation_monitor): "ok" means consistent.

* Its NIS is the prior innovation's: on a linear system with discrete updates it is the discrete Kalman filter's
  NIS, by both engines and with a thinned history.
* False alarms: on runs of the model's own process (the hybrid tests' 100 Hz attitude system with gyro bias and
  acc/mag directions, discrete updates, which NEES finds consistent) it says "consistent"; the rates measured
  per window and per run are the docs' (docs/innovations.md).
* It speaks: a filter that believes the accelerometer 10x better than it is, or a log whose accelerometer
  degrades at t = 10 s, is "inconsistent", naming the accelerometer, above its band, at a plausible time.
* A direction residual has one degree of freedom less, and the monitor counts it.
* "not applicable" where K is not a covariance (a paper system, an AHRS baseline) or no sensor has a window.
* `liemef run` writes it to metrics.json and exits with status 3 on an inconsistent log.
* The linearization leak: its N is the covariance of the output's remainder beyond F xi under xi ~ N(0, K)
  (Monte Carlo); on a planar analogue of the quadrotor (a wall distance and a compass, the position along the wall
  unobservable) it says "nonlinear" on SE(2), whose NEES is far above its band, and "consistent" on
  SO(2) x R^2, whose NEES is in it, with a leak of exactly 0; `liemef run` exits with status 4.
"""

import functools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from liemef.cli import cli
from liemef.filters import MinimumEnergyFilter
from liemef.filters.baselines import Madgwick
from liemef.groups import SE2, SO2, TSO3, Product, Rn
from liemef.metrics import chi2_bounds, innovation_monitor, innovation_nis, left_error, linearization_leak, nees
from liemef.reports import io
from liemef.simulation import simulate
from liemef.systems import Noise, PlanarRigidBody, Sensor, SensorSystem, direction_residual, planar_localization
from liemef.systems import attitude_bias as ab
from liemef.systems import bounded_velocity as ab_vel
from localization_scenario import circle_samples
from test_hybrid import ATT_K0, ATTITUDE, G_IN, H_OUT, Q_WALK, SIGMA, WALK, _walk_log, simulate_attitude
from tolerances import ROUNDOFF

R2 = Rn[2]


# --- the prior innovation, exactly ---------------------------------------------------------------------------------
def _walk_kalman_nis(ts, us, ys, x, P):
    """The discrete Kalman filter's NIS of each fully present sample before its update (NaN elsewhere)."""
    out = np.full(len(ts), np.nan)
    for k in range(len(ts) - 1):
        ok = np.isfinite(ys[k])
        if ok.all():
            nu, S = ys[k] - H_OUT @ x, H_OUT @ P @ H_OUT.T + np.diag(SIGMA**2)
            out[k] = nu @ np.linalg.solve(S, nu)
        if ok.any():
            H, S = H_OUT[ok], np.diag(SIGMA[ok] ** 2)
            gain = P @ H.T @ np.linalg.inv(H @ P @ H.T + S)
            x, P = x + gain @ (ys[k, ok] - H @ x), (np.eye(2) - gain @ H) @ P
        dt = ts[k + 1] - ts[k]
        x, P = x + G_IN[:, 0] * us[k, 0] * dt, P + np.diag(Q_WALK**2) * dt
    return out


@pytest.mark.parametrize("engine", ["c", "xla"])
def test_nis_is_the_discrete_kalman_filters_on_a_linear_system(engine):
    """The state at ts[k] has seen the samples before k, so y_k against it is the prior innovation: measured
    max |NIS - Kalman NIS| 1.4e-14 (34 full samples of 60, uneven times, missing components)."""
    ts, us, ys = _walk_log()
    x0, P0 = np.array([0.3, -1.0]), np.array([[2.0, 0.3], [0.3, 1.0]])
    ref = _walk_kalman_nis(ts, us, ys, x0, P0)
    flt = MinimumEnergyFilter(WALK, updates="discrete", substeps=1)
    traj = flt.run(flt.init(R2(jnp.asarray(x0)), P0), ts, us, ys, gap=math.inf, engine=engine)
    nis, dof = innovation_nis(flt, traj, ts, us, ys)
    assert dof == (2,) and nis.shape == (len(ts), 1)
    np.testing.assert_array_equal(np.isnan(nis[:, 0]), np.isnan(ref))
    assert np.nanmax(np.abs(nis[:, 0] - ref) / np.maximum(1.0, ref)) <= ROUNDOFF
    # a thinned history: the kept states' samples, the same values
    thin = flt.run(flt.init(R2(jnp.asarray(x0)), P0), ts, us, ys, gap=math.inf, engine=engine, keep_every=3)
    nis3, _ = innovation_nis(flt, thin, ts, us, ys)
    np.testing.assert_allclose(nis3[::3, 0], nis[::3, 0], rtol=ROUNDOFF, atol=ROUNDOFF)
    assert np.isnan(nis3[1::3]).all()


# --- false alarms and alarms on the attitude system -----------------------------------------------------------------
GOOD = MinimumEnergyFilter(ATTITUDE, updates="discrete")


def _monitor(flt, seed, fault=None):
    ts, us, ys, _, g0 = simulate_attitude(seed)
    if fault is not None:
        ys = fault(ts, ys, np.random.default_rng(1000 + seed))
    traj = flt.run(flt.init(g0, ATT_K0), ts, us, ys, engine="c")
    assert traj.status.ok
    return innovation_monitor(flt, traj, ts, us, ys)


def false_alarms(seeds):
    """Runs not "consistent", and windows out of band over all sensors, of GOOD on the seeds' runs."""
    alarms = out = windows = 0
    for seed in seeds:
        r = _monitor(GOOD, seed)
        alarms += r.status != "consistent"
        out += sum(round(s.fraction_out * s.windows) for s in r.sensors)
        windows += sum(s.windows for s in r.sensors)
    return alarms, out, windows


def test_consistent_runs_are_consistent():
    """20 runs of 20 s (seeds 0-19; each sensor 1501 windows of 500 samples, 5 s, sustain 7.5 s): measured 0 runs
    and 0 windows out of band at prob 0.999."""
    alarms, out, windows = false_alarms(range(20))
    print(f"{alarms} of 20 runs, {out} of {windows} windows out of band")
    assert alarms == 0
    assert out / windows <= 0.005


@pytest.mark.slow  # 200 runs: about 10 s on 2 busy cores
def test_false_alarm_rates_are_the_documented_ones():
    """The rates of docs/innovations.md, 200 runs (seeds 100-299): measured 0 of 200 runs and 453 of 600400 windows
    (7.5e-4; the band's own rate is 1e-3), the longest excursion 0.8 s against a sustain time of 7.5 s."""
    alarms, out, windows = false_alarms(range(100, 300))
    print(f"{alarms} of 200 runs, {out} of {windows} windows ({out / windows:.2g}) out of band")
    assert alarms <= 1
    assert out / windows <= 2e-3


def _check_names_acc(r, start, stop):
    assert r.status == "inconsistent"
    acc, mag = r.sensors
    assert acc.name == "acc" and acc.sustained and acc.longest[2] == "high"
    assert start <= acc.first_out <= stop
    assert not mag.sustained
    line = r.message()
    assert "acc" in line and "above" in line and "mag" not in line
    d = r.as_dict()
    assert d["status"] == "inconsistent" and d["sensors"][0]["longest_excursion"]["side"] == "high"
    json.dumps(d)


def test_an_overconfident_sensor_is_named():
    """The filter's acc noise 10x too small: measured mean NIS 292 for 3 dof, out of band from the first full
    window (t = 4.99 s) to the end."""
    flt = MinimumEnergyFilter(ATTITUDE.with_noise(acc=Noise.sample(ab.ACC_STD / 10)), updates="discrete")
    r = _monitor(flt, 0)
    _check_names_acc(r, 4.99, 5.0)
    assert r.sensors[0].mean_nis > 100


def test_a_sensor_that_degrades_is_named_when_it_does():
    """From t = 10 s the accelerometer reads 10x its noise: the first window out ends within one window (5 s)
    of the change. Measured: out from t = 10.0 s (the first window holding a degraded sample) to the end."""
    def fault(ts, ys, rng):
        ys = ys.copy()
        late = ts >= 10.0
        ys[late, :3] += 10 * ab.ACC_STD * rng.standard_normal((late.sum(), 3))
        return ys

    r = _monitor(GOOD, 3, fault)
    print(r.message())
    _check_names_acc(r, 10.0, 15.0)


# --- degrees of freedom of a direction -------------------------------------------------------------------------------
def test_a_direction_residual_has_two_degrees_of_freedom():
    """acc and mag as unit directions on S^2 (direction_residual), sampled as normalized noisy vectors: the
    residual lies in the tangent plane, so the NIS has 2 dof (measured mean 1.96 and 1.97), and the run is
    consistent."""
    sensors = tuple(Sensor(name, ab.BodyDirection(v), Noise.sample([std] * 3), residual=direction_residual)
                    for name, v, std in (("acc", ab.E_UP, ab.ACC_STD),
                                         ("mag", ab.magnetic_reference(ab.DIP), ab.MAG_STD)))
    system = SensorSystem(TSO3, ab.gyro_bias_dynamics, sensors, ATTITUDE.process_noise, inputs=ab.INPUT_NAMES)
    flt = MinimumEnergyFilter(system, updates="discrete")
    ts, us, ys, _, g0 = simulate_attitude(1)
    ys = ys.reshape(-1, 2, 3)
    ys = (ys / np.linalg.norm(ys, axis=-1, keepdims=True)).reshape(-1, 6)
    traj = flt.run(flt.init(g0, ATT_K0), ts, us, ys, engine="c")
    r = innovation_monitor(flt, traj, ts, us, ys)
    print([s.mean_nis for s in r.sensors])
    assert [s.dof for s in r.sensors] == [2, 2]
    assert all(abs(s.mean_nis - 2.0) < 0.1 for s in r.sensors)
    assert r.status == "consistent"


# --- not applicable, bad input ---------------------------------------------------------------------------------------
def test_not_applicable_where_k_is_not_a_covariance_or_no_window_is_full():
    system = PlanarRigidBody()   # the paper's weights, Q = D^T D: K is a gain
    flt = MinimumEnergyFilter(system)
    ts = np.arange(50) * 0.01
    us = np.zeros((50, system.input_dim))
    ys = np.zeros((50, system.output_dim))
    traj = flt.run(flt.init(system.group.identity(), np.eye(6)), ts, us, ys)
    r = innovation_monitor(flt, traj, ts, us, ys)
    assert r.status == "not applicable" and "not a covariance" in r.message()
    assert r.as_dict()["sensors"] == []
    ts, us, ys, _, g0 = simulate_attitude(0, duration=1.0)
    ahrs = Madgwick(ATTITUDE)    # keeps no covariance
    assert innovation_monitor(ahrs, ahrs.run(ahrs.init(g0), ts, us, ys), ts, us, ys).status == "not applicable"
    short = GOOD.run(GOOD.init(g0, ATT_K0), ts[:10], us[:10], ys[:10])
    r = innovation_monitor(GOOD, short, ts[:10], us[:10], ys[:10])
    assert r.status == "not applicable" and "full window" in r.message()
    assert [s.samples for s in r.sensors] == [9, 9] and r.sensors[0].window == 500   # 5 s at 100 Hz


def test_the_message_says_times_from_the_log_start():
    from liemef.metrics import InnovationReport, SensorVerdict

    def said(t0):
        acc = SensorVerdict("acc", 2, 3000, window=100, span=1.0, band=(0.8, 1.2), windows=2900, fraction_out=0.2,
                            first_out=t0 + 10.5, longest=(t0 + 10.5, t0 + 14.0, "high"), sustain=1.5, mean_nis=3.0)
        return InnovationReport("inconsistent", (acc,), t0=t0).message()

    assert "from t = 10.5 s to t = 14 s (first out at t = 10.5 s;" in said(0.0)
    assert ("from t = t0 + 10.5 s (1700000010.5 s) to t = t0 + 14 s (1700000014 s) (first out at t = t0 + 10.5 s "
            "(1700000010.5 s);") in said(1_700_000_000.0)


def test_bad_input_names_the_argument():
    ts, us, ys, _, g0 = simulate_attitude(0, duration=0.5)
    traj = GOOD.run(GOOD.init(g0, ATT_K0), ts, us, ys)
    for kwargs, name in (({"window": 0}, "window"), ({"window": 2.5}, "window"), ({"prob": 1.0}, "prob"),
                         ({"prob": True}, "prob"), ({"sustain": -1.0}, "sustain"), ({"sustain": math.nan}, "sustain"),
                         ({"leak": 0.0}, "leak"), ({"leak": True}, "leak"), ({"leak": "1"}, "leak")):
        with pytest.raises(ValueError, match=name):
            innovation_monitor(GOOD, traj, ts, us, ys, **kwargs)
    with pytest.raises(ValueError, match="traj"):
        innovation_monitor(GOOD, traj, ts + 0.5, us, ys)
    with pytest.raises(ValueError, match="ys"):
        innovation_monitor(GOOD, traj, ts, us, ys[:, :4])
    with pytest.raises(ValueError, match="flt"):
        innovation_monitor("mef", traj, ts, us, ys)
    # the leak turned off: no leak in the report, and the report still JSON
    off = innovation_monitor(GOOD, traj, ts, us, ys, window=5, leak=math.inf)
    assert off.as_dict()["leak"] is None and off.sensors[0].leak_limit is None
    json.dumps(off.as_dict(), allow_nan=False)
    # the band of a window of N samples of d dof: chi2_bounds(d, N, prob)
    assert innovation_monitor(GOOD, traj, ts, us, ys, window=5, prob=0.99).sensors[0].band == chi2_bounds(3, 5, 0.99)


# --- the linearization leak --------------------------------------------------------------------------------------
WALL_RATE, WALL_STD, COMPASS_STD, ODO_STD = 20.0, 0.02, 0.05, np.array([0.05, 0.05, 0.02])
WALL_K0 = np.diag([0.05**2, 2.0**2, 2.0**2])
PLANAR_WORLD = Product[SO2, R2]


def _heading(g):
    return g.coords()[:1]


def _wall(g, t):
    """The wall distance and the compass: the world y of the position, and the heading."""
    return jnp.concatenate([g.coords()[2:3], _heading(g)])


def _twist(g, u, t):
    """Odometry (v_x, v_y, omega) in the body: SE(2)'s algebra (omega, v_x, v_y), or on SO(2) x R^2 omega and
    the world velocity R v."""
    if isinstance(g, SE2):
        return jnp.array([u[2], u[0], u[1]])
    return jnp.concatenate([u[2:3], g.factors[0].as_matrix() @ u[:2]])


def _wall_distance(g, t):
    return _wall(g, t)[:1]


def _compass(g, t):
    return _heading(g)


def wall_system(group):
    """The wall and the compass on ``group``; module-level functions, so that every call's system has one
    structure per group and its simulation and the filters' kernels compile once."""
    sensors = [Sensor("wall", _wall_distance, Noise.sample(WALL_STD), ["y"], ["m"]),
               Sensor("compass", _compass, Noise.sample(COMPASS_STD), ["heading"], ["rad"], angles=True)]
    return SensorSystem(group, _twist, sensors, Noise.sample(ODO_STD, rate=WALL_RATE),
                        inputs=["v_x", "v_y", "omega"])


def _circle(t):
    """Odometry of a circle of 3 m radius in 20 s."""
    w = 2 * math.pi / 20
    return jnp.array([3.0 * w, 0.0, w])


@functools.cache
def wall_run(group, seed=0, duration=30.0):
    """A circle of 3 m radius in 20 s beside a wall, odometry, wall distance and compass at 20 Hz, filtered with
    samples at their own time (with held samples the wall's innovations lag on both groups). Kept per arguments:
    the tests read the same runs."""
    system = wall_system(group)
    ts = np.arange(round(duration * WALL_RATE) + 1) / WALL_RATE
    truth, log = simulate(system, group.from_coords(jnp.array([math.pi / 2, 3.0, 0.0])), _circle, ts,
                          jax.random.key(seed), input_noise=np.diag(ODO_STD), substeps=4)
    rng = np.random.default_rng(seed)
    g0 = group.from_coords(jnp.array([math.pi / 2, 3.0, 0.0])).rplus(  # an initial error drawn from K0
        jnp.asarray(rng.normal(size=3) * np.sqrt(np.diag(WALL_K0))))
    flt = MinimumEnergyFilter(system, updates="discrete")
    traj = flt.run(flt.init(g0, WALL_K0), ts, np.asarray(log.us), np.asarray(log.ys))
    return flt, traj, truth, ts, np.asarray(log.us), np.asarray(log.ys)


def test_the_leak_is_the_variance_the_linearization_leaves_out():
    """At states of a run on SE(2), the sample covariance of h(g exp xi) - h(g) - F xi over 200 000 draws
    xi ~ N(0, K) gives tr(S^-1 Cov) equal to the leak to within 3 % (the sample's error about 0.5 %, the cubic
    terms' about K's heading variance). The run is the first of the SE(2) runs below (kept: one simulation and
    one kernel)."""
    flt, traj, _, ts, us, ys = wall_run(SE2)
    leak = linearization_leak(flt, traj, ts, us, ys)
    nis, _ = innovation_nis(flt, traj, ts, us, ys)
    np.testing.assert_array_equal(np.isnan(leak), np.isnan(nis))
    rng = np.random.default_rng(7)
    for k in (1, 20, 50):
        g = jax.tree_util.tree_map(lambda a, k=k: a[k], traj.g_hat)
        K = np.asarray(traj.K[k])
        xi = rng.multivariate_normal(np.zeros(3), K, size=200_000)
        at = lambda x, g=g: _wall(g.rplus(x), 0.0)  # noqa: E731
        h, F, h0 = jax.vmap(at)(jnp.asarray(xi)), jax.jacfwd(at)(jnp.zeros(3)), _wall(g, 0.0)
        rest = np.asarray(h - h0 - xi @ F.T)
        S = np.asarray(F) @ K @ np.asarray(F).T + np.diag([WALL_STD**2, COMPASS_STD**2])
        mc = np.trace(np.linalg.solve(S, np.cov(rest.T)))
        per_sensor = [np.trace(np.linalg.solve(S[i:i + 1, i:i + 1], np.cov(rest.T)[i:i + 1, i:i + 1]))
                      for i in range(2)]
        print(k, leak[k], per_sensor, mc)
        assert leak[k, 1] == 0.0  # the heading is linear in the left coordinates
        assert leak[k, 0] > 0.01 and abs(leak[k, 0] / per_sensor[0] - 1.0) < 0.03


def test_a_huge_early_leak_leaves_the_later_windows_exact():
    """Five samples with a leak of 1e16 (a K0 far beyond the errors), then 0.03 per sample: every window of 20
    samples after them sums to 0.6 (a cumulative sum of the raw leaks loses them to rounding: 0), and a leak that
    cannot be computed counts as the limit."""
    from liemef.metrics._innovations import _verdict

    ts = np.arange(200) * 0.1
    ell = np.r_[np.full(5, 1e16), np.full(195, 0.03)]
    v = _verdict("s", 1, ts, np.ones(200), 20, 0.999, None, ell, 1.0)
    assert v.leak_peak >= 1e16 and math.isclose(v.leak_median, 0.6, rel_tol=1e-9)
    assert v.leak_longest == (ts[19], ts[23]) and not v.nonlinear
    ell[100:190] = np.nan
    v = _verdict("s", 1, ts, np.ones(200), 20, 0.999, None, ell, 1.0)
    assert v.nonlinear and v.leak_longest == (ts[100], ts[199])


def test_the_leaks_cross_terms_count_on_a_range_and_bearing():
    """The second-order suite's near landmark (range and bearing, the bearing an angle): at 5 states of a run, the
    leak of the two-component sensor, whose N has a cross term N_12, equals tr(S^-1 Cov) of 200 000 draws of the
    remainder to within 3 % (measured 1.4-2.5 %, the leak above: the remainder's higher-order terms), where the
    two components' remainders correlate by up to 0.32."""
    from liemef.studies.compare._second_order import CASES, near_range_bearing, trials

    case = CASES["se2-near-rb"][1](1.0)
    flt = MinimumEnergyFilter(case.system, updates="discrete")
    _, us, ys, g0s = trials(case, 1, 0)
    us, ys = us[0], ys[0]
    traj = flt.run(flt.init(jax.tree_util.tree_map(lambda a: a[0], g0s), case.K0), case.ts, us, ys)
    leak = linearization_leak(flt, traj, case.ts, us, ys)
    rng = np.random.default_rng(11)
    R = np.diag([0.05**2, 0.01**2])
    out = []
    for k in (10, 30, 50, 70, 90):
        g = jax.tree_util.tree_map(lambda a, k=k: a[k], traj.g_hat)
        K = np.asarray(traj.K[k])
        xi = rng.multivariate_normal(np.zeros(3), K, size=200_000)
        at = lambda x, g=g: near_range_bearing(g.rplus(x), 0.0)  # noqa: E731
        h, F, h0 = jax.vmap(at)(jnp.asarray(xi)), np.asarray(jax.jacfwd(at)(jnp.zeros(3))), at(jnp.zeros(3))
        C = np.cov(np.asarray(h - h0 - xi @ F.T).T)
        S = F @ K @ F.T + R
        full = np.trace(np.linalg.solve(S, C))
        corr = C[0, 1] / np.sqrt(C[0, 0] * C[1, 1])
        print(k, leak[k, 0], full, corr)
        out.append((abs(leak[k, 0] / full - 1.0), abs(corr)))
    assert max(e for e, _ in out) < 0.03 and max(c for _, c in out) > 0.3


def test_the_leak_names_an_unobservable_direction_that_the_nees_confirms():
    """The planar quadrotor: the position along the wall is unobservable. On SE(2) the left error's position is
    rotated by the heading error, the wall distance is curved in it, and K shrinks along the wall while the error
    stays: measured NEES 19.9, 72.5 and 89.0 over the second half (3 dof, one run's band 0.22-9.35), and the
    monitor, from the run alone, says "nonlinear", naming the wall (window leaks up to 8.6-9.4, at or above 1
    for 12.6-18.7 s against a sustain of 7.5 s). On SO(2) x R^2 the wall distance is linear (a leak of exactly
    0), the NEES 3.3-5.8 and the monitor says "consistent". Neither group's innovations leave their band for
    the sustain time: the NIS alone sees nothing."""
    for group, status in ((SE2, "nonlinear"), (PLANAR_WORLD, "consistent")):
        neess = []
        for seed in range(3):
            flt, traj, truth, ts, us, ys = wall_run(group, seed)
            assert traj.status.ok
            r = innovation_monitor(flt, traj, ts, us, ys)
            e = left_error(truth.g, traj.g_hat)
            neess.append(float(np.mean(nees(e[ts >= 15.0], traj.K[ts >= 15.0]))))
            print(group.__name__, seed, r.status, neess[-1], r.message())
            assert r.status == status
            assert not any(s.sustained for s in r.sensors)  # the innovations alone see nothing
            wall = r.sensors[0]
            assert wall.nonlinear == (group is SE2) and not r.sensors[1].nonlinear
            if group is SE2:
                assert "NONLINEAR: wall:" in r.message() and wall.leak_peak > 5.0
                assert r.as_dict()["sensors"][0]["leak"]["nonlinear"] is True
            else:
                assert np.nanmax(r.leaks[:, 0]) == 0.0
        lo, hi = chi2_bounds(3, 1)
        assert (np.mean(neess) > 5 * hi) if group is SE2 else (max(neess) < hi)


# --- liemef run ----------------------------------------------------------------------------------------------------
def test_liemef_run_writes_the_monitor_and_exits_3_when_inconsistent(tmp_path):
    """30 s of the localization circle with 10 Hz GPS (window 50 fixes, sustain 7.5 s): at the system's 1 m
    consistent (exit 0); with fixes of 10 m std inconsistent (exit 3, measured mean NIS 211 for 2 dof), all
    outputs written; --no-monitor leaves it out."""
    (tmp_path / "s.py").write_text("from liemef.systems import planar_localization\nsystem = planar_localization()\n")
    N = 3000
    codes = {}
    for std in (1.0, 10.0):
        ts, _, _, us, ys = circle_samples(N, np.arange(10, N, 10), std)
        io.write_log(tmp_path / f"log{std}.csv", planar_localization(), ts, us, ys)
        out = tmp_path / f"out{std}"
        res = CliRunner().invoke(cli, [str(a) for a in (
            "run", "--system-file", tmp_path / "s.py", "--log", tmp_path / f"log{std}.csv", "--out", out,
            "--x0", "0,0,0", "--k0-diag", "1e-4,1e-4,1e-4", "--updates", "discrete", "--no-progress")],
            catch_exceptions=False)
        codes[std] = res.exit_code
        m = json.loads((out / "metrics.json").read_text())["innovations"]
        assert m["sensors"][0]["name"] == "gps" and m["sensors"][0]["window"] == 50
        assert (out / "estimates.csv").is_file() and (out / "manifest.json").is_file()
        assert "Innovation monitor: " + ("consistent" if std == 1.0 else "INCONSISTENT: gps") in res.output
        assert m["status"] == ("consistent" if std == 1.0 else "inconsistent")
        # --error auto (the default) resolved from the sensors: a position fix keeps the left error
        assert json.loads((out / "metrics.json").read_text())["config"]["error"] == "left"
    assert codes == {1.0: 0, 10.0: 3}
    res = CliRunner().invoke(cli, [str(a) for a in (
        "run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log1.0.csv", "--out", tmp_path / "bad",
        "--error", "up")])
    assert res.exit_code == 2 and "--error" in res.output and "'up'" in res.output
    res = CliRunner().invoke(cli, [str(a) for a in (
        "run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log10.0.csv", "--out", tmp_path / "off",
        "--x0", "0,0,0", "--k0-diag", "1e-4,1e-4,1e-4", "--updates", "discrete", "--no-progress", "--no-monitor")],
        catch_exceptions=False)
    assert res.exit_code == 0 and "innovations" not in json.loads((tmp_path / "off" / "metrics.json").read_text())


def test_liemef_run_exits_4_when_nonlinear(tmp_path):
    """The wall run on SE(2) through `liemef run --system-file`: every output written, metrics.json's monitor
    "nonlinear" with the wall's leak, the message printed, exit status 4."""
    flt, traj, truth, ts, us, ys = wall_run(SE2, 1)
    (tmp_path / "s.py").write_text("from liemef.groups import SE2\nfrom test_innovations import wall_system\n"
                                   "system = wall_system(SE2)\n")
    io.write_log(tmp_path / "log.csv", flt.system, ts, us, ys)
    x0 = ",".join(f"{v:.17g}" for v in np.asarray(traj.g_hat.coords()[0]))
    k0 = ",".join(f"{v:.17g}" for v in np.diag(WALL_K0))
    res = CliRunner().invoke(cli, [str(a) for a in (
        "run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "out",
        "--x0", x0, "--k0-diag", k0, "--updates", "discrete", "--no-progress")], catch_exceptions=False)
    print(res.output)
    assert res.exit_code == 4
    assert "Innovation monitor: NONLINEAR: wall:" in res.output
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())["innovations"]
    assert m["status"] == "nonlinear" and m["leak"] == 1.0
    assert m["sensors"][0]["leak"]["nonlinear"] is True and m["sensors"][1]["leak"]["nonlinear"] is False
    assert (tmp_path / "out" / "estimates.csv").is_file() and (tmp_path / "out" / "manifest.json").is_file()


def test_a_short_log_whose_every_window_is_out_is_inconsistent():
    """A 10 s log of a 10 Hz sensor, windows of 50 samples (5 s): the default sustain of 1.5 windows (7.5 s) is
    longer than its windows' 5 s, so no excursion could last it. There the sustain is the windows' own span, their
    first and last sharing no sample: a fault from t = 3 s on (NIS 1e4 for 2 dof) is inconsistent, one gross
    outlier at t = 3 s is not, and a log under two windows keeps the 1.5 windows (nothing can be sustained)."""
    from liemef.metrics._innovations import _verdict

    ts = np.arange(100) * 0.1
    rng = np.random.default_rng(3)
    calm = rng.chisquare(2, ts.size)
    fault = np.where(ts >= 3.0, 1e4, calm)
    outlier = calm.copy()
    outlier[30] = 1e6
    v = _verdict("s", 2, ts, fault, 50, 0.999, None)
    assert v.sustained and v.sustain == pytest.approx(5.0) and v.fraction_out == 1.0
    w = _verdict("s", 2, ts, outlier, 50, 0.999, None)
    assert w.fraction_out > 0.3 and not w.sustained
    assert _verdict("s", 2, ts, calm, 50, 0.999, None).longest is None
    assert v.judged and w.judged and v.extent == pytest.approx(5.0)
    short = _verdict("s", 2, ts[:90], fault[:90], 50, 0.999, None)
    assert short.sustain == pytest.approx(7.5) and not short.sustained
    assert not short.judged and short.extent == pytest.approx(4.0)  # its windows cannot hold 7.5 s
    given = _verdict("s", 2, ts, fault, 50, 0.999, 7.5)  # a sustain given is the user's rule, kept
    assert given.sustain == 7.5 and not given.sustained and not given.judged


def test_a_log_shorter_than_two_windows_is_not_judged():
    """800 samples at 100 Hz (the sensors from t = 0.01 s): their full windows of 500 samples end from t = 5 s to
    7.99 s, 2.99 s apart, and an excursion must last 7.5 s. A gross outlier at t = 4 s sits in every window and
    puts them all out of band; such a run was called consistent. Now no sensor is judged, and the run is not
    applicable, saying why."""
    ts, us, ys, _, g0 = simulate_attitude(0, duration=7.99)
    ys = np.array(ys)
    ys[400, :3] += 50.0
    traj = GOOD.run(GOOD.init(g0, ATT_K0), ts, us, ys, engine="c")
    r = innovation_monitor(GOOD, traj, ts, us, ys)
    assert r.status == "not applicable" and "too short to judge" in r.message(), r.message()
    assert [(s.windows, s.judged) for s in r.sensors] == [(300, False), (300, False)]
    assert r.sensors[0].extent == pytest.approx(2.99) and r.sensors[0].fraction_out == 1.0
    d = r.as_dict()["sensors"][0]
    assert d["judged"] is False and d["windows_extent_s"] == pytest.approx(2.99)


def test_a_consistent_run_names_the_sensors_it_could_not_judge():
    from liemef.metrics import InnovationReport, SensorVerdict

    acc = SensorVerdict("acc", 2, 3000, window=100, span=1.0, band=(0.8, 1.2), windows=2901, fraction_out=0.0,
                        sustain=1.5, mean_nis=2.0, extent=29.0)
    gps = SensorVerdict("gps", 2, 30, window=20, span=20.0, band=(0.5, 1.7), windows=11, fraction_out=0.8,
                        sustain=30.0, mean_nis=9.0, extent=10.0)
    msg = InnovationReport("consistent", (acc, gps)).message()
    assert "acc: 100.0 % of 2901 windows" in msg and "gps: not judged, its windows span 10 s of the 30 s" in msg
    assert "gps: 20.0 %" not in msg


def test_a_covariate_sensor_is_not_judged():
    """attitude_velocity's `acc` and `norm` are covariates (outputs that do not depend on the state): their samples
    are the magnetometer noise model's inputs, not measurements, so the monitor judges `mag` and `velocity` only
    (before, their meaningless "innovations" made `liemef run --system attitude-velocity` exit with status 3)."""
    from scipy.spatial.transform import Rotation

    from liemef.groups import R3, SO3, TSO3
    from liemef.metrics import innovation_monitor
    from liemef.systems import attitude_bias as ab
    from liemef.systems import attitude_velocity

    rate, N = 100.0, 1500
    rng = np.random.default_rng(0)
    ts = np.arange(N) / rate
    w = np.stack([0.5 * np.sin(0.4 * ts), 0.4 * np.cos(0.3 * ts), 0.3 * np.ones(N)], axis=1)
    R = [Rotation.from_rotvec([0.1, -0.2, 0.3])]
    for k in range(N - 1):
        R.append(R[-1] * Rotation.from_rotvec(w[k] / rate))
    R = np.stack([r.as_matrix() for r in R])
    field = 43.0 * np.array(ab.magnetic_reference(ab.DIP))
    acc = np.einsum("nji,j->ni", R, [0.0, 0.0, 9.81]) + 0.05 * rng.standard_normal((N, 3))
    mag = np.einsum("nji,j->ni", R, field) + 0.3 * rng.standard_normal((N, 3))
    gyr = w + 0.005 * rng.standard_normal((N, 3))
    _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, rate)
    system = attitude_velocity(0.005, rate, gravity=9.81, field=43.0)
    assert [s.name for s in system.sensors if s.covariate] == ["acc", "norm"]
    flt = MinimumEnergyFilter(system, updates="discrete", order="first")
    g0 = ab_vel.attitude_velocity_state(TSO3((SO3.from_matrix(jnp.asarray(R[0])), R3(jnp.zeros(3)))))
    traj = flt.run(flt.init(g0, np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3)), ts, us, ys)
    report = innovation_monitor(flt, traj, ts, us, ys)
    judged = {s.name: s.windows for s in report.sensors}
    assert judged["acc"] == 0 and judged["norm"] == 0 and judged["mag"] > 0 and judged["velocity"] > 0, judged
    # (on this log K overstates the errors of both measurements: the model's noise levels are BROAD's, the
    # simulation's are smaller and its IMU does not translate; that verdict is the measurements')
    assert all(s.samples == 0 for s in report.sensors if s.name in ("acc", "norm"))
