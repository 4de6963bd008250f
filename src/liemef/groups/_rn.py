from __future__ import annotations

import functools
from typing import ClassVar

import jax.numpy as jnp

from ._base import LieGroup, as_float_array


class Rn(LieGroup):
    """The vector space R^n as an additive Lie group (velocities, biases). ``Rn[3]`` is R^3.

    Its matrix representation is the translation group, ``[[I, x], [0, 1]]``; the algebra is abelian.
    """

    x: jnp.ndarray

    tangent_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    coords_dim: ClassVar[int]

    def __init__(self, x):
        x = as_float_array(x)
        if x.shape[-1:] != (self.tangent_dim,):
            raise ValueError(f"{type(self).__name__}: expected x of shape (..., {self.tangent_dim}), got {x.shape}")
        self.x = x

    @classmethod
    @functools.cache
    def __class_getitem__(cls, n: int) -> type[Rn]:
        if not isinstance(n, int) or n < 1:
            raise ValueError(f"Rn[n]: expected a positive integer dimension n, got {n!r}")
        return type(cls)(f"R{n}", (cls,), {"tangent_dim": n, "matrix_dim": n + 1, "coords_dim": n,
                                       "__module__": cls.__module__, "__qualname__": f"R{n}"})

    @classmethod
    def identity(cls, batch_shape=()):
        return cls(jnp.zeros((*batch_shape, cls.tangent_dim)))

    @classmethod
    def exp(cls, xi):
        return cls(xi)

    @classmethod
    def from_matrix(cls, M):
        return cls(as_float_array(M)[..., :-1, -1])

    @classmethod
    def from_coords(cls, q):
        return cls(q)

    def compose(self, other):
        return type(self)(self.x + other.x)

    def inverse(self):
        return type(self)(-self.x)

    def log(self):
        return self.x

    def coords(self):
        return self.x

    def as_matrix(self):
        return self.hat(self.x) + jnp.eye(self.matrix_dim)

    def Ad(self):
        return jnp.broadcast_to(jnp.eye(self.tangent_dim), (*self.batch_shape, self.tangent_dim, self.tangent_dim))

    @classmethod
    def hat(cls, xi):
        xi = as_float_array(xi)
        n = cls.tangent_dim
        M = jnp.zeros((*xi.shape[:-1], n + 1, n + 1))
        return M.at[..., :n, n].set(xi)

    @classmethod
    def vee(cls, X):
        return as_float_array(X)[..., :-1, -1]

    @classmethod
    def ad(cls, xi):
        n = cls.tangent_dim
        return jnp.zeros((*jnp.shape(xi)[:-1], n, n))


R1, R2, R3 = Rn[1], Rn[2], Rn[3]
