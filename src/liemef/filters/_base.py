r"""What every filter of the library shares: its state, its trajectory, the sample conventions and the health
checks of one interval.

A filter is an :class:`AbstractFilter` that says how one sample interval ``[t, t + dt]`` advances its state
(:meth:`~AbstractFilter.interval`), from :meth:`~AbstractFilter.init`'s state. The minimum-energy filter
(:class:`~liemef.MinimumEnergyFilter`) and the baselines (:mod:`liemef.filters.baselines`) are such filters: they
share the sample conventions (a sample at ``ts[k]`` is used over ``[ts[k], ts[k+1])``, NaN is missing), the
status and the outputs. What loops over intervals (a log, a batch, a robot's loop) is the engines' layer, above
this one, which reads only this public contract (``interval``, ``init``, ``check_state``, ``check_element`` and
the checks of this module); the methods ``run``, ``run_batch``, ``scan``, ``step``, ``predict`` and ``online``
call the engines the package's root gives this layer (``liemef._runner``), so that it never imports them.
``update``, the update at a sample's time with the sample's log-likelihood, is this layer's own (compiled by
XLA).
"""

from __future__ import annotations

import abc
import collections
import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .. import _side, _validate
from .._runner import engines
from ..groups import LieGroup
from ..systems._traced import is_traced
from ._riccati import information_in_force
from ._status import CAUSES, DEFINITE_TOL, SYMMETRY_TOL, Status, positive_definite


class FilterState(eqx.Module):
    """The filter's state: the estimate $\\hat g$, the gain K (n x n), the last input (held over missing input
    samples) and the :class:`~liemef.filters.Status` of the run so far."""

    g_hat: LieGroup
    K: Float[Array, "n n"]
    u_last: Float[Array, " m"]
    status: Status


class Trajectory(eqx.Module):
    """A filter run: ``g_hat[k]`` and ``K[k]`` at ``ts[k]`` (``g_hat`` has batch shape (N,)).

    ``status`` says whether the run failed, where, when and why (:class:`~liemef.filters.Status`); the states
    after a failure are NaN, so that nothing downstream can mistake them for estimates, and ``final`` is the
    last good state (the state at ``ts[-1]`` when the run is healthy), from which a run can continue.
    With ``keep_every = M`` the history holds every M-th sample (``ts = log ts[::M]``).
    """

    ts: Float[Array, " N"]
    g_hat: LieGroup
    K: Float[Array, "N n n"]
    status: Status
    final: FilterState

    @property
    def ok(self) -> Bool[Array, ""]:
        """True if the run did not fail (its status is ok; a failed run has NaN states after the failure)."""
        return self.status.code == CAUSES.OK.code

    def coords(self) -> Float[Array, "N c"]:
        """The estimate in the group's coordinates (e.g. theta, x, y, omega, vx, vy for TSE(2))."""
        return self.g_hat.coords()


class UpdateResult(eqx.Module):
    r"""What :meth:`AbstractFilter.update` made of one sample, filterpy's per-step quantities (NaN marks a missing
    component, as in the sample):

    - ``log_likelihood``: $\log L = -\tfrac12\bigl(\nu^\top S^{-1}\nu + \log\det(2\pi S)\bigr)$ of the sample
      under the prior (the state given to ``update``), over its present components; 0 with none present, NaN
      where S is not positive definite. Summed over a log's samples it is the log-likelihood of the log
      (the prediction-error decomposition).
    - ``innovation``: $\nu = y \ominus h(\hat g)$, the output as seen from the sample (angles wrap), on the
      present components.
    - ``S``: the innovation covariance $H K H^\top + R$ on the present components (p x p).
    - ``nis``: $\nu^\top S^{-1}\nu$ (the normalized innovation squared of the present components; 0 with none).
    - ``sensors_used``: per sensor block, whether the update used its sample (present, not rejected by the
      sensor's gate and of nonzero weight).
    """

    log_likelihood: Float[Array, ""]
    innovation: Float[Array, " p"]
    S: Float[Array, "p p"]
    nis: Float[Array, ""]
    sensors_used: Bool[Array, " b"]


