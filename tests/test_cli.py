"""The command line: `liemef reproduce`, `reproduce all`, `montecarlo` and `run` write every documented file;
bad names, options and paths give clear click errors."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from click.testing import CliRunner

from liemef.cli import cli, main
from liemef.reports import io, plots
from liemef.studies.experiments import EXPERIMENTS, SCHEMA, MonteCarloResult, Output, Reproduction, tse2
from liemef.studies.experiments._base import PAPER_SUBSTEPS

PNG = b"\x89PNG\r\n\x1a\n"


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro") / "new" / "dir"  # created if missing
    res = invoke("reproduce", "tse2", "--out", out, "--duration", 12, "--seed", 3, "--runs", 0)
    return out, res


def test_reproduce_writes_metrics_arrays_and_figures(reproduced):
    out, res = reproduced
    assert res.exit_code == 0, res.output
    for name in ("metrics.json", "arrays.npz", "fig3_pose.png", "fig4_velocity.png"):
        assert (out / name).is_file(), name
    for name in ("fig3_pose.png", "fig4_velocity.png"):
        assert (out / name).read_bytes()[:8] == PNG
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


def test_reproduce_metrics_json_has_the_documented_structure(reproduced):
    out, _ = reproduced
    m = json.loads((out / "metrics.json").read_text())
    assert m["schema"] == SCHEMA
    assert m["experiment"]["name"] == "tse2" and "Rigo" in m["experiment"]["paper"]
    assert (m["config"]["seed"], m["config"]["duration"], m["config"]["connection"]) == (3, 12.0, "zero")
    assert set(m["assumptions"]) >= {"alpha", "K0"}
    assert m["windows"]["full"]["samples"] == 12001 and m["windows"]["10-50s"]["samples"] == 2001
    comps = m["errors"]["components"]
    assert list(comps) == ["theta", "x", "y", "omega", "vx", "vy"]
    assert [comps[c]["unit"] for c in comps] == ["rad", "m", "m", "rad/s", "m/s", "m/s"]
    for c in comps.values():
        for w in ("full", "10-50s"):
            assert set(c[w]) == {"mean", "std", "rms"} and all(isinstance(v, float) for v in c[w].values())
    assert list(m["group_errors"]["components"])[0] == "log_theta"
    assert set(m["gain"]) == {"max_rel_asymmetry", "min_eigenvalue", "final_diagonal", "non_finite_steps"}
    assert m["run"]["finite"] is True
    arrays = io.read_arrays(out / "arrays.npz")
    assert arrays["filtered"].shape == (12001, 6)
    assert comps["x"]["full"]["rms"] == pytest.approx(np.sqrt(np.mean(arrays["error"][:, 1] ** 2)), rel=1e-12)


def test_reproduce_prints_the_error_table(reproduced):
    _, res = reproduced
    text = res.output
    for word in ("component", "unit", "mean(full)", "rms(10-50s)", "theta", "rad/s", "m/s", "Wrote"):
        assert word in text, word


def test_reproduce_options_reach_the_config(tmp_path):
    res = invoke("reproduce", "tse2-velocity", "--out", tmp_path, "--duration", 0.5, "--connection", "minus",
                 "--order", "first", "--seed", 9, "--runs", 0)
    assert res.exit_code == 0, res.output
    m = io.read_metrics(tmp_path / "metrics.json")
    assert (m["config"]["connection"], m["config"]["order"], m["config"]["seed"]) == ("minus", "first", 9)
    assert m["config"]["sensor"] == "velocity"
    assert m["windows"]["10-50s"]["samples"] == 0
    assert m["errors"]["components"]["x"]["10-50s"]["rms"] is None  # empty window: null
    assert "  -  " in res.output or " - " in res.output
    assert (tmp_path / "fig_pose.png").is_file() and (tmp_path / "fig_velocity.png").is_file()


def test_unknown_experiment_lists_the_valid_ones(tmp_path):
    res = CliRunner().invoke(cli, ["reproduce", "tse3", "--out", str(tmp_path)])
    assert res.exit_code == 2
    assert "tse3" in res.output and "'tse2'" in res.output and "'tse2-velocity'" in res.output


def test_bad_out_and_options_are_click_errors(tmp_path):
    f = tmp_path / "file"
    f.write_text("")
    res = CliRunner().invoke(cli, ["reproduce", "tse2", "--out", str(f)])
    assert res.exit_code == 2 and "expected a directory" in res.output
    res = CliRunner().invoke(cli, ["reproduce", "tse2", "--out", str(tmp_path), "--connection", "zerro"])
    assert res.exit_code == 2 and "'minus'" in res.output
    res = CliRunner().invoke(cli, ["reproduce", "tse2", "--out", str(tmp_path), "--duration", "-1"])
    assert res.exit_code == 2 and "duration: expected a finite number > 0" in res.output


# --- liemef run
@pytest.fixture(scope="module")
def recorded_csv(tmp_path_factory):
    """A 2 s log of the paper's setup at 10 ms, written as CSV with the documented header: every 10th sample of
    the first 2 s of a simulation on the `reproduced` fixture's grid (12 s at 1 ms), whose compiled simulation
    serves (a grid of another length compiles its own)."""
    c = tse2.TSE2Config(duration=12.0)
    s = tse2.setup(c)
    truth, log = tse2.simulate(s.system, s.g0, tse2.paper_input, s.ts, jax.random.key(4))
    every = slice(0, 2001, 10)
    p = tmp_path_factory.mktemp("log") / "log.csv"
    io.write_csv(p, io.log_header(2, 7), [np.asarray(log.ts)[every], *np.asarray(log.us)[every].T,
                                          *np.asarray(log.ys)[every].T])
    return p, np.asarray(truth.coords())[every]


def test_run_filters_a_recorded_csv_log(recorded_csv, tmp_path):
    log, truth = recorded_csv
    out = tmp_path / "est"
    res = invoke("run", "--system", "tse2", "--log", log, "--out", out, "--k0", 2.0)
    assert res.exit_code == 0, res.output
    for name in ("estimates.csv", "metrics.json", "arrays.npz", "estimate.png"):
        assert (out / name).is_file(), name
    header = (out / "estimates.csv").read_text().splitlines()[0]
    assert header == "t,theta,x,y,omega,vx,vy," + ",".join(f"K_e{k}e{k}" for k in range(6))
    est = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=1)
    assert est.shape == (201, 13) and np.all(est[:, 7:] > 0)  # coordinates, then K's diagonal
    # the default initial estimate comes from the first sample (antennas' midpoint, heading, IMU)
    m = io.read_metrics(out / "metrics.json")
    assert m["config"]["K0_diag"] == [2.0] * 6
    assert abs(m["config"]["x0"][1] - truth[0, 1]) < 2.0
    assert set(m["innovation"]["components"]) == {"x1", "y1", "x2", "y2", "omega", "vx", "vy"}
    assert m["innovation"]["components"]["x1"]["unit"] == "m"
    assert "Innovation" in res.output


def test_run_accepts_an_experiments_arrays_npz_and_initial_state(reproduced, tmp_path):
    out, _ = reproduced
    x0 = "0.5235987755982988,1,2,0,0,0"
    res = invoke("run", "--system", "tse2", "--log", out / "arrays.npz", "--out", tmp_path, "--x0", x0,
                 "--k0-diag", "1,1,1,2,2,2", "--order", "first")
    assert res.exit_code == 0, res.output
    m = io.read_metrics(tmp_path / "metrics.json")
    assert m["config"]["x0"][0] == pytest.approx(np.pi / 6) and m["config"]["K0_diag"] == [1, 1, 1, 2, 2, 2]
    assert m["log"]["samples"] == 12001


@pytest.mark.parametrize(("system", "experiment", "config"), [
    # the TSO(3) and the Chaplygin IMU filters compile for 25-40 s each: in `make test-slow`
    pytest.param("attitude", "attitude", {"duration": 0.3}, marks=pytest.mark.slow),
    pytest.param("chaplygin", "chaplygin", {"duration": 2.0}, marks=pytest.mark.slow),
    ("chaplygin-gps", "chaplygin", {"duration": 2.0, "sensor": "gps"}),
    ("unit-circle", "unit-circle", {"duration": 2.0}),
])
def test_run_with_a_ready_system_repeats_its_experiments_filter(system, experiment, config, tmp_path):
    """``liemef run --system S`` on an experiment's saved arrays, started where the experiment's filter starts
    (x0, diagonal K0, connection, alpha): the same estimates, so the ready system is the paper's model with the
    experiment's weights."""
    exp = EXPERIMENTS[experiment]
    res = exp.run(exp.config(**config))
    io.write_result(tmp_path / "exp", res.metrics, res.arrays)
    a = res.arrays
    x0 = ",".join(repr(float(v)) for v in a["filtered"][0])
    k0 = ",".join(repr(float(v)) for v in a["K_diag"][0])
    alpha = res.metrics["config"].get("alpha", 0.0)
    out = invoke("run", "--system", system, "--log", tmp_path / "exp" / "arrays.npz", "--out", tmp_path / "run",
                 "--x0", x0, "--k0-diag", k0, "--alpha", alpha, "--connection", res.metrics["config"]["connection"],
                 "--substeps", PAPER_SUBSTEPS,  # the experiments integrate as the papers do
                 "--curvature", "exact")  # and run the theorem's filter
    assert out.exit_code == 0, out.output
    est = np.loadtxt(tmp_path / "run" / "estimates.csv", delimiter=",", skiprows=1)
    c = a["filtered"].shape[1]
    assert est.shape == (a["ts"].shape[0], 1 + c + a["K_diag"].shape[1])  # t, coordinates, K's diagonal
    np.testing.assert_allclose(est[:, 1 + c:], a["K_diag"], rtol=1e-9, atol=1e-12)
    diff = est[:, 1:1 + c] - a["filtered"]
    angles = [n in ("theta",) for n in a["names"]]
    diff[:, angles] = (diff[:, angles] + np.pi) % (2 * np.pi) - np.pi  # filtered angles are unwrapped
    assert np.abs(diff).max() < 1e-9, np.abs(diff).max(axis=0)
    assert np.abs(a["filtered"][-1] - a["filtered"][0]).max() > 1e-3  # the estimate moved: the check can fail


