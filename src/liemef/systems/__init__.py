"""Ready models of the papers' systems, and :class:`System` for your own.

A system is data (parameters, B, D, Q, R) plus pure functions ``dynamics(g, u, t)`` and ``output(g, t)``;
the filter differentiates them by autodiff.
"""

from ._base import AbstractSystem, Block, System
from ._residuals import direction_residual, rotation_residual
from ._right import RightErrorSystem, invariant_sides, natural_error, right_error
from ._sensors import ConstantOutput, Noise, Sensor, SensorSystem
from .attitude import RigidBodyAttitude
from .attitude_bias import attitude_gyro_bias
from .attitude_field import attitude_field
from .attitude_so3 import ukfm_attitude
from .bounded_velocity import attitude_position, attitude_velocity
from .chaplygin import ChaplyginSleigh
from .imu_noise import attitude_imu
from .inertial import inertial_navigation
from .localization import planar_localization
from .planar_rigid_body import PlanarRigidBody, tse2_state
from .rigid_body_3d import pose3d
from .unit_circle import UnitCircleBias

__all__ = ["AbstractSystem", "System", "Block", "Noise", "Sensor", "SensorSystem", "ConstantOutput",
           "planar_localization", "attitude_gyro_bias", "attitude_imu", "attitude_velocity", "attitude_position",
           "attitude_field",
           "pose3d", "inertial_navigation",
           "ChaplyginSleigh", "PlanarRigidBody", "RigidBodyAttitude", "UnitCircleBias",
           "tse2_state", "direction_residual", "rotation_residual", "ukfm_attitude", "right_error", "RightErrorSystem",
           "invariant_sides", "natural_error"]
