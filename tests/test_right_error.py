"""The right error of a system (liemef.systems.right_error): the inverted state h = g^-1, whose left error is the
original's right error.

* Its dynamics are h^-1 dh/dt of the inverted flow, and its process noise the covariance of the inverted noise
  (autodiff of the flow against the closed forms, on SE(2) and on SE_2(3)).
* Its outputs are the original's at g = h^-1, with the same sensors' noise and residuals.
* state_of and estimates_of map exactly: hat g g^-1 = exp(-Ad_hat_g xi) for g = hat g exp(xi).
* On the near landmark of the second-order suite, whose rotation about the landmark no sample observes, the
  default filter, which chooses the right error there, is consistent (NEES within its band) where the left one is
  far above it; on well-observed systems the two agree.
* Which side: invariant_sides measures, per sensor, in which error the directions it observes stay fixed
  (a landmark's range and bearing, a field's direction: right; a position fix, ranges to points: left; an
  altimeter on SE_2(3): neither; a sensor of every direction: both), and natural_error chooses from it.
* MinimumEnergyFilter(error="right") is the filter of right_error(system) with its states mapped back, in every
  entry point (run, step, update, terms, vector_field), to round-off; with discrete updates it is the left
  filter (the same cost, whose coordinates are related linearly at the estimate).
* What needs a constant noise map refuses it, naming the argument.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef import MinimumEnergyFilter
from liemef.groups import SE2, SE3, SE23
from liemef.simulation import simulate
from liemef.studies.compare._second_order import CASES, SecondOrderSuite, compare_second_order, trials
from liemef.studies.logs import LogSystem, filter_log
from liemef.studies.optimum import batch_map
from liemef.systems import (
    Noise,
    RightErrorSystem,
    Sensor,
    SensorSystem,
    direction_residual,
    inertial_navigation,
    invariant_sides,
    natural_error,
    right_error,
)
from tolerances import ROUNDOFF

SE2_CASE = CASES["se2-near-rb"][1](5.0)
"""The near landmark, 5 s: every run of it in this file (whole or a first part) uses these trials, so that its
simulation, and the filters' C kernels of its system, compile once in the file."""
QUAD_CASE = CASES["quad-range"][1](2.0)


def _random(G, seed, scale=0.7):
    return G.identity().rplus(jnp.asarray(np.random.default_rng(seed).normal(size=G.tangent_dim) * scale))


@pytest.mark.parametrize("case", [SE2_CASE, QUAD_CASE], ids=["se2", "se23"])
def test_the_dynamics_and_noise_are_the_inverted_flows(case):
    """With g' = g exp(s (lambda(g) + B delta)) and h = g^-1: d/ds log(h^-1 h(s)) at 0 is the right error's
    dynamics at h, and its derivative in delta gives B' with B' R^-1 B'^T = process_noise_at(h) (autodiff of the
    flow, to round-off)."""
    base, right = case.system, right_error(case.system)
    BRB = base.B @ jnp.linalg.solve(base.R, base.B.T)

    @jax.jit
    def both(g, u, t):
        """The flow's derivatives at 0 and the right error's own, in one compiled program."""
        h, lam, d0 = g.inverse(), base.dynamics(g, u, t), jnp.zeros(base.B.shape[1])

        def flow(s, d):  # log(h^-1 h(s)) with h^-1 = g
            return (g @ g.rplus(s * (lam + base.B @ d)).inverse()).log()

        Bp = jax.jacfwd(lambda d: jax.jacfwd(flow)(0.0, d))(d0)
        return (jax.jacfwd(flow)(0.0, d0), right.dynamics(h, u, t), Bp @ jnp.linalg.solve(base.R, Bp.T),
                right.process_noise_at(h, BRB, u, t), right.output(h, t), base.output(g, t))

    rng = np.random.default_rng(3)
    for seed in range(3):
        u, t = jnp.asarray(rng.normal(size=base.input_dim)), jnp.asarray(0.3)
        lam_flow, lam_right, Q_flow, Q_right, y_right, y = both(_random(base.group, seed), u, t)
        np.testing.assert_allclose(lam_flow, lam_right, atol=ROUNDOFF * 10)
        np.testing.assert_allclose(Q_flow, Q_right, atol=ROUNDOFF * 10 * float(jnp.max(jnp.abs(BRB))))
        np.testing.assert_allclose(y_right, y, rtol=ROUNDOFF, atol=ROUNDOFF)
    assert right.constant_process_noise is False and base.constant_process_noise is True
    assert right.blocks() == base.blocks() and right.output_names == base.output_names
    np.testing.assert_array_equal(right.information(), base.information())


