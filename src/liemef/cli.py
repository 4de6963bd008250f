"""The ``liemef`` command line: it parses, calls the library and prints.

Every command's help, arguments and options are declared once, as data, in :mod:`liemef.studies.commands` (its
choices from :mod:`liemef.studies.registry` and :mod:`liemef._names`), which loads without JAX, so ``liemef --help``
answers at once and bad arguments are reported before JAX is imported; what a command prints after its work is
its result's ``messages()`` (and ``error``, for exit status 1). The work is the
library's: :func:`~liemef.studies.experiments.reproduce_experiment`, :func:`~liemef.studies.experiments.montecarlo`,
:func:`liemef.studies.logs.filter_log_to`, :func:`liemef.codegen.export_c`, :func:`liemef.studies.datasets.convert`,
the comparisons of :mod:`liemef.studies.compare` and :func:`liemef.studies.campaign.run_campaign`.

Output folders are complete or absent (:mod:`liemef.reports.outputs`): written beside ``--out`` and renamed into
place with a ``manifest.json``; a folder holding another command's files is refused unless ``--force``.
Exit status: 0 ok, 1 a failed run (or a Monte Carlo or comparison with no usable trial, or a full disk),
2 bad input, 3 a run of ``liemef run`` whose innovations are inconsistent with its K, 4 one whose innovations
are consistent but whose linearization the monitor calls nonlinear (outputs written whole in both), 5 a
``liemef smooth`` whose smoother did not converge (its last accepted estimates written), 130 interrupted (Ctrl-C
or SIGTERM).
"""

from __future__ import annotations

import math
import os
import signal
from pathlib import Path

import click

from . import __version__
from ._cachedirs import XLA_CACHE
from .reports import outputs
from .studies import commands, registry

EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INCONSISTENT, EXIT_NONLINEAR, EXIT_INTERRUPTED = 1, 2, 3, 4, 130
EXIT_NOT_CONVERGED = 5


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


def _param(p: commands.Param):
    """The click argument or option that the library's declaration ``p`` describes."""
    attrs = dict(p.attrs)
    if p.type is not None:
        attrs["type"] = (click.Path(path_type=Path) if p.type == commands.PATH else
                         click.Choice(p.type[1]) if isinstance(p.type, tuple) and p.type[0] == "choice" else
                         click.IntRange(min=p.type[1]) if isinstance(p.type, tuple) else p.type)
    return (click.argument if p.argument else click.option)(*p.decls, **attrs)


def _command(group, name: str, subgroup: bool = False):
    """Declare the function it decorates as the command ``name`` of ``group``, with its help and parameters from
    :data:`liemef.studies.commands.COMMANDS`."""
    spec = commands.COMMANDS[name]

    def decorate(f):
        for p in reversed(spec.params):
            f = _param(p)(f)
        make = group.group if subgroup else group.command
        return make(name.split()[-1], help=spec.help)(f)
    return decorate


def _echo(saved) -> None:
    """Print what the library's result ``saved`` says (its ``messages()``), and exit with status 1 on its
    ``error``."""
    for text, err in saved.messages():
        click.echo(text, err=err)
    if saved.error is not None:
        raise click.ClickException(saved.error)


@click.group(cls=_Commands, help=commands.CLI.help, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="liemef")
def cli():
    pass


@_command(cli, "reproduce")
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
        _echo(_runs.reproduce_all_to(out, quick=quick is not False, runs=runs, settings=settings, force=force,
                                     progress=progress, echo=lambda text: click.echo(text + "\n"), **options))
    else:
        _echo(_runs.reproduce_to(out, experiment, quick=bool(quick), runs=runs, settings=settings, force=force,
                                 progress=progress, **options))


@_command(cli, "montecarlo")
def montecarlo_cmd(experiment, runs, seed, batch_size, out, duration, quick, settings, force, progress):
    from .studies.runs import montecarlo_to

    _echo(montecarlo_to(out, experiment, runs, seed=seed, batch_size=batch_size, duration=duration, quick=quick,
                        settings=settings, force=force, progress=progress))


def _filter_log(smooth, system_name, system_file, timeout, log_path, topics, tum, out, x0, k0, k0_diag, connection,
                order, alpha, interpolation, updates, curvature, error, substeps, integrator, gap, chunk, params_file,
                settings, monitor, force, progress):
    """``liemef run`` (``smooth`` None) and ``liemef smooth`` (the smoother's options): filter the log, smooth it
    if asked, write the outputs, print, and exit with the run's status."""
    from .studies import logs

    saved = logs.filter_log_to(out, log_path, system=system_name, system_file=system_file, timeout=timeout,
                               topics=topics,
                               params=params_file, settings=settings, x0=_floats(x0, "'--x0'"),
                               K0=_floats(k0_diag, "'--k0-diag'") if k0_diag is not None else k0, tum=tum,
                               force=force, connection=connection, order=order, alpha=alpha,
                               interpolation=interpolation, updates=updates, curvature=curvature, error=error,
                               substeps=_substeps(substeps), integrator=integrator, gap=gap,
                               chunk=chunk, progress=progress, monitor=monitor, smooth=smooth)
    _echo(saved)
    if saved.run.not_converged:  # the outputs are written: an exit status of its own, for scripts
        click.get_current_context().exit(EXIT_NOT_CONVERGED)
    if saved.run.inconsistent:
        click.get_current_context().exit(EXIT_INCONSISTENT)
    if saved.run.nonlinear:
        click.get_current_context().exit(EXIT_NONLINEAR)


