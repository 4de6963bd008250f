r"""Residual and perturbed Riccati right-hand side of Theorem 4.1 (Saccon et al. 2016), in coordinates.

With $\tilde y = D^{-\top} Q D^{-1} (y - h(\hat g))$ (docs/theorem.md; $y \ominus h$ where a sensor declares its
residual, through :meth:`~liemef.systems.AbstractSystem.output_seen_from`, docs/weights.md "Inputs, gaps and outliers"):

$$r = Dh^\top \tilde y,\quad A = D\lambda - \mathrm{ad}_\lambda - T_\lambda,\quad
E = Dh^\top D^{-\top} Q D^{-1} Dh - \sum_k \tilde y_k \mathrm{Hess}\, h_k,\quad W = \omega_{K r},$$

$$\hat g^{-1}\dot{\hat g} = \lambda + K r, \qquad
\dot K = -\alpha K + A K + K A^\top - K E K + B R^{-1} B^\top - W K - K W^\top.$$

The first-order variant drops the Hessian term of E and sets W = 0 (the continuous-time left-invariant EKF).
With ``curvature="safe"`` the Hessian term of E is :func:`~._curvature.safe_curvature`'s: kept where it lies
between minus the Gauss-Newton part and zero and dropped elsewhere (``Terms.modified`` says where), and W = 0.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._linalg import mm, mv
from ..connections import Connection
from ..groups import LieGroup
from ..systems import AbstractSystem
from ..systems._traced import array_module
from ._curvature import safe_curvature
from ._derivatives import left_hessian, left_jacobian


class Terms(eqx.Module):
    """The terms of Theorem 4.1 at one state, in the matrix convention ``M[i, j] = M(e_j)(e_i)``."""

    r: Float[Array, " n"]
    """Residual $Dh^\\top \\tilde y$ (in the dual of the algebra)."""
    A: Float[Array, "n n"]
    E: Float[Array, "n n"]
    W: Float[Array, "n n"]
    BRB: Float[Array, "n n"]
    """$B R^{-1} B^\\top$."""
    lam: Float[Array, " n"]
    """Left-trivialized dynamics $\\lambda(\\hat g, u, t)$."""
    y_tilde: Float[Array, " p"]
    """Weighted innovation $D^{-\\top} Q D^{-1} (y - h(\\hat g))$."""
    Dh: Float[Array, "p n"]
    Dlam: Float[Array, "n n"]
    modified: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(False))
    """Whether the safe curvature dropped E's Hessian term (``curvature="safe"``; always False otherwise)."""


class Weights(eqx.Module):
    """The cost's weights over one interval: $D^{-\\top} Q D^{-1}$ (``Wy``, the information in force) and
    $B R^{-1} B^\\top$ (``BRB``). :meth:`of` gives a system's nominal weights (every sample present, density
    meaning); the engine forms the weights in force with :func:`information_in_force`."""

    Wy: Float[Array, "p p"]
    BRB: Float[Array, "n n"]

    @staticmethod
    def of(system: AbstractSystem) -> Weights:
        """The system's nominal weights: every sample present, information per unit time or per sample."""
        B, R = system.B, system.R
        xp = array_module(B, R)  # NumPy outside a trace: no XLA compile
        B = xp.asarray(B)
        return Weights(Wy=system.information(), BRB=B @ xp.linalg.solve(xp.asarray(R), B.T))


