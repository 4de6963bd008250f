"""A study run into an output folder: what ``liemef montecarlo``, ``reproduce``, ``export-c`` and ``tune`` do,
as functions a script calls alike (``liemef run``'s is :func:`liemef.studies.logs.filter_log_to`).

>>> from liemef.studies import runs
>>> saved = runs.montecarlo_to("out", "tse2", runs=20, quick=True)       # doctest: +SKIP
>>> print(saved.result.format())                                       # doctest: +SKIP

Each writes its folder whole or not at all (:mod:`liemef.reports.outputs`: staged beside ``out``, renamed into
place with a ``manifest.json``; a folder holding another command's files is refused unless ``force``). Bad input
is a ValueError (naming its option as ``err.option`` where there is one) raised before anything is written. This
module loads without JAX: JAX is imported only when a study runs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..reports import io, outputs


def wrote(files, out: Path) -> str:
    """The line that names the ``files`` written to ``out``."""
    return f"Wrote {', '.join(Path(p).name for p in files)} to {out}"


@dataclass(frozen=True)
class SavedMonteCarlo:
    """What :func:`montecarlo_to` did: the ``experiment`` run, its ``result``
    (:class:`~liemef.studies.experiments.MonteCarloResult`), the folder ``out`` (None: nothing written) and the
    files ``written`` there; ``usable`` is False when every trial diverged (then ``written`` is ``failure.json``
    alone)."""

    experiment: Any = field(repr=False)
    result: Any = field(repr=False)
    out: Path | None
    written: list[Path]
    usable: bool

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef montecarlo`` prints, in order: each line with True where it goes to stderr (a warning)."""
        exp, result = self.experiment, self.result
        lines = [(f"{exp.name}: {exp.title}\n  {exp.paper}", False), (result.format(), False),
                 (f"{result.runs} trials in {result.elapsed:.1f} s ({result.runs / result.elapsed:.1f} trials/s "
                  f"including compilation), {result.batch_size} per batch", False)]
        if result.n_nonfinite:
            lines.append((f"WARNING: {result.divergence_summary()} (trials "
                          f"{', '.join(map(str, result.nonfinite_trials[:20]))}); they are left out of the "
                          "statistics", True))
        if self.out is not None:
            lines.append((wrote(self.written, self.out), False))
        return lines

    @property
    def error(self) -> str | None:
        """Why ``liemef montecarlo`` exits with status 1 (no usable trial), or None."""
        return None if self.usable else f"no usable trial: {self.result.divergence_summary()}"


def montecarlo_to(out: str | os.PathLike | None, experiment: str, runs: int = 100, *, seed: int = 0,
                  batch_size: int | None = None, duration: float | None = None, quick: bool = False,
                  settings=(), force: bool = False, progress: bool = False) -> SavedMonteCarlo:
    """``runs`` seeded trials of the registered ``experiment`` (:func:`liemef.studies.experiments.montecarlo`)
    at its config (``quick``: its reduced one) with ``duration`` and the ``KEY=VALUE`` ``settings`` replaced
    (the statistics windows follow a shorter duration, :data:`liemef.studies.registry.DURATION_RULE`), written
    to ``out`` (None: not written) as ``montecarlo.{npz,json,md,csv}``. When no trial is usable (every one
    diverged) ``out`` holds ``failure.json`` alone and the result says ``usable=False``. A ValueError for an
    experiment without a Monte Carlo trial or a bad setting, before anything is written."""
    from .experiments import EXPERIMENTS, get_experiment, montecarlo
    from .logs import FAILURE_SCHEMA
    from .registry import DEFAULT_BATCH_SIZE
    from .settings import experiment_config

    exp = get_experiment(experiment)
    if exp.trial_fn is None:
        with_trials = sorted(e.name for e in EXPERIMENTS.values() if e.trial_fn is not None)
        raise ValueError(f"experiment {exp.name!r} has no Monte Carlo trial; expected one of {with_trials}")
    config = experiment_config(exp, quick, {"duration": duration}, settings, windows_follow=True,
                               own={"seed": "the trials are seeded by --seed (the config's seed is a single run's)"})
    target = outputs.claim(out, "montecarlo", force) if out is not None else None
    result = montecarlo(exp, config, runs, seed=seed, batch_size=batch_size or DEFAULT_BATCH_SIZE,
                        progress=progress)
    usable = result.n_nonfinite < result.runs
    written: list[Path] = []
    if target is not None:
        with outputs.staged(target, manifest=usable) as d:
            written = result.save(d) if usable else [io.write_json(d / "failure.json", {
                "schema": FAILURE_SCHEMA, "command": "montecarlo", "message": result.divergence_summary(),
                "diverged": result.diverged(), "liemef_version": __version__})]
        written = [target.path / p.name for p in written]
    return SavedMonteCarlo(exp, result, None if target is None else target.path, written, usable)


