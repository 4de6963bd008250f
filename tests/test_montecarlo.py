"""The Monte Carlo engine: vmap batches equal single runs, chunking does not change a trial, non-finite trials
are flagged and left out, statistics across trials match numpy, results survive a save/load round trip."""

import io as stdio
import json
import math
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef.filters import Status
from liemef.metrics import FULL, Window, error_stats
from liemef.studies.experiments import (
    PERCENTILES,
    STATS,
    Experiment,
    MonteCarloResult,
    ProgressLine,
    TrialSpec,
    get_experiment,
    montecarlo,
    trial_cause,
    trial_keys,
    tse2,
)
from tolerances import ROUNDOFF


# --- a toy experiment: Gaussian errors, a fraction of trials with a NaN at the last sample -------------------
@dataclass(frozen=True)
class ToyConfig:
    seed: int = 0
    samples: int = 11
    nan_fraction: float = 0.0


def toy_errors(config: ToyConfig, key):
    k1, k2 = jax.random.split(key)
    e = 1.0 + jax.random.normal(k1, (config.samples, 2)) * jnp.array([1.0, 0.1])
    bad = jax.random.uniform(k2) < config.nan_fraction
    return e.at[-1, 0].set(jnp.where(bad, jnp.nan, e[-1, 0]))


def toy_trial(config: ToyConfig) -> TrialSpec:
    ts = np.linspace(0.0, 1.0, config.samples)
    return TrialSpec(ts=ts, names=("a", "b"), units=("m", "rad"), windows=(FULL, Window(0.0, 0.5)),
                     errors=lambda key: toy_errors(config, key))


def _no_run(config, key=None):
    raise NotImplementedError


TOY = Experiment(name="toy", title="Toy", paper="none", default_config=ToyConfig(), run_fn=_no_run,
                 trial_fn=toy_trial)


def sequential_stats(config: ToyConfig, seed: int, runs: int) -> np.ndarray:
    """Per-trial statistics computed one trial at a time, in numpy, from the same keys."""
    spec = toy_trial(config)
    out = []
    for key in trial_keys(seed, runs):
        e = np.asarray(toy_errors(config, key))
        out.append([[np.asarray(error_stats(spec.ts, e, w)[k]) for k in STATS] for w in spec.windows])
    return np.moveaxis(np.array(out), 2, 3)  # (runs, windows, stats, c) -> (runs, windows, c, stats)


# --- vmap batches against single runs ----------------------------------------------------------------------
def test_vmapped_batches_equal_sequential_single_runs_of_tse2():
    exp = get_experiment("tse2")
    config = exp.config(duration=12.0)  # the length test_cli.py uses: one compilation when run together
    mc = montecarlo(exp, config, runs=4, seed=0, batch_size=2, progress=False)
    assert mc.stats.shape == (4, 2, 6, 3) and mc.finite.all() and mc.counts == (12001, 2001)
    assert mc.names == ("theta", "x", "y", "omega", "vx", "vy") and mc.window_labels == ("full", "10-50s")
    for i, key in enumerate(trial_keys(0, 4)):
        table = tse2.run(config, key).table  # the checked single-run path of `liemef reproduce`
        for k, stat in enumerate(STATS):
            np.testing.assert_allclose(mc.stats[i, :, :, k], getattr(table, stat), rtol=0, atol=ROUNDOFF)


def test_toy_batches_equal_numpy_per_trial_statistics():
    c = ToyConfig(samples=21)
    mc = montecarlo(TOY, c, runs=6, seed=3, batch_size=4, progress=False)
    np.testing.assert_allclose(mc.stats, sequential_stats(c, 3, 6), rtol=ROUNDOFF, atol=ROUNDOFF)
    assert mc.counts == (21, 11) and mc.seed == 3 and mc.config == {"seed": 0, "samples": 21, "nan_fraction": 0.0}


@pytest.mark.parametrize("batch_size", [1, 3, 7, 50])
def test_a_trial_does_not_depend_on_the_batch_size(batch_size):
    reference = montecarlo(TOY, ToyConfig(), runs=7, seed=11, batch_size=2, progress=False)
    mc = montecarlo(TOY, ToyConfig(), runs=7, seed=11, batch_size=batch_size, progress=False)
    np.testing.assert_array_equal(mc.stats, reference.stats)
    np.testing.assert_array_equal(mc.keys, reference.keys)
    assert mc.batch_size == min(batch_size, 7)
    other = montecarlo(TOY, ToyConfig(), runs=7, seed=12, batch_size=batch_size, progress=False)
    assert not np.allclose(other.stats, reference.stats)


