from __future__ import annotations

import abc
import functools
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

    def defects(self) -> dict[str, float]:
        """How far the stored parameters are from the group, defect by defect, each the largest over the batch
        (NumPy, on concrete values): ``{}`` for a group whose parameters are unconstrained (R^n); for one that
        stores unit vectors (the (cos, sin) of SO(2) and SE(2), the quaternion of SO(3) and SE_K(3)) the norm,
        ``| |v| - 1 |``; for a :class:`MatrixGroup`, its matrix's (:meth:`matrix_defects`); a product, its
        factors'. NaN parameters give NaN."""
        return {}

    def off_group(self) -> float:
        """The largest of :meth:`defects` (0 without any; NaN for NaN parameters). The boundary checks (every
        filter's ``init``, ``run`` and ``terms``, ``simulate``) refuse an element further than
        ``liemef._validate.ON_GROUP``, naming the defect."""
        sizes = list(self.defects().values())
        return float(np.max(sizes)) if sizes else 0.0

    @classmethod
    def matrix_defects(cls, M: np.ndarray) -> dict[str, np.ndarray]:
        r"""How far each finite matrix of ``M`` (NumPy, ``(..., m, m)``) is from the group's matrices, defect by
        defect, each an array of the batch shape ``M.shape[:-2]``: the orthogonality $|R^T R - I|$ and the
        determinant $|\det R - 1|$ of a rotation block, the bottom rows of a homogeneous matrix (their largest
        entry away from ``[0, I]``), a :class:`MatrixGroup`'s own rule. :meth:`from_matrix` refuses a matrix
        with one beyond ``liemef._validate.ON_GROUP`` (:func:`checked_matrix`). The base class has none."""
        return {}

    @classmethod
    def structure_constants(cls) -> Float[Array, "n n n"]:
        r"""$C[m, j, i] = (\mathrm{ad}_{e_j} e_i)_m$, constant for a given group."""
        return _structure_constants(cls)

    def __getitem__(self, index) -> Self:
        """Index the batch axes."""
        return jax.tree_util.tree_map(lambda leaf: leaf[index], self)


@functools.partial(jax.jit, static_argnums=0)
def _structure_constants(cls: type[LieGroup]) -> Array:
    """:meth:`LieGroup.structure_constants`, compiled as one program per group (every filter's connection needs
    them): eagerly, JAX compiled each operation of ``ad`` alone, 1.1 s for SE_2(3) in a new process, 0.4 s
    compiled."""
    return jnp.moveaxis(cls.ad(jnp.eye(cls.tangent_dim)), 0, 1)


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


def checked_matrix(cls: type[LieGroup], M: ArrayLike, name: str = "M") -> Array:
    """``M`` as a float64 JAX array of shape ``(..., m, m)``, for ``cls.from_matrix``: when its values are
    concrete, finite and within ``liemef._validate.ON_GROUP`` of the group by every one of
    ``cls.matrix_defects`` (a ValueError naming ``name``, the defect, its size and the batch index otherwise).
    Under tracing (``jit``, ``vmap``, ``grad``) it is converted only: a traced value cannot be inspected."""
    from .. import _validate

    if isinstance(M, jax.core.Tracer):
        return as_float_array(M)
    M = as_float_array(M)
    if isinstance(M, jax.core.Tracer):  # a list of tracers
        return M
    m = cls.matrix_dim
    if M.shape[-2:] != (m, m):
        raise ValueError(f"{name}: expected {cls.__name__} matrices of shape (..., {m}, {m}), got shape {M.shape}")
    a = _validate.array(name, np.asarray(M))
    for defect, size in cls.matrix_defects(a).items():
        size = np.broadcast_to(np.asarray(size, dtype=np.float64), a.shape[:-2])
        bad = ~(size <= _validate.ON_GROUP)
        if np.any(bad):
            at = tuple(int(i) for i in np.argwhere(bad)[0])
            where = f" at batch index {at}" if at else ""
            raise ValueError(f"{name}: expected a matrix of {cls.__name__} within {_validate.ON_GROUP:g} of the "
                             f"group, got {defect} = {float(size[at]):.6g}{where}")
    return M


def rotation_defects(R: np.ndarray) -> dict[str, np.ndarray]:
    """The defects of rotation blocks ``R`` (..., k, k) (NumPy): orthogonality ``max |R^T R - I|`` and
    determinant ``|det R - 1|`` (a reflection is orthogonal with determinant -1)."""
    eye = np.eye(R.shape[-1])
    return {"orthogonality max|R^T R - I|": np.abs(np.swapaxes(R, -1, -2) @ R - eye).max(axis=(-2, -1)),
            "determinant |det R - 1|": np.abs(np.linalg.det(R) - 1.0)}


def bottom_rows_defect(M: np.ndarray, k: int) -> dict[str, np.ndarray]:
    """The defect of homogeneous matrices ``M`` (..., m, m) whose last ``k`` rows must be ``[0, I_k]``: their
    largest entry away from it."""
    m = M.shape[-1]
    want = np.concatenate([np.zeros((k, m - k)), np.eye(k)], axis=-1)
    what = f"bottom row max|M[{m - 1}] - [0, 1]|" if k == 1 else f"bottom rows max|M[{m - k}:] - [0, I]|"
    return {what: np.abs(M[..., m - k :, :] - want).max(axis=(-2, -1))}


def unit_distance(v) -> float:
    """``max | |v| - 1 |`` over the last axis of ``v`` (NumPy, not traced): how far a stored unit vector is."""
    v = np.asarray(v, dtype=np.float64)
    return float(np.max(np.abs(np.linalg.norm(v, axis=-1) - 1.0), initial=0.0))
