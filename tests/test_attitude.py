"""Saccon et al. 2016, Sec. V-B: the attitude experiment on TSO(3), both connections on the same data.

Fast tests use 15 s runs (the (0)-filter's transient is over by about 5 s, the (-)-filter's later); the full
50 s paper run is marked slow.
"""

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef.groups import SO3
from liemef.studies.experiments import (
    EXPERIMENTS,
    MonteCarloResult,
    attitude,
    get_experiment,
    montecarlo,
    reproduce_experiment,
)
from tolerances import ON_GROUP, ROUNDOFF, SYMMETRY

CONFIG = attitude.AttitudeConfig(duration=15.0, steady=(10.0, 15.0))
RUNS = 4

# Claims, from what was measured at the time of writing. 16 seeds of CONFIG (rms over 10-15 s): e_R of the
# (0)-filter 1.1-2.1 deg, of the (-)-filter 1.8-5.7 deg; |e_Omega| 0.035-0.065 and 0.064-0.21 rad/s; the
# (0)-filter had the smaller e_R in 15 of 16 trials. Full 50 s run, seed 0 (rms over 10-50 s): e_R 2.00 and
# 2.63 deg; over 16 seeds the (0)-filter was better in 16 of 16. The bounds leave a factor of about 2.
E_R_ZERO_10_15 = 4.0
"""deg; the directions are measured with about 30 deg of noise per sample (sigma_eps = 0.5/3)."""
E_R_MINUS_10_15 = 10.0
"""deg."""
E_OMEGA_ZERO_10_15 = 0.12
"""rad/s."""
E_OMEGA_MINUS_10_15 = 0.4
"""rad/s."""
E_R_ZERO_10_50 = 4.0
"""deg, the full paper run."""
MINUS_ASYMMETRY = 1e-2
"""Smallest max |K - K^T|/|K| of the (-)-filter over a run (0.12 measured): its Riccati equation is not
symmetric (Saccon et al. 2016, after Prop. 5.2)."""
NOISE_STD = 0.05
"""Relative tolerance of a sample standard deviation from 15001 draws (its own relative spread is 0.6 %)."""


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("attitude")
    rep = reproduce_experiment(attitude.ATTITUDE, out, CONFIG, runs=RUNS, progress=False)
    return out, rep


@pytest.fixture(scope="module")
def paper_run():
    # the seeded run of the reproduction, in memory
    return attitude.run(CONFIG)


def test_filter_starts_60_deg_off_and_converges_with_both_connections(paper_run):
    a = paper_run.arrays
    ts = a["ts"]
    for conn in ("zero", "minus"):
        e = a[f"attitude_error_{conn}"]
        assert e[0, 0] == pytest.approx(60.0, abs=1e-9)  # e_R(0) = 60 deg; Omega_hat(0) = Omega(0)
        assert e[0, 1] == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(np.linalg.norm(e[:, 2:5], axis=1), np.radians(e[:, 0]), rtol=1e-12)
    late = ts >= 10.0
    rms = {conn: np.sqrt(np.mean(a[f"attitude_error_{conn}"][late, :2] ** 2, axis=0)) for conn in ("zero", "minus")}
    assert rms["zero"][0] < E_R_ZERO_10_15 and rms["zero"][1] < E_OMEGA_ZERO_10_15
    assert rms["minus"][0] < E_R_MINUS_10_15 and rms["minus"][1] < E_OMEGA_MINUS_10_15
    comps = paper_run.metrics["attitude_errors"]["connections"]
    assert comps["zero"]["e_R"]["10-15s"]["rms"] == pytest.approx(rms["zero"][0], rel=1e-12)
    assert comps["minus"]["e_Omega"]["10-15s"]["rms"] == pytest.approx(rms["minus"][1], rel=1e-12)
    # e_R is eq. (86) of the paper: acos(1 - tr(I - R^T R_hat)/2)
    tr = paper_run.raw["trajectories"]
    R = np.asarray(paper_run.raw["truth"].g.factors[0].as_matrix())[::500]
    R_hat = np.asarray(tr["minus"].g_hat.factors[0].as_matrix())[::500]
    eq86 = np.degrees(np.arccos(np.clip(1.0 - (3.0 - np.einsum("kji,kji->k", R, R_hat)) / 2.0, -1.0, 1.0)))
    np.testing.assert_allclose(a["attitude_error_minus"][::500, 0], eq86, atol=1e-5)


def test_gain_is_symmetric_for_zero_and_not_for_minus(paper_run):
    K = {conn: np.asarray(t.K) for conn, t in paper_run.raw["trajectories"].items()}
    for conn, k in K.items():
        assert k.shape == (15001, 6, 6) and np.all(np.isfinite(k)), conn
        np.testing.assert_array_equal(k[0], np.eye(6))  # K(0) = I6
    assert "alpha=0.01" in paper_run.metrics["run"]["filter"]
    asym = {c: (np.linalg.norm(k - np.swapaxes(k, 1, 2), axis=(1, 2)) / np.linalg.norm(k, axis=(1, 2))).max()
            for c, k in K.items()}
    assert asym["zero"] < SYMMETRY
    assert asym["minus"] > MINUS_ASYMMETRY
    gains = paper_run.metrics["gain_by_connection"]
    assert gains["minus"]["max_rel_asymmetry"] == pytest.approx(asym["minus"], rel=1e-6)
    assert gains["zero"]["min_eigenvalue"] > 0.0


