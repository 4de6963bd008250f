"""The ``liemef`` command line: it parses, calls the library and prints.

Every choice and help list comes from :mod:`liemef.studies.registry` and :mod:`liemef._names`, which load without
JAX, so ``liemef --help`` answers at once and bad arguments are reported before JAX is imported. The work is the
library's: :meth:`~liemef.studies.experiments.Experiment.reproduce`, :func:`~liemef.studies.experiments.montecarlo`,
:func:`liemef.studies.logs.filter_log_to`, :func:`liemef.codegen.export_c`, :func:`liemef.studies.datasets.convert`,
the comparisons of :mod:`liemef.studies.compare` and :func:`liemef.studies.campaign.run_campaign`.

Output folders are complete or absent (:mod:`liemef.reports.outputs`): written beside ``--out`` and renamed into
place with a ``manifest.json``; a folder holding another command's files is refused unless ``--force``.
Exit status: 0 ok, 1 a failed run (or a Monte Carlo or comparison with no usable trial, or a full disk),
2 bad input, 130 interrupted (Ctrl-C or SIGTERM).
"""

from __future__ import annotations

import math
import signal
import sys
from pathlib import Path

import click

from . import __version__, _names
from .reports import outputs
from .studies import registry

EXPERIMENTS = registry.names("experiment")
COMPARISONS = registry.names("comparison")
SYSTEMS = tuple(sorted(registry.SYSTEMS))
EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 1, 2, 130


class _Commands(click.Group):
    """The command group, mapping what the library raises to the exit codes: a ValueError (bad input) to 2, an
    OSError (a full disk, a vanished folder) to 1, Ctrl-C and SIGTERM to 130, each with a message and no
    traceback."""

    def invoke(self, ctx):
        def terminate(signum, frame):
            raise KeyboardInterrupt

        previous = signal.signal(signal.SIGTERM, terminate)
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            click.echo("Interrupted (exit status 130).", err=True)
            ctx.exit(EXIT_INTERRUPTED)
        except outputs.OutputRefused as err:
            raise click.BadParameter(str(err).removeprefix("--out: "), param_hint="'--out'") from err
        except ValueError as err:
            option = getattr(err, "option", None)
            if option is not None:
                raise click.BadParameter(str(err), param_hint=f"'{option}'") from err
            raise click.UsageError(str(err)) from err
        except OSError as err:
            where = f" {err.filename!r}" if err.filename else ""
            raise click.ClickException(f"cannot write{where}: {err.strerror or err}; nothing was written") from err
        finally:
            signal.signal(signal.SIGTERM, previous)


def _floats(text: str | None, option: str):
    """Comma-separated finite numbers (their count is the library's to check)."""
    if text is None:
        return None
    try:
        v = [float(s) for s in text.replace(",", " ").split()]
    except ValueError as err:
        raise click.BadParameter(f"expected numbers separated by commas, got {text!r}", param_hint=option) from err
    if not v or not all(math.isfinite(x) for x in v):
        raise click.BadParameter(f"expected finite numbers separated by commas, got {text!r}", param_hint=option)
    return v


def _substeps(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise click.BadParameter(f"expected 'auto' or an integer >= 1, got {text!r}", param_hint="'--substeps'")
    return value


def _echo_written(files, out: Path) -> None:
    click.echo(f"Wrote {', '.join(p.name for p in files)} to {out}")


FORCE = click.option("--force", is_flag=True, help="Replace --out even if it holds files of another command.")
SETTINGS = click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
                        help="Override any config field (repeatable), e.g. --set dt=0.01 --set alpha=0.1.")


def _progress(help_text: str):
    """``--progress/--no-progress``; the value is True only when stderr is a terminal (quiet in logs, pipes)."""
    return click.option("--progress/--no-progress", default=True, show_default=True,
                        help=help_text + " Shown only when stderr is a terminal.",
                        callback=lambda ctx, param, value: value and sys.stderr.isatty())


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="liemef")
def cli():
    """Second-order-optimal minimum-energy filtering on matrix Lie groups.

    Exit status: 0 ok, 1 a failed run (or no usable trial, or a full disk), 2 bad input, 130 interrupted."""


