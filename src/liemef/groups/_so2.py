from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from .._linalg import mv
from ._base import LieGroup, as_float_array, checked_matrix, rotation_defects, unit_distance


class SO2(LieGroup):
    """Planar rotations, stored as the unit complex number ``(cos theta, sin theta)``; so(2) = (omega,)."""

    cos_sin: jnp.ndarray

    tangent_dim: ClassVar[int] = 1
    matrix_dim: ClassVar[int] = 2
    coords_dim: ClassVar[int] = 1

    def __init__(self, cos_sin):
        self.cos_sin = as_float_array(cos_sin)

    def defects(self) -> dict[str, float]:
        """The norm of ``(cos, sin)``, ``| |v| - 1 |`` (the largest over the batch)."""
        return {"norm | |(cos, sin)| - 1 |": unit_distance(self.cos_sin)}

    @classmethod
    def matrix_defects(cls, M):
        """Orthogonality and determinant of the 2 x 2 matrix."""
        return rotation_defects(M)

    @classmethod
    def identity(cls, batch_shape=()):
        """The rotation by 0, ``(1, 0)``."""
        return cls(jnp.broadcast_to(jnp.array([1.0, 0.0]), (*batch_shape, 2)))

    @classmethod
    def from_angle(cls, theta):
        """Rotation by ``theta`` (rad)."""
        theta = as_float_array(theta)
        return cls(jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1))

    @classmethod
    def exp(cls, xi):
        r"""Rotation by the angle $\omega$ = ``xi[..., 0]``."""
        return cls.from_angle(as_float_array(xi)[..., 0])

    @classmethod
    def from_matrix(cls, M):
        """From a 2 x 2 rotation matrix (its first column), checked (:func:`~liemef.groups._base.checked_matrix`):
        orthogonal and of determinant 1 within ``liemef._validate.ON_GROUP``."""
        M = checked_matrix(cls, M)
        return cls(M[..., :, 0])

    @classmethod
    def from_coords(cls, q):
        """From ``(theta,)``."""
        return cls.exp(q)

    def angle(self):
        """Rotation angle in (-pi, pi]."""
        return jnp.arctan2(self.cos_sin[..., 1], self.cos_sin[..., 0])

    def compose(self, other):
        """Product of unit complex numbers (angles add)."""
        c1, s1 = self.cos_sin[..., 0], self.cos_sin[..., 1]
        c2, s2 = other.cos_sin[..., 0], other.cos_sin[..., 1]
        return SO2(jnp.stack([c1 * c2 - s1 * s2, s1 * c2 + c1 * s2], axis=-1))

    def inverse(self):
        """Complex conjugate (the opposite angle)."""
        return SO2(self.cos_sin * jnp.array([1.0, -1.0]))

    def log(self):
        """``(theta,)`` with theta in (-pi, pi]."""
        return self.angle()[..., None]

    def coords(self):
        """``(theta,)`` with theta in (-pi, pi], the same as :meth:`log`."""
        return self.log()

    def as_matrix(self):
        """The 2 x 2 rotation matrix ``[[c, -s], [s, c]]``."""
        c, s = self.cos_sin[..., 0], self.cos_sin[..., 1]
        return jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)

    def act(self, p):
        """Rotate planar vectors ``p`` (``R @ p``)."""
        return mv(self.as_matrix(), as_float_array(p))

    def Ad(self):
        """The 1 x 1 identity: SO(2) is abelian."""
        return jnp.ones((*self.batch_shape, 1, 1))

    @classmethod
    def hat(cls, xi):
        """``omega`` to the skew matrix ``[[0, -omega], [omega, 0]]``."""
        w = as_float_array(xi)[..., 0]
        z = jnp.zeros_like(w)
        return jnp.stack([jnp.stack([z, -w], -1), jnp.stack([w, z], -1)], -2)

    @classmethod
    def vee(cls, X):
        """The ``[1, 0]`` entry of a 2 x 2 skew matrix."""
        return as_float_array(X)[..., 1, 0:1]

    @classmethod
    def ad(cls, xi):
        """The 1 x 1 zero matrix: so(2) is abelian."""
        return jnp.zeros((*jnp.shape(xi)[:-1], 1, 1))
