r"""A Monte Carlo result written out: its plain-text and Markdown tables, its CSV rows, and its ``<stem>.npz`` +
``<stem>.json`` files read back.

The result is computed in :mod:`liemef.studies.experiments` (:class:`~liemef.studies.experiments.MonteCarloResult`:
per-trial statistics, and across trials their mean, spread and percentiles); its methods ``format``,
``to_markdown``, ``table_rows``, ``write_tables``, ``to_dict``, ``save`` and ``load`` call the functions here.
They read the result through its attributes only, so this layer knows nothing of the study that made it.

Artefacts, one schema each: ``<stem>.json`` (:data:`SCHEMA`, the layout of :func:`to_dict`), ``<stem>.npz`` (the
per-trial arrays, :data:`NPZ_KEYS`), ``<stem>.md`` and ``<stem>.csv`` (:data:`TABLE_HEADER`, one row per window,
component and statistic).
"""

from __future__ import annotations

import collections
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..filters import CAUSES
from ..metrics import Window
from ..metrics._stats import PERCENTILES, STATS, format_number, json_number
from . import io

SCHEMA = "liemef.montecarlo/1"
"""Version tag of the ``<stem>.json`` layout (:func:`to_dict`)."""
TABLE_HEADER = ("window", "component", "unit", "stat", "mean", "spread", *(f"p{p}" for p in PERCENTILES))
"""The columns of ``<stem>.csv`` (:func:`table_rows`)."""
NPZ_KEYS = ("stats", "finite", "causes", "names", "units", "stat_names", "window_start", "window_stop", "counts")
"""The arrays of ``<stem>.npz`` (besides ``keys`` and, with ``keep_every``, ``series`` and ``series_ts``)."""


def trial_list(idx: np.ndarray, limit: int = 10) -> str:
    """``"3, 7, 12"``, cut after ``limit`` items: ``"..., (40 in all)"``."""
    items = [str(int(i)) for i in idx[:limit]]
    return ", ".join(items) + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")


# --- tables ------------------------------------------------------------------------------------------------
def table_rows(result) -> list[tuple]:
    """One row per (window, component, statistic): the names, then mean, spread and percentiles across trials
    (:data:`TABLE_HEADER`); None (an empty CSV cell) where a value does not exist, as JSON's null and the
    Markdown's ``-`` (the spread of one trial)."""
    mean, spread, pct = result.mean, result.spread, result.percentiles
    rows = []
    for w, label in enumerate(result.window_labels):
        for c, (name, unit) in enumerate(zip(result.names, result.units, strict=True)):
            for k, stat in enumerate(STATS):
                rows.append((label, name, unit, stat, json_number(mean[w, c, k]), json_number(spread[w, c, k]),
                             *(json_number(v) for v in pct[:, w, c, k])))
    return rows


def heading(result) -> str:
    """``"Monte Carlo of tse2: 100 trials (seed 0), all finite"`` (or the diverged trials, left out)."""
    word = "non-finite" if set(result.diverged()) <= {CAUSES.NONFINITE.value} else "diverged"
    bad = f", {result.n_nonfinite} {word} (left out: trials {trial_list(result.nonfinite_trials)})" \
        if result.n_nonfinite else ", all finite"
    return f"Monte Carlo of {result.experiment}: {result.runs} trials (seed {result.seed}){bad}"


def _window_heading(result, w: int) -> str:
    return f"window {result.window_labels[w]} ({result.counts[w]} samples)"