_REPRODUCE_HELP = (
    "Run a paper EXPERIMENT and write metrics.json, arrays.npz, its figures and error tables to --out, then print "
    "the error table; with --runs N (or the experiment's default) also a Monte Carlo of N seeded trials "
    "(montecarlo.md/.csv/.json/.npz).\n\n`reproduce all --out DIR` runs every experiment at a reduced size (--quick, "
    "the default) or at the papers' size (--full), one folder each, and writes DIR/index.md. `reproduce --list` "
    "lists the experiments with their papers, figures and tables.\n\n\b\nExperiments:\n"
    + "\n".join(f"  {s.name:<14} {s.paper}" for s in registry.STUDIES["experiment"].values()))


@cli.command(help=_REPRODUCE_HELP)
@click.argument("experiment", required=False, type=click.Choice([*sorted(EXPERIMENTS), "all"]),
                metavar="EXPERIMENT|all")
@click.option("--list", "list_", is_flag=True, help="List the experiments (paper, figures, tables) and exit.")
@click.option("--out", type=click.Path(path_type=Path), help="Output folder (created if missing).")
@click.option("--quick/--full", default=None, help="The experiment's reduced laptop size, or the paper's (default: "
              "--full for one experiment, --quick for all).")
@click.option("--runs", type=click.IntRange(min=0), help="Monte Carlo trials (default: the experiment's; 0: the "
              "seeded run only).")
@click.option("--seed", type=int, help="Random seed (default: the experiment's, 0).")
@click.option("--duration", type=float, help="Final time T in seconds (default: the paper's).")
@click.option("--connection", type=click.Choice(_names.CONNECTIONS), help="Cartan-Schouten connection (default: zero).")
@click.option("--order", type=click.Choice(_names.ORDERS), help="second: the paper filter; first: the left-invariant "
              "EKF.")
@SETTINGS
@FORCE
@_progress("Monte Carlo progress on stderr.")
def reproduce(experiment, list_, out, quick, runs, seed, duration, connection, order, settings, force, progress):
    if list_:
        from .studies.experiments import listing

        click.echo(listing())
        return
    if experiment is None:
        raise click.UsageError("Missing argument 'EXPERIMENT|all' (or --list).")
    if out is None:
        raise click.UsageError("Missing option '--out'.")
    from .studies import runs as _runs

    options = {"seed": seed, "duration": duration, "connection": connection, "order": order}
    if experiment == "all":
        saved = _runs.reproduce_all_to(out, quick=quick is not False, runs=runs, settings=settings, force=force,
                                       progress=progress, echo=lambda text: click.echo(text + "\n"), **options)
        failed = saved.failed
        click.echo(f"Wrote {len(saved.done) - len(failed)} of {len(saved.done)} experiments and {saved.index.name} "
                   f"to {saved.out}")
        for r in failed:
            click.echo(f"FAILED {r.experiment}: {r.error}", err=True)
        if failed:
            raise click.ClickException(f"{len(failed)} experiment(s) failed: {', '.join(r.experiment for r in failed)}")
        return
    one = _runs.reproduce_to(out, experiment, quick=bool(quick), runs=runs, settings=settings, force=force,
                             progress=progress, **options)
    click.echo(one.text)
    for w in one.warnings:
        click.echo(w, err=True)


@cli.command("montecarlo")
@click.argument("experiment", type=click.Choice(sorted(EXPERIMENTS)), metavar="EXPERIMENT")
@click.option("--runs", type=click.IntRange(min=1), default=100, show_default=True, help="Number of trials.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Trial i uses jax.random.split(jax.random.key(seed), runs)[i].")
@click.option("--batch-size", type=click.IntRange(min=1), default=registry.DEFAULT_BATCH_SIZE, show_default=True,
              help="Trials per compiled vmap batch (the results do not depend on it).")
@click.option("--out", type=click.Path(path_type=Path),
              help="Write montecarlo.npz/.json/.md/.csv to this folder (created if missing).")
@click.option("--duration", type=float,
              help=f"Final time T in seconds (default: the paper's); {registry.DURATION_RULE}.")
