"""Where a filter finds the engines that run it.

A filter says how one sample interval advances (``AbstractFilter.interval``); what loops over intervals (a log,
a batch, a robot's loop) is the engines' layer, which sits above the filters and imports them. So the filters
never import the engines, nor name them: the package's root, the composition root above every layer, gives
them here a function that returns the engines' layer, loaded on first use (importing liemef stays cheap).
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType

_PROVIDER: list[Callable[[], ModuleType]] = []


def provide(provider: Callable[[], ModuleType]) -> None:
    """Give the filters the engines: ``provider()`` returns the layer with ``run``, ``run_batch``, ``scan``,
    ``step`` and ``online`` (each called with the filter first). A later call replaces an earlier one."""
    if not callable(provider):
        raise ValueError(f"provider: expected a callable returning the engines' layer, got {provider!r}")
    _PROVIDER[:] = [provider]


def engines() -> ModuleType:
    """The engines given by :func:`provide` (a RuntimeError if none were)."""
    if not _PROVIDER:
        raise RuntimeError("no engines were given to the filters: import liemef (its root gives them)")
    return _PROVIDER[0]()
