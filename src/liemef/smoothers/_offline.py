"""The smoother of a filter's model behind a filter's ``init``/``run``, so that a study that runs filters runs it
as one more row (``liemef compare broad``'s ``mef-vel-smooth``)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..filters import CAUSES, AbstractFilter, Trajectory, nan_after_failure
from ._chunks import smooth


class OfflineSmoother:
    """``run`` filters the log with ``flt``, then smooths it (:func:`~liemef.smoothers.smooth`, with
    ``options``) from the filter's trajectory, and returns a :class:`~liemef.filters.Trajectory` of the smoothed
    estimates and their marginal covariances: acausal (``offline = True``: estimate k has seen the whole log).

    A failed filter's trajectory is returned as it is. A smoother that fails or does not converge gives a failed
    status at sample 0 (cause ``non-finite`` or ``not converged``) and NaN states after the first, so that no
    study counts it as an estimate.
    """

    offline = True
    has_covariance = True

    def __init__(self, flt: AbstractFilter, **options):
        if not isinstance(flt, AbstractFilter):
            raise ValueError(f"flt: expected a liemef filter, got {type(flt).__name__}")
        self.flt, self.options = flt, options
        self.system = flt.system

    def __repr__(self) -> str:
        return f"OfflineSmoother({self.flt!r})"

    def init(self, *args, **kwargs):
        """The filter's :meth:`~liemef.MinimumEnergyFilter.init`: the prior."""
        return self.flt.init(*args, **kwargs)

    def run(self, state, ts, us, ys, *, gap: float | None = None) -> Trajectory:
        """The smoothed log (class docstring)."""
        traj = self.flt.run(state, ts, us, ys, gap=gap)
        if not traj.ok:
            return traj
        sm = smooth(self.flt, state, ts, us, ys, gap=gap, init=traj.g_hat, **self.options)
        if sm.ok:
            return Trajectory(ts=traj.ts, g_hat=sm.g, K=sm.P, status=traj.status, final=traj.final)
        cause = CAUSES.NONFINITE if sm.status == "failed" else CAUSES.NOT_CONVERGED
        status = dataclasses.replace(traj.status, code=jnp.asarray(cause.code, jnp.int32),
                                     index=jnp.asarray(0, jnp.int32), time=jnp.asarray(float(np.asarray(ts)[0])))
        codes = np.full(np.asarray(ts).shape[0], cause.code, np.int32)
        g, K = nan_after_failure(codes, (sm.g, sm.P), first_given=True)
        return Trajectory(ts=traj.ts, g_hat=g, K=K, status=status, final=traj.final)
