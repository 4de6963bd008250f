"""liemef: second-order-optimal minimum-energy filtering on matrix Lie groups.

The public surface: :class:`MinimumEnergyFilter`, the groups (:mod:`liemef.groups`), connections
(:mod:`liemef.connections`), ready systems (:mod:`liemef.systems`), :func:`simulate` and the metrics
(:mod:`liemef.metrics`). Experiments, I/O, plots and the CLI sit on top (:mod:`liemef.experiments`).
"""

# _config sorts first: float64 is switched on before any array is created.
from . import _config, connections, groups, metrics, simulation, systems  # noqa: F401
from .connections import Connection, connection
from .filter import FilterState, MinimumEnergyFilter, Terms, Trajectory
from .simulation import SensorLog, Truth, simulate

__all__ = ["MinimumEnergyFilter", "FilterState", "Trajectory", "Terms", "Connection", "connection", "simulate",
           "SensorLog", "Truth", "groups", "systems", "connections", "simulation", "metrics"]
__version__ = "0.1.0"