def nan_after_failure(codes, states, *, first_given: bool):
    """The rule of a :class:`Trajectory`: ``states`` (a pytree whose leaves have the shape of ``codes`` in front)
    with NaN wherever their status ``codes`` is not ok, except, with ``first_given``, the first state along the
    last axis of ``codes`` (a history's time axis: the state given, never NaN). One state (``codes`` 0-d, as the
    XLA scan emits them) or a history (the C engine's rows). NumPy states stay NumPy, returned as they are when
    none failed; JAX ones stay JAX (traceable, under ``vmap`` too)."""
    xp = np if isinstance(codes, np.ndarray) else jnp
    bad = codes != CAUSES.OK.code
    if first_given:
        bad = bad & (xp.arange(codes.shape[-1]) > 0)
    if xp is np and not bad.any():
        return states

    def nan(a):
        return xp.where(bad if bad.ndim == 0 else bad.reshape(bad.shape + (1,) * (a.ndim - bad.ndim)), xp.nan, a)

    return jax.tree_util.tree_map(nan, states)


TRACES: collections.Counter = collections.Counter()
"""How many times each compiled entry point was traced (= compiled): ``TRACES["run"]``, ``TRACES["step"]``,
``TRACES["update"]``."""


def sensor_layout(system, Wy) -> tuple[tuple, tuple[bool, ...], bool]:
    """The sensor layout a filter needs: the system's blocks, per output component whether it has sample
    meaning, and whether the information matrix ``Wy`` is diagonal (a missing component is then dropped by
    zeroing its row and column; otherwise the filter forms the marginal information, docs/weights.md)."""
    blocks = system.blocks()
    sample = [False] * system.output_dim
    for b in blocks:
        sample[b.start:b.stop] = [b.sample] * b.dim
    Wy = np.asarray(Wy)
    return blocks, tuple(sample), bool(np.array_equal(Wy, np.diag(np.diag(Wy))))


class IntervalSamples(NamedTuple):
    """One sample interval's data under the shared conventions (:meth:`AbstractFilter.samples`)."""

    u0: Float[Array, " m"]
    """The input at the interval's start (the last present one where missing)."""
    u1: Float[Array, " m"]
    """The input at its end (``u0`` where missing)."""
    u_ok: Bool[Array, " m"]
    """Which components of the given ``u0`` were present."""
    y0: Float[Array, " p"]
    """The sample at the start, zeros where missing."""
    y1: Float[Array, " p"]
    """The sample at the end for density sensors present at both ends (``y0`` elsewhere)."""
    mask: Bool[Array, " p"]
    """The present components of ``y0``."""
    Wy: Float[Array, "p p"]
    """The information in force over the interval, per unit time."""
    is_gap: Bool[Array, ""]
    """Whether the interval is longer than the gap threshold."""


def sample_covariance(Wy, dt, present, block) -> Float[Array, "k k"]:
    """The covariance of one sample of the sensor ``block``: the inverse of its information over the interval
    ``dt`` it is used in, ``Wy[sl, sl] * dt`` with ``Wy`` the information in force
    (:func:`~liemef.filters._riccati.information_in_force`, where a sample sensor's information is already
    divided by ``dt``), so ``inv(Wy_block * dt)`` for a density sensor and ``inv(Wy_block)`` per sample.
    The identity where the block is not ``present``. The one definition of the gates' and the innovation
    monitor's (:func:`liemef.metrics.innovation_monitor`) sample covariance. Traceable."""
    sl = slice(block.start, block.stop)
    info = jnp.where(present, Wy[sl, sl] * dt, jnp.eye(block.dim))
    return jnp.linalg.inv(info)


