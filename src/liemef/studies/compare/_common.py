"""What every comparison shares: the filters by name, paired statistics across filters run on the same trials,
and the tables and figures of a study."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path

import numpy as np

from ... import _validate
from ...filters import AbstractFilter, MinimumEnergyFilter
from ...filters.baselines import ExtendedKalmanFilter, invariant_ekf, local_ekf, ukf_m
from ...metrics._stats import json_number
from .. import registry

_FACTORIES = {
    "mef": partial(MinimumEnergyFilter, curvature="exact", error="left"),
    "mef-safe": partial(MinimumEnergyFilter, curvature="safe", error="left"),
    "mef-minus": partial(MinimumEnergyFilter, connection="minus", curvature="exact", error="left"),
    "mef-plus": partial(MinimumEnergyFilter, connection="plus", curvature="exact", error="left"),
    "mef-first": partial(MinimumEnergyFilter, order="first", error="left"),
    "iekf": partial(invariant_ekf),
    "iekf-right": partial(ExtendedKalmanFilter, error="right"),
    "ekf": partial(local_ekf),
    "ukf-left": partial(ukf_m),
    "ukf-right": partial(ukf_m, error="right"),
    "ukf-local": partial(ukf_m, error="local"),
}
FILTERS = {name: (description, _FACTORIES[name]) for name, description in registry.FILTERS.items()}
"""The one table of the comparisons' filters: per name a description (declared in
:data:`liemef.studies.registry.FILTERS`) and a factory ``factory(system, **options)``, the table's constructor
with its own options under ``options``. A study's own rows (``compare broad``'s ``mef-vel``, ...) are these
filters on the study's system with more options (:func:`make_filter`)."""


def make_filter(name: str, system, **options) -> AbstractFilter:
    """The filter ``name`` (:data:`FILTERS`) on ``system``, with ``options`` over the table's own (e.g.
    ``updates="discrete"``)."""
    _validate.choice("filter", name, set(FILTERS))
    return FILTERS[name][1](system, **options)


def parse_names(what: str, names: str | Sequence[str] | None, options, default: Sequence[str]) -> tuple[str, ...]:
    """A comma-separated list or a sequence of names from ``options``, each once (default ``default``); a
    ValueError names the setting ``what``."""
    if names is None:
        return tuple(default)
    items = [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)
    if not items or any(not n for n in items):
        raise ValueError(f"{what}: expected a comma-separated list of names from {sorted(options)}, got {names!r}")
    for n in items:
        _validate.choice(what, n, set(options))
    if len(set(items)) != len(items):
        raise ValueError(f"{what}: expected each name once, got {names!r}")
    return tuple(items)


def parse_filters(names: str | Sequence[str] | None, default: Sequence[str]) -> tuple[str, ...]:
    """A comma-separated list or a sequence of filter names of :data:`FILTERS`, checked (:func:`parse_names`)."""
    return parse_names("filters", names, FILTERS, default)


def check_counts(settings, *names: str) -> None:
    """Each named field of ``settings`` is an integer >= 1 (runs, batch sizes)."""
    for name in names:
        v = getattr(settings, name)
        if not (isinstance(v, int) and v >= 1):
            raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")


def realdata_present(realdata: str | None, find: Callable[[Path], Mapping[str, Path]], sub: str
                     ) -> tuple[Path, dict[str, Path]]:
    """The real-data folder (``realdata``, else :func:`liemef.studies.datasets.realdata_dir`) and the recordings
    ``find(folder / sub)`` finds in it (id -> file, read from the files themselves, e.g.
    :func:`liemef.studies.datasets.broad_trials`)."""
    from .. import datasets

    folder = Path(realdata) if realdata is not None else datasets.realdata_dir()
    if folder is None or not folder.is_dir():
        raise ValueError(f"realdata: expected the real-data folder (set {datasets.ENV_VAR} or give realdata=PATH), "
                         f"got {realdata or 'none found'}")
    return folder, dict(find(folder / sub))


