"""`liemef compare`: the paired statistics that name a winner, and each study at a tiny size."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from liemef import cli
from liemef.studies.compare import (
    HeadingBasin,
    LocalizationComparison,
    bootstrap_interval,
    paired_comparison,
    parse_filters,
)
from liemef.studies.compare._basins import convergence
from liemef.studies.compare._common import nees_cell, nees_flag, unranked_filters, winners_markdown


def test_the_paired_comparison_names_a_winner_only_when_its_lead_is_outside_the_spread():
    rng = np.random.default_rng(0)
    base = rng.normal(1.0, 0.5, 200)  # a trial-to-trial spread shared by the filters (same trials)
    values = {"a": base + 0.05 + 0.01 * rng.standard_normal(200),  # 0.05 behind, tiny paired noise: significant
              "b": base,
              "c": base + 0.3 * rng.standard_normal(200),  # level on average, noisy: not significant
              "d": np.where(np.arange(200) < 3, np.nan, base + 1.0)}  # three failed trials are left out
    r = paired_comparison(values)
    assert r["winner"] == "b"
    assert r["versus"]["a"]["significant"] and r["versus"]["a"]["ci"][0] > 0
    assert not r["versus"]["c"]["significant"] and r["versus"]["c"]["ci"][0] < 0 < r["versus"]["c"]["ci"][1]
    assert r["versus"]["d"]["n"] == 197 and r["versus"]["d"]["diff"] == pytest.approx(1.0)
    assert sorted(r["level"]) == ["b", "c"]
    assert math.isclose(r["means"]["b"], float(base.mean()))
    # a filter that failed where the others did not cannot win, however good its few healthy trials
    r = paired_comparison({"ok": np.array([1.0, 1.1, 0.9, 1.0, 1.2, 1.0]),
                           "fails": np.array([0.1, 0.1, np.nan, np.nan, np.nan, np.nan])})
    assert r["winner"] == "ok" and r["healthy"] == {"ok": 6, "fails": 2}
    # few trials: Student's t, not 1.96 (n = 3: t = 4.30)
    r = paired_comparison({"a": np.array([1.0, 2.0, 3.0]), "b": np.array([1.5, 2.4, 3.7])})
    d = np.array([0.5, 0.4, 0.7])
    assert r["versus"]["b"]["ci"][1] - r["versus"]["b"]["diff"] == pytest.approx(4.303 * d.std(ddof=1) / 3**0.5,
                                                                                  rel=1e-3)


def test_bootstrap_interval_covers_the_statistic_and_is_reproducible():
    x = np.random.default_rng(1).normal(2.0, 1.0, 100)
    lo, hi = bootstrap_interval(x, np.mean)
    assert lo < x.mean() < hi and hi - lo == pytest.approx(2 * 1.96 * x.std() / 10, rel=0.2)
    assert bootstrap_interval(x, np.mean) == [lo, hi]
    assert bootstrap_interval(x[:1], np.mean) == [None, None]


def test_bad_study_settings_are_named():
    with pytest.raises(ValueError, match="filters"):
        parse_filters("mef,kalman", ("mef",))
    with pytest.raises(ValueError, match="filters"):
        parse_filters("mef,mef", ("mef",))
    with pytest.raises(ValueError, match="optimum_runs"):
        LocalizationComparison(runs=2, optimum_runs=3)
    with pytest.raises(ValueError, match="runs"):
        LocalizationComparison(runs=0)
    with pytest.raises(ValueError, match="angles_deg"):
        HeadingBasin(angles_deg=(0.0, 200.0))
    with pytest.raises(ValueError, match="tolerance_deg"):
        HeadingBasin(tolerance_deg=0)
    res = CliRunner().invoke(cli.cli, ["compare", "localization", "--out", "/tmp/x", "--filters", "mef,nope"])
    assert res.exit_code == 2 and "filters" in res.output and "nope" in res.output
    res = CliRunner().invoke(cli.cli, ["compare", "heading-basin", "--out", "/tmp/x", "--set", "duration=true"])
    assert res.exit_code == 2 and "duration" in res.output
    res = CliRunner().invoke(cli.cli, ["compare", "heading-basin", "--out", "/tmp/x", "--set", "optimum_runs=1"])
    assert res.exit_code == 2 and "optimum_runs" in res.output and "angles_deg" in res.output


def test_convergence_is_staying_below_the_tolerance_to_the_end():
    ts = np.linspace(0.0, 10.0, 11)
    err = np.array([[9, 8, 4, 3, 6, 2, 1, 1, 1, 1, 1],  # converges at t = 5 (the last excursion is at t = 4)
                    [9, 1, 1, 1, 1, 1, 1, 1, 1, 7, 1],  # out again in the last quarter: does not converge
                    [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1],  # converged from the start
                    [9, 1, 1, 1, 1, 1, 1, 1, 1, 1, np.nan]], float)  # NaN at the end: not converged
    ok, t = convergence(ts, err, np.array([0, 0, 0, 0]), 5.0)
    assert ok.tolist() == [True, False, True, False]
    assert t[0] == 5.0 and t[2] == 0.0 and np.isnan(t[1]) and np.isnan(t[3])
    ok, _ = convergence(ts, err, np.array([0, 0, 1, 0]), 5.0)  # a failed run never converges
    assert not ok[2]


def test_a_basin_row_counts_the_trials_that_converge_the_same_way_in_every_basin_study():
    from liemef.metrics import wilson_interval
    from liemef.studies.compare._basins import basin_row, fraction_and_time, last_quarter, progress_line

    ts = np.linspace(0.0, 10.0, 11)
    assert last_quarter(ts).tolist() == [False] * 8 + [True] * 3  # t >= 7.5
    err = np.array([[9, 8, 4, 3, 6, 2, 1, 1, 1, 1, 1], [9, 1, 1, 1, 1, 1, 1, 1, 1, 7, 1],
                    [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], [9, 9, 9, 1, 1, 1, 1, 1, 1, 1, 1]], float)
    code = np.array([0, 0, 0, 2])  # the last trial's filter failed: not converged whatever its errors
    row = basin_row(90.0, *convergence(ts, err, code, 5.0), code)
    assert (row["converged"], row["trials"], row["failed"]) == (2, 4, 1) and row["fraction"] == 0.5
    assert row["wilson95"] == list(wilson_interval(2, 4))
    assert row["time_median_s"] == 2.5 and row["time_p90_s"] == pytest.approx(4.5)  # converged at 5 s and 0 s
    none = basin_row(179.0, *convergence(ts, 10 + err, np.zeros(4), 5.0), np.zeros(4))
    assert none["converged"] == 0 and none["time_median_s"] is None and none["wilson95"][0] == 0.0
    frac, times = fraction_and_time([row, none])
    assert frac == [0.5, 0.0] and times[0] == 2.5 and np.isnan(times[1])
    assert progress_line("mef", [row, none], 3.0) == "  mef        converged: 90 deg 2/4, 179 deg 0/4; 1 failed; 3.0 s"


def test_distribution_and_pooled_rms_of_per_trial_metrics():
    from liemef.studies.compare._common import distribution, pooled_rms

    x = np.array([1.0, np.nan, 3.0, 2.0])  # a failed trial is NaN and left out
    d = distribution(x)
    assert d["mean"] == 2.0 and d["p5"] == pytest.approx(1.1) and d["p95"] == pytest.approx(2.9)
    assert distribution(np.full(3, np.nan)) == {"mean": None, "p5": None, "p95": None}
    # per-trial rms over windows of one length pool to the rms over every trial and step
    series = np.random.default_rng(0).normal(size=(5, 40))
    per_trial = np.sqrt(np.mean(series**2, axis=1))
    assert pooled_rms(per_trial) == pytest.approx(np.sqrt(np.mean(series**2)), rel=1e-14)


@pytest.mark.parametrize("filters", [
    "iekf,ekf",
    pytest.param("mef,mef-first,mef-minus,mef-plus,iekf,ekf,ukf-left", marks=pytest.mark.slow),
])
def test_compare_localization_at_a_tiny_size(tmp_path, filters):
    out = tmp_path / "cmp"
    res = CliRunner().invoke(cli.cli, ["compare", "localization", "--runs", "3", "--set", "duration=4", "--set",
                                       "steady=2", "--filters", filters, "--set", "batch_size=3", "--out",
                                       str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert res.stderr.strip() == ""  # --no-progress is quiet (without it: test_a_piped_comparison_says_how_far...)
    for f in ("comparison.md", "comparison.csv", "comparison.json", "arrays.npz", "fig_errors.png"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "comparison.json").read_text())
    names = filters.split(",")
    assert list(meta["filters"]) == names
    for name, e in meta["filters"].items():
        assert e["runs"] == 3 and e["status_ok"] + e["diverged"]["count"] == 3
        assert e["heading_rms"]["p5"] <= e["heading_rms"]["mean"] <= e["heading_rms"]["p95"], name
    assert "published" not in meta["filters"]["iekf"]  # not the published 40 s scenario: no comparison
    arrays = np.load(out / "arrays.npz")
    assert arrays["heading_rms"].shape == (len(names), 3) and arrays["bands"].shape == (len(names), 3, 400, 2)
    # the table's means are the arrays' means
    for i, name in enumerate(names):
        assert meta["filters"][name]["heading_rms"]["mean"] == pytest.approx(np.nanmean(arrays["heading_rms"][i]))
    winner = meta["winners"]["heading rms t >= steady"]["winner"]
    assert winner == min(meta["filters"], key=lambda n: meta["filters"][n]["heading_rms"]["mean"])
    md = (out / "comparison.md").read_text()
    assert "| iekf |" in md and "## Winners" in md and "NaN" not in md
    assert "| filter | status ok | flips |" in md and "healthy" not in md
    for e in meta["filters"].values():
        assert e["nees_position"]["flag"] == nees_flag(e["nees_position"]["mean"], e["nees_position"]["chi2_bounds"])


def test_compare_heading_basin_at_a_tiny_size(tmp_path):
    out = tmp_path / "basin"
    res = CliRunner().invoke(cli.cli, ["compare", "heading-basin", "--runs", "4", "--set", "duration=4", "--set",
                                       "angles_deg=0,179", "--set", "tolerance_deg=30", "--filters", "iekf,ekf",
                                       "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    for f in ("basin.md", "basin.csv", "basin.json", "arrays.npz", "fig_basin.png"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "basin.json").read_text())
    rows = {name: e["angles"] for name, e in meta["filters"].items()}
    assert [r["angle_deg"] for r in rows["iekf"]] == [0.0, 179.0]
    # from the true heading every trial stays within 30 deg; from 179 deg, 4 fixes in 4 s do not turn it round
    for name in ("iekf", "ekf"):
        assert rows[name][0]["converged"] == 4 and rows[name][0]["time_median_s"] == 0.0
        assert rows[name][1]["converged"] == 0 and rows[name][1]["time_median_s"] is None
    arrays = np.load(out / "arrays.npz")
    assert arrays["fraction"].shape == (2, 2) and arrays["fraction"][0, 0] == 1.0


def test_compare_broad_at_a_tiny_size(tmp_path):
    from liemef.studies import datasets

    folder = datasets.realdata_dir()
    if folder is None or "07" not in datasets.broad_trials():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    out = tmp_path / "broad"
    tuned = {"format": "liemef-tune-1", "system": "attitude-imu", "params": {"acc_std": 0.05}, "integrator": "rkmk2",
             "folds": {"07": {"params": {"acc_std": 0.04, "mag_adapt": 2.0}}}}
    (tmp_path / "tune.json").write_text(json.dumps(tuned))
    res = CliRunner().invoke(cli.cli, ["compare", "broad", "--set", "trials=07", "--set", "seconds=32",
                                       "--set", f"params={tmp_path / 'tune.json'}",
                                       "--filters", "iekf,madgwick,mahony-broad,mef-imu,vqf,vqf-broad", "--out",
                                       str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    for f in ("broad.md", "broad.csv", "broad.json", "arrays.npz", "fig_errors_07.png"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "broad.json").read_text())
    rows = meta["trials"]["07"]["filters"]
    assert list(rows) == ["iekf", "madgwick", "mahony-broad", "mef-imu", "vqf", "vqf-broad"]
    assert meta["trials"]["07"]["imu_params"] == {"acc_std": 0.04, "mag_adapt": 2.0}   # the fold without 07
    assert "tuned with integrator='rkmk2', and this study's filters run RKMK4" in meta["study"]["imu_params"]
    assert meta["ratio_to_vqf"]["vqf"] == 1.0
    assert meta["lags"]["vqf"] == meta["lags"]["madgwick"] == {"gyro": 0, "acc": 0, "mag": 0}  # sample k at t_k
    assert meta["lags"]["iekf"] == {"gyro": 1, "acc": 1, "mag": 1}
    assert "| iekf | 1 / 1 / 1 |" in (out / "broad.md").read_text()
    for name, r in rows.items():  # 5 s of motion after 26.5 s of rest, from a TRIAD start: a few degrees
        assert r["ok"] and 0.0 < r["inclination"] <= r["total"] < 15.0, (name, r)
    assert meta["trials"]["07"]["published"] is None  # a head of the trial is not the published run
    # the dip and the norms come from the rest found in the IMU samples (26.4 s), not from BROAD's annotation
    assert 25.9 < meta["trials"]["07"]["rest_s"] < 26.5 and "detected from the IMU (initial_rest: 07 26.4 s)" \
        in meta["study"]["measured"]
    given = meta["study"]["given"]
    assert given["vqf"] == [] and given["madgwick"] == ["initial attitude (TRIAD at rest)"]
    assert given["mef-imu"] == ["initial attitude (TRIAD at rest)", "dip", "gravity", "field", "K0"]
    assert given["iekf"] == ["initial attitude (TRIAD at rest)", "dip", "K0"]
    md = (out / "broad.md").read_text()
    assert "vqf: none (its defaults on the raw readings)" in md and "detected from the IMU" in md
    w = meta["winners"]["07"]["total"]
    assert w["value"] == min(r["total"] for r in rows.values())
    # 5 s of fast rotation: the magnetometer's median within a few degrees of the truth, its tail far beyond
    field = meta["trials"]["07"]["field_vs_truth"]
    assert abs(field["azimuth"]) < 5.0 and abs(field["dip"]) < 5.0 and field["azimuth_p90"] > abs(field["azimuth"])
    assert "## The magnetometer against the optical truth" in md and f"| 07 | {field['azimuth']:.4g} |" in md
    res = CliRunner().invoke(cli.cli, ["compare", "broad", "--runs", "3", "--out", str(out)])
    assert res.exit_code == 2 and "runs" in res.output
    res = CliRunner().invoke(cli.cli, ["compare", "broad", "--set", "trials=99", "--out", str(out)])
    assert res.exit_code == 2 and "trials" in res.output and "99" in res.output


def test_the_broad_figure_is_small_multiples_of_the_chosen_filters():
    """One panel per filter run, each in its own colour, titled with its name and total rms; the best filter in
    grey on every other panel; one shared y axis (deg) on a log scale; no legend over the data."""
    from matplotlib.colors import to_rgba

    from liemef.reports.figures import broad_error_figure

    names = [f"f{i}" for i in range(13)]
    rng = np.random.default_rng(0)
    arrays = {}
    for i, n in enumerate(names):
        arrays[f"07/{n}/error_1s"] = np.concatenate([np.full(5, np.nan), 1.0 + i + rng.random(30)])
        arrays[f"07/{n}"] = np.array([np.nan if i == 4 else 1.0 + i + 0.5, 1.0, 1.0])  # f4 failed
    arrays["07/f0"][0] = 9.0  # the best is f1
    arrays["07/other/error_1s"] = np.ones(35)  # a filter not chosen: not drawn
    fig = broad_error_figure(arrays, "07", names, "BROAD trial 07")
    axes = fig.axes
    assert len(axes) == 13 and fig.get_suptitle() == "BROAD trial 07\nin grey on every other panel: f1, the lowest " \
                                                      "total rms"
    grey = to_rgba("0.65")
    colours = []
    for ax, n in zip(axes, names, strict=True):
        assert ax.get_legend() is None and ax.get_yscale() == "log"
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        assert set(lines) == ({n} if n == "f1" else {n, "f1 (reference)"})
        np.testing.assert_array_equal(lines[n].get_ydata(), arrays[f"07/{n}/error_1s"])
        assert lines[n].get_xdata()[0] == 0
        if n != "f1":
            assert to_rgba(lines["f1 (reference)"].get_color()) == grey
            np.testing.assert_array_equal(lines["f1 (reference)"].get_ydata(), arrays["07/f1/error_1s"])
        colours.append(to_rgba(lines[n].get_color()))
        assert ax.get_title().startswith(f"{n}: ")
    assert len(set(colours)) == 13 and grey not in colours
    assert axes[4].get_title() == "f4: failed" and axes[1].get_title() == "f1: 2.5 deg total rms (lowest)"
    assert all(ax.get_shared_y_axes().joined(axes[0], ax) for ax in axes)  # one unit, one scale
    assert fig.legends == []
    assert all(ax.xaxis.get_tick_params()["labelbottom"] for ax in axes[-4:])  # under every column, the time


def test_wilson_interval_of_a_fraction():
    from liemef.metrics import wilson_interval

    assert wilson_interval(0, 50)[0] == 0.0 and wilson_interval(50, 50)[1] == 1.0
    lo, hi = wilson_interval(25, 50)
    assert lo == pytest.approx(0.366, abs=1e-3) and hi == pytest.approx(0.634, abs=1e-3)  # the textbook value
    assert wilson_interval(0, 0) == (None, None)


def test_compare_wifibot_at_a_tiny_size(tmp_path):
    from liemef.studies import datasets

    folder = datasets.realdata_dir()
    if folder is None or "4" not in datasets.wifibot_runs():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    out = tmp_path / "wifibot"
    res = CliRunner().invoke(cli.cli, ["compare", "wifibot", "--runs", "3", "--set", "recordings=4", "--filters",
                                       "iekf,ekf", "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "wifibot.json").read_text())
    rec = meta["recordings"]["4"]
    for name, e in rec["filters"].items():  # the straight run: GPS of 0.1 m keeps the position within ~0.1 m
        assert e["status_ok"] == 3 and 0.02 < e["position_rms"]["mean"] < 0.2 and e["heading_rms"]["mean"] < 5, name
    arrays = np.load(out / "arrays.npz")
    assert arrays["4/iekf/heading_rms"].shape == (3,)
    assert arrays["4/iekf/bands"].shape == (3, arrays["4/ts"].shape[0], 2)
    assert (out / "fig_errors_4.png").stat().st_size > 0
    assert rec["winners"]["heading rms"]["winner"] in ("iekf", "ekf")
    res = CliRunner().invoke(cli.cli, ["compare", "wifibot", "--set", "recordings=9", "--out", str(out)])
    assert res.exit_code == 2 and "recordings" in res.output


@pytest.mark.parametrize("filters", ["iekf", pytest.param("iekf,mef-first", marks=pytest.mark.slow)])
def test_compare_attitude_basin_at_a_tiny_size(tmp_path, filters):
    out = tmp_path / "attbasin"
    res = CliRunner().invoke(cli.cli, ["compare", "attitude-basin", "--runs", "3", "--set", "angles_deg=0,179",
                                       "--set", "duration=1", "--set", "imu_rate=50", "--set", "systems=gyro-bias",
                                       "--set", "tolerance_deg=10", "--filters", filters, "--out",
                                       str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    for f in ("attitude_basin.md", "attitude_basin.csv", "attitude_basin.json", "arrays.npz",
              "fig_basin_gyro_bias.png"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "attitude_basin.json").read_text())
    assert list(meta["systems"]) == ["gyro-bias"] and meta["systems"]["gyro-bias"]["samples"] == 51
    rows = {name: e["angles"] for name, e in meta["systems"]["gyro-bias"]["filters"].items()}
    assert list(rows) == filters.split(",")
    for name, r in rows.items():
        assert [x["angle_deg"] for x in r] == [0.0, 179.0]
        assert r[0]["converged"] == 3 and r[0]["failed"] == 0 and r[0]["time_median_s"] == 0.0, name
        for x in r:  # the fields agree with each other
            assert x["trials"] == 3 and x["fraction"] == x["converged"] / 3
            assert x["wilson95"][0] <= x["fraction"] <= x["wilson95"][1]
            assert (x["time_median_s"] is None) == (x["converged"] == 0)
    arrays = np.load(out / "arrays.npz")
    assert arrays["gyro_bias_fraction"].shape == (len(rows), 2) and np.all(arrays["gyro_bias_fraction"][:, 0] == 1.0)
    assert list(arrays["gyro_bias_filters"]) == filters.split(",")
    csv = (out / "attitude_basin.csv").read_text().splitlines()
    assert csv[0].startswith("system,filter,angle_deg") and len(csv) == 1 + 2 * len(rows)
    assert "None" not in "".join(csv)  # no value is an empty cell
    md = (out / "attitude_basin.md").read_text()
    assert "| iekf |" in md and "NEES per degree of freedom" in md
    for name, r in rows.items():  # a consistent-ish covariance from the true start: NEES per dof of order 1
        assert r[0]["nees_per_dof"] is not None and 0.05 < r[0]["nees_per_dof"] < 20, (name, r[0])


def test_bad_attitude_basin_settings_are_named():
    from liemef.studies.compare import AttitudeBasin

    assert AttitudeBasin(filters="iekf,mahony").filters_of("rigid-body") == ("iekf",)  # ahrs: gyro bias only
    assert AttitudeBasin(filters="iekf,mahony").filters_of("gyro-bias") == ("iekf", "mahony")
    with pytest.raises(ValueError, match="optimum_runs"):
        AttitudeBasin(runs=2, optimum_runs=3)
    with pytest.raises(ValueError, match="filters"):
        AttitudeBasin(filters="ekf")  # the local EKF is the invariant one on TSO(3)
    for setting, name in (("angles_deg=0,200", "angles_deg"), ("systems=rigid-body,nope", "systems"),
                          ("tolerance_deg=0", "tolerance_deg")):
        res = CliRunner().invoke(cli.cli, ["compare", "attitude-basin", "--out", "/tmp/x", "--set", setting])
        assert res.exit_code == 2 and name in res.output, (setting, res.output)


@pytest.mark.slow
def test_attitude_basin_distance_to_the_optimum(tmp_path):
    from liemef.studies.compare import AttitudeBasin, compare_attitude_basin

    r = compare_attitude_basin(AttitudeBasin(runs=2, systems="gyro-bias", angles_deg=(0.0,), duration=2.0,
                                             imu_rate=50.0, filters="iekf,mef", optimum_runs=1, optimum_every=20),
                               progress=False)
    rows = {n: e["angles"][0] for n, e in r["systems"]["gyro-bias"]["filters"].items()}
    for name, row in rows.items():  # from the true start, both stay within a degree of the exact estimate
        assert 0.0 <= row["optimum_deg_final"] < 1.0 and 0.0 <= row["optimum_deg_mean"] < 2.0, (name, row)
    # the discrete invariant EKF is the Kalman filter of the very cost the MAP minimizes: the closer one
    assert rows["iekf"]["optimum_deg_final"] < rows["mef"]["optimum_deg_final"]


def test_a_nees_far_outside_its_bounds_is_flagged():
    """'status ok' counts the trials run through; the NEES flag says whether K described the error: mef-minus on
    localization ran 5 of 5 trials at a position NEES of 1e6 (far above bounds of about 0.5-1.7)."""

    bounds = (0.5, 1.7)
    assert [nees_flag(v, bounds) for v in (1.0, 1.8, 17.1, 0.4, 0.04, None, float("nan"))] == [
        "within", "above", "far above", "below", "far below", None, None]
    assert nees_cell(1e6, bounds) == "1e+06 (far above!)" and nees_cell(1.8, bounds) == "1.8"


def test_a_filter_that_failed_or_whose_k_is_far_off_is_not_ranked():
    entries = {"good": {"status_ok": 6, "runs": 6, "nees": {"mean": 1.1, "flag": "within"}},
               "failed": {"status_ok": 5, "runs": 6, "nees": {"mean": 1.0, "flag": "within"}},
               "overconfident": {"status_ok": 6, "runs": 6, "nees": {"mean": 812.0, "flag": "far above"}},
               "timid": {"status_ok": 6, "runs": 6, "nees": {"mean": 0.001, "flag": "far below"}},
               "above": {"status_ok": 6, "runs": 6, "nees": {"mean": 2.5, "flag": "above"}}}
    unranked = unranked_filters(entries, ["nees"])
    assert unranked == {"failed": "failed on 1 of 6 trials", "overconfident": "nees 812 far above its band",
                        "timid": "nees 0.001 far below its band"}
    rng = np.random.default_rng(1)
    base = rng.normal(1.0, 0.1, 6)
    values = {"good": base + 0.5, "failed": base - 0.5, "overconfident": base - 0.4, "timid": base - 0.3,
              "above": base + 0.2}
    r = paired_comparison(values, unranked=unranked)
    assert r["winner"] == "above" and r["unranked"] == unranked
    assert r["versus"]["overconfident"]["diff"] == pytest.approx(-0.6)  # still compared, just not ranked
    assert "overconfident" not in r["level"] and "timid" not in r["level"]
    assert paired_comparison(values)["winner"] == "failed"
    none = paired_comparison({"a": base}, unranked={"a": "failed on 6 of 6 trials"})
    assert none["winner"] is None and none["unranked"] == {"a": "failed on 6 of 6 trials"}
    lines = winners_markdown({"heading rms": r}, {"heading rms": "deg"})
    assert "| heading rms | above |" in lines[2]
    assert lines[-1].startswith("Not ranked") and "overconfident: nees 812 far above its band" in lines[-1]


def _ignores_the_gps(system):
    """A filter built to ignore the GPS while trusting its odometry 100 times more than it should (10 times
    smaller stds): its K claims a precision its error does not have."""
    import equinox as eqx

    from liemef.filters.baselines import invariant_ekf
    from liemef.systems import Noise

    noise = system.process_noise
    overconfident = eqx.tree_at(lambda n: n.std, noise, noise.std * 0.1)
    return invariant_ekf(system.with_noise(gps=Noise.sample(1e6), process_noise=overconfident))


def test_a_filter_built_to_ignore_a_sensor_cannot_win_the_localization_comparison(tmp_path, monkeypatch):
    from liemef.studies.compare import _common

    monkeypatch.setitem(_common.FILTERS, "ignores-gps", ("ignores the GPS, trusts its odometry", _ignores_the_gps))
    out = tmp_path / "cmp"
    res = CliRunner().invoke(cli.cli, ["compare", "localization", "--runs", "3", "--set", "duration=4", "--set",
                                       "steady=2", "--filters", "iekf,ignores-gps", "--set", "batch_size=3",
                                       "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "comparison.json").read_text())
    assert meta["filters"]["ignores-gps"]["nees_position"]["flag"] == "far above"
    for metric, w in meta["winners"].items():
        assert w["winner"] == "iekf", metric
        assert "far above its band" in w["unranked"]["ignores-gps"]
    md = (out / "comparison.md").read_text()
    assert "Not ranked" in md and "ignores-gps: " in md


def test_a_piped_comparison_says_how_far_it_is_on_stderr(tmp_path):
    """Piped (stderr not a terminal), `liemef compare` still prints a line per filter on stderr, and nothing of
    it on stdout. The study of test_compare_localization_at_a_tiny_size[iekf,ekf] (3 trials in one batch: its
    compiled programs serve), whose run with --no-progress checks that that is quiet."""
    args = ["compare", "localization", "--runs", "3", "--set", "duration=4", "--set", "steady=2", "--filters",
            "iekf,ekf", "--set", "batch_size=3"]
    res = CliRunner().invoke(cli.cli, [*args, "--out", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    lines = [line for line in res.stderr.splitlines() if line.strip().startswith(("iekf", "ekf"))]
    assert [line.split()[0] for line in lines] == ["iekf", "ekf"] and "heading" in lines[0]
    assert not any(line.strip().startswith(("iekf ", "ekf ")) for line in res.stdout.splitlines())
    assert "Wrote" in res.stdout


def test_a_broad_slice_with_nothing_scored_says_so_and_is_not_usable(tmp_path):
    """A slice that ends before BROAD's movement starts scores nothing: the report names the trial and when the
    movement starts, and with no scored trial the comparison is not usable (exit 1), however ok its runs; run
    past the movement's start, the same trial is scored and nothing is said."""
    from test_cli_run import broad_mat

    (tmp_path / "broad").mkdir()
    broad_mat(tmp_path / "broad" / "01_synthetic.mat", rest_s=2.0, seconds=5.0)  # movement from 3.0 s
    out = tmp_path / "short"
    res = CliRunner().invoke(cli.cli, ["compare", "broad", "--set", f"realdata={tmp_path}", "--set", "seconds=2.5",
                                       "--filters", "vqf", "--out", str(out), "--no-progress"])
    assert res.exit_code == 1, res.output
    why = "trial 01: no sample is scored (its 2.5 s end before BROAD's movement starts at 3.0 s)"
    assert f"WARNING: {why}" in res.output and "no usable trial" in res.output
    meta = json.loads((out / "broad.json").read_text())["trials"]["01"]
    assert meta["filters"]["vqf"]["ok"] and meta["filters"]["vqf"]["total"] is None
    assert (meta["scored_samples"], meta["movement_s"]) == (0, 3.0)
    assert f"**Not scored.** {why}" in (out / "broad.md").read_text()
    res = CliRunner().invoke(cli.cli, ["compare", "broad", "--set", f"realdata={tmp_path}", "--filters", "vqf",
                                       "--out", str(tmp_path / "whole"), "--no-progress"])
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "whole" / "broad.json").read_text())["trials"]["01"]
    assert meta["scored_samples"] == 200 and meta["filters"]["vqf"]["total"] > 0
    assert "no sample is scored" not in res.output and "Not scored" not in (tmp_path / "whole" / "broad.md").read_text()


