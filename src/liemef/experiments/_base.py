from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrics import ErrorTable, Window

SCHEMA = "liemef.metrics/1"
"""Version tag of the ``metrics.json`` layout (see :class:`Result`)."""


@dataclass(frozen=True)
class FigureSpec:
    """A figure of state panels drawn from a result's arrays (``liemef.plots``): for each component, truth,
    measurement and estimate on the left, error on the right, as in Rigo et al. 2022, Figs. 3-4."""

    filename: str
    components: tuple[str, ...]
    title: str
    paper_figure: str = ""

    def to_dict(self) -> dict:
        return {"file": self.filename, "components": list(self.components), "title": self.title,
                "paper_figure": self.paper_figure}


@dataclass(frozen=True)
class Result:
    """What an experiment run produces, ready to be written by :mod:`liemef.io`.

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
    """

    ts: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    windows: tuple[Window, ...]
    errors: Callable[[Any], Any] = field(repr=False)


@dataclass(frozen=True)
class Experiment:
    """A paper figure or table as a frozen default config plus ``run(config, key=None) -> Result``.

    ``key=None`` uses ``jax.random.key(config.seed)``; a Monte Carlo driver passes its own keys.
    ``trial_fn(config) -> TrialSpec`` gives the traceable trial a Monte Carlo batches (None: no Monte Carlo).
    """

    name: str
    title: str
    paper: str
    default_config: Any
    run_fn: Callable[..., Result] = field(repr=False)
    trial_fn: Callable[[Any], TrialSpec] | None = field(default=None, repr=False)
    figures: tuple[FigureSpec, ...] = ()

    def config(self, **overrides) -> Any:
        """The default config with ``overrides`` (field names of the config dataclass) replaced."""
        valid = {f.name for f in dataclasses.fields(self.default_config)}
        unknown = sorted(set(overrides) - valid)
        if unknown:
            raise ValueError(f"{self.name}: unknown config option(s) {unknown}; "
                             f"expected some of {sorted(valid)}")
        return dataclasses.replace(self.default_config, **overrides)

    def run(self, config: Any | None = None, key=None) -> Result:
        return self.run_fn(self.default_config if config is None else config, key)

    def describe(self) -> dict:
        return {"name": self.name, "title": self.title, "paper": self.paper,
                "figures": [f.to_dict() for f in self.figures]}


EXPERIMENTS: dict[str, Experiment] = {}
"""Every registered experiment by name."""


def register(experiment: Experiment) -> Experiment:
    if experiment.name in EXPERIMENTS:
        raise ValueError(f"experiment {experiment.name!r} is already registered")
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
