from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ... import _validate
from ...filters import ORDERS
from ...integrators import INTEGRATORS
from ...metrics import ErrorTable, Window
from .. import registry

SCHEMA = "liemef.metrics/1"
"""Version tag of the ``metrics.json`` layout (see :class:`Result`)."""
PAPER_SUBSTEPS = 1
"""Integrator steps per sample interval in the papers' experiments: one, as the papers integrate (their
measurements are dense and their gains moderate, so no interval is stiff). Real-log systems use ``"auto"``."""


class RunConfig:
    """What the experiments' frozen config dataclasses share: an integer ``seed`` and a run of ``duration`` s
    sampled every ``dt`` s, the checks of those (and of ``order`` and ``integrator`` where a config has them)
    and their canonical values. A config calls :meth:`_check_run` first and :meth:`_freeze` last in its
    ``__post_init__``."""

    seed: int
    duration: float
    dt: float

    window_times = ()
    """The fields that hold times (s) of the statistics windows (a start, or a window (start, stop)): they follow
    a shorter run (:meth:`window_changes`)."""

    def window_changes(self, duration: float) -> dict:
        """The window fields moved into a run of ``duration`` s instead of :attr:`duration`: a window of
        :attr:`window_times` that would start at or after the new final time (so hold no sample) has each of
        its times ``t`` scaled to ``t * duration / self.duration``, keeping its place in the run (the steady
        window 10-50 s of a 50 s run becomes 1-5 s of a 5 s run); a window that starts before it is kept (its
        statistics cover its part of the run). Empty when nothing moves, or for a duration that is not a finite
        number > 0 (the config's check names it). ``liemef montecarlo --duration`` applies it
        (:func:`liemef.studies.settings.experiment_config`)."""
        ok = isinstance(duration, int | float) and not isinstance(duration, bool) and math.isfinite(duration)
        if not ok or duration <= 0:
            return {}
        scale = lambda t: float(t) * duration / self.duration  # noqa: E731
        out = {}
        for name in self.window_times:
            value = getattr(self, name)
            window = isinstance(value, tuple | list)
            if (value[0] if window else value) >= duration:
                out[name] = tuple(scale(t) for t in value) if window else scale(value)
        return out

    def _check_run(self, positive: tuple[str, ...] = ()) -> None:
        """ValueErrors for a seed not an integer in [0, 2**63 - 1], ``duration``, ``dt`` and the ``positive``
        fields not finite numbers > 0, a run shorter than one step, an unknown ``order`` or ``integrator``."""
        _validate.integer("seed", self.seed, 0, _validate.SEED_MAX)
        for name in ("duration", "dt", *positive):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {v!r}")
        if self.duration < self.dt:
            raise ValueError(f"duration: expected at least one step dt = {self.dt}, got {self.duration}")
        if hasattr(self, "order"):
            _validate.choice("order", self.order, set(ORDERS))
        if hasattr(self, "integrator"):
            _validate.choice("integrator", self.integrator, set(INTEGRATORS))

    def _freeze(self, floats: tuple[str, ...] = (), tuples: tuple[str, ...] = ()) -> None:
        """Canonical plain-Python values (int seed, float ``duration``, ``dt`` and ``floats``, tuples of floats
        ``tuples``): the config is hashable (setups are cached by config) and JSON-ready."""
        set_ = functools.partial(object.__setattr__, self)
        set_("seed", int(self.seed))
        for name in ("duration", "dt", *floats):
            set_(name, float(getattr(self, name)))
        for name in tuples:
            set_(name, tuple(float(v) for v in getattr(self, name)))

    @property
    def ts(self) -> np.ndarray:
        """The sample grid 0, dt, ..., T (T rounded to a whole number of steps)."""
        return np.arange(int(round(self.duration / self.dt)) + 1) * self.dt


class UkfmGrid(RunConfig):
    """A run on ukfm's time grid (its benchmarks' convention): N = round(T / dt) states at t_n = n dt, so the
    last time is T - dt, and a sensor of period p observed at the indices m, 2m, ... < N (m = round(p / dt);
    ukfm's y_0 is never used)."""

    @property
    def n_states(self) -> int:
        """N = round(T / dt)."""
        return int(round(self.duration / self.dt))

    @property
    def ts(self) -> np.ndarray:
        """t_n = n dt, n = 0..N-1 (ukfm's grid: the last time is T - dt)."""
        return np.arange(self.n_states) * self.dt

    def every(self, period: float) -> np.ndarray:
        """The state indices m, 2m, ... < N of a sensor of ``period`` s (m = round(period / dt))."""
        m = int(round(period / self.dt))
        return np.arange(m, self.n_states, m)


