import os
import sys

# OpenBLAS chooses its kernels by the CPU it runs on: on an AVX-512 CPU (AMD Zen 4) its matrix products round
# differently in the last bits from the AVX2 kernels (Zen 1, Haswell and later), and a few figures of
# tests/test_pinned_figures.py, amplified by a filter run, then differ at 1e-9. The pins hold the bits of one
# computation, so the tests ask OpenBLAS for its Haswell kernels on every AVX2 CPU. This must run before NumPy
# loads OpenBLAS: pyproject's addopts keep jaxtyping's pytest plugin (which imports NumPy) out, and the CLI
# subprocesses inherit the variable. A user's runs keep OpenBLAS's own choice.
if "numpy" in sys.modules:
    raise RuntimeError("tests/conftest.py must run before NumPy is imported (OPENBLAS_CORETYPE below)")
if os.path.exists("/proc/cpuinfo"):
    with open("/proc/cpuinfo") as _f:
        if " avx2" in _f.read():
            os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")

import liemef._config  # noqa: F401  (switches JAX to float64 before any test creates an array)
