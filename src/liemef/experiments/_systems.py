from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..systems import AbstractSystem, PlanarRigidBody
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
        q = self.measured(np.asarray(ys0, dtype=np.float64)[None, :])[0]
        return np.where(np.isfinite(q), q, 0.0)


SYSTEMS: dict[str, SystemSpec] = {
    "tse2": SystemSpec(
        "tse2",
        "planar rigid body on TSE(2), GPS (x1, y1, x2, y2) + IMU (omega, vx, vy); input (u_omega, u_v)",
        lambda: PlanarRigidBody(sensor="gps_imu"), lambda ys: measured_state("gps_imu", ys)),
    "tse2-velocity": SystemSpec(
        "tse2-velocity", "planar rigid body on TSE(2), IMU only (omega, vx, vy); input (u_omega, u_v)",
        lambda: PlanarRigidBody(sensor="velocity"), lambda ys: measured_state("velocity", ys)),
}
"""Systems available to ``liemef run``, by name."""


def get_system(name: str) -> SystemSpec:
    """The system spec ``name``; a ValueError listing the valid names otherwise."""
    if name not in SYSTEMS:
        raise ValueError(f"system: expected one of {sorted(SYSTEMS)}, got {name!r}")
    return SYSTEMS[name]
