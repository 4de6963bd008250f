from __future__ import annotations

import abc
from typing import ClassVar, Self

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


class LieGroup(eqx.Module):
    r"""Abstract base of every matrix Lie group element.

    An element is a frozen pytree (an :class:`equinox.Module`) holding the arrays that parametrize it, with
    optional leading batch axes. The Lie algebra $\mathfrak g$ is identified with $\mathbb R^n$ through
    :meth:`hat` / :meth:`vee`, in the papers' basis order (see :mod:`liemef.groups`).

    Vocabulary (manif's): ``a @ b`` composes, :meth:`exp` / :meth:`log` map to and from coordinates,
    :meth:`rplus` is the body-frame (left-trivialized) perturbation $g \exp(\xi)$, :meth:`rminus` its inverse
    $\log(h^{-1} g)$, :meth:`ad` and :meth:`Ad` the adjoint representations as $n \times n$ matrices with
    $\mathrm{ad}_X Y = (\hat X \hat Y - \hat Y \hat X)^\vee$ and $\mathrm{Ad}_g X = (g \hat X g^{-1})^\vee$.
    """

    tangent_dim: ClassVar[int]
    """Dimension n of the Lie algebra."""
    matrix_dim: ClassVar[int]
    """Size of the square matrices of the matrix representation."""
    coords_dim: ClassVar[int]
    """Length of the coordinates vector of :meth:`coords` (angles, positions, velocities)."""

    # --- constructors -------------------------------------------------------------------------------------
    @classmethod
    @abc.abstractmethod
    def identity(cls, batch_shape: tuple[int, ...] = ()) -> Self:
        """The identity element, broadcast to ``batch_shape``."""

    @classmethod
    @abc.abstractmethod
    def exp(cls, xi: Float[ArrayLike, "... n"]) -> Self:
        r"""Exponential map $\mathbb R^n \cong \mathfrak g \to G$; smooth (with all derivatives) at 0."""

    @classmethod
    @abc.abstractmethod
    def from_matrix(cls, M: Float[ArrayLike, "... m m"]) -> Self:
        """Element from its matrix representation."""

    @classmethod
    @abc.abstractmethod
    def from_coords(cls, q: Float[ArrayLike, "... c"]) -> Self:
        """Element from its coordinates vector (see :meth:`coords`)."""

    # --- group operations ---------------------------------------------------------------------------------
    @abc.abstractmethod
    def compose(self, other: Self) -> Self:
        """Group product ``self * other``."""

    @abc.abstractmethod
    def inverse(self) -> Self:
        """Group inverse."""

    @abc.abstractmethod
    def log(self) -> Float[Array, "... n"]:
        """Logarithm, inverse of :meth:`exp` on its principal domain."""

    @abc.abstractmethod
    def as_matrix(self) -> Float[Array, "... m m"]:
        """Matrix representation."""

    @abc.abstractmethod
    def coords(self) -> Float[Array, "... c"]:
        """Coordinates vector: angles (rad), positions and velocities in the papers' order."""

    @abc.abstractmethod
    def Ad(self) -> Float[Array, "... n n"]:
        r"""Adjoint matrix: ``Ad() @ xi == vee(g hat(xi) g^{-1})``."""

    # --- Lie algebra --------------------------------------------------------------------------------------
    @classmethod
    @abc.abstractmethod
    def hat(cls, xi: Float[ArrayLike, "... n"]) -> Float[Array, "... m m"]:
        """Coordinates to the matrix Lie algebra."""

    @classmethod
    @abc.abstractmethod
    def vee(cls, X: Float[ArrayLike, "... m m"]) -> Float[Array, "... n"]:
        """Matrix Lie algebra to coordinates (inverse of :meth:`hat`)."""

    @classmethod
    @abc.abstractmethod
    def ad(cls, xi: Float[ArrayLike, "... n"]) -> Float[Array, "... n n"]:
        r"""Adjoint of the algebra: ``ad(X) @ Y == vee(hat(X) @ hat(Y) - hat(Y) @ hat(X))``."""

    # --- derived operations (final) -----------------------------------------------------------------------
    def __matmul__(self, other: Self) -> Self:
        return self.compose(other)

    def rplus(self, xi: Float[ArrayLike, "... n"]) -> Self:
        r"""Body-frame perturbation $g \exp(\xi)$ (the library's one perturbation convention)."""
        return self @ type(self).exp(xi)

    def rminus(self, other: Self) -> Float[Array, "... n"]:
        r"""$\log(\mathrm{other}^{-1} g)$, so that ``other.rplus(g.rminus(other)) == g``."""
        return (other.inverse() @ self).log()

    def between(self, other: Self) -> Self:
        r"""$g^{-1} h$."""
        return self.inverse() @ other

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes of this element."""
        # Every parameter array of every group has exactly one trailing (event) axis.
        return tuple(jax.tree_util.tree_leaves(self)[0].shape[:-1])

    def off_group(self) -> float:
        """How far the stored parameters are from the group, as a float (the largest over the batch): 0 for a
        group whose parameters are unconstrained (R^n); for one that stores unit vectors (the (cos, sin) of
        SO(2) and SE(2), SO(3)'s quaternion), ``| |v| - 1 |``. The boundary checks refuse an element further
        than ``liemef._validate.ON_GROUP``."""
        return 0.0

    @classmethod
    def structure_constants(cls) -> Float[Array, "n n n"]:
        r"""$C[m, j, i] = (\mathrm{ad}_{e_j} e_i)_m$, constant for a given group."""
        return jnp.moveaxis(cls.ad(jnp.eye(cls.tangent_dim)), 0, 1)

    def __getitem__(self, index) -> Self:
        """Index the batch axes."""
        return jax.tree_util.tree_map(lambda leaf: leaf[index], self)


def as_float_array(x: ArrayLike) -> Array:
    """Convert to a float64 JAX array (the library computes in double precision); complex values are refused
    (a ValueError), not truncated."""
    dtype = getattr(x, "dtype", None)
    if dtype is None:
        try:
            dtype = np.asarray(x).dtype
        except Exception:  # noqa: BLE001 - e.g. a list of tracers: jnp converts it below
            dtype = None
    if dtype is not None and np.issubdtype(dtype, np.complexfloating):
        raise ValueError(f"group parameters: expected real numbers, got complex values {np.asarray(x)!r}")
    return jnp.asarray(x, dtype=jnp.float64)


def unit_distance(v) -> float:
    """``max | |v| - 1 |`` over the last axis of ``v`` (NumPy, not traced): how far a stored unit vector is."""
    v = np.asarray(v, dtype=np.float64)
    return float(np.max(np.abs(np.linalg.norm(v, axis=-1) - 1.0), initial=0.0))
