r"""``liemef compare localization``: every filter on ukfm's 2D localization benchmark, on the same trials.

The scenario is :mod:`liemef.studies.experiments.localization` (odometry at 100 Hz, GPS at 1 Hz, a 45 deg initial
heading error, the position known): trial i draws its noise from ``split(key(seed), runs)[i]``, and every filter
filters the same logs from the same initial estimate and K0 = diag(theta0_std^2, 0, 0). Per trial and filter:
the heading and position rms over t >= ``steady`` and over the whole run, the final heading error, the heading
and position NEES over t >= ``steady`` (K as the covariance of the left error), and the status. Across trials:
mean, percentiles 5 and 95, the pooled rms (ukfm's figure) with a bootstrap interval, the published figures of
ukfm's own benchmark code, and per metric the winner with its paired lead over each other filter
(:func:`~liemef.studies.compare.paired_comparison`). With ``optimum_runs`` > 0, the distance of each filter's estimate
from the exact minimum-energy estimate (:mod:`liemef.studies.optimum`) on the first trials.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...filters import CAUSES
from ...metrics import chi2_bounds
from ...metrics._stats import json_number
from ...reports import io
from ...reports.figures import comparison_band_figure as band_figure
from ..experiments import localization as L
from ._common import (
    FILTERS,
    bootstrap_interval,
    check_counts,
    distribution,
    fmt,
    make_filter,
    nees_cell,
    nees_flag,
    paired_comparison,
    parse_filters,
    pooled_rms,
    unranked_filters,
    versus_published,
    winners_markdown,
)

SCHEMA = "liemef.compare.localization/1"
"""Version tag of ``comparison.json``."""

DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf", "ekf", "ukf-left")
PUBLISHED_OF = {"iekf": "iekf", "ukf-left": "iekf", "ekf": "ekf"}
"""Which published figure of the scenario (:data:`liemef.studies.experiments.localization.PUBLISHED`) a filter is
compared with: ukfm's IEKF and left UKF-M share one, its EKF has its own."""
PUBLISHED_RUNS = 20
"""The runs behind ukfm's published figures (../shared/scenarios/ukfm_localization.md: 20 seeds)."""
METRICS = (("heading_rms", "heading rms t >= steady", "deg"), ("position_rms", "position rms t >= steady", "m"),
           ("heading_rms_all", "heading rms, whole run", "deg"), ("position_rms_all", "position rms, whole run", "m"),
           ("final_heading", "final heading error (absolute)", "deg"))


@dataclass(frozen=True)
class LocalizationComparison:
    """The study's settings: ``runs`` trials from ``seed``, the scenario's ``duration`` (s) and ``steady``
    window start (s), the ``filters`` (names of :data:`~liemef.studies.compare.FILTERS`), ``optimum_runs`` trials with
    the distance to the exact estimate, ``batch_size`` trials per compiled batch, and ``rng``: ``"jax"`` (trial
    i from ``split(key(seed), runs)[i]``) or ``"numpy"`` (ukfm's legacy stream seeded ``seed + i``: with seeds
    0-19 these are the runs behind ukfm's published figures)."""

    runs: int = 20
    seed: int = 0
    duration: float = 40.0
    steady: float = 20.0
    filters: tuple[str, ...] = DEFAULT_FILTERS
    optimum_runs: int = 0
    batch_size: int = 20
    rng: str = "jax"

    def __post_init__(self):
        _validate.choice("rng", self.rng, set(L.RNGS))
        check_counts(self, "runs", "batch_size")
        if not (isinstance(self.optimum_runs, int) and 0 <= self.optimum_runs <= self.runs):
            raise ValueError(f"optimum_runs: expected an integer in [0, runs = {self.runs}], got {self.optimum_runs!r}")
        object.__setattr__(self, "filters", parse_filters(self.filters, DEFAULT_FILTERS))
        self.config  # noqa: B018  (checks duration and steady)

    @property
    def config(self) -> L.LocalizationConfig:
        """The scenario's config."""
        return L.LocalizationConfig(duration=self.duration, steady=self.steady)


