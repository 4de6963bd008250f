"""liemef: second-order-optimal minimum-energy filtering on matrix Lie groups.

The package is layered, and each layer imports only the ones below it (``tests/test_layers.py`` checks it);
the layers, the conventions and the reasons for each design decision are described once, in ``docs/design.md``.

Importing the package is cheap: JAX and the submodules load on first use (``liemef.MinimumEnergyFilter``,
``from liemef import simulate``, ``import liemef.groups``, ...), so ``liemef --help`` answers without JAX.
Whatever path loads them, :mod:`liemef._config` runs first and switches JAX to float64 before liemef creates an
array (if JAX is already imported when ``liemef`` is, it runs at once).
"""

from __future__ import annotations

import contextlib
import importlib
import sys
from typing import TYPE_CHECKING

from . import _runner

__all__ = ["MinimumEnergyFilter", "FilterState", "Trajectory", "Terms", "Connection", "connection", "simulate",
           "SensorLog", "Truth", "smooth", "Smoothed", "groups", "systems", "connections", "simulation", "metrics"]
__version__ = "0.1.0"

# Public names and the submodule each comes from (None: the name is itself a submodule).
_ATTRS = {
    "MinimumEnergyFilter": "filters", "FilterState": "filters", "Trajectory": "filters", "Terms": "filters",
    "Connection": "connections", "connection": "connections",
    "simulate": "simulation", "SensorLog": "simulation", "Truth": "simulation",
    "smooth": "smoothers", "Smoothed": "smoothers",
}
# Submodules reachable as attributes of the package without an explicit import.
_SUBMODULES = frozenset({"groups", "connections", "integrators", "systems", "simulation", "filters", "codegen",
                         "engines", "smoothers", "metrics", "studies", "reports"})
# Modules (dotted below the package) that load without JAX: importing them does not run _config.
_JAX_FREE = frozenset({"cli", "__main__", "_config", "_cachedirs", "_names", "_validate", "_runner", "studies",
                        "studies.registry", "studies.commands", "studies.logs", "studies.runs", "studies.settings",
                        "studies._schemas", "reports", "reports.outputs", "reports.io"})

if TYPE_CHECKING:  # what the lazy names are, for type checkers and IDEs
    from . import (  # noqa: F401
        codegen,
        connections,
        engines,
        filters,
        groups,
        integrators,
        metrics,
        reports,
        simulation,
        smoothers,
        studies,
        systems,
    )
    from .connections import Connection, connection
    from .filters import FilterState, MinimumEnergyFilter, Terms, Trajectory
    from .simulation import SensorLog, Truth, simulate
    from .smoothers import Smoothed, smooth


def _enable_float64() -> None:
    """Import :mod:`liemef._config` (JAX in float64) once; after that the import hook is not needed."""
    with contextlib.suppress(ValueError):
        sys.meta_path.remove(_FLOAT64_FIRST)
    importlib.import_module("._config", __name__)


class _Float64First:
    """Import hook: before the first liemef submodule that may use JAX loads, run :mod:`liemef._config`.

    It finds nothing itself (``find_spec`` returns None, the usual finders load the module); it only makes
    ``import liemef.groups`` (or any other submodule, directly or through :func:`__getattr__`) switch float64 on
    first, as importing every submodule eagerly in this file did.
    """

    @staticmethod
    def find_spec(fullname, path=None, target=None):
        package, _, rest = fullname.partition(".")
        if package == __name__ and rest and rest not in _JAX_FREE:
            _enable_float64()
        return None


# The composition root: the filters' run, step and online methods reach the engines above them through this slot
# (they never import them), loaded on first use.
_runner.provide(lambda: importlib.import_module(".engines", __name__))

_FLOAT64_FIRST = _Float64First()
if "jax" in sys.modules:  # JAX is loaded already: nothing to save, configure it now
    _enable_float64()
elif f"{__name__}._config" not in sys.modules:
    sys.meta_path.insert(0, _FLOAT64_FIRST)


def __getattr__(name: str):
    """PEP 562: load a public name's submodule on first access (after :mod:`liemef._config`)."""
    if name in _ATTRS or name in _SUBMODULES:
        _enable_float64()  # the import hook would too; explicit here
    if name in _ATTRS:
        value = getattr(importlib.import_module(f".{_ATTRS[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__, *_SUBMODULES})
