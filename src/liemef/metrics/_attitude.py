"""Attitude errors as BROAD (Laidig et al. 2021) scores them: the world-frame error ``q_est * q_ref^-1`` split into
its heading (about the vertical) and inclination (tilt) parts, on quaternions (w, x, y, z), body -> world."""

from __future__ import annotations

import numpy as np

ATTITUDE_METRICS = ("total", "heading", "inclination")
"""The keys of :func:`attitude_rms`."""


def _world_error(quat_est: np.ndarray, quat_ref: np.ndarray, mask: np.ndarray):
    """The samples that count (in ``mask``, the reference present, the estimate finite) and the world-frame error
    rotation ``q_est * q_ref^-1`` on them."""
    from scipy.spatial.transform import Rotation

    ok = mask & ~np.isnan(quat_ref).any(axis=1) & np.isfinite(quat_est).all(axis=1)
    est, ref = (Rotation.from_quat(q[ok][:, [1, 2, 3, 0]]) for q in (quat_est, quat_ref))
    return ok, est * ref.inv()


def attitude_rms(quat_est: np.ndarray, quat_ref: np.ndarray, mask: np.ndarray) -> dict[str, float | None]:
    """BROAD's total, heading and inclination rms (deg) of the error ``q_est * q_ref^-1`` (world frame) over
    ``mask`` where the reference is present and the estimate finite; quaternions (w, x, y, z), body -> world
    (the dataset's README). None for each when no sample qualifies."""
    ok, rot = _world_error(quat_est, quat_ref, mask)
    e = rot.as_quat()
    w, z = np.abs(e[:, 3]), e[:, 2]
    total = 2 * np.arccos(np.clip(w, 0, 1))
    heading = 2 * np.arctan(np.abs(z) / np.maximum(w, 1e-12))
    incl = 2 * np.arccos(np.clip(np.hypot(w, z), 0, 1))
    if not ok.any():
        return dict.fromkeys(ATTITUDE_METRICS)
    return {k: float(np.degrees(np.sqrt(np.mean(x**2)))) for k, x in zip(ATTITUDE_METRICS, (total, heading, incl),
                                                                          strict=True)}


def field_against_reference(mag: np.ndarray, quat_ref: np.ndarray, rest: np.ndarray,
                            moving: np.ndarray) -> dict[str, float | None]:
    """The magnetometer read through the reference attitude: each sample ``mag`` (body frame) turned into the
    world by ``quat_ref`` (w, x, y, z, body -> world), its azimuth about the vertical and its dip, in degrees,
    against their medians over the ``rest`` samples. Returns, over the ``moving`` samples, the median azimuth and
    dip offsets (``azimuth``, ``dip``) and the 90th percentile of the azimuth offset's size (``azimuth_p90``);
    None for each where ``rest`` or ``moving`` has no sample with the reference.

    A magnetometer that agrees with the reference gives zeros. An offset that lasts through the motion is what
    the magnetometer tells every filter that trusts it, however long it averages: a field that changes along
    the path, or a magnetometer whose calibration or alignment with the other sensors errs with the attitude.
    For diagnosis and scoring only: it reads the reference."""
    from scipy.spatial.transform import Rotation

    mag, quat_ref = np.asarray(mag, dtype=np.float64), np.asarray(quat_ref, dtype=np.float64)
    have = ~np.isnan(quat_ref).any(axis=1) & np.isfinite(mag).all(axis=1)
    keys = ("azimuth", "azimuth_p90", "dip")
    rest, moving = np.asarray(rest, dtype=bool) & have, np.asarray(moving, dtype=bool) & have
    if not rest.any() or not moving.any():
        return dict.fromkeys(keys)
    sel = rest | moving
    m = Rotation.from_quat(quat_ref[sel][:, [1, 2, 3, 0]]).apply(mag[sel])
    az = np.degrees(np.arctan2(m[:, 1], m[:, 0]))
    dip = np.degrees(np.arctan2(m[:, 2], np.hypot(m[:, 0], m[:, 1])))
    r, v = rest[sel], moving[sel]
    d_az = (az[v] - np.median(az[r]) + 180.0) % 360.0 - 180.0
    return {"azimuth": float(np.median(d_az)), "azimuth_p90": float(np.percentile(np.abs(d_az), 90)),
            "dip": float(np.median(dip[v]) - np.median(dip[r]))}


def attitude_error_per_second(ts: np.ndarray, quat_est: np.ndarray, quat_ref: np.ndarray,
                              mask: np.ndarray) -> np.ndarray:
    """The total attitude error (deg) of :func:`attitude_rms` as its rms over each whole second from ``ts[0]``
    (NaN where the second has no sample in ``mask`` with a reference), for figures."""
    ok, rot = _world_error(quat_est, quat_ref, mask)
    err = np.full(ts.shape, np.nan)
    err[ok] = np.degrees(rot.magnitude())
    sec = np.floor(ts - ts[0]).astype(int)
    out = np.full(sec[-1] + 1, np.nan)
    for k in np.unique(sec[ok]):
        x = err[(sec == k) & ok]
        out[k] = np.sqrt(np.mean(x**2))
    return out


def attitude_error(R_true: np.ndarray, R_hat: np.ndarray) -> np.ndarray:
    r"""The total attitude error angle (rad) of $E = \hat R R^\top$ per row, as BROAD's total error, by
    ``atan2(sin, cos)`` (accurate at small angles, unlike ``arccos``); NaN rows stay NaN."""
    R_true, R_hat = np.asarray(R_true, dtype=np.float64), np.asarray(R_hat, dtype=np.float64)
    E = R_hat @ np.swapaxes(R_true, -1, -2)
    s = 0.5 * np.linalg.norm(np.stack([E[..., 2, 1] - E[..., 1, 2], E[..., 0, 2] - E[..., 2, 0],
                                       E[..., 1, 0] - E[..., 0, 1]], -1), axis=-1)
    c = 0.5 * (np.trace(E, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)
