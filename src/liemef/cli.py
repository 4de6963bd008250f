"""The ``liemef`` command line.

* ``liemef reproduce EXPERIMENT --out DIR [--seed N] [--duration T] [--connection zero|minus|plus]
  [--order second|first]``: run a paper experiment, write ``metrics.json``, ``arrays.npz`` and its figures to
  DIR and print the error table (mean, std, rms of each component over the whole run and the steady window).
* ``liemef run --system NAME --log FILE --out DIR``: filter a recorded log (CSV or NPZ, see
  :mod:`liemef.io`) and write the estimates (``estimates.csv``, ``arrays.npz``, ``metrics.json``, a figure).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import click
import jax
import numpy as np

from . import __version__, io, plots
from .connections import CARTAN_SCHOUTEN
from .experiments import EXPERIMENTS, SCHEMA, SYSTEMS, get_experiment, get_system
from .filter import MinimumEnergyFilter
from .metrics import FULL, angle_mask, continuous_angles, error_table, gain_stats, state_labels

CONNECTIONS = tuple(CARTAN_SCHOUTEN)
ORDERS = ("second", "first")


def _out_dir(out: Path) -> Path:
    try:
        return io.ensure_dir(out)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--out'") from err


def _floats(text: str | None, n: int, option: str) -> np.ndarray | None:
    if text is None:
        return None
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
    lines = "\n".join(f"  {e.name:<14} {e.paper}" for e in EXPERIMENTS.values())
    return ("Run a paper EXPERIMENT and write metrics.json, arrays.npz and its figures to --out, then print "
            "the error table.\n\n\b\nExperiments:\n" + lines)


@cli.command(help=_experiments_help())
@click.argument("experiment", type=click.Choice(sorted(EXPERIMENTS)), metavar="EXPERIMENT")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Output folder (created if missing).")
@click.option("--seed", type=int, help="Random seed (default: the experiment's, 0).")
@click.option("--duration", type=float, help="Final time T in seconds (default: the paper's).")
@click.option("--connection", type=click.Choice(CONNECTIONS),
              help="Cartan-Schouten connection (default: zero).")
@click.option("--order", type=click.Choice(ORDERS),
              help="second: the paper filter; first: the left-invariant EKF.")
def reproduce(experiment, out, seed, duration, connection, order):
    exp = get_experiment(experiment)
    overrides = {k: v for k, v in {"seed": seed, "duration": duration, "connection": connection,
                                   "order": order}.items() if v is not None}
    try:
        config = exp.config(**overrides)
    except ValueError as err:
        raise click.UsageError(str(err)) from err
    d = _out_dir(out)
    t0 = time.perf_counter()
    result = exp.run(config)
    elapsed = time.perf_counter() - t0
    io.write_result(d, result.metrics, result.arrays)
    figs = plots.write_figures(d)
    click.echo(f"{exp.name}: {exp.title}")
    click.echo(f"  {exp.paper}; seed {config.seed}, T = {config.duration:g} s, dt = {config.dt:g} s, "
               f"connection {config.connection}, order {config.order} ({elapsed:.1f} s)")
    click.echo("Errors truth - estimate (angles wrapped):")
    click.echo(result.table.format())
    gain = result.metrics.get("gain", {})
    if gain:
        click.echo(f"Gain K: max |K - K'|/|K| = {gain['max_rel_asymmetry']:.2e}, "
                   f"min eigenvalue = {gain['min_eigenvalue']:.3e}")
    if not result.metrics["run"]["finite"]:
        click.echo("WARNING: the filter produced non-finite values (diverged)", err=True)
    names = [io.METRICS_FILE, io.ARRAYS_FILE] + [p.name for p in figs]
    click.echo(f"Wrote {', '.join(names)} to {d}")


@cli.command("run")
@click.option("--system", "system_name", required=True, type=click.Choice(sorted(SYSTEMS)),
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
