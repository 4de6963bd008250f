"""Small-matrix products that XLA fuses.

On the CPU, XLA lowers every ``dot`` to a library call costing about 0.3 microseconds whatever the size; the
filter's matrices are 2x2 to 12x12, where a broadcast multiply-and-sum fuses with its neighbours and runs
several times faster (benchmarks/bench_tse2.py). Above ``_FUSE_MAX`` the ordinary ``matmul`` is used.
"""

from __future__ import annotations

import jax.numpy as jnp

_FUSE_MAX = 16


def mm(a, b):
    """Matrix product ``a @ b`` with leading batch axes."""
    if max(a.shape[-2:] + b.shape[-1:]) > _FUSE_MAX:
        return jnp.matmul(a, b)
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def mv(a, x):
    """Matrix-vector product ``a @ x`` with leading batch axes."""
    if a.shape[-1] > _FUSE_MAX:
        return jnp.einsum("...ij,...j->...i", a, x)
    return jnp.sum(a * x[..., None, :], axis=-1)


def solve3(a, b):
    """``a^-1 b`` for a 3x3 matrix ``a`` and a 3-vector ``b`` (leading batch axes), by Cramer's rule: cross
    products and one division, which every engine compiles (a batched LU is not in the C engine's set)."""
    c0, c1, c2 = a[..., :, 0], a[..., :, 1], a[..., :, 2]
    det = jnp.sum(c0 * jnp.cross(c1, c2), axis=-1)
    x = jnp.stack([jnp.sum(b * jnp.cross(c1, c2), axis=-1), jnp.sum(c0 * jnp.cross(b, c2), axis=-1),
                   jnp.sum(c0 * jnp.cross(c1, b), axis=-1)], axis=-1)
    return x / det[..., None]
