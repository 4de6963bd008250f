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
* ``broad-ins``: inertial navigation on SE_2(3) with BROAD's real IMU and optical position fixes
  (:class:`BroadInsComparison`);
* ``second-order``: the second-order safety suite, every filter on the same trials of 12 systems
  (:class:`SecondOrderSuite`);
* ``wifibot``: the planar filters on UKF-M's Wifibot runs with synthetic GPS (:class:`WifibotComparison`).
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .. import registry
from . import (
    _attitude_basin,
    _basins,
    _broad,
    _broad_ins,
    _inertial,
    _inertial_basin,
    _localization,
    _second_order,
    _wifibot,
)
from ._attitude_basin import AttitudeBasin, compare_attitude_basin
from ._basins import HeadingBasin, compare_heading_basin
from ._broad import BroadComparison, compare_broad
from ._broad_ins import BroadInsComparison, compare_broad_ins
from ._common import FILTERS, bootstrap_interval, make_filter, paired_comparison, parse_filters, unscored
from ._inertial import InertialComparison, compare_inertial
from ._inertial_basin import InertialBasin, compare_inertial_basin
from ._localization import DEFAULT_FILTERS as LOCALIZATION_FILTERS
from ._localization import LocalizationComparison, compare_localization
from ._second_order import SecondOrderSuite, compare_second_order
from ._wifibot import WifibotComparison, compare_wifibot


@dataclass(frozen=True)
class Study:
    """A study of ``liemef compare``: its settings class, its runner and how its result is written."""

    description: str
    settings: type
    run: Callable[..., dict]
    markdown: Callable[[dict], str]
    save: Callable[[dict, Any], list]


_PARTS = {
    "localization": (LocalizationComparison, compare_localization, _localization.markdown, _localization.save),
    "heading-basin": (HeadingBasin, compare_heading_basin, _basins.markdown, _basins.save),
    "attitude-basin": (AttitudeBasin, compare_attitude_basin, _attitude_basin.markdown, _attitude_basin.save),
    "inertial-navigation": (InertialComparison, compare_inertial, _inertial.markdown, _inertial.save),
    "inertial-basin": (InertialBasin, compare_inertial_basin, _inertial_basin.markdown, _inertial_basin.save),
    "broad": (BroadComparison, compare_broad, _broad.markdown, _broad.save),
    "broad-ins": (BroadInsComparison, compare_broad_ins, _broad_ins.markdown, _broad_ins.save),
    "second-order": (SecondOrderSuite, compare_second_order, _second_order.markdown, _second_order.save),
    "wifibot": (WifibotComparison, compare_wifibot, _wifibot.markdown, _wifibot.save),
}
STUDIES = {name: Study(registry.get("comparison", name).title, *_PARTS[name]) for name in registry.names("comparison")}
"""The studies of ``liemef compare``, in the order of :mod:`liemef.studies.registry` (which names and
describes them)."""

def failures(result: dict) -> tuple[list[str], int, int]:
    """What failed in a comparison's ``result``: one line per filter (and system, case, recording, trial or angle)
    that failed somewhere, the number of (filter, trial) pairs that failed and the number run."""
    lines, failed, total = [], 0, 0
    for sname, sysr in result.get("systems", {}).items():
        for name, e in sysr["filters"].items():
            n = sum(r["failed"] for r in e["angles"])
            failed, total = failed + n, total + sum(r["trials"] for r in e["angles"])
            if n:
                lines.append(f"{sname}: {name} failed in {n} trials (counted as not converged)")
    for cname, case in result.get("cases", {}).items():
        for name, e in case["filters"].items():
            failed, total = failed + e["failed"], total + e["runs"]
            if e["failed"]:
                first = e["failures"][0]
                lines.append(f"{cname}: {name} failed in {e['failed']} of {e['runs']} trials (first: trial "
                             f"{first['trial']}, {first['cause']} at t = {first['time']:.3f} s); left out of the "
                             "statistics")
    for rid, rec in result.get("recordings", {}).items():
        for name, e in rec["filters"].items():
            failed, total = failed + e["failed"], total + e["runs"]
            if e["failed"]:
                lines.append(f"recording {rid}: {name} failed on {e['failed']} of {e['runs']} seeds; left out of "
                             "the statistics")
    for tid, per in result.get("trials", {}).items():
        why = unscored(tid, per)  # a run with nothing scored is of no use either, however ok
        if why is not None:
            lines.append(why)
        for name, r in per["filters"].items():
            failed, total = failed + (not r["ok"] or why is not None), total + 1
            if not r["ok"]:
                lines.append(f"trial {tid}: {name} failed: {r['status']}; its errors are of the states before")
    for tid, per in result.get("per_trial", {}).items():
        why = unscored(tid, per)
        if why is not None:
            lines.append(why)
        for variant, ve in per["variants"].items():
            for name, r in ve["filters"].items():
                failed, total = failed + (not r["ok"] or why is not None), total + 1
                if not r["ok"]:
                    lines.append(f"trial {tid} ({variant}): {name} failed: {r['status']}; no figures")
    for name, e in result.get("filters", {}).items():
        n = e.get("diverged", {}).get("count", 0)
        if "runs" in e:
            failed, total = failed + n, total + e["runs"]
        if n:
            first = e["diverged"]["trials"][0]
            lines.append(f"{name}: {n} of {e['runs']} trials failed (first: trial {first['trial']}, "
                         f"{first['cause']} at t = {first['time']:.3f} s); left out of the statistics")
        for r in e.get("angles", []):
            failed, total = failed + r["failed"], total + r["trials"]
            if r["failed"]:
                lines.append(f"{name}: {r['failed']} of {r['trials']} trials at {r['angle_deg']:g} deg failed "
                             "(counted as not converged)")
    return lines, failed, total


__all__ = ["STUDIES", "Study", "failures", "FILTERS", "make_filter", "parse_filters", "paired_comparison",
           "bootstrap_interval",
           "LocalizationComparison", "compare_localization", "LOCALIZATION_FILTERS", "HeadingBasin",
           "compare_heading_basin", "AttitudeBasin", "compare_attitude_basin", "BroadComparison", "compare_broad",
           "BroadInsComparison", "compare_broad_ins",
           "SecondOrderSuite", "compare_second_order",
           "WifibotComparison", "compare_wifibot", "InertialComparison", "compare_inertial", "InertialBasin",
           "compare_inertial_basin"]
