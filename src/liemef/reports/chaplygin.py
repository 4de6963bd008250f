r"""The Chaplygin sleigh reproduction written out: Rigo et al. 2023, Tables 1-2 side by side with a Monte Carlo
(Markdown and CSV), and Figs. 3-6 from saved arrays.

The study (:mod:`liemef.studies.experiments.chaplygin`) runs the Monte Carlos and turns each into table cells
(:class:`Entry`: one printed statistic of one error against the Monte Carlo distribution); this module lays the
cells out as the paper does (one table per Ts, rows by sensor set, connection and error, columns mean, std and
rms) and draws the figures. Units: mrad, mm, mrad/s, mm/s (:data:`TABLE_UNITS`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..metrics._stats import STATS
from ..systems.chaplygin import CONNECTIONS, SENSORS, STATE_NAMES
from . import figures, io

LABEL = {"zero": "(0)", "minus": "(-)", "gps_ins": "GPS + INS", "gps": "GPS"}
"""How the tables and figures name the connections and sensor sets."""
TABLE_UNITS = ("mrad", "mm", "mm", "mrad/s", "mm/s")
"""The unit of each error (:data:`~liemef.systems.chaplygin.STATE_NAMES`) in the tables."""
GREEK = {"theta": "θ", "omega": "ω", "x": "x", "y": "y", "v": "v"}
FIGURES = {(0.01, "gps_ins"): "Fig. 3", (0.01, "gps"): "Fig. 4", (0.001, "gps_ins"): "Fig. 5",
           (0.001, "gps"): "Fig. 6"}
"""The paper's figure of each (Ts, sensor)."""
CSV_HEADER = ("choice", "Ts_s", "sensor", "connection", "error", "unit", "stat", "mc_mean", "mc_spread", "p5",
              "p50", "p95", "paper", "paper_percentile", "paper_inside_5_95", "runs", "nonfinite")
"""The columns of ``tables.csv`` (:func:`csv_rows`)."""


@dataclass(frozen=True)
class Entry:
    """One cell of Tables 1-2 against the Monte Carlo: per-trial statistic ``stat`` of error ``component``
    (scaled to mrad, mm, mrad/s, mm/s) across the finite trials of one configuration."""

    dt: float
    sensor: str
    connection: str
    component: str
    stat: str
    mc_mean: float
    mc_spread: float
    p5: float
    p50: float
    p95: float
    paper: float | None
    percentile: float | None

    @property
    def inside(self) -> bool | None:
        """Whether the paper's value lies in the 5-95 % band of the Monte Carlo (None if not printed)."""
        return None if self.paper is None else bool(self.p5 <= self.paper <= self.p95)


def band_fraction(es: list[Entry], stats=("std", "rms")) -> tuple[int, int]:
    """(inside, total): how many printed ``stats`` entries lie in the 5-95 % Monte Carlo band."""
    sel = [e for e in es if e.stat in stats and e.paper is not None and e.inside is not None]
    return sum(e.inside for e in sel), len(sel)


def _f(x: float | None, nd: int = 1) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


def ms(dt: float) -> str:
    """A step in ms: ``"10 ms"``."""
    return f"{1e3 * dt:g} ms"


def _table_number(dt: float) -> str:
    return {0.01: "Table 1", 0.001: "Table 2"}.get(round(dt, 9), "(no printed table)")


def slug(text: str) -> str:
    """``text`` as a file name: runs of anything but letters and digits become one ``_``."""
    return "_".join("".join(ch if ch.isalnum() else " " for ch in text).split())


