r"""Comparisons of the minimum-energy filter with the filters people use (:mod:`liemef.filters.baselines`), on the same
trials: ``liemef compare STUDY`` writes each study's metrics, tables (Markdown, CSV) and figures.

Studies (:data:`STUDIES`):

* ``localization``: ukfm's 2D localization benchmark, every filter on the same trials
  (:class:`LocalizationComparison`);
* ``heading-basin``: the convergence basin in the initial heading error on the same scenario
  (:class:`HeadingBasin`);
* ``attitude-basin``: the convergence basin in the initial attitude error on TSO(3), Saccon et al.'s rigid body
  and attitude + gyro bias (:class:`AttitudeBasin`);
* ``inertial-navigation``: ukfm's inertial-navigation benchmark on SE_2(3), every filter on the same trials
  (:class:`InertialComparison`);
* ``inertial-basin``: the convergence basin in the initial attitude error on the same scenario
  (:class:`InertialBasin`);
* ``broad``: the attitude filters on the BROAD recordings (:class:`BroadComparison`);
* ``wifibot``: the planar filters on UKF-M's Wifibot runs with synthetic GPS (:class:`WifibotComparison`).
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from . import _attitude_basin, _basins, _broad, _inertial, _inertial_basin, _localization, _wifibot
from ._attitude_basin import AttitudeBasin, compare_attitude_basin
from ._basins import HeadingBasin, compare_heading_basin
from ._broad import BroadComparison, compare_broad
from ._common import FILTERS, bootstrap_interval, make_filter, paired_comparison, parse_filters
from ._inertial import InertialComparison, compare_inertial
from ._inertial_basin import InertialBasin, compare_inertial_basin
from ._localization import DEFAULT_FILTERS as LOCALIZATION_FILTERS
from ._localization import LocalizationComparison, compare_localization
from ._wifibot import WifibotComparison, compare_wifibot


@dataclass(frozen=True)
class Study:
    """A study of ``liemef compare``: its settings class, its runner and how its result is written."""

    description: str
    settings: type
    run: Callable[..., dict]
    markdown: Callable[[dict], str]
    save: Callable[[dict, Any], list]


STUDIES = {
    "localization": Study("ukfm's 2D localization benchmark: every filter on the same trials",
                          LocalizationComparison, compare_localization, _localization.markdown, _localization.save),
    "heading-basin": Study("convergence basin in the initial heading error (0-180 deg) on the same scenario",
                           HeadingBasin, compare_heading_basin, _basins.markdown, _basins.save),
    "attitude-basin": Study("convergence basin in the initial attitude error (0-180 deg) on TSO(3): rigid body and "
                            "attitude + gyro bias", AttitudeBasin, compare_attitude_basin, _attitude_basin.markdown,
                            _attitude_basin.save),
    "inertial-navigation": Study("ukfm's inertial-navigation benchmark on SE_2(3): every filter on the same trials",
                                 InertialComparison, compare_inertial, _inertial.markdown, _inertial.save),
    "inertial-basin": Study("convergence basin in the initial attitude error (0-180 deg) on ukfm's inertial "
                            "navigation", InertialBasin, compare_inertial_basin, _inertial_basin.markdown,
                            _inertial_basin.save),
    "broad": Study("the BROAD attitude recordings: the MEF, the EKF, the UKF-M, Madgwick and Mahony",
                   BroadComparison, compare_broad, _broad.markdown, _broad.save),
    "wifibot": Study("UKF-M's Wifibot runs: real wheel odometry, optical truth, synthetic GPS over seeds",
                     WifibotComparison, compare_wifibot, _wifibot.markdown, _wifibot.save),
}
"""The studies of ``liemef compare``."""

__all__ = ["STUDIES", "Study", "FILTERS", "make_filter", "parse_filters", "paired_comparison", "bootstrap_interval",
           "LocalizationComparison", "compare_localization", "LOCALIZATION_FILTERS", "HeadingBasin",
           "compare_heading_basin", "AttitudeBasin", "compare_attitude_basin", "BroadComparison", "compare_broad",
           "WifibotComparison", "compare_wifibot", "InertialComparison", "compare_inertial", "InertialBasin",
           "compare_inertial_basin"]