def test_trial_keys_are_split_from_the_seed():
    mc = montecarlo(TOY, ToyConfig(), runs=5, seed=4, batch_size=2, progress=False)
    np.testing.assert_array_equal(mc.keys, jax.random.key_data(jax.random.split(jax.random.key(4), 5)))
    e = toy_errors(ToyConfig(), mc.trial_key(3))
    assert float(error_stats(np.linspace(0, 1, 11), e)["rms"][1]) == pytest.approx(mc.stats[3, 0, 1, 2], rel=1e-14)


# --- non-finite trials --------------------------------------------------------------------------------------
def test_nonfinite_trials_are_flagged_and_left_out_of_the_statistics():
    c = ToyConfig(nan_fraction=0.3)
    runs = 40
    mc = montecarlo(TOY, c, runs=runs, seed=0, batch_size=16, progress=False)
    expected_bad = [i for i, k in enumerate(trial_keys(0, runs)) if not np.isfinite(toy_errors(c, k)).all()]
    assert 3 <= len(expected_bad) <= 25  # the fixture does produce both kinds
    assert list(mc.nonfinite_trials) == expected_bad and mc.n_nonfinite == len(expected_bad)
    assert mc.n_finite == runs - len(expected_bad)
    # the NaN is at the last sample: its trial's full-window stats are NaN, the 0-0.5 s window's are not
    assert np.isnan(mc.stats[expected_bad, 0, 0]).all() and np.isfinite(mc.stats[expected_bad, 1]).all()
    good = np.setdiff1d(np.arange(runs), expected_bad)
    np.testing.assert_allclose(mc.mean, mc.stats[good].mean(axis=0), rtol=ROUNDOFF)
    np.testing.assert_allclose(mc.spread, mc.stats[good].std(axis=0, ddof=1), rtol=ROUNDOFF)
    # the window the NaN does not reach still leaves the flagged trials out
    np.testing.assert_allclose(mc.percentiles[:, 1], np.percentile(mc.stats[good, 1], PERCENTILES, axis=0),
                               rtol=ROUNDOFF)
    assert np.isfinite(mc.mean).all() and np.isfinite(mc.percentiles).all()
    assert f"{len(expected_bad)} non-finite (left out: trials {expected_bad[0]}" in mc.format()


def test_all_trials_nonfinite_gives_nan_statistics_without_warnings():
    mc = montecarlo(TOY, ToyConfig(nan_fraction=2.0), runs=3, batch_size=3, progress=False)
    assert mc.n_nonfinite == 3
    assert np.isnan(mc.mean).all() and np.isnan(mc.spread).all() and np.isnan(mc.percentiles).all()
    assert math.isnan(mc.percentile_of(1.0, "a", "full", "rms"))
    json.dumps(mc.to_dict(), allow_nan=False)  # NaN becomes null


# --- statistics across trials against numpy on known data ---------------------------------------------------
def known_result(finite=None) -> MonteCarloResult:
    rng = np.random.default_rng(0)
    runs = 50
    stats = rng.normal(size=(runs, 2, 3, 3))
    return MonteCarloResult(experiment="known", config={"duration": 1.0}, seed=5, names=("p", "q", "r"),
                            units=("m", "m/s", "rad"), windows=(FULL, Window(1.0, 2.0)), counts=(100, 10),
                            stats=stats, finite=np.ones(runs, bool) if finite is None else finite,
                            keys=np.arange(2 * runs, dtype=np.uint32).reshape(runs, 2), elapsed=1.5, batch_size=8)


def test_mean_spread_and_percentiles_match_numpy():
    finite = np.ones(50, bool)
    finite[[3, 17]] = False
    r = known_result(finite)
    x = r.stats[finite]
    np.testing.assert_allclose(r.mean, x.mean(axis=0), rtol=ROUNDOFF)
    np.testing.assert_allclose(r.spread, x.std(axis=0, ddof=1), rtol=ROUNDOFF)
    np.testing.assert_allclose(r.percentiles, np.percentile(x, [5, 25, 50, 75, 95], axis=0), rtol=ROUNDOFF)
    assert r.percentiles.shape == (5, 2, 3, 3)
    np.testing.assert_array_equal(r.values("q", "1-2s", "std"), x[:, 1, 1, 1])
    assert r.index("r", Window(1.0, 2.0), "rms") == (1, 2, 2) and r.index(0, 0, 0) == (0, 0, 0)


