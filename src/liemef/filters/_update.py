r"""The hybrid minimum-energy filter's update at a sample time (docs/theorem.md, "Samples at their own time").

With discrete samples the cost is $J = \text{prior} + \int \text{continuous terms} + \sum_k \tfrac12
|y_k \ominus h(g(t_k))|^2_{W_k}$. Between samples the value function evolves by Theorem 4.1 with the continuous
terms only; at $t_k$ the new value function is the old one plus the sample's term. To second order about the
estimate $\hat g$ (gain K, the inverse of the value function's Hessian in left-trivialized coordinates) the
update minimizes the sample's cost

$$c(\xi) = \tfrac12 \xi^\top K^{-1}\xi + \tfrac12 |e(\xi)|^2_{W},\qquad e(\xi) = y \ominus h(\hat g\exp\xi),$$

$$\hat g^+ = \hat g\exp\xi^*,\qquad K^+ = J\,(K^{-1} + H(\xi^*))^{-1} J^\top,\qquad
J = \partial_\xi\bigl[(\hat g\exp\xi)\ominus\hat g^+\bigr]_{\xi^*}.$$

**The minimizer** is found by a globally convergent Newton method on the true cost c (Nocedal & Wright,
Numerical Optimization, ch. 3): from $\xi = 0$, each iteration takes the direction
$d = -(K^{-1} + H)^{-1}\nabla c$ and the largest step $a \in \{1, \tfrac12, \tfrac14, \dots\}$ that satisfies
Armijo's condition $c(\xi + a d) \le c(\xi) + 10^{-4} a\, \nabla c^\top d$; iterations stop when the Newton
decrement $-\nabla c^\top d$ falls below ``tol`` times $1 + c(\xi)$ (that last step is still taken), after
``iterations`` of them, or when no step of the line search lowers the cost (then $\xi$ stays where it is, and
the update counts as converged only if the decrement was at the cost's round-off, ``ROUNDOFF_DECREMENT``).
**The cost never increases** (beyond its round-off, ``ROUNDOFF``): a step is taken only if it lowers c. The
Hessian of the sample's term is

* Gauss-Newton (``newton=False``, the first-order filter): $H = G = F^\top W F$, $F = \partial_\xi
  h(\hat g\exp\xi)$; positive semidefinite, so $d$ always descends;
* Newton (``newton=True``, the second-order filter): $H = G + C$ with the curvature
  $C = -\nabla^2_\xi(\tilde y\cdot h(\hat g\exp\xi))$, $\tilde y = W e$ held fixed (the discrete analogue of the
  theorem's Hessian term of E). The direction uses H wherever $K^{-1} + H$ is positive definite (so that the
  iterations converge quadratically near the minimizer), and elsewhere a modified Hessian (Newton with Hessian
  modification, Nocedal & Wright ch. 3.4): the Gauss-Newton $G$, or with ``safe=True`` $G + C_{\text{safe}}$
  (:func:`~._curvature.safe_curvature`: C where $-G \preceq C \preceq 0$, else 0).

**K+** is the inverse of a positive definite Hessian at the final iterate, moved by J: $(K^{-1} +
H_+)^{-1}$ with $H_+ = G + C_{\text{safe}}$ (``safe=True``: always the safe curvature, which equals C where C is
already safe), or, with ``safe=False``, $H_+ = H$ where $K^{-1} + H$ is positive definite and $G$ where it is
not; first order, $H_+ = G$. ``UpdateInfo.modified`` says whether $H_+$ differs from Newton's H. At a
minimizer where it does not, K+ is the inverse of the exact Hessian of c at its minimizer, in the coordinates at
$\hat g^+$ (at a critical point a Hessian changes coordinates by the first derivative alone, and no connection
enters: Saccon et al. 2016, the remark after Lemma A.1).

Every step is written with K, not its inverse, so that a singular K (a state known exactly) stays allowed:
with $\xi = K z$, $\nabla c = z - F^\top\tilde y$, the step is $z \leftarrow z - a\,(I + H K)^{-1}\nabla c$ and
$(K^{-1} + H)^{-1} = (I + K H)^{-1} K$; the prior term is $\tfrac12 z^\top K z$.

No branch depends on the data in Python: the iterations and the line search are ``lax.while_loop``\ s with a
fixed maximum, so the update is one program in a compiled scan and in the C kernel alike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._linalg import mm, mv
from ..groups import LieGroup
from ._curvature import safe_curvature
from ._status import positive_definite

ARMIJO = 1e-4
"""Armijo's sufficient-decrease constant of the line search."""
HALVINGS = 12
"""The most trial steps of one line search: a = 1, 1/2, ..., 2^-11."""
ROUNDOFF = 64 * float(jnp.finfo(jnp.float64).eps)
"""The cost's round-off, relative: a trial step passes Armijo's test if it raises c by less than this."""
ROUNDOFF_DECREMENT = 1e-10
"""A line search that finds no lower cost ends the iterations as converged where the Newton decrement is below
this, relative to 1 + c: there the decrease it asks for is at the cost's round-off."""


class UpdateInfo(NamedTuple):
    """What one sample update did: the cost before and after, the iterations taken, whether it converged (the
    Newton decrement below the tolerance) and whether K+ comes from a modified Hessian (the safe curvature, or
    the Gauss-Newton fallback of an indefinite Newton Hessian) rather than Newton's at the final iterate."""

    cost0: Float[Array, ""]
    cost: Float[Array, ""]
    iterations: Int[Array, ""]
    converged: Bool[Array, ""]
    modified: Bool[Array, ""]


