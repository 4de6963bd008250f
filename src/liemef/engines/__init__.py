"""The engines: what runs a filter's sample intervals over a log, a batch of trials, inside a JAX program or
one online step, by XLA (jitted JAX) or by a compiled C kernel of the interval (:mod:`liemef.codegen`).

A filter (:mod:`liemef.filters`) says how one interval advances its state and knows nothing of what runs it;
its methods ``run``, ``run_batch``, ``scan``, ``step`` and ``online`` call the functions of the same names
here. ``engine="auto"`` (the default, or ``$LIEMEF_ENGINE``) runs by C where a C compiler is found
(:func:`engine_of`).
"""

from ._driver import LogGapWarning, online, run, run_batch, scan, step
from ._online import OnlineFilter
from ._select import ENGINES, EngineWarning, engine_of, kernel
from ._xla import bucket

__all__ = ["run", "run_batch", "scan", "step", "online", "OnlineFilter", "ENGINES", "engine_of", "kernel",
           "EngineWarning", "LogGapWarning", "bucket"]