def test_state_of_and_estimates_of_map_the_errors_exactly():
    """For g = hat g exp(xi): hat g g^-1 = exp(-Ad_hat_g xi), so state_of's covariance is the right error's; and
    estimates_of inverts state_of."""
    right = right_error(QUAD_CASE.system)
    g_hat = _random(SE23, 7)
    xi = jnp.asarray(np.random.default_rng(8).normal(size=9) * 0.3)
    eta = (g_hat @ g_hat.rplus(xi).inverse()).log()
    np.testing.assert_allclose(eta, -(g_hat.Ad() @ xi), atol=ROUNDOFF * 10)
    K0 = np.diag(np.arange(1.0, 10.0))
    h0, Kh = right.state_of(g_hat, K0)
    A = np.asarray(g_hat.Ad())
    np.testing.assert_allclose(Kh, A @ K0 @ A.T, rtol=ROUNDOFF * 10)
    g_back, K_back = right.estimates_of(h0, Kh)
    np.testing.assert_allclose(np.asarray(g_back.coords()), np.asarray(g_hat.coords()), atol=ROUNDOFF * 10)
    np.testing.assert_allclose(K_back, K0, atol=ROUNDOFF * 100)


def test_the_default_keeps_the_right_error_where_no_sample_observes():
    """The second-order suite's near landmark, 5 trials of 5 s from 60 deg off: the defaults in the left error
    have a NEES of 121 for 3 dof (band 1.25-5.5); the defaults, which choose the right error for a landmark's
    range and bearing, have 4.21, within it, and less heading error (the suite's 20 s: 113 and 2.77, the invariant
    EKF of the right error 3.24). Where every direction is observed the two agree (the slow full-suite test
    checks bearings to 3 landmarks: 3.88 and 3.88)."""
    result = compare_second_order(SecondOrderSuite(runs=5, duration=5.0, systems="se2-near-rb",
                                                   filters="mef-hold-safe,mef-hold-left"), progress=False)
    near = result["cases"]["se2-near-rb"]["filters"]
    print({k: (r["nees"], r["attitude_deg"]) for k, r in near.items()})
    assert result["cases"]["se2-near-rb"]["error"] == "right"
    assert near["mef-hold-left"]["nees_flag"] == "far above"
    assert near["mef-hold-safe"]["status"] == "ok" and near["mef-hold-safe"]["nees_flag"] == "within"
    assert near["mef-hold-safe"]["attitude_deg"] <= near["mef-hold-left"]["attitude_deg"]


def test_what_needs_a_constant_noise_map_refuses_it():
    right = right_error(SE2_CASE.system)
    ts = np.arange(5) * 0.1
    with pytest.raises(ValueError, match="system: expected a system with a constant noise map"):
        simulate(right, SE2.identity(), None, ts, jax.random.key(0))
    with pytest.raises(ValueError, match="system: expected a system with a constant noise map"):
        batch_map(right, ts, np.zeros((5, 3)), np.full((5, 2), np.nan), SE2.identity(), np.eye(3))
    with pytest.raises(ValueError, match="system: expected a SensorSystem"):
        right_error(right)
    with pytest.raises(ValueError, match="system: expected a SensorSystem"):
        right_error("se2")
    assert isinstance(right, RightErrorSystem) and right.base is SE2_CASE.system
    # liemef run would read x0, K0 and write the outputs of the inverse: refused
    log = SimpleNamespace(ts=ts, us=np.zeros((5, 3)), ys=np.full((5, 2), np.nan))
    with pytest.raises(ValueError, match="system: expected a system whose state is the one to estimate"):
        filter_log(LogSystem(right, "right", "the right error"), log, x0=np.zeros(3))


