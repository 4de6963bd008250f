from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from .._linalg import mv
from ._base import LieGroup, as_float_array, checked_matrix, rotation_defects, unit_distance

# Below this squared angle, exp/log use Taylor series: the values and their first and second derivatives stay
# finite and accurate at exactly 0 (the engine differentiates exp twice at 0).
_TAYLOR_SQ = 1e-4


def _skew(w):
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2)


def quaternion_of_matrix(M):
    """The quaternion of rotation matrices ``M`` (..., 3, 3) (Shepperd's method), unchecked."""
    # Shepperd's method: pick the numerically largest of the four candidate quaternion components.
    m00, m01, m02 = M[..., 0, 0], M[..., 0, 1], M[..., 0, 2]
    m10, m11, m12 = M[..., 1, 0], M[..., 1, 1], M[..., 1, 2]
    m20, m21, m22 = M[..., 2, 0], M[..., 2, 1], M[..., 2, 2]
    t = jnp.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22],
                  -1)
    cands = jnp.stack([
        jnp.stack([t[..., 0], m21 - m12, m02 - m20, m10 - m01], -1),
        jnp.stack([m21 - m12, t[..., 1], m10 + m01, m02 + m20], -1),
        jnp.stack([m02 - m20, m10 + m01, t[..., 2], m21 + m12], -1),
        jnp.stack([m10 - m01, m02 + m20, m21 + m12, t[..., 3]], -1),
    ], -2)
    k = jnp.argmax(t, axis=-1)
    q = jnp.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    tk = jnp.take_along_axis(t, k[..., None], axis=-1)
    return q * 0.5 / jnp.sqrt(tk)