@dataclass(frozen=True)
class SavedReproduction:
    """What :func:`reproduce_to` did: the ``reproduction``
    (:class:`~liemef.studies.experiments.Reproduction`), its ``text`` (the error table and the files, naming
    the final folder), its ``warnings`` and the folder ``out``."""

    reproduction: Any = field(repr=False)
    text: str
    warnings: tuple[str, ...]
    out: Path
    error = None

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef reproduce`` prints, in order: each line with True where it goes to stderr (a warning)."""
        return [(self.text, False), *((w, True) for w in self.warnings)]


@dataclass(frozen=True)
class SavedReproductions:
    """What :func:`reproduce_all_to` did: one :class:`~liemef.studies.experiments.Reproduction` or
    :class:`~liemef.studies.experiments.Failure` per experiment (``done``), the folder ``out`` and its
    ``index`` (``index.md``)."""

    done: list = field(repr=False)
    out: Path
    index: Path

    @property
    def failed(self) -> list:
        """The :class:`~liemef.studies.experiments.Failure` entries of :attr:`done`."""
        from .experiments import Failure

        return [r for r in self.done if isinstance(r, Failure)]

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef reproduce all`` prints at the end: each line with True where it goes to stderr."""
        failed = self.failed
        return [(f"Wrote {len(self.done) - len(failed)} of {len(self.done)} experiments and {self.index.name} to "
                 f"{self.out}", False), *((f"FAILED {r.experiment}: {r.error}", True) for r in failed)]

    @property
    def error(self) -> str | None:
        """Why ``liemef reproduce all`` exits with status 1 (an experiment failed), or None."""
        failed = self.failed
        if not failed:
            return None
        return f"{len(failed)} experiment(s) failed: {', '.join(r.experiment for r in failed)}"


def _shown(text: str, stage: Path, out: Path) -> str:
    """``text`` with the temporary folder's path replaced by the final one."""
    return text.replace(str(stage), str(out))


def reproduce_to(out: str | os.PathLike, experiment: str, *, quick: bool = False, runs: int | None = None,
                 seed: int | None = None, duration: float | None = None, connection: str | None = None,
                 order: str | None = None, settings=(), force: bool = False,
                 progress: bool = False) -> SavedReproduction:
    """Reproduce the registered ``experiment`` into ``out`` (:meth:`~liemef.studies.experiments.Experiment.
    reproduce`): its config (``quick``: the reduced one) with ``seed``, ``duration``, ``connection`` and
    ``order`` (None: the config's) and the ``KEY=VALUE`` ``settings`` replaced, and ``runs`` Monte Carlo
    trials (None: the experiment's own number; 0: the seeded run only)."""
    from .experiments import get_experiment, reproduce_experiment
    from .settings import experiment_config

    exp = get_experiment(experiment)
    options = {"seed": seed, "duration": duration, "connection": connection, "order": order}
    config = experiment_config(exp, quick, options, settings)
    runs = (exp.quick_runs if quick else exp.runs) if runs is None else runs
    target = outputs.claim(out, "reproduce", force)
    with outputs.staged(target) as d:
        rep = reproduce_experiment(exp, d, config, runs=runs, progress=progress)
    return SavedReproduction(rep, _shown(rep.text, d, target.path), tuple(rep.warnings), target.path)


