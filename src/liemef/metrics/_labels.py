from __future__ import annotations

from ..systems import AbstractSystem, PlanarRigidBody
from ..systems import planar_rigid_body as _prb

# Names and units of the coordinates of the ready systems, until systems carry them themselves.
_KNOWN: dict[type, tuple[tuple[str, ...], tuple[str, ...]]] = {
    PlanarRigidBody: (_prb.STATE_NAMES, _prb.STATE_UNITS),
}


def state_labels(system: AbstractSystem) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and units of the system's state coordinates (``group.coords()``), e.g. for TSE(2)
    ``("theta", "x", "y", "omega", "vx", "vy")`` in ``("rad", "m", "m", "rad/s", "m/s", "m/s")``.

    Uses ``system.state_names`` / ``system.state_units`` when the system defines them; otherwise the ready
    systems' tables; otherwise ``q1, q2, ...`` without units.
    """
    names = getattr(system, "state_names", None)
    units = getattr(system, "state_units", None)
    if names is not None and units is not None:
        return tuple(names), tuple(units)
    for cls, labels in _KNOWN.items():
        if isinstance(system, cls):
            return labels
    c = system.group.coords_dim
    return tuple(f"q{k + 1}" for k in range(c)), ("",) * c


def group_error_labels(system: AbstractSystem) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and units of the components of :func:`~liemef.metrics.group_error`: ``log_<coordinate>`` when
    the coordinates and the algebra have the same size (TSE(2)), else ``xi1, xi2, ...`` without units."""
    names, units = state_labels(system)
    n = system.group.tangent_dim
    if len(names) == n:
        return tuple(f"log_{s}" for s in names), units
    return tuple(f"xi{k + 1}" for k in range(n)), ("",) * n