def test_percentile_of_is_the_share_of_trials_at_or_below_the_value():
    r = known_result()
    x = r.stats[:, 1, 2, 0]
    for v in (-10.0, x.min(), np.median(x), 0.3, x.max(), 10.0):
        assert r.percentile_of(v, "r", "1-2s", "mean") == pytest.approx(100.0 * np.mean(x <= v), abs=ROUNDOFF)
    assert r.percentile_of(-10.0, "r", "1-2s", "mean") == 0.0
    assert r.percentile_of(10.0, "r", "1-2s", "mean") == 100.0
    # 1..10: 5 is the 50th percentile, 10.5 the 100th
    simple = MonteCarloResult(experiment="s", config={}, seed=0, names=("a",), units=("m",), windows=(FULL,),
                              counts=(1,), stats=np.arange(1.0, 11.0)[:, None, None, None] * np.ones((1, 1, 1, 3)),
                              finite=np.ones(10, bool))
    assert simple.percentile_of(5.0, "a", "full", "rms") == 50.0
    assert simple.percentile_of(10.5, "a", 0, 2) == 100.0
    np.testing.assert_allclose(simple.percentiles[:, 0, 0, 2], np.percentile(np.arange(1.0, 11.0), PERCENTILES))


def test_selection_errors_name_the_valid_choices():
    r = known_result()
    with pytest.raises(ValueError, match=r"component: expected one of \['p', 'q', 'r'\], got 's'"):
        r.percentile_of(0.0, "s", "full", "rms")
    with pytest.raises(ValueError, match=r"window: expected one of \['full', '1-2s'\]"):
        r.values("p", "10-50s", "rms")
    with pytest.raises(ValueError, match=r"stat: expected one of \['mean', 'std', 'rms'\]"):
        r.values("p", "full", "max")
    with pytest.raises(ValueError, match=r"stats: expected shape \(runs, 2, 3, 3\)"):
        MonteCarloResult(experiment="x", config={}, seed=0, names=("p", "q", "r"), units=("m",) * 3,
                         windows=(FULL, FULL), counts=(1, 1), stats=np.zeros((4, 2, 3)), finite=np.ones(4, bool))


# --- saving, loading, tables --------------------------------------------------------------------------------
def test_save_and_load_round_trip(tmp_path):
    finite = np.ones(50, bool)
    finite[7] = False
    r = known_result(finite)
    written = r.save(tmp_path / "mc")
    assert sorted(p.name for p in written) == ["montecarlo.csv", "montecarlo.json", "montecarlo.md",
                                               "montecarlo.npz"]
    assert not [p for p in (tmp_path / "mc").iterdir() if p.name.endswith(".tmp")]
    back = MonteCarloResult.load(tmp_path / "mc")
    np.testing.assert_array_equal(back.stats, r.stats)
    np.testing.assert_array_equal(back.finite, r.finite)
    np.testing.assert_array_equal(back.keys, r.keys)
    for field in ("experiment", "config", "seed", "names", "units", "windows", "counts", "elapsed", "batch_size",
                  "title", "paper"):
        assert getattr(back, field) == getattr(r, field), field
    np.testing.assert_array_equal(back.percentiles, r.percentiles)
    assert back.percentile_of(0.1, "q", "full", "rms") == r.percentile_of(0.1, "q", "full", "rms")
    meta = json.loads((tmp_path / "mc" / "montecarlo.json").read_text())
    assert meta["schema"] == "liemef.montecarlo/1" and meta["runs"] == 50
    assert meta["nonfinite"] == {"count": 1, "trials": [7]}
    assert meta["windows"]["1-2s"] == {"start": 1.0, "stop": 2.0, "samples": 10}
    assert meta["statistics"]["full"]["q"]["rms"]["p95"] == pytest.approx(r.percentiles[4, 0, 1, 2], rel=1e-15)
    # a second stem in the same folder
    r.save(tmp_path / "mc", stem="other")
    assert MonteCarloResult.load(tmp_path / "mc", stem="other").runs == 50