def test_run_errors_are_click_errors(recorded_csv, tmp_path):
    log, _ = recorded_csv
    res = CliRunner().invoke(cli, ["run", "--system", "car", "--log", str(log), "--out", str(tmp_path)])
    assert res.exit_code == 2 and "'tse2'" in res.output and "'tse2-velocity'" in res.output
    res = CliRunner().invoke(cli, ["run", "--system", "tse2-velocity", "--log", str(log), "--out",
                                   str(tmp_path)])
    assert res.exit_code == 2 and "unexpected column(s)" in res.output
    res = CliRunner().invoke(cli, ["run", "--system", "tse2", "--log", str(tmp_path / "no.csv"), "--out",
                                   str(tmp_path)])
    assert res.exit_code == 2 and "file not found" in res.output
    res = CliRunner().invoke(cli, ["run", "--system", "tse2", "--log", str(log), "--out", str(tmp_path),
                                   "--x0", "1,2,3"])
    assert res.exit_code == 2 and "expected 6 finite numbers" in res.output


def test_figures_are_drawn_from_the_saved_files_alone(tmp_path):
    N = 50
    ts = np.linspace(0, 1, N)
    truth = np.stack([np.sin(ts), ts, ts**2], axis=1)
    arrays = {"ts": ts, "names": np.array(["theta", "x", "y"]), "units": np.array(["rad", "m", "m"]),
              "truth": truth, "filtered": truth + 0.01,
              "measured": np.where(ts[:, None] > 0.5, truth, np.nan),
              "error": np.full((N, 3), -0.01)}
    figures = [{"file": "f.png", "components": ["theta", "y"], "title": "t"}]
    io.write_result(tmp_path, {"figures": figures}, arrays)
    written = plots.write_figures(tmp_path)
    assert [p.name for p in written] == ["f.png"] and written[0].read_bytes()[:8] == PNG
    with pytest.raises(ValueError, match="components: expected names among"):
        plots.state_figure(arrays, ["psi"])


