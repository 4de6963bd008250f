"""The command line: `liemef reproduce` and `liemef run` write every documented file; bad names and paths give
clear click errors."""

import json

import jax
import numpy as np
import pytest
from click.testing import CliRunner

from liemef import io, plots
from liemef.cli import cli, main
from liemef.experiments import SCHEMA, tse2

PNG = b"\x89PNG\r\n\x1a\n"


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro") / "new" / "dir"  # created if missing
    res = invoke("reproduce", "tse2", "--out", out, "--duration", 12, "--seed", 3)
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
                 "--order", "first", "--seed", 9)
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
    """A 2 s log of the paper's setup at 10 ms, written as CSV with the documented header."""
    c = tse2.TSE2Config(duration=2.0, dt=1e-2)
    s = tse2.setup(c)
    truth, log = tse2.simulate(s.system, s.g0, tse2.paper_input, s.ts, jax.random.key(4))
    p = tmp_path_factory.mktemp("log") / "log.csv"
    io.write_csv(p, io.log_header(2, 7), [log.ts, *np.asarray(log.us).T, *np.asarray(log.ys).T])
    return p, np.asarray(truth.coords())


def test_run_filters_a_recorded_csv_log(recorded_csv, tmp_path):
    log, truth = recorded_csv
    out = tmp_path / "est"
    res = invoke("run", "--system", "tse2", "--log", log, "--out", out, "--k0", 2.0)
    assert res.exit_code == 0, res.output
    for name in ("estimates.csv", "metrics.json", "arrays.npz", "estimate.png"):
        assert (out / name).is_file(), name
    header = (out / "estimates.csv").read_text().splitlines()[0]
    assert header == "t,theta,x,y,omega,vx,vy"
    est = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=1)
    assert est.shape == (201, 7)
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