def test_new_noise_levels_keep_the_inverted_base():
    """with_noise on the right error is the right error of the base with that noise: the same structure (one
    compilation), the base's and its own B alike."""
    right = right_error(SE2_CASE.system)
    louder = right.with_noise(process_noise=Noise.sample([0.5, 0.5, 0.5], rate=100.0))
    assert isinstance(louder, RightErrorSystem)
    np.testing.assert_array_equal(louder.B, louder.base.B)
    assert float(louder.B[0, 0]) > float(right.B[0, 0])
    assert jax.tree_util.tree_structure(louder) == jax.tree_util.tree_structure(right)


def test_a_filter_of_sensor_systems_is_not_applicable_to_a_papers_system():
    from liemef.studies.compare._second_order import FILTERS, not_applicable, side_rows, table_rows

    tse2 = CASES["tse2"][1](1.0)
    assert FILTERS["mef-hold-right"][1](tse2.system, tse2, "hold") is None
    row = not_applicable(tse2, 5)
    result = {"cases": {"tse2": {"filters": {"mef-hold-right": row}, "first_order_updates": "hold", "side": "left"}}}
    assert table_rows(result) == [["tse2", "mef-hold-right", "not applicable", "-", "-", "-", "6", "3.36-9.4", "-",
                                   "-", "-"]]
    # the sides table: a papers' system has no sensors to measure, and the defaults keep the left error there
    result["cases"]["tse2"].update(error="left", sensor_sides=None)
    result["cases"]["se2-near-rb"] = {"filters": {}, "first_order_updates": "hold", "side": "right",
                                      "error": "right", "sensor_sides": {"rb": "right"}}
    assert side_rows(result) == [["tse2", "- (not a sensor system)", "left", "left"],
                                 ["se2-near-rb", "rb: right", "right", "right"]]


def _se2_system(*sensors):
    return SensorSystem(SE2, lambda g, u, t: u, sensors, Noise.sample([0.01, 0.01, 0.01], rate=100.0),
                        inputs=("w", "vx", "vy"))


def test_invariant_sides_says_where_the_observed_directions_stay():
    """Per sensor: a landmark's range and bearing (the world seen from the body) right; a position fix and the
    ranges to points (invariant to a turn of the body) left; three bearings, which observe every direction of
    SE(2), both; an altimeter on SE_2(3), whose rows turn with the attitude in the left error and with the
    position in the right one, neither; the magnetometer right. natural_error: right only where some sensor is
    right and none left."""
    assert invariant_sides(SE2_CASE.system) == {"rb": "right"}
    assert natural_error(SE2_CASE.system) == "right"
    quad = CASES["quad-altimeter"][1](1.0).system
    assert invariant_sides(quad) == {"alt": "neither", "mag": "right"}
    assert natural_error(quad) == "right"
    assert invariant_sides(CASES["se2-range"][1](1.0).system) == {"range": "left"}
    assert invariant_sides(CASES["se2-bearing"][1](1.0).system) == {"bearing": "both"}
    ins = inertial_navigation(gnss_std=1.0)
    assert set(invariant_sides(ins).values()) == {"left"} and natural_error(ins) == "left"
    # a position fix beside a landmark: a left-only sensor keeps the left error
    fix = Sensor("fix", lambda g, t: g.translation(), Noise.sample([0.1, 0.1], rate=10.0))
    rb = SE2_CASE.system.sensors[0]
    both = _se2_system(rb, fix)
    assert invariant_sides(both) == {"rb": "right", "fix": "left"} and natural_error(both) == "left"
    assert natural_error(_se2_system(rb)) == "right"
    # what the filter linearizes, not the raw output: a camera's bearing to a point, R^T (b - p), normalized by its
    # direction residual, observes directions that turn with p in either error (the raw vector is "right")
    point = jnp.array([2.0, -1.0, 0.5])
    camera = Sensor("cam", lambda g, t: g.rotation().as_matrix().T @ (point - g.translation()),
                    Noise.sample([0.01] * 3), residual=direction_residual)
    raw = Sensor("raw", lambda g, t: g.rotation().as_matrix().T @ (point - g.translation()), Noise.sample([0.01] * 3))
    pose = SensorSystem(SE3, lambda g, u, t: jnp.zeros(6), [camera, raw], Noise.sample([0.01] * 6, rate=10.0))
    assert invariant_sides(pose) == {"cam": "neither", "raw": "right"}
    # an output that varies with time is measured at several times: a fix p t (zero at t = 0) is a position fix
    scaled = Sensor("fix", lambda g, t: g.translation() * t, Noise.sample([0.1, 0.1], rate=10.0))
    assert invariant_sides(_se2_system(rb, scaled)) == {"rb": "right", "fix": "left"}
    # the papers' systems, and a system already inverted, stay in the left error
    assert natural_error(CASES["tse2"][1](1.0).system) == "left"
    assert natural_error(right_error(SE2_CASE.system)) == "left"
    with pytest.raises(ValueError, match="system: expected a SensorSystem"):
        invariant_sides(CASES["tse2"][1](1.0).system)


