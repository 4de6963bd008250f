"""The papers' experiments, each a frozen config plus ``run(config, key=None) -> Result``, in a registry.

``EXPERIMENTS[name]`` is an :class:`Experiment` (name, title, paper, figures, default config, run);
:func:`get_experiment` looks one up with an error listing the valid names. ``SYSTEMS[name]`` are the ready
systems that ``liemef run`` filters recorded logs with.

Registered: ``tse2`` (Rigo et al. 2022, Sec. VI, Figs. 3-4), ``tse2-velocity`` (Segala poster),
``attitude`` (Saccon et al. 2016, Fig. 3), ``chaplygin`` (Rigo et al. 2023, Tables 1-2, Figs. 3-6),
``localization`` (the ukfm 2D localization benchmark) and ``unit-circle`` (Zamani et al., Figs. 2-3);
``liemef reproduce --list`` lists them.

Monte Carlo: :func:`montecarlo` runs N seeded trials of any experiment with a ``trial_fn`` (``vmap`` over
split keys) into a :class:`MonteCarloResult` (statistics per trial, then across trials; tables; npz + json).
Its parts are public for drivers that split the trials elsewhere (campaigns): :func:`resolve_experiment`,
:func:`run_trials` (one slice of trials as :class:`TrialArrays`) and :func:`result_of` (the result of them all).
The experiments' names, titles and papers are declared in :mod:`liemef.studies.registry`.
Reproduction: :func:`reproduce_experiment` writes an experiment's folder (:func:`default_reproduce` unless the
experiment has its own ``reproduce_fn``), :func:`reproduce_all` every experiment plus ``index.md``.
"""

from . import attitude, chaplygin, localization, tse2, unit_circle
from ._base import (
    EXPERIMENTS,
    SCHEMA,
    Experiment,
    FigureSpec,
    Output,
    Reproduction,
    Result,
    TrialSpec,
    config_dict,
    get_experiment,
    register,
)
from ._evaluate import evaluate
from ._montecarlo import (
    DEFAULT_BATCH_SIZE,
    PERCENTILES,
    STATS,
    MonteCarloResult,
    ProgressLine,
    TrialArrays,
    format_seconds,
    montecarlo,
    resolve_experiment,
    result_of,
    run_trials,
    trial_cause,
    trial_keys,
    trial_statistics,
)
from ._reproduce import (
    INDEX_FILE,
    Failure,
    default_reproduce,
    listing,
    reproduce_all,
    reproduce_experiment,
    write_index,
)
from ._systems import SYSTEMS, SystemSpec, get_system

__all__ = ["EXPERIMENTS", "Experiment", "FigureSpec", "Result", "TrialSpec", "SCHEMA", "get_experiment", "register",
           "config_dict", "evaluate", "SYSTEMS", "SystemSpec", "get_system", "tse2", "attitude", "unit_circle",
           "chaplygin", "localization", "montecarlo", "MonteCarloResult", "trial_keys", "trial_statistics",
           "trial_cause", "ProgressLine", "STATS", "PERCENTILES", "DEFAULT_BATCH_SIZE", "Output", "Reproduction",
           "default_reproduce", "reproduce_experiment", "reproduce_all", "write_index", "Failure", "listing",
           "INDEX_FILE", "TrialArrays", "format_seconds", "resolve_experiment", "result_of", "run_trials"]
