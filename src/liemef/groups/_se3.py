from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from ._sek3 import SEK3, register


@register
class SE3(SEK3):
    r"""Rigid motions in space, SE(3) = ``SEK3[1]``: rotation R (body to world) and translation p (world frame).

    se(3) = $(\omega, v)$: the rotation rate first, as se(2) = $(\omega, v_x, v_y)$; $\hat\xi =
    \begin{bmatrix} {[\omega]_\times} & v \\ 0 & 0\end{bmatrix}$ and the matrix is ``[[R, p], [0, 1]]``.
    Stored as ``(w, x, y, z, px, py, pz)``; coordinates are the rotation vector and p. A body twist
    $(\omega, v)$ held for a time $t$ moves the pose to $g \exp(t\,(\omega, v))$.
    """

    K: ClassVar[int] = 1
    tangent_dim: ClassVar[int] = 6
    matrix_dim: ClassVar[int] = 4
    coords_dim: ClassVar[int] = 6

    @classmethod
    def from_rotation_translation(cls, rotation, p):
        """From an :class:`SO3` and a translation ``p`` (..., 3), broadcast together."""
        return cls.from_rotation_vectors(rotation, jnp.asarray(p, dtype=jnp.float64)[..., None, :])

    def translation(self):
        """The translation p (world frame), shape ``(..., 3)``."""
        return self.wxyz_p[..., 4:7]