class _hot_path:
    """A method read off a filter as a plain ``functools.partial``: equinox builds a bound-method Module at each
    read of an ordinary method (tens of microseconds), too slow for :meth:`AbstractFilter.step` in a robot's
    loop."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, cls=None):
        return self.fn if obj is None else functools.partial(self.fn, obj)


class AbstractFilter(eqx.Module):
    """A filter on a liemef system: :meth:`init`, :meth:`step`, :meth:`run` and :meth:`scan` over the
    sample intervals of a log, with the status of the run (:class:`~liemef.filters.Status`), and a step's two
    halves, :meth:`update` and :meth:`predict`.

    A concrete filter holds ``system``, ``weights`` (the system's nominal :class:`~liemef.filters.Weights`),
    ``blocks``, ``sample`` and ``diagonal`` (the sensor layout, see :func:`sensor_layout`) and ``symmetric``
    (whether K must stay symmetric), and implements :meth:`interval`, with :meth:`samples` and :meth:`finish`
    for the shared conventions. For :meth:`update` it implements ``_prior_output`` (the predicted output and its
    covariance from the state) and ``_correct`` (the state after a sample of given information), which its
    ``interval`` uses too.
    """

    @abc.abstractmethod
    def interval(self, state: FilterState, t, dt, u0, u1, y0, y1, gap) -> FilterState:
        """The state after the sample interval ``[t, t + dt]``: the extension point of every filter, and all an
        engine calls (traced once per filter structure, by XLA or into the C kernel).

        ``u0``, ``y0`` are the samples at ``t`` and ``u1``, ``y1`` those at ``t + dt`` (NaN: missing; shapes
        (m,) and (p,)); ``gap`` the threshold above which ``dt`` is a gap. Pure and traceable: arrays in, a
        :class:`FilterState` out, with no check and no Python branch on a value (a failure is the status that
        :meth:`finish` writes, never an exception)."""

    def __hash__(self) -> int:
        # The structure only (static fields and non-array leaves), never the arrays: filters equal as pytrees
        # hash equal, and ``jax.jit(flt.vector_field)`` works (equality still compares the arrays).
        leaves, treedef = jax.tree_util.tree_flatten(self)
        return hash((treedef, tuple(x for x in leaves if not eqx.is_array(x))))


    @property
    def n(self) -> int:
        """The dimension n of the group's algebra (K is n x n)."""
        return self.system.group.tangent_dim

    # --- initialisation -----------------------------------------------------------------------------------
    def init(self, g0: LieGroup, K0: ArrayLike | None = None, *, X0: ArrayLike | None = None,
             u0: ArrayLike | None = None) -> FilterState:
        """Initial state: ``g_hat = g0`` (argmin of m0) and ``K = K0``, or ``K = X0^{-1}`` with X0 the
        left-trivialized Hessian of m0. K0 may be singular (positive semidefinite), as in Rigo et al. 2023,
        eq. (63). ``u0`` is the input held until the first present input sample (default zeros).

        The system's outputs and residuals are evaluated once at ``g0`` (t = 0, outside a trace): an output that
        is NaN there, or a residual that is not finite at ``y = h``, is a ValueError naming its sensor and function
        (:meth:`~liemef.systems.AbstractSystem.check_finite_at`; an infinite output, a singularity, passes)."""
        self.check_element("g0", g0)
        if not is_traced(g0):
            self.system.check_finite_at(g0)
        n, m = self.n, self.system.input_dim
        if (K0 is None) == (X0 is None):
            raise ValueError("init: expected exactly one of K0 (initial gain) or X0 (Hessian of m0), got "
                             f"{'both' if K0 is not None else 'neither'}")
        if K0 is not None:
            K = _validate.symmetric_psd("K0", K0, n, definite=False)
        else:
            K = np.linalg.inv(_validate.symmetric_psd("X0", X0, n))
        u = np.zeros(m) if u0 is None else _validate.array("u0", u0, (m,))
        return FilterState(g_hat=g0, K=jnp.asarray(K), u_last=jnp.asarray(u), status=Status.initial(len(self.blocks)))


    def samples(self, state: FilterState, dt, u0, u1, y0, y1, gap) -> IntervalSamples:
        """The interval's data under the shared conventions (:class:`IntervalSamples`): a missing input sample
        holds the last one; a missing measurement component has no weight; density samples are not held across
        a gap; the information in force ``Wy`` is per unit time (a sample sensor's divided by ``dt``), for sensors
        marked ``adaptive`` given the sample (:meth:`~liemef.systems.AbstractSystem.sample_transform`).
        Traceable; for :meth:`interval`."""
        sample = jnp.asarray(self.sample, dtype=bool)
        u_ok = jnp.isfinite(u0)
        u0 = jnp.where(u_ok, u0, state.u_last)
        u1 = jnp.where(jnp.isfinite(u1), u1, u0)
        is_gap = dt > gap
        mask = jnp.isfinite(y0) & ~(is_gap & ~sample)
        dense = mask & jnp.isfinite(y1) & ~sample
        y0 = jnp.where(mask, y0, 0.0)
        y1 = jnp.where(dense, y1, y0)
        Wy = self.adapted(information_in_force(self.weights.Wy, sample, mask, dt, diagonal=self.diagonal), y0)
        return IntervalSamples(u0, u1, u_ok, y0, y1, mask, Wy, is_gap)

    def adapted(self, Wy, y0):
        """The information ``Wy`` for the sample ``y0`` (zeros where missing): for sensors marked ``adaptive``, a
        heteroscedastic sensor's own noise, Sigma(y) = T^-1 Sigma T^-T, so W(y) = T^T W T; else ``Wy``. Part of
        :meth:`samples`; public for the layers that read a sample's information as the filter does (the
        innovation monitor). Traceable."""
        if not any(b.adaptive for b in self.blocks):
            return Wy
        T = self.system.sample_transform(y0)
        return T.T @ Wy @ T

    def finish(self, state: FilterState, g1, K1, *, t, dt, samples: IntervalSamples, rejected=None,
               consecutive=None, n_sub=1, capped=False, asymmetric=None) -> FilterState:
        """The state after an interval, the end of every :meth:`interval`: checks ``(g1, K1)`` (finite, K
        symmetric where it must be and positive definite, the gates' runs of rejections) and counts the interval
        in the status; a failing interval keeps the state before it, and a state that had failed stays as it
        was. ``samples``: :meth:`samples`' of the interval; ``rejected``, ``consecutive``: the gates' counters
        after it (default: unchanged); ``n_sub``: integrator steps taken, ``capped``: whether the last was
        forced; ``asymmetric``: the filter's own verdict that K cannot stay symmetric (in place of checking
        K1's symmetry). Traceable."""
        st = state.status
        u0, u_ok, is_gap = samples.u0, samples.u_ok, samples.is_gap
        rejected = st.rejected if rejected is None else rejected
        consecutive = st.consecutive if consecutive is None else consecutive
        code = self._health(g1, K1, consecutive, asymmetric)
        new_fail = code != CAUSES.OK.code
        g_out = jax.tree_util.tree_map(lambda a, b: jnp.where(new_fail, a, b), state.g_hat, g1)
        K_out = jnp.where(new_fail, state.K, K1)
        n_sub = jnp.asarray(n_sub, jnp.int32)
        status = Status(
            code=code, index=jnp.where(new_fail, st.steps, st.index), time=jnp.where(new_fail, t, st.time),
            steps=st.steps + 1, rejected=rejected, consecutive=consecutive,
            substeps_max=jnp.maximum(st.substeps_max, n_sub), substeps_total=st.substeps_total + n_sub,
            substeps_capped=st.substeps_capped + capped, gaps=st.gaps + is_gap,
            longest_gap=jnp.maximum(st.longest_gap, dt), inputs_held=st.inputs_held + jnp.any(~u_ok))
        out = FilterState(g_hat=g_out, K=K_out, u_last=jnp.where(new_fail, state.u_last, u0), status=status)
        # A failed state is final: later intervals leave all of it unchanged (estimate, gain, held input and the
        # status with its counters, which describe the run up to and including the failing interval).
        return jax.tree_util.tree_map(lambda a, b: jnp.where(st.code != CAUSES.OK.code, a, b), state, out)

    @property
    def _screens_samples(self) -> bool:
        """Whether a sensor has a gate, a robust loss or a time-varying weight (static)."""
        return any(b.gate_threshold is not None or b.robust is not None or b.weight_fn is not None
                   for b in self.blocks)

    def _sensor_scale(self, nu, HKH, t, dt, mask, Wy, st):
        """Per-component weight factors from the sensors' gates, robust losses and time-varying weights, and
        the updated rejection counters, from the innovation ``nu = y - h(g_hat)`` and its covariance from the
        state, ``HKH`` = Dh K Dh^T (the sample's own covariance is added here)."""
        p = self.system.output_dim
        rejected, consecutive = st.rejected, st.consecutive
        if not self._screens_samples:
            return jnp.ones((p,)), rejected, consecutive
        # per block: its factor, its rejection and its run of rejections, stacked at the end (whole arrays, no
        # scatter: the same program in XLA and in the C kernel)
        factors, new_rejected, new_consecutive = [], [], []
        for i, b in enumerate(self.blocks):
            sl = slice(b.start, b.stop)
            factor = jnp.asarray(1.0)
            rej, cons = rejected[i], consecutive[i]
            if b.gate_threshold is not None or b.robust is not None:
                present = jnp.all(mask[sl])
                S = HKH[sl, sl] + sample_covariance(Wy, dt, present, b)
                d2 = nu[sl] @ jnp.linalg.solve(S, nu[sl])
                d2 = jnp.where(jnp.isfinite(d2), d2, jnp.inf)
                if b.gate_threshold is not None:
                    reject = present & (d2 > b.gate_threshold)
                    factor = jnp.where(reject, 0.0, factor)
                    rej = rej + reject.astype(rej.dtype)
                    cons = jnp.where(reject, cons + 1, jnp.where(present, 0, cons))
                if b.robust is not None:
                    d = jnp.sqrt(jnp.maximum(d2, 1e-300))
                    c = b.robust_scale
                    w = jnp.minimum(1.0, c / d) if b.robust == "huber" else 1.0 / (1.0 + (d / c) ** 2)
                    factor = factor * jnp.where(present, w, 1.0)
            if b.weight_fn is not None:
                factor = factor * jnp.asarray(b.weight_fn(t), dtype=jnp.float64)
            factors.append(factor)
            new_rejected.append(rej)
            new_consecutive.append(cons)
        owner = np.full(p, len(self.blocks))  # the block of each component (none: factor 1)
        for i, b in enumerate(self.blocks):
            owner[b.start:b.stop] = i
        scale = jnp.stack([*factors, jnp.asarray(1.0)])[owner]
        return (scale, jnp.stack(new_rejected).astype(rejected.dtype),
                jnp.stack(new_consecutive).astype(consecutive.dtype))

    # --- the update at a sample's time (update) -------------------------------------------------------------
    def _prior_output(self, state: FilterState, t, y0):
        """The output predicted from ``state`` at ``t`` as seen from the sample ``y0`` (zeros where missing),
        its covariance from the state (H K H^T, or the filter's own moments) and what :meth:`_correct` needs
        besides: ``(h0, HKH, aux)``. A filter with a per-sample update implements it."""
        raise NotImplementedError(f"update: {type(self).__name__} has no update at a sample's time; use step")

    def _correct(self, state: FilterState, t, y0, mask, W, prior):
        """``(g_hat, K)`` after the sample ``y0`` (present components ``mask``) of information ``W`` (already
        screened by the sensors' gates), from ``prior`` = :meth:`_prior_output`'s."""
        raise NotImplementedError(f"update: {type(self).__name__} has no update at a sample's time; use step")

    def _update_core(self, state: FilterState, t, y) -> tuple[FilterState, UpdateResult]:
        """Traceable core of :meth:`update` (no checks): the sample's per-sample information, the screening,
        the filter's correction, the log-likelihood and the status."""
        st = state.status
        p = self.system.output_dim
        sample = jnp.asarray(self.sample, dtype=bool)
        mask = jnp.isfinite(y) & sample  # a density sensor has no per-sample information (update refuses it)
        y0 = jnp.where(mask, y, 0.0)
        W = self.adapted(information_in_force(self.weights.Wy, sample, mask, 1.0, diagonal=self.diagonal), y0)
        prior = self._prior_output(state, t, y0)
        h0, HKH = prior[0], prior[1]
        nu = y0 - h0
        scale, rejected, consecutive = self._sensor_scale(nu, HKH, t, 1.0, mask, W, st)
        root = jnp.sqrt(scale)
        g1, K1 = self._correct(state, t, y0, mask, W * root[:, None] * root[None, :], prior)
        # the log-likelihood under the prior, over the present components (the others padded with the identity)
        both = mask[:, None] & mask[None, :]
        eye = jnp.eye(p)
        S = jnp.where(both, HKH + jnp.linalg.inv(jnp.where(both, W, eye)), eye)
        S = 0.5 * (S + S.T)
        L = jnp.linalg.cholesky(S)  # NaN where S is not positive definite
        z = jax.scipy.linalg.solve_triangular(L, jnp.where(mask, nu, 0.0), lower=True)
        nis = z @ z
        log_likelihood = -0.5 * (nis + 2.0 * jnp.sum(jnp.log(jnp.diag(L))) + jnp.sum(mask) * math.log(2 * math.pi))
        used = jnp.stack([jnp.any(mask[b.start:b.stop]) & (scale[b.start] > 0) for b in self.blocks])
        result = UpdateResult(log_likelihood=log_likelihood, innovation=jnp.where(mask, nu, jnp.nan),
                              S=jnp.where(both, S, jnp.nan), nis=nis, sensors_used=used)
        # the state: checked as an interval's (finish), but no interval is counted
        code = self._health(g1, K1, consecutive)
        new_fail = code != CAUSES.OK.code
        g_out = jax.tree_util.tree_map(lambda a, b: jnp.where(new_fail, a, b), state.g_hat, g1)
        status = dataclasses.replace(st, code=code, index=jnp.where(new_fail, st.steps, st.index),
                                     time=jnp.where(new_fail, t, st.time), rejected=rejected,
                                     consecutive=consecutive)
        out = FilterState(g_hat=g_out, K=jnp.where(new_fail, state.K, K1), u_last=state.u_last, status=status)
        out = jax.tree_util.tree_map(lambda a, b: jnp.where(st.code != CAUSES.OK.code, a, b), state, out)
        return out, result

    def _health(self, g, K, consecutive, asymmetric=None):
        """The cause code of a state just computed (:data:`~liemef.filters.CAUSES`)."""
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves((g, K))]))
        Kf = jnp.where(finite, K, jnp.eye(K.shape[0]))
        big = jnp.max(jnp.abs(Kf))
        asym = jnp.max(jnp.abs(Kf - Kf.T)) > SYMMETRY_TOL * jnp.maximum(1.0, big) if asymmetric is None \
            else asymmetric
        Ks = 0.5 * (Kf + Kf.T) + DEFINITE_TOL * jnp.maximum(big, 1e-300) * jnp.eye(K.shape[0])
        definite = positive_definite(Ks)
        gate = jnp.asarray(False)
        for i, b in enumerate(self.blocks):
            if b.max_rejections is not None:
                gate = gate | (consecutive[i] > b.max_rejections)
        code = jnp.where(~finite, CAUSES.NONFINITE.code,
                         jnp.where(asym & self.symmetric, CAUSES.ASYMMETRIC.code,
                                   jnp.where(~definite, CAUSES.INDEFINITE.code,
                                             jnp.where(gate, CAUSES.GATE.code, CAUSES.OK.code))))
        return code.astype(jnp.int32)

    # --- drivers ------------------------------------------------------------------------------------------
    # --- running: by the engines the package's root gives this layer (liemef._runner), which it never imports --
    def run(self, state: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *,
            gap: float | None = None, keep_every: int = 1, engine: str | None = None) -> Trajectory:
        """Filter a whole log: the engines' ``run`` (``ts`` (N,), ``us`` (N, m), ``ys`` (N, p); sample k used
        over ``[ts[k], ts[k+1])``; ``engine``: ``"auto"``, ``"c"`` or ``"xla"``)."""
        return engines().run(self, state, ts, us, ys, gap=gap, keep_every=keep_every, engine=engine)

    def run_batch(self, states: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *,
                  gap: float | None = None, keep_every: int = 1, engine: str | None = None,
                  threads: int | None = None) -> Trajectory:
        """Filter B logs on one time grid: the engines' ``run_batch`` (``states`` with a leading trial axis,
        ``us`` (B, N, m), ``ys`` (B, N, p))."""
        return engines().run_batch(self, states, ts, us, ys, gap=gap, keep_every=keep_every, engine=engine,
                                    threads=threads)

    def scan(self, state: FilterState, ts, us, ys, *, gap=jnp.inf, n_valid=None, keep_every: int = 1,
             engine: str | None = "xla") -> Trajectory:
        """Traceable core of :meth:`run` (no checks): the engines' ``scan``."""
        return engines().scan(self, state, ts, us, ys, gap=gap, n_valid=n_valid, keep_every=keep_every,
                               engine=engine)

    @_hot_path
    def step(self, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float, *,
             u_next: ArrayLike | None = None, y_next: ArrayLike | None = None, gap: float = math.inf,
             engine: str | None = None) -> FilterState:
        """Advance one sample interval ``[t, t + dt]`` (online use): the engines' ``step``."""
        return engines().step(self, state, t, u, y, dt, u_next=u_next, y_next=y_next, gap=gap, engine=engine)

    @_hot_path
    def predict(self, state: FilterState, t: float, u: ArrayLike, dt: float, *, u_next: ArrayLike | None = None,
                gap: float = math.inf, engine: str | None = None) -> FilterState:
        """The propagation over ``[t, t + dt]`` with no measurement: exactly :meth:`step` with every output
        component missing (``y`` all NaN), by the same engine (``engine`` as in ``step``), checks included.

        With :meth:`update` it splits a step in filterpy's two calls: ``flt.predict(flt.update(state, t, y)[0],
        t, u, dt)`` is ``flt.step(state, t, u, y, dt)`` to round-off where every present sensor is a sample
        sensor, for the Kalman baselines and for the minimum-energy filter with ``updates="discrete"``
        (docs/concepts.md, "Predict and update")."""
        return engines().step(self, state, t, u, np.full(self.system.output_dim, np.nan), dt, u_next=u_next,
                               gap=gap, engine=engine)

    @_hot_path
    def update(self, state: FilterState, t: float, y: ArrayLike) -> tuple[FilterState, UpdateResult]:
        r"""The update of ``state`` at time ``t`` with the sample ``y`` (p,) (NaN: a missing component), and the
        sample's innovation and log-likelihood under the prior (:class:`UpdateResult`).

        Each present sensor brings its information **per sample** (its ``Noise.sample`` std, the sensor's noise
        model ``scale`` included: docs/weights.md, "One sample carries its information once"). A density sensor
        (``Noise.density``) has no information per sample: a present component of one is refused (use
        :meth:`step`, which spreads it over the interval). Each filter updates as its own step does: the
        minimum-energy filter by the hybrid filter's sample update (:func:`~liemef.filters.sample_update`, with
        the filter's ``iterations``, ``order``, ``curvature`` and ``tol``, whatever its ``updates``), a Kalman
        baseline by its Kalman update. Sensors' gates, robust losses and time-varying weights screen the sample
        as in ``step`` (the gate reads the same innovation covariance, and counts its rejections in the
        status); they decide how much of the sample the update uses, not how likely it was: the
        log-likelihood is the model's, $S = H K H^\top + R$ with R the sample's noise covariance on its present
        components, H the output's left Jacobian (a Kalman baseline: its own moments, $H P H^\top$ in its error
        coordinates or the sigma points' spread).

        ``predict(update(state, t, y)[0], t, u, dt)`` is ``step(state, t, u, y, dt)`` to round-off for a
        Kalman baseline, and for the minimum-energy filter with ``updates="discrete"``, where the present
        sensors are sample sensors. An update that fails (a non-finite state, a gain no longer positive
        definite, or a gate's ``max_rejections`` exceeded) keeps the state given with a failed status at the
        interval that starts at ``t`` (index ``status.steps``), as ``step`` would; it counts no interval
        (``steps`` and the sub-step counters are the prediction's). A failed state is returned unchanged.

        Compiled by XLA (``jax.jit``, once per filter structure), whatever the engine of ``step``: the C engine
        has no separate update."""
        t = check_t(t)
        self.check_state(state)
        y = self._check_sample("y", y, self.system.output_dim, missing=True)
        for b in self.blocks:
            present = np.isfinite(y[b.start:b.stop])
            if not b.sample and present.any():
                raise ValueError(
                    f"y: sensor {b.name!r} is a density sensor (Noise.density), which has no information per "
                    f"sample, but y has a sample of it at index {b.start + int(np.argmax(present))}; give NaN for "
                    "its components here and use step, which spreads its samples over their intervals")
        return _update_jit(self, state, np.asarray(t), y)

    def online(self, state: FilterState, *, engine: str | None = None):
        """The online filter of a robot's loop: the engines' ``online``."""
        return engines().online(self, state, engine=engine)

    # --- checks -------------------------------------------------------------------------------------------
    def check_state(self, state):
        """``state`` is a :class:`FilterState` of this filter's group and dimension (a ValueError naming
        ``state`` otherwise): cheap structural checks only, for the engines' online hot path."""
        if not isinstance(state, FilterState):
            raise ValueError(f"state: expected a FilterState (from init or step), got {type(state).__name__}")
        G = self.system.group
        n = G.tangent_dim
        if type(state.g_hat) is not G or getattr(state.K, "shape", None) != (n, n):
            raise ValueError(f"state: expected g_hat in {G.__name__} and K of shape ({n}, {n}), got "
                             f"{type(state.g_hat).__name__} and {getattr(state.K, 'shape', None)}")

    def check_element(self, name, g):
        """``g`` is a single element of this filter's group with finite parameters (a ValueError naming
        ``name`` otherwise)."""
        check_element(self.system.group, name, g)

    @staticmethod
    def _check_dt(dt) -> float:
        return check_dt(dt)

    @staticmethod
    def _check_sample(name, v, n, missing: bool = False) -> np.ndarray:
        return _validate.array(name, np.zeros(0) if v is None and n == 0 else v, (n,), missing=missing)



