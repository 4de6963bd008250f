"""`liemef smooth`: the filter's pass, then the smoother over the whole log, written as `liemef run` writes a run;
its status in metrics.json and in the exit status; bad options refused by name before anything is written."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from liemef.cli import EXIT_NOT_CONVERGED, cli
from test_cli_run import gated_localization, localization_log


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same log with a 1e4 m GPS outlier, a gated system file, run and smoothed."""
    d = tmp_path_factory.mktemp("smooth")
    _, p, _ = gated_localization(d)
    common = ("--system-file", d / "my_system.py", "--log", d / "log.csv", "--no-progress")
    run = invoke("run", *common, "--out", d / "run")
    smooth = invoke("smooth", *common, "--out", d / "smooth")
    return d, run, smooth, p


def test_smooth_writes_a_run_of_the_smoothers_estimates(runs):
    d, run, smooth, p = runs
    assert run.exit_code == 0, run.output
    assert smooth.exit_code == 0, smooth.output
    assert "Smoothed: converged in" in smooth.output
    assert "Residual y - h(g_smoothed)" in smooth.output
    for name in ("estimates.csv", "innovations.csv", "metrics.json", "arrays.npz", "estimate.png"):
        assert (d / "smooth" / name).is_file(), name
    header = (d / "smooth" / "estimates.csv").read_text().splitlines()[0]
    assert header == "t,theta,x,y,K_e0e0,K_e1e1,K_e2e2"
    filt = np.loadtxt(d / "run" / "estimates.csv", delimiter=",", skiprows=1)
    smo = np.loadtxt(d / "smooth" / "estimates.csv", delimiter=",", skiprows=1)
    assert np.isfinite(smo).all()
    err_f = np.linalg.norm(filt[:, 2:4] - p, axis=1)
    err_s = np.linalg.norm(smo[:, 2:4] - p, axis=1)
    print(f"position error: filter {err_f.mean():.3f} m, smoother {err_s.mean():.3f} m")
    assert err_s.max() < 1.0  # the gate's truncated loss ignored the 1e4 m outlier
    assert err_s.mean() < err_f.mean()
    # a state's position variance from all the samples is below the filter's from those before it, except near
    # the log's end, where the two have seen the same samples (there they differ by the discretizations)
    assert np.all(smo[100:-100, 5:] < filt[100:-100, 5:])
    metrics = json.loads((d / "smooth" / "metrics.json").read_text())
    sm = metrics["smoother"]
    assert sm["status"] == "converged" and sm["cost"] <= sm["cost_init"] and sm["options"]["max_iterations"] == 200
    assert "smoother's estimate" in metrics["innovation"]["definition"]
    assert metrics["innovations"] == json.loads((d / "run" / "metrics.json").read_text())["innovations"]
    manifest = json.loads((d / "smooth" / "manifest.json").read_text())
    assert manifest["command"] == "smooth"


def test_smooth_in_chunks_writes_the_same_files_and_says_how_it_cut_the_log(runs):
    """--smooth-chunk: windows of 200 states with 320 samples of overlap on each side (of the 1000 of a log with
    a fix a second; every window, the first and last too, in the whole log's length bucket, so that no other
    program is compiled) write the files of the whole-log smoother; their estimates leave out the fixes beyond each
    window, so they are not the whole log's, but they are nearer the truth than the filter's. metrics.json
    records the options and the windows."""
    d, _, _, p = runs
    res = invoke("smooth", "--system-file", d / "my_system.py", "--log", d / "log.csv", "--no-progress",
                 "--smooth-chunk", 200, "--smooth-overlap", 320, "--out", d / "chunks")
    assert res.exit_code == 0, res.output
    err = {name: np.linalg.norm(np.loadtxt(d / name / "estimates.csv", delimiter=",", skiprows=1)[:, 2:4] - p,
                                axis=1).mean() for name in ("run", "smooth", "chunks")}
    print("mean position error (m):", err)
    assert err["chunks"] < err["run"]
    sm = json.loads((d / "chunks" / "metrics.json").read_text())["smoother"]
    assert sm["status"] == "converged" and sm["options"]["chunk"] == 200 and sm["options"]["overlap"] == 320
    assert "5 windows of 200 states with overlaps 320 before and 320 after" in sm["message"]
    whole = json.loads((d / "smooth" / "metrics.json").read_text())["smoother"]  # the whole log's minimizer
    assert whole["cost"] < sm["cost"] < sm["cost_init"] == pytest.approx(whole["cost_init"], rel=1e-9)


def test_a_smoother_that_does_not_converge_says_so_and_exits_5(tmp_path):
    localization_log(tmp_path / "log.csv", N=300)
    res = invoke("smooth", "--system", "localization", "--log", tmp_path / "log.csv", "--out",
                 tmp_path / "o", "--max-iterations", 1, "--no-progress")
    assert res.exit_code == EXIT_NOT_CONVERGED, res.output
    assert "WARNING: the smoother not converged" in res.output
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["smoother"]["status"] == "max-iterations"
    assert np.isfinite(np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)).all()


@pytest.mark.parametrize("args, words", [(("--max-iterations", 0), "--max-iterations"),
                                         (("--tol", -1.0), "--tol"), (("--tol", 0.0), "tol: expected a finite "
                                                                                     "number > 0, got 0.0"),
                                         (("--gap", 0.0), "'--gap': expected a finite number > 0 (s), got 0.0"),
                                         (("--alpha", "nan"), "'--alpha': expected a finite number >= 0, got nan"),
                                         (("--k0-diag", "1,-2,1"), "'--k0-diag': expected finite numbers >= 0"),
                                         (("--smooth-chunk", 0), "--smooth-chunk"),
                                         (("--smooth-overlap", 3), "'--smooth-overlap': only with --smooth-chunk")])
def test_bad_smoother_options_are_refused_by_name(tmp_path, args, words):
    localization_log(tmp_path / "log.csv", N=200)
    res = CliRunner().invoke(cli, ["smooth", "--system", "localization", "--log", str(tmp_path / "log.csv"),
                                   "--out", str(tmp_path / "o"), *map(str, args)])
    assert res.exit_code == 2, res.output
    assert words in res.output
    assert not (tmp_path / "o").exists()


def test_a_failed_smoother_makes_the_run_a_failure(tmp_path, monkeypatch):
    """Where the smoother fails (its status "failed"), the run is a failure: failure.json alone, its cause the
    smoother, and exit status 1; nothing is written as if it had worked."""
    import liemef.smoothers

    real = liemef.smoothers.smooth

    def failing(*args, **kwargs):
        sm = real(*args, **{**kwargs, "max_iterations": 1})
        return type(sm)(ts=sm.ts, g=sm.g, P=sm.P * np.nan, cost=sm.cost, cost_init=sm.cost_init,
                        gradient_norm=sm.gradient_norm, iterations=sm.iterations, status="failed",
                        message="failed after 1 iteration(s): a test's failure")

    monkeypatch.setattr(liemef.smoothers, "smooth", failing)
    localization_log(tmp_path / "log.csv", N=200)
    res = invoke("smooth", "--system", "localization", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--no-progress")
    assert res.exit_code == 1, res.output
    assert "a test's failure" in res.output
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["failure.json"]
    failure = json.loads((tmp_path / "o" / "failure.json").read_text())
    assert failure["status"]["cause"] == "smoother" and failure["command"] == "smooth"
