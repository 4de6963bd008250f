"""The ready systems ``liemef run --system NAME`` filters recorded logs with, each built with the weights of its
paper's experiment, and how to read a first state estimate off a measurement."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...systems import AbstractSystem, PlanarRigidBody, attitude_gyro_bias, attitude_imu, planar_localization
from ...systems import attitude_bias as _attitude_bias
from . import attitude, chaplygin, unit_circle
from .tse2 import measured_state


@dataclass(frozen=True)
class SystemSpec:
    """A ready system for filtering recorded logs (``liemef run --system NAME``).

    ``make()`` builds the system; ``measured(ys)`` reads the state coordinates off measurements (N, p)
    (NaN where not measured); ``initial_guess(ys0)`` is the default initial estimate in coordinates from the
    first measurement (unmeasured coordinates 0).
    """

    name: str
    description: str
    make: Callable[[], AbstractSystem] = field(repr=False)
    measured: Callable[[np.ndarray], np.ndarray] = field(repr=False)

    def initial_guess(self, ys0) -> np.ndarray:
        """State coordinates read off the first measurement ``ys0`` (p,), 0 where not measured."""
        q = self.measured(np.asarray(ys0, dtype=np.float64)[None, :])[0]
        return np.where(np.isfinite(q), q, 0.0)


def _gps_state(ys) -> np.ndarray:
    """(theta, x, y) read off GPS fixes (N, 2): the position where a fix is present; the heading is not
    measured (NaN, so the initial guess is 0)."""
    ys = np.asarray(ys, dtype=np.float64)
    return np.concatenate([np.full((ys.shape[0], 1), np.nan), ys[:, 0:2]], axis=1)


SYSTEMS: dict[str, SystemSpec] = {
    "tse2": SystemSpec(
        "tse2",
        "planar rigid body on TSE(2), GPS (x1, y1, x2, y2) + IMU (omega, vx, vy); input (u_omega, u_v)",
        lambda: PlanarRigidBody(sensor="gps_imu"), lambda ys: measured_state("gps_imu", ys)),
    "tse2-velocity": SystemSpec(
        "tse2-velocity", "planar rigid body on TSE(2), IMU only (omega, vx, vy); input (u_omega, u_v)",
        lambda: PlanarRigidBody(sensor="velocity"), lambda ys: measured_state("velocity", ys)),
    "attitude": SystemSpec(
        "attitude",
        "rigid-body attitude on TSO(3) (Saccon et al. 2016), two body-frame directions of e3 and e2; input the "
        "torque (3); the weights of the paper's experiment",
        lambda: attitude.setup(attitude.AttitudeConfig()).system, attitude.measured_state),
    "chaplygin": SystemSpec(
        "chaplygin",
        "Chaplygin sleigh on SE(2) x R^2 (Rigo et al. 2023), GPS (x1, y1, x2, y2) + INS (omega, v); input "
        "(u_omega, u_v); the weights of the paper's experiment",
        lambda: chaplygin.make_system(chaplygin.ChaplyginConfig(sensor="gps_ins")),
        lambda ys: chaplygin.measured_state("gps_ins", ys)),
    "chaplygin-gps": SystemSpec(
        "chaplygin-gps",
        "Chaplygin sleigh on SE(2) x R^2 (Rigo et al. 2023), GPS only (x1, y1, x2, y2); input (u_omega, u_v)",
        lambda: chaplygin.make_system(chaplygin.ChaplyginConfig(sensor="gps")),
        lambda ys: chaplygin.measured_state("gps", ys)),
    "unit-circle": SystemSpec(
        "unit-circle",
        "unit circle with a biased gyro on SO(2) x R (Zamani et al.), vector measurement (cos theta, -sin theta) "
        "with D = 0.4 I; input the gyro reading (1)",
        lambda: unit_circle.setup(unit_circle.UnitCircleConfig()).system, unit_circle.measured_state),
    "attitude-bias": SystemSpec(
        "attitude-bias",
        "attitude and gyro bias on TSO(3) from an IMU at 285.714 Hz (BROAD's rate): input the gyro (3, rad/s), "
        "normalized accelerometer and magnetometer directions (acc_x..z, mag_x..z); the default MEMS noise "
        "levels and a dip of 68 deg (liemef.systems.attitude_bias)",
        attitude_gyro_bias, _attitude_bias.measured_state),
    "attitude-imu": SystemSpec(
        "attitude-imu",
        "attitude and gyro bias on TSO(3) with the IMU noise model (linear acceleration, magnetic disturbance, "
        "heading-only magnetometer): input the gyro (3, rad/s), the accelerometer and magnetometer directions and "
        "their raw norms (norm_acc m/s^2, norm_mag uT); defaults of liemef.systems.attitude_imu",
        attitude_imu, _attitude_bias.measured_state),
    "localization": SystemSpec(
        "localization",
        "planar localization on SE(2): input the odometry (v_x, v_y, omega), GPS fixes (gps_x, gps_y) with NaN "
        "between fixes; the default noise levels (liemef.systems.localization)",
        planar_localization, _gps_state),
}
"""Systems available to ``liemef run``, by name: each built as in its paper's experiment."""


def get_system(name: str) -> SystemSpec:
    """The system spec ``name``; a ValueError listing the valid names otherwise."""
    if name not in SYSTEMS:
        raise ValueError(f"system: expected one of {sorted(SYSTEMS)}, got {name!r}")
    return SYSTEMS[name]
