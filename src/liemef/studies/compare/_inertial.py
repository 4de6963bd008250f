r"""``liemef compare inertial-navigation``: every filter on ukfm's inertial-navigation benchmark, on the same trials.

The scenario is :mod:`liemef.studies.experiments.inertial` (SE_2(3), IMU at 100 Hz, three landmarks at 1 Hz, a
15 deg / 1 m initial error, g = 9.82): trial i draws its noise from ``split(key(seed), runs)[i]`` (or, with
``rng="numpy"``, ukfm's legacy stream seeded ``seed + i``: seeds 0-19 are the runs behind ukfm's figures), and
every filter filters the same logs from the same initial estimate with K0 = P0. The filters: the minimum-energy
filter (both orders, the three connections) and ukfm's five: the invariant EKF with the right-invariant error
(``iekf-right``), the EKF in SO(3) x R^6 coordinates (``ekf``), and the UKF-M with the left and right SE_2(3)
retractions and in SO(3) x R^6 (``ukf-left``, ``ukf-right``, ``ukf-local``).

Per trial and filter: the attitude, velocity and position rms over all n (ukfm's figure) and over t >= ``steady``,
the final attitude error, the attitude and position NEES (K as the covariance of the left error; divided by 3),
ukfm's position NEES (:func:`~liemef.studies.experiments.inertial.series`) and the status. Across trials: mean,
percentiles 5 and 95, the pooled rms with a bootstrap interval, the NEES with the chi-square bounds of a
consistent filter, ukfm's figures beside ours (on ukfm's own runs, per seed; on independent trials, within Monte
Carlo error: :func:`~liemef.studies.compare._common.versus_published`), and per metric the winner with its paired
lead over each other filter (:func:`~liemef.studies.compare.paired_comparison`). Beside liemef's own errors, when
evo is installed (the test and dev extras): each trial's APE and RPE (over 1 s) by evo's library
(:func:`trajectory_errors`, :func:`liemef.metrics.ape_rpe`), their means over the trials with a bootstrap interval.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ... import _validate
from ...filters import CAUSES
from ...metrics import chi2_bounds
from ...metrics._stats import json_number
from ...reports import io
from ..experiments import inertial as I
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
from ._localization import band_figure

DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf-right", "ekf", "ukf-left", "ukf-right",
                   "ukf-local")
METRICS = (("attitude_rms", "attitude rms, all n", "deg"), ("position_rms", "position rms, all n", "m"),
           ("velocity_rms", "velocity rms, all n", "m/s"),
           ("attitude_rms_steady", "attitude rms t >= steady", "deg"),
           ("position_rms_steady", "position rms t >= steady", "m"),
           ("final_attitude", "final attitude error", "deg"))
NEES = (("nees_attitude", "attitude NEES / 3"), ("nees_position", "position NEES / 3"),
        ("nees_position_ukfm", "position NEES / 3, ukfm's M"))
BATCH_NOTE = ("batch_size defaults to 1: on a shared 2-core machine (jax 0.10.2), vmapped batches of 10 trials of "
              "this 3000-step SE_2(3) scan hung four times inside XLA's CPU runtime (every thread idle in "
              "block_until_ready, with and without the compilation cache, nice or intra-op threads); batches "
              "of 1 ran. Not understood.")
"""Why the inertial-navigation studies compile one trial per call."""
PUBLISHED_KEYS = (("attitude_rms", "attitude_deg"), ("position_rms", "position_m"),
                  ("nees_attitude", "nees_attitude"), ("nees_position_ukfm", "nees_position"))
"""Our per-trial metric -> ukfm's figure (:data:`liemef.studies.experiments.inertial.PUBLISHED`)."""