class _Local(NamedTuple):
    """The sample's term at one iterate: its cost, the weighted residual, F, the Hessian that gives the search
    direction and the one that gives K+ (module docstring)."""

    cost: Float[Array, ""]
    y_tilde: Float[Array, " p"]
    F: Float[Array, "p n"]
    H_step: Float[Array, "n n"]
    H_gain: Float[Array, "n n"]
    modified: Bool[Array, ""]


def _local(output, g_hat: LieGroup, K, z, y, Wy, newton: bool, safe: bool) -> _Local:
    r"""At $\xi = K z$: c, $\tilde y$, F and the Hessians of the sample's term (module docstring)."""
    xi = mv(K, z)
    F_of = lambda d: output(g_hat.rplus(d))  # noqa: E731
    F, h = jax.jacfwd(lambda d: (F_of(d),) * 2, has_aux=True)(xi)
    e = y - h
    y_tilde = mv(Wy, e)
    cost = 0.5 * (xi @ z + e @ y_tilde)
    G = mm(F.T, mm(Wy, F))
    if not newton:
        return _Local(cost, y_tilde, F, G, G, jnp.asarray(False))
    C = -jax.hessian(lambda d: y_tilde @ F_of(d))(xi)
    H = G + C
    S = K + mm(K, mm(H, K))
    definite = positive_definite(0.5 * (S + S.T))   # K^-1 + H positive definite (K's range)
    fallback = G
    modified = ~definite
    if safe:
        C_safe, modified = safe_curvature(G, C)
        fallback = G + C_safe
    # the direction: Newton's where its Hessian is positive definite (quadratic convergence near the minimizer),
    # else the modified one; K+: the modified one with safe=True, Newton's or Gauss-Newton's otherwise
    H_step = jnp.where(definite, H, fallback)
    return _Local(cost, y_tilde, F, H_step, fallback if safe else H_step, modified)


def sample_update(output: Callable[[LieGroup], Array], g_hat: LieGroup, K: Float[Array, "n n"], y: Float[Array, " p"],
                  Wy: Float[Array, "p p"], *, iterations: int, newton: bool, safe: bool = False,
                  tol: Float[Array, ""] | float = 1e-14) -> tuple[LieGroup, Float[Array, "n n"], UpdateInfo]:
    r"""$(\hat g^+, K^+)$ after the sample ``y`` of information ``Wy``, and what the update did (module docstring).

    ``output(g)`` is the sample's output map as seen from ``y`` ($y - (y \ominus h(g))$, so that
    $y - \text{output}(g)$ is the sensors' residual); a missing component has zero rows and columns in ``Wy``.
    ``iterations`` (static, >= 1): the most Newton (``newton=True``) or Gauss-Newton iterations from
    $\xi = 0$; ``safe`` (static): the safe curvature in Newton's Hessian; ``tol``: the Newton decrement, relative
    to $1 + c$, below which the iterations stop.
    """
    n = K.shape[0]
    eye = jnp.eye(n)
    local = lambda z: _local(output, g_hat, K, z, y, Wy, newton, safe)  # noqa: E731
    cost_of = lambda z: _cost(output, g_hat, K, z, y, Wy)  # noqa: E731
    z0 = jnp.zeros(n)
    at0 = local(z0)

    def iterate(c):
        z, at, it, _, _ = c
        grad = z - mv(at.F.T, at.y_tilde)
        dz = -jnp.linalg.solve(eye + mm(at.H_step, K), grad)
        slope = grad @ mv(K, dz)                  # = grad . d <= 0 (d = K dz descends)
        converged = -slope <= tol * (1.0 + at.cost)

        def trial(s):
            a, _, _ = s
            z_try = z + a * dz
            c_try = cost_of(z_try)
            # Armijo's condition, up to the cost's round-off: the last Newton step, whose decrease is below it,
            # is taken whole
            return 0.5 * a, c_try <= at.cost + ARMIJO * a * slope + ROUNDOFF * jnp.abs(at.cost), z_try

        def more(s):
            a, ok, _ = s
            return ~ok & (a >= 2.0 ** (1 - HALVINGS))

        _, ok, z_new = jax.lax.while_loop(more, trial, (jnp.asarray(1.0), jnp.asarray(False), z))
        # the step is taken if it lowers the cost (even the last one, whose decrement is below the tolerance:
        # Newton's last step is the cheapest digits); a search that finds no lower cost leaves z where it is,
        # converged if the decrement is already at the cost's round-off
        z_new = jnp.where(ok, z_new, z)
        at_new = jax.lax.cond(ok, local, lambda _: at, z_new)
        converged = converged | (~ok & (-slope <= ROUNDOFF_DECREMENT * (1.0 + at.cost)))
        return z_new, at_new, it + ok, converged, ~ok

    def more(c):
        _, _, it, converged, stuck = c
        return ~converged & ~stuck & (it < iterations)

    z, at, it, converged, _ = jax.lax.while_loop(
        more, iterate, (z0, at0, jnp.asarray(0, jnp.int32), jnp.asarray(False), jnp.asarray(False)))
    xi = mv(K, z)
    g_plus = g_hat.rplus(xi)
    K_xi = jnp.linalg.solve(eye + mm(K, at.H_gain), K)
    J = jax.jacfwd(lambda d: g_hat.rplus(xi + d).rminus(g_plus))(jnp.zeros(n))
    return g_plus, mm(J, mm(K_xi, J.T)), UpdateInfo(at0.cost, at.cost, it, converged, at.modified)


def _cost(output, g_hat: LieGroup, K, z, y, Wy) -> Float[Array, ""]:
    """c at $\\xi = K z$ (no derivatives: the line search's trial points)."""
    xi = mv(K, z)
    e = y - output(g_hat.rplus(xi))
    return 0.5 * (xi @ z + e @ mv(Wy, e))