@dataclass(frozen=True)
class FigureSpec:
    """A figure of state panels drawn from a result's arrays (``liemef.reports.plots``): for each component, truth,
    measurement and estimate on the left, error on the right, as in Rigo et al. 2022, Figs. 3-4."""

    filename: str
    components: tuple[str, ...]
    title: str
    paper_figure: str = ""

    def to_dict(self) -> dict:
        """JSON-ready description, as listed in ``metrics.json`` and by ``reproduce --list``."""
        return {"file": self.filename, "components": list(self.components), "title": self.title,
                "paper_figure": self.paper_figure}


@dataclass(frozen=True)
class Result:
    """What an experiment run produces, ready to be written by :mod:`liemef.reports.io`.

    ``arrays`` (saved as ``arrays.npz``) holds at least ``ts`` (N,), ``names`` and ``units`` (c,),
    ``truth``, ``measured``, ``filtered`` and ``error`` (N, c): angles in ``truth``/``measured``/``filtered``
    are continuous (unwrapped, the measured one on the branch of the estimate), ``error`` is truth - estimate
    with angles wrapped to (-pi, pi]; unmeasured components of ``measured`` are NaN. It also holds the sensor
    log ``us``/``ys``, so ``arrays.npz`` can be filtered again with ``liemef run``.

    ``metrics`` (saved as ``metrics.json``) has the keys ``schema``, ``experiment`` (name, title, paper),
    ``config``, ``assumptions``, ``windows``, ``errors`` and ``group_errors`` (each ``{"definition",
    "components": {name: {"unit", <window>: {"mean", "std", "rms"}}}}``), ``gain``, ``run`` and ``figures``.

    ``raw`` keeps the in-memory objects of the run (for TSE(2): ``truth``, ``log``, ``trajectory``) for use
    from Python; it is not written to disk.
    """

    experiment: str
    config: Any
    arrays: dict[str, np.ndarray]
    metrics: dict
    table: ErrorTable
    figures: tuple[FigureSpec, ...] = ()
    raw: dict = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class TrialSpec:
    """One Monte Carlo trial of an experiment config: ``errors(key)`` (N, c) for the sample times ``ts``.

    ``errors`` is traceable in the ``jax.random`` key (simulation and filter for that key, truth minus
    estimate in coordinates), so a Monte Carlo driver batches trials with ``jax.vmap`` over split keys and
    reduces each trial to per-window statistics (:func:`liemef.metrics.error_stats`).

    **Parameters as data.** With ``params`` (a pytree of arrays and equinox modules: the system, the filter,
    its initial state, noise levels...), ``errors(params, key)`` receives them as an argument instead of
    closing over them, and the Monte Carlo driver compiles one batch per ``errors`` function and structure of
    ``params`` (and number of samples): configs that differ only in array values (weights, noise levels,
    initial states, window bounds) share one compilation. ``errors`` must then be one function object for
    every config (a module-level function, not a closure made per config).
    """

    ts: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    windows: tuple[Window, ...]
    errors: Callable[..., Any] = field(repr=False)
    params: Any = field(default=None, repr=False)


class Output(NamedTuple):
    """A file an experiment's reproduction wrote, with the caption the index shows (e.g. the paper figure)."""

    path: Path
    caption: str = ""