def test_tables_as_text_markdown_and_csv(tmp_path):
    r = known_result()
    text = r.format()
    assert "Monte Carlo of known: 50 trials (seed 5), all finite" in text
    for word in ("window full (100 samples)", "window 1-2s (10 samples)", "spread", "p5", "p95", "rad"):
        assert word in text, word
    md = r.to_markdown()
    assert "| component | unit | stat | mean | spread | p5 | p25 | p50 | p75 | p95 |" in md
    assert md.count("| p | m | rms |") == 2
    r.write_tables(tmp_path)
    rows = (tmp_path / "montecarlo.csv").read_text().splitlines()
    assert rows[0] == "window,component,unit,stat,mean,spread,p5,p25,p50,p75,p95"
    assert len(rows) == 1 + 2 * 3 * 3
    w, comp, unit, stat, *vals = rows[1 + 3 * 3 + 3 + 1].split(",")  # window 1-2s, component q, std
    assert (w, comp, unit, stat) == ("1-2s", "q", "m/s", "std")
    assert float(vals[0]) == r.mean[1, 1, 1] and float(vals[6]) == r.percentiles[4, 1, 1, 1]


def test_load_refuses_other_files(tmp_path):
    with pytest.raises(ValueError, match="arrays: file not found"):
        MonteCarloResult.load(tmp_path)
    r = known_result()
    r.save(tmp_path)
    (tmp_path / "montecarlo.json").write_text('{"schema": "liemef.metrics/1"}')
    with pytest.raises(ValueError, match="expected schema 'liemef.montecarlo/1'"):
        MonteCarloResult.load(tmp_path)


# --- progress -----------------------------------------------------------------------------------------------
def test_progress_is_reported_after_every_batch():
    calls = []
    montecarlo(TOY, ToyConfig(), runs=7, batch_size=3, progress=lambda *a: calls.append(a))
    assert [(d, t) for d, t, _, _ in calls] == [(3, 7), (6, 7), (7, 7)]
    elapsed = [e for _, _, e, _ in calls]
    assert elapsed == sorted(elapsed)
    assert calls[0][3] is None  # the first batch includes compilation: no ETA from it
    assert calls[1][3] >= 0.0 and calls[2][3] == 0.0


class FakeTTY(stdio.StringIO):
    def isatty(self):
        return True


def test_progress_line_on_a_terminal_and_in_a_log():
    tty = FakeTTY()
    line = ProgressLine("montecarlo toy", tty)
    line(3, 7, 1.0, None)
    line(7, 7, 2.5, 0.0)
    out = tty.getvalue()
    assert out.startswith("\rmontecarlo toy: 3/7 trials (43%), 1.0 s elapsed, ETA --")
    assert "\rmontecarlo toy: 7/7 trials (100%), 2.5 s elapsed, ETA 0.0 s" in out and out.endswith("\n")
    log = stdio.StringIO()
    line = ProgressLine("mc", log, interval=5.0)
    for done, t in ((1, 0.5), (2, 1.0), (3, 6.0), (4, 7.0), (10, 125.0)):
        line(done, 10, t, 10.0)
    assert log.getvalue().splitlines() == [
        "mc: 1/10 trials (10%), 0.5 s elapsed, ETA 10.0 s",
        "mc: 3/10 trials (30%), 6.0 s elapsed, ETA 10.0 s",
        "mc: 10/10 trials (100%), 2 min 05 s elapsed, ETA 10.0 s"]


def test_progress_true_writes_to_stderr(capsys):
    montecarlo(TOY, ToyConfig(), runs=4, batch_size=2, progress=True)
    err = capsys.readouterr().err
    assert "montecarlo toy: 4/4 trials (100%)" in err


