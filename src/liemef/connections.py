r"""Affine connections on a Lie group, given by a bilinear connection function on the algebra.

A left-invariant connection is fixed by a bilinear map
$\omega: \mathfrak g \times \mathfrak g \to \mathfrak g$, $\nabla_{gX} (gY) = g\,\omega(X, Y)$ for constant
$X, Y$ (Saccon et al. 2016, Sec. II). The Cartan-Schouten family is $\omega(X, Y) = c\,\mathrm{ad}_X Y$:
$c = 0$ the (-)-connection, $c = 1/2$ the torsion-free (0)-connection (the papers' default), $c = 1$ the
(+)-connection. Its torsion is $T(X, Y) = \omega(X, Y) - \omega(Y, X) - [X, Y]$, for the family
$T_X = (2c - 1)\,\mathrm{ad}_X$.

Everything the filter needs from a connection is the constant tensor
$\Gamma[m, j, i] = \omega(e_j, e_i)_m$, computed once per group.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._linalg import mv
from ._names import CONNECTIONS
from .groups import LieGroup

CARTAN_SCHOUTEN = dict(zip(CONNECTIONS, (0.0, 0.5, 1.0), strict=True))
"""Named members of the Cartan-Schouten family and their coefficient c."""

ConnectionFunction = Callable[[Float[Array, " n"], Float[Array, " n"]], Float[Array, " n"]]


class Connection(eqx.Module):
    """A left-invariant connection: the tensor of a bilinear connection function on one group's algebra.

    Build it with :func:`connection`, from a Cartan-Schouten name, a coefficient ``c`` or a function.
    """

    name: str = eqx.field(static=True)
    Gamma: Float[Array, "n n n"]
    """``Gamma[m, j, i] = omega(e_j, e_i)[m]``."""
    C: Float[Array, "n n n"]
    """Structure constants ``C[m, j, i] = ad(e_j) e_i [m]``."""

    def omega(self, X: Float[Array, " n"], Y: Float[Array, " n"]) -> Float[Array, " n"]:
        r"""$\omega(X, Y)$."""
        return mv(self.omega_matrix(X), Y)

    def omega_matrix(self, X: Float[Array, " n"]) -> Float[Array, "n n"]:
        r"""The matrix of $Y \mapsto \omega(X, Y)$ (the papers' $\omega_X$; $W = \omega_{K r}$)."""
        return jnp.sum(self.Gamma * X[None, :, None], axis=1)

    def torsion_matrix(self, X: Float[Array, " n"]) -> Float[Array, "n n"]:
        r"""The matrix of $Y \mapsto T(X, Y) = \omega(X, Y) - \omega(Y, X) - \mathrm{ad}_X Y$."""
        T = self.Gamma - jnp.swapaxes(self.Gamma, 1, 2) - self.C
        return jnp.sum(T * X[None, :, None], axis=1)

    def hessian_correction(self, r: Float[Array, " n"]) -> Float[Array, "n n"]:
        r"""$M[i, j] = r \cdot (\tfrac12 \mathrm{ad}_{e_j} e_i - \omega(e_j, e_i))$.

        Added to the autodiff Hessian of $\xi \mapsto f(g \exp \xi)$ at 0 (the (0)-connection Hessian), it
        gives the connection Hessian $\mathrm{Hess}_\omega f(e_j, e_i)$ of a function whose differential is
        $r$.
        """
        return jnp.sum(r[:, None, None] * (0.5 * self.C - self.Gamma), axis=0).T


def connection(spec: str | float | ConnectionFunction | Connection, group: type[LieGroup]) -> Connection:
    """Build the :class:`Connection` of ``group`` from a name, a Cartan-Schouten coefficient or a function.

    ``spec`` is ``"minus"`` (c = 0), ``"zero"`` (c = 1/2), ``"plus"`` (c = 1), a number c, or a bilinear
    function ``omega(X, Y) -> Z`` on n-vectors (checked for bilinearity here, before any compiled code runs).
    """
    if isinstance(spec, Connection):
        return spec
    C = group.structure_constants()  # C[m, j, i] = ad(e_j)[m, i]: the group's one definition
    if isinstance(spec, str):
        if spec not in CARTAN_SCHOUTEN:
            raise ValueError(f"connection: expected one of {sorted(CARTAN_SCHOUTEN)}, a number c or a "
                             f"function, got {spec!r}")
        return Connection(name=spec, Gamma=CARTAN_SCHOUTEN[spec] * C, C=C)
    if isinstance(spec, int | float) and not isinstance(spec, bool):
        if not np.isfinite(spec):
            raise ValueError(f"connection: expected a finite Cartan-Schouten coefficient c, got {spec!r}")
        return Connection(name=f"cartan-schouten(c={spec:g})", Gamma=float(spec) * C, C=C)
    if callable(spec):
        return _from_function(spec, group, C)
    raise ValueError("connection: expected a name, a number or a function omega(X, Y), "
                     f"got {type(spec).__name__}")


def _from_function(fn: ConnectionFunction, group: type[LieGroup], C: Array) -> Connection:
    n = group.tangent_dim
    basis = jnp.eye(n)
    try:
        column = lambda ej: jax.vmap(lambda ei: jnp.asarray(fn(ej, ei), dtype=jnp.float64))(basis)  # noqa: E731
        Gamma = jax.vmap(column)(basis)
    except Exception as err:  # noqa: BLE001  (a user function may fail in any way: say which argument)
        raise ValueError("connection: the function omega(X, Y) failed on basis vectors of length "
                         f"{n}: {err}") from err
    if Gamma.shape != (n, n, n):
        raise ValueError(f"connection: expected omega(X, Y) to return a vector of shape ({n},), "
                         f"got shape {Gamma.shape[2:]}")
    Gamma = jnp.moveaxis(Gamma, 2, 0)  # (j, i, m) -> (m, j, i)
    # Bilinearity, checked at random arguments: the tensor must reproduce the function.
    rng = np.random.default_rng(0)
    for _ in range(3):
        X, Y = rng.standard_normal(n), rng.standard_normal(n)
        got = np.asarray(fn(jnp.asarray(X), jnp.asarray(Y)), dtype=float)
        want = np.einsum("mji,j,i->m", np.asarray(Gamma), X, Y)
        if not np.allclose(got, want, rtol=1e-9, atol=1e-9 * (1 + np.abs(want).max())):
            raise ValueError("connection: expected a bilinear function omega(X, Y); it is not bilinear at "
                             f"random arguments (max deviation {np.abs(got - want).max():.3g})")
    name = getattr(fn, "__name__", "user")
    return Connection(name=name, Gamma=Gamma, C=C)


ConnectionName = Literal["minus", "zero", "plus"]
