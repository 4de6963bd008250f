from __future__ import annotations

import functools
import numbers
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ._base import LieGroup, as_float_array, bottom_rows_defect, checked_matrix


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
            raise ValueError(f"{type(self).__name__}: expected x of shape (..., {self.tangent_dim}), "
                             f"got {x.shape}")
        self.x = x

    @classmethod
    def __class_getitem__(cls, n: int) -> type[Rn]:
        # Validated before the cache: True == 1 and 2.0 == 2 would otherwise hit the cached R1 and R2.
        # bool is rejected (an int subclass); numpy integers are accepted as the ints they are.
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
            raise ValueError(f"Rn[n]: expected a positive integer dimension n, got {n!r}")
        return _rn_type(int(n))

    @classmethod
    def identity(cls, batch_shape=()):
        """The zero vector."""
        return cls(jnp.zeros((*batch_shape, cls.tangent_dim)))

    @classmethod
    def exp(cls, xi):
        """The vector itself: the exponential of an additive group is the identity map."""
        return cls(xi)

    @classmethod
    def matrix_defects(cls, M):
        """The identity block ``I`` and the bottom row ``(0, 1)`` of ``[[I, x], [0, 1]]``."""
        n = cls.tangent_dim
        return {f"identity block max|M[:{n}, :{n}] - I|": np.abs(M[..., :n, :n] - np.eye(n)).max(axis=(-2, -1)),
                **bottom_rows_defect(M, 1)}

    @classmethod
    def from_matrix(cls, M):
        """From the translation column of ``[[I, x], [0, 1]]``, checked
        (:func:`~liemef.groups._base.checked_matrix`): the identity block and the bottom row within
        ``liemef._validate.ON_GROUP``."""
        return cls(checked_matrix(cls, M)[..., :-1, -1])

    @classmethod
    def from_coords(cls, q):
        """From the vector ``x``."""
        return cls(q)

    def compose(self, other):
        """Vector sum."""
        return type(self)(self.x + other.x)

    def inverse(self):
        """Negated vector."""
        return type(self)(-self.x)

    def log(self):
        """The vector ``x``."""
        return self.x

    def coords(self):
        """The vector ``x``."""
        return self.x

    def as_matrix(self):
        """The translation matrix ``[[I, x], [0, 1]]``."""
        return self.hat(self.x) + jnp.eye(self.matrix_dim)

    def Ad(self):
        """The n x n identity: R^n is abelian."""
        n = self.tangent_dim
        return jnp.broadcast_to(jnp.eye(n), (*self.batch_shape, n, n))

    @classmethod
    def hat(cls, xi):
        """``x`` to the matrix ``[[0, x], [0, 0]]``."""
        xi = as_float_array(xi)
        n = cls.tangent_dim
        M = jnp.zeros((*xi.shape[:-1], n + 1, n + 1))
        return M.at[..., :n, n].set(xi)

    @classmethod
    def vee(cls, X):
        """The translation column of ``[[0, x], [0, 0]]``."""
        return as_float_array(X)[..., :-1, -1]

    @classmethod
    def ad(cls, xi):
        """The n x n zero matrix: the algebra is abelian."""
        n = cls.tangent_dim
        return jnp.zeros((*jnp.shape(xi)[:-1], n, n))


@functools.cache
def _rn_type(n: int) -> type[Rn]:
    # Always a direct subclass of Rn (``R3[2]`` is R2, not a subclass of R3), one class per n.
    return type(Rn)(f"R{n}", (Rn,), {"tangent_dim": n, "matrix_dim": n + 1, "coords_dim": n,
                                     "__module__": Rn.__module__, "__qualname__": f"R{n}"})


R1, R2, R3 = Rn[1], Rn[2], Rn[3]
