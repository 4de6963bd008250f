"""The ``liemef`` command line.

* ``liemef reproduce EXPERIMENT --out DIR [--seed N] [--duration T] [--connection zero|minus|plus]
  [--order second|first] [--set KEY=VALUE ...] [--runs N] [--quick/--full]``: run a paper experiment, write
  ``metrics.json``, ``arrays.npz``, its figures and ``errors.md``/``errors.csv`` to DIR and print the error
  table (mean, std, rms of each component over the whole run and the steady window); with ``--runs N`` also a
  Monte Carlo of N trials. An experiment may define its own reproduction (``Experiment.reproduce_fn``).
* ``liemef reproduce all --out DIR [--quick/--full]``: every experiment, one folder each, and ``index.md``;
  ``liemef reproduce --list``: the experiments with their papers, figures and tables.
* ``liemef montecarlo EXPERIMENT --runs N [--seed S] [--batch-size B] [--out DIR] [--duration T]
  [--set KEY=VALUE ...]``: N seeded trials batched with ``vmap``; prints the statistics table and, with
  ``--out``, writes ``montecarlo.{npz,json,md,csv}``.
* ``liemef run --system NAME|--system-file FILE.py --log FILE --out DIR``: filter a recorded log (CSV or
  NPZ, see :mod:`liemef.reports.io`) and write the estimates with K's diagonal (``estimates.csv``), the innovations
  (``innovations.csv``), ``arrays.npz``, ``metrics.json`` and a figure; a failed run writes only
  ``failure.json`` and exits with status 1.
* ``liemef export-c --system NAME|--system-file FILE.py --out DIR [--name PREFIX] [--order ...] [--connection ...]
  [--integrator ...] [--alpha A] [--substeps auto|N] [--backend auto|scalar|array]``: the filter as standalone
  C99, ``PREFIX.h`` and ``PREFIX.c`` (:func:`liemef.codegen.export_c`); prints the files and the C API.
* ``liemef schema SYSTEM|--system-file FILE.py``: the log columns a system expects, with units and noise.
* ``liemef dataset broad|wifibot PATH --out LOG``: a real recording (BROAD, Wifibot) as a log for ``run``.
* ``liemef compare localization|heading-basin|attitude-basin|broad|wifibot --out DIR [--runs N] [--seed S]
  [--filters a,b] [--set KEY=VALUE]``:
  every filter (the minimum-energy filter with its connections and orders, and the baselines) on the same
  trials; writes the study's tables (Markdown, CSV, JSON), ``arrays.npz`` and figures (:mod:`liemef.studies.compare`).
* ``liemef campaign run FILE [--out DIR] [--scheduler tcp://HOST:PORT] [--workers N]``: a Monte Carlo campaign
  over a grid of settings on Dask, resumable (:mod:`liemef.studies.campaign`); ``liemef campaign status FILE``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import click

from . import __version__

if TYPE_CHECKING:
    import numpy as np

# JAX, numpy, the experiments and the plots load inside the commands, so that `liemef --help` and `--version`
# answer at once. The names the help texts and choices need are kept here instead; tests/test_cli_startup.py
# pins them to their sources (EXPERIMENTS, SYSTEMS, CARTAN_SCHOUTEN, ORDERS, DEFAULT_BATCH_SIZE).
EXPERIMENT_PAPERS = {
    "attitude": "Saccon, Trumpf, Mahony, Aguiar 2016, Sec. V-B, Fig. 3",
    "chaplygin": "Rigo, Sansonetto, Muradore 2023, Sec. 6, Tables 1-2, Figs. 3-6",
    "localization": "ukfm 2D localization benchmark (Brossard, Barrau, Bonnabel); Barrau & Bonnabel 2017, Sec. IV",
    "tse2": "Rigo, Segala, Sansonetto, Muradore 2022, Sec. VI, Figs. 3-4",
    "tse2-velocity": "Segala, Sansonetto, Muradore, poster 'Tracking and filtering on SE(2)'; setup of Rigo et al. "
                     "2022",
    "unit-circle": "Zamani, Hua, Trumpf, Mahony, 'Minimum-Energy Filtering on the Unit Circle Using Velocity "
                   "Measurements with Bias and Vectorial State Measurements', Sec. IV, Figs. 2-3",
}
"""``liemef.studies.experiments.EXPERIMENTS``: each experiment's name and paper, in the registry's order."""
SYSTEM_NAMES = ("attitude", "attitude-bias", "chaplygin", "chaplygin-gps", "localization", "tse2", "tse2-velocity",
                "unit-circle")
"""``sorted(liemef.studies.experiments.SYSTEMS)``."""
CONNECTIONS = ("minus", "zero", "plus")
"""``tuple(liemef.connections.CARTAN_SCHOUTEN)``."""
ORDERS = ("second", "first")
"""``liemef.filters.ORDERS``."""
DEFAULT_BATCH_SIZE = 8
"""``liemef.studies.experiments.DEFAULT_BATCH_SIZE``."""
COMPARE_STUDIES = ("localization", "heading-basin", "attitude-basin", "broad", "wifibot")
"""``tuple(liemef.studies.compare.STUDIES)``."""


def _out_dir(out: Path) -> Path:
    from .reports import io

    try:
        return io.ensure_dir(out)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--out'") from err


def _floats(text: str | None, n: int, option: str) -> np.ndarray | None:
    if text is None:
        return None
    import numpy as np

    try:
        v = np.array([float(s) for s in text.replace(",", " ").split()])
    except ValueError as err:
        raise click.BadParameter(f"expected {n} numbers separated by commas, got {text!r}",
                                 param_hint=option) from err
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise click.BadParameter(f"expected {n} finite numbers separated by commas, got {text!r}",
                                 param_hint=option)
    return v


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="liemef")
def cli():
    """Second-order-optimal minimum-energy filtering on matrix Lie groups."""


def _experiments_help() -> str:
    lines = "\n".join(f"  {name:<14} {paper}" for name, paper in EXPERIMENT_PAPERS.items())
    return ("Run a paper EXPERIMENT and write metrics.json, arrays.npz, its figures and error tables to --out, "
            "then print the error table; with --runs N (or the experiment's default) also a Monte Carlo of N "
            "seeded trials (montecarlo.md/.csv/.json/.npz).\n\n"
            "`reproduce all --out DIR` runs every experiment at a reduced size (--quick, the default) or at the "
            "papers' size (--full), one folder each, and writes DIR/index.md. `reproduce --list` lists the "
            "experiments with their papers, figures and tables.\n\n\b\nExperiments:\n" + lines)


def _parse_value(text: str, current, key: str):
    """``text`` as a value of the type of the config field's current value."""
    try:
        if isinstance(current, bool):
            low = text.lower()
            if low not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError("expected true or false")
            return low in ("true", "1", "yes", "on")
        if isinstance(current, int):
            return int(text)
        if isinstance(current, float):
            return float(text)
        if isinstance(current, str):
            return text
        if isinstance(current, tuple | list):
            item = current[0] if len(current) else 0.0
            return tuple(_parse_value(part, item, key) for part in text.replace(",", " ").split())
        try:
            return json.loads(text)
        except ValueError:
            return text
    except ValueError as err:
        raise click.BadParameter(f"{key}: expected a value like {current!r}, got {text!r} ({err})",
                                 param_hint="'--set'") from err


