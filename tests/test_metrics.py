"""Errors and statistics against hand-computed cases."""

import json
import math

import jax
import numpy as np
import pytest

from liemef.groups import SE2, SO2R1, SO3, TSE2, TSO3, Rn
from liemef.metrics import (
    FULL,
    Window,
    angle_mask,
    continuous_angles,
    coordinate_error,
    error_stats,
    error_table,
    gain_stats,
    group_error,
    group_error_labels,
    state_error,
    state_labels,
    wrap_angle,
)
from liemef.systems import PlanarRigidBody, RigidBodyAttitude, tse2_state
from tolerances import ROUNDOFF

PI = math.pi


@pytest.mark.parametrize(("a", "wrapped"), [
    (0.5, 0.5), (-0.5, -0.5), (PI, -PI), (-PI, -PI), (3 * PI, -PI), (2 * PI, 0.0), (-3.5, -3.5 + 2 * PI),
    (3.5, 3.5 - 2 * PI), (7.0, 7.0 - 2 * PI), (-7.0, -7.0 + 2 * PI),
])
def test_wrap_angle_maps_to_minus_pi_inclusive_pi_exclusive(a, wrapped):
    assert abs(float(wrap_angle(a)) - wrapped) < ROUNDOFF * 10


def test_there_is_one_angle_wrap():
    """metrics' wrap_angle is the residuals' (one convention, one place)."""
    from liemef.systems._residuals import wrap_angle as residual_wrap

    assert wrap_angle is residual_wrap


def test_angle_masks_follow_the_coordinates():
    assert angle_mask(TSE2) == (True, False, False, False, False, False)
    assert angle_mask(SO2R1) == (True, False)
    assert angle_mask(SE2) == (True, False, False)
    assert angle_mask(TSO3) == (False,) * 6  # a rotation vector is not an angle to wrap


def test_coordinate_error_wraps_across_pi():
    # truth just below pi, estimate just above -pi: they are 0.1 apart, not 2 pi - 0.1
    truth = np.array([[PI - 0.05, 1.0, 2.0]])
    est = np.array([[-PI + 0.05, 0.5, 2.5]])
    d = np.asarray(coordinate_error(truth, est, (True, False, False)))
    np.testing.assert_allclose(d, [[-0.1, 0.5, -0.5]], rtol=0, atol=ROUNDOFF * 10)
    np.testing.assert_allclose(coordinate_error(est, truth, (True, False, False)), [[0.1, -0.5, 0.5]], rtol=0,
                               atol=ROUNDOFF * 10)
    # an unwrapped component keeps its 2 pi
    np.testing.assert_allclose(coordinate_error([4.0], [4.0 - 2 * PI], (False,)), [2 * PI], rtol=0,
                               atol=ROUNDOFF)


def test_state_error_of_tse2_elements_is_truth_minus_estimate_with_the_heading_wrapped():
    g = tse2_state(PI - 0.05, 1.0, 2.0, 0.3, -0.2, 0.1)
    g_hat = tse2_state(-PI + 0.05, 1.5, 1.0, 0.1, 0.2, 0.0)
    np.testing.assert_allclose(state_error(g, g_hat), [-0.1, -0.5, 1.0, 0.2, -0.4, 0.1], rtol=0, atol=1e-11)


def test_group_error_is_the_body_frame_log():
    g_hat = tse2_state(2.0, 1.0, -1.0, 0.3, 0.2, 0.1)
    xi = np.array([0.1, -0.2, 0.3, 0.05, -0.02, 0.01])
    g = g_hat.rplus(xi)
    np.testing.assert_allclose(group_error(g, g_hat), xi, rtol=0, atol=ROUNDOFF * 10)
    np.testing.assert_allclose(group_error(g_hat, g_hat), np.zeros(6), rtol=0, atol=ROUNDOFF)
    # hand case: same position, headings pi/2 apart -> pure rotation error pi/2
    a = TSE2((SE2.from_coords(np.array([PI / 2, 3.0, 4.0])), g_hat.factors[1]))
    b = TSE2((SE2.from_coords(np.array([0.0, 3.0, 4.0])), g_hat.factors[1]))
    np.testing.assert_allclose(group_error(a, b), [PI / 2, 0, 0, 0, 0, 0], rtol=0, atol=ROUNDOFF * 10)
    # batched
    gb = jax.tree_util.tree_map(lambda x: np.stack([x, x]), g)
    hb = jax.tree_util.tree_map(lambda x: np.stack([x, x]), g_hat)
    assert group_error(gb, hb).shape == (2, 6)
    assert state_error(gb, hb).shape == (2, 6)