class SO3(LieGroup):
    """Rotations in space, stored as a unit quaternion ``(w, x, y, z)``; so(3) = (w_x, w_y, w_z).

    The quaternion is an implementation detail: :meth:`as_matrix` / :meth:`from_matrix` are the papers'
    rotation matrices R (body to world), and every operation agrees with the matrix group.
    """

    wxyz: jnp.ndarray

    tangent_dim: ClassVar[int] = 3
    matrix_dim: ClassVar[int] = 3
    coords_dim: ClassVar[int] = 3

    def __init__(self, wxyz):
        self.wxyz = as_float_array(wxyz)

    def defects(self) -> dict[str, float]:
        """The quaternion's norm, ``| |q| - 1 |`` (the largest over the batch)."""
        return {"quaternion norm | |q| - 1 |": unit_distance(self.wxyz)}

    @classmethod
    def matrix_defects(cls, M):
        """Orthogonality and determinant of the 3 x 3 matrix."""
        return rotation_defects(M)

    @classmethod
    def identity(cls, batch_shape=()):
        """The quaternion ``(1, 0, 0, 0)``."""
        return cls(jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0, 0.0]), (*batch_shape, 4)))

    @classmethod
    def exp(cls, xi):
        """Rodrigues' formula as a quaternion, with a Taylor branch for small angles."""
        w = as_float_array(xi)
        theta_sq = jnp.sum(w**2, axis=-1)
        small = theta_sq < _TAYLOR_SQ
        theta = jnp.sqrt(jnp.where(small, 1.0, theta_sq))  # double-where: no NaN in the unused branch
        real = jnp.where(small, 1.0 - theta_sq / 8.0 + theta_sq**2 / 384.0 - theta_sq**3 / 46080.0,
                         jnp.cos(theta / 2.0))
        imag = jnp.where(small, 0.5 - theta_sq / 48.0 + theta_sq**2 / 3840.0 - theta_sq**3 / 645120.0,
                         jnp.sin(theta / 2.0) / theta)
        return cls(jnp.concatenate([real[..., None], imag[..., None] * w], axis=-1))

    @classmethod
    def from_matrix(cls, M):
        """From a 3 x 3 rotation matrix (Shepperd's method), checked
        (:func:`~liemef.groups._base.checked_matrix`): orthogonal and of determinant 1 within
        ``liemef._validate.ON_GROUP`` (a shear, 2 I or a reflection is refused, not turned into a quaternion
        that is not a unit one)."""
        return cls(quaternion_of_matrix(checked_matrix(cls, M)))

    @classmethod
    def from_coords(cls, q):
        """From a rotation vector (axis times angle), the same as :meth:`exp`."""
        return cls.exp(q)

    @classmethod
    def from_rpy(cls, roll, pitch, yaw):
        r"""From roll, pitch and yaw (rad): $R = R_z(\mathrm{yaw})\,R_y(\mathrm{pitch})\,R_x(\mathrm{roll})$ (body to
        world; the aerospace z-y-x convention, jaxlie's ``from_rpy_radians``). The three broadcast to a batch;
        the quaternion is the product of the three axis quaternions, exact and differentiable everywhere."""
        r, p, y = (as_float_array(a) / 2.0 for a in (roll, pitch, yaw))
        r, p, y = jnp.broadcast_arrays(r, p, y)
        cr, sr, cp, sp, cy, sy = jnp.cos(r), jnp.sin(r), jnp.cos(p), jnp.sin(p), jnp.cos(y), jnp.sin(y)
        return cls(jnp.stack([cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
                              cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr], axis=-1))

    def as_rpy(self):
        r"""Roll, pitch and yaw (rad), stacked on the last axis, of
        $R = R_z(\mathrm{yaw})\,R_y(\mathrm{pitch})\,R_x(\mathrm{roll})$ (:meth:`from_rpy`): roll and yaw in
        $[-\pi, \pi]$, pitch in $[-\pi/2, \pi/2]$. At pitch $\pm\pi/2$ (gimbal lock) only
        roll - yaw (or roll + yaw) is defined; the split returned there is arbitrary."""
        R = self.as_matrix()
        return jnp.stack([jnp.arctan2(R[..., 2, 1], R[..., 2, 2]), jnp.arcsin(jnp.clip(-R[..., 2, 0], -1.0, 1.0)),
                          jnp.arctan2(R[..., 1, 0], R[..., 0, 0])], axis=-1)

    def compose(self, other):
        """Quaternion product (rotation matrices multiply)."""
        w1, v1 = self.wxyz[..., :1], self.wxyz[..., 1:]
        w2, v2 = other.wxyz[..., :1], other.wxyz[..., 1:]
        w = w1 * w2 - jnp.sum(v1 * v2, axis=-1, keepdims=True)
        v = w1 * v2 + w2 * v1 + jnp.cross(v1, v2)
        return SO3(jnp.concatenate([w, v], axis=-1))

    def inverse(self):
        """Conjugate quaternion (the transposed rotation matrix)."""
        return SO3(self.wxyz * jnp.array([1.0, -1.0, -1.0, -1.0]))

    def log(self):
        """Rotation vector of angle in [0, pi], finite with finite derivatives at 0 and at pi."""
        # jaxlie's formulation: the shorter of the two rotations the quaternion pair represents, finite
        # derivatives at 0 (Taylor) and at pi (w -> 0).
        w, v = self.wxyz[..., 0], self.wxyz[..., 1:]
        n_sq = jnp.sum(v**2, axis=-1)
        small = n_sq < _TAYLOR_SQ / 4.0
        n = jnp.sqrt(jnp.where(small, 1.0, n_sq))
        w_safe = jnp.where(small, w, 1.0)
        # 2 atan(x) / (x w) with x^2 = n^2 / w^2 <= 2.5e-5: the series needs the x^4 and x^6 terms; with only
        # 1 - x^2/3 the truncation (2/5) x^4 is a relative error of 1e-10 at the threshold
        # (tests/test_groups.py::test_log_exp_round_trip_near_identity).
        x_sq = n_sq / w_safe**2
        factor = jnp.where(
            small,
            2.0 / w_safe * (1.0 - x_sq / 3.0 + x_sq**2 / 5.0 - x_sq**3 / 7.0),
            jnp.where(jnp.abs(w) < 1e-12, jnp.where(w > 0, 1.0, -1.0) * jnp.pi / n,
                      2.0 * jnp.arctan2(jnp.where(w < 0, -n, n), jnp.abs(w)) / n),
        )
        return factor[..., None] * v

    def coords(self):
        """Rotation vector (axis times angle, the principal :meth:`log`)."""
        return self.log()

    def as_matrix(self):
        """The 3 x 3 rotation matrix R (body to world)."""
        w, x, y, z = (self.wxyz[..., i] for i in range(4))
        return jnp.stack([
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ], -2)

    def act(self, p):
        """Rotate vectors ``p`` (``R @ p``)."""
        return mv(self.as_matrix(), as_float_array(p))

    def Ad(self):
        """The rotation matrix R itself."""
        return self.as_matrix()

    @classmethod
    def hat(cls, xi):
        """The skew matrix ``[w]_x`` with ``[w]_x p = w x p``."""
        return _skew(as_float_array(xi))

    @classmethod
    def vee(cls, X):
        """Inverse of :meth:`hat`: ``(X[2, 1], X[0, 2], X[1, 0])``."""
        X = as_float_array(X)
        return jnp.stack([X[..., 2, 1], X[..., 0, 2], X[..., 1, 0]], -1)

    @classmethod
    def ad(cls, xi):
        """The skew matrix ``[w]_x`` (so(3) is the cross product)."""
        return _skew(as_float_array(xi))
