"""The ready systems ``liemef run --system NAME`` filters recorded logs with, each built with the weights of its
paper's experiment, and how to read a first state estimate off a measurement."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...systems import (
    AbstractSystem,
    PlanarRigidBody,
    attitude_field,
    attitude_gyro_bias,
    attitude_imu,
    attitude_position,
    attitude_velocity,
    inertial_navigation,
    planar_localization,
    pose3d,
    ukfm_attitude,
)
from ...systems import attitude_bias as _attitude_bias
from ...systems import attitude_so3 as _attitude_so3
from ...systems import bounded_velocity as ab_vel
from ...systems import imu_rest as ab_rest
from ...systems.attitude_field import K0_FIELD, field_log_rest_constants, field_measured_state
from .. import registry
from . import attitude, chaplygin, unit_circle
from .tse2 import measured_state


@dataclass(frozen=True)
class SystemSpec:
    """A ready system for filtering recorded logs (``liemef run --system NAME``).

    Its name is one of :data:`liemef.studies.registry.SYSTEMS`, which declares its description and run options.
    ``make()`` builds the system; ``measured(ys)`` reads the state coordinates off measurements (N, p)
    (NaN where not measured); ``initial_guess(ys0)`` is the default initial estimate in coordinates from the
    first measurement (unmeasured coordinates 0). ``K0``: the default initial gain (None: the identity);
    ``constants(ts, us, ys)``: the factory's keyword arguments measured from the log
    before the run (the IMU systems' dip, gravity and field over the rest found in the log,
    :func:`liemef.systems.imu_rest.log_rest_constants`), None for a system that takes none.
    """

    name: str
    make: Callable[..., AbstractSystem] = field(repr=False)
    measured: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    K0: np.ndarray | None = field(default=None, repr=False)
    constants: Callable[..., dict] | None = field(default=None, repr=False)

    @property
    def description(self) -> str:
        """What the command line says of it (:data:`liemef.studies.registry.SYSTEMS`)."""
        return registry.SYSTEMS[self.name].description

    @property
    def run_options(self) -> dict:
        """The filter options it runs with unless the user gives them (:data:`liemef.studies.registry.SYSTEMS`)."""
        return dict(registry.SYSTEMS[self.name].run_options)

    def initial_guess(self, ys0) -> np.ndarray:
        """State coordinates read off the first measurement ``ys0`` (p,), 0 where not measured."""
        q = self.measured(np.asarray(ys0, dtype=np.float64)[None, :])[0]
        return np.where(np.isfinite(q), q, 0.0)


def _gps_state(ys) -> np.ndarray:
    """(theta, x, y) read off GPS fixes (N, 2): the position where a fix is present; the heading is not
    measured (NaN, so the initial guess is 0)."""
    ys = np.asarray(ys, dtype=np.float64)
    return np.concatenate([np.full((ys.shape[0], 1), np.nan), ys[:, 0:2]], axis=1)


def _position_fix_state(n_before: int):
    """Coordinates read off position fixes (N, 3) in the first three outputs: the position where a fix is
    present, after ``n_before`` coordinates that are not measured (NaN: the rotation vector, and the velocity of
    SE_2(3))."""
    def measured(ys) -> np.ndarray:
        ys = np.asarray(ys, dtype=np.float64)
        return np.concatenate([np.full((ys.shape[0], n_before), np.nan), ys[:, 0:3]], axis=1)
    return measured


SYSTEMS: dict[str, SystemSpec] = {
    "tse2": SystemSpec(
        "tse2", lambda: PlanarRigidBody(sensor="gps_imu"), lambda ys: measured_state("gps_imu", ys)),
    "tse2-velocity": SystemSpec(
        "tse2-velocity", lambda: PlanarRigidBody(sensor="velocity"), lambda ys: measured_state("velocity", ys)),
    "attitude": SystemSpec(
        "attitude", lambda: attitude.setup(attitude.AttitudeConfig()).system, attitude.measured_state),
    "chaplygin": SystemSpec(
        "chaplygin",
        lambda: chaplygin.make_system(chaplygin.ChaplyginConfig(sensor="gps_ins")),
        lambda ys: chaplygin.measured_state("gps_ins", ys)),
    "chaplygin-gps": SystemSpec(
        "chaplygin-gps",
        lambda: chaplygin.make_system(chaplygin.ChaplyginConfig(sensor="gps")),
        lambda ys: chaplygin.measured_state("gps", ys)),
    "unit-circle": SystemSpec(
        "unit-circle", lambda: unit_circle.setup(unit_circle.UnitCircleConfig()).system, unit_circle.measured_state),
    "attitude-bias": SystemSpec("attitude-bias", attitude_gyro_bias, _attitude_bias.measured_state),
    "attitude-imu": SystemSpec(
        "attitude-imu", attitude_imu, _attitude_bias.measured_state,
        constants=ab_rest.log_rest_constants),
    "attitude-velocity": SystemSpec(
        "attitude-velocity", attitude_velocity,
        ab_vel.velocity_measured_state, K0=ab_vel.K0_VELOCITY, constants=ab_rest.log_rest_constants),
    "attitude-position": SystemSpec(
        "attitude-position", attitude_position,
        ab_vel.position_measured_state, K0=ab_vel.K0_POSITION, constants=ab_rest.log_rest_constants),
    "attitude-field": SystemSpec(
        "attitude-field", attitude_field, field_measured_state, K0=K0_FIELD, constants=field_log_rest_constants),
    "pose3d": SystemSpec("pose3d", pose3d, _position_fix_state(3)),
    "inertial-navigation": SystemSpec("inertial-navigation", inertial_navigation, _position_fix_state(6)),
    "localization": SystemSpec("localization", planar_localization, _gps_state),
    "ukfm-attitude": SystemSpec("ukfm-attitude", ukfm_attitude, _attitude_so3.measured_state),
}
"""How each ready system of :data:`liemef.studies.registry.SYSTEMS` is built (as in its paper's experiment) and read
off its measurements, by the same names."""


def get_system(name: str) -> SystemSpec:
    """The system spec ``name``; a ValueError listing the valid names otherwise."""
    if name not in SYSTEMS:
        raise ValueError(f"system: expected one of {sorted(SYSTEMS)}, got {name!r}")
    return SYSTEMS[name]
