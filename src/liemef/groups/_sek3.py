from __future__ import annotations

import functools
import numbers
from typing import ClassVar

import jax.numpy as jnp

from ._base import LieGroup, as_float_array, bottom_rows_defect, checked_matrix, rotation_defects, unit_distance
from ._so3 import SO3, _skew, quaternion_of_matrix

# Below this squared angle the SO(3) Jacobian coefficients use Taylor series (functions of theta^2 only): values
# and first and second derivatives stay finite and accurate at 0. Truncation at the threshold: < 1e-22.
_TAYLOR_SQ = 1e-4


def _theta(w):
    """``(theta^2, small, theta)`` of rotation vectors, with a safe ``theta`` (1) in the Taylor branch."""
    theta_sq = jnp.sum(w * w, axis=-1)
    small = theta_sq < _TAYLOR_SQ
    return theta_sq, small, jnp.sqrt(jnp.where(small, 1.0, theta_sq))  # double-where: no NaN gradient at 0


def left_jacobian_coefficients(w):
    r"""$(a, b)$ with the SO(3) left Jacobian $J_l(w) = I + a [w]_\times + b [w]_\times^2$,
    $a = (1 - \cos\theta)/\theta^2$, $b = (\theta - \sin\theta)/\theta^3$ (Taylor branch near 0)."""
    t2, small, theta = _theta(w)
    ts = jnp.where(small, 1.0, t2)
    # 1 - cos = 2 sin^2(theta/2): the direct difference cancels near the threshold.
    a = jnp.where(small, 0.5 - t2 / 24.0 + t2**2 / 720.0 - t2**3 / 40320.0,
                  2.0 * jnp.sin(theta / 2.0) ** 2 / ts)
    b = jnp.where(small, 1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0 - t2**3 / 362880.0,
                  (theta - jnp.sin(theta)) / (ts * theta))
    return a, b


def inverse_left_jacobian_coefficient(w):
    r"""$c$ with $J_l(w)^{-1} = I - \tfrac12 [w]_\times + c [w]_\times^2$,
    $c = 1/\theta^2 - \cot(\theta/2) / (2\theta)$: finite up to and at $\theta = \pi$ (Taylor branch near 0)."""
    t2, small, theta = _theta(w)
    ts = jnp.where(small, 1.0, t2)
    return jnp.where(small, 1.0 / 12.0 + t2 / 720.0 + t2**2 / 30240.0 + t2**3 / 1209600.0,
                     1.0 / ts - jnp.cos(theta / 2.0) / (2.0 * theta * jnp.sin(theta / 2.0)))


def _cross(w, p):
    """``w x p`` with ``w`` (..., 3) broadcast against ``p`` (..., K, 3)."""
    return jnp.cross(w[..., None, :], p)


def left_jacobian_apply(w, p):
    r"""$J_l(w)\,p$ for rotation vectors ``w`` (..., 3) and vectors ``p`` (..., K, 3)."""
    a, b = left_jacobian_coefficients(w)
    wp = _cross(w, p)
    return p + a[..., None, None] * wp + b[..., None, None] * _cross(w, wp)


def inverse_left_jacobian_apply(w, p):
    r"""$J_l(w)^{-1} p$ for rotation vectors ``w`` (..., 3) and vectors ``p`` (..., K, 3)."""
    c = inverse_left_jacobian_coefficient(w)
    wp = _cross(w, p)
    return p - 0.5 * wp + c[..., None, None] * _cross(w, wp)