def test_error_stats_by_hand():
    ts = np.array([0.0, 1.0, 2.0, 3.0])
    e = np.array([[1.0, -1.0], [2.0, 1.0], [3.0, -1.0], [4.0, 1.0]])
    s = error_stats(ts, e)
    np.testing.assert_allclose(s["mean"], [2.5, 0.0], atol=ROUNDOFF)
    np.testing.assert_allclose(s["std"], [math.sqrt(1.25), 1.0], atol=ROUNDOFF)
    np.testing.assert_allclose(s["rms"], [math.sqrt(7.5), 1.0], atol=ROUNDOFF)
    assert int(s["count"]) == 4
    w = error_stats(ts, e, Window(1.0, 2.0))  # both ends included: samples 2 and 3
    np.testing.assert_allclose(w["mean"], [2.5, 0.0], atol=ROUNDOFF)
    np.testing.assert_allclose(w["std"], [0.5, 1.0], atol=ROUNDOFF)
    np.testing.assert_allclose(w["rms"], [math.sqrt(6.5), 1.0], atol=ROUNDOFF)
    np.testing.assert_allclose(w["rms"] ** 2, w["mean"] ** 2 + w["std"] ** 2, atol=ROUNDOFF)
    empty = error_stats(ts, e, Window(10.0, 50.0))
    assert int(empty["count"]) == 0 and np.all(np.isnan(empty["mean"]))


def test_error_stats_vmap_over_trials():
    ts = np.linspace(0.0, 1.0, 11)
    e = np.random.default_rng(0).normal(size=(5, 11, 3))
    batched = jax.vmap(lambda x: error_stats(ts, x, Window(0.2, 0.8)))(e)
    for i in range(5):
        single = error_stats(ts, e[i], Window(0.2, 0.8))
        np.testing.assert_allclose(batched["rms"][i], single["rms"], atol=ROUNDOFF)


def test_error_table_structure_format_and_json():
    ts = np.array([0.0, 1.0, 2.0, 3.0])
    e = np.array([[1.0, -1.0], [2.0, 1.0], [3.0, -1.0], [4.0, 1.0]])
    table = error_table(ts, e, ("theta", "x"), ("rad", "m"), (FULL, Window(1.0, 2.0), Window(10.0, 50.0)))
    d = table.to_dict()
    assert list(d) == ["theta", "x"]
    assert d["theta"]["unit"] == "rad"
    assert set(d["theta"]) == {"unit", "full", "1-2s", "10-50s"}
    assert d["theta"]["full"] == pytest.approx({"mean": 2.5, "std": math.sqrt(1.25), "rms": math.sqrt(7.5)})
    assert d["x"]["10-50s"] == {"mean": None, "std": None, "rms": None}  # empty window: null, not NaN
    json.dumps(d, allow_nan=False)
    assert table.windows_dict()["1-2s"] == {"start": 1.0, "stop": 2.0, "samples": 2}
    text = table.format()
    assert "theta" in text and "rad" in text and "rms(10-50s)" in text and "2.500e+00" in text
    with pytest.raises(ValueError, match="names/units: expected 2"):
        error_table(ts, e, ("theta",), ("rad",))
    with pytest.raises(ValueError, match=r"errors: expected shape \(4, c\)"):
        error_table(ts, e[:3], ("theta", "x"), ("rad", "m"))


def test_non_finite_errors_give_null_statistics():
    ts = np.array([0.0, 1.0])
    table = error_table(ts, np.array([[np.nan], [1.0]]), ("x",), ("m",))
    assert table.to_dict()["x"]["full"]["rms"] is None


def test_units_come_from_the_system():
    assert state_labels(PlanarRigidBody()) == (("theta", "x", "y", "omega", "vx", "vy"),
                                               ("rad", "m", "m", "rad/s", "m/s", "m/s"))
    names, units = group_error_labels(PlanarRigidBody(sensor="velocity"))
    assert names[0] == "log_theta" and units[3] == "rad/s"
    assert state_labels(RigidBodyAttitude())[1] == ("rad",) * 3 + ("rad/s",) * 3


