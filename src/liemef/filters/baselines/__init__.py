r"""The filters people compare with, on any liemef system and with the same interface as the minimum-energy filter
(``init``, ``step``, ``run``, ``scan``, the status and the sensors' noise levels):

* :class:`ExtendedKalmanFilter`: the invariant EKF (``error="left"``, :func:`invariant_ekf`) and the EKF in local
  coordinates (``error="local"``, :func:`local_ekf`);
* :class:`UnscentedKalmanFilter`: the UKF on the manifold (UKF-M, :func:`ukf_m`), left retraction by default;
* :class:`Madgwick` and :class:`Mahony`: the AHRS filters of the ``ahrs`` package, on attitude systems (no
  covariance: ``has_covariance = False``);
* :class:`VQF`: Laidig and Seel's VQF (the ``vqf`` package), online or offline, on attitude systems;
* :class:`Fusion`: x-io Technologies' Fusion AHRS (the ``imufusion`` package), on attitude systems.

Their state's ``K`` is the covariance of the left error $\xi$, $g = \hat g\exp\xi$, whatever their own error
coordinates, as the minimum-energy filter's K: metrics and NEES read every filter the same way.
"""

from ._ahrs import Madgwick, Mahony
from ._fusion import Fusion
from ._kalman import (
    ERRORS,
    AbstractKalmanFilter,
    ExtendedKalmanFilter,
    UnscentedKalmanFilter,
    invariant_ekf,
    local_ekf,
    retraction,
    ukf_m,
)
from ._vqf import VQF

__all__ = ["AbstractKalmanFilter", "ExtendedKalmanFilter", "UnscentedKalmanFilter", "invariant_ekf", "local_ekf",
           "ukf_m", "ERRORS", "retraction", "Madgwick", "Mahony", "VQF", "Fusion"]