def format_text(result) -> str:
    """A plain-text table, one block per window: per component and statistic over time, its mean and spread
    across trials and its percentiles."""
    head = ["component", "unit", "stat", "mean", "spread", *(f"p{p}" for p in PERCENTILES)]
    lines = [heading(result), *([result.divergence_summary()] if result.n_nonfinite else []),
             "Per trial over time: mean, std, rms of each error; across trials: mean, spread (std), "
             "percentiles."]
    by_window = collections.defaultdict(list)
    for r in table_rows(result):
        by_window[r[0]].append(r)
    for w, label in enumerate(result.window_labels):
        if result.counts[w] == 0:
            lines += ["", f"{_window_heading(result, w)}: no statistics"]
            continue
        rows = [head]
        for i, r in enumerate(by_window[label]):
            first = i % len(STATS) == 0
            rows.append([r[1] if first else "", r[2] if first else "", r[3], *map(format_number, r[4:])])
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        table = ["  ".join(s.ljust(wd) if i < 3 else s.rjust(wd)
                           for i, (s, wd) in enumerate(zip(r, widths, strict=True))) for r in rows]
        table.insert(1, "-" * len(table[0]))
        lines += ["", _window_heading(result, w), *table]
    return "\n".join(lines)


def to_markdown(result) -> str:
    """The table as Markdown: a heading, the config, one table per window."""
    title = f"# Monte Carlo: {result.experiment}" + (f" ({result.title})" if result.title else "")
    cfg = ", ".join(f"{k} = {v}" for k, v in result.config.items() if k != "seed")  # trials: result.seed
    out = [title, ""]
    if result.paper:
        out += [f"Paper: {result.paper}.", ""]
    out += [f"{heading(result)}; {result.batch_size} trials per compiled batch, {result.elapsed:.1f} s.", "",
            *([f"{result.divergence_summary().capitalize()}.", ""] if result.n_nonfinite else []),
            f"Config: {cfg}.", "",
            "Per trial, over time: mean, std and rms of each error component; across trials: their mean, "
            "spread (std, ddof = 1) and percentiles.", ""]
    head = ["component", "unit", "stat", "mean", "spread", *(f"p{p}" for p in PERCENTILES)]
    for w, label in enumerate(result.window_labels):
        if result.counts[w] == 0:
            out += [f"## {_window_heading(result, w).capitalize()}", "", "No statistics.", ""]
            continue
        out += [f"## {_window_heading(result, w).capitalize()}", "",
                "| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 3 + ["---:"] * (len(head) - 3)) + "|"]
        out += ["| " + " | ".join([*r[1:4], *map(format_number, r[4:])]) + " |"
                for r in table_rows(result) if r[0] == label]
        out.append("")
    return "\n".join(out)


def write_tables(result, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
    """``<stem>.md`` and ``<stem>.csv`` (full precision, one row per window, component and statistic) into the
    folder ``out``."""
    d = io.ensure_dir(out)
    return [io.write_text(d / f"{stem}.md", to_markdown(result)),
            io.write_rows(d / f"{stem}.csv", TABLE_HEADER, table_rows(result))]


# --- files -------------------------------------------------------------------------------------------------
def to_dict(result) -> dict:
    """Metadata and the statistics across trials, JSON-ready (NaN -> None): the ``<stem>.json`` layout
    (:data:`SCHEMA`)."""
    mean, spread, pct = result.mean, result.spread, result.percentiles
    summary: dict = {}
    for w, label in enumerate(result.window_labels):
        comps = {}
        for c, (name, unit) in enumerate(zip(result.names, result.units, strict=True)):
            entry: dict = {"unit": unit}
            for k, stat in enumerate(STATS):
                entry[stat] = {"mean": json_number(mean[w, c, k]), "spread": json_number(spread[w, c, k]),
                               **{f"p{p}": json_number(pct[i, w, c, k]) for i, p in enumerate(PERCENTILES)}}
            comps[name] = entry
        summary[label] = comps
    return {
        "schema": SCHEMA,
        "experiment": {"name": result.experiment, "title": result.title, "paper": result.paper},
        "config": result.config,
        "seed": result.seed,
        "runs": result.runs,
        "keys": f"trial i uses jax.random.split(jax.random.key({result.seed}), {result.runs})[i]",
        "nonfinite": {"count": result.n_nonfinite, "trials": [int(i) for i in result.nonfinite_trials]},
        "diverged": {"count": result.n_nonfinite, "by_cause": result.diverged(),
                     "trials": {CAUSES[c].value: [int(i) for i in np.flatnonzero(result.causes == c)]
                                for c in sorted(set(result.causes.tolist()) - {CAUSES.OK.code})},
                     "definition": "a trial diverged when its filter status failed (its cause) or its "
                                   "errors are not all finite (non-finite); diverged trials are left out "
                                   "of the statistics"},
        "windows": {w.label: {"start": w.start, "stop": w.stop, "samples": n}
                    for w, n in zip(result.windows, result.counts, strict=True)},
        "definition": {"per_trial": "mean, std (population) and rms over the samples of the window of each "
                                    "error component (liemef.metrics.error_stats)",
                       "across_trials": "over the finite trials: mean, spread = std with ddof = 1, "
                                        "percentiles with linear interpolation (numpy.percentile)"},
        "statistics": summary,
        "run": {"elapsed_s": json_number(result.elapsed), "batch_size": result.batch_size,
                "liemef_version": __version__},
    }


def save(result, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
    """``<stem>.npz`` (per-trial arrays), ``<stem>.json`` (:func:`to_dict`) and the tables (:func:`write_tables`)
    into the folder ``out`` (created if missing); each written atomically."""
    d = io.ensure_dir(out)
    nan = lambda v: np.nan if v is None else v  # noqa: E731
    arrays = {"stats": result.stats, "finite": result.finite, "causes": result.causes,
              "names": np.array(result.names, dtype=str),
              "units": np.array(result.units, dtype=str), "stat_names": np.array(STATS),
              "window_start": np.array([nan(w.start) for w in result.windows], dtype=np.float64),
              "window_stop": np.array([nan(w.stop) for w in result.windows], dtype=np.float64),
              "counts": np.array(result.counts, dtype=np.int64)}
    if result.keys is not None:
        arrays["keys"] = result.keys
    if result.series is not None:
        arrays["series"], arrays["series_ts"] = result.series, result.series_ts
    return [io.write_npz(d / f"{stem}.npz", arrays), io.write_json(d / f"{stem}.json", to_dict(result)),
            *write_tables(result, d, stem)]


def read(out: str | os.PathLike, stem: str = "montecarlo") -> dict[str, Any]:
    """The fields of a result saved by :func:`save` in the folder ``out``, as keyword arguments of
    :class:`~liemef.studies.experiments.MonteCarloResult` (ValueError unless its JSON has :data:`SCHEMA`)."""
    d = Path(out)
    a = io.read_arrays(d / f"{stem}.npz")
    meta = io.read_json(d / f"{stem}.json", "montecarlo")
    if meta.get("schema") != SCHEMA:
        raise ValueError(f"montecarlo: expected schema {SCHEMA!r} in {str(d / f'{stem}.json')!r}, "
                         f"got {meta.get('schema')!r}")
    opt = lambda v: None if math.isnan(v) else float(v)  # noqa: E731
    windows = tuple(Window(opt(s), opt(e)) for s, e in zip(a["window_start"], a["window_stop"], strict=True))
    run = meta.get("run", {})
    return dict(experiment=meta["experiment"]["name"], title=meta["experiment"].get("title", ""),
                paper=meta["experiment"].get("paper", ""), config=meta["config"], seed=int(meta["seed"]),
                names=tuple(a["names"]), units=tuple(a["units"]), windows=windows, counts=tuple(a["counts"]),
                stats=a["stats"], finite=a["finite"], keys=a.get("keys"), causes=a.get("causes"),
                series=a.get("series"), series_ts=a.get("series_ts"),
                elapsed=math.nan if run.get("elapsed_s") is None else run["elapsed_s"],
                batch_size=int(run.get("batch_size", 0)))
