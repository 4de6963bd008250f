"""The filter engine: left-trivialized derivatives, the Riccati terms, integrators and the driver."""

from ._derivatives import left_hessian, left_jacobian
from ._driver import (
    ENGINES,
    TRACES,
    AbstractFilter,
    EngineWarning,
    FilterState,
    LogGapWarning,
    Trajectory,
    bucket,
    engine_of,
    sensor_layout,
)
from ._filter import INTERPOLATIONS, ORDERS, MinimumEnergyFilter
from ._integrators import INTEGRATORS, RKMK4, AbstractIntegrator, LieEuler, integrator
from ._online import OnlineFilter
from ._riccati import Terms, Weights, information_in_force, riccati_rhs, terms
from ._status import CAUSES, Status

__all__ = ["MinimumEnergyFilter", "AbstractFilter", "OnlineFilter", "sensor_layout",
           "ORDERS", "INTERPOLATIONS", "TRACES", "LogGapWarning", "EngineWarning", "ENGINES", "engine_of",
           "bucket", "Status", "CAUSES",
           "information_in_force", "FilterState", "Trajectory", "Terms", "Weights", "terms", "riccati_rhs",
           "left_jacobian", "left_hessian", "AbstractIntegrator", "LieEuler", "RKMK4", "INTEGRATORS", "integrator"]