@pytest.mark.parametrize(("connection", "engine"), [
    ("zero", "c"), pytest.param("zero", "xla", marks=pytest.mark.slow),
    pytest.param("minus", "xla", marks=pytest.mark.slow)])
def test_error_right_is_the_filter_of_the_right_error_mapped_back(connection, engine):
    """A run of MinimumEnergyFilter(system, error="right"), which inverts the state about each interval's first
    estimate (RightErrorAbout), is that of the filter of right_error(system) (inverted about the world's origin)
    from state_of, mapped back by estimates_of, to round-off: the two coordinates differ by a constant Ad per
    interval, under which Theorem 4.1's terms, the Cartan-Schouten connections and RKMK4 are covariant. With
    fixed sub-steps, the exact curvature, the second order, 60 samples of the near landmark from 6 deg off (its
    adaptive steps are chosen in each one's coordinates, and differ). An update likewise; the default chooses
    "right" there (a landmark's range and bearing). The runs by the C engine, whose kernels translate the intervals
    the XLA scan runs: the same runs by XLA, whose two scans compile in about 4x the kernels' time, are in make
    test-slow."""
    case = SE2_CASE
    _, us, ys, g0s = trials(case, 1, 0, 0.1)
    us, ys, g0 = us[0][:60], ys[0][:60], jax.tree_util.tree_map(lambda a: a[0], g0s)
    ts, K0 = case.ts[:60], case.K0 * 0.01
    system = case.system.with_noise(rb=Noise.sample([5.0, 1.0]))  # not stiff: 2 fixed sub-steps per interval
    options = {"substeps": 2, "connection": connection, "curvature": "exact"}
    mine = MinimumEnergyFilter(system, error="right", **options)
    assert MinimumEnergyFilter(system).error == "right" and "error='right'" in repr(mine)
    inner = MinimumEnergyFilter(right_error(system), **options)
    assert inner.error == "left"
    right = inner.system
    traj = mine.run(mine.init(g0, K0), ts, us, ys, engine=engine)
    ref = inner.run(inner.init(*right.state_of(g0, K0)), ts, us, ys, engine=engine)
    g_ref, K_ref = right.estimates_of(ref.g_hat, ref.K)
    assert bool(traj.ok) and bool(ref.ok)
    scale = float(np.max(np.abs(np.asarray(K_ref))))
    np.testing.assert_allclose(np.asarray(traj.g_hat.as_matrix()), np.asarray(g_ref.as_matrix()), atol=1e-12)
    np.testing.assert_allclose(np.asarray(traj.K), np.asarray(K_ref), atol=1e-12 * scale)
    if connection == "zero":
        np.testing.assert_array_equal(np.asarray(traj.K), np.swapaxes(np.asarray(traj.K), 1, 2))
    assert np.abs(np.asarray(traj.g_hat.coords()[-1] - g0.coords())).max() > 0.01  # the estimate moved
    if connection == "minus":
        return
    # one update: the same sample update, mapped back (Newton iterated to its tolerance: 10 iterations leave
    # the first sample 60 deg off short of it, where round-off moves the result by 1e-8)
    _, _, ys, g0s = trials(case, 1, 0, 1.0)
    ys, g0 = ys[0], jax.tree_util.tree_map(lambda a: a[0], g0s)
    mine = MinimumEnergyFilter(case.system, error="right", iterations=50)
    inner = MinimumEnergyFilter(right_error(case.system), iterations=50)
    right = inner.system
    k = int(np.argmax(np.all(np.isfinite(ys), axis=1)))
    s1, r1 = mine.update(mine.init(g0, case.K0), float(ts[k]), ys[k])
    s2, r2 = inner.update(inner.init(*right.state_of(g0, case.K0)), float(ts[k]), ys[k])
    scale = float(np.max(np.abs(np.asarray(s2.K))))
    g2, K2 = right.estimates_of(s2.g_hat, s2.K)
    np.testing.assert_allclose(np.asarray(s1.g_hat.as_matrix()), np.asarray(g2.as_matrix()), atol=1e-10)
    np.testing.assert_allclose(np.asarray(s1.K), np.asarray(K2), atol=1e-10 * scale)
    np.testing.assert_allclose(float(r1.nis), float(r2.nis), rtol=1e-9)