def _settings(settings: tuple[str, ...], base) -> dict:
    """``--set KEY=VALUE`` options as config overrides, each parsed as the type of the field in ``base``."""
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
    out = {}
    for item in settings:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="'--set'")
        if key not in fields:
            raise click.BadParameter(f"unknown config option {key!r}; expected one of {sorted(fields)}",
                                     param_hint="'--set'")
        out[key] = _parse_value(text.strip(), fields[key], key)
    return out


def _config(exp, quick: bool, options: dict, settings: tuple[str, ...]):
    base = exp.quick() if quick else exp.default_config
    overrides = {k: v for k, v in options.items() if v is not None}
    overrides.update(_settings(settings, base))
    try:
        return exp.quick(**overrides) if quick else exp.config(**overrides)
    except ValueError as err:
        raise click.UsageError(str(err)) from err


def _list_experiments() -> str:
    from .studies.experiments import EXPERIMENTS

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


def _echo_reproduction(rep) -> None:
    click.echo(rep.text)
    for w in rep.warnings:
        click.echo(w, err=True)


@cli.command(help=_experiments_help())
@click.argument("experiment", required=False, type=click.Choice([*sorted(EXPERIMENT_PAPERS), "all"]),
                metavar="EXPERIMENT|all")
@click.option("--list", "list_", is_flag=True, help="List the experiments (paper, figures, tables) and exit.")
@click.option("--out", type=click.Path(path_type=Path), help="Output folder (created if missing).")
@click.option("--quick/--full", default=None,
              help="The experiment's reduced laptop size, or the paper's (default: --full for one experiment, "
                   "--quick for all).")
@click.option("--runs", type=click.IntRange(min=0),
              help="Monte Carlo trials (default: the experiment's; 0: the seeded run only).")
@click.option("--seed", type=int, help="Random seed (default: the experiment's, 0).")
@click.option("--duration", type=float, help="Final time T in seconds (default: the paper's).")
@click.option("--connection", type=click.Choice(CONNECTIONS),
              help="Cartan-Schouten connection (default: zero).")
@click.option("--order", type=click.Choice(ORDERS),
              help="second: the paper filter; first: the left-invariant EKF.")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Override any config field (repeatable), e.g. --set dt=0.01 --set alpha=0.1.")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="Monte Carlo progress on stderr.")
def reproduce(experiment, list_, out, quick, runs, seed, duration, connection, order, settings, progress):
    if list_:
        click.echo(_list_experiments())
        return
    if experiment is None:
        raise click.UsageError("Missing argument 'EXPERIMENT|all' (or --list).")
    if out is None:
        raise click.UsageError("Missing option '--out'.")
    from .studies.experiments import Failure, get_experiment, reproduce_all
    from .studies.experiments._reproduce import INDEX_FILE

    options = {"seed": seed, "duration": duration, "connection": connection, "order": order}
    if experiment == "all":
        given = [f"--{k}" for k, v in options.items() if v is not None] + (["--set"] if settings else [])
        if given:
            raise click.UsageError(f"{', '.join(given)}: config options apply to one experiment, not to "
                                   "'all' (each runs its own reduced or full config)")
        d = _out_dir(out)
        reps = reproduce_all(d, quick=quick is not False, progress=progress, runs=runs,
                             echo=lambda text: click.echo(text + "\n"))
        failed = [r for r in reps if isinstance(r, Failure)]
        click.echo(f"Wrote {len(reps) - len(failed)} of {len(reps)} experiments and {INDEX_FILE} to {d}")
        for r in failed:
            click.echo(f"FAILED {r.experiment}: {r.error}", err=True)
        if failed:
            raise click.ClickException(f"{len(failed)} experiment(s) failed: {', '.join(r.experiment for r in failed)}")
        return
    exp = get_experiment(experiment)
    config = _config(exp, bool(quick), options, settings)
    d = _out_dir(out)
    if runs is None:
        runs = exp.quick_runs if quick else exp.runs
    _echo_reproduction(exp.reproduce(d, config, runs=runs, progress=progress))


@cli.command("montecarlo")
@click.argument("experiment", type=click.Choice(sorted(EXPERIMENT_PAPERS)), metavar="EXPERIMENT")
@click.option("--runs", type=click.IntRange(min=1), default=100, show_default=True, help="Number of trials.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Trial i uses jax.random.split(jax.random.key(seed), runs)[i].")
@click.option("--batch-size", type=click.IntRange(min=1), default=DEFAULT_BATCH_SIZE, show_default=True,
              help="Trials per compiled vmap batch (the results do not depend on it).")
@click.option("--out", type=click.Path(path_type=Path),
              help="Write montecarlo.npz/.json/.md/.csv to this folder (created if missing).")
