import math
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

# The command line keeps XLA's compiled programs in the user's cache folder (LIEMEF_XLA_CACHE=1, set by
# liemef.cli.main unless set already). The tests call main() in this process and start CLI subprocesses: off
# here, so that no test reads or writes ~/.cache/liemef; tests/test_program_cache.py turns it on for its own
# processes, each in a temporary folder.
os.environ.setdefault("LIEMEF_XLA_CACHE", "0")

# XLA compiles the suite's programs without its expensive optimisations, in this process and in the CLI processes
# the tests start (tests/fast_compile.py says why, what it saves and which check keeps XLA's defaults); before
# JAX starts its CPU backend, which reads XLA_FLAGS once. LIEMEF_TEST_XLA_DEFAULTS=1 keeps XLA's defaults.
import fast_compile  # noqa: E402  (imports nothing)

if os.environ.get(fast_compile.OPT_OUT) != "1":
    os.environ["XLA_FLAGS"] = fast_compile.added(os.environ.get("XLA_FLAGS", ""))

import pytest  # noqa: E402

import liemef._config  # noqa: F401  (switches JAX to float64 before any test creates an array)

# `make test` runs the files with `--dist loadfile --no-loadscope-reorder`: each file in one xdist worker, which
# compiles the programs its tests share once (split across two workers, each compiled them). The workers take
# files in collection order (xdist's own reorder, by number of tests, is off), so the heaviest come first and the
# last file to start is a short one: neither worker idles while the other finishes a long file. Seconds of each
# in one cold run (2 workers on 2 cores, December 2026, tests/fast_compile.py's flags); a file not named here
# keeps its place after them. Refresh the list from `--durations=0` when a file grows past these.
HEAVY_FIRST = ("test_engine.py", "test_groups.py", "test_pinned_figures.py", "test_export_c.py",  # 127-65 s
               "test_smoother.py", "test_hostile.py", "test_second_order_suite.py", "test_predict_update.py",  # 62-48
               "test_right_error.py", "test_cli_run.py", "test_sample_update.py", "test_innovations.py",  # 44-37 s
               "test_kernel_cache.py", "test_campaign.py", "test_cli.py", "test_compare.py",  # 31-29 s
               "test_jaxpr_c_primitives.py", "test_ukfm_attitude.py", "test_tutorial.py", "test_systems_3d.py")  # 28-19


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each file's tests as written


@pytest.fixture(autouse=True, scope="session")
def _no_background_optimized_builds():
    """No -O2 kernel build starts by the engine's rule (liemef.codegen._kernel.OPTIMIZE_AFTER_S: once a quick
    build has served 2 s of C calls) in the tests' own processes. A test's few runs of a large system reach that
    rule and start a build the test never uses (the -O2 build computes the quick build's bits,
    test_quick_and_optimized_builds_agree_bit_for_bit): up to 45 s of compiler CPU beside the tests for a
    9.6 MB kernel, on cores the other worker needs. ``Kernel.wait()`` and online filters still build it; the
    tests of the rule itself (tests/test_engine.py) set the threshold they check; CLI subprocesses keep the rule.
    Session-scoped: pytest sets up fixtures of wider scope first, so a function-scoped patch came after every
    module fixture, and those that run filters (the pinned figures, the tutorial, the second-order suite) started
    the builds it is meant to stop (tests/test_fixtures.py checks that one sees the patch)."""
    from liemef.codegen import _kernel

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_kernel, "OPTIMIZE_AFTER_S", math.inf)
        yield
