"""Estimates out as TUM trajectories, and APE/RPE by evo against closed forms (liemef.metrics.ape_rpe)."""

import numpy as np
import pytest

from liemef.groups import R3, SE2, SE3, SE23, SO2, SO3, Product
from liemef.metrics import ape_rpe, pose_parts
from liemef.reports.io import read_tum, write_tum
from liemef.reports.rosbag import quaternion_matrix
from tolerances import ROUNDOFF

N = 20


def random_se3(seed, n=N, scale=1.0):
    return SE3.exp(np.random.default_rng(seed).normal(size=(n, 6)) * scale)


def rotations(q):
    return np.stack([quaternion_matrix(*row) for row in q])


def test_tum_round_trip_of_se3_estimates_is_exact(tmp_path):
    ts = 1_700_000_000.0 + 0.01 * np.arange(N)
    g = random_se3(0)
    path = write_tum(tmp_path / "estimates.tum", ts, g)
    assert path.read_text().splitlines()[0] == "# timestamp tx ty tz qx qy qz qw"
    ts_back, (p, q) = read_tum(path)
    np.testing.assert_array_equal(ts_back, ts)
    p_ref, q_ref = pose_parts(g)
    np.testing.assert_array_equal(p, p_ref)
    np.testing.assert_array_equal(q, q_ref)
    M = np.asarray(g.as_matrix())
    np.testing.assert_allclose(p, M[:, :3, 3], atol=ROUNDOFF)
    np.testing.assert_allclose(rotations(q), M[:, :3, :3], atol=ROUNDOFF)


def test_evo_reads_the_tum_file_liemef_writes(tmp_path):
    from evo.tools import file_interface

    ts = 0.1 * np.arange(N)
    g = random_se3(1)
    traj = file_interface.read_tum_trajectory_file(str(write_tum(tmp_path / "e.tum", ts, g)))
    np.testing.assert_array_equal(traj.timestamps, ts)
    np.testing.assert_allclose(np.stack(traj.poses_se3), np.asarray(g.as_matrix()), atol=ROUNDOFF)


def test_pose_parts_of_the_3d_attitude_and_planar_groups():
    rng = np.random.default_rng(2)
    # SE_2(3): the position, not the velocity
    x = SE23.exp(rng.normal(size=(N, 9)))
    p, q = pose_parts(x)
    M = np.asarray(x.as_matrix())
    np.testing.assert_allclose(p, M[:, :3, 4], atol=ROUNDOFF)
    np.testing.assert_allclose(rotations(q), M[:, :3, :3], atol=ROUNDOFF)
    # a product whose first factor is SE_2(3) (inertial navigation with biases)
    p_b, q_b = pose_parts(Product[SE23, R3](factors=(x, R3(rng.normal(size=(N, 3))))))
    np.testing.assert_array_equal(p_b, p)
    np.testing.assert_array_equal(q_b, q)
    # SO(3): attitude only, position zero
    R = SO3.exp(rng.normal(size=(N, 3)))
    p, q = pose_parts(R)
    np.testing.assert_array_equal(p, 0.0)
    np.testing.assert_allclose(rotations(q), np.asarray(R.as_matrix()), atol=ROUNDOFF)
    # SE(2) and SO(2): a rotation about z, z = 0
    th = rng.uniform(-np.pi, np.pi, N)
    xy = rng.normal(size=(N, 2))
    p, q = pose_parts(SE2.from_coords(np.column_stack([th, xy])))
    c, s = np.cos(th), np.sin(th)
    Rz = np.stack([np.stack([c, -s, 0 * c], -1), np.stack([s, c, 0 * c], -1), np.stack([0 * c, 0 * c, 1 + 0 * c], -1)],
                  axis=1)
    np.testing.assert_allclose(rotations(q), Rz, atol=ROUNDOFF)
    np.testing.assert_allclose(p, np.column_stack([xy, np.zeros(N)]), atol=ROUNDOFF)
    p, q = pose_parts(SO2.from_coords(th[:, None]))
    np.testing.assert_allclose(rotations(q), Rz, atol=ROUNDOFF)
    np.testing.assert_array_equal(p, 0.0)


def test_bad_tum_input(tmp_path):
    with pytest.raises(ValueError, match=r"g: expected a pose group \(SE3, SE23, SO3, SE2, SO2.*got R3"):
        write_tum(tmp_path / "a.tum", np.arange(N), R3(np.zeros((N, 3))))
    with pytest.raises(ValueError, match=r"ts: expected shape \(20,\) \(one time per estimate\), got \(19,\)"):
        write_tum(tmp_path / "a.tum", np.arange(N - 1), random_se3(0))
    with pytest.raises(ValueError, match=r"expected finite times and poses"):
        write_tum(tmp_path / "a.tum", np.full(N, np.nan), random_se3(0))
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary file left
    bad = tmp_path / "bad.tum"
    bad.write_text("# header\n0 1 2 3 0 0 0 1\n1 1 2 3 0 0 0\n")
    with pytest.raises(ValueError, match=r"trajectory: expected 8 finite numbers .* on line 3 .*got '1 1 2 3 0 0 0'"):
        read_tum(bad)


