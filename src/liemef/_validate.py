"""Checks at the library's boundaries: each raises a ValueError that names the argument, what was expected
and what came, before any compiled code runs."""

from __future__ import annotations

import math
import os

import numpy as np

ON_GROUP = 1e-6
"""How far a group element may be from the group, by each of its defects (``LieGroup.defects`` for a stored
element, ``LieGroup.matrix_defects`` for a matrix given to ``from_matrix``), in their own units: the norm of a
stored unit vector (the (cos, sin) of SO(2) and SE(2), the quaternion of SO(3) and SE_K(3)), ``| |v| - 1 |``;
a matrix's orthogonality ``max |R^T R - I|`` and determinant ``|det R - 1|`` of its rotation block, and its bottom
rows' largest entry away from ``[0, I]``; a ``MatrixGroup``'s own rule. Elements made by liemef's constructors are
within 1e-15; a unit vector typed with six decimals is within 1e-6, a rotation matrix typed with seven decimals."""

INT_MAX = 2**31 - 1
"""The largest count (sub-steps, samples kept, trials) a compiled loop takes: a C ``int`` and JAX's int32."""

SEED_MAX = 2**63 - 1
"""The largest random seed (``jax.random.key`` takes a 64-bit integer)."""


def numeric(name: str, value) -> np.ndarray:
    """``value`` as a NumPy array of real numbers, not yet converted: booleans, integers and floats pass (a
    lone Python integer beyond 64 bits as a float, if it has one); complex numbers, objects (ragged lists,
    ``None``, big integers inside a list), strings and anything else are refused with a ValueError naming
    ``name`` and what came."""
    if isinstance(value, int) and not isinstance(value, bool) and not -2**63 <= value < 2**63:
        return np.asarray(_float(name, value))
    try:
        a = value if isinstance(value, np.ndarray) else np.asarray(value)
    except (TypeError, ValueError, OverflowError) as err:
        raise ValueError(f"{name}: expected a numeric array, got {type(value).__name__} ({err})") from err
    kind = a.dtype.kind
    if kind == "c":
        bad = np.argwhere(np.imag(a) != 0)
        at = tuple(int(i) for i in bad[0]) if bad.size else (0,) * a.ndim
        raise ValueError(f"{name}: expected real numbers, got complex values (dtype {a.dtype}), "
                         f"{_first(a, at)}")
    if kind not in "biuf":
        what = {"O": "objects", "U": "strings", "S": "bytes", "V": "raw records", "M": "dates",
                "m": "time deltas"}.get(kind, "non-numbers")
        raise ValueError(f"{name}: expected a numeric array, got {what} (dtype {a.dtype}), "
                         f"{_first(a, (0,) * a.ndim)}")
    return a


def _first(a: np.ndarray, at: tuple) -> str:
    if a.size == 0:
        return "empty"
    v = a[at] if a.ndim else a[()]
    v = v.item() if isinstance(v, np.generic) else v
    return f"{v!r}" + (f" at index {at}" if a.ndim else "")


def _float(name: str, value: int) -> float:
    try:
        return float(value)
    except OverflowError as err:
        raise ValueError(f"{name}: expected a number, got an integer of {value.bit_length()} bits") from err