# --- bad input ----------------------------------------------------------------------------------------------
def test_bad_arguments_are_value_errors_naming_them():
    with pytest.raises(ValueError, match="runs: expected an integer >= 1, got 0"):
        montecarlo(TOY, runs=0)
    with pytest.raises(ValueError, match="batch_size: expected an integer >= 1, got 0"):
        montecarlo(TOY, runs=2, batch_size=0)
    with pytest.raises(ValueError, match="progress: expected True, False or a function"):
        montecarlo(TOY, runs=2, progress="yes")
    with pytest.raises(ValueError, match=r"experiment: expected one of .*'tse2'"):
        montecarlo("tse3", runs=2)
    no_trials = Experiment(name="single", title="", paper="", default_config=ToyConfig(), run_fn=_no_run)
    with pytest.raises(ValueError, match=r"'single' has no trial_fn, so no Monte Carlo; expected one of \[.*'tse2'"):
        montecarlo(no_trials, runs=2)

    def wrong_shape(config):
        spec = toy_trial(config)
        return TrialSpec(spec.ts, ("a", "b", "c"), ("m",) * 3, spec.windows, spec.errors)

    bad = Experiment(name="bad", title="", paper="", default_config=ToyConfig(), run_fn=_no_run,
                     trial_fn=wrong_shape)
    with pytest.raises(ValueError, match=r"expected errors\(key\) of shape \(11, 3\).*got \(11, 2\)"):
        montecarlo(bad, runs=2)


def test_experiment_reduced_size_fields():
    exp = Experiment(name="toy2", title="", paper="", default_config=ToyConfig(), run_fn=_no_run,
                     quick_config=ToyConfig(samples=5), quick_runs=3, runs=20)
    assert exp.quick() == ToyConfig(samples=5) and exp.quick(seed=2) == ToyConfig(seed=2, samples=5)
    assert TOY.quick() == ToyConfig()  # no quick config: the default
    with pytest.raises(ValueError, match=r"toy2: unknown config option\(s\) \['duration'\]"):
        exp.quick(duration=1.0)
    with pytest.raises(ValueError, match="quick_runs: expected an integer >= 0, got -1"):
        Experiment(name="x", title="", paper="", default_config=ToyConfig(), run_fn=_no_run, quick_runs=-1)


# --- diverged trials by cause (the filter status beside the errors) -----------------------------------------
@dataclass(frozen=True)
class StatusConfig:
    seed: int = 0
    samples: int = 11


def status_errors(config: StatusConfig, key):
    """Finite errors; a status code per trial: 0 (ok), 3 (K not positive definite, errors still finite) or 1
    with a NaN in the errors (non-finite)."""
    k1, k2 = jax.random.split(key)
    e = 1.0 + jax.random.normal(k1, (config.samples, 2))
    u = jax.random.uniform(k2)
    code = jnp.where(u < 0.2, 3, jnp.where(u < 0.3, 1, 0)).astype(jnp.int32)
    return e.at[-1, 1].set(jnp.where(code == 1, jnp.nan, e[-1, 1])), code


def status_trial(config: StatusConfig) -> TrialSpec:
    return TrialSpec(ts=np.linspace(0.0, 1.0, config.samples), names=("a", "b"), units=("m", "m"), windows=(FULL,),
                     errors=lambda key: status_errors(config, key))


STATUS = Experiment(name="status-toy", title="Toy with a status", paper="none", default_config=StatusConfig(),
                    run_fn=_no_run, trial_fn=status_trial)


def test_a_failed_status_counts_as_diverged_even_with_finite_errors():
    runs = 40
    mc = montecarlo(STATUS, runs=runs, seed=2, batch_size=16, progress=False)
    codes = np.array([int(status_errors(StatusConfig(), k)[1]) for k in trial_keys(2, runs)])
    assert {0, 1, 3} <= set(codes.tolist())
    np.testing.assert_array_equal(mc.causes, codes)
    np.testing.assert_array_equal(mc.finite, codes == 0)
    assert np.isfinite(mc.stats[codes == 3]).all()  # finite errors, yet left out
    good = codes == 0
    np.testing.assert_allclose(mc.mean, mc.stats[good].mean(axis=0), rtol=ROUNDOFF)
    n1, n3 = int(np.sum(codes == 1)), int(np.sum(codes == 3))
    assert mc.diverged() == {"non-finite": n1, "K not positive definite": n3}
    summary = f"{n1 + n3} of {runs} diverged: non-finite {n1}, K not positive definite {n3}"
    assert mc.divergence_summary() == summary
    text = mc.format()
    assert summary in text and f"{n1 + n3} diverged (left out: trials" in text
    assert f"{summary.capitalize()}." in mc.to_markdown()


