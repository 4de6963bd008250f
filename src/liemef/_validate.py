"""Checks at the library's boundaries: each raises a ValueError that names the argument, what was expected
and what came, before any compiled code runs."""

from __future__ import annotations

import numpy as np


def array(name: str, value, shape: tuple[int | None, ...] | None = None, *, missing: bool = False) -> np.ndarray:
    """``value`` as a finite float64 numpy array of the given shape (None is any length); with ``missing``,
    NaN is allowed (a missing sample) but infinities are not."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name}: expected a numeric array, got {type(value).__name__} ({err})") from err
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


def square(name: str, value, n: int) -> np.ndarray:
    return array(name, value, (n, n))


def symmetric_psd(name: str, value, n: int, *, definite: bool = True) -> np.ndarray:
    """A symmetric positive (semi)definite n x n matrix."""
    a = square(name, value, n)
    scale = max(1.0, float(np.abs(a).max()))
    if not np.allclose(a, a.T, rtol=0, atol=1e-10 * scale):
        raise ValueError(f"{name}: expected a symmetric matrix, got max |M - M^T| = {np.abs(a - a.T).max():.3g}")
    eig = np.linalg.eigvalsh(0.5 * (a + a.T))
    if definite and eig.min() <= 1e-12 * scale:
        raise ValueError(f"{name}: expected a positive definite matrix, got smallest eigenvalue {eig.min():.3g}")
    if not definite and eig.min() < -1e-10 * scale:
        raise ValueError(f"{name}: expected a positive semidefinite matrix, got smallest eigenvalue {eig.min():.3g}")
    return a


def invertible(name: str, value, n: int) -> np.ndarray:
    a = square(name, value, n)
    s = np.linalg.svd(a, compute_uv=False)
    if s.min() <= 1e-12 * max(1.0, s.max()):
        raise ValueError(f"{name}: expected an invertible matrix (D D^T positive definite), "
                         f"got smallest singular value {s.min():.3g}")
    return a


def nonnegative(name: str, value) -> float:
    v = float(array(name, value, ()))
    if v < 0:
        raise ValueError(f"{name}: expected a number >= 0, got {v}")
    return v


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