def information_in_force(Wy, sample, mask, dt, *, diagonal: bool = False) -> Float[Array, "p p"]:
    r"""The measurement information over an interval of length ``dt`` in which the components ``mask`` have a
    sample (docs/weights.md, "One sample carries its information once").

    A missing component carries no information: the information of the present ones is that of their marginal,
    $(\Sigma_{SS})^{-1}$ with $\Sigma = W_y^{-1}$, padded with zeros (for a block-diagonal $W_y$ this is
    zeroing the missing rows and columns; in general it is the filter built without those components). A
    ``sample`` component carries its per-sample information once, spread over the interval: divided by ``dt``.
    ``diagonal`` (static) says that ``Wy`` is diagonal, where zeroing is the marginal (no inverse needed).
    """
    M = mask.astype(Wy.dtype)
    if diagonal:
        W = Wy * M[:, None] * M[None, :]
    else:
        Sigma = jnp.linalg.inv(Wy)
        S = Sigma * M[:, None] * M[None, :] + jnp.diag(1.0 - M)
        W = jnp.linalg.inv(S) * M[:, None] * M[None, :]
    s = jnp.sqrt(jnp.where(sample, 1.0 / dt, 1.0))
    return W * s[:, None] * s[None, :]


@eqx.filter_jit  # one call per evaluation: traced once per interval structure (not once per RK stage), one
# function in the exported C (liemef.codegen); XLA inlines it
def terms(system: AbstractSystem, weights: Weights, conn: Connection, second_order: bool,
          g: LieGroup, K, u, y, t, outputs: bool = True, safe: bool = False) -> Terms:
    """r, A, E, W, B R^{-1} B^T of Theorem 4.1 at the estimate ``g`` with gain ``K``. ``outputs=False``
    (static): no output carries weight (the hybrid filter's prediction with sample sensors only), so r, E, W and
    the innovation are zero and the output's derivatives are not computed. ``safe`` (static): E's Hessian term
    is the safe curvature (module docstring)."""
    G = type(g)
    if not outputs:
        lam, Dlam = left_jacobian(lambda gg: system.dynamics(gg, u, t), g)
        A = Dlam - G.ad(lam) - conn.torsion_matrix(lam)
        p, n = weights.Wy.shape[0], lam.shape[0]
        return Terms(r=jnp.zeros(n), A=A, E=jnp.zeros((n, n)), W=jnp.zeros((n, n)),
                     BRB=system.process_noise_at(g, weights.BRB, u, t), lam=lam,
                     y_tilde=jnp.zeros(p), Dh=jnp.zeros((p, n)), Dlam=Dlam)
    h0, Dh = left_jacobian(lambda gg: system.output_seen_from(y, gg, t), g)
    y_tilde = mv(weights.Wy, y - h0)
    r = mv(Dh.T, y_tilde)
    lam, Dlam = left_jacobian(lambda gg: system.dynamics(gg, u, t), g)
    A = Dlam - G.ad(lam) - conn.torsion_matrix(lam)
    E = mm(Dh.T, mm(weights.Wy, Dh))
    modified = jnp.asarray(False)
    if second_order:
        # sum_k y_tilde_k Hess h_k = Hess (y_tilde . h) + connection correction linear in r = Dh^T y_tilde
        C = -(left_hessian(lambda gg: y_tilde @ system.output_seen_from(y, gg, t), g) + conn.hessian_correction(r))
        if safe:
            # the curvature only inside its band, and no connection term W = omega(K r), which grows with the
            # same residual (docs/theorem.md)
            C, modified = safe_curvature(E, C)
            W = jnp.zeros_like(A)
        else:
            W = conn.omega_matrix(mv(K, r))
        E = E + C
    else:
        W = jnp.zeros_like(A)
    return Terms(r=r, A=A, E=E, W=W, BRB=system.process_noise_at(g, weights.BRB, u, t), lam=lam, y_tilde=y_tilde,
                 Dh=Dh, Dlam=Dlam, modified=modified)


def riccati_rhs(tm: Terms, K, alpha) -> Float[Array, "n n"]:
    """Perturbed Riccati equation (Saccon et al. 2016, Theorem 4.1, eq. (11))."""
    # A K + K A^T - W K - K W^T = M K + K M^T with M = A - W. K is not symmetric in general (the
    # (-)-connection E is not), so K M^T must not be formed as (M K)^T.
    M = tm.A - tm.W
    return -alpha * K + mm(M, K) + mm(K, M.T) - mm(K, mm(tm.E, K)) + tm.BRB