def trial_draws(config: L.LocalizationConfig, rng: str, seed: int, runs: int) -> L.Draws:
    """The standard normals of the trials, stacked (leading axis: trial): ``rng="jax"``: trial i from
    ``split(key(seed), runs)[i]``; ``rng="numpy"``: ukfm's legacy stream after ``np.random.seed(seed + i)``
    (:func:`liemef.studies.experiments.localization.numpy_draws`), the data of ukfm's own benchmark runs."""
    if rng == "numpy":
        draws = [L.numpy_draws(config, seed + i) for i in range(runs)]
        return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *draws)
    keys = jax.random.split(jax.random.key(seed), runs)
    return jax.jit(jax.vmap(lambda k: L.jax_draws(config, k)))(keys)


def _trial_fn(config: L.LocalizationConfig):
    s = L.setup(config)

    def one(flt, state0, draws):
        log, g0 = L.sensor_log(config, s.truth, draws)
        traj = flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, g0), log.ts, log.us, log.ys)
        return L.series(s.truth, traj.g_hat, traj.K), traj.g_hat.coords(), traj.status.code, traj.status.time

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0)))


def run_filter(name: str, config: L.LocalizationConfig, draws: L.Draws, batch_size: int = 20) -> dict[str, np.ndarray]:
    """One filter on the trials of ``draws`` (:func:`trial_draws`): its error series (runs, N, 4)
    (:func:`~liemef.studies.experiments.localization.series`), estimates (runs, N, 3) as (theta, x, y), status codes
    and failure times."""
    s = L.setup(config)
    flt = make_filter(name, s.system)
    state0 = flt.init(s.truth[0], np.diag([config.theta0_std**2, 0.0, 0.0]))
    fn = _trial_fn(config)
    runs = draws.theta0.shape[0]
    parts = [fn(flt, state0, jax.tree_util.tree_map(lambda a, i=i: a[i:i + batch_size], draws))
             for i in range(0, runs, batch_size)]
    ser, coords, code, t_fail = (np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(4))
    return {"series": ser, "coords": coords, "code": code, "time": t_fail}