@click.option("--duration", type=float, help="Final time T in seconds (default: the paper's).")
@click.option("--quick", is_flag=True, help="Start from the experiment's reduced config.")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Override any config field (repeatable), e.g. --set connection=minus --set dt=0.01.")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="Trials done, elapsed time and ETA on stderr.")
def montecarlo_cmd(experiment, runs, seed, batch_size, out, duration, quick, settings, progress):
    """Run N seeded trials of EXPERIMENT, batched with vmap, and print the statistics: per trial the mean, std
    and rms over time of each error component, then across trials their mean, spread and percentiles."""
    from .studies.experiments import EXPERIMENTS, get_experiment, montecarlo

    exp = get_experiment(experiment)
    if exp.trial_fn is None:
        with_trials = sorted(e.name for e in EXPERIMENTS.values() if e.trial_fn is not None)
        raise click.UsageError(f"experiment {exp.name!r} has no Monte Carlo trial; expected one of {with_trials}")
    config = _config(exp, quick, {"duration": duration}, settings)
    d = _out_dir(out) if out is not None else None
    try:
        result = montecarlo(exp, config, runs, seed=seed, batch_size=batch_size, progress=progress)
    except ValueError as err:
        raise click.UsageError(str(err)) from err
    click.echo(f"{exp.name}: {exp.title}")
    click.echo(f"  {exp.paper}")
    click.echo(result.format())
    click.echo(f"{result.runs} trials in {result.elapsed:.1f} s ({result.runs / result.elapsed:.1f} trials/s "
               f"including compilation), {result.batch_size} per batch")
    if result.n_nonfinite:
        click.echo(f"WARNING: {result.divergence_summary()} (trials "
                   f"{', '.join(map(str, result.nonfinite_trials[:20]))}); they are left out of the statistics",
                   err=True)
    if d is not None:
        written = result.save(d)
        click.echo(f"Wrote {', '.join(p.name for p in written)} to {d}")


def _resolve_system(system_name, system_file):
    """The system and what the command needs to start it: (system, label, description, measured_fn or None,
    user file or None)."""
    from .studies.experiments import get_system
    from .systems import _file as _system_file

    if (system_name is None) == (system_file is None):
        raise click.UsageError("expected exactly one of --system NAME (a ready system) or --system-file FILE.py "
                               f"(your own), got {'both' if system_name else 'neither'}")
    if system_name is not None:
        spec = get_system(system_name)
        return spec.make(), spec.name, spec.description, spec.measured, None
    try:
        user = _system_file.load_system_file(system_file)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--system-file'") from err
    return user.system, system_file.stem, f"user system from {system_file}", None, user


def _first_present(ys) -> np.ndarray:
    """Each measurement component's first present (finite) value, NaN where a component never has one."""
    import numpy as np

    ok = np.isfinite(ys)
    first = np.argmax(ok, axis=0)
    return np.where(ok.any(axis=0), ys[first, np.arange(ys.shape[1])], np.nan)


def _run_chunked(flt, state, log, gap, chunk, progress):
    """``flt.run`` over the log in chunks of ``chunk`` intervals (one compilation per chunk length), each
    continuing from the previous chunk's final state, with a progress line; stops at the first failure."""
    import time
    import warnings

    import jax
    import jax.numpy as jnp

    from .engines import LogGapWarning
    from .filters import Trajectory
    from .studies.experiments import ProgressLine

    N = log.ts.shape[0]
    show = ProgressLine("filtering (samples)") if progress and N - 1 > chunk else None
    pieces, start, t0 = [], 0, time.perf_counter()
    while start < N - 1:
        stop = min(start + chunk, N - 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LogGapWarning)  # said once, from the final status
            traj = flt.run(state, log.ts[start:stop + 1], log.us[start:stop + 1], log.ys[start:stop + 1], gap=gap)
        pieces.append(traj if start == 0 else jax.tree_util.tree_map(lambda a: a[1:], (traj.g_hat, traj.K)))
        state, start = traj.final, stop
        if show is not None:
            elapsed = time.perf_counter() - t0
            show(stop + 1, N, elapsed, elapsed / (stop + 1) * (N - stop - 1))
        if not traj.status.code == 0:
            break
    if len(pieces) == 1:
        return pieces[0]
    first = pieces[0]
    parts = [(first.g_hat, first.K)] + pieces[1:]
    g_hat, K = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)
    n = K.shape[0]
    if n < N:  # stopped at a failure: the rest of the log has no estimate
        g_hat = jax.tree_util.tree_map(lambda a: jnp.concatenate([a, jnp.full((N - n,) + a.shape[1:], jnp.nan)]),
                                       g_hat)
        K = jnp.concatenate([K, jnp.full((N - n,) + K.shape[1:], jnp.nan)])
    return Trajectory(ts=jnp.asarray(log.ts), g_hat=g_hat, K=K, status=traj.status, final=traj.final)


def _innovation_table(ts, innov, names, units) -> tuple[str, dict]:
    """Mean, std and rms of each innovation component over its present samples (NaN = no sample)."""
    import numpy as np

    from .metrics._stats import format_number, json_number

    rows, out = [], {}
    for j, name in enumerate(names):
        v = innov[:, j][np.isfinite(innov[:, j])]
        stats = {"count": int(v.size), "mean": float(v.mean()) if v.size else math.nan,
                 "std": float(v.std(ddof=1)) if v.size > 1 else math.nan,
                 "rms": float(np.sqrt(np.mean(v ** 2))) if v.size else math.nan}
        out[name] = {"unit": units[j], **{k: json_number(x) for k, x in stats.items()}}
        rows.append(f"  {name:<12} {units[j]:<7} {stats['count']:>8d} " + " ".join(
            f"{format_number(stats[k]):>12}" for k in ("mean", "std", "rms")))
    head = f"  {'component':<12} {'unit':<7} {'samples':>8} {'mean':>12} {'std':>12} {'rms':>12}"
    return "\n".join([head, *rows]), out


@cli.command("run")
@click.option("--system", "system_name", type=click.Choice(SYSTEM_NAMES),
              help="A ready system the log was recorded with (or --system-file).")
@click.option("--system-file", type=click.Path(path_type=Path),
              help="A Python file that defines `system` (your own liemef system) and optionally K0, x0, "
                   "initial_guess(y0).")
@click.option("--log", "log_path", required=True, type=click.Path(path_type=Path),
              help="Recorded log: CSV with the system's columns (`liemef schema SYSTEM`; an empty field is a "
                   "missing sample) or NPZ with ts, us, ys (or one time vector per sensor).")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Output folder (created if missing).")
@click.option("--x0", help="Initial estimate in coordinates, comma separated (default: the system file's x0, "
              "else read off the first present measurements).")
@click.option("--k0", type=float, help="Initial gain K(0) = k0 * I (default: the system file's K0, else 1).")
@click.option("--k0-diag", help="Initial gain K(0) = diag(...), comma separated (overrides --k0).")
@click.option("--connection", type=click.Choice(CONNECTIONS), default="zero", show_default=True)
@click.option("--order", type=click.Choice(ORDERS), default="second", show_default=True)
@click.option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
@click.option("--interpolation", type=click.Choice(("hold", "linear")), default="hold", show_default=True,
              help="Inputs and dense measurements held over each interval, or linear between samples.")