def test_main_is_the_console_entry_point(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "reproduce" in out and "run" in out


# --- liemef montecarlo, reproduce --list, reproduce all
def test_montecarlo_prints_the_table_and_writes_results(tmp_path):
    # duration 12 s: the configuration of the `reproduced` fixture and of test_montecarlo.py (one compilation)
    res = invoke("montecarlo", "tse2", "--duration", 12, "--runs", 4, "--batch-size", 2, "--seed", 1,
                 "--out", tmp_path / "mc", "--no-progress")
    assert res.exit_code == 0, res.output
    text = res.output
    for word in ("Monte Carlo of tse2: 4 trials (seed 1), all finite", "window full (12001 samples)",
                 "window 10-50s (2001 samples)", "spread", "p95", "trials/s", "Wrote montecarlo.npz"):
        assert word in text, word
    for name in ("montecarlo.npz", "montecarlo.json", "montecarlo.md", "montecarlo.csv"):
        assert (tmp_path / "mc" / name).is_file(), name
    mc = MonteCarloResult.load(tmp_path / "mc")
    assert (mc.runs, mc.seed, mc.config["duration"], mc.batch_size) == (4, 1, 12.0, 2)
    assert len((tmp_path / "mc" / "montecarlo.csv").read_text().splitlines()) == 1 + 2 * 6 * 3
    assert "| x | m | rms |" in (tmp_path / "mc" / "montecarlo.md").read_text()


def test_montecarlo_option_errors_are_click_errors(tmp_path):
    res = CliRunner().invoke(cli, ["montecarlo", "tse2", "--runs", "2", "--set", "dtt=0.1"])
    assert res.exit_code == 2 and "unknown config option 'dtt'" in res.output and "'dt'" in res.output
    res = CliRunner().invoke(cli, ["montecarlo", "tse2", "--runs", "2", "--set", "dt=fast"])
    assert res.exit_code == 2 and "dt: expected a value like 0.001, got 'fast'" in res.output
    res = CliRunner().invoke(cli, ["montecarlo", "tse2", "--runs", "2", "--set", "connection"])
    assert res.exit_code == 2 and "expected KEY=VALUE" in res.output
    res = CliRunner().invoke(cli, ["montecarlo", "tse2", "--runs", "0"])
    assert res.exit_code == 2 and "--runs" in res.output
    res = CliRunner().invoke(cli, ["montecarlo", "tse2", "--set", "connection=zerro"])
    assert res.exit_code == 2 and "connection: expected one of" in res.output


def test_set_values_take_the_type_of_the_config_field():
    from liemef.studies.settings import parse_settings as _settings

    base = tse2.TSE2Config()
    got = _settings(("dt=0.01", "seed=4", "connection=minus", "K0_diag=1, 1, 1, 2,2,2", "steady=5 20"), base)
    assert got == {"dt": 0.01, "seed": 4, "connection": "minus", "K0_diag": (1.0, 1.0, 1.0, 2.0, 2.0, 2.0),
                   "steady": (5.0, 20.0)}
    assert tse2.TSE2Config(**got).K0_diag == (1.0, 1.0, 1.0, 2.0, 2.0, 2.0)


def test_reproduce_list_names_every_experiment_with_its_paper_and_figures():
    res = invoke("reproduce", "--list")
    assert res.exit_code == 0, res.output
    for name, exp in EXPERIMENTS.items():
        assert f"{name}: {exp.title}" in res.output and exp.paper in res.output
        for f in exp.figures:
            assert f.filename in res.output and f.paper_figure in res.output
    assert "tse2:" in res.output and "tse2-velocity:" in res.output and "Fig. 3" in res.output


def test_reproduce_needs_an_experiment_and_out(tmp_path):
    res = CliRunner().invoke(cli, ["reproduce"])
    assert res.exit_code == 2 and "Missing argument" in res.output
    res = CliRunner().invoke(cli, ["reproduce", "tse2"])
    assert res.exit_code == 2 and "Missing option '--out'" in res.output
    res = CliRunner().invoke(cli, ["reproduce", "all", "--out", str(tmp_path), "--duration", "1"])
    assert res.exit_code == 2 and "--duration: config options apply to one experiment" in res.output


@pytest.fixture
def tiny_registry():
    """Only tse2 and tse2-velocity, with quick configs that reuse the compilations of the tests above."""
    saved = dict(EXPERIMENTS)
    EXPERIMENTS.clear()
    EXPERIMENTS["tse2"] = dataclasses.replace(saved["tse2"], quick_config=saved["tse2"].config(duration=12.0),
                                              quick_runs=2)
    velocity = saved["tse2-velocity"]
    EXPERIMENTS["tse2-velocity"] = dataclasses.replace(
        velocity, quick_config=velocity.config(duration=0.5, connection="minus", order="first"), quick_runs=0)
    yield EXPERIMENTS
    EXPERIMENTS.clear()
    EXPERIMENTS.update(saved)


def test_reproduce_all_writes_one_folder_per_experiment_and_an_index(tiny_registry, tmp_path):
    out = tmp_path / "all"
    res = invoke("reproduce", "all", "--out", out, "--no-progress")
    assert res.exit_code == 0, res.output
    assert "Wrote 2 of 2 experiments and index.md" in res.output
    for name in ("metrics.json", "arrays.npz", "fig3_pose.png", "fig4_velocity.png", "errors.md", "errors.csv",
                 "montecarlo.md", "montecarlo.csv", "montecarlo.json", "montecarlo.npz"):
        assert (out / "tse2" / name).is_file(), name
    assert (out / "tse2-velocity" / "fig_pose.png").is_file()
    assert not (out / "tse2-velocity" / "montecarlo.md").exists()  # quick_runs = 0: the seeded run only
    assert io.read_metrics(out / "tse2-velocity" / "metrics.json")["config"]["duration"] == 0.5
    assert MonteCarloResult.load(out / "tse2").runs == 2
    index = (out / "index.md").read_text()
    for link in ("](tse2/fig3_pose.png)", "](tse2/fig4_velocity.png)", "](tse2/montecarlo.md)",
                 "](tse2/errors.md)", "](tse2-velocity/fig_velocity.png)", "](tse2-velocity/errors.md)"):
        assert link in index, link
    assert "Rigo et al. 2022, Fig. 3" in index and "duration = 12.0 (default: 50.0)" in index
    assert "2 Monte Carlo trials" in index and "| ok |" in index
    assert "--quick" in index


def test_reproduce_all_reports_a_failing_experiment_and_keeps_going(tiny_registry, tmp_path):
    def broken(config, key=None):
        raise RuntimeError("boom")

    EXPERIMENTS["tse2-velocity"] = dataclasses.replace(EXPERIMENTS["tse2-velocity"], run_fn=broken)
    del EXPERIMENTS["tse2"]
    EXPERIMENTS["custom"] = dataclasses.replace(
        tiny_registry["tse2-velocity"], name="custom", run_fn=broken,
        reproduce_fn=lambda config, out, runs, progress: Reproduction(
            "custom", out, tables=(Output(io.write_text(out / "t.md", "x"), "Table 1"),), text="custom done"))
    res = CliRunner().invoke(cli, ["reproduce", "all", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "1 experiment(s) failed: tse2-velocity" in res.output
    assert "custom done" in res.output
    index = (tmp_path / "index.md").read_text()
    assert "**Failed**: `RuntimeError: boom`" in index and "[t.md](custom/t.md): Table 1" in index


def test_a_setting_given_twice_is_refused_not_overwritten(tmp_path):
    """--set KEY twice, or --set KEY beside the option for KEY, or montecarlo's --set seed (its trials are seeded by
    --seed): one of the two would silently win (a run recorded seed 5 and ran seed 0). Each exits 2 naming --set
    and the key, before anything is written."""
    cases = [(["montecarlo", "unit-circle", "--quick", "--runs", "2", "--set", "seed=5"], "seed: expected no --set"),
             (["montecarlo", "unit-circle", "--quick", "--runs", "2", "--duration", "5", "--set", "duration=50"],
              "duration: given both by --duration and by --set"),
             (["montecarlo", "unit-circle", "--quick", "--runs", "2", "--set", "duration=5", "--set", "duration=6"],
              "duration: expected each key once"),
             (["compare", "localization", "--runs", "2", "--set", "duration=4", "--set", "duration=5"],
              "duration: expected each key once")]
    for i, (args, said) in enumerate(cases):
        res = CliRunner().invoke(cli, [*args, "--out", str(tmp_path / str(i)), "--no-progress"])
        assert res.exit_code == 2 and "'--set'" in res.output and said in res.output, (args, res.output)
        assert not (tmp_path / str(i)).exists()


def test_one_trial_s_spread_is_an_empty_cell_in_every_output(tmp_path):
    """One trial has no spread: the JSON's null and the Markdown's '-' are an empty CSV cell, not 'nan' (a value a
    reader would parse as one)."""
    import csv

    res = CliRunner().invoke(cli, ["montecarlo", "unit-circle", "--quick", "--runs", "1", "--out",
                                   str(tmp_path / "mc"), "--no-progress"])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader((tmp_path / "mc" / "montecarlo.csv").open()))
    assert rows and all(r["spread"] == "" and r["mean"] not in ("", "nan") for r in rows)
    assert "nan" not in (tmp_path / "mc" / "montecarlo.csv").read_text()
