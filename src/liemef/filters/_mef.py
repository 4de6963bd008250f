r"""The minimum-energy filter of Saccon et al. 2016, Theorem 4.1: the terms at a state and one sample interval,
integrated on the group; the driver (init, step, run, scan, status) is :mod:`liemef.filters._base`'s."""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from .._linalg import mm, mv
from .._names import ERROR_SIDES, INTERPOLATIONS, ORDERS, UPDATES
from ..connections import Connection, ConnectionFunction
from ..connections import connection as make_connection
from ..groups import LieGroup
from ..integrators import AbstractIntegrator
from ..integrators import integrator as make_integrator
from ..systems import AbstractSystem, RightErrorSystem, SensorSystem
from ..systems._right import RightErrorAbout, natural_error
from ._base import AbstractFilter, FilterState, sensor_layout
from ._derivatives import left_jacobian, refuse_state_while_in_outputs
from ._riccati import Terms, Weights, information_in_force, riccati_rhs, terms
from ._status import SYMMETRY_TOL
from ._substeps import stiffness_rate, substep_controller
from ._update import sample_update


class MinimumEnergyFilter(AbstractFilter):
    r"""Second-order-optimal minimum-energy filter on a matrix Lie group (Saccon et al. 2016, Theorem 4.1).

    Args:
        system: the model (group, dynamics, output, B, D, Q, R), e.g. :class:`liemef.systems.PlanarRigidBody`,
            or a :class:`liemef.systems.SensorSystem` whose weights come from sensor noise levels.
        connection: ``"zero"`` (c = 1/2, torsion-free, the papers' default), ``"minus"`` (c = 0), ``"plus"``
            (c = 1), a Cartan-Schouten coefficient c, or a bilinear function ``omega(X, Y)``.
        order: ``"second"`` (the paper filter) or ``"first"`` (no Hessian term in E, W = 0: the continuous-time
            left-invariant EKF on the group).
        integrator: ``"rkmk4"`` (4th-order Runge-Kutta-Munthe-Kaas), ``"rkmk2"`` (its explicit midpoint rule,
            order 2, half the field evaluations) or ``"lie-euler"``.
        alpha: forgetting factor, >= 0.
        interpolation: ``"hold"`` (inputs and density measurements held over each sample interval, the
            papers' zero-order hold) or ``"linear"`` (interpolated between the interval's two samples where
            both are present).
        substeps: ``"auto"`` (default): each sample interval is integrated in adaptive steps, each of size
            $h = \min(\text{rest}, 1/\rho)$ with the stiffness rate
            $\rho = \max(\|K E\|/0.5, \|A\|/0.5, \|\lambda + K r\|/0.5)$ (Frobenius norms) at the step's start,
            so that an impulsive sample or a large K0 does not make the explicit step unstable (K shrinks
            during an update, so the steps grow: their number is logarithmic in $\|K E\| \Delta$); an interval
            that is not stiff takes one step. Or a fixed number of equal steps per interval (1: the papers'
            scheme).
        max_substeps: the most steps ``"auto"`` takes in one interval (the last one finishes it).
        constant_E: ``"weighted"`` (the theorem: E's constant part is $Dh^\top D^{-\top} Q D^{-1} Dh$) or
            ``"unit"`` ($Dh^\top Dh$, as Rigo et al. 2022/2023 print it, right only for $Q = D^\top D$: the
            reproduction of a misprint, docs/errata.md).
        updates: how the samples of sample-meaning sensors (``Noise.sample``) enter. ``"hold"`` (the default,
            the papers' scheme, which the reproductions use): a sample's information is spread over the interval
            that follows its time stamp, against an estimate that moves on meanwhile. ``"discrete"``: the hybrid
            minimum-energy filter (docs/theorem.md): at its time stamp the sample updates the estimate by the
            minimizer of the second-order expansion of the cost (prior plus the sample's residual) on the group,
            then the interval is predicted with the continuous terms of Theorem 4.1 (inputs, density sensors).
            On a linear system this is the discrete Kalman filter exactly; on fast rotation it removes the lag
            of the held sample. Recommended for a user system with sample sensors. Density sensors are
            continuous in either mode.
        iterations: the most iterations of a discrete update: Newton's (``order="second"``) or Gauss-Newton's
            (``order="first"``), each with a line search on the sample's true cost, so that an update never
            raises it (:mod:`liemef.filters` docs, docs/theorem.md "Samples at their own time"). Default: 10 for
            the second order (iterated to ``tol``), 1 for the first (one Gauss-Newton step: the invariant
            EKF's update where the step is accepted whole).
        tol: the Newton decrement, relative to 1 + the sample's cost, below which a discrete update stops.
        curvature: the output's second-order term, in E (continuous) and in the discrete update's Hessian.
            ``"safe"`` (the default, chosen on ``liemef compare second-order``, docs/second-order.md): kept where
            it lies between minus the Gauss-Newton information and zero, so that it only lowers that information
            and never below zero, and dropped elsewhere (:func:`liemef.filters.safe_curvature`; the exact term,
            bit for bit, inside that band); the connection term W, which grows with the same residual, is 0.
            ``"exact"``: Theorem 4.1's, whatever its sign (the papers' filter, which their reproductions use).
            Ignored by the first order.
        error: the error coordinates the filter's terms are written in. ``"left"``: the left error $\xi$,
            $g = \hat g\exp\xi$, Theorem 4.1's (the papers' filter). ``"right"``: the right error $\eta$,
            $\hat g g^{-1} = \exp\eta$, by running Theorem 4.1 on the system's state inverted about each
            interval's first estimate (:class:`~liemef.systems._right.RightErrorAbout`; sensor systems only).
            ``"auto"`` (the default): ``"right"`` where some sensor observes fixed directions of the right error
            and none observes fixed directions of the left error only (a landmark's range and bearing, a known
            field's direction, and no position fix), else ``"left"`` (:func:`liemef.systems.natural_error`). With
            held samples, the right error keeps K from taking information along a direction no sample observes
            where the left error does not (docs/second-order.md, "The side of the error"); with samples at their
            own time and the (0)-connection the two give the same estimates. Whatever the side, the state's K
            is the covariance of the left error, as every filter of the library keeps it.

    Samples: a NaN in ``y`` is a missing sample (that component carries no information over the interval);
    a NaN in ``u`` holds the last input. Sample-meaning sensors carry each sample's information once
    (:mod:`liemef.systems`). The filter is an immutable pytree: every weight, noise level and parameter is an
    array leaf, so a new weight set reuses the compiled code. :meth:`init`, :meth:`step` and :meth:`run`
    return new states; :meth:`scan` is the traceable, unchecked core of ``run`` for your own ``jit``/``vmap``.
    """

    system: AbstractSystem
    connection: Connection
    integrator: AbstractIntegrator
    alpha: Float[Array, ""]
    weights: Weights
    order: str = eqx.field(static=True)
    interpolation: str = eqx.field(static=True)
    substeps: str | int = eqx.field(static=True)
    max_substeps: int = eqx.field(static=True)
    symmetric: bool = eqx.field(static=True)
    sample: tuple[bool, ...] = eqx.field(static=True)
    blocks: tuple = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)
    constant_E: str = eqx.field(static=True)
    updates: str = eqx.field(static=True, default="hold")
    iterations: int = eqx.field(static=True, default=1)
    curvature: str = eqx.field(static=True, default="safe")
    error: str = eqx.field(static=True, default="left")
    tol: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(1e-14))

    def __init__(self, system: AbstractSystem, connection: str | float | ConnectionFunction | Connection = "zero",
                 order: Literal["second", "first"] = "second", integrator: str | AbstractIntegrator = "rkmk4",
                 alpha: float = 0.0, *, interpolation: Literal["hold", "linear"] = "hold",
                 substeps: Literal["auto"] | int = "auto", max_substeps: int = 256,
                 constant_E: Literal["weighted", "unit"] = "weighted",
                 updates: Literal["hold", "discrete"] = "hold", iterations: int | None = None,
                 tol: float = 1e-14, curvature: Literal["exact", "safe"] = "safe",
                 error: Literal["auto", "left", "right"] = "auto"):
        if not isinstance(system, AbstractSystem):
            raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
        _validate.choice("order", order, set(ORDERS))
        _validate.choice("interpolation", interpolation, set(INTERPOLATIONS))
        _validate.choice("constant_E", constant_E, {"weighted", "unit"})
        if substeps != "auto" and not (isinstance(substeps, int) and 1 <= substeps <= _validate.INT_MAX):
            raise ValueError(f"substeps: expected 'auto' or an integer >= 1 and <= {_validate.INT_MAX}, "
                             f"got {substeps!r}")
        _validate.integer("max_substeps", max_substeps, 1)
        _validate.choice("updates", updates, set(UPDATES))
        if iterations is None:
            iterations = 10 if order == "second" else 1
        if not (isinstance(iterations, int) and not isinstance(iterations, bool) and iterations >= 1):
            raise ValueError(f"iterations: expected an integer >= 1 (Newton or Gauss-Newton steps), got {iterations!r}")
        _validate.choice("curvature", curvature, {"exact", "safe"})
        self.updates, self.iterations, self.curvature = updates, iterations, curvature
        self.tol = jnp.asarray(_validate.nonnegative("tol", tol))
        if order == "second":  # its Hessian of each output: a while_loop there is refused now, by name
            refuse_state_while_in_outputs(system)
        _validate.choice("error", error, set(ERROR_SIDES))
        if error == "right" and not isinstance(system, SensorSystem):
            raise ValueError(f"error: 'right' needs a SensorSystem (its right error is a sensor system), got "
                             f"{type(system).__name__}; use error='left'")
        if isinstance(system, RightErrorSystem) and error == "right":
            raise ValueError(f"error: a RightErrorSystem is already the right error of its base; expected "
                             f"error='left' (or the base system with error='right'), got {error!r}")
        self.error = natural_error(system) if error == "auto" else error
        self.system = system
        self.connection = make_connection(connection, system.group)
        self.order = order
        self.integrator = make_integrator(integrator)
        self.alpha = jnp.asarray(_validate.nonnegative("alpha", alpha))
        self.weights = Weights.of(system)
        self.interpolation, self.substeps, self.max_substeps = interpolation, substeps, max_substeps
        self.constant_E = constant_E
        self.blocks, self.sample, self.diagonal = sensor_layout(system, self.weights.Wy)
        # K stays symmetric when E is (first order, or a torsion-free connection) (docs/theorem.md).
        Gamma = np.asarray(self.connection.Gamma)  # NumPy: a check, not worth an XLA compile
        torsion = Gamma - np.swapaxes(Gamma, 1, 2) - np.asarray(self.connection.C)
        self.symmetric = order == "first" or bool(np.allclose(torsion, 0.0, atol=1e-12))

    def __repr__(self) -> str:
        updates = f", updates={self.updates!r}" if self.updates != "hold" else ""
        updates += f", curvature={self.curvature!r}" if self.curvature != "safe" else ""
        updates += f", error={self.error!r}" if self.error != "left" else ""
        return (f"MinimumEnergyFilter({type(self.system).__name__}, connection={self.connection.name!r}, "
                f"order={self.order!r}, integrator={self.integrator.name!r}, alpha={float(self.alpha)}{updates}"
                + (f", constant_E={self.constant_E!r})" if self.constant_E != "weighted" else ")"))

    # --- the error coordinates ------------------------------------------------------------------------------
    def _model_at(self, g):
        """The system Theorem 4.1 runs on over an interval that starts at the estimate ``g``: ``system``, or
        (``error="right"``) its right error about ``g`` (:class:`~liemef.systems._right.RightErrorAbout`), whose
        state starts at the identity, so that nothing in it grows with the distance from the world's origin."""
        return self.system if self.error == "left" else RightErrorAbout(self.system, g)

    def _to_model(self, g, K):
        """``(g_hat, K)`` of the system's left error as the state of :meth:`_model_at` ``(g_hat)``: the same for
        ``"left"``; the identity and the same K for ``"right"`` (about g_hat, the two left errors coincide)."""
        return (g, K) if self.error == "left" else (type(g).identity(), K)

    def _from_model(self, model, h, K):
        """The ``model``'s ``(h_hat, K)`` back to the system's left error, K kept exactly symmetric where it must
        be."""
        if self.error == "left":
            return h, K
        g, K = model.estimates_of(h, K)
        return g, self._mirrored(K)

    def _mirrored(self, K):
        """K with its lower triangle the mirror of its upper one where K must stay symmetric (K as it is
        otherwise): exactly symmetric, and the other triangle not computed where the compiler can see it."""
        return jnp.triu(K) + jnp.triu(K, 1).T if self.symmetric else K

    # --- the mathematics ----------------------------------------------------------------------------------
    def _terms(self, model, weights: Weights, g_hat, K, u, y, t, outputs: bool = True) -> Terms:
        """Theorem 4.1's terms of ``model`` (:meth:`_model_at`) at ``(g_hat, K)`` in its coordinates."""
        tm = terms(model, weights, self.connection, self.order == "second", g_hat, K, u, y, t, outputs,
                   self.curvature == "safe")
        if self.constant_E == "weighted":
            return tm
        unit = tm.Dh.T @ (weights.Wy - jnp.eye(weights.Wy.shape[0])) @ tm.Dh  # E's constant part as Dh^T Dh
        return eqx.tree_at(lambda x: x.E, tm, tm.E - unit)

    def _riccati(self, tm: Terms, K):
        """K's rate (eq. (11)); where K stays symmetric, one triangle mirrored: K stays exactly symmetric, and
        the other triangle is not computed where the compiler can see it (exported C) (docs/theorem.md)."""
        Kd = riccati_rhs(tm, K, self.alpha)
        return self._mirrored(Kd)

    def terms(self, g_hat: LieGroup, K: ArrayLike, u: ArrayLike, y: ArrayLike, t: float = 0.0, *,
              dt: float | None = None) -> Terms:
        r"""r, A, E, W and B R^{-1} B^T of Theorem 4.1 at a state, to compare with the papers' printed forms.

        A NaN in ``y`` is a missing component; sample-meaning sensors need the interval ``dt`` their sample is
        spread over. ``K`` may be any finite n x n matrix (not only a gain a run can reach: the closed-form tests
        evaluate the terms at random K); ``t`` and ``dt`` must be finite. ``g_hat`` and ``K`` are the system's
        (K of its left error); the terms are those of the filter's coordinates: with ``error="right"``, those of
        the right error about $\hat g$ (:meth:`_model_at`) at the identity, where its K is this K."""
        self.check_element("g_hat", g_hat)
        K = _validate.square("K", K, self.n)  # any finite K: the terms are polynomials in it
        t = _validate.real("t", t)
        u = self._check_sample("u", u, self.system.input_dim)
        y = self._check_sample("y", y, self.system.output_dim, missing=True)
        if any(self.sample) and dt is None:
            raise ValueError("dt: expected the sample interval (sample-meaning sensors spread a sample over it), "
                             "got None")
        dt = 1.0 if dt is None else self._check_dt(dt)
        mask = np.isfinite(y)
        weights = Weights(Wy=information_in_force(self.weights.Wy, np.asarray(self.sample, bool), mask, dt,
                                                  diagonal=self.diagonal),
                          BRB=self.weights.BRB)
        return self._terms(self._model_at(g_hat), weights, *self._to_model(g_hat, jnp.asarray(K)), u,
                           jnp.where(mask, y, 0.0), jnp.asarray(t))

    def vector_field(self, g_hat: LieGroup, K, u, y, t):
        r"""$(\hat g^{-1}\dot{\hat g}, \dot K)$ at a state with the nominal weights (every sample present;
        traceable), K the covariance of the left error. With ``error="right"`` the flow $(v, \dot K_h)$ of the
        right error about $\hat g$ (:meth:`_model_at`) at its identity maps back by $\hat g^{-1}\dot{\hat g} = -v$
        and $\dot K = \dot K_h + \mathrm{ad}_v K + K\mathrm{ad}_v^\top$ (from $\hat g = T\hat h^{-1}$ and
        $K = \mathrm{Ad}_{\hat h} K_h \mathrm{Ad}_{\hat h}^\top$ at $\hat h = I$)."""
        model = self._model_at(g_hat)
        h, Kh = self._to_model(g_hat, K)
        tm = self._terms(model, self.weights, h, Kh, u, y, t)
        v, K_dot = tm.lam + mv(Kh, tm.r), riccati_rhs(tm, Kh, self.alpha)
        if self.error == "left":
            return v, K_dot
        ad = type(h).ad(v)
        return -v, K_dot + mm(ad, Kh) + mm(Kh, ad.T)

    # --- the update at a sample's time (the hybrid filter's, and update's) -----------------------------------
    def _sample_update(self, model, g, K, t, y0, W):
        """``(g_hat, K)`` (in the model's coordinates) after the sample ``y0`` of per-sample information ``W``
        (zero rows and columns where missing): :func:`~liemef.filters.sample_update` with the filter's
        iterations, order, curvature and tol; K kept exactly symmetric where it must be."""
        def update(gK):
            g2, K2, _ = sample_update(lambda gg: model.output_seen_from(y0, gg, t), *gK, y0, W,
                                      iterations=self.iterations, newton=self.order == "second",
                                      safe=self.curvature == "safe", tol=self.tol)
            return g2, self._mirrored(K2)

        # only an interval that starts with a sample is updated: the update of zero information is the
        # identity, and at 100 Hz against 1 Hz landmarks it was two thirds of a step's arithmetic
        return jax.lax.cond(jnp.any(W != 0), update, lambda gK: gK, (g, K))

    def _prior_output(self, state: FilterState, t, y0):
        r"""The output as seen from ``y0`` at the estimate and $Dh\,K\,Dh^\top$ (Dh its left Jacobian): the gates'
        and the log-likelihood's innovation and covariance from the state (the same in either error coordinates:
        the linearization is one map, written in two)."""
        K = state.K
        h0, Dh = left_jacobian(lambda gg: self.system.output_seen_from(y0, gg, t), state.g_hat)
        return h0, mm(Dh, mm(0.5 * (K + K.T), Dh.T)), None

    def _correct(self, state: FilterState, t, y0, mask, W, prior):
        model = self._model_at(state.g_hat)
        return self._from_model(model, *self._sample_update(model, *self._to_model(state.g_hat, state.K), t, y0, W))

    # --- one sample interval --------------------------------------------------------------------------------
    def interval(self, state: FilterState, t, dt, u0, u1, y0, y1, gap) -> FilterState:
        """Advance over ``[t, t + dt]`` from the samples at its two ends (NaN = missing), in four parts: the
        information the interval's samples carry, screened by the sensors (:meth:`_information`); with
        ``updates="discrete"``, the update at ``t`` (:meth:`_sample_update`); the flow of Theorem 4.1 over the
        interval (:meth:`_flow`), integrated by the sub-step controller (:mod:`~liemef.filters._substeps`);
        and the checks of the result (:meth:`finish`). In the coordinates of :meth:`_model_at`."""
        s = self.samples(state, dt, u0, u1, y0, y1, gap)
        Wy, W_sample, rejected, consecutive = self._information(state, t, dt, s.y0, s.mask, s.Wy)
        model = self._model_at(state.g_hat)
        g, K = self._to_model(state.g_hat, state.K)
        if W_sample is not None:
            g, K = self._sample_update(model, g, K, t, s.y0, W_sample)
        # static: with only sample sensors, no output acts over the discrete filter's interval
        outputs = W_sample is None or not all(self.sample)
        data = _interpolated(self.interpolation, t, dt, s.u0, s.u1, s.y0, s.y1)
        f, field_and_rate = self._flow(model, Weights(Wy=Wy, BRB=self.weights.BRB), outputs, data)
        controller = substep_controller(self.substeps, self.max_substeps)
        g1, K1, n_sub, capped, skew = controller.integrate(self.integrator, f, field_and_rate, g, K, t, dt)
        g1, K1 = self._from_model(model, g1, K1)
        return self.finish(state, g1, K1, t=t, dt=dt, samples=s, rejected=rejected, consecutive=consecutive,
                           n_sub=n_sub, capped=capped, asymmetric=skew)

    def _information(self, state: FilterState, t, dt, y0, mask, Wy):
        """``(Wy, W_sample, rejected, consecutive)``: the information in force over the interval, the samples'
        information for the update at ``t`` (``updates="discrete"`` with sample sensors; else None, and the
        samples are in ``Wy``), both screened by the sensors' gates, robust losses and time-varying weights, and
        the gates' counters."""
        st = state.status
        W_sample = None
        if self.updates == "discrete" and any(self.sample):
            # the samples' information, per sample, for the update at t; the density sensors' over the interval
            sample = jnp.asarray(self.sample, dtype=bool)
            W_sample = self.adapted(
                information_in_force(self.weights.Wy, sample, mask & sample, 1.0, diagonal=self.diagonal), y0)
            Wy = self.adapted(
                information_in_force(self.weights.Wy, sample, mask & ~sample, dt, diagonal=self.diagonal), y0)
        if not self._screens_samples:
            return Wy, W_sample, st.rejected, st.consecutive
        h0, HKH, _ = self._prior_output(state, t, y0)
        W_all = Wy if W_sample is None else Wy + W_sample / dt  # the information in force, as the gate reads it
        scale, rejected, consecutive = self._sensor_scale(y0 - h0, HKH, t, dt, mask, W_all, st)
        root = jnp.sqrt(scale)[:, None] * jnp.sqrt(scale)[None, :]
        return Wy * root, None if W_sample is None else W_sample * root, rejected, consecutive

    def _flow(self, model, weights: Weights, outputs: bool, data):
        """The interval's vector field ``f(g, K, tau) -> (xi, K_dot)`` and ``field_and_rate`` (the field, its
        stiffness rate and whether E is not symmetric where K must stay so), for the sub-step controller. An
        output without information in force adds nothing (r, E and W are linear in the weights and vanish with
        them): where none is in force, the field is the prediction's, taken whole (its Riccati equation without
        the K E K product) and without differentiating the outputs, as between the samples of a slower sensor
        (constant_E="unit" has E = Dh^T Dh without information too, so it keeps the outputs)."""
        if not (outputs and self.constant_E == "weighted"):
            return self._field(model, weights, outputs, data)
        in_force = jnp.any(weights.Wy != 0)
        (f_out, far_out), (f_pred, far_pred) = (self._field(model, weights, o, data) for o in (True, False))
        return (lambda gg, KK, tau: jax.lax.cond(in_force, f_out, f_pred, gg, KK, tau),
                lambda gg, KK, tau: jax.lax.cond(in_force, far_out, far_pred, gg, KK, tau))

    def _field(self, model, weights: Weights, outputs: bool, data):
        """:meth:`_flow`'s pair with the outputs' terms (``outputs``) or without."""
        def f(gg, KK, tau):
            u, y = data(tau)
            tm = self._terms(model, weights, gg, KK, u, y, tau, outputs=outputs)
            return tm.lam + mv(KK, tm.r), self._riccati(tm, KK)

        def field_and_rate(gg, KK, tau):
            u, y = data(tau)
            tm = self._terms(model, weights, gg, KK, u, y, tau, outputs=outputs)
            xi = tm.lam + mv(KK, tm.r)
            rate = stiffness_rate(tm.E, tm.A, KK, xi)
            # K stays symmetric only if E is (its rate keeps one triangle, _riccati): an E that is not, from a
            # broken system, is a failure ("K not symmetric"), checked at each interval's start
            big = jnp.maximum(1.0, jnp.max(jnp.abs(tm.E)))
            skew = self.symmetric & (jnp.max(jnp.abs(tm.E - tm.E.T)) > SYMMETRY_TOL * big)
            return (xi, self._riccati(tm, KK)), jnp.where(jnp.isfinite(rate), rate, 0.0), skew
        return f, field_and_rate


def _interpolated(interpolation: str, t, dt, u0, u1, y0, y1):
    """The input and output at a time ``tau`` of the interval ``[t, t + dt]``: held at its start (``"hold"``)
    or linear between its two samples (``"linear"``; the samples are held where the one at the end is missing)."""
    if interpolation == "hold":
        return lambda tau: (u0, y0)

    def data(tau):
        s = (tau - t) / dt
        return u0 + s * (u1 - u0), y0 + s * (y1 - y0)
    return data