def paired_comparison(values: Mapping[str, np.ndarray], prob: float = 0.95,
                      unranked: Mapping[str, str] | None = None) -> dict:
    """Which filter has the lowest mean of a per-trial metric, and whether its lead is outside the Monte Carlo
    spread. A failed trial is NaN.

    A filter named in ``unranked`` (name -> why, from :func:`unranked_filters`: it failed on a trial, or its K
    does not describe its error) cannot win; it is still compared with the winner. The winner is chosen among
    the other filters healthy on the most trials (a filter that failed where another did not cannot win), by
    the lowest mean over its healthy trials. The filters ran on the same trials, so each
    other filter is compared with it by the paired differences d_i = x_i - x_winner,i over the trials where
    both are finite, with the interval mean(d) +- t sd(d)/sqrt(n) (Student's t quantile of ``prob``, n - 1
    degrees of freedom: honest for the few trials of a distance-to-optimum study).

    Returns ``winner``, ``means`` and ``healthy`` (per filter), ``versus`` (per other filter: mean difference,
    its interval, n and ``significant``: the interval excludes 0), ``level`` (the filters whose interval
    includes 0, and the winner; never an unranked one) and ``unranked`` (the filters that could not win, and
    why); a filter with fewer
    than 2 trials in common with the winner is not compared. ``winner`` is None when no filter may win."""
    from scipy.stats import t as student_t

    arrays = {k: np.asarray(v, float) for k, v in values.items()}
    unranked = {k: str(why) for k, why in (unranked or {}).items() if k in arrays}
    healthy = {k: int(np.isfinite(v).sum()) for k, v in arrays.items()}
    means = {k: float(np.nanmean(v)) if healthy[k] else math.nan for k, v in arrays.items()}
    eligible = [k for k in arrays if k not in unranked]
    most = max((healthy[k] for k in eligible), default=0)
    if most == 0:
        return {"winner": None, "means": {k: json_number(m) for k, m in means.items()}, "healthy": healthy,
                "versus": {}, "level": [], "unranked": unranked}
    winner = min((k for k in eligible if healthy[k] == most), key=lambda k: means[k])
    versus, level = {}, [winner]
    w = arrays[winner]
    for k, v in arrays.items():
        if k == winner:
            continue
        ok = np.isfinite(v) & np.isfinite(w)
        d = v[ok] - w[ok]
        n = d.size
        if n < 2:
            versus[k] = {"diff": None, "ci": [None, None], "n": int(n), "significant": False}
            continue
        mean = float(d.mean())
        half = float(student_t.ppf(0.5 + prob / 2, n - 1) * d.std(ddof=1) / math.sqrt(n))
        sig = bool(mean - half > 0)
        versus[k] = {"diff": mean, "ci": [mean - half, mean + half], "n": int(n), "significant": sig}
        if not sig and k not in unranked:
            level.append(k)
    return {"winner": winner, "means": {k: json_number(m) for k, m in means.items()}, "healthy": healthy,
            "versus": versus, "level": level, "unranked": unranked}


def unranked_filters(entries: Mapping[str, dict], nees_keys: Sequence[str]) -> dict[str, str]:
    """The filters of a study that may not win a comparison, and why: those that failed on any trial
    (``status_ok < runs``) and those with a NEES of ``nees_keys`` flagged "far above" or "far below" its band
    (:func:`nees_flag`: their K does not describe their error, so their error is not what they claim). ``entries``:
    per filter, a study's summary with ``status_ok``, ``runs`` and per NEES key ``{"mean", "flag"}``."""
    out = {}
    for name, e in entries.items():
        why = []
        if e["status_ok"] < e["runs"]:
            why.append(f"failed on {e['runs'] - e['status_ok']} of {e['runs']} trials")
        for key in nees_keys:
            flag = e[key].get("flag")
            if flag in ("far above", "far below"):
                why.append(f"{key.replace('_', ' ')} {fmt(e[key]['mean'], 3)} {flag} its band")
        if why:
            out[name] = "; ".join(why)
    return out


def versus_published(ours: float | None, interval, n: int, published: float, published_runs: int,
                     independent: bool) -> dict:
    """Our Monte Carlo figure ``ours`` (over ``n`` trials, with the 95 % bootstrap ``interval``) against a
    published one from ``published_runs`` runs: ``difference`` (ours - published), and ``z`` and ``within``.

    Both figures are Monte Carlo estimates: the published one's standard error is taken as ours scaled to its
    number of runs (the same spread across trials), and the two agree within Monte Carlo error when their
    difference is within 1.96 standard errors of a difference (``z <= 1.96``). Only for ``independent`` trials:
    on the published runs themselves, or on some of them, the two share their Monte Carlo error and only the
    difference is reported (z and within None). Without an interval: z and within None, no difference."""
    lo, hi = interval
    if lo is None or ours is None:
        return {"z": None, "within": None}
    se = (hi - lo) / (2 * 1.96)
    se_diff = se * np.sqrt(1.0 + n / published_runs)
    z = None if not independent or se_diff == 0 else abs(ours - published) / se_diff
    return {"difference": ours - published, "z": None if z is None else json_number(z),
            "within": None if z is None else bool(z <= 1.96)}


def bootstrap_interval(x: np.ndarray, stat, *, n_boot: int = 2000, prob: float = 0.95, seed: int = 0):
    """A percentile bootstrap interval of ``stat(x)`` over the trials (fixed seed, so reports are reproducible)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)] if x.ndim == 1 else x[np.all(np.isfinite(x), axis=tuple(range(1, x.ndim)))]
    if x.shape[0] < 2:
        return [None, None]
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.shape[0], size=(n_boot, x.shape[0]))
    s = np.array([stat(x[i]) for i in idx])
    lo, hi = np.percentile(s, [50 * (1 - prob), 50 * (1 + prob)])
    return [float(lo), float(hi)]


FAR_FACTOR = 10.0
"""A NEES is flagged "far above" (below) its chi-square bounds beyond FAR_FACTOR times the upper bound (below the
lower bound divided by it): the filter's K does not describe its error, whatever its status says."""


