r"""Comparisons of the minimum-energy filter with the filters people use (:mod:`liemef.baselines`), on the same
trials or recordings: ``liemef compare STUDY`` writes each study's metrics, tables (Markdown, CSV) and figures.

Studies: ``localization`` (ukfm's 2D localization benchmark, :mod:`liemef.compare._localization`).
"""

from ._common import FILTERS, bootstrap_interval, make_filter, paired_comparison, parse_filters
from ._localization import DEFAULT_FILTERS as LOCALIZATION_FILTERS
from ._localization import LocalizationComparison, compare_localization

STUDIES = {"localization": "ukfm's 2D localization benchmark: every filter on the same trials"}
"""The studies of ``liemef compare``."""

__all__ = ["STUDIES", "FILTERS", "make_filter", "parse_filters", "paired_comparison", "bootstrap_interval",
           "LocalizationComparison", "compare_localization", "LOCALIZATION_FILTERS"]
