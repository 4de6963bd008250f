r"""Residuals on manifolds: $y \ominus h$ for outputs that do not live in a vector space (docs/weights.md).

A filter compares a sample y with the predicted output h. For a vector output the residual is $y - h$; for an
angle it is the wrapped difference; for a direction on $S^2$ it lies in the tangent plane at h; for a rotation
it is $\log(h^{-1} y)$. A :class:`~liemef.systems.Sensor` declares its residual (``angles=`` or
``residual=``), and every filter, gate, robust loss and innovation then uses it: the filters see the output
through $\tilde h_y(g) = y - (y \ominus h(g))$, so that $y - \tilde h_y(g) = y \ominus h(g)$ and the
derivatives of $\tilde h_y$ are those of the residual (Theorem 4.1's r, E and W, the hybrid update's Newton
steps, the Kalman filters' Jacobians and sigma points).

A residual is a pure JAX function ``residual(y, h) -> (k,)`` of a sample and an output of the sensor's k
components, zero at ``y == h``, smooth in h near y (the filters differentiate it twice).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..groups import SO3


def wrap_angle(a: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
    r"""``a`` wrapped into $[-\pi, \pi)$: $a - 2\pi\lfloor (a + \pi) / 2\pi\rfloor$ (exactly ``a`` there, derivative
    1 everywhere but at the cut; so $\pi \mapsto -\pi$). liemef's one angle wrap: residuals of angle outputs,
    the errors of :mod:`liemef.metrics` and the studies all use it."""
    a = jnp.asarray(a)
    a = a if jnp.issubdtype(a.dtype, jnp.floating) else a.astype(jnp.float64)
    return a - 2.0 * math.pi * jnp.floor((a + math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class AngleResidual:
    """$y - h$ with the components ``mask`` (a tuple of bools, static) wrapped into $[-\\pi, \\pi)$: angles."""

    mask: tuple[bool, ...]

    def __call__(self, y, h):
        d = y - h
        return jnp.where(jnp.asarray(self.mask), wrap_angle(d), d)


def direction_residual(y: Float[Array, " 3"], h: Float[Array, " 3"]) -> Float[Array, " 3"]:
    r"""Unit directions on $S^2$: the tangent vector at h that points to y, of length the angle between them,
    $\theta/\sin\theta\,(y - (h\cdot y)h)$ with $\theta = \angle(h, y)$ (the log map of the sphere at h, in the
    ambient coordinates: its component along h is zero). ``y`` and ``h`` are normalized first."""
    ny, nh = jnp.sqrt(jnp.sum(y * y)), jnp.sqrt(jnp.sum(h * h))
    y = y / jnp.where(ny > 0, ny, 1.0)   # a missing sample (zeros, no weight) stays finite
    h = h / jnp.where(nh > 0, nh, 1.0)
    c = jnp.sum(h * y)
    v = y - c * h
    s2 = jnp.sum(v * v)
    small = s2 < 1e-12
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    # theta / sin(theta) = 1 + s^2/6 + ... near theta = 0 (smooth under autodiff there)
    factor = jnp.where(small, 1.0 + s2 / 6.0, jnp.arctan2(s, c) / s)
    return factor * v


def rotation_residual(y: Float[Array, " 3"], h: Float[Array, " 3"]) -> Float[Array, " 3"]:
    r"""Rotations given as rotation vectors: $\log(\mathrm{Exp}(h)^{-1}\mathrm{Exp}(y))$ (body frame of h)."""
    return SO3.exp(y).rminus(SO3.exp(h))
