"""Writing an experiment's reproduction to a folder, and ``reproduce all`` with its Markdown index.

:func:`reproduce_experiment` writes one experiment's folder: its own ``reproduce_fn``, or
:func:`default_reproduce`; :func:`reproduce_all` runs every registered experiment
into one folder each and writes ``index.md`` (:func:`write_index`). Figures are drawn from the saved files
by :mod:`liemef.reports.plots`, imported only when a reproduction is written.
"""

from __future__ import annotations

import dataclasses
import os
import time
import traceback
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from ... import __version__
from ...metrics import ErrorTable
from ...metrics._stats import format_number
from ...reports import io
from ._base import EXPERIMENTS, Experiment, Output, Reproduction
from ._montecarlo import montecarlo

INDEX_FILE = "index.md"
ERRORS_MD, ERRORS_CSV = "errors.md", "errors.csv"
MONTECARLO_STEM = "montecarlo"


def error_table_markdown(table: ErrorTable) -> str:
    """An :class:`~liemef.metrics.ErrorTable` as Markdown: one row per component, mean/std/rms per window."""
    head = ["component", "unit"] + [f"{k} ({w.label})" for w in table.windows for k in ("mean", "std", "rms")]
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for c, (name, unit) in enumerate(zip(table.names, table.units, strict=True)):
        vals = [getattr(table, k)[w, c] for w in range(len(table.windows)) for k in ("mean", "std", "rms")]
        lines.append("| " + " | ".join([name, unit, *map(format_number, vals)]) + " |")
    return "\n".join(lines) + "\n"


def write_error_table(out: Path, table: ErrorTable, heading: str) -> list[Path]:
    """``errors.md`` (``heading`` + :func:`error_table_markdown`) and ``errors.csv`` (one row per window and
    component) into ``out``."""
    windows = ", ".join(f"{w.label}: {n} samples" for w, n in zip(table.windows, table.counts, strict=True))
    md = f"{heading}\n\nErrors truth - estimate (angles wrapped); windows {windows}.\n\n" + \
        error_table_markdown(table)
    rows = [(w.label, name, unit, float(table.mean[i, c]), float(table.std[i, c]), float(table.rms[i, c]))
            for i, w in enumerate(table.windows) for c, (name, unit) in enumerate(zip(table.names, table.units,
                                                                                        strict=True))]
    return [io.write_text(out / ERRORS_MD, md),
            io.write_rows(out / ERRORS_CSV, ("window", "component", "unit", "mean", "std", "rms"), rows)]


def _config_line(config: Any) -> str:
    parts = []
    for key, fmt in (("seed", "seed {}"), ("duration", "T = {:g} s"), ("dt", "dt = {:g} s"),
                     ("connection", "connection {}"), ("order", "order {}")):
        if hasattr(config, key):
            parts.append(fmt.format(getattr(config, key)))
    return ", ".join(parts)


def reproduce_experiment(experiment: Experiment, out: str | os.PathLike, config: Any | None = None,
                         runs: int | None = None, progress: bool = True) -> Reproduction:
    """Write ``experiment``'s reproduction into the folder ``out`` (created if missing): its ``reproduce_fn``
    or :func:`default_reproduce`. ``config=None``: the default config; ``runs=None``: ``experiment.runs`` Monte
    Carlo trials."""
    runs = experiment.runs if runs is None else runs
    if not isinstance(runs, int) or isinstance(runs, bool) or runs < 0:
        raise ValueError(f"runs: expected an integer >= 0, got {runs!r}")
    config = experiment.default_config if config is None else config
    d = io.ensure_dir(out)
    if experiment.reproduce_fn is not None:
        return experiment.reproduce_fn(config, d, runs, progress)
    return default_reproduce(experiment, config, d, runs, progress)