@click.option("--updates", type=click.Choice(("hold", "discrete")), default="hold", show_default=True,
              help="Sample sensors: held over the interval after their time stamp (the papers' scheme), or used "
              "at their own time (the hybrid filter: recommended for sample sensors).")
@click.option("--substeps", default="auto", show_default=True,
              help="Integrator steps per sample interval: auto (by stiffness) or a number.")
@click.option("--gap", type=float, help="An interval longer than this (s) is a gap: predicted through, dense "
              "measurements not held (default: 10 x the median interval).")
@click.option("--chunk", type=click.IntRange(min=16), default=65536, show_default=True,
              help="Samples per compiled chunk (progress is shown between chunks).")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Progress on stderr.")
@click.option("--params", "params_file", type=click.Path(path_type=Path),
              help="A tuning file of `liemef tune` (JSON): its final parameter set for --system attitude-imu.")
def run_log(system_name, system_file, log_path, out, x0, k0, k0_diag, connection, order, alpha, interpolation,
            updates, substeps, gap, chunk, progress, params_file):
    """Filter a recorded log with a ready system or your own, and write the estimates, K's diagonal and the
    innovations to --out. A failed run (non-finite, K no longer symmetric or positive definite, a gate) writes
    only failure.json, says where, when and why, and exits with status 1."""
    import jax
    import numpy as np

    from .filters import MinimumEnergyFilter
    from .metrics import angle_mask, continuous_angles, gain_stats, state_labels
    from .reports import io, plots
    from .studies.experiments import SCHEMA

    system, label, description, measured, user = _resolve_system(system_name, system_file)
    if params_file is not None:
        from .studies import tune as _tune

        if system_name != "attitude-imu":
            raise click.BadParameter(f"expected --system attitude-imu with a tuning file, got {system_name!r}",
                                     param_hint="'--params'")
        try:
            system = _tune.system_from(_tune.params_for(_tune.load(params_file)), {})
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="'--params'") from err
    n, c = system.group.tangent_dim, system.group.coords_dim
    try:
        log = io.read_log(log_path, system)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--log'") from err
    if substeps != "auto":
        try:
            substeps = int(substeps)
        except ValueError as err:
            raise click.BadParameter(f"expected 'auto' or an integer >= 1, got {substeps!r}",
                                     param_hint="'--substeps'") from err
    y_first = _first_present(log.ys)
    q0 = _floats(x0, c, "'--x0'")
    if q0 is None and user is not None:
        q0 = user.x0 if user.x0 is not None else (
            user.guess(y_first) if user.initial_guess else np.zeros(c))
    if q0 is None:
        q = measured(y_first[None, :])[0]
        q0 = np.where(np.isfinite(q), q, 0.0)
    if k0 is not None and not (math.isfinite(k0) and k0 >= 0):
        raise click.BadParameter(f"expected a number >= 0, got {k0}", param_hint="'--k0'")
    if k0_diag is not None:
        K0 = np.diag(_floats(k0_diag, n, "'--k0-diag'"))
    elif k0 is not None:
        K0 = k0 * np.eye(n)
    else:
        K0 = user.K0 if user is not None and user.K0 is not None else np.eye(n)
    d = _out_dir(out)
    try:
        flt = MinimumEnergyFilter(system, connection=connection, order=order, alpha=alpha,
                                  interpolation=interpolation, substeps=substeps, updates=updates)
        state = flt.init(system.group.from_coords(q0), K0)
        if gap is None:
            gap = 10.0 * float(np.median(np.diff(log.ts)))
        traj = _run_chunked(flt, state, log, gap, chunk, progress)
    except ValueError as err:
        raise click.UsageError(str(err)) from err

    status = traj.status
    blocks = [b.name for b in system.blocks()]
    report = status.as_dict(blocks)
    click.echo(f"Filtered {log.ts.shape[0]} samples of {log_path} with {label} ({repr(flt)})")
    rejected = {k: v for k, v in report["rejected"].items() if v}
    if rejected:
        click.echo("Gate rejected samples: " + ", ".join(f"{k} {v}" for k, v in rejected.items()))
    if report["gaps"]:
        click.echo(f"WARNING: {report['gaps']} interval(s) longer than the gap threshold {gap:.4g} s (longest "
                   f"{report['longest_gap']:.4g} s) were predicted through", err=True)
    if report["inputs_held"]:
        click.echo(f"WARNING: {report['inputs_held']} input sample(s) were missing; the previous input was held",
                   err=True)
    if not status.ok:
        k = int(status.index)
        last = np.asarray(traj.final.g_hat.coords())
        names, _ = state_labels(system)
        failure = {"schema": SCHEMA, "status": report, "message": status.message(log.ts),
                   "last_good_state": {"sample": k, "t": float(log.ts[k]),
                                       "coords": dict(zip(names, map(float, last), strict=True)),
                                       "K_diag": [float(v) for v in np.diagonal(np.asarray(traj.final.K))]},
                   "log": str(log_path), "filter": repr(flt), "liemef_version": __version__}
        io.write_json(d / "failure.json", failure)
        raise click.ClickException(f"{status.message(log.ts)} (cause: {status.cause}). No estimates "
                                   f"were written; see {d / 'failure.json'}")

    names, units = state_labels(system)
    angles = angle_mask(system.group)
    coords = np.asarray(traj.coords())
    filt = continuous_angles(coords, angles)
    K = np.asarray(traj.K)
    K_diag = np.diagonal(K, axis1=1, axis2=2)
    innov = np.asarray(jax.vmap(system.residual)(log.ys, jax.vmap(system.output)(traj.g_hat, log.ts), log.ts))
    onames, ounits = system.output_names, system.output_units
    table_text, table = _innovation_table(log.ts, innov, onames, ounits)
    comps = [f"e{k}" for k in range(n)]
    figures = [{"file": "estimate.png", "components": list(names),
                "title": f"{label}: " + ("measured (blue), " if measured else "") + f"filtered (green) from "
                         f"{log_path.name}"}]
    metrics = {
        "schema": SCHEMA,
        "system": {"name": label, "description": description, "filter": repr(flt)},
        "log": {"file": str(log_path), "samples": int(log.ts.shape[0]), "t0": float(log.ts[0]),
                "t1": float(log.ts[-1])},
        "config": {"x0": [float(v) for v in q0], "K0_diag": [float(v) for v in np.diagonal(K0)],
                   "connection": connection, "order": order, "alpha": alpha, "interpolation": interpolation,
                   "updates": updates,
                   "substeps": substeps, "gap": gap},
        "innovation": {"definition": "y (-) h(g_hat) (the sensors' residual, y - h unless declared) at each present "
                       "sample (before the update of that sample)",
                       "components": table},
        "gain": gain_stats(K),
        "status": report,
        "run": {"finite": True, "liemef_version": __version__},
        "figures": figures,
    }
    arrays = {"ts": log.ts, "names": np.array(names), "units": np.array(units), "filtered": filt,
              "K_diag": K_diag, "us": log.us, "ys": log.ys, "innovation": innov, "output_names": np.array(onames)}
    if measured is not None:
        arrays["measured"] = continuous_angles(measured(log.ys), angles, reference=filt)
    io.write_csv(d / "estimates.csv", ["t", *names, *(f"K_{e}{e}" for e in comps)],
                 [log.ts, *coords.T, *K_diag.T])
    io.write_rows(d / "innovations.csv", ["t", *onames],  # an empty field: no sample, hence no innovation
                  [[float(t), *("" if math.isnan(v) else float(v) for v in row)] for t, row in zip(log.ts, innov,
                                                                                                    strict=True)])
    io.write_result(d, metrics, arrays)
    figs = plots.write_figures(d)
    click.echo("Innovation y - h(g_hat) over the present samples:")
    click.echo(table_text)
    click.echo(f"Sub-steps: {report['substeps_total']} over {report['steps']} intervals (at most "
               f"{report['substeps_max']} in one)")
    click.echo(f"Wrote estimates.csv (coordinates and K's diagonal), innovations.csv, {io.METRICS_FILE}, "
               f"{io.ARRAYS_FILE}, {', '.join(p.name for p in figs)} to {d}")