class SEK3(LieGroup):
    r"""$SE_K(3)$: a rotation and $K$ vectors, $\begin{bmatrix} R & p_1 & \cdots & p_K \\ 0 & I_K \end{bmatrix}$.

    ``SEK3[K]`` is the group for a given $K$ (static): ``SEK3[1]`` is :class:`SE3`, ``SEK3[2]`` is
    :class:`SE23`; larger $K$ holds e.g. landmarks in the state. The algebra order is the rotation first,
    $(\omega;\ \nu_1; \ldots; \nu_K)$, with $\hat\xi = \begin{bmatrix} {[\omega]_\times} & \nu_1 & \cdots & \nu_K
    \\ 0 & 0\end{bmatrix}$. An element is stored as the unit quaternion of $R$ and the $K$ vectors,
    ``(w, x, y, z, p_1, ..., p_K)``; coordinates are the rotation vector then the vectors (world frame).

    Closed forms: $\exp(\omega, \nu_k) = (\exp\omega,\ J_l(\omega)\nu_k)$ and $\log$ its inverse, with the SO(3)
    left Jacobian $J_l$ (Taylor branches near 0; finite at $\pi$);
    $\mathrm{Ad}_g = \begin{bmatrix} R & 0 \\ [p_k]_\times R & R \end{bmatrix}$ (block rows $k$),
    $\mathrm{ad}_\xi = \begin{bmatrix} {[\omega]_\times} & 0 \\ [\nu_k]_\times & [\omega]_\times \end{bmatrix}$.
    """

    wxyz_p: jnp.ndarray

    K: ClassVar[int]
    tangent_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    coords_dim: ClassVar[int]

    def __init__(self, wxyz_p):
        wxyz_p = as_float_array(wxyz_p)
        if wxyz_p.shape[-1:] != (4 + 3 * self.K,):
            raise ValueError(f"{type(self).__name__}: expected wxyz_p of shape (..., {4 + 3 * self.K}) (a unit "
                             f"quaternion and {self.K} vectors), got {wxyz_p.shape}")
        self.wxyz_p = wxyz_p

    @classmethod
    def __class_getitem__(cls, K: int) -> type[SEK3]:
        if isinstance(K, bool) or not isinstance(K, numbers.Integral) or K < 1:
            raise ValueError(f"SEK3[K]: expected a positive integer number of vectors K, got {K!r}")
        return _sek3_type(int(K))

    def defects(self) -> dict[str, float]:
        """The norm of the rotation's quaternion, ``| |q| - 1 |`` (the largest over the batch): the vectors are
        unconstrained."""
        return {"quaternion norm | |q| - 1 |": unit_distance(self.wxyz_p[..., :4])}

    @classmethod
    def matrix_defects(cls, M):
        """Orthogonality and determinant of the rotation block, and the bottom rows ``[0, I_K]``."""
        return {**rotation_defects(M[..., :3, :3]), **bottom_rows_defect(M, cls.K)}

    # --- parts ------------------------------------------------------------------------------------------------
    @classmethod
    def from_rotation_vectors(cls, rotation: SO3, vectors):
        """From an :class:`SO3` and the K vectors ``(..., K, 3)`` (world frame), broadcast together."""
        q = rotation.wxyz
        p = as_float_array(vectors)
        batch = jnp.broadcast_shapes(q.shape[:-1], p.shape[:-2])
        q = jnp.broadcast_to(q, (*batch, 4))
        p = jnp.broadcast_to(p, (*batch, cls.K, 3)).reshape(*batch, 3 * cls.K)
        return cls(jnp.concatenate([q, p], axis=-1))

    def rotation(self) -> SO3:
        """The rotation part R, an :class:`SO3`."""
        return SO3(self.wxyz_p[..., :4])

    def vectors(self):
        """The K vectors, shape ``(..., K, 3)`` (world frame)."""
        return self.wxyz_p[..., 4:].reshape(*self.wxyz_p.shape[:-1], self.K, 3)

    # --- LieGroup ---------------------------------------------------------------------------------------------
    @classmethod
    def identity(cls, batch_shape=()):
        """Identity rotation, zero vectors."""
        e = jnp.zeros(4 + 3 * cls.K).at[0].set(1.0)
        return cls(jnp.broadcast_to(e, (*batch_shape, 4 + 3 * cls.K)))

    @classmethod
    def exp(cls, xi):
        r"""$(\exp\omega,\ J_l(\omega)\,\nu_k)$ (Taylor branches near 0)."""
        xi = as_float_array(xi)
        w, nu = xi[..., :3], xi[..., 3:].reshape(*xi.shape[:-1], cls.K, 3)
        return cls.from_rotation_vectors(SO3.exp(w), left_jacobian_apply(w, nu))

    @classmethod
    def from_matrix(cls, M):
        """From the ``(3 + K) x (3 + K)`` matrix ``[[R, p_1 .. p_K], [0, I]]``, checked
        (:func:`~liemef.groups._base.checked_matrix`): R a rotation and the bottom rows ``[0, I]`` within
        ``liemef._validate.ON_GROUP``."""
        M = checked_matrix(cls, M)
        return cls.from_rotation_vectors(SO3(quaternion_of_matrix(M[..., :3, :3])),
                                         jnp.swapaxes(M[..., :3, 3:], -1, -2))

    @classmethod
    def from_coords(cls, q):
        """From the rotation vector and the K vectors."""
        q = as_float_array(q)
        return cls.from_rotation_vectors(SO3.exp(q[..., :3]), q[..., 3:].reshape(*q.shape[:-1], cls.K, 3))

    def compose(self, other):
        """``(R1 R2, R1 p2_k + p1_k)``."""
        rot = self.rotation()
        p = _rotate(rot, other.vectors()) + self.vectors()
        return type(self).from_rotation_vectors(rot @ other.rotation(), p)

    def inverse(self):
        """``(R^T, -R^T p_k)``."""
        rot_inv = self.rotation().inverse()
        return type(self).from_rotation_vectors(rot_inv, -_rotate(rot_inv, self.vectors()))

    def log(self):
        r"""$(\omega,\ J_l(\omega)^{-1} p_k)$ with $\omega = \log R$ of angle in $[0, \pi]$."""
        w = self.rotation().log()
        nu = inverse_left_jacobian_apply(w, self.vectors())
        return jnp.concatenate([w, nu.reshape(*nu.shape[:-2], 3 * self.K)], axis=-1)

    def coords(self):
        """The rotation vector (principal log of R), then the K vectors."""
        return jnp.concatenate([self.rotation().log(), self.wxyz_p[..., 4:]], axis=-1)

    def as_matrix(self):
        """The ``(3 + K) x (3 + K)`` matrix ``[[R, p_1 .. p_K], [0, I]]``."""
        K = self.K
        Rm = self.rotation().as_matrix()
        top = jnp.concatenate([Rm, jnp.swapaxes(self.vectors(), -1, -2)], axis=-1)
        bottom = jnp.broadcast_to(jnp.concatenate([jnp.zeros((K, 3)), jnp.eye(K)], axis=-1),
                                  (*top.shape[:-2], K, 3 + K))
        return jnp.concatenate([top, bottom], axis=-2)

    def act(self, p):
        r"""Transform points ``p`` (..., 3) by the rotation and the first vector: $R p + p_1$ (a pose)."""
        return self.rotation().act(p) + self.vectors()[..., 0, :]

    def Ad(self):
        r"""$\begin{bmatrix} R & 0 \\ [p_k]_\times R & R \end{bmatrix}$ in the order $(\omega; \nu_k)$."""
        K = self.K
        Rm = self.rotation().as_matrix()
        pR = jnp.einsum("...kij,...jl->...kil", _skew(self.vectors()), Rm)  # (..., K, 3, 3)
        out = jnp.zeros((*Rm.shape[:-2], 3 + 3 * K, 3 + 3 * K))
        for k in range(K + 1):
            out = out.at[..., 3 * k : 3 * k + 3, 3 * k : 3 * k + 3].set(Rm)
        for k in range(K):
            out = out.at[..., 3 + 3 * k : 6 + 3 * k, 0:3].set(pR[..., k, :, :])
        return out

    @classmethod
    def hat(cls, xi):
        r"""$(\omega; \nu_k)$ to $\begin{bmatrix} {[\omega]_\times} & \nu_1 \cdots \nu_K \\ 0 & 0\end{bmatrix}$."""
        xi = as_float_array(xi)
        K = cls.K
        nu = xi[..., 3:].reshape(*xi.shape[:-1], K, 3)
        top = jnp.concatenate([_skew(xi[..., :3]), jnp.swapaxes(nu, -1, -2)], axis=-1)
        return jnp.concatenate([top, jnp.zeros((*xi.shape[:-1], K, 3 + K))], axis=-2)

    @classmethod
    def vee(cls, X):
        """Inverse of :meth:`hat`: ``(X[2, 1], X[0, 2], X[1, 0])``, then the columns ``X[:3, 3 + k]``."""
        X = as_float_array(X)
        w = jnp.stack([X[..., 2, 1], X[..., 0, 2], X[..., 1, 0]], -1)
        nu = jnp.swapaxes(X[..., :3, 3:], -1, -2).reshape(*X.shape[:-2], 3 * cls.K)
        return jnp.concatenate([w, nu], axis=-1)

    @classmethod
    def ad(cls, xi):
        r"""$\begin{bmatrix} {[\omega]_\times} & 0 \\ [\nu_k]_\times & [\omega]_\times \end{bmatrix}$."""
        xi = as_float_array(xi)
        K = cls.K
        W = _skew(xi[..., :3])
        N = _skew(xi[..., 3:].reshape(*xi.shape[:-1], K, 3))
        out = jnp.zeros((*xi.shape[:-1], 3 + 3 * K, 3 + 3 * K))
        for k in range(K + 1):
            out = out.at[..., 3 * k : 3 * k + 3, 3 * k : 3 * k + 3].set(W)
        for k in range(K):
            out = out.at[..., 3 + 3 * k : 6 + 3 * k, 0:3].set(N[..., k, :, :])
        return out


def _rotate(rot: SO3, p):
    """``R p_k`` for vectors ``p`` (..., K, 3)."""
    Rm = rot.as_matrix()
    return jnp.sum(Rm[..., None, :, :] * p[..., None, :], axis=-1)


_NAMED: dict[int, type[SEK3]] = {}
"""SEK3[1] and SEK3[2], registered by their own modules (SE3, SE23)."""


def register(cls: type[SEK3]) -> type[SEK3]:
    """Make ``SEK3[cls.K]`` return ``cls`` (the named groups SE3 and SE23)."""
    _NAMED[cls.K] = cls
    return cls


def sek3_dims(K: int) -> dict:
    """The class attributes of SE_K(3)."""
    return {"K": K, "tangent_dim": 3 + 3 * K, "matrix_dim": 3 + K, "coords_dim": 3 + 3 * K}


@functools.cache
def _sek3_type(K: int) -> type[SEK3]:
    if K in _NAMED:
        return _NAMED[K]
    name = f"SEK3_{K}"
    return type(SEK3)(name, (SEK3,), {**sek3_dims(K), "__module__": SEK3.__module__, "__qualname__": name})