@dataclass(frozen=True)
class Reproduction:
    """What :func:`~liemef.studies.experiments.reproduce_experiment` wrote to its folder ``out``: read by the CLI
    (which prints ``text`` and writes ``warnings`` to stderr) and by ``liemef reproduce all`` (whose ``index.md``
    links ``figures`` and ``tables``). ``files`` is every file written; ``summary`` is a short JSON-ready digest
    for the index (e.g. runs, non-finite trials)."""

    experiment: str
    out: Path
    figures: tuple[Output, ...] = ()
    tables: tuple[Output, ...] = ()
    files: tuple[Path, ...] = ()
    text: str = ""
    warnings: tuple[str, ...] = ()
    summary: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Experiment:
    """A paper figure or table as a frozen default config plus ``run(config, key=None) -> Result``.

    ``key=None`` uses ``jax.random.key(config.seed)``; a Monte Carlo driver passes its own keys.
    ``trial_fn(config) -> TrialSpec`` gives the traceable trial a Monte Carlo batches (None: no Monte Carlo;
    see :func:`liemef.studies.experiments.montecarlo`).

    Reproduction (``liemef reproduce NAME`` and ``liemef reproduce all``) is :meth:`reproduce`, shaped by:

    * ``runs``: Monte Carlo trials ``reproduce`` runs by default (``--runs`` overrides; 0: the single seeded
      run only). ``quick_config`` and ``quick_runs``: the reduced size of ``reproduce --quick`` and of
      ``reproduce all`` (default ``--quick``), a few seconds to a minute on a laptop: e.g. a shorter
      ``duration`` and fewer trials (``quick_config=None``: the default config).
    * ``tables``: the paper tables the experiment reproduces, for ``reproduce --list`` (figures are listed
      from ``figures``).
    * ``reproduce_fn(config, out, runs, progress) -> Reproduction``: the experiment's own reproduction, for
      experiments whose output is more than one run (e.g. a grid of configurations, each a Monte Carlo of
      ``runs`` trials, written as the paper's tables with :class:`~liemef.studies.experiments.MonteCarloResult`).
      ``out`` is a :class:`~pathlib.Path` to an existing folder; write every file atomically through
      :mod:`liemef.reports.io` and return what was written. None: :func:`default_reproduce` (one seeded run:
      ``metrics.json``, ``arrays.npz``, the ``figures``, ``errors.md``/``errors.csv``; plus a Monte Carlo of
      ``runs`` trials, ``montecarlo.*``, when ``runs > 0``), which a custom hook may call for its parts.
    """

    name: str
    title: str
    paper: str
    default_config: Any
    run_fn: Callable[..., Result] = field(repr=False)
    trial_fn: Callable[[Any], TrialSpec] | None = field(default=None, repr=False)
    figures: tuple[FigureSpec, ...] = ()
    tables: tuple[str, ...] = ()
    runs: int = 0
    quick_config: Any | None = None
    quick_runs: int = 0
    reproduce_fn: Callable[..., Reproduction] | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("runs", "quick_runs"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"{name}: expected an integer >= 0, got {v!r}")

    def config(self, **overrides) -> Any:
        """The default config with ``overrides`` (field names of the config dataclass) replaced."""
        return self._replace(self.default_config, overrides)

    def quick(self, **overrides) -> Any:
        """The reduced config of ``reproduce --quick`` (``quick_config``, else the default) with ``overrides``."""
        return self._replace(self.default_config if self.quick_config is None else self.quick_config, overrides)

    def _replace(self, config: Any, overrides: dict) -> Any:
        valid = {f.name for f in dataclasses.fields(config)}
        unknown = sorted(set(overrides) - valid)
        if unknown:
            raise ValueError(f"{self.name}: unknown config option(s) {unknown}; "
                             f"expected some of {sorted(valid)}")
        return dataclasses.replace(config, **overrides)

    def run(self, config: Any | None = None, key=None) -> Result:
        """One run: ``run_fn(config, key)``; ``config=None``: the default config, ``key=None``: from its seed."""
        return self.run_fn(self.default_config if config is None else config, key)

    def describe(self) -> dict:
        """Name, title, paper, figures, tables and whether it has a Monte Carlo (``reproduce --list``)."""
        return {"name": self.name, "title": self.title, "paper": self.paper,
                "figures": [f.to_dict() for f in self.figures], "tables": list(self.tables),
                "montecarlo": self.trial_fn is not None}


def setup_cache(maxsize: int = 8, **irrelevant):
    """An experiment's ``setup(config)`` from its builder: the builder runs once per config, with the fields that
    do not enter the setup (the ``seed``, which picks the trials, and ``irrelevant``) set to fixed values, and
    the last ``maxsize`` setups are kept. The one setup cache of every experiment module, whose shape is
    ``setup(config) -> Setup`` (system, filter, initial states, time grid), ``trial(setup, key)`` (traceable, one
    seeded run), ``trial_spec(config)`` (the Monte Carlo trial: ``trial_fn``) and ``run(config, key)`` (one
    evaluated run: ``run_fn``)."""
    def wrap(build):
        cached = functools.lru_cache(maxsize=maxsize)(build)

        @functools.wraps(build)
        def setup(config):
            return cached(dataclasses.replace(config, **{"seed": 0, **irrelevant}))
        setup.cache_clear = cached.cache_clear
        return setup
    return wrap


EXPERIMENTS: dict[str, Experiment] = {}
"""Every registered experiment by name."""


def register(experiment: Experiment) -> Experiment:
    """Add ``experiment`` to :data:`EXPERIMENTS` under its name and return it; a ValueError if the name is taken,
    or if the name is declared in :mod:`liemef.studies.registry` with another title or paper. A name the
    registry does not know is declared there."""
    if experiment.name in EXPERIMENTS:
        raise ValueError(f"experiment {experiment.name!r} is already registered")
    declared = registry.STUDIES["experiment"].get(experiment.name)
    if declared is None:
        registry.declare(registry.Study(experiment.name, "experiment", experiment.title, experiment.paper))
    elif (declared.title, declared.paper) != (experiment.title, experiment.paper):
        raise ValueError(f"experiment {experiment.name!r}: expected the registry's title and paper "
                         f"{(declared.title, declared.paper)!r}, got {(experiment.title, experiment.paper)!r}")
    EXPERIMENTS[experiment.name] = experiment
    return experiment


def get_experiment(name: str) -> Experiment:
    """The registered experiment ``name``; a ValueError listing the valid names otherwise."""
    if name not in EXPERIMENTS:
        raise ValueError(f"experiment: expected one of {sorted(EXPERIMENTS)}, got {name!r}")
    return EXPERIMENTS[name]


def config_dict(config: Any) -> dict:
    """A frozen config dataclass as JSON-ready data (tuples become lists)."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()}
