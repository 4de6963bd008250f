r"""The reproduction of Rigo et al. 2023, Tables 1-2 and Figs. 3-6: a Monte Carlo per (Ts, sensor set,
connection), its cells against the printed values (:func:`entries`), the representative trial the figures are
drawn from, and :func:`reproduce`, which writes them all through :mod:`liemef.reports.chaplygin`.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from ....reports import chaplygin as report
from ....reports import io
from ....reports.chaplygin import LABEL, Entry, band_fraction, ms, slug
from ....reports.progress import ProgressLine
from ....systems.chaplygin import CONNECTIONS, SENSORS
from .._base import Output, Reproduction, config_dict, get_experiment
from .._mcresult import MonteCarloResult
from .._montecarlo import DEFAULT_BATCH_SIZE, montecarlo
from .._reproduce import default_reproduce
from ._paper import PRINTED_MODEL_ERROR_STD, SCALE, STATS3, ChaplyginConfig, paper_value
from ._trial import run


def entries(mc: MonteCarloResult, dt: float, sensor: str, connection: str) -> list[Entry]:
    """Every (component, statistic) of one Monte Carlo against the printed table."""
    out = []
    pct = mc.percentiles  # (5 percentiles, windows, components, 3)
    for c, comp in enumerate(mc.names):
        for k, stat in enumerate(STATS3):
            paper = paper_value(dt, sensor, connection, comp, stat)
            where = None if paper is None or mc.n_finite == 0 else mc.percentile_of(paper / SCALE, comp, 0, stat)
            out.append(Entry(dt=dt, sensor=sensor, connection=connection, component=comp, stat=stat,
                             mc_mean=SCALE * float(mc.mean[0, c, k]), mc_spread=SCALE * float(mc.spread[0, c, k]),
                             p5=SCALE * float(pct[0, 0, c, k]), p50=SCALE * float(pct[2, 0, c, k]),
                             p95=SCALE * float(pct[4, 0, c, k]), paper=paper, percentile=where))
    return out


def representative_trial(mc: MonteCarloResult) -> int:
    """The finite trial whose rms errors are closest to the Monte Carlo medians (sum over the components of
    |log(rms / median)|): the run Figs. 3-6 are drawn from."""
    rms = mc.stats[:, 0, :, 2]
    ok = np.flatnonzero(mc.finite & np.all(rms > 0, axis=1))
    if ok.size == 0:
        return 0
    med = np.median(rms[ok], axis=0)
    return int(ok[np.argmin(np.sum(np.abs(np.log(rms[ok] / med)), axis=1))])


def figure_arrays(config: ChaplyginConfig, key, trial_index: int | None = None) -> dict[str, np.ndarray]:
    """Both connections filtering the same simulated data (``key``): what Figs. 3-6 show."""
    results = {conn: run(dataclasses.replace(config, connection=conn), key) for conn in CONNECTIONS}
    a0 = results["zero"].arrays
    arrays = {k: a0[k] for k in ("ts", "names", "units", "truth", "measured")}
    for conn, res in results.items():
        arrays[f"filtered_{conn}"] = res.arrays["filtered"]
        arrays[f"error_{conn}"] = res.arrays["error"]
        arrays[f"lateral_velocity_{conn}"] = res.arrays["lateral_velocity"]
    arrays["trial"] = np.array(-1 if trial_index is None else trial_index)
    arrays["sensor"], arrays["dt"] = np.array(config.sensor), np.array(config.dt)
    return arrays


def _alternative_configs(config: ChaplyginConfig) -> dict[str, ChaplyginConfig]:
    alts = {}
    if config.weights != "printed":
        alts["printed weights"] = dataclasses.replace(config, weights="printed")
    if config.model_error_std != PRINTED_MODEL_ERROR_STD:
        alts["printed model error"] = dataclasses.replace(config, model_error_std=PRINTED_MODEL_ERROR_STD)
    if config.weights != "unweighted":
        alts["unweighted (Q = D'D)"] = dataclasses.replace(config, weights="unweighted")
    return alts


def _grid(config: ChaplyginConfig, runs: int, progress: bool, out: Path, choice: str,
          batch_size: int) -> tuple[list[Entry], dict, dict]:
    """The four configurations at every Ts of ``config.table_dts``, each a Monte Carlo of ``runs`` trials
    (saved under ``out/montecarlo/``): (entries, {(Ts, sensor, connection): run info}, {...: result})."""
    es, info, results = [], {}, {}
    for dt in config.table_dts:
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                cfg = dataclasses.replace(config, dt=dt, sensor=sensor, connection=conn)
                label = f"{choice}, Ts = {ms(dt)}, {LABEL[sensor]}, {LABEL[conn]}"
                mc = montecarlo(get_experiment("chaplygin"), cfg, runs, seed=config.seed, batch_size=batch_size,
                                progress=ProgressLine(f"chaplygin {label}") if progress else False)
                mc.save(out / "montecarlo", slug(f"{choice}_{1e3 * dt:g}ms_{sensor}_{conn}"))
                es += entries(mc, dt, sensor, conn)
                info[(dt, sensor, conn)] = {"runs": mc.runs, "nonfinite": mc.n_nonfinite,
                                            "elapsed_s": mc.elapsed}
                results[(dt, sensor, conn)] = mc
    return es, info, results



def reproduce(config: ChaplyginConfig, out: Path, runs: int = 100, progress: bool = True,
              batch_size: int = DEFAULT_BATCH_SIZE) -> Reproduction:
    """Tables 1-2 and Figs. 3-6 of Rigo et al. 2023 into the folder ``out`` (the ``reproduce_fn`` of the
    ``chaplygin`` experiment; ``liemef reproduce chaplygin --runs N --out DIR``).

    For each Ts in ``config.table_dts`` (paper: 10 ms and 1 ms), sensor set and connection, a Monte Carlo of
    ``runs`` trials seeded with ``config.seed`` (the other fields of ``config``, e.g. ``weights`` and
    ``model_error_std``, apply to all): ``tables.md``/``tables.csv`` put every entry of Tables 1-2 next to the
    Monte Carlo mean, seed-to-seed spread and 5-95 % band, with the paper's percentile; ``velocity.md`` the
    velocity rows. With ``config.alternatives`` the same grid for the alternative simulation choices (printed
    weights, printed model error, Q = D'D): ``alternatives.md`` and rows in ``tables.csv``. Figs. 3-6: both
    connections on the data of the representative trial of the (0)-connection Monte Carlo
    (:func:`representative_trial`), arrays saved next to the figures and drawn from them. ``runs = 0``: the
    single seeded run of ``config`` only (:func:`~liemef.studies.experiments.default_reproduce`).
    """
    exp = get_experiment("chaplygin")
    if runs == 0:
        return default_reproduce(exp, config, out, 0, progress)
    from ....reports import plots

    out = io.ensure_dir(out)
    t0 = time.perf_counter()
    main_choice = f"weights {config.weights}, model error {config.model_error_std:g}"
    es, info, mcs = _grid(config, runs, progress, out, "main", batch_size)
    alts: dict[str, tuple[list[Entry], dict]] = {}
    if config.alternatives:
        for name, cfg in _alternative_configs(config).items():
            a_es, a_info, _ = _grid(cfg, runs, progress, out, name, batch_size)
            alts[name] = (a_es, a_info)

    # Figs. 3-6 from the representative trial of each (Ts, sensor)
    figures, files = [], []
    for dt in config.table_dts:
        for sensor in SENSORS:
            mc = mcs[(dt, sensor, "zero")]
            i = representative_trial(mc)
            arrays = figure_arrays(dataclasses.replace(config, dt=dt, sensor=sensor), mc.trial_key(i), i)
            stem = report.figure_stem(dt, sensor)
            files.append(io.write_npz(out / f"{stem}.npz", arrays))
            png = plots.save_figure(report.figure(io.read_arrays(out / f"{stem}.npz")), out / f"{stem}.png")
            files.append(png)
            figures.append(Output(png, report.figure_caption(dt, sensor, i)))

    k_all, n_all = band_fraction(es)
    runs_note = (f"{runs} Monte Carlo trials per configuration (seed {config.seed}); T = {config.duration:g} s; "
                 f"{main_choice}; the paper's values are single runs")
    written = report.write_tables(out, es, info, alts, runs=runs, seed=config.seed, duration=config.duration,
                                  main_choice=main_choice)
    files += written.files
    tables = [Output(path, caption) for path, caption in written.captions]
    summary = {"runs": runs, "band_std_rms": {"inside": k_all, "total": n_all},
               "nonfinite": int(sum(v["nonfinite"] for v in info.values()))}
    for name, (a_es, _) in alts.items():
        k, n = band_fraction(a_es)
        summary[f"band_std_rms_{slug(name)}"] = {"inside": k, "total": n}
    elapsed = time.perf_counter() - t0
    files.append(io.write_json(out / "reproduction.json", {
        "schema": "liemef.reproduction.chaplygin/1", "experiment": exp.name, "paper": exp.paper,
        "config": config_dict(config),
        "runs": runs, "elapsed_s": elapsed, "summary": summary,
        "figures": [{"file": f.path.name, "caption": f.caption} for f in figures]}))
    warnings = []
    if summary["nonfinite"]:
        warnings.append(f"WARNING: {summary['nonfinite']} Monte Carlo trials of the main choice were non-finite "
                        "(diverged) and are left out of the statistics")
    text = "\n".join([f"{exp.name}: {exp.title}", f"  {exp.paper}; {runs_note} ({elapsed:.0f} s)",
                      "", written.markdown, "", written.velocity,
                      *([written.alternatives] if written.alternatives else []),
                      f"Wrote {len(files)} files (and montecarlo/) to {out}"])
    mc_files = tuple(sorted((out / "montecarlo").glob("*")))
    return Reproduction(experiment=exp.name, out=out, figures=tuple(figures), tables=tuple(tables),
                        files=tuple(files) + mc_files, text=text, warnings=tuple(warnings), summary=summary)
