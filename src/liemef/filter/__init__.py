"""The filter engine: left-trivialized derivatives, the Riccati terms, integrators and the driver."""

from ._derivatives import left_hessian, left_jacobian
from ._filter import ORDERS, FilterState, MinimumEnergyFilter, Trajectory
from ._integrators import INTEGRATORS, RKMK4, AbstractIntegrator, LieEuler, integrator
from ._riccati import Terms, Weights, riccati_rhs, terms

__all__ = ["MinimumEnergyFilter", "ORDERS", "FilterState", "Trajectory", "Terms", "Weights", "terms", "riccati_rhs",
           "left_jacobian", "left_hessian", "AbstractIntegrator", "LieEuler", "RKMK4", "INTEGRATORS", "integrator"]
