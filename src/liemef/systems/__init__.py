"""Ready models of the papers' systems, and :class:`System` for your own.

A system is data (parameters, B, D, Q, R) plus pure functions ``dynamics(g, u, t)`` and ``output(g, t)``;
the filter differentiates them by autodiff.
"""

from ._base import AbstractSystem, System
from .attitude import RigidBodyAttitude
from .planar_rigid_body import PlanarRigidBody, tse2_state

__all__ = ["AbstractSystem", "System", "PlanarRigidBody", "RigidBodyAttitude", "tse2_state"]