def test_the_right_vector_field_maps_back():
    """vector_field with error="right" is the derivative of the left error's (g_hat, K) along the right error's
    flow: (h exp(s v))^-1 and Ad_h(s) (K_eta + s dK_eta) Ad_h(s)^T, by finite differences (central, s = 1e-6)."""
    case = SE2_CASE
    mine, inner = MinimumEnergyFilter(case.system, error="right"), MinimumEnergyFilter(right_error(case.system))
    right = inner.system
    g = _random(SE2, 4)
    K = np.diag([0.3, 0.2, 0.1]) + 0.01
    u, y = jnp.asarray([0.2, 1.0, 0.1]), jnp.asarray([2.0, 0.4])
    xi, K_dot = mine.vector_field(g, jnp.asarray(K), u, y, 0.0)
    h, Kh = right.state_of(g, K)
    v, Kh_dot = inner.vector_field(h, Kh, u, y, 0.0)

    def along(s):
        return right.estimates_of(h.rplus(s * v), Kh + s * Kh_dot)

    eps = 1e-6
    (gp, Kp), (gm, Km) = along(eps), along(-eps)
    np.testing.assert_allclose(xi, ((g.inverse() @ gp).log() - (g.inverse() @ gm).log()) / (2 * eps), atol=1e-7)
    np.testing.assert_allclose(K_dot, (Kp - Km) / (2 * eps), atol=1e-7 * float(np.max(np.abs(K_dot))))
    # terms() of the filter are those of the right error about g: in the coordinates of right_error(system) at
    # state_of, whose left error is M = Ad_{g^-1} times the one about g, E (a quadratic form) is M^T E M and r
    # (a covector) M^T r
    tm, tm_ref = mine.terms(g, K, u, y, dt=0.1), inner.terms(h, Kh, u, y, dt=0.1)
    M = np.asarray(g.inverse().Ad())
    np.testing.assert_allclose(M.T @ np.asarray(tm.E) @ M, tm_ref.E, atol=1e-10 * float(np.abs(tm_ref.E).max()))
    np.testing.assert_allclose(M.T @ np.asarray(tm.r), tm_ref.r, atol=1e-10 * float(np.abs(tm_ref.r).max()))
    assert float(np.abs(np.asarray(tm.E) - np.asarray(tm_ref.E)).max()) > 1e-3  # the coordinates differ


def test_discrete_updates_do_not_depend_on_the_side():
    """With samples at their own time the filter minimizes each sample's cost, the same in either error (the two
    are related linearly at the estimate, eta = -Ad xi), and, with the (0)-connection, predicts without outputs
    by a linear map of K: the two sides agree to the integrator's error where held samples do not (the near
    landmark, 5 s). (A connection with torsion adds a term to the prediction that is not covariant.)"""
    case = SE2_CASE
    _, us, ys, g0s = trials(case, 1, 0, 1.0)
    g0 = jax.tree_util.tree_map(lambda a: a[0], g0s)
    final = {}
    for updates in ("hold", "discrete"):
        for side in ("left", "right"):
            f = MinimumEnergyFilter(case.system, updates=updates, error=side)
            final[updates, side] = np.asarray(f.run(f.init(g0, case.K0), case.ts, us[0], ys[0]).g_hat.coords()[-1])
    assert np.max(np.abs(final["discrete", "left"] - final["discrete", "right"])) < 1e-6
    assert np.max(np.abs(final["hold", "left"] - final["hold", "right"])) > 0.1