C_IDENTIFIER = r"[A-Za-z_][A-Za-z0-9_]*"
"""What ``liemef export-c --name`` accepts: the prefix of every name of the exported C."""
C_BACKENDS = ("auto", "scalar", "array")
"""``liemef.codegen.BACKENDS``."""


def _c_api_summary(exported, system) -> str:
    """The exported C API with its sizes, the state's members, the status codes and the order of u and y."""
    import re

    from .filters import CAUSES

    P, U = exported.prefix, exported.prefix.upper()
    n, m, p = exported.n, exported.input_dim, exported.output_dim
    members = []
    for f in exported.fields:
        size = "" if f.scalar else f"[{f.size}]"
        members.append(f"{f.name}{size}" + (f" ({n} x {n}, row-major)" if f.name == "K" else ""))
    codes = ", ".join(f"{i} {U}_{re.sub(r'[^A-Z]', '_', cause.upper()).strip('_')} ({cause})"
                      for i, cause in enumerate(CAUSES))
    return "\n".join([
        f"C API ({P}.h; n = {n}, m = {m} inputs, p = {p} outputs, {exported.group_params} group parameters, "
        f"{exported.coords_dim} coordinates):",
        f"  {P}_state s;  /* {', '.join(members)} */",
        f"  int  {P}_init({P}_state *s, const double *g0, const double *K0);  /* 0, or {U}_BAD_ARGUMENT (-1) */",
        f"  int  {P}_step({P}_state *s, double t, double dt, const double *u, const double *y, const int *mask);",
        f"  int  {P}_run({P}_state *s, int n, const double *ts, const double *us, const double *ys, "
        "double *g_out, double *K_out);",
        f"  void {P}_from_coords(const double *q, double *g);",
        f"  void {P}_coords(const double *g, double *q);",
        f"Status codes ({P}_step, {P}_run, s.code): {codes}",
        f"u = ({', '.join(system.input_names) or 'none'})",
        f"y = ({', '.join(system.output_names)}); mask[i] = 0 or a NaN in y: a missing component",
        f"Build: cc -std=c99 -O2 -c {P}.c (link with -lm); no heap, no library but libm",
    ])


@cli.command("export-c")
@click.option("--system", "system_name", type=click.Choice(SYSTEM_NAMES), help="A ready system (or --system-file).")
@click.option("--system-file", type=click.Path(path_type=Path), help="A Python file that defines `system`.")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Folder for NAME.h and NAME.c (created if missing).")
@click.option("--name", help="The C prefix of every exported name, a C identifier (default: the system's name with "
                             "- replaced by _).")
@click.option("--connection", type=click.Choice(CONNECTIONS), default="zero", show_default=True)
@click.option("--order", type=click.Choice(ORDERS), default="second", show_default=True)
@click.option("--integrator", type=click.Choice(("rkmk4", "lie-euler")), default="rkmk4", show_default=True)
@click.option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
@click.option("--substeps", default="auto", show_default=True,
              help="Integrator steps per sample interval: auto (by stiffness) or a number.")
@click.option("--max-substeps", type=click.IntRange(min=1), default=256, show_default=True,
              help="The most steps 'auto' takes in one interval.")
@click.option("--backend", type=click.Choice(C_BACKENDS), default="auto", show_default=True,
              help="scalar: straight-line code (fast, its size grows as n^3); array: loops over arrays (compact); "
                   "auto: scalar up to n = 12.")
