r"""The fixed-lag smoother: online, the estimate of the state ``lag`` samples back from every sample up to now.

At each new sample $t_e$ it minimizes the cost of :mod:`._batch` over the window $t_s..t_e$ ($s = e - L$, $L$ =
``lag`` samples), with the filter's estimate at $t_s$ as the window's prior: the filter's $\hat g(t_s)$ and K,
which carry every sample before $t_s$. On a linear system this is exact: the filter's state at $t_s$ is the
Gaussian of $x_s$ given the samples before it, so the window's minimizer is the whole-log smoother's estimate
given the samples up to $t_e$ (``tests/test_smoother.py`` checks it against the Rauch-Tung-Striebel smoother of
the log cut at $t_e$). On a nonlinear system the filter's estimate is the prior's linearization point, as a
sliding-window estimator's marginalized prior is.

**Cost per step.** One filter step, then Levenberg-Marquardt on the window from the last window's solution
(shifted by one sample, the new state by dead reckoning): each iteration is linear in $L$, and a window whose
start has not moved much converges in a few. The window has a fixed size, padded to a length bucket, so it is
compiled once.
"""

from __future__ import annotations

import collections
import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate
from ..filters import CAUSES, AbstractFilter, FilterState
from ..integrators import AbstractIntegrator
from ..integrators import integrator as make_integrator
from . import _batch


class FixedLagSmoother:
    """Online fixed-lag smoothing of a filter's model (module docstring).

    Args:
        flt: the filter whose model is smoothed (its weights, integrator and sensors).
        state: the filter's initial state at the first sample's time (:meth:`~liemef.MinimumEnergyFilter.init`).
        lag: the window, in samples: each estimate is of the state ``lag`` samples before the newest one.
        gap: an interval longer than this holds no density sample, as in the filter (default: none is a gap).
        integrator: the process model's step (default: the filter's integrator, else RKMK4).
        max_iterations: the most Levenberg-Marquardt steps per window.
        tol: a window has converged when a step's largest component is below it.
        floor_std: the floor of the prior's and the process noise's stds (:data:`~liemef.smoothers.FLOOR_STD`).

    :meth:`update` takes each sample as it comes and, once ``lag + 1`` samples are in, returns the window's
    :class:`~liemef.smoothers.Smoothed`: ``g[0]`` is the estimate of the state at ``ts[0]``, delayed by ``lag``
    samples, ``g[-1]`` that of the newest state, with their covariances and the window's status.
    """

    def __init__(self, flt: AbstractFilter, state: FilterState, lag: int, *, gap: float = math.inf,
                 integrator: str | AbstractIntegrator | None = None, max_iterations: int = 50, tol: float = 1e-9,
                 floor_std: float = _batch.FLOOR_STD):
        if not isinstance(flt, AbstractFilter):
            raise ValueError(f"flt: expected a liemef filter (MinimumEnergyFilter or a baseline), got "
                             f"{type(flt).__name__}")
        flt.check_state(state)
        if not (isinstance(lag, int) and not isinstance(lag, bool) and lag >= 1):
            raise ValueError(f"lag: expected a number of samples >= 1, got {lag!r}")
        self.tol = _batch._check_options(max_iterations, tol, floor_std)
        if not (isinstance(gap, int | float) and gap == math.inf):
            gap = float(_validate.nonnegative("gap", gap))
        self.flt, self.lag, self.gap = flt, lag, gap
        self.max_iterations, self.floor_std = max_iterations, floor_std
        self.integ = make_integrator(integrator if integrator is not None else getattr(flt, "integrator", "rkmk4"))
        self.screens = _batch._screens(flt.system)
        self._state = state  # the filter's state at the newest sample's time, before that sample acts
        self._buffer: collections.deque = collections.deque(maxlen=lag + 1)  # (t, u, y, filter state at t)
        self._last = None  # the last window's estimates

    def update(self, t: float, u, y) -> _batch.Smoothed | None:
        """Take the sample ``(u, y)`` at time ``t`` (after the previous one; NaN: missing, a missing input holds
        the last). Returns the window's smoothed estimates once ``lag + 1`` samples are in, else None."""
        system = self.flt.system
        u = np.zeros(0) if u is None and system.input_dim == 0 else _validate.array("u", u, (system.input_dim,),
                                                                                     missing=True)
        y = _validate.array("y", y, (system.output_dim,), missing=True)
        t = float(t)
        if self._buffer:
            t_prev, u_prev, y_prev, _ = self._buffer[-1]
            if not (math.isfinite(t) and t > t_prev):
                raise ValueError(f"t: expected a time after the previous sample's {t_prev}, got {t}")
            self._state = self.flt.step(self._state, t_prev, u_prev, y_prev, t - t_prev, gap=self.gap)
        elif not math.isfinite(t):
            raise ValueError(f"t: expected a finite time, got {t}")
        self._buffer.append((t, u, y, self._state))
        if len(self._buffer) <= self.lag:
            return None
        return self._solve()

    def _solve(self) -> _batch.Smoothed:
        flt, system = self.flt, self.flt.system
        ts = np.array([b[0] for b in self._buffer])
        first = self._buffer[0][3]
        if int(first.status.code) != CAUSES.OK.code:  # the window's prior is the filter's: no prior, no window
            return _batch.failed(ts, first.g_hat, f"failed: the filter that gives the window's prior failed "
                                                  f"({CAUSES[int(first.status.code)].message})")
        us = np.stack([b[1] for b in self._buffer]) if system.input_dim else np.zeros((ts.size, 0))
        ys = np.stack([b[2] for b in self._buffer])
        us = _batch._held(us, np.asarray(first.u_last, dtype=np.float64))
        if self._last is None:
            init = jax.tree_util.tree_map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]),
                                          *[b[3].g_hat for b in self._buffer])
        else:  # the last window's solution, shifted by one sample; the newest state by dead reckoning
            prev = self._last
            step = _batch.dead_reckoning(system, self.integ, prev[-1], jnp.asarray(ts[-2:]), jnp.asarray(us[-2:]))
            init = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[1:], b[1:]]), prev, step)
        P0 = np.asarray(first.K, dtype=np.float64)
        sm = _batch.solve(system, flt.weights, ts, us, ys, first.g_hat, P0, init, integ=self.integ,
                          screens=self.screens, gap=self.gap, floor_std=self.floor_std,
                          max_iterations=self.max_iterations, tol=self.tol)
        self._last = sm.g if sm.status != "failed" else None
        return sm