def test_error_is_checked_by_name():
    with pytest.raises(ValueError, match="error: expected one of"):
        MinimumEnergyFilter(SE2_CASE.system, error="both")
    with pytest.raises(ValueError, match="error: 'right' needs a SensorSystem"):
        MinimumEnergyFilter(CASES["tse2"][1](1.0).system, error="right")
    with pytest.raises(ValueError, match="error: a RightErrorSystem is already the right error"):
        MinimumEnergyFilter(right_error(SE2_CASE.system), error="right")
    assert MinimumEnergyFilter(CASES["tse2"][1](1.0).system).error == "left"


def _shifted_near_landmark(d):
    """se2-near-rb's system with its world translated by (d, d): the landmark moves, the odometry and the range and
    bearing read the same."""
    from liemef.studies.compare._second_order import NEAR, odometry_dynamics

    landmark = jnp.asarray(NEAR[0]) + d

    def rb(g, t):
        b = (landmark - g.translation()) @ g.rotation().as_matrix()
        return jnp.array([jnp.linalg.norm(b), jnp.arctan2(b[1], b[0])])

    base = SE2_CASE.system
    sensor = Sensor("rb", rb, base.sensors[0].noise, ["r", "b"], ["m", "rad"], angles=["b"])
    return SensorSystem(SE2, odometry_dynamics, [sensor], base.process_noise, inputs=base.inputs)


def test_the_right_error_does_not_depend_on_where_the_world_origin_is():
    """The near landmark's run from 60 deg off, with the world translated by 1e4 m: the left error and the
    right error about each interval's estimate give the translated estimates, the same K and the same sub-steps
    (to round-off of positions of 1e4 m). Inverted about the world's origin (right_error), the same filter hits
    the sub-step cap in its first interval there and fails: its Ad, and so its rates, hold the position."""
    _, us, ys, g0s = trials(SE2_CASE, 1, 0, 1.0)
    us, ys, g0 = us[0][:200], ys[0][:200], jax.tree_util.tree_map(lambda a: a[0], g0s)
    ts, K0 = SE2_CASE.ts[:200], SE2_CASE.K0
    shift = SE2.from_coords(jnp.array([0.0, 1e4, 1e4]))
    runs = {}
    for d in (0.0, 1e4):
        system = _shifted_near_landmark(d) if d else SE2_CASE.system  # (the file's kernels of it, shared)
        start = shift @ g0 if d else g0
        for error in ("left", "right"):
            flt = MinimumEnergyFilter(system, error=error)
            runs[d, error] = flt.run(flt.init(start, K0), ts, us, ys)
        inner = MinimumEnergyFilter(right_error(system))
        runs[d, "global"] = inner.run(inner.init(*inner.system.state_of(start, K0)), ts, us, ys)
    for error in ("left", "right"):
        near, far = runs[0.0, error], runs[1e4, error]
        assert bool(near.ok) and bool(far.ok)
        back = np.asarray((shift.inverse() @ far.g_hat).coords())
        np.testing.assert_allclose(back, np.asarray(near.g_hat.coords()), atol=1e-7)
        np.testing.assert_allclose(np.asarray(far.K), np.asarray(near.K), rtol=1e-6, atol=1e-9)
        assert abs(int(far.status.substeps_total) - int(near.status.substeps_total)) <= 2
    print({k: int(v.status.substeps_total) for k, v in runs.items()})
    near, far = runs[0.0, "global"], runs[1e4, "global"]
    assert bool(near.ok) and int(near.status.substeps_capped) == 0
    assert int(far.status.substeps_capped) >= 1 and not bool(far.ok)  # K lost at the cap of the first interval