def reproduce_all_to(out: str | os.PathLike, *, quick: bool = True, runs: int | None = None, settings=(),
                     force: bool = False, progress: bool = False, echo=None, seed: int | None = None,
                     duration: float | None = None, connection: str | None = None,
                     order: str | None = None) -> SavedReproductions:
    """Every registered experiment into a subfolder of ``out``, then ``index.md``
    (:func:`~liemef.studies.experiments.reproduce_all`), each at its reduced size (``quick``) or its full one;
    ``runs`` overrides every experiment's number of Monte Carlo trials; ``echo(text)`` receives each
    reproduction's text (naming the final folder) as it finishes. Any of ``seed``, ``duration``,
    ``connection``, ``order`` (not None) or ``settings`` is a ValueError, before JAX is imported: they apply to
    one experiment. An
    experiment that raises is recorded as a :class:`~liemef.studies.experiments.Failure`; the others still run."""
    options = {"seed": seed, "duration": duration, "connection": connection, "order": order}
    given = [f"--{k}" for k, v in options.items() if v is not None] + (["--set"] if settings else [])
    if given:
        raise ValueError(f"{', '.join(given)}: config options apply to one experiment, not to 'all' (each runs its "
                         "own reduced or full config)")
    from .experiments import INDEX_FILE, reproduce_all

    target = outputs.claim(out, "reproduce", force)
    with outputs.staged(target) as d:
        shown = None if echo is None else (lambda text: echo(_shown(text, d, target.path)))
        done = reproduce_all(d, quick=quick, progress=progress, runs=runs, echo=shown)
    return SavedReproductions(done, target.path, target.path / INDEX_FILE)


C_IDENTIFIER = r"[A-Za-z_][A-Za-z0-9_]*"
"""What :func:`export_c_to` accepts as ``name`` (``liemef export-c --name``): the prefix of every name of the
exported C."""