def nees_flag(mean: float | None, bounds) -> str | None:
    """How a mean NEES (per dimension) sits against its 95 % chi-square ``bounds`` (lo, hi): ``"within"``,
    ``"above"``, ``"below"``, ``"far above"`` or ``"far below"`` (beyond :data:`FAR_FACTOR`); None without a
    value. The bounds are those of one step's average over the trials; a mean over time as well is tighter, so
    "above" and "below" are the conservative reading."""
    if mean is None or not math.isfinite(mean):
        return None
    lo, hi = bounds
    if mean > hi:
        return "far above" if mean > FAR_FACTOR * hi else "above"
    if mean < lo:
        return "far below" if mean < lo / FAR_FACTOR else "below"
    return "within"


def nees_cell(mean: float | None, bounds, digits: int = 3) -> str:
    """A table cell of a mean NEES, marked when far outside its bounds (:func:`nees_flag`)."""
    flag = nees_flag(mean, bounds)
    return fmt(mean, digits) + (f" ({flag}!)" if flag is not None and flag.startswith("far") else "")
def distribution(x: np.ndarray) -> dict:
    """``mean``, ``p5`` and ``p95`` of the finite values of a per-trial metric (all None when none is finite: a
    failed trial is NaN)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"mean": None, "p5": None, "p95": None}
    return {"mean": float(x.mean()), "p5": float(np.percentile(x, 5)), "p95": float(np.percentile(x, 95))}


def pooled_rms(x: np.ndarray) -> float:
    """sqrt(mean(x^2)) over the trials: for per-trial rms over windows of the same length, the rms pooled over the
    trials and the steps (ukfm's figure)."""
    return float(np.sqrt(np.mean(np.square(x))))


def scoring(scored: np.ndarray, ends_s: float, movement_s: float | None) -> dict:
    """How much of a BROAD trial's slice is scored, as a result entry's keys: ``scored_samples`` (the samples
    the mask ``scored`` marks), the slice's end ``ends_s`` and the start of the whole trial's movement
    ``movement_s`` (:meth:`~liemef.studies.datasets.BroadTrial.movement_start`), both from the first sample. A
    slice with no scored sample has no figures (``-``); :func:`unscored` says why."""
    return {"scored_samples": int(np.count_nonzero(scored)), "ends_s": float(ends_s), "movement_s": movement_s}


def unscored(tid: str, per: Mapping) -> str | None:
    """Why trial ``tid`` (its result entry ``per``, with :func:`scoring`'s keys) has no figures, or None where a
    sample is scored (or the entry predates the count)."""
    if per.get("scored_samples", 1):
        return None
    moves = per.get("movement_s")
    where = (f"its {per['ends_s']:.1f} s end before BROAD's movement starts at {moves:.1f} s"
             if moves is not None and moves > per["ends_s"]
             else "BROAD's movement mask holds no sample of it where the optical truth is present")
    return f"trial {tid}: no sample is scored ({where}); its figures are '-'"


def unscored_lines(trials: Mapping[str, Mapping]) -> list[str]:
    """A report's paragraph naming the trials with no scored sample (:func:`unscored`), or nothing."""
    why = [w for t, per in trials.items() if (w := unscored(t, per)) is not None]
    return [f"**Not scored.** {'; '.join(why)}. Run past the movement's start (--set seconds) to score them.", ""] \
        if why else []


def fmt(v, digits: int = 4) -> str:
    """A table cell: ``-`` for None or NaN."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, int | np.integer):
        return str(int(v))
    return f"{v:.{digits}g}"


def winners_markdown(rows: Mapping[str, dict], units: Mapping[str, str]) -> list[str]:
    """Lines of a table: per metric, the winner, its lead over the runner-up (paired mean difference and 95 %
    interval) and the filters level with it."""
    lines = ["| metric | winner | mean | runner-up | lead (95 % interval) | outside the spread? | "
             "level with the winner |", "|---|---|---:|---|---:|---|---|"]
    unranked = {}
    for metric, cmp in rows.items():
        unranked.update(cmp.get("unranked", {}))
        w = cmp["winner"]
        if w is None:
            lines.append(f"| {metric} | - | - | - | - | - | - |")
            continue
        others = {k: v for k, v in cmp["versus"].items() if v["diff"] is not None and k not in cmp.get("unranked", {})}
        if others:
            r = min(others, key=lambda k: others[k]["diff"])
            v = others[r]
            lead = f"{fmt(v['diff'], 3)} ({fmt(v['ci'][0], 3)} to {fmt(v['ci'][1], 3)}) {units.get(metric, '')}"
            sig = "yes" if v["significant"] else "no"
        else:
            r, lead, sig = "-", "-", "-"
        level = ", ".join(k for k in cmp["level"] if k != w) or "none"
        apart = [f"{k} (n = {v['n']})" for k, v in cmp["versus"].items()
                 if v["diff"] is None and k not in cmp.get("unranked", {})]
        if apart:
            level += "; not comparable: " + ", ".join(apart)
        lines.append(f"| {metric} | {w} | {fmt(cmp['means'][w])} | {r} | {lead} | {sig} | {level} |")
    if unranked:
        lines += ["", "Not ranked (a filter that failed on a trial, or whose K does not describe its error, cannot "
                  "win): " + "; ".join(f"{k}: {why}" for k, why in unranked.items()) + "."]
    return lines