@click.option("--quick", is_flag=True, help="Start from the experiment's reduced config.")
@SETTINGS
@FORCE
@_progress("Trials done, elapsed time and ETA on stderr.")
def montecarlo_cmd(experiment, runs, seed, batch_size, out, duration, quick, settings, force, progress):
    """Run N seeded trials of EXPERIMENT, batched with vmap, and print the statistics: per trial the mean, std
    and rms over time of each error component, then across trials their mean, spread and percentiles. Exit
    status 1 when no trial is usable (every one diverged): then --out holds failure.json alone."""
    from .studies.runs import montecarlo_to

    saved = montecarlo_to(out, experiment, runs, seed=seed, batch_size=batch_size, duration=duration, quick=quick,
                          settings=settings, force=force, progress=progress)
    exp, result = saved.experiment, saved.result
    click.echo(f"{exp.name}: {exp.title}\n  {exp.paper}")
    click.echo(result.format())
    click.echo(f"{result.runs} trials in {result.elapsed:.1f} s ({result.runs / result.elapsed:.1f} trials/s "
               f"including compilation), {result.batch_size} per batch")
    if result.n_nonfinite:
        click.echo(f"WARNING: {result.divergence_summary()} (trials "
                   f"{', '.join(map(str, result.nonfinite_trials[:20]))}); they are left out of the statistics",
                   err=True)
    if saved.out is not None:
        _echo_written(saved.written, saved.out)
    if not saved.usable:
        raise click.ClickException(f"no usable trial: {result.divergence_summary()}")


SYSTEM_FILE = click.option("--system-file", type=click.Path(path_type=Path), help="A Python file that defines "
                           "`system` (your own liemef system) and optionally K0, x0, initial_guess(y0).")


def _system_option(help_text: str):
    return click.option("--system", "system_name", type=click.Choice(SYSTEMS), help=help_text)


@cli.command("run")
@_system_option("A ready system the log was recorded with (or --system-file).")
@SYSTEM_FILE
@click.option("--log", "log_path", required=True, type=click.Path(path_type=Path),
              help="Recorded log: CSV with the system's columns (`liemef schema SYSTEM`; an empty field is a "
                   "missing sample), NPZ with ts, us, ys (or one time vector per sensor), or a ROS bag with --topics.")
@click.option("--topics", type=click.Path(path_type=Path), help="With a ROS 1 .bag or a ROS 2 bag folder as "
              "--log: the JSON/TOML mapping from topics to the system's columns (liemef.reports.rosbag).")
@click.option("--tum/--no-tum", default=False, help="Also write the estimates as a TUM trajectory, estimates.tum.")
@click.option("--out", required=True, type=click.Path(path_type=Path), help="Output folder (created if missing).")
@click.option("--x0", help="Initial estimate in coordinates, comma separated (default: the system file's x0, "
              "else read off the first present measurements).")
@click.option("--k0", type=float, help="Initial gain K(0) = k0 * I (default: the system file's K0, else 1).")
@click.option("--k0-diag", help="Initial gain K(0) = diag(...), comma separated (overrides --k0).")
@click.option("--connection", type=click.Choice(_names.CONNECTIONS), default="zero", show_default=True)
@click.option("--order", type=click.Choice(_names.ORDERS), default="second", show_default=True)
@click.option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
@click.option("--interpolation", type=click.Choice(_names.INTERPOLATIONS), default="hold", show_default=True,
              help="Inputs and dense measurements held over each interval, or linear between samples.")
@click.option("--updates", type=click.Choice(_names.UPDATES), default="hold", show_default=True,
              help="Sample sensors: held over the interval after their time stamp (the papers' scheme), or used "
              "at their own time (the hybrid filter: recommended for sample sensors).")
@click.option("--substeps", default="auto", show_default=True,
              help="Integrator steps per sample interval: auto (by stiffness) or a number.")
@click.option("--gap", type=float, help="An interval longer than this (s) is a gap: predicted through, dense "
              "measurements not held (default: 10 x the median interval).")
