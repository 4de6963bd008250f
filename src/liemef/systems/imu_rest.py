r"""What an IMU's samples at rest say, from the samples alone: where a log's initial rest ends
(:func:`initial_rest`), gravity's and the field's norms (:func:`rest_norms`), the magnetic dip
(:func:`magnetic_dip`), all three at once (:func:`rest_constants`, :func:`log_rest_constants`), and the TRIAD
attitude (:func:`triad`, :func:`initial_estimate`): the structural constants and the initial estimate of the
IMU models (:mod:`~liemef.systems.attitude_bias`, :mod:`~liemef.systems.imu_noise`,
:mod:`~liemef.systems.bounded_velocity`, :mod:`~liemef.systems.attitude_field`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .. import _validate
from ..groups import R3, SO3, TSO3


def _unit_rows(name: str, v) -> np.ndarray:
    a = _validate.array(name, np.atleast_2d(np.asarray(v, dtype=np.float64)), (None, 3), missing=True)
    n = np.linalg.norm(a, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, a / n, np.nan)


def magnetic_dip(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> float:
    r"""The magnetic dip (rad) from accelerometer and magnetometer samples taken at rest (any units).

    At rest the normalized accelerometer reads up, $a = R^\top e_{up}$, so the angle between $a$ and the field
    direction $m$ is $90° + \delta$: $\delta = \arcsin(-a \cdot m)$, the median over the samples (rows with a
    NaN are skipped).
    """
    a, m = _unit_rows("acc", acc), _unit_rows("mag", mag)
    if a.shape != m.shape:
        raise ValueError(f"mag: expected the shape of acc {a.shape}, got {m.shape}")
    s = -np.sum(a * m, axis=1)
    s = s[np.isfinite(s)]
    if s.size == 0:
        raise ValueError("acc, mag: expected at least one sample with both vectors finite and non-zero, got none")
    return float(np.median(np.arcsin(np.clip(s, -1.0, 1.0))))


REST_WINDOW = 0.5
"""Default window (s) of :func:`initial_rest`."""
REST_GYRO_TOL = 0.1
"""Default gyro tolerance (rad/s) of :func:`initial_rest`: the rms gyro norm over a window at rest stays below it
(BROAD's seven trials at rest: at most 0.061 rad/s over 0.5 s, bias and noise together)."""
REST_ACC_TOL = 0.5
"""Default accelerometer tolerance (m/s^2) of :func:`initial_rest`: the rms spread of the accelerometer vector about
its window mean stays below it at rest (BROAD at rest: at most 0.30 m/s^2 over 0.5 s)."""


def initial_rest(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], rate: float, *,
                 window: float = REST_WINDOW, gyro_tol: float = REST_GYRO_TOL, acc_tol: float = REST_ACC_TOL) -> int:
    r"""The length ``k`` (samples) of a log's initial rest, from the IMU samples alone: samples ``[0, k)``.

    A window of ``window`` s (``w = round(window * rate)`` samples, at least 2) is *still* when the rms of the gyro
    norm over it is below ``gyro_tol`` (rad/s; it includes the gyro's bias, so a bias near it needs a higher
    tolerance) and the rms distance of the accelerometer vectors from their window mean is below ``acc_tol``
    (the accelerometer's units, m/s^2: it sees a change of the norm and of the direction alike). The rest ends at
    the first sample of the first window that is not still: every sample before it lies in a still window, and the
    motion that ended it lies within the ``window`` s after it, so the detected rest ends up to ``window`` s early,
    never late. On BROAD's seven trials the defaults end the rest 0.08 to 0.26 s before the dataset's movement
    annotation (``tests/test_attitude_bias.py``). A row with a NaN counts as absent; a window without two
    present rows is not still.

    A log whose every window is still is all rest (``k`` = N: the caller sees it). A log that does not start at
    rest (its first window is not still) or is shorter than one window is a ValueError naming ``gyr`` and
    ``acc`` with the first window's figures.
    """
    gyr = _validate.array("gyr", np.asarray(gyr, dtype=np.float64), (None, 3), missing=True)
    acc = _validate.array("acc", np.asarray(acc, dtype=np.float64), (gyr.shape[0], 3), missing=True)
    for name, v, unit in (("rate", rate, "a sample rate > 0 in Hz"), ("window", window, "a duration > 0 in s"),
                          ("gyro_tol", gyro_tol, "a tolerance > 0 in rad/s"),
                          ("acc_tol", acc_tol, "a tolerance > 0 in m/s^2")):
        number = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        if not (number and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected {unit}, got {v!r}")
    N, w = gyr.shape[0], max(2, int(round(window * rate)))
    if N < w:
        raise ValueError(f"gyr, acc: expected a log of at least one window ({w} samples, {window} s at {rate} Hz) "
                         f"to find its initial rest, got {N} samples")
    ok = np.all(np.isfinite(gyr), axis=1) & np.all(np.isfinite(acc), axis=1)
    g, a = np.where(ok[:, None], gyr, 0.0), np.where(ok[:, None], acc, 0.0)

    def window_sums(x):
        c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
        return c[w:] - c[:-w]

    n = window_sums(ok.astype(np.float64))
    m = np.maximum(n, 1.0)
    gyro_rms = np.sqrt(window_sums(np.sum(g**2, axis=1)) / m)
    mean = window_sums(a) / m[:, None]
    spread = np.sqrt(np.maximum(window_sums(np.sum(a**2, axis=1)) / m - np.sum(mean**2, axis=1), 0.0))
    still = (n >= 2) & (gyro_rms < gyro_tol) & (spread < acc_tol)
    if not still[0]:
        raise ValueError(f"gyr, acc: expected a log that starts at rest (a first window of {window} s with an rms gyro "
                         f"norm < gyro_tol = {gyro_tol} rad/s and an accelerometer spread < acc_tol = {acc_tol} "
                         f"m/s^2), got {gyro_rms[0]:.3g} rad/s and {spread[0]:.3g} m/s^2 over {int(n[0])} present "
                         "samples; measure gravity, field and dip on samples at rest yourself (rest_norms, "
                         "magnetic_dip)")
    return N if still.all() else int(np.argmin(still))


def rest_constants(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
                   rate: float, **tolerances) -> dict:
    """The structural constants of :func:`attitude_imu` and :func:`attitude_velocity` measured over a log's initial
    rest, found from the IMU samples alone (:func:`initial_rest`, with its ``tolerances``): ``dip`` (rad,
    :func:`magnetic_dip`), ``gravity`` (m/s^2) and ``field`` (uT) (:func:`rest_norms`), and the rest's extent
    ``rest_samples`` and ``rest_s`` (s), so that a study can say what its filters were given."""
    k = initial_rest(gyr, acc, rate, **tolerances)
    acc, mag = np.asarray(acc, dtype=np.float64)[:k], np.asarray(mag, dtype=np.float64)[:k]
    gravity, field = rest_norms(acc, mag)
    return {"dip": magnetic_dip(acc, mag), "gravity": gravity, "field": field, "rest_samples": k,
            "rest_s": k / float(rate)}


def log_arrays(ts, us, ys, inputs: int, outputs: int, expected: str) -> tuple[np.ndarray, np.ndarray, float]:
    """A filter log's ``us`` and ``ys`` as float arrays with at least ``inputs`` and ``outputs`` columns, and its
    rate (the inverse of the median interval of ``ts``); a ValueError naming ``us``, ``ys`` (with ``expected``,
    what those columns hold) or ``ts``."""
    ts = _validate.array("ts", np.asarray(ts, dtype=np.float64), (None,))
    us = _validate.array("us", np.asarray(us, dtype=np.float64), (ts.shape[0], None), missing=True)
    ys = _validate.array("ys", np.asarray(ys, dtype=np.float64), (ts.shape[0], None), missing=True)
    if us.shape[1] < inputs or ys.shape[1] < outputs:
        raise ValueError(f"us, ys: expected {expected}, got {us.shape[1]} input and {ys.shape[1]} output columns")
    dt = np.diff(ts)
    if ts.shape[0] < 2 or not np.median(dt) > 0:
        raise ValueError(f"ts: expected increasing times, got {ts.shape[0]} samples with median interval "
                         f"{float(np.median(dt)) if dt.size else float('nan')}")
    return us, ys, 1.0 / float(np.median(dt))


def log_rest_constants(ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N m"], ys: Float[ArrayLike, "N p"],
                       **tolerances) -> dict:
    """:func:`rest_constants` of a filter log with the raw norms (:func:`imu_log` with ``norms=True``, for
    :func:`attitude_imu`, or :func:`imu_velocity_log`): the gyro is ``us[:, :3]``, the accelerometer and the
    magnetometer are their directions ``ys[:, 0:6]`` times their norms ``ys[:, 6:8]``, the rate is the inverse of
    the median interval of ``ts``. A ValueError naming ``us``, ``ys`` or ``ts`` for a log without these columns."""
    us, ys, rate = log_arrays(ts, us, ys, 3, 8, "the gyro in us[:, :3] and the directions and norms in ys[:, :8]")
    acc, mag = ys[:, 0:3] * ys[:, 6:7], ys[:, 3:6] * ys[:, 7:8]
    return rest_constants(us[:, :3], acc, mag, rate, **tolerances)


def rest_norms(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> tuple[float, float]:
    """The medians of the accelerometer's and the magnetometer's norms over samples at rest (their units):
    ``gravity`` and ``field`` of :func:`attitude_imu` (rows with a NaN are skipped)."""
    a = np.linalg.norm(np.atleast_2d(np.asarray(acc, dtype=np.float64)), axis=1)
    m = np.linalg.norm(np.atleast_2d(np.asarray(mag, dtype=np.float64)), axis=1)
    a, m = a[np.isfinite(a) & (a > 0)], m[np.isfinite(m) & (m > 0)]
    if a.size == 0 or m.size == 0:
        raise ValueError("acc, mag: expected samples at rest with finite, non-zero vectors, got none")
    return float(np.median(a)), float(np.median(m))


def triad(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> Float[np.ndarray, "N 3 3"]:
    r"""Rotations body -> ENU from accelerometer and magnetometer vectors (TRIAD, trusting gravity first).

    The rows of $R$ are the world axes seen in the body frame: $R^\top e_{up} = \bar a$ (the normalized
    accelerometer), $R^\top e_{north}$ = the part of the field orthogonal to it, normalized, and
    $R^\top e_{east}$ = north x up. The dip does not enter. Rows with a NaN, or with a field parallel to gravity,
    give NaN.
    """
    up = _unit_rows("acc", acc)
    m = _unit_rows("mag", mag)
    if up.shape != m.shape:
        raise ValueError(f"mag: expected the shape of acc {up.shape}, got {m.shape}")
    north = m - np.sum(m * up, axis=1, keepdims=True) * up
    n = np.linalg.norm(north, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        north = np.where(n > 1e-9, north / n, np.nan)
    return np.stack([np.cross(north, up), north, up], axis=1)


def initial_estimate(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"], bias=(0.0, 0.0, 0.0)) -> TSO3:
    """A TSO(3) estimate ``(R, b)`` from the first accelerometer and magnetometer samples (at rest): TRIAD of
    their means (one sample or N), and the bias ``bias`` (rad/s; e.g. the mean gyro reading at rest)."""
    a = np.nanmean(_unit_rows("acc", acc), axis=0)
    m = np.nanmean(_unit_rows("mag", mag), axis=0)
    R = triad(a, m)[0]
    if not np.all(np.isfinite(R)):
        raise ValueError(f"acc, mag: expected finite, non-parallel vectors, got mean directions {a.tolist()} and "
                         f"{m.tolist()}")
    b = _validate.array("bias", np.asarray(bias, dtype=np.float64), (3,))
    return TSO3((SO3.from_matrix(jnp.asarray(R)), R3(jnp.asarray(b))))