def per_trial(config: L.LocalizationConfig, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-trial metrics (:data:`METRICS` plus the NEES); NaN for a trial whose filter failed or whose errors
    are not finite."""
    ser, ok = out["series"], out["code"] == 0
    late = config.ts >= config.steady
    ok = ok & np.all(np.isfinite(ser[..., :2]), axis=(1, 2))
    rms = lambda x: np.sqrt(np.mean(np.square(x), axis=1))  # noqa: E731
    m = {"heading_rms": rms(ser[:, late, 0]), "position_rms": rms(ser[:, late, 1]),
         "heading_rms_all": rms(ser[:, :, 0]), "position_rms_all": rms(ser[:, :, 1]),
         "final_heading": np.abs(ser[:, -1, 0]),
         "nees_heading": np.mean(ser[:, late, 2], axis=1), "nees_position": np.mean(ser[:, late, 3], axis=1)}
    return {k: np.where(ok, v, np.nan) for k, v in m.items()}


def summarize(config: L.LocalizationConfig, name: str, out: dict, trials: dict, prob: float = 0.95, *,
              same_runs: bool = False, overlap: bool = False) -> dict:
    """One filter's numbers across trials (JSON-ready). ``same_runs``: the trials are ukfm's own benchmark runs
    (its legacy stream, seeds 0-19), so the published figures are compared on the same data."""
    ok = np.isfinite(trials["heading_rms"])
    n = int(ok.sum())

    entry = {"filter": FILTERS[name][0], "runs": int(ok.size), "status_ok": n}
    for key, _, _ in METRICS:
        entry[key] = distribution(trials[key])
    for key in ("heading_rms", "position_rms"):
        x = trials[key][ok]
        entry[key]["pooled"] = json_number(pooled_rms(x)) if n else None
        entry[key]["pooled_interval"] = bootstrap_interval(x, pooled_rms)
    for key, dof in (("nees_heading", 1), ("nees_position", 2)):
        entry[key] = {**distribution(trials[key]),
                      "chi2_bounds": list(chi2_bounds(dof, max(n, 1), prob, per_dof=True))}
        entry[key]["flag"] = nees_flag(entry[key]["mean"], entry[key]["chi2_bounds"])
    codes = out["code"]
    failed = np.flatnonzero(codes != 0)
    entry["diverged"] = {"count": int(failed.size),
                         "trials": [{"trial": int(i), "cause": CAUSES[int(codes[i])].value,
                                     "time": float(out["time"][i])}
                                    for i in failed[:20]]}
    flips = np.flatnonzero(trials["final_heading"] > L.FLIP_DEG)
    entry["heading_flips"] = {"count": int(flips.size), "trials": [int(i) for i in flips]}
    if name in PUBLISHED_OF and config == L.LocalizationConfig(steady=config.steady) and config.steady == 20.0:
        # Only on the published scenario (40 s, t >= 20 s), within Monte Carlo error (versus_published).
        pub = L.PUBLISHED[PUBLISHED_OF[name]]
        entry["published"] = {"which": PUBLISHED_OF[name], "runs": PUBLISHED_RUNS, "same_runs": same_runs,
                              "overlapping_runs": overlap}
        for key, pkey in (("heading_rms", "heading_deg"), ("position_rms", "position_m")):
            entry["published"][pkey] = pub[pkey]
            # trials that include some of ukfm's are not independent of its figure: no z then
            cmp = versus_published(entry[key]["pooled"], entry[key]["pooled_interval"], n, pub[pkey],
                                   PUBLISHED_RUNS, independent=not (same_runs or overlap))
            entry["published"].update({f"{pkey}_{k}": v for k, v in cmp.items()})
    return entry


def compare_localization(study: LocalizationComparison | None = None, *, progress: bool = True) -> dict:
    """Run the study (module docstring); returns ``{"study", "filters", "winners", "optimum", "arrays"}``
    (``arrays``: the per-trial metrics and the time bands per filter, for :func:`save`)."""
    st = LocalizationComparison() if study is None else study
    config = st.config
    draws = trial_draws(config, st.rng, st.seed, st.runs)
    per_filter, trials, bands, timing, coords = {}, {}, {}, {}, {}
    # ukfm's published runs are its legacy stream's seeds 0-19: the same trials, or some of them
    same = st.rng == "numpy" and st.seed == 0 and st.runs == PUBLISHED_RUNS
    overlap = st.rng == "numpy" and st.seed < PUBLISHED_RUNS and st.seed + st.runs > 0 and not same
    for name in st.filters:
        t0 = time.perf_counter()
        out = run_filter(name, config, draws, st.batch_size)
        timing[name] = time.perf_counter() - t0
        trials[name] = per_trial(config, out)
        per_filter[name] = summarize(config, name, out, trials[name], same_runs=same, overlap=overlap)
        per_filter[name]["elapsed_s"] = timing[name]
        ok = np.isfinite(trials[name]["heading_rms"])
        ab = np.abs(out["series"][ok][..., :2])
        bands[name] = (np.percentile(ab, (5, 50, 95), axis=0) if ok.any()
                       else np.full((3, config.n_states, 2), np.nan))
        coords[name] = out["coords"][:st.optimum_runs]
        if progress:
            e = per_filter[name]
            print(f"  {name:10s} heading {fmt(e['heading_rms']['mean'])} deg, position "
                  f"{fmt(e['position_rms']['mean'])} m (t >= {st.steady:g} s, mean over {e['status_ok']} trials "
                  "with status ok); "
                  f"{e['diverged']['count']} diverged; {timing[name]:.1f} s", file=sys.stderr, flush=True)
    unranked = unranked_filters(per_filter, ("nees_heading", "nees_position"))
    winners = {label: paired_comparison({n: trials[n][key] for n in st.filters}, unranked=unranked)
               for key, label, _ in METRICS}
    optimum = None
    if st.optimum_runs:
        from ._optimum import localization_distances

        first = jax.tree_util.tree_map(lambda a: a[:st.optimum_runs], draws)
        optimum = localization_distances(config, first, coords, progress=progress, unranked=unranked)
    arrays = {"ts": config.ts, "filters": np.array(st.filters),
              "bands": np.stack([bands[n] for n in st.filters]),  # (filters, 3, N, 2): p5/p50/p95 |heading|, pos
              **{f"{key}": np.stack([trials[n][key] for n in st.filters]) for key in trials[st.filters[0]]}}
    if optimum is not None:
        arrays.update(optimum.pop("arrays"))
    return {"study": {**dataclasses.asdict(st), "scenario": "ukfm 2D localization benchmark "
                      "(../shared/scenarios/ukfm_localization.md), rebuilt by liemef.studies.experiments.localization",
                      "keys": (f"trial i uses jax.random.split(jax.random.key({st.seed}), {st.runs})[i]"
                               if st.rng == "jax" else f"trial i uses ukfm's legacy NumPy stream after "
                               f"np.random.seed({st.seed} + i), the data of ukfm's own benchmark runs")},
            "filters": per_filter, "winners": winners, "optimum": optimum, "arrays": arrays}


def markdown(result: dict) -> str:
    """The study's tables."""
    st, pf = result["study"], result["filters"]
    lines = [f"# Filters on ukfm's 2D localization benchmark ({st['runs']} trials, seed {st['seed']})", "",
             f"{st['scenario']}; {st['keys']}. Per trial: rms over t >= {st['steady']:g} s; across the trials "
             "with status ok: mean [p5, p95]; pooled = sqrt(mean over trials and steps), ukfm's figure, with a 95 % "
             "bootstrap interval over the trials.", "",
             "| filter | status ok | flips | heading rms [deg] | pooled (95 % interval) | position rms [m] | "
             "pooled (95 % interval) | heading NEES | position NEES / 2 | published (ukfm) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name, e in pf.items():
        cells = []
        for key in ("heading_rms", "position_rms"):
            d = e[key]
            cells.append(f"{fmt(d['mean'])} [{fmt(d['p5'])}, {fmt(d['p95'])}]")
            lo, hi = d["pooled_interval"]
            cells.append(f"{fmt(d['pooled'])} ({fmt(lo)}-{fmt(hi)})")
        nees = [nees_cell(e[k]["mean"], e[k]["chi2_bounds"]) for k in ("nees_heading", "nees_position")]
        pub = e.get("published")
        yes = lambda b: "-" if b is None else ("yes" if b else "no")  # noqa: E731
        if pub is None:
            pub_cell = "-"
        elif pub["same_runs"]:
            pub_cell = (f"{pub['which']}: {pub['heading_deg']:g} deg / {pub['position_m']:g} m on the same runs "
                        f"(ours - published: {fmt(pub['heading_deg_difference'], 2)} / "
                        f"{fmt(pub['position_m_difference'], 2)})")
        else:
            pub_cell = (f"{pub['which']}: {pub['heading_deg']:g} deg / {pub['position_m']:g} m (z = "
                        f"{fmt(pub['heading_deg_z'], 2)} / {fmt(pub['position_m_z'], 2)}; within MC error: "
                        f"{yes(pub['heading_deg_within'])} / {yes(pub['position_m_within'])})")
        lines.append(f"| {name} | {e['status_ok']}/{e['runs']} | {e['heading_flips']['count']} | {cells[0]} | "
                     f"{cells[1]} | {cells[2]} | {cells[3]} | {nees[0]} | {nees[1]} | {pub_cell} |")
    e0 = next(iter(pf.values()))
    lo, hi = e0["nees_heading"]["chi2_bounds"]
    lines += ["", f"Status ok: the trials the filter ran through without a failure (finite, K symmetric and positive "
              "definite), not that it converged: see the errors and the NEES. NEES: mean over t >= "
              f"{st['steady']:g} s and the trials with status ok; 1 for a consistent filter "
              f"(the 95 % chi-square bounds of one step's average over the trials: {lo:.3f}-{hi:.3f} for the "
              "heading; '(far above!)' marks a NEES beyond 10 times the upper bound, a K that does not describe the "
              "error). Published: the figure of ukfm's own benchmark code (20 runs); z = |ours - published| "
              "over the standard error of that difference (ours from the bootstrap, ukfm's scaled to its 20 runs); "
              "within Monte Carlo error when z <= 1.96.", "", "## Winners", "",
              "Per metric, the lowest mean across the trials; the lead over each other filter is the paired mean "
              "difference over the same trials with its 95 % interval. 'Outside the spread' means the interval "
              "excludes 0.", ""]
    lines += winners_markdown(result["winners"], {label: unit for _, label, unit in METRICS})
    opt = result.get("optimum")
    if opt:
        lines += ["", "## Distance to the exact minimum-energy estimate", "", opt["definition"], "",
                  "| filter | heading, mean over the run [deg] | heading, t >= steady [deg] | position, mean [m] | "
                  "position, t >= steady [m] |", "|---|---:|---:|---:|---:|"]
        for name, d in opt["filters"].items():
            lines.append(f"| {name} | {fmt(d['heading_mean'])} | {fmt(d['heading_steady'])} | "
                         f"{fmt(d['position_mean'])} | {fmt(d['position_steady'])} |")
        lines += ["", "## Winners: distance to the optimum", ""]
        lines += winners_markdown(opt["winners"], {k: "deg" if k.startswith("heading") else "m"
                                                   for k in opt["winners"]})
    return "\n".join(lines + [""])


def csv_rows(result: dict) -> tuple[list[str], list[list]]:
    """One row per filter: the means, pooled values and counts."""
    header = ["filter", "runs", "status_ok", "diverged", "heading_flips"]
    for key, _, _ in METRICS:
        header += [f"{key}_mean", f"{key}_p5", f"{key}_p95"]
    header += ["heading_pooled", "position_pooled", "nees_heading", "nees_position", "nees_heading_flag",
               "nees_position_flag"]
    rows = []
    for name, e in result["filters"].items():
        row = [name, e["runs"], e["status_ok"], e["diverged"]["count"], e["heading_flips"]["count"]]
        for key, _, _ in METRICS:
            row += [e[key]["mean"], e[key]["p5"], e[key]["p95"]]
        row += [e["heading_rms"]["pooled"], e["position_rms"]["pooled"], e["nees_heading"]["mean"],
                e["nees_position"]["mean"], e["nees_heading"]["flag"], e["nees_position"]["flag"]]
        rows.append(row)
    return header, rows


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``comparison.json``, ``comparison.md``, ``comparison.csv``, ``arrays.npz`` and the figures
    (``fig_errors.png``, ``fig_optimum.png`` with the optimum) to ``out``; each file completely or not at all."""
    from ...reports import plots

    out = io.ensure_dir(out)
    arrays = result["arrays"]
    meta = {k: v for k, v in result.items() if k != "arrays"}
    header, rows = csv_rows(result)
    written = [io.write_npz(out / "arrays.npz", arrays),
               io.write_json(out / "comparison.json", {"schema": SCHEMA, **meta}),
               io.write_text(out / "comparison.md", markdown(result)),
               io.write_rows(out / "comparison.csv", header, rows)]
    st = result["study"]
    written.append(plots.save_figure(band_figure(io.read_arrays(out / "arrays.npz"),
                                                 f"ukfm 2D localization, {st['runs']} trials: median and 5-95 % "
                                                 "band"), out / "fig_errors.png"))
    if result.get("optimum"):
        from ...reports.figures import optimum_figure

        written.append(plots.save_figure(optimum_figure(io.read_arrays(out / "arrays.npz")), out / "fig_optimum.png"))
    return written


__all__ = ["LocalizationComparison", "compare_localization", "markdown", "save", "run_filter", "per_trial",
           "DEFAULT_FILTERS"]