@click.option("--chunk", type=click.IntRange(min=16), default=65536, show_default=True,
              help="Samples per compiled chunk (progress is shown between chunks).")
@click.option("--params", "params_file", type=click.Path(path_type=Path),
              help="A tuning file of `liemef tune` (JSON): its final parameter set for --system attitude-imu.")
@FORCE
@_progress("Progress on stderr (on a terminal).")
def run_log(system_name, system_file, log_path, topics, tum, out, x0, k0, k0_diag, connection, order, alpha,
            interpolation, updates, substeps, gap, chunk, params_file, force, progress):
    """Filter a recorded log with a ready system or your own, and write the estimates, K's diagonal and the
    innovations to --out. A failed run (non-finite, K no longer symmetric or positive definite, a gate) writes
    only failure.json, says where, when and why, and exits with status 1."""
    from .studies import logs

    saved = logs.filter_log_to(out, log_path, system=system_name, system_file=system_file, topics=topics,
                               params=params_file, x0=_floats(x0, "'--x0'"),
                               K0=_floats(k0_diag, "'--k0-diag'") if k0_diag is not None else k0, tum=tum,
                               force=force, connection=connection, order=order, alpha=alpha,
                               interpolation=interpolation, updates=updates, substeps=_substeps(substeps), gap=gap,
                               chunk=chunk, progress=progress)
    run = saved.run
    click.echo(f"Filtered {saved.log.ts.shape[0]} samples of {log_path} with {run.source.label} ({run.filter})")
    if run.rejected():
        click.echo("Gate rejected samples: " + ", ".join(f"{k} {v}" for k, v in run.rejected().items()))
    for w in run.warnings():
        click.echo(f"WARNING: {w}", err=True)
    if not run.ok:
        raise click.ClickException(f"{run.message} (cause: {run.report['cause']}). No estimates were written; see "
                                   f"{saved.out / 'failure.json'}")
    click.echo("Innovation y - h(g_hat) over the present samples:")
    click.echo(run.innovation_text)
    click.echo(f"Sub-steps: {run.report['substeps_total']} over {run.report['steps']} intervals (at most "
               f"{run.report['substeps_max']} in one)")
    click.echo(f"Wrote estimates.csv (coordinates and K's diagonal), innovations.csv, metrics.json, arrays.npz, "
               f"{', '.join(p.name for p in saved.written[4:])} to {saved.out}")


@cli.command("export-c")
@_system_option("A ready system (or --system-file).")
@click.option("--system-file", type=click.Path(path_type=Path), help="A Python file that defines `system`.")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Folder for NAME.h and NAME.c (created if missing).")
@click.option("--name", help="The C prefix of every exported name, a C identifier (default: the system's name with "
                             "- replaced by _).")
@click.option("--connection", type=click.Choice(_names.CONNECTIONS), default="zero", show_default=True)
@click.option("--order", type=click.Choice(_names.ORDERS), default="second", show_default=True)
@click.option("--integrator", type=click.Choice(_names.EXPORT_INTEGRATORS), default="rkmk4", show_default=True)
@click.option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
@click.option("--substeps", default="auto", show_default=True,
              help="Integrator steps per sample interval: auto (by stiffness) or a number.")
@click.option("--max-substeps", type=click.IntRange(min=1), default=256, show_default=True,
              help="The most steps 'auto' takes in one interval.")
@click.option("--backend", type=click.Choice(_names.C_BACKENDS), default="auto", show_default=True,
              help="scalar: straight-line code (fast, its size grows as n^3); array: loops over arrays (compact); "
                   "auto: scalar up to n = 12.")