def array(name: str, value, shape: tuple[int | None, ...] | None = None, *, missing: bool = False) -> np.ndarray:
    """``value`` as a finite float64 numpy array of the given shape (None is any length); with ``missing``,
    NaN is allowed (a missing sample) but infinities are not. Integers are converted; complex numbers and
    objects are refused (:func:`numeric`)."""
    a = np.asarray(numeric(name, value), dtype=np.float64)
    if shape is not None and (a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape,
                                                                                                   strict=False))):
        want = str(tuple("N" if s is None else s for s in shape)).replace("'", "")
        raise ValueError(f"{name}: expected shape {want}, got {a.shape}")
    ok = ~np.isinf(a) if missing else np.isfinite(a)
    if not np.all(ok):
        bad = np.argwhere(~ok)[0]
        what = "finite values or NaN (missing)" if missing else "finite values"
        raise ValueError(f"{name}: expected {what}, got {a[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    return a


def positive(name: str, value) -> float:
    """A finite number > 0 (a mass, an inertia, a length, a rate), as a float."""
    v = float(array(name, value, ()))
    if not v > 0:
        raise ValueError(f"{name}: expected a finite number > 0, got {v}")
    return v


def real(name: str, value) -> float:
    """A finite real number, as a float."""
    return float(array(name, value, ()))


def integer(name: str, value, low: int = 0, high: int = INT_MAX) -> int:
    """An integer in [low, high], as an int: Python and NumPy integers pass, booleans, floats and the rest do
    not (a count given as 2.5 is a mistake, not a rounding)."""
    want = f"an integer >= {low} and <= {high}"
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{name}: expected {want}, got {type(value).__name__} {value!r}")
    v = int(value)
    if not low <= v <= high:
        raise ValueError(f"{name}: expected {want}, got {v}")
    return v


def cpus() -> int:
    """The CPUs this process may use (its affinity where the OS tells it, else the machine's count): the default
    number of threads of the C engine's batches and of ``liemef tune``."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def element(name: str, g, G) -> None:
    """``g`` is a single element of the group type ``G`` with finite parameters on the group: each of its
    ``g.defects()`` (the norm of a stored unit vector, a matrix's orthogonality, determinant or bottom row, a
    :class:`~liemef.groups.MatrixGroup`'s rule; none for a vector space) within :data:`ON_GROUP`. ValueError
    naming ``name`` otherwise, with the defect and its size."""
    import jax

    if not isinstance(g, G):
        raise ValueError(f"{name}: expected an element of {G.__name__}, got {type(g).__name__}")
    if g.batch_shape != ():
        raise ValueError(f"{name}: expected a single element (no batch axes), got batch shape {g.batch_shape}")
    for leaf in jax.tree_util.tree_leaves(g):
        array(name, leaf)
    defects = g.defects()
    off = float(g.off_group())
    if not off <= ON_GROUP:
        worst = next(what for what, size in defects.items() if not size < off)
        params = np.concatenate([np.ravel(np.asarray(x)) for x in jax.tree_util.tree_leaves(g)])
        raise ValueError(f"{name}: expected an element of {G.__name__} within {ON_GROUP:g} of the group, got one "
                         f"{off:.6g} off the group by its {worst}, parameters {params.tolist()}")


def square(name: str, value, n: int) -> np.ndarray:
    return array(name, value, (n, n))


def symmetric_psd(name: str, value, n: int, *, definite: bool = True) -> np.ndarray:
    """A symmetric positive (semi)definite n x n matrix (its eigenvalues computed on the matrix scaled to a
    largest entry of 1, so that no entry overflows)."""
    a = square(name, value, n)
    scale = max(1.0, float(np.abs(a).max()))
    u = a / scale
    if not np.allclose(u, u.T, rtol=0, atol=1e-10):
        raise ValueError(f"{name}: expected a symmetric matrix, got max |M - M^T| = {np.abs(a - a.T).max():.3g}")
    eig = np.linalg.eigvalsh(0.5 * (u + u.T))
    if definite and eig.min() <= 1e-12:
        raise ValueError(f"{name}: expected a positive definite matrix, got smallest eigenvalue "
                         f"{eig.min() * scale:.3g}")
    if not definite and eig.min() < -1e-10:
        raise ValueError(f"{name}: expected a positive semidefinite matrix, got smallest eigenvalue "
                         f"{eig.min() * scale:.3g}")
    return a


def invertible(name: str, value, n: int) -> np.ndarray:
    a = square(name, value, n)
    scale = max(1.0, float(np.abs(a).max()))
    s = np.linalg.svd(a / scale, compute_uv=False)
    if s.min() <= 1e-12 * max(1.0, s.max()):
        raise ValueError(f"{name}: expected an invertible matrix (D D^T positive definite, condition number below "
                         f"1e12), got singular values from {s.min() * scale:.3g} to {s.max() * scale:.3g}")
    return a


def nonnegative(name: str, value) -> float:
    v = float(array(name, value, ()))
    if v < 0:
        raise ValueError(f"{name}: expected a number >= 0, got {v}")
    return v


def timeout(name: str, value) -> float | None:
    """A time limit in seconds: None for none (None or 0), else a finite number > 0; a ValueError naming
    ``name`` for a negative, non-finite or non-numeric value (a boolean included)."""
    if value is None:
        return None
    try:
        v = math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{name}: expected seconds >= 0 (0: no limit), got {value!r}")
    return v or None


def sorted_times(name: str, ts) -> np.ndarray:
    t = array(name, ts, (None,))
    if t.size >= 2 and not np.all(np.diff(t) > 0):
        k = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(f"{name}: expected strictly increasing time stamps, got t[{k}] = {t[k]} "
                         f"followed by t[{k + 1}] = {t[k + 1]}")
    return t


def choice(name: str, value, options) -> str:
    if value not in options:
        raise ValueError(f"{name}: expected one of {sorted(options)}, got {value!r}")
    return value
