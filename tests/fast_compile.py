"""XLA's compile options for the test suite: every program a test compiles (the library's, the tests' own, those
of the CLI processes a test starts) is compiled without XLA's expensive optimisations.

Compiling is most of the suite's time: programs compiled once and run a few times on small logs. These flags
skip LLVM's expensive passes and XLA's fusion emitters, and compile such programs about 3x faster; a cold
``make test`` on 2 idle cores went from 1050 s to 678 s with them (December 2026). They enable no fast-math:
no operation changes its meaning, and every tolerance of the suite holds unchanged (the whole suite passes with
and without them). They do change the last bits of some results, so the one bit-for-bit check of XLA's numbers
against a stored file, ``tests/test_pinned_figures.py``, computes its figures in a process with XLA's defaults
(:func:`removed`), as a user's run has them. ``LIEMEF_TEST_XLA_DEFAULTS=1`` runs the whole suite with XLA's
defaults, as the library runs for its users.

``tests/conftest.py`` adds the flags to ``XLA_FLAGS`` before JAX starts its CPU backend. This module imports
nothing (it must load before NumPy, see tests/conftest.py).
"""

OPT_OUT = "LIEMEF_TEST_XLA_DEFAULTS"
FLAGS = ("--xla_backend_optimization_level=0", "--xla_llvm_disable_expensive_passes=true",
         "--xla_cpu_use_fusion_emitters=false", "--xla_cpu_parallel_codegen_split_count=1")


def _name(flag: str) -> str:
    return flag.split("=", 1)[0]


def added(flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with each of :data:`FLAGS` that it does not name already: a setting
    the user chose is kept."""
    named = {_name(f) for f in flags.split()}
    return " ".join([*flags.split(), *(f for f in FLAGS if _name(f) not in named)])


def removed(flags: str) -> str:
    """``flags`` without :data:`FLAGS`: XLA's defaults for what they set, everything else kept."""
    return " ".join(f for f in flags.split() if f not in FLAGS)