@dataclass(frozen=True)
class InertialComparison:
    """The study's settings: ``runs`` trials from ``seed``, the scenario's ``duration`` (s) and the start of the
    second window ``steady`` (s), the ``filters`` (names of :data:`~liemef.studies.compare.FILTERS`),
    ``batch_size`` trials per compiled batch, and ``rng``: ``"jax"`` (trial i from ``split(key(seed),
    runs)[i]``) or ``"numpy"`` (ukfm's legacy stream seeded ``seed + i``: with seeds 0-19 these are the runs
    behind ukfm's figures). ``initial``: ``"consistent"`` (every filter starts from K0 = P0 as the left-error
    covariance, converted exactly to its own coordinates) or ``"ukfm"`` (ukfm's filters start from the matrix
    ukfm gives each, quirks included: :func:`~liemef.studies.experiments.inertial.ukfm_initial_K`; the MEF as
    in ``"consistent"``)."""

    runs: int = 20
    seed: int = 0
    duration: float = 30.0
    steady: float = 10.0
    filters: tuple[str, ...] | str | None = DEFAULT_FILTERS
    batch_size: int = 1  # see BATCH_NOTE
    rng: str = "jax"
    initial: str = "consistent"

    def __post_init__(self):
        _validate.choice("rng", self.rng, set(I.RNGS))
        _validate.choice("initial", self.initial, {"consistent", "ukfm"})
        check_counts(self, "runs", "batch_size")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise ValueError(f"seed: expected an integer >= 0, got {self.seed!r}")
        object.__setattr__(self, "filters", parse_filters(self.filters, DEFAULT_FILTERS))
        self.config  # noqa: B018  (checks duration and steady)

    @property
    def config(self) -> I.InertialConfig:
        """The scenario's config."""
        return I.InertialConfig(duration=self.duration, steady=self.steady)


def _trial_fn(config: I.InertialConfig, right: bool, ukfm_name: str | None):
    s = I.setup(config)

    def one(flt, state0, draws):
        log, g0 = I.sensor_log(config, s.truth, s.u_true, draws)
        K0 = state0.K if ukfm_name is None else I.ukfm_initial_K(ukfm_name, config, g0)
        traj = flt.scan(eqx.tree_at(lambda st: (st.g_hat, st.K), state0, (g0, K0)), log.ts, log.us, log.ys)
        return (I.series(s.truth, traj.g_hat, traj.K, right=right), traj.status.code, traj.status.time,
                traj.g_hat.wxyz_p)

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0)))


def run_filter(name: str, config: I.InertialConfig, draws: I.Draws, batch_size: int = 1,
               initial: str = "consistent") -> dict[str, np.ndarray]:
    """One filter on the trials of ``draws`` (:func:`~liemef.studies.experiments.inertial.stacked_draws`), from
    ``initial`` K0 (:class:`InertialComparison`): its error series (runs, N, 6)
    (:func:`~liemef.studies.experiments.inertial.series`), status codes, failure times and the estimates
    ``wxyz_p`` (runs, N, 10) (quaternion, velocity, position: :class:`~liemef.groups.SE23`)."""
    s = I.setup(config)
    flt = make_filter(name, s.system)
    state0 = flt.init(jax.tree_util.tree_map(lambda a: a[0], s.truth), config.K0)
    ukfm_name = name if initial == "ukfm" and name in I.UKFM_FILTERS else None
    fn = _trial_fn(config, getattr(flt, "error", "left") == "right", ukfm_name)
    runs = draws.rot0.shape[0]
    parts = [fn(flt, state0, jax.tree_util.tree_map(lambda a, i=i: a[i:i + batch_size], draws))
             for i in range(0, runs, batch_size)]
    ser, code, t_fail, est = (np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(4))
    return {"series": ser, "code": code, "time": t_fail, "wxyz_p": est}


EVO_KEYS = (("ape_translation", "APE translation", "m"), ("ape_rotation", "APE rotation", "deg"),
            ("rpe_translation", "RPE translation", "m"), ("rpe_rotation", "RPE rotation", "deg"))
"""The trajectory errors by evo (:func:`liemef.metrics.ape_rpe`), each as its rmse over a trial's poses."""


