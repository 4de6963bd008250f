"""What runs on a worker: one task, a range of seeded trials of one setting, as compiled ``vmap`` batches.

:func:`run_task` is a plain module-level function of picklable data (:class:`TaskInput`), so Dask ships it by
reference; everything it needs (the experiment, or the text of the user's experiment file) is in the input.
The experiment module and the compiled batch are cached per worker process, so a worker compiles each
setting once, whatever number of its tasks it runs.
"""

from __future__ import annotations

import functools
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ._spec import CampaignError


@dataclass(frozen=True)
class TaskInput:
    """Everything a worker needs for one task: the experiment (``experiment`` a registered name, or ``source``
    the text of an experiment file named ``filename``), the config (``quick``, ``overrides``) and the trials
    ``[start, stop)`` of ``runs`` under root ``seed``, ``batch_size`` per compiled batch."""

    task_id: str
    experiment: str | None
    source: str | None
    filename: str
    quick: bool
    overrides: tuple[tuple[str, Any], ...]
    seed: int
    runs: int
    start: int
    stop: int
    batch_size: int


@dataclass(frozen=True)
class TaskOutput:
    """A finished task: the per-trial arrays (see :class:`liemef.studies.experiments.TrialArrays`), the samples of one
    trial, and where and how long it ran (``seconds`` inside the worker, compilation included when this worker
    compiled the setting for this task)."""

    task_id: str
    stats: Any
    finite: Any
    causes: Any
    samples: int
    seconds: float
    worker: str


def _frozen(value: Any) -> Any:
    """Lists (from TOML, YAML or JSON) as tuples, so that configs stay hashable and their compiled batches
    are cached."""
    return tuple(_frozen(v) for v in value) if isinstance(value, list | tuple) else value


@functools.lru_cache(maxsize=8)
def _experiment_from_source(source: str, filename: str):
    from ...systems._file import run_python_file
    from ..experiments import Experiment

    module = run_python_file(Path(filename), "experiment_file", source=source)
    exp = getattr(module, "experiment", None)
    if not isinstance(exp, Experiment):
        raise CampaignError(f"experiment_file: expected {filename!r} to define `experiment`, a "
                            f"liemef.studies.experiments.Experiment with a trial_fn, got {type(exp).__name__}")
    return exp


def experiment_of(name: str | None, source: str | None, filename: str = "<experiment_file>"):
    """The experiment of a task or campaign: the registered ``name``, or the ``experiment`` defined by the
    file text ``source`` (executed once per process and text). CampaignError unless it has a Monte Carlo
    trial."""
    from ..experiments import resolve_experiment

    if source is not None:
        try:
            exp = _experiment_from_source(source, filename)
        except ValueError as err:
            raise CampaignError(str(err)) from None
    else:
        exp = name
    try:
        return resolve_experiment(exp)
    except ValueError as err:
        raise CampaignError(str(err)) from None


def config_of(exp, quick: bool, overrides) -> Any:
    """The experiment's config (its quick config with ``quick``) with ``overrides`` (a mapping or pairs)."""
    ov = {k: _frozen(v) for k, v in dict(overrides).items()}
    try:
        return exp.quick(**ov) if quick else exp.config(**ov)
    except (ValueError, TypeError) as err:
        raise CampaignError(str(err)) from None


def run_task(task: TaskInput) -> TaskOutput:
    """Run one task on this process (a Dask worker, or the caller): its trials through the cached compiled
    batch of its setting (:func:`liemef.studies.experiments.run_trials`)."""
    from ..experiments import run_trials

    t0 = time.perf_counter()
    exp = experiment_of(task.experiment, task.source, task.filename)
    config = config_of(exp, task.quick, task.overrides)
    arrays = run_trials(exp, config, task.seed, task.runs, task.start, task.stop, task.batch_size)
    return TaskOutput(task_id=task.task_id, stats=arrays.stats, finite=arrays.finite, causes=arrays.causes,
                      samples=arrays.samples, seconds=time.perf_counter() - t0,
                      worker=f"{socket.gethostname()}:{os.getpid()}")
