"""Code generation: a liemef filter as standalone C99 (``liemef export-c``), from the jaxpr of one step.

:func:`export_c` writes the header and source (scalar straight-line code, or loops over arrays for large n:
:data:`BACKENDS`); :class:`CFilter` loads a compiled export with ctypes;
:func:`jaxpr_to_c` is the translator underneath, for any traced JAX function over the primitives
:data:`PRIMITIVES`. The engines read only this module's names: :func:`kernel_for` (a filter's compiled
:class:`Kernel`, built, cached and loaded), :func:`fast_step_module` (the online step's extension, or None),
:func:`compiler` and :class:`EngineWarning`. See ``docs/export-c.md``.
"""

from ._cache import EngineWarning
from ._export import BACKENDS, CFLAGS, SCALAR_MAX_N, CFilter, ExportedC, build_shared, compiler, export_c, state_leaves
from ._fast import module as fast_step_module
from ._jaxpr_c import jaxpr_to_c
from ._kernel import Kernel, kernel_for
from ._primitives import PRIMITIVES, UnsupportedPrimitive

__all__ = ["BACKENDS", "CFLAGS", "PRIMITIVES", "SCALAR_MAX_N", "CFilter", "ExportedC", "UnsupportedPrimitive",
           "build_shared", "compiler", "export_c", "jaxpr_to_c", "state_leaves", "Kernel", "kernel_for",
           "EngineWarning", "fast_step_module"]
