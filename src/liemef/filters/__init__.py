"""The filters: the mathematics of one sample interval, with no engine and no I/O.

:class:`MinimumEnergyFilter` (Theorem 4.1 of Saccon et al. 2016) is built from the left-trivialized derivatives
(:func:`left_jacobian`, :func:`left_hessian`), the Riccati terms (:func:`terms`, :func:`riccati_rhs`), the
sample update at a sample's own time (:func:`sample_update`, with :func:`safe_curvature`) and a
Lie-group integrator (:mod:`liemef.integrators`); the baselines (:mod:`liemef.filters.baselines`) share its
:class:`AbstractFilter` interface, state and :class:`Status`. That interface is public and is all the layers above
read: :meth:`AbstractFilter.interval` (one sample interval), ``init``, the state checks, and the log and sample
checks (:func:`check_log`, :func:`check_samples`, :func:`check_time`) that every engine shares.
"""

from ._base import (
    TRACES,
    AbstractFilter,
    FilterState,
    IntervalSamples,
    Trajectory,
    UpdateResult,
    check_log,
    check_samples,
    check_time,
    nan_after_failure,
    sample_covariance,
    sensor_layout,
)
from ._curvature import safe_curvature
from ._derivatives import left_hessian, left_jacobian
from ._mef import ERROR_SIDES, INTERPOLATIONS, ORDERS, UPDATES, MinimumEnergyFilter
from ._riccati import Terms, Weights, information_in_force, riccati_rhs, terms
from ._status import CAUSES, DEFINITE_TOL, FILTER_CAUSES, Status
from ._update import UpdateInfo, sample_update

__all__ = ["MinimumEnergyFilter", "AbstractFilter", "sensor_layout", "ORDERS", "INTERPOLATIONS", "UPDATES",
           "ERROR_SIDES", "TRACES",
           "Status", "CAUSES", "information_in_force", "FilterState", "Trajectory", "Terms", "Weights", "terms",
           "riccati_rhs", "left_jacobian", "left_hessian", "safe_curvature", "sample_update", "UpdateInfo",
           "UpdateResult", "IntervalSamples", "check_log", "check_samples", "check_time", "nan_after_failure",
           "sample_covariance", "DEFINITE_TOL", "FILTER_CAUSES"]
