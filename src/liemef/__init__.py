"""liemef: second-order-optimal minimum-energy filtering on matrix Lie groups.

The public surface: :class:`MinimumEnergyFilter`, the groups (:mod:`liemef.groups`), connections
(:mod:`liemef.connections`), ready systems (:mod:`liemef.systems`).
"""

from . import _config  # noqa: F401  (float64 before any array is created)
from . import connections, groups, systems
from .connections import Connection, connection
from .filter import FilterState, MinimumEnergyFilter, Terms, Trajectory

__all__ = ["MinimumEnergyFilter", "FilterState", "Trajectory", "Terms", "Connection", "connection", "groups",
           "systems", "connections"]
__version__ = "0.1.0"
