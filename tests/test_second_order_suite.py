"""The second-order safety suite (``liemef compare second-order``): it runs every row it is asked for, its numbers
are finite where a run is ok, first order runs through, and the failures of the second-order default that issue 31
reported appear."""

import math

import jax
import numpy as np
import pytest

from liemef.studies import registry
from liemef.studies.compare import STUDIES, failures
from liemef.studies.compare._second_order import (
    CASES,
    FILTERS,
    SecondOrderSuite,
    better_updates,
    compare_second_order,
    markdown,
    table_rows,
    trials,
)

FAST_SYSTEMS = ("quad-range", "se2-bearing")
FAST_FILTERS = ("mef-hold", "mef-discrete", "mef-first", "iekf")
FAST_DURATION = 10.0
"""The fast fixture's trials' duration (s); the other tests simulate their systems on the same grid, so that each
system's simulation compiles once in the file."""


def _row(failed, nees, dof=3):
    return {"failed": failed, "nees": nees, "dof": dof}


def test_the_first_order_row_takes_the_better_second_order_updates():
    assert better_updates({"mef-hold": _row(0, 40.0), "mef-discrete": _row(1, 3.0)}) == "hold"
    assert better_updates({"mef-hold": _row(0, 40.0), "mef-discrete": _row(0, 3.5)}) == "discrete"
    assert better_updates({"mef-hold": _row(2, None), "mef-discrete": _row(2, None)}) == "discrete"
    assert better_updates({}) == "discrete"


def test_the_suite_is_registered_with_twelve_systems_and_checks_its_settings():
    assert "second-order" in registry.names("comparison") and "second-order" in STUDIES
    assert len(CASES) >= 12
    with pytest.raises(ValueError, match="systems"):
        SecondOrderSuite(systems="quad-range,nowhere")
    with pytest.raises(ValueError, match="filters"):
        SecondOrderSuite(filters="mef-hold,mef-hold")
    with pytest.raises(ValueError, match="duration"):
        SecondOrderSuite(duration=0.5)
    for bad in (-0.5, float("nan"), True, "1"):
        with pytest.raises(ValueError, match="initial_scale"):
            SecondOrderSuite(initial_scale=bad)


@pytest.mark.parametrize("scale", [0.0, 0.5])
def test_the_initial_scale_scales_the_drawn_initial_error(scale):
    """``initial_scale`` multiplies each trial's drawn error log(g0^-1 g_hat0); 0 starts every filter at the truth.
    (The fast fixture's bearing-only SE(2) of 10 s: the same compiled simulation.)"""
    case = CASES["se2-bearing"][1](FAST_DURATION)
    truth, _, _, drawn = trials(case, 2, 0)
    _, _, _, scaled = trials(case, 2, 0, initial_scale=scale)
    g0 = jax.tree_util.tree_map(lambda a: a[:, 0], truth)
    e_drawn, e_scaled = np.asarray(drawn.rminus(g0)), np.asarray(scaled.rminus(g0))
    assert np.abs(e_drawn).min() > 1e-4
    np.testing.assert_allclose(e_scaled, scale * e_drawn, atol=1e-12)


@pytest.fixture(scope="module")
def fast():
    """2 trials of 10 s of the quadrotor (range + magnetometer) and the bearing-only SE(2) of the issue."""
    return compare_second_order(SecondOrderSuite(runs=2, duration=FAST_DURATION, systems=FAST_SYSTEMS,
                                                 filters=FAST_FILTERS), progress=False)


def _check_rows(result, systems, filters):
    assert list(result["cases"]) == list(systems)
    for s in result["cases"].values():
        assert list(s["filters"]) == list(filters)
        for r in s["filters"].values():
            assert r["runs"] - r["failed"] == r["runs"] - len(r["failures"])
            lo, hi = r["nees_band"]
            assert 0 < lo < s["dof"] < hi
            if r["status"] == "not applicable":  # a filter of sensor systems on a paper's system
                assert r["nees"] is None and r["monitor_trials"] == []
            elif r["status"] == "ok":
                assert math.isfinite(r["nees"]) and r["nees"] >= 0
                assert r["attitude_deg"] is None or math.isfinite(r["attitude_deg"])
                assert r["position_m"] is None or math.isfinite(r["position_m"])
            else:
                assert r["failures"] and r["failures"][0]["cause"] != "ok"
    assert len(table_rows(result)) == len(systems) * len(filters)


def test_the_fast_suite_runs_every_row_with_finite_numbers_where_ok(fast):
    _check_rows(fast, FAST_SYSTEMS, FAST_FILTERS)
    text = markdown(fast)
    # the results' header and rows, then the sides' header and one row per system
    assert text.count("\n| ") == 1 + len(FAST_SYSTEMS) * len(FAST_FILTERS) + 1 + len(FAST_SYSTEMS)
    assert "| quad-range | range: neither, mag: right | right | right |" in text


def test_first_order_and_the_iekf_run_through_where_the_second_order_filter_fails(fast):
    """Issue 31's evidence on the quadrotor: the second-order filter with held samples loses K's definiteness
    (at 8.8 s in trial 0) and with discrete samples it fails or reports a NEES far above its band; first order
    and the invariant EKF run every trial of both systems (the line-searched discrete update runs the
    bearing-only SE(2) the issue saw fail at 0.1 s)."""
    cases = fast["cases"]
    for s in cases.values():
        for name in ("mef-first", "iekf"):
            assert s["filters"][name]["status"] == "ok"
    quad = cases["quad-range"]["filters"]
    assert quad["mef-hold"]["failed"] >= 1 and quad["mef-hold"]["failures"][0]["cause"] == "K not positive definite"
    assert quad["mef-discrete"]["failed"] >= 1 or quad["mef-discrete"]["nees_flag"] == "far above"
    assert cases["se2-bearing"]["filters"]["mef-discrete"]["nees_flag"] == "within"
    lines, failed, total = failures(fast)
    assert failed >= quad["mef-hold"]["failed"] and total == 2 * len(FAST_SYSTEMS) * len(FAST_FILTERS)
    assert any("quad-range" in line and "mef-hold" in line for line in lines)