def export_c_cmd(system_name, system_file, out, name, connection, order, integrator, alpha, substeps, max_substeps,
                 backend):
    """Write the filter of a ready system (--system) or of your own (--system-file) as standalone C99: NAME.h
    and NAME.c in --out, with NAME_init, NAME_step (one sample interval, exactly as the filter's step), NAME_run
    and the coordinate maps. No heap, no library but libm; the weights, connection and parameters are constants
    of the source (export again for new ones). See docs/export-c.md."""
    import re

    given = name is not None
    if not given and (system_name or system_file):
        name = (system_name or system_file.stem).replace("-", "_")
    if name is not None and not re.fullmatch(C_IDENTIFIER, name):
        raise click.BadParameter(f"expected a C identifier (letters, digits and _, not starting with a digit), got "
                                 f"{name!r}" + ("" if given else " (from the system's name: give --name)"),
                                 param_hint="'--name'")
    if substeps != "auto":
        try:
            substeps = int(substeps)
        except ValueError:
            substeps = 0
        if substeps < 1:
            raise click.BadParameter("expected 'auto' or an integer >= 1", param_hint="'--substeps'")
    if not math.isfinite(alpha) or alpha < 0:
        raise click.BadParameter(f"expected a number >= 0, got {alpha}", param_hint="'--alpha'")
    d = _out_dir(out)
    system, label, _, _, _ = _resolve_system(system_name, system_file)
    from .codegen import SCALAR_MAX_N, UnsupportedPrimitive, export_c
    from .filters import MinimumEnergyFilter

    try:
        flt = MinimumEnergyFilter(system, connection=connection, order=order, integrator=integrator, alpha=alpha,
                                  substeps=substeps, max_substeps=max_substeps)
    except ValueError as err:
        raise click.UsageError(str(err)) from err
    try:
        exported = export_c(flt, d, name, backend=backend)
    except UnsupportedPrimitive as err:
        raise click.ClickException(f"{label}: the filter step uses what the C translator does not cover: {err}. "
                                   "See docs/export-c.md (supported primitives)") from err
    except OSError as err:
        raise click.BadParameter(f"cannot write to {str(d)!r} ({err.strerror or err})", param_hint="'--out'") from err
    if backend == "auto":
        backend = "scalar" if flt.n <= SCALAR_MAX_N else "array"
    click.echo(f"Exported {label} ({flt!r}) as C99 ({backend} code):")
    click.echo(f"  {exported.header}\n  {exported.source}")
    click.echo(_c_api_summary(exported, system))


@cli.command("schema")
@click.argument("system_name", required=False, type=click.Choice(SYSTEM_NAMES), metavar="SYSTEM")
@click.option("--system-file", type=click.Path(path_type=Path), help="A Python file that defines `system`.")
def schema(system_name, system_file):
    """Print the log columns of SYSTEM (a ready system) or of --system-file: names, units, roles and the
    sensors' noise levels, and the CSV header that `liemef run` expects."""
    from .systems._file import format_schema

    system, label, description, _, _ = _resolve_system(system_name, system_file)
    click.echo(f"{label}: {description}")
    click.echo(format_schema(system))


@cli.command("dataset")
@click.argument("kind", type=click.Choice(("broad", "wifibot")))
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="The log to write (.csv, or .npz), in the columns of the matching ready system.")
@click.option("--truth", type=click.Path(path_type=Path), help="Also write the ground truth here (CSV).")
@click.option("--seconds", type=float, help="Only the first SECONDS of the recording.")
@click.option("--gps-std", type=float, default=0.1, show_default=True,
              help="wifibot: std (m) of the synthetic 1 Hz GPS (ground truth + noise, numpy seed 0).")
@click.option("--norms", is_flag=True, help="broad: also the raw norms, a log for the system attitude-imu.")
def dataset(kind, path, out, truth, seconds, gps_std, norms):
    """Convert a real recording (read in place, e.g. from ../shared/realdata) into a liemef log for
    `liemef run`: `broad FILE.mat` (BROAD IMU trial, system attitude-bias: gyro input, accelerometer and
    magnetometer directions) or `wifibot FILE.txt` (wheel odometry input with synthetic 1 Hz GPS, system
    localization). PATH may also be the id of a recording present in the real-data folder (`broad 16`,
    `wifibot 4`; found by reading the files)."""
    import numpy as np

    from .reports import io
    from .studies import datasets
    from .studies.experiments import get_system

    try:
        if not path.exists():  # an id of a recording present (datasets.broad_trials / wifibot_runs)
            found = (datasets.broad_trials if kind == "broad" else datasets.wifibot_runs)()
            key = f"{int(str(path)):02d}" if kind == "broad" and str(path).isdigit() else str(path)
            path = found.get(key, path)
        if kind == "broad":
            rec = datasets.broad(path)
            rec = rec.head(seconds) if seconds else rec
            log = datasets.broad_to_log(rec, norms=norms)
            system = get_system("attitude-imu" if norms else "attitude-bias").make()
            header = ["t", "q_w", "q_x", "q_y", "q_z", "movement"]
            columns = [rec.ts, *rec.quat_true.T, rec.movement.astype(np.float64)]
        else:
            rec = datasets.wifibot(path)
            if seconds:
                k = max(2, int(np.searchsorted(rec.ts, rec.ts[0] + seconds)))
                rec = datasets.WifibotRun(rec.ts[:k], rec.v[:k], rec.omega[:k], rec.truth[:k], rec.name)
            log, system = datasets.wifibot_to_log(rec, gps_std=gps_std), get_system("localization").make()
            header, columns = ["t", "theta", "x", "y"], [rec.ts, *rec.truth.T]
        written = [io.write_log(out, system, log.ts, log.us, log.ys)]
        if truth is not None:
            written.append(io.write_csv(truth, header, columns))
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'PATH'") from err
    click.echo(f"{kind} {path}: {log.ts.shape[0]} samples over {log.ts[-1] - log.ts[0]:.1f} s; wrote "
               f"{', '.join(str(p) for p in written)}")
    name = ("attitude-imu" if norms else "attitude-bias") if kind == "broad" else "localization"
    click.echo(f"Filter it with: liemef run --system {name} "
               f"--log {out} --out DIR")


@cli.command("tune")
@click.argument("data", type=click.Choice(("broad",)))
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Output folder: tune.json (the tuned set, for run/compare --set params=...) and tune.md.")
@click.option("--objective", type=click.Choice(("truth", "nll")), default="truth", show_default=True,
              help="truth: BROAD's total attitude rms; nll: the innovations' negative log-likelihood (no truth).")
@click.option("--trials", metavar="A,B,...", help="BROAD trial ids (default: every trial present).")
@click.option("--params", "names", metavar="A,B,...", help="Parameters to tune (default: liemef.studies.tune's).")
@click.option("--seconds", type=float, default=90.0, show_default=True,
              help="Tune on the first SECONDS of each trial (0: whole trials); evaluate with `compare broad`.")
@click.option("--maxfev", type=click.IntRange(min=1), default=40, show_default=True,
              help="Evaluations of the shared search (each runs every trial).")
@click.option("--fold-maxfev", type=click.IntRange(min=1), default=12, show_default=True,
              help="Evaluations of each leave-one-out fold's refinement.")