@dataclass(frozen=True)
class SavedC:
    """What :func:`export_c_to` did: the ``exported`` files (:class:`liemef.codegen.ExportedC`), the ``filter``
    exported and the ``source`` system (:class:`liemef.studies.logs.LogSystem`)."""

    exported: Any
    filter: Any = field(repr=False)
    source: Any = field(repr=False)

    @property
    def backend(self) -> str:
        """The C translator used (``"scalar"`` or ``"array"``, ``"auto"`` resolved by
        :func:`liemef.codegen.export_c`)."""
        return self.exported.backend

    error = None

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef export-c`` prints: the files and the C API."""
        return [(f"Exported {self.source.label} ({self.filter!r}) as C99 ({self.backend} code):", False),
                (f"  {self.exported.header}\n  {self.exported.source}", False),
                (self.exported.api_summary(self.source.system), False)]


def export_c_to(out: str | os.PathLike, *, system: str | None = None, system_file: str | os.PathLike | None = None,
                name: str | None = None, connection: str = "zero", order: str = "second", integrator: str = "rkmk4",
                alpha: float = 0.0, substeps: int | str = "auto", max_substeps: int = 256,
                backend: str = "auto", timeout: float | None = None, error: str = "auto") -> SavedC:
    """The minimum-energy filter of a ready ``system`` or of your own ``system_file`` (exactly one) as C99:
    ``NAME.h`` and ``NAME.c`` in the folder ``out`` (created if missing; each file whole or not at all), by
    :func:`liemef.codegen.export_c`. ``name`` is a C identifier (default: the system's name with - replaced by
    _); ``error``: the filter's error coordinates (``"auto"``, ``"left"`` or ``"right"``, as
    :class:`~liemef.MinimumEnergyFilter`'s); ``timeout``: the seconds ``system_file`` may take to load (None or
    0: no limit; the command line's ``--timeout``, :data:`liemef.studies.registry.SYSTEM_FILE_TIMEOUT` by
    default). Bad input is a ValueError naming its option (``err.option``), the name, ``alpha`` and ``timeout``
    checked before JAX is imported; a step the C translator does not cover is
    :class:`liemef.codegen.UnsupportedPrimitive`, naming the system and what it uses, with nothing written. A
    failed export (bad input, a system file that fails or is stopped, an interruption) leaves no folder it
    created."""
    import math
    import re

    from .. import _validate
    from .settings import OptionError

    given = name is not None
    if not given and (system or system_file):
        name = (system or Path(system_file).stem).replace("-", "_")
    if name is not None and not re.fullmatch(C_IDENTIFIER, name):
        raise OptionError(f"expected a C identifier (letters, digits and _, not starting with a digit), got {name!r}"
                          + ("" if given else " (from the system's name: give --name)"), "--name")
    if not math.isfinite(alpha) or alpha < 0:
        raise OptionError(f"expected a number >= 0, got {alpha}", "--alpha")
    try:
        timeout = _validate.timeout("--timeout", timeout)
    except ValueError as err:
        raise OptionError(str(err).removeprefix("--timeout: "), "--timeout") from err
    created = [q for q in (Path(out), *Path(out).parents) if not q.exists()]  # the folders made here, deepest first
    try:
        d = io.ensure_dir(out)
    except ValueError as err:
        raise OptionError(str(err), "--out") from err
    try:
        return _export_c(d, system, system_file, name, timeout, backend, connection=connection, order=order,
                         error=error, integrator=integrator, alpha=alpha, substeps=substeps, max_substeps=max_substeps)
    except BaseException:
        for q in created:  # empty unless the files were written: then the export did not fail
            try:
                q.rmdir()
            except OSError:
                break
        raise


def _export_c(d: Path, system, system_file, name, timeout, backend, **options) -> SavedC:
    from ..codegen import UnsupportedPrimitive, export_c
    from ..filters import MinimumEnergyFilter
    from .logs import resolve_system
    from .settings import OptionError

    source = resolve_system(system, system_file, timeout=timeout)
    flt = MinimumEnergyFilter(source.system, **options)
    try:
        exported = export_c(flt, d, name, backend=backend)
    except UnsupportedPrimitive as err:
        raise UnsupportedPrimitive(f"{source.label}: the filter step uses what the C translator does not cover: "
                                   f"{err}. See docs/export-c.md (supported primitives)") from err
    except OSError as err:
        raise OptionError(f"cannot write to {str(d)!r} ({err.strerror or err})", "--out") from err
    return SavedC(exported, flt, source)


@dataclass(frozen=True)
class SavedTune:
    """What :func:`tune_to` did: the tuning ``result`` (:func:`liemef.studies.tune.tune`'s), its ``markdown``
    report, the folder ``out`` and the files ``written`` there (``tune.json``, ``tune.md``)."""

    result: dict = field(repr=False)
    markdown: str = field(repr=False)
    out: Path
    written: list[Path]
    error = None

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef tune`` prints: the report and the files."""
        return [(self.markdown, False), (f"Wrote {' and '.join(p.name for p in self.written)} to {self.out}", False)]


def tune_to(out: str | os.PathLike, data: str = "broad", *, objective: str = "truth", trials=None,
            names=None, seconds: float | None = 90.0, maxfev: int = 40, fold_maxfev: int | None = None,
            system: str = "attitude-imu", updates: str = "hold", integrator: str = "rkmk4",
            realdata: str | os.PathLike | None = None, start=None, force: bool = False, progress: bool = False,
            workers: int | None = None) -> SavedTune:
    """Fit ``system``'s noise levels (:func:`liemef.studies.registry.tune_systems`) to the recordings ``data``
    (:data:`~liemef.studies.registry.TUNE_DATA`: the BROAD ``trials`` present, each id a string; None: all) with
    nested leave-one-trial-out cross-validation (:func:`liemef.studies.tune.tune`, on each trial's first
    ``seconds``; 0 or None: whole trials; ``maxfev`` points for the final search and ``fold_maxfev``, default
    ``maxfev``, for each fold's), and write ``tune.json`` (for ``liemef run --params``) and ``tune.md`` to ``out``.
    ``names``: the parameters to tune (None: the system's defaults). ``start``: ``NAME=VALUE`` entries, the
    starting values of every search (None: the system's defaults; the defaults of ``attitude-velocity`` and
    ``attitude-position`` were tuned on the shared trials, so a held-out error meant to be honest starts from
    values chosen without them).
    ``attitude-velocity`` and ``attitude-position`` take ``updates="discrete"`` only. ``integrator``: the
    filter's (``"rkmk2"``: a faster tune, recorded in the file). ``workers``: threads that run a point's trials
    side by side (None: the CPUs this process may use). Bad input is a ValueError before anything is written;
    an empty list of ``trials`` or ``names``, or an empty entry in one, is refused naming ``--trials`` or
    ``--params`` (an empty ``--trials ''`` is not every trial)."""
    from .registry import TUNE_DATA
    from .settings import OptionError

    trials, names = (_entries(v, option, what) for v, option, what in (
        (trials, "--trials", "BROAD trial ids"), (names, "--params", "parameter names")))
    if data not in TUNE_DATA:
        raise ValueError(f"data: expected one of {list(TUNE_DATA)}, got {data!r}")
    if trials is not None and len(trials) < 2:
        raise OptionError(f"expected two or more BROAD trial ids for the leave-one-out, got {','.join(trials)!r}",
                          "--trials")
    start = _start(start, system)
    if system in ("attitude-velocity", "attitude-position") and updates != "discrete":
        raise ValueError(f"--updates: expected discrete with --system {system} (as compare broad's mef-vel and "
                         f"mef-pos), got {updates}")
    target = outputs.claim(out, "tune", force)
    from . import tune

    recs = tune.broad_recordings(trials, seconds or None,
                                 None if realdata is None else str(realdata),
                                 gyro="backward" if updates == "discrete" else "forward", system=system)
    kw = {} if names is None else {"names": tuple(names)}
    result = tune.tune(recs, objective=objective, maxfev=maxfev, fold_maxfev=fold_maxfev, progress=progress,
                       updates=updates, integrator=integrator, start=start, workers=workers, **kw)
    text = tune.markdown(result)
    with outputs.staged(target) as d:
        written = [tune.save(result, d / "tune.json"), io.write_text(d / "tune.md", text)]
    return SavedTune(result, text, target.path, [target.path / p.name for p in written])


def _start(values, system: str) -> dict | None:
    """``--start``'s ``NAME=VALUE`` entries (None: the system's defaults) as ``{name: value}``, each name a
    tunable parameter of ``system`` (:func:`liemef.studies.tune.check_params`), given once; an OptionError
    naming ``--start`` otherwise."""
    from . import tune
    from .settings import OptionError

    entries = _entries(values, "--start", "NAME=VALUE entries")
    if entries is None:
        return None
    out = {}
    for entry in entries:
        name, sep, text = (part.strip() for part in entry.partition("="))
        if not sep or not name:
            raise OptionError(f"expected NAME=VALUE entries separated by commas, got {entry!r}", "--start")
        if name in out:
            raise OptionError(f"{name}: given twice", "--start")
        try:
            out[name] = float(text)
        except ValueError:
            raise OptionError(f"{name}: expected a number, got {text!r}", "--start") from None
    try:
        return tune.check_params(out, system, "--start")
    except ValueError as err:
        raise OptionError(str(err), "--start") from err


def _entries(values, option: str, what: str) -> list[str] | None:
    """``values`` (None: the default) as a list of stripped, non-empty strings; an OptionError naming
    ``option`` for an empty list or an empty entry."""
    from .settings import OptionError

    if values is None:
        return None
    values = [values] if isinstance(values, str) else list(values)
    entries = [str(v).strip() for v in values]
    if not entries or not all(entries):
        raise OptionError(f"expected {what} separated by commas, got {','.join(map(str, values))!r} (omit the "
                          "option for the default)", option)
    return entries


@dataclass(frozen=True)
class SavedComparison:
    """What :func:`compare_to` did: the comparison's ``result``, its ``markdown`` report, the folder ``out``,
    the files ``written`` there, one ``warnings`` line per filter that failed somewhere, and how many (filter,
    trial) pairs ``failed`` of the ``total`` run (:func:`liemef.studies.compare.failures`)."""

    result: dict = field(repr=False)
    markdown: str = field(repr=False)
    out: Path
    written: list[Path]
    warnings: list[str]
    failed: int
    total: int

    @property
    def usable(self) -> bool:
        """False when every trial of every filter failed or has nothing scored."""
        return not (self.total and self.failed == self.total)

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef compare`` prints, in order: each line with True where it goes to stderr (a warning)."""
        return [(self.markdown, False), *((f"WARNING: {line}", True) for line in self.warnings),
                (wrote(self.written, self.out), False)]

    @property
    def error(self) -> str | None:
        """Why ``liemef compare`` exits with status 1 (no usable trial), or None."""
        return None if self.usable else (f"no usable trial: each of the {self.total} runs (a filter on a trial) "
                                         "failed or scored nothing")


def compare_to(out: str | os.PathLike, study: str, *, runs: int | None = None, seed: int = 0,
               filters: str | None = None, settings=(), force: bool = False,
               progress: bool = False) -> SavedComparison:
    """Run the comparison ``study`` (:data:`liemef.studies.compare.STUDIES`) with ``runs`` trials from ``seed``,
    the ``filters`` (comma-separated names; None: the study's) and the ``KEY=VALUE`` ``settings``, and write its
    tables, data and figures to ``out``. Bad input is a ValueError before anything is written or run."""
    from . import registry
    from .compare import STUDIES, failures
    from .settings import comparison_settings

    registry.get("comparison", study)
    spec = STUDIES[study]
    st = comparison_settings(study, spec.settings, runs=runs, seed=seed, filters=filters, items=settings)
    target = outputs.claim(out, "compare", force)
    result = spec.run(st, progress=progress)
    text = spec.markdown(result)
    lines, failed, total = failures(result)
    with outputs.staged(target) as d:
        written = spec.save(result, d)
    return SavedComparison(result, text, target.path, [target.path / Path(p).name for p in written], lines, failed,
                           total)
