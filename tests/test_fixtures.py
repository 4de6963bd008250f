"""The suite's own fixtures (tests/conftest.py) reach every fixture that runs filters, whatever its scope."""

import math
import os

import pytest

import fast_compile
from liemef.codegen import _kernel


@pytest.fixture(scope="module")
def rule_seen_by_a_module_fixture():
    """What a module fixture that runs filters (the pinned figures, the tutorial) sees of the -O2 rule."""
    return _kernel.OPTIMIZE_AFTER_S


def test_no_rule_started_build_in_module_fixtures(rule_seen_by_a_module_fixture):
    """A function-scoped patch was set up after every module fixture: theirs saw the engine's own 2 s rule and
    started -O2 builds beside the tests (a cold run of the suite counted 78 s of compiler CPU while the
    tutorial's file ran)."""
    assert rule_seen_by_a_module_fixture == math.inf
    assert _kernel.OPTIMIZE_AFTER_S == math.inf


def test_a_test_can_still_set_the_rule_it_checks(monkeypatch):
    monkeypatch.setattr(_kernel, "OPTIMIZE_AFTER_S", 0.5)
    assert _kernel.OPTIMIZE_AFTER_S == 0.5


def test_the_suite_compiles_with_the_fast_flags_and_keeps_a_users_choice():
    """tests/conftest.py put tests/fast_compile.py's flags in this process's XLA_FLAGS (unless
    LIEMEF_TEST_XLA_DEFAULTS=1); a flag the user set keeps the user's value, and :func:`fast_compile.removed`
    gives back exactly what was there before."""
    named = {f.split("=", 1)[0] for f in os.environ.get("XLA_FLAGS", "").split()}
    wanted = {f.split("=", 1)[0] for f in fast_compile.FLAGS}
    if os.environ.get(fast_compile.OPT_OUT) == "1":
        assert not set(fast_compile.FLAGS) & set(os.environ.get("XLA_FLAGS", "").split())
    else:
        assert wanted <= named
    user = "--xla_backend_optimization_level=2 --xla_cpu_enable_concurrency_optimized_scheduler=false"
    both = fast_compile.added(user)
    assert both.split()[:2] == user.split() and "--xla_backend_optimization_level=0" not in both
    assert set(both.split()) == set(user.split()) | set(fast_compile.FLAGS[1:])
    assert fast_compile.removed(both) == user
    assert fast_compile.added("") == " ".join(fast_compile.FLAGS) and fast_compile.removed(fast_compile.added("")) == ""
