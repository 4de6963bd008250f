"""The papers' experiments, each a frozen config plus ``run(config, key=None) -> Result``, in a registry.

``EXPERIMENTS[name]`` is an :class:`Experiment` (name, title, paper, figures, default config, run);
:func:`get_experiment` looks one up with an error listing the valid names. ``SYSTEMS[name]`` are the ready
systems that ``liemef run`` filters recorded logs with.

Registered: ``tse2`` (Rigo et al. 2022, Sec. VI, Figs. 3-4) and ``tse2-velocity`` (Segala poster).
"""

from . import tse2
from ._base import (
    EXPERIMENTS,
    SCHEMA,
    Experiment,
    FigureSpec,
    Result,
    TrialSpec,
    config_dict,
    get_experiment,
    register,
)
from ._evaluate import evaluate
from ._systems import SYSTEMS, SystemSpec, get_system

__all__ = ["EXPERIMENTS", "Experiment", "FigureSpec", "Result", "TrialSpec", "SCHEMA", "get_experiment", "register",
           "config_dict", "evaluate", "SYSTEMS", "SystemSpec", "get_system", "tse2"]