def test_trial_cause_prefers_the_status_and_falls_back_to_the_errors():
    ok, nan = jnp.ones((3, 2)), jnp.ones((3, 2)).at[1, 0].set(jnp.nan)
    assert int(trial_cause(ok)) == 0 and int(trial_cause(nan)) == 1
    assert int(trial_cause(ok, jnp.asarray(4))) == 4 and int(trial_cause(nan, jnp.asarray(3))) == 3
    assert int(trial_cause(nan, jnp.asarray(0))) == 1
    st = Status.initial(1)
    assert int(trial_cause(ok, st)) == 0
    assert int(trial_cause(ok, eqx.tree_at(lambda s: s.code, st, jnp.asarray(2, jnp.int32)))) == 2


def test_causes_survive_save_and_load_and_older_files_derive_them(tmp_path):
    mc = montecarlo(STATUS, runs=30, seed=2, batch_size=30, progress=False)
    mc.save(tmp_path)
    back = MonteCarloResult.load(tmp_path)
    np.testing.assert_array_equal(back.causes, mc.causes)
    assert back.divergence_summary() == mc.divergence_summary()
    meta = json.loads((tmp_path / "montecarlo.json").read_text())
    assert meta["diverged"]["count"] == mc.n_nonfinite and meta["diverged"]["by_cause"] == mc.diverged()
    assert meta["diverged"]["trials"]["K not positive definite"] == [int(i) for i in np.flatnonzero(mc.causes == 3)]
    assert meta["nonfinite"]["count"] == mc.n_nonfinite  # the older key, kept
    # a result without causes (an older file): every trial not finite is "non-finite"
    old = known_result(np.arange(50) % 7 != 0)
    assert old.diverged() == {"non-finite": 8} and old.divergence_summary() == "8 of 50 diverged: non-finite 8"
    assert "8 non-finite (left out: trials 0, 7" in old.format()
    with pytest.raises(ValueError, match="causes: expected code 0 \\(ok\\) exactly for the finite trials"):
        MonteCarloResult(experiment="x", config={}, seed=0, names=("a",), units=("m",), windows=(FULL,), counts=(1,),
                         stats=np.zeros((2, 1, 1, 3)), finite=np.array([True, False]), causes=np.array([0, 0]))


def test_bad_status_shape_is_a_value_error():
    def with_float_status(config):
        spec = toy_trial(config)
        return TrialSpec(spec.ts, spec.names, spec.units, spec.windows, lambda key: (spec.errors(key), 0.5))

    bad = Experiment(name="bad-status", title="", paper="", default_config=ToyConfig(), run_fn=_no_run,
                     trial_fn=with_float_status)
    with pytest.raises(ValueError, match="expected the status of errors\\(key\\) to be a Status or its integer code"):
        montecarlo(bad, runs=2)


def test_series_and_bands_across_trials_over_time(tmp_path):
    c = ToyConfig(samples=21, nan_fraction=0.3)
    mc = montecarlo(TOY, c, runs=12, seed=5, batch_size=5, progress=False, keep_every=4)
    keys = trial_keys(5, 12)
    full = np.stack([np.asarray(toy_errors(c, k)) for k in keys])
    np.testing.assert_allclose(mc.series, full[:, ::4], rtol=ROUNDOFF, atol=ROUNDOFF)
    np.testing.assert_array_equal(mc.series_ts, np.linspace(0.0, 1.0, 21)[::4])
    b = mc.bands((5, 50, 95), absolute=True)
    np.testing.assert_allclose(b, np.percentile(np.abs(full[mc.finite][:, ::4]), [5, 50, 95], axis=0), rtol=ROUNDOFF)
    # the same statistics as without the series
    np.testing.assert_array_equal(mc.stats, montecarlo(TOY, c, runs=12, seed=5, batch_size=5, progress=False).stats)
    mc.save(tmp_path)
    back = MonteCarloResult.load(tmp_path)
    np.testing.assert_array_equal(back.series, mc.series)
    with pytest.raises(ValueError, match="series: this result kept no errors over time"):
        known_result().bands()


def test_tse2_trials_return_their_filter_status():
    exp = get_experiment("tse2")
    config = exp.config(duration=12.0)  # as in the first test: the compiled function is reused
    mc = montecarlo(exp, config, runs=4, seed=0, batch_size=2, progress=False)
    assert np.all(mc.causes == 0) and mc.divergence_summary() == "none of 4 diverged"
    out = jax.eval_shape(tse2.trial_spec(config).errors, jax.random.key(0))
    assert isinstance(out, tuple) and out[0].shape == (12001, 6) and isinstance(out[1], Status)