_UPDATE_JIT: dict = {}


def _update_leaves(static, leaves, state, t, y):
    TRACES["update"] += 1
    flt = eqx.combine(jax.tree_util.tree_unflatten(static[0], leaves), static[1])
    return flt._update_core(state, t, y)


def _update_jit(flt, state, t, y):
    """:meth:`AbstractFilter.update`'s compiled core, one program per filter structure (shared), called on the
    filter's array leaves, cached beside it: ``eqx.filter_jit`` would flatten the whole filter at every call."""
    cached = _side.get(flt, "update")
    if cached is None:
        dyn, static = eqx.partition(flt, eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dyn)
        key = (treedef, static)
        if key not in _UPDATE_JIT:
            _UPDATE_JIT[key] = jax.jit(functools.partial(_update_leaves, key))
        cached = (_UPDATE_JIT[key], leaves)
        _side.put(flt, "update", cached)
    fn, leaves = cached
    return fn(leaves, state, t, y)


def check_element(G: type[LieGroup], name: str, g) -> None:
    """``g`` is a single element of ``G`` with finite parameters (ValueError naming ``name`` otherwise): the
    boundary check of every filter's initial and given states."""
    _validate.element(name, g, G)


def check_dt(dt) -> float:
    """A finite time step > 0, as a float (ValueError naming ``dt`` otherwise, also for a non-number)."""
    try:
        value = float(dt)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"dt: expected a finite time step > 0, got {dt}")
    return value