def test_the_two_quadrotors_are_one_system_on_two_groups():
    """quad-range-world is quad-range written on SO(3) x R^3 x R^3: the same truth (rotation vector, world velocity
    and position) and the same samples from the same keys, to the integrators' accuracy, over the fast fixture's
    10 s (the simulations it and the SO(3) x R^6 test compile)."""
    se23, world = (trials(CASES[name][1](FAST_DURATION), 1, 0) for name in ("quad-range", "quad-range-world"))
    np.testing.assert_allclose(np.asarray(world[0].coords()), np.asarray(se23[0].coords()), atol=1e-9)
    np.testing.assert_array_equal(world[1], se23[1])
    np.testing.assert_allclose(world[2], se23[2], atol=1e-9)


def test_on_so3_r6_the_quadrotor_is_consistent_where_on_se23_it_is_not(fast):
    """The far-above NEES of the quadrotor is its group's: the same flight, sensors and draws on SO(3) x R^3 x R^3
    (world-frame velocity and position) leave every held second-order filter within its band, the exact curvature
    included, which on SE_2(3) loses K's definiteness (the fast fixture's quad-range rows, the same trials)."""
    assert fast["cases"]["quad-range"]["filters"]["mef-hold"]["failed"] >= 1
    world = compare_second_order(SecondOrderSuite(runs=2, duration=FAST_DURATION, systems="quad-range-world",
                                                  filters="mef-hold,mef-hold-safe"), progress=False)
    _check_rows(world, ("quad-range-world",), ("mef-hold", "mef-hold-safe"))
    for name, r in world["cases"]["quad-range-world"]["filters"].items():
        assert r["status"] == "ok" and r["nees_flag"] == "within", (name, r["status"], r["nees"])
        assert r["monitor_trials"] == ["consistent"] * 2 and r["leak"] < 0.01, (name, r["leak"])


def test_the_leak_tells_the_two_quadrotors_apart(fast):
    """The linearization leak (liemef.metrics.linearization_leak) of the range sensor: on SE_2(3) its median
    window is above the monitor's limit of 1 for the first order and the invariant EKF, whose NEES is far above
    its band; on SE(2) with bearings to 3 landmarks it is far below it (the fast fixture's 10 s trials end before
    a leak can last the sustain time, 7.5 s from the first window at 5 s, so this is the leak, not the status)."""
    quad = fast["cases"]["quad-range"]["filters"]
    for name in ("mef-first", "iekf"):
        assert quad[name]["leak"] > 1.0, (name, quad[name]["leak_trials"])
    for name, r in fast["cases"]["se2-bearing"]["filters"].items():
        assert r["leak"] < 0.01, (name, r["leak_trials"])


@pytest.mark.slow  # the whole study: 14 systems x 11 filters x 5 trials of 20 s, 20-40 minutes on the C engine
def test_the_full_suite():
    result = compare_second_order(SecondOrderSuite(), progress=False)
    _check_rows(result, tuple(CASES), tuple(FILTERS))
    rows = {name: s["filters"] for name, s in result["cases"].items()}
    for name, r in rows.items():
        assert r["mef-first"]["status"] == "ok", name
    # the reproduced failures of the second-order filter: K loses definiteness, or the run says "ok" with a NEES
    # far above its band
    for name in ("quad-range", "quad-altimeter", "ins-baro-mag"):
        assert rows[name]["mef-hold"]["failed"] >= 1, name
        r = rows[name]["mef-discrete"]
        assert r["failed"] >= 1 or r["nees_flag"] == "far above", name
    nees = np.array([rows[n]["mef-first"]["nees"] / rows[n]["mef-first"]["dof"] for n in ("ins-gnss", "attitude")])
    assert np.all(nees < 3.0)
    # issue 31's bar: where the default runs with a NEES far above its band, no trial of it is called consistent
    # (docs/second-order.md)
    for name, r in rows.items():
        d = r["mef-hold-safe"]
        if d["status"] == "ok" and d["nees_flag"] == "far above":
            assert "consistent" not in d["monitor_trials"], (name, d["monitor_trials"])
    # and so for every far-above row of the first order, the invariant EKF and the UKF-M on the SE_2(3) systems
    for name in ("quad-range", "quad-altimeter", "ins-baro-mag"):
        for f in ("mef-first", "mef-first-hold", "mef-first-iterated", "iekf", "ukf-m"):
            r = rows[name][f]
            if r["nees_flag"] == "far above":
                assert "consistent" not in r["monitor_trials"], (name, f, r["monitor_trials"])
    # the defaults choose the right error on the near landmark and keep K there, where the left error is far above
    assert rows["se2-near-rb"]["mef-hold-left"]["nees_flag"] == "far above"
    assert rows["se2-near-rb"]["mef-hold-safe"]["nees_flag"] == "within"
    assert result["cases"]["se2-near-rb"]["error"] == "right"
    # and the two sides agree where every direction is observed
    for name in ("se2-bearing", "se2-range"):
        r, d = rows[name]["mef-hold-right"], rows[name]["mef-hold-left"]
        assert math.isclose(r["nees"], d["nees"], rel_tol=0.05) and math.isclose(r["position_m"], d["position_m"],
                                                                                 rel_tol=0.05), name
