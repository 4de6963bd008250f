"""The suite's own fixtures (tests/conftest.py) reach every fixture that runs filters, whatever its scope."""

import math

import pytest

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
