r"""The hybrid minimum-energy filter's update at a sample time (DESIGN.md §7, docs/theorem.md "Samples at their
own time").

With discrete samples the cost is $J = \text{prior} + \int \text{continuous terms} + \sum_k \tfrac12
|y_k \ominus h(g(t_k))|^2_{W_k}$. Between samples the value function evolves by Theorem 4.1 with the continuous
terms only; at $t_k$ the new value function is the old one plus the sample's term. To second order about the
estimate $\hat g$ (gain K, the inverse of the value function's Hessian in left-trivialized coordinates) the
update is

$$\xi^* = \arg\min_\xi\; \tfrac12 \xi^\top K^{-1}\xi + \tfrac12 |e(\xi)|^2_{W},\qquad
e(\xi) = y \ominus h(\hat g\exp\xi),$$

$$\hat g^+ = \hat g\exp\xi^*,\qquad K^+ = J\,(K^{-1} + H_f(\xi^*))^{-1} J^\top,\qquad
J = \partial_\xi\bigl[(\hat g\exp\xi)\ominus\hat g^+\bigr]_{\xi^*}$$

with $H_f$ the Hessian of the sample's term. The minimizer comes from a fixed number of Newton iterations
(``newton=True``: $H_f = F^\top W F - \nabla^2(\tilde y\cdot h)$, the second-order term of h kept, the discrete
analogue of the theorem's Hessian term of E) or Gauss-Newton iterations ($H_f = F^\top W F$, the first-order
variant) from $\xi = 0$, with $F = \partial_\xi h(\hat g\exp\xi)$ and $\tilde y = W e$. Every step is written
with K, not its inverse, so that a singular K (a state known exactly) stays allowed:

$$\xi \leftarrow \xi - (I + K H_f)^{-1}(\xi - K F^\top \tilde y), \qquad (K^{-1} + H_f)^{-1} = (I + K H_f)^{-1} K.$$

J is the derivative of exp between the coordinates at $\hat g$ and at $\hat g^+$ ($\hat g\exp(\xi^* + d) =
\hat g^+\exp(J d + O(d^2))$): the Hessian at the minimizer moved to the new estimate's coordinates, where the
gradient vanishes and no connection enters (Saccon et al. 2016, the remark after Lemma A.1).

No branch depends on the data: the iterations are unrolled and a missing sample has zero weight (then
$\xi^* = 0$), so that the update is one straight-line program in a compiled scan and in the C kernel.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._linalg import mm, mv
from ..groups import LieGroup


def _output_derivatives(output: Callable[[LieGroup], Array], g_hat: LieGroup, xi, y, Wy, newton: bool):
    """At $\\hat g\\exp\\xi$: the weighted residual $\\tilde y = W(y - h)$, $F = \\partial h$ and the sample term's
    Hessian $H_f$ (Newton or Gauss-Newton)."""
    F_of = lambda z: output(g_hat.rplus(z))  # noqa: E731
    F, h = jax.jacfwd(lambda z: (F_of(z),) * 2, has_aux=True)(xi)
    y_tilde = mv(Wy, y - h)
    Hf = mm(F.T, mm(Wy, F))
    if newton:
        Hf = Hf - jax.hessian(lambda z: y_tilde @ F_of(z))(xi)
    return y_tilde, F, Hf


def sample_update(output: Callable[[LieGroup], Array], g_hat: LieGroup, K: Float[Array, "n n"], y: Float[Array, " p"],
                  Wy: Float[Array, "p p"], *, iterations: int, newton: bool) -> tuple[LieGroup, Float[Array, "n n"]]:
    r"""$(\hat g^+, K^+)$ after the sample ``y`` of information ``Wy`` (module docstring).

    ``output(g)`` is the sample's output map as seen from ``y`` ($y - (y \ominus h(g))$, so that
    $y - \text{output}(g)$ is the sensors' residual); a missing component has zero rows and columns in ``Wy``.
    ``iterations`` (static, >= 1) Newton (``newton=True``) or Gauss-Newton steps from $\xi = 0$.
    """
    n = K.shape[0]
    eye = jnp.eye(n)
    xi = jnp.zeros(n)
    for _ in range(iterations):
        y_tilde, F, Hf = _output_derivatives(output, g_hat, xi, y, Wy, newton)
        xi = xi - jnp.linalg.solve(eye + mm(K, Hf), xi - mv(K, mv(F.T, y_tilde)))
    g_plus = g_hat.rplus(xi)
    _, _, Hf = _output_derivatives(output, g_hat, xi, y, Wy, newton)
    K_xi = jnp.linalg.solve(eye + mm(K, Hf), K)
    J = jax.jacfwd(lambda d: g_hat.rplus(xi + d).rminus(g_plus))(jnp.zeros(n))
    return g_plus, mm(J, mm(K_xi, J.T))