def trajectory_errors(config: I.InertialConfig, out: dict[str, np.ndarray], delta_s: float = 1.0
                      ) -> dict[str, np.ndarray] | None:
    """APE and RPE (:data:`EVO_KEYS`, rmse per trial) of each healthy trial's estimates against the truth by evo's
    library (:func:`liemef.metrics.ape_rpe`), on all N states; RPE over ``delta_s`` seconds of states. NaN for a
    failed trial; None when evo is not installed."""
    try:
        import evo  # noqa: F401
    except ImportError:
        return None
    from ...groups import SE23
    from ...metrics import ape_rpe

    truth = I.setup(config).truth
    delta = max(1, int(round(delta_s / config.dt)))
    res = {key: np.full(out["code"].shape[0], np.nan) for key, _, _ in EVO_KEYS}
    for i, est in enumerate(out["wxyz_p"]):
        if out["code"][i] != 0 or not np.isfinite(est).all():
            continue
        r = ape_rpe(config.ts, SE23(est), config.ts, truth, delta=delta, max_diff=1e-6)
        for key, _, _ in EVO_KEYS:
            res[key][i] = r[key]["rmse"]
    return res


def per_trial(config: I.InertialConfig, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-trial metrics (:data:`METRICS` and :data:`NEES`; NEES over n >= 1); NaN for a trial whose filter failed
    or whose errors are not finite."""
    ser = out["series"]
    ok = (out["code"] == 0) & np.all(np.isfinite(ser[..., :3]), axis=(1, 2))
    late = config.ts >= config.steady
    rms = lambda x: np.sqrt(np.mean(np.square(x), axis=1))  # noqa: E731
    m = {"attitude_rms": rms(ser[:, :, 0]), "position_rms": rms(ser[:, :, 2]), "velocity_rms": rms(ser[:, :, 1]),
         "attitude_rms_steady": rms(ser[:, late, 0]), "position_rms_steady": rms(ser[:, late, 2]),
         "final_attitude": ser[:, -1, 0]}
    for k, (key, _) in enumerate(NEES):
        m[key] = np.mean(ser[:, 1:, 3 + k], axis=1)
    return {k: np.where(ok, v, np.nan) for k, v in m.items()}


def _published(name: str, trials: dict, entry: dict, n: int, same_runs: bool, overlap: bool, seed: int) -> dict:
    """ukfm's figures beside ours: on ukfm's own runs the per-seed paired differences of the rms; otherwise
    :func:`~liemef.studies.compare._common.versus_published` per figure."""
    pub = I.PUBLISHED[name]
    out = {"ukfm_filter": I.UKFM_FILTERS[name], "runs": I.PUBLISHED_RUNS, "same_runs": same_runs,
           "overlapping_runs": overlap}
    for key, pkey in PUBLISHED_KEYS:
        ours = entry[key]["pooled"] if key in ("attitude_rms", "position_rms") else entry[key]["mean"]
        interval = (entry[key]["pooled_interval"] if key in ("attitude_rms", "position_rms")
                    else entry[key]["interval"])
        out[pkey] = {"ours": ours, "ukfm": pub[pkey],
                     **versus_published(ours, interval, n, pub[pkey], I.PUBLISHED_RUNS,
                                        independent=not (same_runs or overlap))}
    if same_runs or overlap:
        # the same data as ukfm's runs seed..seed+runs-1 (those below 20): paired per-seed differences of the rms
        seeds = np.arange(seed, seed + trials["attitude_rms"].size)
        have = seeds < I.PUBLISHED_RUNS
        per_seed = np.asarray(I.PUBLISHED_PER_SEED[name])[seeds[have]]
        for j, (key, pkey) in enumerate(PUBLISHED_KEYS[:2]):
            cmp = paired_comparison({"ukfm": per_seed[:, j], "ours": trials[key][have]})
            other = "ours" if cmp["winner"] == "ukfm" else "ukfm"
            v = cmp["versus"].get(other, {"diff": None, "ci": [None, None], "n": 0})
            sign = 1.0 if other == "ours" else -1.0
            diff = None if v["diff"] is None else sign * v["diff"]
            ci = [None, None] if v["diff"] is None else sorted(sign * c for c in v["ci"])
            out[pkey]["per_seed"] = {"seeds": int(have.sum()), "mean_difference": diff, "interval": ci,
                                     "max_abs_difference": json_number(float(np.nanmax(np.abs(
                                         trials[key][have] - per_seed[:, j])))) if have.any() else None}
    return out


def summarize(config: I.InertialConfig, name: str, out: dict, trials: dict, prob: float = 0.95, *,
              same_runs: bool = False, overlap: bool = False, seed: int = 0) -> dict:
    """One filter's numbers across trials (JSON-ready)."""
    ok = np.isfinite(trials["attitude_rms"])
    n = int(ok.sum())

    entry = {"filter": FILTERS[name][0], "runs": int(ok.size), "status_ok": n}
    for key, _, _ in METRICS:
        entry[key] = distribution(trials[key])
    for key in ("attitude_rms", "position_rms", "velocity_rms", "attitude_rms_steady", "position_rms_steady"):
        x = trials[key][ok]
        entry[key]["pooled"] = json_number(pooled_rms(x)) if n else None
        entry[key]["pooled_interval"] = bootstrap_interval(x, pooled_rms)
    for key, _ in NEES:
        entry[key] = {**distribution(trials[key]), "interval": bootstrap_interval(trials[key][ok], np.mean),
                      "chi2_bounds": list(chi2_bounds(3, max(n, 1), prob, per_dof=True))}
        entry[key]["flag"] = nees_flag(entry[key]["mean"], entry[key]["chi2_bounds"])
    codes = out["code"]
    failed = np.flatnonzero(codes != 0)
    entry["diverged"] = {"count": int(failed.size),
                         "trials": [{"trial": int(i), "cause": CAUSES[int(codes[i])].value,
                                     "time": float(out["time"][i])} for i in failed[:20]]}
    if name in I.PUBLISHED and config == I.InertialConfig(steady=config.steady):
        entry["published"] = _published(name, trials, entry, n, same_runs, overlap, seed)
    return entry


def compare_inertial(study: InertialComparison | None = None, *, progress: bool = True) -> dict:
    """Run the study (module docstring); returns ``{"study", "filters", "winners", "arrays"}`` (``arrays``: the
    per-trial metrics and the time bands per filter, for :func:`save`)."""
    st = InertialComparison() if study is None else study
    config = st.config
    draws = I.stacked_draws(config, st.rng, st.seed, st.runs)
    same = st.rng == "numpy" and st.seed == 0 and st.runs == I.PUBLISHED_RUNS
    overlap = st.rng == "numpy" and st.seed < I.PUBLISHED_RUNS and not same
    per_filter, trials, bands = {}, {}, {}
    for name in st.filters:
        t0 = time.perf_counter()
        out = run_filter(name, config, draws, st.batch_size, st.initial)
        elapsed = time.perf_counter() - t0
        trials[name] = per_trial(config, out)
        per_filter[name] = summarize(config, name, out, trials[name], same_runs=same, overlap=overlap, seed=st.seed)
        per_filter[name]["elapsed_s"] = elapsed
        evo_res = trajectory_errors(config, out)
        if evo_res is not None:
            trials[name].update(evo_res)
            per_filter[name]["evo"] = {key: {"mean": json_number(float(np.nanmean(v))) if np.isfinite(v).any()
                                             else None, "interval": bootstrap_interval(v[np.isfinite(v)], np.mean)}
                                       for key, v in evo_res.items()}
        ok = np.isfinite(trials[name]["attitude_rms"])
        ab = np.abs(out["series"][ok][..., [0, 2]])
        bands[name] = (np.percentile(ab, (5, 50, 95), axis=0) if ok.any()
                       else np.full((3, config.n_states, 2), np.nan))
        if progress:
            e = per_filter[name]
            print(f"  {name:10s} attitude {fmt(e['attitude_rms']['pooled'])} deg, position "
                  f"{fmt(e['position_rms']['pooled'])} m (pooled, all n, {e['status_ok']} trials with status ok); NEES "
                  f"{fmt(e['nees_attitude']['mean'], 3)} / {fmt(e['nees_position']['mean'], 3)}; "
                  f"{e['diverged']['count']} diverged; {elapsed:.1f} s", file=sys.stderr, flush=True)
    unranked = unranked_filters(per_filter, [key for key, _ in NEES])
    winners = {label: paired_comparison({n: trials[n][key] for n in st.filters}, unranked=unranked)
               for key, label, _ in METRICS}
    arrays = {"ts": config.ts, "filters": np.array(st.filters),
              "bands": np.stack([bands[n] for n in st.filters]),  # (filters, 3, N, 2): p5/p50/p95 |att|, |pos|
              **{key: np.stack([trials[n][key] for n in st.filters]) for key in trials[st.filters[0]]}}
    keys = (f"trial i uses jax.random.split(jax.random.key({st.seed}), {st.runs})[i]" if st.rng == "jax"
            else f"trial i uses ukfm's legacy NumPy stream after np.random.seed({st.seed} + i), the data of ukfm's "
                 "own benchmark runs")
    return {"study": {**dataclasses.asdict(st), "scenario": "ukfm inertial-navigation benchmark "
                      "(../shared/scenarios/ukfm_inertial_navigation.md), rebuilt by "
                      "liemef.studies.experiments.inertial", "keys": keys},
            "filters": per_filter, "winners": winners, "arrays": arrays}


def _published_cell(pub: dict | None, pkey: str) -> str:
    if pub is None:
        return "-"
    d = pub[pkey]
    if "per_seed" in d:
        p = d["per_seed"]
        lo, hi = p["interval"]
        return (f"{d['ukfm']:g}; per seed ours - ukfm {fmt(p['mean_difference'], 2)} ({fmt(lo, 2)} to "
                f"{fmt(hi, 2)}), max {fmt(p['max_abs_difference'], 2)}")
    if d["z"] is None:
        return f"{d['ukfm']:g} (ours - ukfm {fmt(d.get('difference'), 2)})"
    return f"{d['ukfm']:g} (z = {fmt(d['z'], 2)}: {'within' if d['within'] else 'outside'} MC error)"


def markdown(result: dict) -> str:
    """The study's tables."""
    st, pf = result["study"], result["filters"]
    lines = [f"# Filters on ukfm's inertial-navigation benchmark ({st['runs']} trials, seed {st['seed']})", "",
             f"{st['scenario']}; {st['keys']}. Per trial: rms over all n (ukfm's figure) and over t >= "
             f"{st['steady']:g} s; pooled = sqrt(mean over trials and steps) with a 95 % bootstrap interval over the "
             "trials; NEES: mean over n >= 1 and the trials with status ok, divided by 3. Status ok: the trials the "
             "filter ran through without a failure (finite, K symmetric and positive definite), not that it "
             "converged.", "",
             "| filter | status ok | attitude rms [deg] (95 %) | position rms [m] (95 %) | attitude NEES | "
             "position NEES | position NEES, ukfm's M | attitude rms t >= steady [deg] | position rms t >= "
             "steady [m] |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, e in pf.items():
        cells = []
        for key in ("attitude_rms", "position_rms"):
            lo, hi = e[key]["pooled_interval"]
            cells.append(f"{fmt(e[key]['pooled'])} ({fmt(lo, 3)}-{fmt(hi, 3)})")
        nees = [nees_cell(e[key]["mean"], e[key]["chi2_bounds"]) for key, _ in NEES]
        steady = [fmt(e[key]["pooled"]) for key in ("attitude_rms_steady", "position_rms_steady")]
        lines.append(f"| {name} | {e['status_ok']}/{e['runs']} | {cells[0]} | {cells[1]} | {' | '.join(nees)} | "
                     f"{' | '.join(steady)} |")
    e0 = next(iter(pf.values()))
    lo, hi = e0["nees_attitude"]["chi2_bounds"]
    lines += ["", f"NEES: 1 for a consistent filter; the 95 % chi-square bounds of one step's average over the "
              f"trials: {lo:.3f}-{hi:.3f}; '(far above!)' marks a NEES beyond 10 times the upper bound. ukfm's M: "
              "ukfm's map of a right-invariant filter's covariance, with "
              "+[p_hat]_x where the first-order map has a minus sign (the same as the first for the others)."]
    with_pub = {n: e["published"] for n, e in pf.items() if "published" in e}
    if with_pub:
        lines += ["", "## ukfm's own figures", "",
                  "ukfm's code over its seeds 0-19 (../shared/scenarios/ukfm_inertial_navigation.md §1.6), all n. On "
                  "ukfm's own runs (rng numpy, seeds 0-19) the per-seed difference of the rms, with its paired 95 % "
                  "interval and largest value; on independent trials z = |ours - ukfm| over the standard error of "
                  "that difference (ours from the bootstrap, ukfm's scaled to its 20 runs), within Monte Carlo "
                  "error when z <= 1.96.", "",
                  "| filter | ukfm's | ours: attitude [deg] | ukfm | ours: position [m] | ukfm | ours: attitude "
                  "NEES | ukfm | ours: position NEES (ukfm's M) | ukfm |",
                  "|---|---|---:|---|---:|---|---:|---|---:|---|"]
        for name, pub in with_pub.items():
            cells = [f"{fmt(pub[pkey]['ours'])} | {_published_cell(pub, pkey)}" for _, pkey in PUBLISHED_KEYS]
            lines.append(f"| {name} | {pub['ukfm_filter']} | " + " | ".join(cells) + " |")
    with_evo = {n: e["evo"] for n, e in pf.items() if "evo" in e}
    if with_evo:
        lines += ["", "## APE and RPE (evo)", "",
                  "By evo's library (liemef.metrics.ape_rpe), per trial on all states against the truth, then the mean "
                  "over the healthy trials with its 95 % bootstrap interval: APE = rmse of the pose error "
                  "Q_k^-1 P_k, RPE = rmse of the relative pose error over 1 s (100 states). Translation in m, "
                  "rotation in deg.", "",
                  "| filter | " + " | ".join(f"{label} [{unit}]" for _, label, unit in EVO_KEYS) + " |",
                  "|---|" + "---:|" * len(EVO_KEYS)]
        for name, ev in with_evo.items():
            cells = []
            for key, _, _ in EVO_KEYS:
                lo, hi = ev[key]["interval"]
                cells.append(f"{fmt(ev[key]['mean'])} ({fmt(lo, 3)}-{fmt(hi, 3)})")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Winners", "", "Per metric, the lowest mean across the trials; the lead over each other "
              "filter is the paired mean difference over the same trials with its 95 % interval. 'Outside the "
              "spread' means the interval excludes 0.", ""]
    lines += winners_markdown(result["winners"], {label: unit for _, label, unit in METRICS})
    return "\n".join(lines + [""])


def csv_rows(result: dict) -> tuple[list[str], list[list]]:
    """One row per filter: the means, pooled values, NEES and counts."""
    header = ["filter", "runs", "status_ok", "diverged"]
    for key, _, _ in METRICS:
        header += [f"{key}_mean", f"{key}_p5", f"{key}_p95"]
    header += ["attitude_pooled", "position_pooled", "attitude_steady_pooled", "position_steady_pooled"]
    header += [key for key, _ in NEES]
    evo = all("evo" in e for e in result["filters"].values())
    header += [f"{key}_rmse_mean" for key, _, _ in EVO_KEYS] if evo else []
    rows = []
    for name, e in result["filters"].items():
        row = [name, e["runs"], e["status_ok"], e["diverged"]["count"]]
        for key, _, _ in METRICS:
            row += [e[key]["mean"], e[key]["p5"], e[key]["p95"]]
        row += [e[k]["pooled"] for k in ("attitude_rms", "position_rms", "attitude_rms_steady", "position_rms_steady")]
        row += [e[key]["mean"] for key, _ in NEES]
        row += [e["evo"][key]["mean"] for key, _, _ in EVO_KEYS] if evo else []
        rows.append(row)
    return header, rows


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``inertial.json``, ``inertial.md``, ``inertial.csv``, ``arrays.npz`` and ``fig_errors.png`` to
    ``out``; each file completely or not at all."""
    from ...reports import plots

    out = io.ensure_dir(out)
    header, rows = csv_rows(result)
    written = [io.write_npz(out / "arrays.npz", result["arrays"]),
               io.write_json(out / "inertial.json", {k: v for k, v in result.items() if k != "arrays"}),
               io.write_text(out / "inertial.md", markdown(result)),
               io.write_rows(out / "inertial.csv", header, rows)]
    st = result["study"]
    fig = band_figure(io.read_arrays(out / "arrays.npz"),
                      f"ukfm inertial navigation, {st['runs']} trials: median and 5-95 % band")
    fig.axes[0].set_ylabel("|attitude error| [deg]")
    written.append(plots.save_figure(fig, out / "fig_errors.png"))
    return written


__all__ = ["InertialComparison", "compare_inertial", "markdown", "save", "run_filter", "per_trial", "trajectory_errors",
           "DEFAULT_FILTERS"]
