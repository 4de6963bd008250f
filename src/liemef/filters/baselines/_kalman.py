r"""Discrete Kalman filters on the group, for any liemef system: the extended (EKF, invariant EKF) and the unscented
(UKF-M) filter, with the error coordinates as a field.

**Error coordinates.** A filter keeps a mean $\hat g$ and the covariance P of an error $e \in \mathbb R^n$ through
a retraction $g = \varphi(\hat g, e)$ (:data:`ERRORS`):

* ``"left"``: $g = \hat g \exp(e)$, the left-invariant (body-frame) error of the invariant EKF (Barrau & Bonnabel
  2017) and of ukfm's left UKF-M;
* ``"right"``: $g = \exp(e)\,\hat g$, the right-invariant error;
* ``"local"``: the chart practitioners write: rotations multiplicative, and every translation or vector part
  additive in the world frame, $p = \hat p + e_p$. SE(2) is SO(2) x R^2 with $R = \hat R \exp(e_R)$ (ukfm's
  ``ekf``/``ukf_so2xr2``); SE(3), SE_2(3) and SE_K(3) are SO(3) x R^{3K} with the rotation error in the **world**
  frame, $R = \exp(e_R)\hat R$, as ukfm writes it (``ekf``/``ukf_so3xr6`` of inertial navigation), so that the
  whole error is world-frame; an SO(3) factor of a product keeps the body-frame error $R = \hat R\exp(e_R)$ (the
  MEKF with additive bias on SO(3) x R^3). Groups without a translation part have the left error.

  The frame of the rotation error is part of the filter, not a notation: at one mean the two charts differ by
  the orthogonal map $e_R^{world} = \hat R e_R^{body}$, which carries the covariance, the Jacobians and the
  prediction of one onto the other exactly, but the update moves the mean and leaves P in the coordinates it
  had (ukfm's EKF and UKF-M, and these). A world-frame P kept through an update with the attitude correction
  $\delta$ is the body-frame P rotated by $\exp(\delta)$ in its rotation rows and columns. On ukfm's
  inertial-navigation benchmark (its 20 runs) this is the difference between the SO(3) x R^6 EKF's attitude rms
  of 2.89 deg (world frame; ukfm: 2.88) and 4.55 deg (body frame).

Whatever its coordinates, a filter's state holds $K = J P J^\top$, the covariance of the **left** error $\xi$
with $g = \hat g \exp\xi$ ($J = \partial\xi/\partial e$ at the mean), as the minimum-energy filter's K: so NEES
and every metric read all filters the same way. The conversion is exact linear algebra at the same mean.

**The discrete model** of the continuous system $\dot g = g(\lambda(g, u, t) + B\delta)$, $y = h(g, t) + D\varepsilon$
(:mod:`liemef.systems`). Over a sample interval $[t_k, t_k + \Delta]$ with the input $u_k$ held:
$g^+ = g \exp(\lambda(g, u_k, t_k)\Delta + w)$ with $w \sim N(0, B R^{-1} B^\top \Delta)$ in the algebra (the
process-noise density over $\Delta$; ``substeps`` splits $\Delta$ into equal Lie-Euler steps, exact in one step
when $\lambda$ does not depend on g). A measurement sample $y_k$ has the information of the minimum-energy
filter's cost over the interval: $W_y$ once for a sample-meaning sensor, $W_y \Delta$ for a density one
(:func:`~liemef.filters.information_in_force`; a missing component carries none, and gates, robust losses and
time-varying weights scale it as in the minimum-energy filter).

**Order of operations** (the library's sample convention): on $[t_k, t_{k+1}]$ the filter first updates with
$y_k$, then predicts with $u_k$; the state at $t_k$ has seen $y_0 \dots y_{k-1}$, like the minimum-energy filter's
(whose sample $y_k$ acts over the interval that follows it). ukfm updates at $t_k$ right after the prediction to
$t_k$: its estimate at $t_k$ is this one's at $t_{k+1}$.

**The update** is written with the information $I_k$ of the present components (zero rows for missing ones), so
that no singular covariance is inverted: with the predicted output covariance $C$ and cross-covariance
$P_{ey}$ ($C = H P H^\top$, $P_{ey} = P H^\top$ for the EKF; sigma-point sums for the UKF),
$K = P_{ey}(I + I_k C)^{-1} I_k = P_{ey}(C + \Sigma)^{-1}$, $e = K\nu$, $\hat g \leftarrow \varphi(\hat g, e)$ and
$P \leftarrow P - P_{ey}K^\top - K P_{ey}^\top + K(C + \Sigma)K^\top$ (Joseph's form, symmetric and positive
semidefinite by construction). As in ukfm and the usual invariant EKF, P is not transported to the new mean.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ... import _validate
from ..._linalg import mm, mv
from ...groups import SE2, SEK3, SO2, SO3, LieGroup, Product
from ...systems import AbstractSystem
from .. import AbstractFilter, FilterState, Weights, sensor_layout

ERRORS = ("left", "right", "local")
"""The error coordinates: ``"left"`` $g = \\hat g\\exp e$, ``"right"`` $g = \\exp(e)\\hat g$, ``"local"``
(rotations multiplicative, translations additive)."""


# --- retractions ------------------------------------------------------------------------------------------
def _local_plus(g: LieGroup, e):
    if isinstance(g, Product):
        sizes = [t.tangent_dim for t in g.factor_types]
        cuts = [sum(sizes[:i]) for i in range(len(sizes) + 1)]
        return type(g)(tuple(_local_plus(f, e[a:b]) for f, a, b in zip(g.factors, cuts[:-1], cuts[1:],
                                                                            strict=True)))
    if isinstance(g, SE2):
        return SE2.from_rotation_translation(g.rotation() @ SO2.exp(e[:1]), g.translation() + e[1:])
    if isinstance(g, SEK3):  # ukfm's SO(3) x R^{3K}: the rotation error in the world frame (module docstring)
        vectors = g.vectors() + e[3:].reshape(g.K, 3)
        return type(g).from_rotation_vectors(SO3.exp(e[:3]) @ g.rotation(), vectors)
    return g.rplus(e)


def _local_minus(g2: LieGroup, g: LieGroup):
    """$e$ with ``_local_plus(g, e) == g2``."""
    if isinstance(g, Product):
        return jnp.concatenate([_local_minus(a, b) for a, b in zip(g2.factors, g.factors, strict=True)])
    if isinstance(g, SE2):
        return jnp.concatenate([g2.rotation().rminus(g.rotation()), g2.translation() - g.translation()])
    if isinstance(g, SEK3):
        return jnp.concatenate([(g2.rotation() @ g.rotation().inverse()).log(),
                                (g2.vectors() - g.vectors()).reshape(-1)])
    return g2.rminus(g)


def retraction(error: str) -> tuple[Callable, Callable]:
    r"""``(plus, minus)`` of the error coordinates: ``plus(g_hat, e)`` $= \varphi(\hat g, e)$ and
    ``minus(g, g_hat)`` $= \varphi^{-1}(\hat g, g)$, so that ``minus(plus(g_hat, e), g_hat) == e``."""
    _validate.choice("error", error, set(ERRORS))
    if error == "left":
        return (lambda g, e: g.rplus(e)), (lambda g2, g: g2.rminus(g))
    if error == "right":
        return (lambda g, e: type(g).exp(e) @ g), (lambda g2, g: (g2 @ g.inverse()).log())
    return _local_plus, _local_minus


def _sqrt_psd(P: Float[Array, "n n"]) -> Float[Array, "n n"]:
    r"""The symmetric square root S S^T = P of a positive semidefinite matrix, $V \sqrt{W} V^\top$ by
    eigendecomposition (P may be singular, e.g. an initial covariance with exactly known components). Unique:
    it does not depend on the eigenvectors LAPACK picks (their signs, a repeated eigenvalue's basis), so that
    the C engine's eigh (Jacobi sweeps) gives XLA's sigma points to rounding (docs/engines.md)."""
    w, V = jnp.linalg.eigh(0.5 * (P + P.T))
    return (V * jnp.sqrt(jnp.maximum(w, 0.0))[None, :]) @ V.T


class AbstractKalmanFilter(AbstractFilter):
    """A discrete Kalman filter on the group (module docstring): one update with the interval's first sample,
    then one prediction over the interval. Concrete filters say how the update's moments and the prediction's
    covariance are formed (:class:`ExtendedKalmanFilter`, :class:`UnscentedKalmanFilter`)."""

    system: AbstractSystem
    weights: Weights
    error: str = eqx.field(static=True)
    substeps: int = eqx.field(static=True)
    blocks: tuple = eqx.field(static=True)
    sample: tuple[bool, ...] = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)
    symmetric = True  # P is symmetrized after every step

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """Short name for tables (``"iekf"``, ``"ekf"``, ``"ukf-left"``, ...)."""

    @abc.abstractmethod
    def _moments(self, g, P, t, y) -> tuple[Array, Array, Array]:
        """``h(g_hat)``, the output covariance C from the state and the cross-covariance P_ey (the output as seen
        from the sample ``y``: :meth:`~liemef.systems.AbstractSystem.output_seen_from`)."""

    @abc.abstractmethod
    def _predict(self, g, P, u, t, dt) -> tuple[LieGroup, Array]:
        """Mean and covariance (in the filter's error coordinates at the new mean) after ``dt``."""

    def _left_jacobian(self, g) -> Float[Array, "n n"]:
        r"""$J = \partial\xi/\partial e$ at $e = 0$: the left error of the filter's error e at the mean g."""
        plus, _ = retraction(self.error)
        zero = jnp.zeros(self.n)
        return jax.jacfwd(lambda e: plus(g, e).rminus(g))(zero)

    def _to_own(self, g, K):
        if self.error == "left":
            return K
        J_inv = jnp.linalg.inv(self._left_jacobian(g))
        return mm(J_inv, mm(K, J_inv.T))

    def _to_left(self, g, P):
        if self.error == "left":
            return P
        J = self._left_jacobian(g)
        return mm(J, mm(P, J.T))

    def _kalman_update(self, g, P, nu, mask, C, P_ey, info):
        """Mean and covariance (in the filter's error coordinates, not transported to the new mean) after the
        innovation ``nu`` (present components ``mask``) of information ``info`` (module docstring)."""
        M = jnp.linalg.inv(jnp.eye(C.shape[0]) + mm(info, C))
        gain = mm(P_ey, mm(M, info))
        plus, _ = retraction(self.error)
        g = plus(g, mv(gain, jnp.where(mask, nu, 0.0)))
        # Joseph's form: P - P_ey K^T - K P_ey^T + K C K^T + K Sigma K^T, with K Sigma K^T = P_ey M I M^T P_ey^T
        KCK = mm(gain, mm(C, gain.T)) + mm(P_ey, mm(mm(M, mm(info, M.T)), P_ey.T))
        return g, P - mm(P_ey, gain.T) - mm(gain, P_ey.T) + KCK

    def _prior_output(self, state: FilterState, t, y0):
        """The filter's moments at the state (:meth:`_moments`): ``(h0, C, (P, P_ey))``."""
        P = self._to_own(state.g_hat, state.K)
        h0, C, P_ey = self._moments(state.g_hat, P, t, y0)
        return h0, C, (P, P_ey)

    def _correct(self, state: FilterState, t, y0, mask, W, prior):
        h0, C, (P, P_ey) = prior
        g, P = self._kalman_update(state.g_hat, P, y0 - h0, mask, C, P_ey, W)
        # the state's K: the covariance of the left error at the new mean (P is not transported, as in interval)
        K = self._to_left(g, 0.5 * (P + P.T))
        return g, 0.5 * (K + K.T)

    def interval(self, state: FilterState, t, dt, u0, u1, y0, y1, gap) -> FilterState:
        """One Kalman update with ``y0`` (its information over the interval), then one prediction with ``u0``."""
        st = state.status
        s = self.samples(state, dt, u0, u1, y0, y1, gap)
        u0, y0, mask, Wy = s.u0, s.y0, s.mask, s.Wy
        # update with y0: the information of the present components over the interval
        h0, C, (P, P_ey) = self._prior_output(state, t, y0)
        nu = y0 - h0
        scale, rejected, consecutive = self._sensor_scale(nu, C, t, dt, mask, Wy, st)
        info = Wy * dt * jnp.sqrt(scale)[:, None] * jnp.sqrt(scale)[None, :]
        g, P = self._kalman_update(state.g_hat, P, nu, mask, C, P_ey, info)
        # predict with u0 over the interval
        g1, P1 = self._predict(g, 0.5 * (P + P.T), u0, t, dt)
        K1 = self._to_left(g1, 0.5 * (P1 + P1.T))
        return self.finish(state, g1, 0.5 * (K1 + K1.T), t=t, dt=dt, samples=s, rejected=rejected,
                           consecutive=consecutive, n_sub=self.substeps)

    def _euler(self, g, u, t, h, w):
        """One Lie-Euler step of the discrete model with the algebra noise ``w``."""
        return g.rplus(self.system.dynamics(g, u, t) * h + w)


def _init_fields(flt, system, error, substeps):
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
    _validate.choice("error", error, set(ERRORS))
    if not (isinstance(substeps, int) and substeps >= 1):
        raise ValueError(f"substeps: expected an integer >= 1, got {substeps!r}")
    flt.system, flt.error, flt.substeps = system, error, substeps
    flt.weights = Weights.of(system)
    flt.blocks, flt.sample, flt.diagonal = sensor_layout(system, flt.weights.Wy)


class ExtendedKalmanFilter(AbstractKalmanFilter):
    r"""The extended Kalman filter on the group in the error coordinates ``error`` (module docstring).

    ``error="left"`` is the invariant EKF (left-invariant error; Barrau & Bonnabel 2017: for a left-invariant
    output and group-affine dynamics its Jacobians do not depend on the estimate), ``error="local"`` the EKF as
    practitioners write it (:func:`local_ekf`). Jacobians by autodiff through the retraction:
    $F = \partial_e \varphi^{-1}(\hat g^+, f(\varphi(\hat g, e), 0))$, $G = \partial_w \varphi^{-1}(\hat g^+,
    f(\hat g, w))$, $H = \partial_e h(\varphi(\hat g, e))$, all at 0; $P^+ = F P F^\top + G (BR^{-1}B^\top h) G^\top$
    per Lie-Euler step of size h.
    """

    def __init__(self, system: AbstractSystem, error: str = "left", *, substeps: int = 1):
        _init_fields(self, system, error, substeps)

    def __repr__(self) -> str:
        return f"ExtendedKalmanFilter({type(self.system).__name__}, error={self.error!r})"

    @property
    def name(self) -> str:
        """``"iekf"`` (left error), ``"ekf"`` (local) or ``"ekf-right"``."""
        return {"left": "iekf", "local": "ekf", "right": "ekf-right"}[self.error]

    def _moments(self, g, P, t, y):
        plus, _ = retraction(self.error)
        zero = jnp.zeros(self.n)
        h = lambda e: self.system.output_seen_from(y, plus(g, e), t)  # noqa: E731
        H = jax.jacfwd(h)(zero)
        PH = mm(P, H.T)
        return h(zero), mm(H, PH), PH

    def _predict(self, g, P, u, t, dt):
        plus, minus = retraction(self.error)
        zero = jnp.zeros(self.n)
        h = dt / self.substeps
        Qd = self.system.process_noise_at(g, self.weights.BRB, u, t) * h
        for j in range(self.substeps):
            tj = t + j * h
            g1 = self._euler(g, u, tj, h, zero)
            F = jax.jacfwd(lambda e, g=g, g1=g1, tj=tj: minus(self._euler(plus(g, e), u, tj, h, zero), g1))(zero)
            G = jax.jacfwd(lambda w, g=g, g1=g1, tj=tj: minus(self._euler(g, u, tj, h, w), g1))(zero)
            P = mm(F, mm(P, F.T)) + mm(G, mm(Qd, G.T))
            g = g1
        return g, P


class UnscentedKalmanFilter(AbstractKalmanFilter):
    r"""The unscented Kalman filter on the manifold (UKF-M; Brossard, Barrau & Bonnabel 2020, as in ukfm) in the
    error coordinates ``error`` (``"left"``: ukfm's left UKF-M).

    Sigma points $\varphi(\hat g, \pm s\,c_j)$, $c_j$ the columns of a square root of P (of the noise
    covariance $B R^{-1} B^\top h$ for the noise points), $s = a\sqrt n$; weights $\lambda = (a^2 - 1)n$,
    $w_j = 1/(2(n + \lambda))$, $w_m = \lambda/(n + \lambda)$, $w_0 = w_m + 3 - a^2$, with ``spread`` a = 1e-3 as
    ukfm's benchmark (ukfm's ``alpha``). The propagated mean is $f(\hat g, u, 0)$; the covariance is the
    weighted spread of the propagated state and noise points mapped back by $\varphi^{-1}$ (ukfm's scheme).

    ukfm's scheme, kept as the reference this baseline stands for, has a trap: $w_0 = 1 - 1/a^2 + 3 - a^2
    \approx -10^6$ multiplies $\bar\xi\bar\xi^\top$, and $\bar\xi = w_j\sum_j \xi_j$ is the points'
    second-order displacement, of the order of the curvature times P whatever a. Where the propagation is
    linear in the error coordinates (group-affine dynamics with the invariant error, e.g. the localization)
    $\bar\xi = 0$ and the filter is the invariant EKF to $O(a^2)$; elsewhere (the rigid body of Saccon et al.
    2016) the term subtracts about $10^6\,\bar\xi\bar\xi^\top$ from P and the filter turns overconfident (seen in
    ``liemef compare attitude-basin``). A larger ``spread`` tempers it.
    """

    spread: float = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, error: str = "left", *, spread: float = 1e-3, substeps: int = 1):
        _init_fields(self, system, error, substeps)
        if not (isinstance(spread, int | float) and 0 < spread <= 1):
            raise ValueError(f"spread: expected the sigma-point spread a in (0, 1], got {spread!r}")
        self.spread = float(spread)

    def __repr__(self) -> str:
        return f"UnscentedKalmanFilter({type(self.system).__name__}, error={self.error!r}, spread={self.spread})"

    @property
    def name(self) -> str:
        """``"ukf-left"``, ``"ukf-right"`` or ``"ukf-local"``."""
        return f"ukf-{self.error}"

    def _weights(self):
        n, a = self.n, self.spread
        lam = (a * a - 1.0) * n
        return a * jnp.sqrt(n), 1.0 / (2.0 * (n + lam)), lam / (lam + n), lam / (lam + n) + 3.0 - a * a

    def _spread(self, xis):
        r"""$w_j\sum (\xi_j - \bar\xi)(\cdot)^\top + w_0 \bar\xi\bar\xi^\top$, $\bar\xi = w_j \sum \xi_j$."""
        _, wj, _, w0 = self._weights()
        mean = wj * jnp.sum(xis, axis=0)
        d = xis - mean
        return wj * jnp.einsum("ki,kj->ij", d, d) + w0 * jnp.outer(mean, mean)

    def _moments(self, g, P, t, y):
        plus, _ = retraction(self.error)
        s, wj, wm, w0 = self._weights()
        cols = s * _sqrt_psd(P).T  # rows: s c_j
        xis = jnp.concatenate([cols, -cols])
        h0 = self.system.output_seen_from(y, g, t)
        ys = jax.vmap(lambda e: self.system.output_seen_from(y, plus(g, e), t))(xis)
        y_bar = wm * h0 + wj * jnp.sum(ys, axis=0)
        dy = ys - y_bar
        C = w0 * jnp.outer(h0 - y_bar, h0 - y_bar) + wj * jnp.einsum("ki,kj->ij", dy, dy)
        P_ey = wj * jnp.einsum("ki,kj->ij", xis, dy)
        return y_bar, C, P_ey

    def _predict(self, g, P, u, t, dt):
        plus, minus = retraction(self.error)
        s, _, _, _ = self._weights()
        zero = jnp.zeros(self.n)
        h = dt / self.substeps
        noise = s * _sqrt_psd(self.system.process_noise_at(g, self.weights.BRB, u, t) * h).T
        noise = jnp.concatenate([noise, -noise])
        for j in range(self.substeps):
            tj = t + j * h
            g1 = self._euler(g, u, tj, h, zero)
            cols = s * _sqrt_psd(P).T
            xis = jnp.concatenate([cols, -cols])
            state_pts = jax.vmap(lambda e, g=g, g1=g1, tj=tj: minus(self._euler(plus(g, e), u, tj, h, zero), g1))(xis)
            noise_pts = jax.vmap(lambda w, g=g, g1=g1, tj=tj: minus(self._euler(g, u, tj, h, w), g1))(noise)
            P = self._spread(state_pts) + self._spread(noise_pts)
            g = g1
        return g, P


def invariant_ekf(system: AbstractSystem, *, substeps: int = 1) -> ExtendedKalmanFilter:
    """The invariant EKF: :class:`ExtendedKalmanFilter` with the left-invariant error."""
    return ExtendedKalmanFilter(system, "left", substeps=substeps)


def local_ekf(system: AbstractSystem, *, substeps: int = 1) -> ExtendedKalmanFilter:
    """The EKF in local coordinates, as practitioners write it (rotations multiplicative, translations additive):
    :class:`ExtendedKalmanFilter` with ``error="local"``."""
    return ExtendedKalmanFilter(system, "local", substeps=substeps)


def ukf_m(system: AbstractSystem, error: str = "left", *, spread: float = 1e-3,
          substeps: int = 1) -> UnscentedKalmanFilter:
    """The UKF-M with the left retraction (ukfm's ``ukf_left``) unless ``error`` says otherwise."""
    return UnscentedKalmanFilter(system, error, spread=spread, substeps=substeps)