# --- tables ------------------------------------------------------------------------------------------------
def tables_markdown(es: list[Entry], runs: dict, heading: str = "") -> str:
    """Tables 1-2 side by side with the paper: one table per Ts, one row per (sensor, connection, error);
    per statistic the Monte Carlo mean +- seed-to-seed spread [5 %, 95 %] and the paper's value with its
    percentile in the Monte Carlo (``*``: outside the 5-95 % band)."""
    lines = [heading] if heading else []
    for dt in sorted({e.dt for e in es}, reverse=True):
        sel = [e for e in es if e.dt == dt]
        k, n = band_fraction(sel)
        lines += [f"## {_table_number(dt)}: Ts = {ms(dt)}", "",
                  f"Paper's std and rms entries inside the 5-95 % Monte Carlo band: **{k} of {n}**.", "",
                  "| sensor | connection | error | unit | " + " | ".join(
                      f"{s}: MC mean ± spread [p5, p95] | {s}: paper (pct)" for s in STATS) + " |",
                  "|---|---|---|---|" + "---:|" * 6]
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                rows = {(e.component, e.stat): e for e in sel if e.sensor == sensor and e.connection == conn}
                if not rows:
                    continue
                r = runs.get((dt, sensor, conn), {})
                tag = f"{LABEL[sensor]} | {LABEL[conn]}" + (f" ({r['nonfinite']} of {r['runs']} diverged)"
                                                            if r.get("nonfinite") else "")
                for comp, unit in zip(STATE_NAMES, TABLE_UNITS, strict=True):
                    cells = []
                    for stat in STATS:
                        e = rows[(comp, stat)]
                        cells.append(f"{_f(e.mc_mean)} ± {_f(e.mc_spread)} [{_f(e.p5)}, {_f(e.p95)}]")
                        mark = "" if e.inside in (None, True) else "*"
                        cells.append("-" if e.paper is None else f"{e.paper:.1f} ({_f(e.percentile, 0)} %){mark}")
                    lines.append(f"| {tag} | δ{GREEK[comp]} | {unit} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def velocity_markdown(es: list[Entry]) -> str:
    """The velocity rows (the sharpest check, docs/chaplygin.md): rms of delta omega and delta v, Monte Carlo against
    the paper."""
    lines = ["| Ts | sensor | connection | δω rms MC [mrad/s] | δω rms paper (pct) | δv rms MC [mm/s] | "
             "δv rms paper (pct) |", "|---|---|---|---:|---:|---:|---:|"]
    for dt in sorted({e.dt for e in es}, reverse=True):
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                cells = []
                for comp in ("omega", "v"):
                    e = next((e for e in es if (e.dt, e.sensor, e.connection, e.component, e.stat)
                              == (dt, sensor, conn, comp, "rms")), None)
                    if e is None:
                        break
                    cells += [f"{_f(e.mc_mean)} ± {_f(e.mc_spread)}",
                              "-" if e.paper is None else f"{e.paper:.1f} ({_f(e.percentile, 0)} %)"]
                if len(cells) == 4:
                    lines.append(f"| {ms(dt)} | {LABEL[sensor]} | {LABEL[conn]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def csv_rows(choice: str, es: list[Entry], runs: dict) -> list[tuple]:
    """The rows of ``tables.csv`` (:data:`CSV_HEADER`) of one simulation choice."""
    unit = dict(zip(STATE_NAMES, TABLE_UNITS, strict=True))
    rows = []
    for e in es:
        r = runs.get((e.dt, e.sensor, e.connection), {})
        rows.append((choice, e.dt, e.sensor, e.connection, e.component, unit[e.component], e.stat, e.mc_mean,
                     e.mc_spread, e.p5, e.p50, e.p95, "" if e.paper is None else e.paper,
                     "" if e.percentile is None else e.percentile, "" if e.inside is None else e.inside,
                     r.get("runs", ""), r.get("nonfinite", "")))
    return rows


def alternatives_markdown(results: dict[str, tuple[list[Entry], dict]]) -> str:
    """One row per (choice, Ts, sensor, connection): velocity and pose rms against the paper, diverged trials,
    and the fraction of the printed std/rms entries in the 5-95 % band."""
    lines = ["| choice | Ts | sensor | connection | diverged | δθ rms [mrad] | δx rms [mm] | δy rms [mm] | "
             "δω rms [mrad/s] | δv rms [mm/s] | std/rms in 5-95 % band |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for choice, (es, runs) in results.items():
        for dt in sorted({e.dt for e in es}, reverse=True):
            for sensor in SENSORS:
                for conn in CONNECTIONS:
                    sel = [e for e in es if (e.dt, e.sensor, e.connection) == (dt, sensor, conn)]
                    if not sel:
                        continue
                    rms = {e.component: e for e in sel if e.stat == "rms"}
                    r = runs.get((dt, sensor, conn), {})
                    k, n = band_fraction(sel)
                    cells = [f"{_f(rms[c].mc_mean)} (paper {_f(rms[c].paper)})" for c in STATE_NAMES]
                    lines.append(f"| {choice} | {ms(dt)} | {LABEL[sensor]} | {LABEL[conn]} | "
                                 f"{r.get('nonfinite', 0)} of {r.get('runs', 0)} | " + " | ".join(cells)
                                 + f" | {k} of {n} |")
    return "\n".join(lines)


@dataclass(frozen=True)
class Tables:
    """What :func:`write_tables` wrote: the texts, the files in order and a caption for each table file."""

    markdown: str
    velocity: str
    alternatives: str
    files: tuple[Path, ...]
    captions: tuple[tuple[Path, str], ...]


def write_tables(out: str | os.PathLike, es: list[Entry], info: dict,
                 alternatives: Mapping[str, tuple[list[Entry], dict]], *, runs: int, seed: int, duration: float,
                 main_choice: str) -> Tables:
    """``tables.md`` (Tables 1-2 against the Monte Carlo), ``velocity.md`` (the velocity rows),
    ``alternatives.md`` (if there are ``alternatives``: ``{choice: (entries, run info)}``) and ``tables.csv``
    (every cell of every choice) into the folder ``out``. ``info[(Ts, sensor, connection)]`` holds the
    trials (``runs``) and the diverged ones (``nonfinite``) of each Monte Carlo."""
    out = Path(out)
    k_all, n_all = band_fraction(es)
    size_note = f"{runs} Monte Carlo trials per configuration (seed {seed}); T = {duration:g} s"
    runs_note = f"{size_note}; {main_choice}; the paper's values are single runs"
    heading = (f"# Chaplygin sleigh: Rigo et al. 2023, Tables 1-2 against a Monte Carlo\n\n{runs_note}. Each cell: "
               "the Monte Carlo mean of the per-trial statistic ± its seed-to-seed spread (std across trials) "
               "[5 %, 95 % percentiles]; the paper's value with its percentile in the Monte Carlo (* outside the "
               "5-95 % band). Units: mrad, mm, mrad/s, mm/s (the velocity rows are printed 'mm/rad' in the paper)."
               f"\n\nAll Ts: **{k_all} of {n_all}** printed std/rms entries inside the 5-95 % band.\n")
    md = tables_markdown(es, info, heading)
    vel = ("# Velocity rows of Tables 1-2 (rms)\n\n" + runs_note + ".\n\n" + velocity_markdown(es) + "\n")
    rows = csv_rows("main", es, info)
    files = [io.write_text(out / "tables.md", md), io.write_text(out / "velocity.md", vel)]
    captions = [(out / "tables.md", "Tables 1-2 side by side with the paper"),
                (out / "velocity.md", "Velocity rows (rms) against the paper")]
    alt_text = ""
    if alternatives:
        for name, (a_es, a_info) in alternatives.items():
            rows += csv_rows(name, a_es, a_info)
        alt_text = ("# Alternative simulation choices against Tables 1-2\n\n" + size_note
                    + f"; the paper's values are single runs. Main choice: {main_choice}; each alternative changes "
                    "one of them. Cells: Monte Carlo "
                    "mean of the per-trial rms (the paper's value).\n\n"
                    + alternatives_markdown({f"main ({main_choice})": (es, info), **alternatives}) + "\n")
        files.append(io.write_text(out / "alternatives.md", alt_text))
        captions.append((out / "alternatives.md", "Alternative simulation choices (weights, model error)"))
    files.append(io.write_rows(out / "tables.csv", CSV_HEADER, rows))
    captions.append((out / "tables.csv", "Tables 1-2 and alternatives (CSV)"))
    return Tables(markdown=md, velocity=vel, alternatives=alt_text, files=tuple(files), captions=tuple(captions))


# --- figures -----------------------------------------------------------------------------------------------
def figure(arrays) -> object:
    """Figs. 3-6 of Rigo et al. 2023 from saved arrays
    (:func:`liemef.studies.experiments.chaplygin.figure_arrays`), drawn by
    :func:`liemef.reports.figures.chaplygin_figure` with the paper's connections, labels and figure numbers."""
    return figures.chaplygin_figure(arrays, connections=CONNECTIONS, label=LABEL, paper_figures=FIGURES, ms=ms)


def figure_stem(dt: float, sensor: str) -> str:
    """The file stem of the figure of (Ts, sensor): ``fig3_gps_ins_10ms``."""
    fig = FIGURES.get((round(dt, 9), sensor), "fig")
    return f"{fig.lower().replace('. ', '').replace(' ', '')}_{sensor}_{1e3 * dt:g}ms"


def figure_caption(dt: float, sensor: str, trial: int) -> str:
    """The caption of the figure of (Ts, sensor) drawn from Monte Carlo trial ``trial``."""
    return (f"{FIGURES.get((round(dt, 9), sensor), 'cf. Figs. 3-6')}: {LABEL[sensor]}, Ts = {ms(dt)}, "
            f"both connections on the data of Monte Carlo trial {trial}")