def true_trajectory(n=50, dt=0.1):
    ts = dt * np.arange(n)
    g = random_se3(3, n)
    return ts, g


def test_a_constant_position_offset_is_the_ape_and_no_rpe():
    ts, g = true_trajectory()
    p, q = pose_parts(g)
    c = np.array([0.3, -0.4, 1.2])  # |c| = 1.3
    out = ape_rpe(ts, (p + c, q), ts, g)
    assert out["pairs"] == ts.shape[0]
    for k in ("rmse", "mean", "median", "min", "max"):
        assert out["ape_translation"][k] == pytest.approx(1.3, abs=1e-12)
        assert out["rpe_translation"][k] == pytest.approx(0.0, abs=1e-12)
    assert out["ape_rotation"]["max"] < 1e-6 and out["rpe_rotation"]["max"] < 1e-6


def test_a_constant_velocity_drift_is_the_rpe_per_step():
    ts, g = true_trajectory()
    p, q = pose_parts(g)
    v = np.array([0.0, 2.0, 0.0])
    out = ape_rpe(ts, (p + ts[:, None] * v, q), ts, g, delta=2)
    for k in ("mean", "min", "max"):  # |v| * 2 steps of 0.1 s
        assert out["rpe_translation"][k] == pytest.approx(0.4, abs=1e-12)
    assert out["ape_translation"]["max"] == pytest.approx(2.0 * ts[-1], abs=1e-12)


def test_a_constant_body_rotation_is_the_ape_angle():
    ts, g = true_trajectory()
    delta = np.array([0.0, 0.0, np.radians(5.0)])
    est = g @ SE3.exp(np.concatenate([delta, np.zeros(3)]))  # g exp(delta), same positions
    out = ape_rpe(ts, est, ts, g)
    for k in ("mean", "min", "max"):
        assert out["ape_rotation"][k] == pytest.approx(5.0, abs=1e-9)
    assert out["ape_translation"]["max"] < 1e-12


def test_ape_equals_the_rms_position_difference_and_pairs_by_nearest_time():
    ts, g = true_trajectory()
    est = g @ random_se3(4, ts.shape[0], scale=0.05)
    # the estimate has extra rows (measurement times) between the truth's: only nearest times within 1 ms pair
    ts_est = np.sort(np.concatenate([ts, ts[:-1] + 0.05]))
    p, q = pose_parts(est)
    p_all = np.zeros((ts_est.shape[0], 3))
    q_all = np.tile([0.0, 0.0, 0.0, 1.0], (ts_est.shape[0], 1))
    rows = np.searchsorted(ts_est, ts)
    p_all[rows], q_all[rows] = p, q
    out = ape_rpe(ts_est, (p_all, q_all), ts, g, max_diff=1e-3)
    assert out["pairs"] == ts.shape[0]
    d = np.linalg.norm(p - pose_parts(g)[0], axis=1)
    assert out["ape_translation"]["rmse"] == pytest.approx(np.sqrt(np.mean(d**2)), rel=1e-12)
    assert out["ape_translation"]["max"] == pytest.approx(d.max(), rel=1e-12)


def test_align_removes_a_rigid_change_of_world_frame():
    ts, g = true_trajectory()
    T = SE3.exp(np.array([0.1, -0.2, 0.3, 5.0, -1.0, 2.0]))
    out = ape_rpe(ts, T @ g, ts, g, align=True)
    assert out["ape_translation"]["max"] < 1e-9 and out["ape_rotation"]["max"] < 1e-6
    assert ape_rpe(ts, T @ g, ts, g)["ape_translation"]["min"] > 1.0  # without alignment it is there


def test_bad_ape_rpe_input():
    ts, g = true_trajectory()
    with pytest.raises(ValueError, match=r"delta: expected an integer >= 1 \(pose pairs\), got 0"):
        ape_rpe(ts, g, ts, g, delta=0)
    with pytest.raises(ValueError, match=r"ts, ts_true: expected time stamps that match within max_diff"):
        ape_rpe(ts + 100.0, g, ts, g)
    with pytest.raises(ValueError, match=r"poses_true: expected positions \(N, 3\) and quaternions \(N, 4\)"):
        ape_rpe(ts, g, ts, (np.zeros((ts.shape[0], 2)), np.zeros((ts.shape[0], 4))))
    with pytest.raises(ValueError, match=r"g_est: expected finite time stamps of shape \(50,\)"):
        ape_rpe(ts[:-1], g, ts, g)
