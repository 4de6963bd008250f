from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from .._linalg import mv
from ._base import LieGroup, as_float_array


class SO2(LieGroup):
    """Planar rotations, stored as the unit complex number ``(cos theta, sin theta)``; so(2) = (omega,)."""

    cos_sin: jnp.ndarray

    tangent_dim: ClassVar[int] = 1
    matrix_dim: ClassVar[int] = 2
    coords_dim: ClassVar[int] = 1

    def __init__(self, cos_sin):
        self.cos_sin = as_float_array(cos_sin)

    @classmethod
    def identity(cls, batch_shape=()):
        return cls(jnp.broadcast_to(jnp.array([1.0, 0.0]), (*batch_shape, 2)))

    @classmethod
    def from_angle(cls, theta):
        theta = as_float_array(theta)
        return cls(jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1))

    @classmethod
    def exp(cls, xi):
        return cls.from_angle(as_float_array(xi)[..., 0])

    @classmethod
    def from_matrix(cls, M):
        M = as_float_array(M)
        return cls(M[..., :, 0])

    @classmethod
    def from_coords(cls, q):
        return cls.exp(q)

    def angle(self):
        """Rotation angle in (-pi, pi]."""
        return jnp.arctan2(self.cos_sin[..., 1], self.cos_sin[..., 0])

    def compose(self, other):
        c1, s1 = self.cos_sin[..., 0], self.cos_sin[..., 1]
        c2, s2 = other.cos_sin[..., 0], other.cos_sin[..., 1]
        return SO2(jnp.stack([c1 * c2 - s1 * s2, s1 * c2 + c1 * s2], axis=-1))

    def inverse(self):
        return SO2(self.cos_sin * jnp.array([1.0, -1.0]))

    def log(self):
        return self.angle()[..., None]

    def coords(self):
        return self.log()

    def as_matrix(self):
        c, s = self.cos_sin[..., 0], self.cos_sin[..., 1]
        return jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)

    def act(self, p):
        """Rotate planar vectors ``p`` (``R @ p``)."""
        return mv(self.as_matrix(), as_float_array(p))

    def Ad(self):
        return jnp.ones((*self.batch_shape, 1, 1))

    @classmethod
    def hat(cls, xi):
        w = as_float_array(xi)[..., 0]
        z = jnp.zeros_like(w)
        return jnp.stack([jnp.stack([z, -w], -1), jnp.stack([w, z], -1)], -2)

    @classmethod
    def vee(cls, X):
        return as_float_array(X)[..., 1, 0:1]

    @classmethod
    def ad(cls, xi):
        return jnp.zeros((*jnp.shape(xi)[:-1], 1, 1))
