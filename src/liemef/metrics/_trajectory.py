r"""Estimates as 3D poses, and the standard trajectory errors APE and RPE through evo's library.

:func:`pose_parts` reads a position and an orientation quaternion off any pose-like state: $SE(3)$, $SE_2(3)$
(its position), $SO(3)$ (attitude only: position zero), $SE(2)$ and $SO(2)$ lifted to 3D (a rotation about z,
$z = 0$), and a :class:`~liemef.groups.Product` whose first factor is one of these ($SE_2(3) \times \mathbb R^6$,
TSO(3), TSE(2), ...). :func:`ape_rpe` compares two such trajectories with `evo
<https://github.com/MichaelGrupp/evo>`_ (imported only when called; ``pip install 'liemef[evo]'``).
"""

from __future__ import annotations

import math

import numpy as np

from ..groups import SE2, SE3, SE23, SO2, SO3, LieGroup, Product

POSE_GROUPS = (SE3, SE23, SO3, SE2, SO2)
"""The groups :func:`pose_parts` reads a pose off (also as the first factor of a product)."""


def pose_parts(g: LieGroup) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 3) and unit quaternions ``(x, y, z, w)`` (N, 4), ROS's and TUM's order, of a batch of
    group elements ``g`` (batch shape (N,)). The rotation is body to world, as the groups store it.

    SE(3): ``(R, p)``; SE_2(3): ``(R, p)`` (the velocity is dropped); SO(3): ``(R, 0)``; SE(2) ``(theta, x, y)``:
    the rotation by theta about z and ``(x, y, 0)``; SO(2): the rotation about z and 0; a product: its first
    factor. ValueError for any other group."""
    G = type(g)
    factor = g.factors[0] if isinstance(g, Product) else g
    if not isinstance(factor, POSE_GROUPS):
        raise ValueError(f"g: expected a pose group ({', '.join(t.__name__ for t in POSE_GROUPS)}, or a product "
                         f"whose first factor is one), got {G.__name__}")
    if isinstance(factor, SE23):
        wxyz, p = np.asarray(factor.wxyz_p[..., :4]), np.asarray(factor.position())
    elif isinstance(factor, SE3):
        wxyz, p = np.asarray(factor.wxyz_p[..., :4]), np.asarray(factor.translation())
    elif isinstance(factor, SO3):
        wxyz = np.asarray(factor.wxyz)
        p = np.zeros((*wxyz.shape[:-1], 3))
    else:  # planar: a rotation about z, z = 0
        cs = np.asarray(factor.cos_sin if isinstance(factor, SO2) else factor.cos_sin_xy)
        half = 0.5 * np.arctan2(cs[..., 1], cs[..., 0])
        wxyz = np.stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), np.sin(half)], axis=-1)
        p = np.zeros((*cs.shape[:-1], 3))
        if isinstance(factor, SE2):
            p[..., :2] = cs[..., 2:4]
    if wxyz.ndim != 2:
        raise ValueError(f"g: expected a batch of elements (batch shape (N,)), got batch shape {wxyz.shape[:-1]}")
    wxyz = wxyz / np.linalg.norm(wxyz, axis=-1, keepdims=True)
    return np.asarray(p, dtype=np.float64), np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)


def _poses(name: str, poses) -> tuple[np.ndarray, np.ndarray]:
    """Positions and quaternions (x, y, z, w) from a group batch or a pair ``(positions, quaternions_xyzw)``."""
    if isinstance(poses, LieGroup):
        return pose_parts(poses)
    try:
        p, q = (np.asarray(a, dtype=np.float64) for a in poses)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name}: expected a batch of group elements or a pair (positions (N, 3), quaternions "
                         f"(N, 4) as x, y, z, w), got {type(poses).__name__}") from err
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4):
        raise ValueError(f"{name}: expected positions (N, 3) and quaternions (N, 4), got {p.shape} and {q.shape}")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError(f"{name}: expected finite positions and quaternions, got NaN or inf")
    n = np.linalg.norm(q, axis=1)
    if not (n > 0).all():
        raise ValueError(f"{name}: expected nonzero quaternions, got a zero one at row {int(np.argmin(n))}")
    return p, q / n[:, None]


def _trajectory(name: str, ts, poses):
    from evo.core.trajectory import PoseTrajectory3D

    p, q = _poses(name, poses)
    ts = np.asarray(ts, dtype=np.float64)
    if ts.shape != (p.shape[0],) or not np.isfinite(ts).all():
        raise ValueError(f"{name}: expected finite time stamps of shape ({p.shape[0]},) beside the poses, got "
                         f"shape {ts.shape}")
    return PoseTrajectory3D(positions_xyz=p, orientations_quat_wxyz=q[:, [3, 0, 1, 2]], timestamps=ts)


def ape_rpe(ts, g_est, ts_true, poses_true, *, max_diff: float = 0.01, delta: int = 1,
            align: bool = False) -> dict:
    r"""Absolute and relative pose errors (APE, RPE) of an estimate against a truth, by evo's
    ``evo.core.metrics``.

    ``g_est`` and ``poses_true``: batches of group elements (:func:`pose_parts`) or pairs ``(positions (N, 3),
    quaternions (N, 4) as x, y, z, w)`` (what :func:`liemef.reports.io.read_tum` returns), at the time stamps
    ``ts`` and ``ts_true``. The two are associated by nearest time stamps within ``max_diff`` seconds
    (``evo.core.sync.associate_trajectories``); ``align=True`` first aligns the estimate to the truth by the
    Umeyama rigid transform (evo's ``--align``), as for a SLAM estimate in its own frame.

    With $P_k$ the estimated and $Q_k$ the true pose of pair $k$, as $4 \times 4$ matrices:

    * APE: $E_k = Q_k^{-1} P_k$; ``ape_translation`` is $|\mathrm{trans}(E_k)|$ (m), ``ape_rotation`` the
      angle of $\mathrm{rot}(E_k)$ (degrees);
    * RPE over ``delta`` pairs: $E_k = (Q_k^{-1} Q_{k+\delta})^{-1} (P_k^{-1} P_{k+\delta})$, the same two
      measures (m, degrees): drift per step, blind to a constant offset.

    Returns a dict of those four, each with evo's statistics ``rmse, mean, median, std, min, max``, and
    ``pairs``, the number of associated poses. ValueError (naming the argument) on bad shapes, non-finite
    values, or fewer than ``delta + 1`` associated poses."""
    try:
        from evo.core import metrics, sync
    except ImportError as err:  # pragma: no cover - evo is in the test extra
        raise ModuleNotFoundError("ape_rpe needs evo: pip install 'liemef[evo]' (or evo)") from err
    if not (isinstance(max_diff, int | float) and math.isfinite(max_diff) and max_diff >= 0):
        raise ValueError(f"max_diff: expected a finite number of seconds >= 0, got {max_diff!r}")
    if not (isinstance(delta, int) and not isinstance(delta, bool) and delta >= 1):
        raise ValueError(f"delta: expected an integer >= 1 (pose pairs), got {delta!r}")
    est = _trajectory("g_est", ts, g_est)
    ref = _trajectory("poses_true", ts_true, poses_true)
    try:
        ref, est = sync.associate_trajectories(ref, est, max_diff=float(max_diff))
    except sync.SyncException as err:
        raise ValueError(f"ts, ts_true: expected time stamps that match within max_diff = {max_diff} s, got none "
                         f"({err})") from err
    if est.num_poses < delta + 1:
        raise ValueError(f"ts, ts_true: expected at least {delta + 1} poses matched within max_diff = {max_diff} s, "
                         f"got {est.num_poses}")
    if align:
        est.align(ref)
    out = {}
    R = metrics.PoseRelation
    for key, Metric, relation in (("ape_translation", metrics.APE, R.translation_part),
                                  ("ape_rotation", metrics.APE, R.rotation_angle_deg),
                                  ("rpe_translation", metrics.RPE, R.translation_part),
                                  ("rpe_rotation", metrics.RPE, R.rotation_angle_deg)):
        m = Metric(relation) if Metric is metrics.APE else Metric(relation, delta=delta,
                                                                   delta_unit=metrics.Unit.frames)
        m.process_data((ref, est))
        stats = m.get_all_statistics()
        out[key] = {k: float(stats[k]) for k in ("rmse", "mean", "median", "std", "min", "max")}
    out["pairs"] = int(est.num_poses)
    return out
