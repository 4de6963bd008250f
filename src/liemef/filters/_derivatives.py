r"""Left-trivialized derivatives at the estimate, by autodiff through $\xi \mapsto g\exp(\xi)$ at $\xi = 0$.

For $F(\xi) = f(g \exp \xi)$: the differential is ``jacfwd(F)(0)`` (column j = direction $e_j$) and the autodiff
Hessian of F at 0 is the symmetric (0)-connection Hessian, since by Baker-Campbell-Hausdorff
$\partial_s\partial_t f(g e^{sX} e^{tY}) = D^2F(X, Y) + \tfrac12 DF\,[X, Y]$. The connection Hessian of any other
connection adds a term linear in $DF$ (:meth:`liemef.connections.Connection.hessian_correction`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..groups import LieGroup


def left_jacobian(f: Callable[[LieGroup], Array], g: LieGroup) -> tuple[Array, Array]:
    r"""Value and left-trivialized Jacobian of ``f`` at ``g``: ``J[:, j] = d/ds f(g exp(s e_j))`` at 0."""
    zero = jnp.zeros(type(g).tangent_dim)
    F = lambda xi: f(g.rplus(xi))  # noqa: E731
    return F(zero), jax.jacfwd(F)(zero)


def left_hessian(f: Callable[[LieGroup], Float[Array, ""]], g: LieGroup) -> Float[Array, "n n"]:
    r"""Symmetric Hessian of the scalar $\xi \mapsto f(g\exp\xi)$ at 0 (the (0)-connection Hessian of f)."""
    zero = jnp.zeros(type(g).tangent_dim)
    return jax.hessian(lambda xi: f(g.rplus(xi)))(zero)