def export_c_cmd(system_name, system_file, out, name, connection, order, integrator, alpha, substeps, max_substeps,
                 backend):
    """Write the filter of a ready system (--system) or of your own (--system-file) as standalone C99: NAME.h
    and NAME.c in --out, with NAME_init, NAME_step (one sample interval, exactly as the filter's step), NAME_run
    and the coordinate maps. No heap, no library but libm; the weights, connection and parameters are constants
    of the source (export again for new ones). The two files are written in place, each whole or not at all
    (the folder may be your project's). See docs/export-c.md."""
    from .studies.runs import export_c_to

    try:
        saved = export_c_to(out, system=system_name, system_file=system_file, name=name, connection=connection,
                            order=order, integrator=integrator, alpha=alpha, substeps=_substeps(substeps),
                            max_substeps=max_substeps, backend=backend)
    except NotImplementedError as err:  # liemef.codegen.UnsupportedPrimitive: the step uses what C lacks
        raise click.ClickException(str(err)) from err
    click.echo(f"Exported {saved.source.label} ({saved.filter!r}) as C99 ({saved.backend} code):")
    click.echo(f"  {saved.exported.header}\n  {saved.exported.source}")
    click.echo(saved.exported.api_summary(saved.source.system))


@cli.command("schema")
@click.argument("system_name", required=False, type=click.Choice(SYSTEMS), metavar="SYSTEM")
@click.option("--system-file", type=click.Path(path_type=Path), help="A Python file that defines `system`.")
def schema(system_name, system_file):
    """Print the log columns of SYSTEM (a ready system) or of --system-file: names, units, roles and the
    sensors' noise levels, and the CSV header that `liemef run` expects."""
    if system_name is not None and system_file is None:  # a ready system: no JAX
        known = registry.system_schema(system_name)
        click.echo(f"{system_name}: {known['description']}")
        click.echo(known["text"])
        return
    from .studies.logs import resolve_system
    from .systems._file import format_schema

    source = resolve_system(system_name, system_file)
    click.echo(f"{source.label}: {source.description}")
    click.echo(format_schema(source.system))


@cli.command("dataset")
@click.argument("kind", type=click.Choice(registry.DATASETS))
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
    from .studies import datasets

    try:
        log, system, written = datasets.convert(kind, path, out, truth=truth, seconds=seconds, gps_std=gps_std,
                                                norms=norms)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'PATH'") from err
    click.echo(f"{kind} {path}: {log.ts.shape[0]} samples over {log.ts[-1] - log.ts[0]:.1f} s; wrote "
               f"{', '.join(str(p) for p in written)}")
    click.echo(f"Filter it with: liemef run --system {system} --log {out} --out DIR")


@cli.command("tune")
@click.argument("data", type=click.Choice(registry.TUNE_DATA))
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="Output folder: tune.json (the tuned set, for run/compare --set params=...) and tune.md.")
@click.option("--objective", type=click.Choice(tuple(registry.TUNE_OBJECTIVES)), default="truth", show_default=True,
              help="; ".join(f"{k}: {v}" for k, v in registry.TUNE_OBJECTIVES.items()) + ".")
@click.option("--trials", metavar="A,B,...", help="BROAD trial ids (default: every trial present).")
@click.option("--params", "names", metavar="A,B,...", help="Parameters to tune (default: liemef.studies.tune's).")
@click.option("--seconds", type=float, default=90.0, show_default=True,
              help="Tune on the first SECONDS of each trial (0: whole trials); evaluate with `compare broad`.")
@click.option("--maxfev", type=click.IntRange(min=1), default=40, show_default=True,
              help="Evaluations of the shared search (each runs every trial).")
@click.option("--fold-maxfev", type=click.IntRange(min=1), default=12, show_default=True,
              help="Evaluations of each leave-one-out fold's refinement.")
@click.option("--system", "system_name", type=click.Choice(tuple(registry.TUNE_SYSTEMS)), default="attitude-imu",
              show_default=True, help="The model: " + " or ".join(f"{k} ({v})" for k, v in
                                                                    registry.TUNE_SYSTEMS.items()) + ".")
@click.option("--updates", type=click.Choice(_names.UPDATES), default="hold", show_default=True,
              help="discrete: samples at their own time (the hybrid update, gyro sample k over the interval "
                   "ending at t_k), as compare broad's mef-imu-d.")
