"""Failures are values (docs/weights.md): a run returns the first bad interval, its cause and the last
good state, and a failed state stays as it is. (Padding and keep_every: tests/test_recompilation.py.)"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef.filters import CAUSES, FilterState
from liemef.groups import SE2, Rn
from liemef.systems import PlanarRigidBody, System, planar_localization, tse2_state

R1 = Rn[1]


def _leaves_equal(a, b) -> bool:
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
                                      for x, y in zip(la, lb, strict=True))


# --- a large K0 with one explicit step per interval ---------------------------------------------------------------
def test_large_K0_with_one_substep_fails_on_the_first_interval():
    """TSE(2) (Rigo et al. 2022, printed weights), K0 = 1e4 I, samples every 1 ms, substeps=1: |K E| dt ~ 10 makes
    the explicit RK4 step unstable; measured: cause "K not positive definite" at interval 0 (t = 0). The states
    after it are NaN and ``final`` is the initial state. (substeps="auto" takes 67 sub-steps there and stays ok.)"""
    sys_ = PlanarRigidBody()
    truth = tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0)
    ts = 1e-3 * np.arange(30)
    ys = np.tile(np.asarray(sys_.output(truth, 0.0)), (ts.size, 1))
    flt = liemef.MinimumEnergyFilter(sys_, substeps=1)
    state = flt.init(tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1), 1e4 * np.eye(6))
    traj = flt.run(state, ts, np.zeros((ts.size, 2)), ys)
    assert traj.status.cause == "K not positive definite"
    assert int(traj.status.index) == 0 and float(traj.status.time) == 0.0
    assert np.isnan(np.asarray(traj.K[1:])).all() and np.isnan(np.asarray(traj.coords()[1:])).all()
    assert _leaves_equal((traj.final.g_hat, traj.final.K), (state.g_hat, state.K))
    assert "interval 0" in traj.status.message(ts)


# --- a model that produces NaN ---------------------------------------------------------------------------------------
T_BAD = 1.002  # the dynamics are NaN after this time: first reached inside the interval [1.00, 1.01] (index 100)


def _nan_after(g, u, t):
    return jnp.where(t > T_BAD, jnp.nan, -0.5 * g.x + u)


def _identity_output(g, t):
    return g.x


@pytest.fixture(scope="module")
def nan_run():
    sys_ = System(group_type=R1, dynamics_fn=_nan_after, output_fn=_identity_output, B=np.eye(1), D=0.3 * np.eye(1),
                  Q=np.eye(1), R=np.eye(1), n_inputs=1)
    flt = liemef.MinimumEnergyFilter(sys_)
    ts = 0.01 * np.arange(200)
    rng = np.random.default_rng(0)
    us, ys = np.sin(ts)[:, None], (np.cos(ts) + 0.1 * rng.standard_normal(ts.size))[:, None]
    state = flt.init(R1(jnp.array([2.0])), np.eye(1))
    return flt, state, ts, us, ys, flt.run(state, ts, us, ys)


def test_nonfinite_model_is_reported_with_the_first_bad_interval(nan_run):
    """Cause "non-finite" at interval 100 ([1.00, 1.01] s, the first whose RK4 stages pass t = 1.002), time 1.0;
    the states before are finite, those after NaN, and ``final`` is the state at ts[100]."""
    flt, state, ts, us, ys, traj = nan_run
    st = traj.status
    assert (st.cause, int(st.index), float(st.time)) == ("non-finite", 100, ts[100])
    x, K = np.asarray(traj.g_hat.x), np.asarray(traj.K)
    assert np.isfinite(x[:101]).all() and np.isfinite(K[:101]).all()
    assert np.isnan(x[101:]).all() and np.isnan(K[101:]).all()
    assert np.array_equal(np.asarray(traj.final.g_hat.x), x[100]) and np.array_equal(np.asarray(traj.final.K), K[100])
    assert "[1, 1.01] s" in st.message(ts) and CAUSES[int(st.code)] == "non-finite"
    # a log with epoch time stamps (a ROS bag's) is said from its start, not as [1.7e+09, 1.7e+09] s
    assert "interval 100 ([t0 + 1, t0 + 1.01] s, t0 = 1700000000 s)" in st.message(1_700_000_000.0 + ts)


def test_step_reports_the_failure_and_then_leaves_the_state_unchanged(nan_run):
    """Online: the step over the bad interval returns its input state with a failed status; any later step
    returns the failed state unchanged (estimate, gain, held input and status)."""
    flt, state, ts, us, ys, traj = nan_run
    k = 100
    good = FilterState(g_hat=traj.g_hat[k], K=traj.K[k], u_last=jnp.asarray(us[k - 1]), status=state.status)
    failed = flt.step(good, ts[k], us[k], ys[k], ts[k + 1] - ts[k])
    assert failed.status.cause == "non-finite" and float(failed.status.time) == ts[k]
    assert _leaves_equal((failed.g_hat, failed.K), (good.g_hat, good.K))
    for j in (k + 1, k + 5):
        later = flt.step(failed, ts[j], us[j], ys[j], ts[j + 1] - ts[j])
        assert _leaves_equal(later, failed), j
    assert _leaves_equal(flt.step(traj.final, ts[150], us[150], ys[150], 0.01), traj.final)


# --- symmetry of K ---------------------------------------------------------------------------------------------------
def _quarter(X, Y):
    """A user connection with torsion: omega(X, Y) = ad_X Y / 4 (T_X = -ad_X / 2)."""
    return 0.25 * (SE2.ad(X) @ Y)


def _localization_log(n=60):
    ts = 0.01 * np.arange(n)
    us = np.tile([0.8, 0.0, 0.3], (n, 1))
    ys = np.full((n, 2), np.nan)
    ys[::10] = np.column_stack([np.sin(ts[::10]), 0.2 * ts[::10]]) + 0.3
    return ts, us, ys


def test_connection_with_torsion_may_make_K_asymmetric():
    """A user connection with torsion gives an asymmetric K (measured relative asymmetry 0.04, far above the
    1e-8 of the check), which is not a failure: the filter knows K need not be symmetric then."""
    flt = liemef.MinimumEnergyFilter(planar_localization(), connection=_quarter, substeps=1,
                                     curvature="exact")  # the theorem: its E and W carry the torsion
    assert not flt.symmetric
    ts, us, ys = _localization_log()
    traj = flt.run(flt.init(SE2.from_coords(jnp.array([0.3, 0.1, -0.2])), np.diag([0.5, 1.0, 1.0])), ts, us, ys)
    K = np.asarray(traj.K)
    asym = np.abs(K - np.swapaxes(K, 1, 2)).max() / np.abs(K).max()
    print(f"torsion: relative asymmetry of K {asym:.3g}")
    assert asym > 1e-6
    assert traj.status.ok


class _SkewedE(liemef.MinimumEnergyFilter):
    """A filter whose E has a (wrong) skew part: with the (0)-connection K must stay symmetric, so it fails."""

    def _terms(self, model, weights, g_hat, K, u, y, t, **kwargs):
        tm = super()._terms(model, weights, g_hat, K, u, y, t, **kwargs)
        return eqx.tree_at(lambda m: m.E, tm, tm.E + jnp.array([[0.0, 0.5, 0.0], [-0.5, 0.0, 0.0], [0.0, 0.0, 0.0]]))


def test_asymmetric_K_is_a_failure_where_it_must_be_symmetric():
    """The (0)-connection (and the first order) keep K symmetric; a non-symmetric E breaks that and is reported
    as "K not symmetric" at the first interval."""
    flt = _SkewedE(planar_localization(), connection="zero", order="first", substeps=1)
    assert flt.symmetric
    ts, us, ys = _localization_log()
    traj = flt.run(flt.init(SE2.from_coords(jnp.array([0.3, 0.1, -0.2])), np.diag([0.5, 1.0, 1.0])), ts, us, ys)
    assert (traj.status.cause, int(traj.status.index)) == ("K not symmetric", 0)


# --- gate ------------------------------------------------------------------------------------------------------------
def test_too_many_consecutive_rejections_fail_with_cause_gate():
    """planar_localization(gate=0.999, max_rejections=2): three GPS fixes in a row 50 m off; the first two are
    rejected and counted, the third exceeds max_rejections: cause "gate" at its interval."""
    flt = liemef.MinimumEnergyFilter(planar_localization(gate=0.999, max_rejections=2), order="first", substeps=1)
    ts = 0.01 * np.arange(700)
    us = np.tile([1.0, 0.0, 0.0], (ts.size, 1))
    ys = np.full((ts.size, 2), np.nan)
    fix = np.arange(0, ts.size, 100)
    ys[fix] = np.column_stack([ts[fix], np.zeros(fix.size)])
    bad = fix[3:6]
    ys[bad, 1] += 50.0
    state = flt.init(SE2.identity(), np.diag([1e-3, 0.1, 0.1]))
    traj = flt.run(state, ts, us, ys)
    st = traj.status
    assert (st.cause, int(st.index)) == ("gate", bad[2])
    assert int(st.rejected[0]) == 3 and int(st.consecutive[0]) == 3
    # one rejection fewer in a row is not a failure
    ys2 = ys.copy()
    ys2[bad[2]] = np.nan
    ok = flt.run(state, ts, us, ys2)
    assert ok.status.ok and int(ok.status.rejected[0]) == 2


def test_each_cause_is_one_member_with_its_code_label_and_message():
    """CAUSES is one enumeration (diffrax's RESULTS shape): a member is its label, reads back by its code, and
    carries the message that Status.message prints."""
    assert [c.code for c in CAUSES] == list(range(len(CAUSES)))
    assert all(CAUSES[c.code] is c and CAUSES[np.int32(c.code)] is c for c in CAUSES)
    assert CAUSES.NONFINITE == "non-finite" and CAUSES["GATE"] is CAUSES.GATE
    assert len({c.message for c in CAUSES}) == len(CAUSES)
    st = liemef.filters.Status.initial(1)
    failed = eqx.tree_at(lambda s: (s.code, s.index, s.time), st,
                         (jnp.asarray(CAUSES.INDEFINITE.code, jnp.int32), jnp.asarray(3, jnp.int32), jnp.asarray(0.5)))
    assert failed.cause == "K not positive definite" and CAUSES.INDEFINITE.message in failed.message()