def check_t(t) -> float:
    """A finite time ``t``, as a float (ValueError naming ``t`` otherwise, also for a non-number)."""
    try:
        value = float(t)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"t: expected a finite time, got {t}")
    return value


def check_time(t, dt) -> tuple[float, float]:
    """An online step's finite time ``t`` and time step ``dt`` > 0, as floats (ValueError naming either)."""
    dt = check_dt(dt)
    return check_t(t), dt


def check_samples(m: int, p: int, u, y, u_next=None, y_next=None) -> tuple[np.ndarray, ...]:
    """One interval's samples ``u``, ``y``, ``u_next``, ``y_next`` (None: held) as float64 arrays of shapes
    (m,), (p,), (m,), (p,), checked in that order, each for its shape and then for infinities (NaN: missing;
    None for an input of dimension 0): the one check of both engines, so that they name the same sample."""
    return tuple(AbstractFilter._check_sample(name, v, n, missing=True) for name, v, n in (
        ("u", u, m), ("y", y, p), ("u_next", u if u_next is None else u_next, m),
        ("y_next", y if y_next is None else y_next, p)))



def check_log(flt, ts, us, ys, lead=(), gap=None, keep_every=1, *, threads=None, g_hat=None,
              missing_inputs: bool = True):
    """A log's boundary checks, the one check of every filter's run, for one trial (``lead = ()``) or B of them
    (``lead = (B,)``): the times, the samples' shapes (NaN in ``ys`` missing; in ``us`` held, or refused with
    ``missing_inputs=False``), ``keep_every``, ``threads``, the states' ``g_hat`` and the gap threshold
    (default: 10 times the median interval; ``math.inf``: no interval is a gap). Returns ``ts``, ``us``,
    ``ys`` as float64 arrays and the gap."""
    ts = _validate.sorted_times("ts", ts)
    N = ts.shape[0]
    if N < 2:
        raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
    m, p = flt.system.input_dim, flt.system.output_dim
    us = np.zeros((*lead, N, 0)) if us is None and m == 0 else _validate.array("us", us, (*lead, N, m),
                                                                                missing=missing_inputs)
    ys = _validate.array("ys", ys, (*lead, N, p), missing=True)
    if not (isinstance(keep_every, int) and not isinstance(keep_every, bool) and keep_every >= 1):
        raise ValueError(f"keep_every: expected an integer >= 1, got {keep_every!r}")
    if threads is not None and not (isinstance(threads, int) and threads >= 1):
        raise ValueError(f"threads: expected an integer >= 1 (or None: every CPU), got {threads!r}")
    if g_hat is not None:
        for leaf in jax.tree_util.tree_leaves(g_hat):
            _validate.array("states.g_hat", leaf)
    if gap is None:
        gap = 10.0 * float(np.median(np.diff(ts)))
    elif not (isinstance(gap, int | float | np.number) and gap == math.inf):  # inf: no gaps, as in step()
        gap = float(_validate.positive("gap", gap))  # 0 would make every interval a gap: no sample held
    return ts, us, ys, gap