def test_truth_is_geometric_euler_from_the_nominal_torque_and_sensors_as_printed(paper_run):
    truth, log = paper_run.raw["truth"], paper_run.raw["log"]
    R = np.asarray(truth.g.factors[0].as_matrix())
    W = np.asarray(truth.g.factors[1].x)
    ts, h = np.asarray(truth.ts), CONFIG.dt
    I = np.diag(CONFIG.inertia_diag)
    tau = np.asarray(jax.vmap(attitude.paper_torque)(jnp.asarray(ts)))
    np.testing.assert_allclose(tau[:, 1], np.cos(2 * np.pi * ts), atol=1e-12)  # eq. (80), cos(2 pi t)
    for k in (0, 1, 777, 9000, 14999):
        # Saccon et al. 2016, Sec. V-B: R(t + h) = R(t) exp(h Omega(t)); Omega by forward Euler of eq. (56)
        np.testing.assert_allclose(R[k + 1], R[k] @ np.asarray(SO3.exp(jnp.asarray(h * W[k])).as_matrix()),
                                   atol=ROUNDOFF)
        W_dot = np.linalg.solve(I, np.cross(I @ W[k], W[k]) + tau[k])
        np.testing.assert_allclose(W[k + 1], W[k] + h * W_dot, atol=ROUNDOFF)
    assert np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max() < ON_GROUP
    np.testing.assert_allclose(R[0], np.eye(3), atol=ROUNDOFF)
    np.testing.assert_allclose(W[0], CONFIG.omega0, atol=ROUNDOFF)
    # the filter's torque is tau + I B2 delta, delta ~ N(0, I3) per sample (eq. (81))
    delta = np.linalg.solve(I, (np.asarray(log.us) - tau).T).T / CONFIG.sigma_delta
    np.testing.assert_allclose(delta.std(axis=0), 1.0, rtol=NOISE_STD)
    np.testing.assert_allclose(np.asarray(truth.u), tau, atol=1e-12)
    # the directions R^T a1, R^T a2 with noise sigma_eps per component
    eps = np.asarray(log.ys) - np.concatenate([R[:, 2, :], R[:, 1, :]], axis=1)
    np.testing.assert_allclose(eps.std(axis=0), CONFIG.sigma_eps, rtol=NOISE_STD)


def test_measured_attitude_by_triad_recovers_noise_free_rotations():
    Rs = np.asarray(SO3.exp(jnp.asarray(np.random.default_rng(3).normal(0.0, 1.2, (50, 3)))).as_matrix())
    ys = np.concatenate([Rs[:, 2, :], Rs[:, 1, :]], axis=1)  # (R^T e3, R^T e2)
    q = attitude.measured_state(ys)
    np.testing.assert_allclose(np.asarray(SO3.exp(jnp.asarray(q[:, :3])).as_matrix()), Rs, atol=1e-9)
    assert np.all(np.isnan(q[:, 3:]))


