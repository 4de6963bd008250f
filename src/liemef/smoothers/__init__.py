r"""The minimum-energy smoother: every state of a whole log estimated from all of its samples.

A filter's estimate at $t_k$ uses the samples up to $t_k$. :func:`smooth` minimizes the same cost over the whole
log, so every state's estimate uses the samples before and after it (the batch MAP of the model the filter runs:
the same group, sensors, weights, residuals and robust losses), with the marginal covariance of each state.
A log too long to hold as one problem is smoothed in windows with overlap (``chunk=``,
:func:`smooth_chunks`), in the memory of one window. :class:`FixedLagSmoother` does it online over a window of
the last samples, for estimates delayed by that window. docs/smoothing.md states the cost, the solver and what
it was checked against.
"""

from ._batch import FLOOR_STD, STATUSES, Smoothed, dead_reckoning, floor_eigenvalues, sample_information, solve
from ._chunks import smooth, smooth_chunks
from ._lag import FixedLagSmoother
from ._offline import OfflineSmoother

__all__ = ["smooth", "smooth_chunks", "Smoothed", "FixedLagSmoother", "OfflineSmoother", "STATUSES", "FLOOR_STD",
           "solve", "dead_reckoning", "sample_information", "floor_eigenvalues"]
