"""Code generation: a liemef filter as standalone C99 (``liemef export-c``), from the jaxpr of one step.

:func:`export_c` writes the header and source (scalar straight-line code, or loops over arrays for large n:
:data:`BACKENDS`); :class:`CFilter` loads a compiled export with ctypes;
:func:`jaxpr_to_c` is the translator underneath, for any traced JAX function over the primitives
:data:`PRIMITIVES`. See ``docs/export-c.md``.
"""

from ._export import BACKENDS, CFLAGS, SCALAR_MAX_N, CFilter, ExportedC, build_shared, compiler, export_c, state_leaves
from ._jaxpr_c import jaxpr_to_c
from ._primitives import PRIMITIVES, UnsupportedPrimitive

__all__ = ["BACKENDS", "CFLAGS", "PRIMITIVES", "SCALAR_MAX_N", "CFilter", "ExportedC", "UnsupportedPrimitive",
           "build_shared", "compiler", "export_c", "jaxpr_to_c", "state_leaves"]
