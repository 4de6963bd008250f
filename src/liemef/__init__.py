"""liemef: second-order-optimal minimum-energy filtering on matrix Lie groups."""

from . import _config  # noqa: F401  (float64 before any array is created)
from . import groups