def default_reproduce(experiment: Experiment, config: Any, out: Path, runs: int = 0,
                      progress: bool = True) -> Reproduction:
    """One seeded run written to ``out`` (``metrics.json``, ``arrays.npz``, the figures, ``errors.md``,
    ``errors.csv``) and, when ``runs > 0`` and the experiment has a ``trial_fn``, a Monte Carlo of ``runs``
    trials seeded with ``config.seed`` (``montecarlo.{npz,json,md,csv}``)."""
    from ...reports import plots

    out = io.ensure_dir(out)
    t0 = time.perf_counter()
    result = experiment.run(config)
    elapsed = time.perf_counter() - t0
    files = io.write_result(out, result.metrics, result.arrays)
    figs = plots.write_figures(out)
    captions = {f.filename: f.paper_figure or f.title for f in experiment.figures}
    figures = [Output(p, captions.get(p.name, "")) for p in figs]
    tables = write_error_table(out, result.table, f"# {experiment.name}: {experiment.title}\n\n"
                                                  f"{experiment.paper}; {_config_line(config)}.")
    text = [f"{experiment.name}: {experiment.title}",
            f"  {experiment.paper}; {_config_line(config)} ({elapsed:.1f} s)",
            "Errors truth - estimate (angles wrapped):", result.table.format()]
    gain = result.metrics.get("gain", {})
    if gain:
        text.append(f"Gain K: max |K - K'|/|K| = {gain['max_rel_asymmetry']:.2e}, "
                    f"min eigenvalue = {gain['min_eigenvalue']:.3e}")
    warnings = []
    if not result.metrics.get("run", {}).get("finite", True):
        warnings.append("WARNING: the filter produced non-finite values (diverged)")
    summary: dict = {"runs": 0, "finite": result.metrics.get("run", {}).get("finite", True)}
    table_outputs = [Output(tables[0], "Errors of the seeded run"), Output(tables[1], "Errors (CSV)")]
    all_files = [*files, *figs, *tables]
    if runs > 0 and experiment.trial_fn is None:
        warnings.append(f"WARNING: {experiment.name} has no trial_fn: no Monte Carlo (runs = {runs} ignored)")
    if runs > 0 and experiment.trial_fn is not None:
        mc = montecarlo(experiment, config, runs, seed=int(getattr(config, "seed", 0)), progress=progress)
        written = mc.save(out, MONTECARLO_STEM)
        all_files += written
        table_outputs += [Output(out / f"{MONTECARLO_STEM}.md", f"Monte Carlo over {runs} seeds"),
                          Output(out / f"{MONTECARLO_STEM}.csv", "Monte Carlo (CSV)")]
        text += ["", mc.format(), f"{mc.runs} trials in {mc.elapsed:.1f} s"]
        summary.update(runs=mc.runs, nonfinite=mc.n_nonfinite)
        if mc.n_nonfinite:
            warnings.append(f"WARNING: {mc.n_nonfinite} of {mc.runs} Monte Carlo trials were non-finite "
                            f"(diverged) and are left out of the statistics")
    text.append(f"Wrote {', '.join(p.name for p in all_files)} to {out}")
    return Reproduction(experiment=experiment.name, out=out, figures=tuple(figures), tables=tuple(table_outputs),
                        files=tuple(all_files), text="\n".join(text), warnings=tuple(warnings), summary=summary)


@dataclasses.dataclass(frozen=True)
class Failure:
    """An experiment of ``reproduce all`` that raised: its name, folder and the error."""

    experiment: str
    out: Path
    error: str
    detail: str = ""


def listing() -> str:
    """Every registered experiment with its paper, figures, tables and Monte Carlo (``reproduce --list``)."""
    lines = []
    for e in EXPERIMENTS.values():
        lines += [f"{e.name}: {e.title}", f"    paper:   {e.paper}"]
        if e.figures:
            lines.append("    figures: " + "; ".join(f"{f.filename}" + (f" ({f.paper_figure})" if f.paper_figure
                                                                          else "") for f in e.figures))
        if e.tables:
            lines.append("    tables:  " + "; ".join(e.tables))
        mc = f"yes (liemef montecarlo {e.name} --runs N)" if e.trial_fn is not None else "no"
        lines.append(f"    Monte Carlo: {mc}; reproduce runs {e.runs} trial(s) by default, {e.quick_runs} with "
                     "--quick")
    return "\n".join(lines)


def config_changes(config: Any, reference: Any) -> dict[str, tuple[Any, Any]]:
    """``{field: (value, reference value)}`` for the config fields that differ from ``reference``."""
    try:
        a, b = dataclasses.asdict(config), dataclasses.asdict(reference)
    except TypeError:
        return {}
    return {k: (v, b.get(k)) for k, v in a.items() if b.get(k) != v and k != "seed"}


