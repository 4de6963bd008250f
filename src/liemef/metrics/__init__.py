r"""Errors between a truth and an estimate, and their statistics over time windows.

Two error measures:

* :func:`state_error`: $\delta = q - \hat q$ in the group's coordinates (truth minus estimate, as in
  Rigo et al. 2022, Sec. VI), angles wrapped to $(-\pi, \pi]$;
* :func:`group_error`: $\log(\hat g^{-1} g)$, the body-frame error on the group.

:func:`error_stats` (traceable, vmap-able) gives per-component mean, std and rms over a :class:`Window`;
:func:`error_table` collects them for several windows with names and units (:func:`state_labels`) into an
:class:`ErrorTable` that prints and serializes itself. :func:`gain_stats` summarizes the symmetry and
definiteness of a gain over a run; :func:`continuous_angles` prepares angle time series for figures.
Consistency: :func:`left_error` (the error K is the covariance of), :func:`nees`, :func:`run_nees` (a run against
its truth, one call) and :func:`chi2_bounds`;
:func:`wilson_interval` for a fraction of trials. Without a truth: :func:`innovation_monitor`, whether a run's
innovations are consistent with its K and its linearization sound (:func:`innovation_nis` and
:func:`linearization_leak` per sample, :func:`gain_is_covariance` where the test applies). Trajectories:
:func:`pose_parts` (a position and a quaternion off any pose-like state) and :func:`ape_rpe`, the absolute and
relative pose errors by evo's library. Attitudes as BROAD scores them: :func:`attitude_rms` (total, heading,
inclination), :func:`attitude_error_per_second` and :func:`attitude_error` per sample; the magnetometer against
the reference, :func:`field_against_reference`.
"""

from ._attitude import (
    ATTITUDE_METRICS,
    attitude_error,
    attitude_error_per_second,
    attitude_rms,
    field_against_reference,
)
from ._consistency import chi2_bounds, left_error, nees, run_nees, wilson_interval
from ._errors import angle_mask, continuous_angles, coordinate_error, group_error, state_error, wrap_angle
from ._gain import gain_stats
from ._innovations import (
           InnovationReport,
           SensorVerdict,
           gain_is_covariance,
           innovation_monitor,
           innovation_nis,
           linearization_leak,
)
from ._labels import group_error_labels, state_labels
from ._stats import FULL, ErrorTable, Window, error_stats, error_table, window_mask
from ._trajectory import ape_rpe, pose_parts

__all__ = ["wrap_angle", "angle_mask", "coordinate_error", "state_error", "group_error", "state_labels",
           "group_error_labels", "Window", "FULL", "window_mask", "error_stats", "error_table", "ErrorTable",
           "continuous_angles", "gain_stats", "left_error", "nees", "run_nees", "chi2_bounds",
           "wilson_interval", "pose_parts", "ape_rpe", "innovation_monitor", "innovation_nis", "linearization_leak",
           "gain_is_covariance", "InnovationReport", "SensorVerdict", "attitude_rms", "attitude_error_per_second",
           "attitude_error", "ATTITUDE_METRICS", "field_against_reference"]
