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
* ``liemef run --system NAME --log FILE --out DIR``: filter a recorded log (CSV or NPZ, see
  :mod:`liemef.io`) and write the estimates (``estimates.csv``, ``arrays.npz``, ``metrics.json``, a figure).
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
    "tse2": "Rigo, Segala, Sansonetto, Muradore 2022, Sec. VI, Figs. 3-4",
    "tse2-velocity": "Segala, Sansonetto, Muradore, poster 'Tracking and filtering on SE(2)'; setup of Rigo et al. "
                     "2022",
    "unit-circle": "Zamani, Hua, Trumpf, Mahony, 'Minimum-Energy Filtering on the Unit Circle Using Velocity "
                   "Measurements with Bias and Vectorial State Measurements', Sec. IV, Figs. 2-3",
}
"""``liemef.experiments.EXPERIMENTS``: each experiment's name and paper, in the registry's order."""
SYSTEM_NAMES = ("attitude", "chaplygin", "chaplygin-gps", "tse2", "tse2-velocity", "unit-circle")
"""``sorted(liemef.experiments.SYSTEMS)``."""
CONNECTIONS = ("minus", "zero", "plus")
"""``tuple(liemef.connections.CARTAN_SCHOUTEN)``."""
ORDERS = ("second", "first")
"""``liemef.filter.ORDERS``."""
DEFAULT_BATCH_SIZE = 8
"""``liemef.experiments.DEFAULT_BATCH_SIZE``."""


def _out_dir(out: Path) -> Path:
    from . import io

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
    from .experiments import EXPERIMENTS

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
    from .experiments import Failure, get_experiment, reproduce_all
    from .experiments._reproduce import INDEX_FILE

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
    from .experiments import EXPERIMENTS, get_experiment, montecarlo

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
        click.echo(f"WARNING: {result.n_nonfinite} of {result.runs} trials produced non-finite errors (diverged; "
                   f"trials {', '.join(map(str, result.nonfinite_trials[:20]))}); they are left out of the "
                   "statistics", err=True)
    if d is not None:
        written = result.save(d)
        click.echo(f"Wrote {', '.join(p.name for p in written)} to {d}")


@cli.command("run")
@click.option("--system", "system_name", required=True, type=click.Choice(SYSTEM_NAMES),
              help="The model the log was recorded with.")
@click.option("--log", "log_path", required=True, type=click.Path(path_type=Path),
              help="Recorded log: CSV with header t,u1..um,y1..yp or NPZ with ts, us, ys.")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Output folder (created if missing).")
@click.option("--x0", help="Initial estimate in coordinates, comma separated (default: from the first "
              "sample).")
@click.option("--k0", type=float, default=1.0, show_default=True, help="Initial gain K(0) = k0 * I.")
@click.option("--k0-diag", help="Initial gain K(0) = diag(...), comma separated (overrides --k0).")
@click.option("--connection", type=click.Choice(CONNECTIONS), default="zero", show_default=True)
@click.option("--order", type=click.Choice(ORDERS), default="second", show_default=True)
@click.option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
def run_log(system_name, log_path, out, x0, k0, k0_diag, connection, order, alpha):
    """Filter a recorded log with a ready system and write the estimates to --out."""
    import jax
    import numpy as np

    from . import io, plots
    from .experiments import SCHEMA, get_system
    from .filter import MinimumEnergyFilter
    from .metrics import FULL, angle_mask, continuous_angles, error_table, gain_stats, state_labels

    spec = get_system(system_name)
    system = spec.make()
    n, c = system.group.tangent_dim, system.group.coords_dim
    try:
        log = io.read_log(log_path, system.input_dim, system.output_dim)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--log'") from err
    q0 = _floats(x0, c, "'--x0'")
    q0 = spec.initial_guess(log.ys[0]) if q0 is None else q0
    K0 = np.diag(_floats(k0_diag, n, "'--k0-diag'")) if k0_diag is not None else k0 * np.eye(n)
    if not (math.isfinite(k0) and k0 >= 0):
        raise click.BadParameter(f"expected a number >= 0, got {k0}", param_hint="'--k0'")
    d = _out_dir(out)
    try:
        flt = MinimumEnergyFilter(system, connection=connection, order=order, alpha=alpha)
        state = flt.init(system.group.from_coords(q0), K0)
        traj = flt.run(state, log.ts, log.us, log.ys)
    except ValueError as err:
        raise click.UsageError(str(err)) from err

    names, units = state_labels(system)
    angles = angle_mask(system.group)
    filt = continuous_angles(traj.coords(), angles)
    meas = continuous_angles(spec.measured(log.ys), angles, reference=filt)
    K = np.asarray(traj.K)
    innov = np.asarray(log.ys - jax.vmap(system.output)(traj.g_hat, log.ts))
    onames = system.output_names
    table = error_table(log.ts, innov, onames, system.output_units, (FULL,))
    figures = [{"file": "estimate.png", "components": list(names),
                "title": f"{spec.name}: measured (blue), filtered (green) from {log_path.name}"}]
    metrics = {
        "schema": SCHEMA,
        "system": {"name": spec.name, "description": spec.description, "filter": repr(flt)},
        "log": {"file": str(log_path), "samples": int(log.ts.shape[0]), "t0": float(log.ts[0]),
                "t1": float(log.ts[-1])},
        "config": {"x0": [float(v) for v in q0], "K0_diag": [float(v) for v in np.diagonal(K0)],
                   "connection": connection, "order": order, "alpha": alpha},
        "innovation": {"definition": "y - h(g_hat) at each sample (before the update of that sample)",
                       "components": table.to_dict()},
        "gain": gain_stats(K),
        "run": {"finite": bool(traj.finite), "liemef_version": __version__},
        "figures": figures,
    }
    arrays = {"ts": log.ts, "names": np.array(names), "units": np.array(units), "filtered": filt,
              "measured": meas, "K_diag": np.diagonal(K, axis1=1, axis2=2), "us": log.us, "ys": log.ys,
              "innovation": innov, "output_names": np.array(onames)}
    io.write_csv(d / "estimates.csv", ["t", *names], [log.ts, *np.asarray(traj.coords()).T])
    io.write_result(d, metrics, arrays)
    figs = plots.write_figures(d)
    click.echo(f"Filtered {log.ts.shape[0]} samples of {log_path} with {spec.name} ({repr(flt)})")
    click.echo("Innovation y - h(g_hat):")
    click.echo(table.format())
    if not traj.finite:
        click.echo("WARNING: the filter produced non-finite values (diverged)", err=True)
    click.echo(f"Wrote estimates.csv, {io.METRICS_FILE}, {io.ARRAYS_FILE}, "
               f"{', '.join(p.name for p in figs)} to {d}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``liemef``)."""
    cli.main(args=argv, prog_name="liemef")
