from __future__ import annotations

from ..systems import AbstractSystem


def state_labels(system: AbstractSystem) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and units of the system's state coordinates (``group.coords()``), e.g. for TSE(2)
    ``("theta", "x", "y", "omega", "vx", "vy")`` in ``("rad", "m", "m", "rad/s", "m/s", "m/s")``."""
    return tuple(system.state_names), tuple(system.state_units)


def group_error_labels(system: AbstractSystem) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and units of the components of :func:`~liemef.metrics.group_error`: ``log_<coordinate>`` when
    the coordinates and the algebra have the same size (TSE(2)), else ``xi1, xi2, ...`` without units."""
    names, units = state_labels(system)
    n = system.group.tangent_dim
    if len(names) == n:
        return tuple(f"log_{s}" for s in names), units
    return tuple(f"xi{k + 1}" for k in range(n)), ("",) * n