@click.option("--system", "system_name", type=click.Choice(("attitude-imu", "attitude-velocity")),
              default="attitude-imu", show_default=True,
              help="The model: attitude-imu (direction sensors with noise from their norms) or attitude-velocity "
                   "(linear acceleration as a bounded velocity; always with --updates discrete).")
@click.option("--updates", type=click.Choice(("hold", "discrete")), default="hold", show_default=True,
              help="discrete: samples at their own time (the hybrid update, gyro sample k over the interval "
                   "ending at t_k), as compare broad's mef-imu-d.")
@click.option("--realdata", type=click.Path(path_type=Path), help="The real-data folder (default: found).")
@click.option("--progress/--no-progress", default=True, show_default=True, help="A progress bar on stderr.")
def tune_cmd(data, out, objective, trials, names, seconds, maxfev, fold_maxfev, system_name, updates, realdata,
             progress):
    """Fit an IMU model's noise levels (--system) to the BROAD trials present, by a derivative-free
    search, with leave-one-trial-out cross-validation; writes the held-out and training errors and the tuned
    set (tune.json, accepted by `liemef run --params` and `liemef compare broad --set params=...`)."""
    from .reports import io
    from .studies import tune as _tune

    if system_name == "attitude-velocity" and updates != "discrete":
        raise click.UsageError("--updates: expected discrete with --system attitude-velocity (as compare broad's "
                               f"mef-vel), got {updates}")
    try:
        recs = _tune.broad_recordings(None if not trials else trials.split(","), seconds or None,
                                      None if realdata is None else str(realdata),
                                      gyro="backward" if updates == "discrete" else "forward", system=system_name)
        kw = {} if not names else {"names": tuple(n.strip() for n in names.split(","))}
        result = _tune.tune(recs, objective=objective, maxfev=maxfev, fold_maxfev=fold_maxfev, progress=progress,
                            updates=updates, **kw)
    except ValueError as err:
        raise click.UsageError(str(err)) from err
    d = io.ensure_dir(out)
    _tune.save(result, d / "tune.json")
    io.write_text(d / "tune.md", _tune.markdown(result))
    click.echo(_tune.markdown(result))
    click.echo(f"Wrote tune.json and tune.md to {d}")


@cli.command("compare")
@click.argument("study", type=click.Choice(COMPARE_STUDIES))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Output folder (created if missing).")
@click.option("--runs", type=click.IntRange(min=1), help="Trials (the same for every filter; default: the study's).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="First seed: trial i uses split(key(seed), runs)[i] (localization with --set rng=numpy: ukfm's "
                   "stream seeded seed + i; wifibot: the GPS noise of seed + i).")
@click.option("--filters", metavar="A,B,...", help="Filters to compare (default: all of the study's).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Any other setting of the study (repeatable). localization: duration, steady, "
                   "optimum_runs, rng (jax or numpy), batch_size. heading-basin: duration, angles_deg "
                   "(comma-separated), prior_std_deg, tolerance_deg, batch_size. attitude-basin: duration, "
                   "angles_deg, tolerance_deg, systems (rigid-body,gyro-bias), rigid_body_dt, imu_rate, "
                   "prior_std_deg, batch_size, optimum_runs, optimum_every. broad: trials (comma-separated ids), "
                   "seconds, realdata. wifibot: recordings (comma-separated ids), gps_rate, gps_std, realdata.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="One line per filter.")
def compare_cmd(study, out, runs, seed, filters, settings, progress):
    """Compare the minimum-energy filter with the filters people use on STUDY, on the same trials.

    Filters: mef (second order, (0)-connection), mef-minus, mef-plus, mef-first, iekf, ekf, ukf-left.

    localization: ukfm's 2D localization benchmark (odometry 100 Hz, GPS 1 Hz, 45 deg initial heading error);
    writes comparison.md (per filter the rms, pooled rms with its bootstrap interval, NEES, the published
    figures, and per metric the winner with its paired lead), comparison.csv, comparison.json, arrays.npz and
    fig_errors.png (and fig_optimum.png with --set optimum_runs=M).

    heading-basin: the fraction of trials that converge and the time to converge against the initial heading
    error; writes basin.md, basin.csv, basin.json, arrays.npz and fig_basin.png.

    attitude-basin: the same against the initial attitude error (0-180 deg) on TSO(3), Saccon et al.'s rigid body
    and attitude + gyro bias from a synthetic IMU (filters: mef, mef-first, mef-minus, mef-plus, iekf, ukf-left;
    madgwick and mahony on request, gyro bias only); writes attitude_basin.md, attitude_basin.csv,
    attitude_basin.json, arrays.npz and fig_basin_<system>.png.

    broad: the BROAD attitude recordings present in the real-data folder (gyro, accelerometer, magnetometer
    with optical truth), with the MEF, a robust MEF, the invariant EKF, the UKF-M and ahrs's Madgwick and
    Mahony (default and published gains), one weight set for all trials; writes broad.md, broad.csv, broad.json
    and arrays.npz.

    wifibot: UKF-M's Wifibot runs (real wheel odometry, optical truth) with synthetic 1 Hz GPS of 0.1 m over
    --runs seeds; writes wifibot.md, wifibot.csv, wifibot.json and arrays.npz.

    Trials where a filter fails are counted and named, and left out of the statistics."""
    from .studies.compare import STUDIES

    spec = STUDIES[study]
    d = _out_dir(out)
    fields = {f.name: f for f in dataclasses.fields(spec.settings)}
    kwargs = {}
    for key, value in (("runs", runs), ("seed", seed), ("filters", filters)):
        if value is not None and not (key == "seed" and value == 0):
            if key not in fields:
                raise click.BadParameter(f"{study} has no {key} (a recording, not trials)", param_hint=f"'--{key}'")
            kwargs[key] = value
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or key not in fields or key in ("seed", "runs", "filters"):
            allowed = sorted(k for k in fields if k not in ("seed", "runs", "filters"))
            raise click.BadParameter(f"expected KEY=VALUE with KEY one of {allowed}, got {item!r}",
                                     param_hint="'--set'")
        try:
            parsed = json.loads(f"[{value}]") if key == "angles_deg" else json.loads(value)
        except json.JSONDecodeError:
            parsed = value  # a name or a list of names (trials=01,07; realdata=PATH): the study checks it
        default = fields[key].default
        number = isinstance(parsed, int | float) and not isinstance(parsed, bool)
        if isinstance(default, int | float) and not isinstance(default, bool) and not number:
            raise click.BadParameter(f"{key}: expected a number, got {value!r}", param_hint="'--set'")
        kwargs[key] = value if isinstance(parsed, bool) else parsed  # true/false is no number: left as text
    try:
        st = spec.settings(**kwargs)
    except (ValueError, TypeError) as err:
        raise click.UsageError(str(err)) from err
    result = spec.run(st, progress=progress)
    click.echo(spec.markdown(result))
    written = spec.save(result, d)
    for sname, sysr in result.get("systems", {}).items():
        for name, e in sysr["filters"].items():
            failed = sum(r["failed"] for r in e["angles"])
            if failed:
                click.echo(f"WARNING: {sname}: {name} failed in {failed} trials (counted as not converged)", err=True)
    for rid, rec in result.get("recordings", {}).items():
        for name, e in rec["filters"].items():
            if e["failed"]:
                click.echo(f"WARNING: recording {rid}: {name} failed on {e['failed']} of {e['runs']} seeds; left out "
                           "of the statistics", err=True)
    for tid, per in result.get("trials", {}).items():
        for name, r in per["filters"].items():
            if not r["ok"]:
                click.echo(f"WARNING: trial {tid}: {name} failed: {r['status']}; its errors are of the states before",
                           err=True)
    for name, e in result.get("filters", {}).items():
        failed = e.get("diverged", {}).get("count", 0)
        if failed:
            first = e["diverged"]["trials"][0]
            click.echo(f"WARNING: {name}: {failed} of {e['runs']} trials failed (first: trial {first['trial']}, "
                       f"{first['cause']} at t = {first['time']:.3f} s); left out of the statistics", err=True)
        for r in e.get("angles", []):
            if r["failed"]:
                click.echo(f"WARNING: {name}: {r['failed']} of {r['trials']} trials at {r['angle_deg']:g} deg "
                           "failed (counted as not converged)", err=True)
    click.echo(f"Wrote {', '.join(p.name for p in written)} to {d}")


@cli.group("campaign")
def campaign_group():
    """Monte Carlo campaigns over a grid of settings on Dask: resumable, fault-tolerant.

    A campaign file (TOML or YAML) names an experiment (or an experiment file), a grid of config values, the
    seeds per setting and an output folder; see `liemef campaign run --help` and docs/campaigns.md."""


def _load_campaign(path: Path, out: Path | None):
    from .studies.campaign import Campaign, CampaignError

    try:
        return Campaign.load(path, out=None if out is None else str(out.resolve()))
    except CampaignError as err:
        raise click.BadParameter(str(err), param_hint="'FILE'") from err


@campaign_group.command("run")
@click.argument("file", type=click.Path(path_type=Path), metavar="FILE")
@click.option("--out", type=click.Path(path_type=Path), help="Output folder (default: the file's `out`).")
@click.option("--scheduler", metavar="tcp://HOST:PORT",
              help="Use this running Dask scheduler and its workers (default: a local cluster).")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True,
              help="Worker processes of the local cluster (one thread each).")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="Tasks done, trial-steps/s and time left on stderr.")
