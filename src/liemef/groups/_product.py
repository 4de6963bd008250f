from __future__ import annotations

import functools
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ._base import LieGroup, as_float_array, checked_matrix


def _split(v, sizes):
    out, start = [], 0
    for n in sizes:
        out.append(v[..., start : start + n])
        start += n
    return out


def _block_diag(blocks):
    """Block-diagonal matrices with shared leading batch axes."""
    batch = jnp.broadcast_shapes(*(b.shape[:-2] for b in blocks))
    rows = sum(b.shape[-2] for b in blocks)
    cols = sum(b.shape[-1] for b in blocks)
    out = jnp.zeros((*batch, rows, cols), dtype=blocks[0].dtype)
    r = c = 0
    for b in blocks:
        out = out.at[..., r : r + b.shape[-2], c : c + b.shape[-1]].set(b)
        r, c = r + b.shape[-2], c + b.shape[-1]
    return out


class Product(LieGroup):
    """Direct product of groups: ``Product[SE2, R3]`` is TSE(2) = SE(2) x R^3.

    The algebra coordinates concatenate the factors' coordinates in order; so do :meth:`coords`; the matrix
    representation is block diagonal. An element is built from its factors: ``TSE2((SE2(...), R3(...)))``.
    """

    factors: tuple

    factor_types: ClassVar[tuple[type[LieGroup], ...]]
    tangent_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    coords_dim: ClassVar[int]

    def __init__(self, factors):
        factors = tuple(factors)
        types = self.factor_types
        if len(factors) != len(types) or not all(map(isinstance, factors, types)):
            got = tuple(type(f).__name__ for f in factors)
            raise ValueError(f"{type(self).__name__}: expected factors of types "
                             f"{tuple(t.__name__ for t in types)}, got {got}")
        self.factors = factors

    @classmethod
    def __class_getitem__(cls, factor_types) -> type[Product]:
        # Validated before the cache, so that an unhashable argument also gets the ValueError.
        if not isinstance(factor_types, tuple):
            factor_types = (factor_types,)
        concrete = [isinstance(t, type) and issubclass(t, LieGroup) and hasattr(t, "tangent_dim")
                    for t in factor_types]
        if not factor_types or not all(concrete):
            raise ValueError(f"Product[...]: expected one or more concrete LieGroup types, "
                             f"got {factor_types!r}")
        return _product_type(factor_types)

    @classmethod
    def _tangent_sizes(cls):
        return [t.tangent_dim for t in cls.factor_types]

    def defects(self) -> dict[str, float]:
        """The factors' defects, each named after its factor: ``"factor 0 (SO3): quaternion norm ..."``."""
        return {f"factor {k} ({type(f).__name__}): {what}": size
                for k, f in enumerate(self.factors) for what, size in f.defects().items()}

    @classmethod
    def _blocks(cls):
        """``(k, factor type, slice of its diagonal block)`` for each factor."""
        start = 0
        for k, t in enumerate(cls.factor_types):
            yield k, t, slice(start, start + t.matrix_dim)
            start += t.matrix_dim

    @classmethod
    def matrix_defects(cls, M):
        """The entries off the diagonal blocks (their largest), then each block's defects, named after its
        factor."""
        outside = np.ones(M.shape[-2:], dtype=bool)
        for _, _, b in cls._blocks():
            outside[b, b] = False
        out = {"off-diagonal blocks max|M|": np.abs(np.where(outside, M, 0.0)).max(axis=(-2, -1))}
        for k, t, b in cls._blocks():
            out.update({f"factor {k} ({t.__name__}) block M[{b.start}:{b.stop}, {b.start}:{b.stop}]: {what}": size
                        for what, size in t.matrix_defects(M[..., b, b]).items()})
        return out

    @classmethod
    def identity(cls, batch_shape=()):
        """The tuple of the factors' identities."""
        return cls(tuple(t.identity(batch_shape) for t in cls.factor_types))

    @classmethod
    def exp(cls, xi):
        """Factor by factor, on consecutive slices of ``xi``."""
        parts = _split(as_float_array(xi), cls._tangent_sizes())
        return cls(tuple(t.exp(p) for t, p in zip(cls.factor_types, parts, strict=True)))

    @classmethod
    def from_matrix(cls, M):
        """From the diagonal blocks of a block-diagonal matrix, factor by factor, checked
        (:func:`~liemef.groups._base.checked_matrix`): the entries off the blocks zero and each block its
        factor's matrix, within ``liemef._validate.ON_GROUP``."""
        M = checked_matrix(cls, M)
        return cls(tuple(t.from_matrix(M[..., b, b]) for _, t, b in cls._blocks()))

    @classmethod
    def from_coords(cls, q):
        """Factor by factor, on consecutive slices of ``q``."""
        parts = _split(as_float_array(q), [t.coords_dim for t in cls.factor_types])
        return cls(tuple(t.from_coords(p) for t, p in zip(cls.factor_types, parts, strict=True)))

    def compose(self, other):
        """Factor by factor."""
        return type(self)(tuple(a @ b for a, b in zip(self.factors, other.factors, strict=True)))

    def inverse(self):
        """Factor by factor."""
        return type(self)(tuple(a.inverse() for a in self.factors))

    def log(self):
        """The factors' logarithms, concatenated."""
        return jnp.concatenate([f.log() for f in self.factors], axis=-1)

    def coords(self):
        """The factors' coordinates, concatenated."""
        return jnp.concatenate([f.coords() for f in self.factors], axis=-1)

    def as_matrix(self):
        """Block-diagonal matrix of the factors' matrices."""
        return _block_diag([f.as_matrix() for f in self.factors])

    def Ad(self):
        """Block-diagonal matrix of the factors' adjoints."""
        return _block_diag([f.Ad() for f in self.factors])

    @classmethod
    def hat(cls, xi):
        """Block-diagonal matrix of the factors' :meth:`hat` on consecutive slices of ``xi``."""
        parts = _split(as_float_array(xi), cls._tangent_sizes())
        return _block_diag([t.hat(p) for t, p in zip(cls.factor_types, parts, strict=True)])

    @classmethod
    def vee(cls, X):
        """The factors' :meth:`vee` of the diagonal blocks, concatenated."""
        X = as_float_array(X)
        out, k = [], 0
        for t in cls.factor_types:
            out.append(t.vee(X[..., k : k + t.matrix_dim, k : k + t.matrix_dim]))
            k += t.matrix_dim
        return jnp.concatenate(out, axis=-1)

    @classmethod
    def ad(cls, xi):
        """Block-diagonal matrix of the factors' :meth:`ad` (the factors commute)."""
        parts = _split(as_float_array(xi), cls._tangent_sizes())
        return _block_diag([t.ad(p) for t, p in zip(cls.factor_types, parts, strict=True)])


@functools.cache
def _product_type(factor_types: tuple[type[LieGroup], ...]) -> type[Product]:
    # Always a direct subclass of Product, one class per tuple of factor types.
    name = "x".join(t.__name__ for t in factor_types)
    return type(Product)(name, (Product,), {
        "factor_types": factor_types,
        "tangent_dim": sum(t.tangent_dim for t in factor_types),
        "matrix_dim": sum(t.matrix_dim for t in factor_types),
        "coords_dim": sum(t.coords_dim for t in factor_types),
        "__module__": Product.__module__,
        "__qualname__": name,
    })
