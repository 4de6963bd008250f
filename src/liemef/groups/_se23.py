from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from ._sek3 import SEK3, register


@register
class SE23(SEK3):
    r"""Extended poses, $SE_2(3)$ = ``SEK3[2]``: attitude R (body to world), velocity v and position p (world
    frame), the state of inertial navigation (Barrau & Bonnabel 2017).

    se_2(3) = $(\omega, \nu_v, \nu_p)$, the rotation first: $\hat\xi = \begin{bmatrix} {[\omega]_\times} & \nu_v &
    \nu_p \\ 0 & 0 & 0\end{bmatrix}$; the matrix is ``[[R, v, p], [0, 1, 0], [0, 0, 1]]``. Stored as
    ``(w, x, y, z, vx, vy, vz, px, py, pz)``; coordinates are the rotation vector, v, p.
    """

    K: ClassVar[int] = 2
    tangent_dim: ClassVar[int] = 9
    matrix_dim: ClassVar[int] = 5
    coords_dim: ClassVar[int] = 9

    @classmethod
    def from_rotation_velocity_position(cls, rotation, v, p):
        """From an :class:`SO3`, a velocity ``v`` and a position ``p`` (..., 3), broadcast together."""
        v, p = jnp.broadcast_arrays(jnp.asarray(v, dtype=jnp.float64), jnp.asarray(p, dtype=jnp.float64))
        return cls.from_rotation_vectors(rotation, jnp.stack([v, p], axis=-2))

    def velocity(self):
        """The velocity v (world frame), shape ``(..., 3)``."""
        return self.wxyz_p[..., 4:7]

    def position(self):
        """The position p (world frame), shape ``(..., 3)``."""
        return self.wxyz_p[..., 7:10]