@pytest.mark.slow  # a 4-trial Monte Carlo of 15 s at 1 ms: about 70 s of the fast suite's 2 cores
def test_reproduction_writes_fig3_metrics_and_the_paired_comparison(reproduced, paper_run):
    out, rep = reproduced
    for name in ("metrics.json", "arrays.npz", "fig3_errors.png", "fig_angular_velocity.png", "comparison.md",
                 "montecarlo.json", "montecarlo.npz"):
        assert (out / name).is_file(), name
    assert (out / "fig3_errors.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert rep.figures[0].path.name == "fig3_errors.png" and "Fig. 3" in rep.figures[0].caption
    m = json.loads((out / "metrics.json").read_text())
    cmp = m["comparison"]["monte_carlo"]
    assert (cmp["runs"], cmp["connection"], cmp["compare_with"]) == (RUNS, "zero", "minus")
    w = cmp["windows"]["10-15s"]
    a, b = np.array(w["per_trial_rms_e_R_deg"]["zero"]), np.array(w["per_trial_rms_e_R_deg"]["minus"])
    assert w["wins"] == int(np.sum(a < b)) and w["fraction"] == w["wins"] / RUNS
    assert w["wins"] >= RUNS - 1  # the paper: "the (0)-connection based filter performing best"
    assert "smaller in" in rep.text and f"of {RUNS} trials" in rep.text
    # paired: trial k is one simulation filtered by both connections, the run with key k
    mc = MonteCarloResult.load(out)
    k = 1
    single = attitude.run(CONFIG, key=mc.trial_key(k)).metrics["attitude_errors"]["connections"]
    for conn, v in (("zero", a[k]), ("minus", b[k])):
        assert single[conn]["e_R"]["10-15s"]["rms"] == pytest.approx(v, rel=1e-9)
    # the seeded run written to the folder is paper_run
    assert m["comparison"]["single_run"]["10-15s"]["rms_e_R_deg"]["zero"] == pytest.approx(
        paper_run.metrics["comparison"]["single_run"]["10-15s"]["rms_e_R_deg"]["zero"], rel=1e-12)


def test_figure3_draws_both_connections_on_the_same_axes(paper_run):
    fig = attitude.figure3(paper_run.arrays, CONFIG.steady)
    axes = fig.get_axes()
    assert len(axes) == 4
    top_left = axes[0]
    lines = top_left.get_lines()
    assert [ln.get_label() for ln in lines] == ["(0)-connection", "(-)-connection"]
    np.testing.assert_array_equal(lines[1].get_ydata(), paper_run.arrays["attitude_error_minus"][:, 0])
    assert lines[1].get_linestyle() == "--"


def test_trial_spec_columns_are_both_connections():
    spec = attitude.trial_spec(CONFIG)
    assert spec.names == ("e_R_zero", "e_Omega_zero", "e_R_minus", "e_Omega_minus")
    assert spec.units == ("deg", "rad/s", "deg", "rad/s")
    assert [w.label for w in spec.windows] == ["full", "10-15s", "12.5-15s"]
    out = jax.eval_shape(spec.errors, jax.random.key(0))
    assert out.shape == (15001, 4)
    # a shorter run cuts the steady window at its final time (`liemef reproduce attitude --duration 20`)
    assert [w.label for w in attitude.AttitudeConfig(duration=20.0).windows] == ["full", "10-20s", "15-20s"]
    assert [w.label for w in attitude.AttitudeConfig(duration=5.0).windows] == ["full"]


def test_registry_and_quick_config():
    exp = get_experiment("attitude")
    assert exp is EXPERIMENTS["attitude"] and "Saccon" in exp.paper and "Fig. 3" in exp.paper
    assert exp.trial_fn is attitude.trial_spec and exp.reproduce_fn is attitude.reproduce
    quick = exp.quick()
    assert quick.duration < exp.default_config.duration and quick.steady[1] <= quick.duration
    assert exp.quick_runs > 0 and exp.runs >= exp.quick_runs


@pytest.mark.slow  # a 20-seed paired Monte Carlo study: `make test-slow`
def test_consistent_weights_halve_the_attitude_error_and_close_the_gap_between_connections():
    """The printed Q = sigma_eps^2 I6, R = sigma_delta^2 I3 make the filter ignore the noise levels; with Q = I6,
    R = I3, on the same data, the attitude error of both connections is about halved and the (-)-filter almost
    catches up with the (0)-filter. Measured over 20 trials of the full 50 s (10-50 s): rms e_R (0) 1.80 -> 0.90
    deg, (-) 2.53 -> 0.91 deg; the (0)-filter still wins 19 of 20, by 0.012 +- 0.007 deg."""
    res = {w: montecarlo(attitude.ATTITUDE, dataclasses.replace(CONFIG, weights=w), runs=RUNS, seed=0,
                         batch_size=RUNS, progress=False) for w in ("printed", "consistent")}
    window = res["printed"].windows[1]
    e = {(w, conn): res[w].values(f"e_R_{conn}", window, "rms") for w in res for conn in ("zero", "minus")}
    for conn in ("zero", "minus"):
        assert e["consistent", conn].mean() < 0.75 * e["printed", conn].mean(), (conn, e)
    gap = lambda w: (e[w, "minus"] - e[w, "zero"]).mean()  # noqa: E731
    assert gap("consistent") < 0.25 * gap("printed"), (gap("consistent"), gap("printed"))


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(compare_with="zero"), "compare_with: expected one of"),
    (dict(connection="nope"), "connection: expected one of"),
    (dict(initial_axis=(0.0, 0.0, 0.0)), "initial_axis: expected a nonzero vector"),
    (dict(inertia_diag=(1.0, -1.0, 1.0)), "inertia_diag: expected entries > 0"),
    (dict(steady=(20.0, 10.0)), "steady: expected a window"),
    (dict(sigma_eps=0.0), "sigma_eps: expected a finite number > 0"),
    (dict(weights="unweighted"), "weights: expected one of"),
])
def test_bad_config_raises_a_named_value_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        attitude.AttitudeConfig(**kwargs)


@pytest.mark.slow
def test_full_paper_run_zero_connection_converges_and_is_better():
    res = attitude.run(attitude.AttitudeConfig())
    single = res.metrics["comparison"]["single_run"]["10-50s"]["rms_e_R_deg"]
    assert single["zero"] < E_R_ZERO_10_50
    assert single["zero"] < single["minus"]
    assert res.metrics["gain_by_connection"]["zero"]["max_rel_asymmetry"] < SYMMETRY
    assert math.isclose(res.arrays["attitude_error_zero"][0, 0], 60.0, abs_tol=1e-9)