def campaign_run(file, out, scheduler, workers, progress):
    """Run the campaign FILE, or resume it: tasks already in its output folder are not computed again.

    Each setting's trials run as tasks of whole compiled vmap batches on Dask; each result is written to the
    output folder as it arrives (tasks/, manifest.jsonl with a SHA-256 per task). When all are finished:
    settings/*/montecarlo.{npz,json,md,csv}, summary.md, summary.csv and result.json. Trial i of a setting
    uses the key of `liemef montecarlo` trial i, so the statistics are the same. Exit status: 0 when complete,
    1 on an error (the failed task is named; finished tasks are kept), 130 when interrupted (Ctrl-C or
    SIGTERM): run the same command again to resume."""
    import signal

    from .studies.campaign import CampaignError, run_campaign

    c = _load_campaign(file, out)

    def terminate(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        result = run_campaign(c, scheduler=scheduler, workers=workers, progress=progress)
    except CampaignError as err:
        raise click.ClickException(str(err)) from err
    except KeyboardInterrupt:
        raise SystemExit(130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    click.echo(result.to_markdown())
    rate = "--" if result.rate is None else f"{result.rate:.3g}"
    click.echo(f"{result.computed} tasks computed, {result.reused} reused from earlier runs; {result.elapsed:.1f} s, "
               f"{rate} trial-steps/s on {result.workers} worker(s)")
    for s, r in zip(result.settings, result.results, strict=True):
        if r.n_nonfinite:
            click.echo(f"WARNING: setting {s.index} ({s.label}): {r.divergence_summary()}; left out of its "
                       "statistics", err=True)
    click.echo(f"Wrote {c.out}/summary.md, summary.csv, result.json and settings/*/montecarlo.*")


@campaign_group.command("status")
@click.argument("file", type=click.Path(path_type=Path), metavar="FILE")
@click.option("--out", type=click.Path(path_type=Path), help="Output folder (default: the file's `out`).")
def campaign_status(file, out):
    """How far the campaign FILE has come: finished tasks per setting (verified against their checksums),
    and whether its results are complete. Runs nothing."""
    from .studies.campaign import CAMPAIGN_FILE, RESULT_FILE, CampaignError, Store

    c = _load_campaign(file, out)
    if not (c.out / CAMPAIGN_FILE).exists():
        click.echo(f"campaign {c.name}: not started ({c.out} has no {CAMPAIGN_FILE}); "
                   f"{len(c.tasks())} tasks to run")
        return
    try:
        store = Store.open(c)
    except CampaignError as err:
        raise click.ClickException(str(err)) from err
    done = store.finished()
    tasks = c.tasks()
    for p in store.problems:
        click.echo(p)
    for s in c.points():
        mine = [t for t in tasks if t.setting == s.index]
        n = sum(t.id in done for t in mine)
        click.echo(f"setting {s.index} ({s.label}): {n}/{len(mine)} tasks")
    complete = len(done) == len(tasks) and (c.out / RESULT_FILE).exists()
    click.echo(f"campaign {c.name}: {len(done)}/{len(tasks)} tasks finished; "
               + ("complete" if complete else "incomplete: `liemef campaign run` resumes it"))


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``liemef``)."""
    cli.main(args=argv, prog_name="liemef")


if __name__ == "__main__":
    main()
