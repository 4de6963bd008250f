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
    config = experiment_config(exp, quick, {"duration": duration}, settings, windows_follow=True)
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
