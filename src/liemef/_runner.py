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
_LOADED: list[ModuleType] = []  # the provider's result, kept: engines() is on the online step's path


def provide(provider: Callable[[], ModuleType]) -> None:
    """Give the filters the engines: ``provider()`` returns the layer with ``run``, ``run_batch``, ``scan``,
    ``step`` and ``online`` (each called with the filter first), once. A later call replaces an earlier one."""
    if not callable(provider):
        raise ValueError(f"provider: expected a callable returning the engines' layer, got {provider!r}")
    _PROVIDER[:] = [provider]
    _LOADED.clear()


def engines() -> ModuleType:
    """The engines given by :func:`provide`, loaded on the first call (a RuntimeError if none were given)."""
    if _LOADED:
        return _LOADED[0]
    if not _PROVIDER:
        raise RuntimeError("no engines were given to the filters: import liemef (its root gives them)")
    _LOADED[:] = [_PROVIDER[0]()]
    return _LOADED[0]
