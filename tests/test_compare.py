"""`liemef compare`: the paired statistics that name a winner, and each study at a tiny size."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from liemef import cli
from liemef.compare import LocalizationComparison, bootstrap_interval, paired_comparison, parse_filters


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
    res = CliRunner().invoke(cli.cli, ["compare", "localization", "--out", "/tmp/x", "--filters", "mef,nope"])
    assert res.exit_code == 2 and "filters" in res.output and "nope" in res.output


def test_compare_localization_at_a_tiny_size(tmp_path):
    out = tmp_path / "cmp"
    res = CliRunner().invoke(cli.cli, ["compare", "localization", "--runs", "3", "--duration", "4", "--steady", "2",
                                       "--filters", "mef,iekf,ekf", "--batch-size", "3", "--out", str(out),
                                       "--no-progress"])
    assert res.exit_code == 0, res.output
    for f in ("comparison.md", "comparison.csv", "comparison.json", "arrays.npz", "fig_errors.png"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "comparison.json").read_text())
    assert list(meta["filters"]) == ["mef", "iekf", "ekf"]
    for name, e in meta["filters"].items():
        assert e["runs"] == 3 and e["healthy"] + e["diverged"]["count"] == 3
        assert e["heading_rms"]["p5"] <= e["heading_rms"]["mean"] <= e["heading_rms"]["p95"], name
    assert meta["filters"]["iekf"]["published"]["which"] == "iekf"
    arrays = np.load(out / "arrays.npz")
    assert arrays["heading_rms"].shape == (3, 3) and arrays["bands"].shape == (3, 3, 400, 2)
    # the table's means are the arrays' means
    for i, name in enumerate(["mef", "iekf", "ekf"]):
        assert meta["filters"][name]["heading_rms"]["mean"] == pytest.approx(np.nanmean(arrays["heading_rms"][i]))
    winner = meta["winners"]["heading rms t >= steady"]["winner"]
    assert winner == min(meta["filters"], key=lambda n: meta["filters"][n]["heading_rms"]["mean"])
    md = (out / "comparison.md").read_text()
    assert "| iekf |" in md and "## Winners" in md and "NaN" not in md