def test_so3_state_error_is_the_rotation_error():
    # same axis: the rotation error is the angle difference
    a = SO3.exp(np.array([0.0, 0.0, 0.3]))
    b = SO3.exp(np.array([0.0, 0.0, 0.1]))
    np.testing.assert_allclose(state_error(a, b), [0.0, 0.0, 0.2], atol=1e-12)
    np.testing.assert_allclose(group_error(a, b), [0.0, 0.0, 0.2], atol=1e-12)
    # different axes: log(R_hat^T R), not the difference of rotation vectors (which would be (0.3, 0, -0.3))
    a, b = SO3.exp(np.array([0.3, 0.0, 0.0])), SO3.exp(np.array([0.0, 0.0, 0.3]))
    err = np.asarray(state_error(TSO3((a, Rn[3](np.zeros(3)))), TSO3((b, Rn[3](np.ones(3))))))
    np.testing.assert_allclose(err[:3], np.asarray((b.inverse() @ a).log()), atol=1e-12)
    assert abs(np.linalg.norm(err[:3]) - 0.42347) < 1e-5  # the angle between the two rotations
    np.testing.assert_allclose(err[3:], -np.ones(3), atol=1e-15)


def test_continuous_angles_unwrap_or_follow_a_reference():
    theta = np.array([3.0, -3.1, -2.9, 3.1, np.nan])
    q = np.stack([theta, np.arange(5.0)], axis=1)
    out = continuous_angles(q, (True, False))
    np.testing.assert_allclose(out[:4, 0], [3.0, -3.1 + 2 * PI, -2.9 + 2 * PI, 3.1], atol=ROUNDOFF * 10)
    assert np.isnan(out[4, 0])
    np.testing.assert_array_equal(out[:, 1], q[:, 1])  # not an angle: untouched
    ref = np.array([[10.0, 0.0]] * 5)
    near = continuous_angles(q, (True, False), reference=ref)
    assert np.all(np.abs(near[:4, 0] - 10.0) <= PI)
    np.testing.assert_allclose(np.cos(near[:4, 0]), np.cos(theta[:4]), atol=ROUNDOFF * 10)


def test_gain_stats_by_hand_and_for_a_diverged_run():
    K = np.stack([np.eye(2), np.array([[2.0, 1.0], [0.0, 1.0]])])
    s = gain_stats(K)
    assert s["max_rel_asymmetry"] == pytest.approx(math.sqrt(2.0) / math.sqrt(6.0))
    assert s["min_eigenvalue"] == pytest.approx(1.5 - math.sqrt(0.5))  # eig of [[2, .5], [.5, 1]]
    assert s["final_diagonal"] == [2.0, 1.0] and s["non_finite_steps"] == 0
    bad = np.concatenate([K, np.full((1, 2, 2), np.nan)])
    s = gain_stats(bad)
    assert s["non_finite_steps"] == 1 and s["final_diagonal"] == [None, None]
    assert s["min_eigenvalue"] == pytest.approx(1.5 - math.sqrt(0.5))
    json.dumps(s, allow_nan=False)


def test_run_nees_is_the_left_errors_nees_in_one_call():
    """run_nees(truth, run) = e^T K^-1 e with e = log(g_hat^-1 g), per sample, against an explicit solve."""
    from types import SimpleNamespace

    from liemef.groups import SE2
    from liemef.metrics import run_nees

    rng = np.random.default_rng(3)
    g = SE2.from_coords(rng.normal(size=(5, 3)))
    g_hat = SE2.from_coords(np.asarray(g.coords()) + 0.1 * rng.normal(size=(5, 3)))
    A = rng.normal(size=(5, 3, 3))
    K = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    e = np.asarray((g_hat.inverse() @ g).log())
    expected = np.einsum("ni,ni->n", e, np.linalg.solve(K, e[:, :, None])[:, :, 0])
    got = np.asarray(run_nees(g, SimpleNamespace(g_hat=g_hat, K=K)))
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert np.all(got > 0)