def reproduce_all(out: str | os.PathLike, quick: bool = True, progress: bool = True,
                  experiments: Iterable[str] | None = None, runs: int | None = None,
                  echo: Callable[[str], None] | None = None) -> list[Reproduction | Failure]:
    """Every registered experiment (or ``experiments``), one subfolder of ``out`` each, then ``index.md``.

    ``quick``: each experiment at its reduced size (``quick_config``, ``quick_runs``); else its full size
    (``default_config``, ``runs``). ``runs`` overrides every experiment's number of Monte Carlo trials. An
    experiment that raises is recorded as a :class:`Failure` and the others still run. ``echo(text)``
    receives each reproduction's text as it finishes.
    """
    d = io.ensure_dir(out)
    names = list(EXPERIMENTS) if experiments is None else list(experiments)
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        raise ValueError(f"experiments: expected names among {sorted(EXPERIMENTS)}, got {unknown}")
    done: list[Reproduction | Failure] = []
    sizes: dict[str, str] = {}
    for name in names:
        exp = EXPERIMENTS[name]
        config = exp.quick() if quick else exp.default_config
        n = (exp.quick_runs if quick else exp.runs) if runs is None else runs
        changes = config_changes(config, exp.default_config)
        sizes[name] = ", ".join([f"{k} = {v} (default: {ref})" for k, (v, ref) in changes.items()]
                                + [f"{n} Monte Carlo trials" if n else "one seeded run"])
        sub = d / name
        try:
            rep = reproduce_experiment(exp, sub, config, runs=n, progress=progress)
        except Exception as err:  # one failure must not stop the others; it is reported
            rep = Failure(name, sub, f"{type(err).__name__}: {err}", traceback.format_exc())
        done.append(rep)
        if echo is not None:
            echo(rep.text if isinstance(rep, Reproduction) else f"{name}: FAILED ({rep.error})")
    write_index(d, done, sizes, quick)
    return done


def _rel(path: Path, root: Path) -> str:
    try:
        return Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        return Path(path).as_posix()


def write_index(out: Path, reproductions: list[Reproduction | Failure], sizes: dict[str, str] | None = None,
                quick: bool = True) -> Path:
    """``out/index.md``: a summary table, then per experiment its paper, size, tables (links) and figures
    (embedded images), with paths relative to ``out``."""
    sizes = sizes or {}
    flag, size = ("--quick", "reduced sizes for a laptop") if quick else ("--full", "the experiments' full sizes")
    lines = ["# liemef: reproductions of the papers' experiments", "",
             f"Written by `liemef reproduce all {flag}` (liemef {__version__}) at {size}, one folder per "
             "experiment. The papers report single noisy runs: where an experiment runs a Monte Carlo, its "
             "tables give the distribution over seeds.", "",
             "| experiment | paper | size | status |", "|---|---|---|---|"]
    for rep in reproductions:
        exp = EXPERIMENTS.get(rep.experiment)
        paper = exp.paper if exp else ""
        status = "ok" if isinstance(rep, Reproduction) and not rep.warnings else \
            ("FAILED" if isinstance(rep, Failure) else "warnings")
        lines.append(f"| [{rep.experiment}](#{rep.experiment}) | {paper} | {sizes.get(rep.experiment, '')} | "
                     f"{status} |")
    for rep in reproductions:
        exp = EXPERIMENTS.get(rep.experiment)
        lines += ["", f'<a id="{rep.experiment}"></a>', "",
                  f"## {rep.experiment}" + (f": {exp.title}" if exp else ""), ""]
        if exp:
            lines.append(f"Paper: {exp.paper}.  ")
        if rep.experiment in sizes:
            lines.append(f"Size: {sizes[rep.experiment]}.  ")
        lines.append(f"Folder: [{_rel(rep.out, out)}/]({_rel(rep.out, out)}/)")
        if isinstance(rep, Failure):
            lines += ["", f"**Failed**: `{rep.error}`"]
            continue
        for w in rep.warnings:
            lines += ["", f"**{w}**"]
        if rep.tables:
            lines += ["", "Tables:", ""]
            lines += [f"- [{t.path.name}]({_rel(t.path, out)})" + (f": {t.caption}" if t.caption else "")
                      for t in rep.tables]
        if rep.figures:
            lines += ["", "Figures:", ""]
            for f in rep.figures:
                cap = f.caption or f.path.name
                lines += [f"- [{f.path.name}]({_rel(f.path, out)}): {cap}", "",
                          f"  ![{cap}]({_rel(f.path, out)})", ""]
    return io.write_text(out / INDEX_FILE, "\n".join(lines).rstrip() + "\n")