@_command(cli, "run")
def run_log(**params):
    _filter_log(None, **params)


@_command(cli, "smooth")
def smooth_log(max_iterations, tol, smooth_chunk, smooth_overlap, **params):
    _filter_log({"max_iterations": max_iterations, "tol": tol, "chunk": smooth_chunk, "overlap": smooth_overlap},
                **params)


@_command(cli, "export-c")
def export_c_cmd(system_name, system_file, timeout, out, name, connection, order, error, integrator, alpha,
                 substeps, max_substeps, backend):
    from .studies.runs import export_c_to

    try:
        saved = export_c_to(out, system=system_name, system_file=system_file, timeout=timeout, name=name,
                            connection=connection, error=error,
                            order=order, integrator=integrator, alpha=alpha, substeps=_substeps(substeps),
                            max_substeps=max_substeps, backend=backend)
    except NotImplementedError as err:  # liemef.codegen.UnsupportedPrimitive: the step uses what C lacks
        raise click.ClickException(str(err)) from err
    _echo(saved)


@_command(cli, "schema")
def schema(system_name, system_file, timeout):
    if system_name is not None and system_file is None:  # a ready system: no JAX
        known = registry.system_schema(system_name)
        click.echo(f"{system_name}: {known['description']}")
        click.echo(known["text"])
        return
    from .studies.logs import schema_text

    click.echo(schema_text(system_name, system_file, timeout=timeout))


@_command(cli, "dataset")
def dataset(kind, path, out, truth, seconds, gps_std, system_name, norms):
    from .studies import datasets

    try:
        log, system, written = datasets.convert(kind, path, out, truth=truth, seconds=seconds, gps_std=gps_std,
                                                norms=norms, system=system_name)
    except ValueError as err:
        said = str(err).split(":", 1)[0]
        hint = {"system": "'--system'", "out": "'--out'", "seconds": "'--seconds'", "std": "'--gps-std'",
                "gps_std": "'--gps-std'"}.get(said, "'PATH'")
        raise click.BadParameter(str(err), param_hint=hint) from err
    click.echo(f"{kind} {path}: {log.ts.shape[0]} samples over {log.ts[-1] - log.ts[0]:.1f} s; wrote "
               f"{', '.join(str(p) for p in written)}")
    click.echo(f"Filter it with: liemef run --system {system} --log {out} --out DIR")
    best = registry.dataset_systems(kind)[0]
    if system != best:
        click.echo(f"The best model of `liemef compare broad` is {best}: liemef dataset {kind} {path} --system {best} "
                   f"--out LOG, then liemef run --system {best} --log LOG --out DIR")


@_command(cli, "tune")
def tune_cmd(data, out, objective, trials, names, seconds, start, maxfev, fold_maxfev, system_name, updates,
             integrator, realdata, workers, force, progress):
    from .studies.runs import tune_to

    _echo(tune_to(out, data, objective=objective, trials=None if trials is None else trials.split(","),
                  names=None if names is None else names.split(","), seconds=seconds,
                  maxfev=maxfev, fold_maxfev=fold_maxfev, system=system_name, updates=updates,
                  integrator=integrator, realdata=realdata,
                  start=None if start is None else start.split(","), force=force, progress=progress,
                  workers=workers))


@_command(cli, "compare")
def compare_cmd(study, out, runs, seed, filters, settings, force, progress):
    from .studies.runs import compare_to

    _echo(compare_to(out, study, runs=runs, seed=seed, filters=filters, settings=settings, force=force,
                     progress=progress))


@_command(cli, "campaign", subgroup=True)
def campaign_group():
    pass


def _load_campaign(path: Path, out: Path | None):
    from .studies.campaign import Campaign, CampaignError

    try:
        return Campaign.load(path, out=None if out is None else str(out.resolve()))
    except CampaignError as err:
        raise click.BadParameter(str(err), param_hint="'FILE'") from err


@_command(campaign_group, "campaign run")
def campaign_run(file, out, scheduler, workers, progress):
    from .studies.campaign import CampaignError, CampaignInputError, run_campaign

    c = _load_campaign(file, out)
    try:
        result = run_campaign(c, scheduler=scheduler, workers=workers, progress=progress)
    except CampaignInputError as err:  # bad input (exit 2), as _load_campaign's
        raise click.BadParameter(str(err), param_hint="'FILE'") from err
    except CampaignError as err:
        raise click.ClickException(str(err)) from err
    _echo(result)


@_command(campaign_group, "campaign status")
def campaign_status(file, out):
    from .studies.campaign import CampaignError, status_lines

    c = _load_campaign(file, out)
    try:
        click.echo("\n".join(status_lines(c)))
    except CampaignError as err:
        raise click.ClickException(str(err)) from err


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``liemef``, ``python -m liemef``). Its process keeps XLA's compiled programs on disk
    (``LIEMEF_XLA_CACHE=1``, unless set otherwise: :mod:`liemef._config`), so that the next command compiles less."""
    os.environ.setdefault(XLA_CACHE, "1")
    cli.main(args=argv, prog_name="liemef")


if __name__ == "__main__":
    main()