def test_an_inertial_trial_with_nothing_scored_counts_as_unusable():
    """compare broad-ins' trials carry the same count: a trial with no scored sample makes each of its runs
    unusable in :func:`failures`, and its report names it; a scored one is left alone."""
    from liemef.studies.compare import failures
    from liemef.studies.compare._common import unscored_lines

    row = {"ok": True, "status": "ok"}
    result = {"per_trial": {
        "10": {"scored_samples": 0, "ends_s": 20.0, "movement_s": 36.6,
               "variants": {"recorded": {"filters": {"mef": row, "iekf-right": row}}}},
        "16": {"scored_samples": 900, "ends_s": 50.0, "movement_s": 35.0,
               "variants": {"recorded": {"filters": {"mef": row, "iekf-right": row}}}}}}
    lines, failed, total = failures(result)
    assert (failed, total) == (2, 4)
    assert lines == ["trial 10: no sample is scored (its 20.0 s end before BROAD's movement starts at 36.6 s); "
                     "its figures are '-'"]
    assert unscored_lines(result["per_trial"])[0].startswith(f"**Not scored.** {lines[0]}.")
    result["per_trial"]["10"]["movement_s"] = 5.0  # moving, but the optical truth is absent there
    assert "no sample of it where the optical truth is present" in failures(result)[0][0]
