from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from ._base import LieGroup, as_float_array, bottom_rows_defect, checked_matrix, rotation_defects, unit_distance
from ._so2 import SO2

_TAYLOR = 1e-2  # |omega| below which exp/log use Taylor series (see _so3._TAYLOR_SQ)


class SE2(LieGroup):
    """Planar rigid motions ``(R, p)``, stored as ``(cos theta, sin theta, x, y)``; se(2) = (omega, v_x, v_y).

    The algebra's first coordinate is the rotation rate, as in the papers (Rigo et al. 2022, eq. 9).
    """

    cos_sin_xy: jnp.ndarray

    tangent_dim: ClassVar[int] = 3
    matrix_dim: ClassVar[int] = 3
    coords_dim: ClassVar[int] = 3

    def __init__(self, cos_sin_xy):
        self.cos_sin_xy = as_float_array(cos_sin_xy)

    def defects(self) -> dict[str, float]:
        """The norm of ``(cos, sin)``, ``| |v| - 1 |`` (the largest over the batch)."""
        return {"norm | |(cos, sin)| - 1 |": unit_distance(self.cos_sin_xy[..., :2])}

    @classmethod
    def matrix_defects(cls, M):
        """Orthogonality and determinant of the rotation block, and the bottom row ``(0, 0, 1)``."""
        return {**rotation_defects(M[..., :2, :2]), **bottom_rows_defect(M, 1)}

    @classmethod
    def identity(cls, batch_shape=()):
        """The pose at the origin with heading 0."""
        return cls(jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0, 0.0]), (*batch_shape, 4)))

    @classmethod
    def from_rotation_translation(cls, rotation: SO2, p):
        """From a rotation ``R`` and a translation ``p`` (world frame), broadcast together."""
        rot, p = rotation.cos_sin, as_float_array(p)
        rot, p = jnp.broadcast_arrays(rot, p)
        return cls(jnp.concatenate([rot, p], axis=-1))

    @classmethod
    def from_coords(cls, q):
        """From ``(theta, x, y)``."""
        q = as_float_array(q)
        return cls.from_rotation_translation(SO2.from_angle(q[..., 0]), q[..., 1:3])

    @classmethod
    def exp(cls, xi):
        r"""$\exp$ of $(\omega, v_x, v_y)$: rotation by $\omega$, translation $V(\omega) v$ (Taylor branch near 0)."""
        xi = as_float_array(xi)
        w, v = xi[..., 0], xi[..., 1:3]
        small = jnp.abs(w) < _TAYLOR
        w_safe = jnp.where(small, 1.0, w)
        w2 = w * w
        a = jnp.where(small, 1.0 - w2 / 6.0 + w2**2 / 120.0 - w2**3 / 5040.0, jnp.sin(w_safe) / w_safe)
        # 1 - cos(w) = 2 sin^2(w/2): the direct difference cancels (relative error ~1e-16 / w^2 just above the
        # threshold, 2e-13 at w = 1e-2).
        b = jnp.where(small, w / 2.0 - w * w2 / 24.0 + w * w2**2 / 720.0 - w * w2**3 / 40320.0,
                      2.0 * jnp.sin(w_safe / 2.0) ** 2 / w_safe)
        p = jnp.stack([a * v[..., 0] - b * v[..., 1], b * v[..., 0] + a * v[..., 1]], -1)
        return cls.from_rotation_translation(SO2.from_angle(w), p)

    @classmethod
    def from_matrix(cls, M):
        """From the homogeneous 3 x 3 matrix ``[[R, p], [0, 1]]``, checked
        (:func:`~liemef.groups._base.checked_matrix`): R a rotation and the bottom row ``(0, 0, 1)`` within
        ``liemef._validate.ON_GROUP``."""
        M = checked_matrix(cls, M)
        return cls.from_rotation_translation(SO2(M[..., :2, 0]), M[..., :2, 2])

    def rotation(self) -> SO2:
        """The rotation part R, an :class:`SO2`."""
        return SO2(self.cos_sin_xy[..., :2])

    def translation(self):
        """The translation part ``(x, y)`` (world frame)."""
        return self.cos_sin_xy[..., 2:4]

    def compose(self, other):
        """``(R1 R2, R1 p2 + p1)``."""
        rot = self.rotation()
        p = rot.act(other.translation()) + self.translation()
        return SE2.from_rotation_translation(rot @ other.rotation(), p)

    def inverse(self):
        """``(R^T, -R^T p)``."""
        rot_inv = self.rotation().inverse()
        return SE2.from_rotation_translation(rot_inv, -rot_inv.act(self.translation()))

    def log(self):
        r"""$(\theta, V(\theta)^{-1} p)$ with $\theta$ in (-pi, pi] (Taylor branch near 0)."""
        theta = self.rotation().angle()
        small = jnp.abs(theta) < _TAYLOR
        t_safe = jnp.where(small, 1.0, theta)
        t2 = theta * theta
        # V(theta)^{-1} = [[A, B], [-B, A]] with A = (theta/2) cot(theta/2), B = theta/2
        # Half-angle form: sin(t) / (1 - cos(t)) cancels (relative error ~1e-16 / t^2 above the threshold).
        A = jnp.where(small, 1.0 - t2 / 12.0 - t2**2 / 720.0 - t2**3 / 30240.0,
                      0.5 * t_safe * jnp.cos(t_safe / 2.0) / jnp.sin(t_safe / 2.0))
        B = theta / 2.0
        p = self.translation()
        v = jnp.stack([A * p[..., 0] + B * p[..., 1], -B * p[..., 0] + A * p[..., 1]], -1)
        return jnp.concatenate([theta[..., None], v], axis=-1)

    def coords(self):
        """``(theta, x, y)`` with theta in (-pi, pi]."""
        return jnp.concatenate([self.rotation().log(), self.translation()], axis=-1)

    def as_matrix(self):
        """The homogeneous 3 x 3 matrix ``[[R, p], [0, 1]]``."""
        Rm = self.rotation().as_matrix()
        p = self.translation()
        top = jnp.concatenate([Rm, p[..., :, None]], axis=-1)
        bottom = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (*top.shape[:-2], 1, 3))
        return jnp.concatenate([top, bottom], axis=-2)

    def act(self, p):
        """Transform planar points ``p`` (``R @ p + t``)."""
        return self.rotation().act(p) + self.translation()

    def Ad(self):
        """``[[1, 0], [(y, -x), R]]`` in the order (omega, v_x, v_y)."""
        c, s, x, y = (self.cos_sin_xy[..., i] for i in range(4))
        o, one = jnp.zeros_like(c), jnp.ones_like(c)
        rows = [jnp.stack([one, o, o], -1), jnp.stack([y, c, -s], -1), jnp.stack([-x, s, c], -1)]
        return jnp.stack(rows, -2)

    @classmethod
    def hat(cls, xi):
        """``(omega, v_x, v_y)`` to ``[[0, -omega, v_x], [omega, 0, v_y], [0, 0, 0]]``."""
        xi = as_float_array(xi)
        w, vx, vy = xi[..., 0], xi[..., 1], xi[..., 2]
        o = jnp.zeros_like(w)
        rows = [jnp.stack([o, -w, vx], -1), jnp.stack([w, o, vy], -1), jnp.stack([o, o, o], -1)]
        return jnp.stack(rows, -2)

    @classmethod
    def vee(cls, X):
        """Inverse of :meth:`hat`: ``(X[1, 0], X[0, 2], X[1, 2])``."""
        X = as_float_array(X)
        return jnp.stack([X[..., 1, 0], X[..., 0, 2], X[..., 1, 2]], -1)

    @classmethod
    def ad(cls, xi):
        """``[[0, 0, 0], [v_y, 0, -omega], [-v_x, omega, 0]]`` (Rigo et al. 2022, eq. 33)."""
        # Rigo et al. 2022, eq. (33)
        xi = as_float_array(xi)
        w, vx, vy = xi[..., 0], xi[..., 1], xi[..., 2]
        o = jnp.zeros_like(w)
        rows = [jnp.stack([o, o, o], -1), jnp.stack([vy, o, -w], -1), jnp.stack([-vx, w, o], -1)]
        return jnp.stack(rows, -2)