@click.option("--realdata", type=click.Path(path_type=Path), help="The real-data folder (default: found).")
@FORCE
@_progress("A progress bar on stderr.")
def tune_cmd(data, out, objective, trials, names, seconds, maxfev, fold_maxfev, system_name, updates, realdata,
             force, progress):
    """Fit an IMU model's noise levels (--system) to the BROAD trials present, by a derivative-free
    search, with leave-one-trial-out cross-validation; writes the held-out and training errors and the tuned
    set (tune.json, accepted by `liemef run --params` and `liemef compare broad --set params=...`)."""
    from .studies.runs import tune_to

    saved = tune_to(out, data, objective=objective, trials=None if not trials else trials.split(","),
                    names=None if not names else [n.strip() for n in names.split(",")], seconds=seconds,
                    maxfev=maxfev, fold_maxfev=fold_maxfev, system=system_name, updates=updates, realdata=realdata,
                    force=force, progress=progress)
    click.echo(saved.markdown)
    click.echo(f"Wrote {' and '.join(p.name for p in saved.written)} to {saved.out}")


_COMPARE_HELP = (
    "Compare the minimum-energy filter with the filters people use on STUDY, on the same trials.\n\n"
    "\b\nFilters (--filters; each study's default set is in its tables):\n"
    + "\n".join(f"  {name:<11} {description}" for name, description in registry.FILTERS.items()) + "\n\n"
    + "\n\n".join(f"{s.name}: {s.help}" for s in registry.STUDIES["comparison"].values())
    + "\n\nTrials where a filter fails are counted and named, and left out of the statistics. Exit status 1 when "
    "no trial of any filter is usable.")


@cli.command("compare", help=_COMPARE_HELP)
@click.argument("study", type=click.Choice(COMPARISONS))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Output folder (created if missing).")
@click.option("--runs", type=click.IntRange(min=1), help="Trials (the same for every filter; default: the study's).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="First seed: trial i uses split(key(seed), runs)[i] (localization with --set rng=numpy: ukfm's "
                   "stream seeded seed + i, as inertial-navigation; wifibot: the GPS noise of seed + i).")
@click.option("--filters", metavar="A,B,...", help="Filters to compare (default: all of the study's).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Any other setting of the study (repeatable). " + " ".join(
                  f"{s.name}: {', '.join(s.settings)}." for s in registry.STUDIES["comparison"].values()))
@FORCE
@_progress("One line per filter.")
def compare_cmd(study, out, runs, seed, filters, settings, force, progress):
    from .studies.runs import compare_to

    saved = compare_to(out, study, runs=runs, seed=seed, filters=filters, settings=settings, force=force,
                       progress=progress)
    click.echo(saved.markdown)
    for line in saved.warnings:
        click.echo(f"WARNING: {line}", err=True)
    _echo_written(saved.written, saved.out)
    if not saved.usable:
        raise click.ClickException(f"no usable trial: every filter failed in all {saved.total} trials")


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
@_progress("Tasks done, trial-steps/s and time left on stderr.")
def campaign_run(file, out, scheduler, workers, progress):
    """Run the campaign FILE, or resume it: tasks already in its output folder are not computed again.

    Each setting's trials run as tasks of whole compiled vmap batches on Dask; each result is written to the
    output folder as it arrives (tasks/, manifest.jsonl with a SHA-256 per task). When all are finished:
    settings/*/montecarlo.{npz,json,md,csv}, summary.md, summary.csv and result.json. Trial i of a setting
    uses the key of `liemef montecarlo` trial i, so the statistics are the same. Exit status: 0 when complete,
    1 on an error (the failed task is named; finished tasks are kept), 130 when interrupted (Ctrl-C or
    SIGTERM): run the same command again to resume."""
    from .studies.campaign import CampaignError, run_campaign

    c = _load_campaign(file, out)
    try:
        result = run_campaign(c, scheduler=scheduler, workers=workers, progress=progress)
    except CampaignError as err:
        raise click.ClickException(str(err)) from err
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
    from .studies.campaign import CampaignError, status_lines

    c = _load_campaign(file, out)
    try:
        click.echo("\n".join(status_lines(c)))
    except CampaignError as err:
        raise click.ClickException(str(err)) from err


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``liemef``, ``python -m liemef``)."""
    cli.main(args=argv, prog_name="liemef")


if __name__ == "__main__":
    main()
