"""Real-data loaders (liemef.studies.datasets): where the data are, bad paths, the logs they make, a log CSV in a
system's column names, and the Wifibot run (Brossard et al., UKF-M, BSD-3-Clause) filtered with planar
localization and synthetic GPS (skipped when the real data are absent)."""

import csv
import json
import math

import numpy as np
import pytest

from liemef.filters import MinimumEnergyFilter
from liemef.groups import SE2
from liemef.metrics import wrap_angle
from liemef.reports import io
from liemef.studies import datasets
from liemef.systems import attitude_gyro_bias, planar_localization

REALDATA = datasets.realdata_dir()


def _real(rel):
    if REALDATA is None:
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    path = REALDATA / rel
    if not path.is_file():
        pytest.skip(f"real data absent: {path} not found")
    return path


# --- where the data are -----------------------------------------------------------------------------------------
def test_realdata_dir_from_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path))
    assert datasets.realdata_dir() == tmp_path.resolve()
    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path / "absent"))
    assert datasets.realdata_dir() is None           # a wrong setting is not replaced by another folder
    monkeypatch.delenv(datasets.ENV_VAR)
    found = datasets.realdata_dir()
    assert found is None or found.is_dir()


# --- bad paths --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("load", [datasets.broad, datasets.wifibot], ids=["broad", "wifibot"])
def test_bad_paths_raise_value_errors_naming_the_argument(load, tmp_path):
    with pytest.raises(ValueError, match=r"^path: file not found"):
        load(tmp_path / "missing.mat")
    with pytest.raises(ValueError, match=r"^path: expected a file, got a directory"):
        load(tmp_path)
    with pytest.raises(ValueError, match=r"^path: expected a file path"):
        load(None)
    junk = tmp_path / "junk.txt"
    junk.write_text("not a log\n1 2\n")
    with pytest.raises(ValueError, match=r"^path: "):
        load(junk)


def test_conversions_check_their_argument():
    with pytest.raises(ValueError, match="^trial:"):
        datasets.broad_to_log("01")
    with pytest.raises(ValueError, match="^run:"):
        datasets.wifibot_to_log(None)


# --- a log as CSV in the system's column names ------------------------------------------------------------------
def test_write_log_names_columns_and_leaves_missing_samples_empty(tmp_path):
    system = planar_localization()
    ts = np.array([0.0, 0.02, 0.04])
    us = np.array([[0.1, 0.0, 0.2], [0.1, 0.0, np.nan], [0.3, 0.0, 0.1]])
    ys = np.array([[1.0, 2.0], [np.nan, np.nan], [1.0 / 3.0, -2.5]])
    path = io.write_log(tmp_path / "log.csv", system, ts, us, ys)
    rows = list(csv.reader(path.open(newline="")))
    assert rows[0] == ["t", "v_x", "v_y", "omega", "gps_x", "gps_y"]
    assert rows[2][3:] == ["", "", ""]
    back = np.array([[np.nan if c == "" else float(c) for c in r] for r in rows[1:]])
    np.testing.assert_array_equal(back, np.concatenate([ts[:, None], us, ys], axis=1))   # full precision
    assert not list(tmp_path.glob(".*tmp"))                                                 # atomic
    with pytest.raises(ValueError, match="^ys:"):
        io.write_log(tmp_path / "bad.csv", system, ts, us, ys[:, :1])
    with pytest.raises(ValueError, match="^ts:"):
        io.write_log(tmp_path / "bad.csv", system, ts[::-1], us, ys)
    assert not (tmp_path / "bad.csv").exists()
    io.write_log(tmp_path / "a.csv", attitude_gyro_bias(), ts, np.zeros((3, 3)), np.zeros((3, 6)))
    assert next(csv.reader((tmp_path / "a.csv").open(newline=""))) == [
        "t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z"]


# --- BROAD ------------------------------------------------------------------------------------------------------
def test_broad_loader_and_log():
    trial = datasets.broad(_real("broad/01_undisturbed_slow_rotation_A.mat"))
    N = 56940
    assert trial.rate == pytest.approx(2000.0 / 7.0)
    assert trial.gyr.shape == trial.acc.shape == trial.mag.shape == (N, 3) and trial.quat_true.shape == (N, 4)
    np.testing.assert_allclose(trial.ts[-1], (N - 1) / trial.rate)
    missing = np.isnan(trial.quat_true).any(axis=1)
    assert 0 < missing.mean() < 0.01                       # README: 0.3 % dropped
    np.testing.assert_allclose(np.linalg.norm(trial.quat_true[~missing], axis=1), 1.0, atol=1e-6)
    assert 0.6 < trial.movement.mean() < 0.66 and not trial.movement[0]
    # quaternion convention (README): at rest the accelerometer reads R^T e_up
    rest = np.arange(N) < np.argmax(trial.movement)  # before the first annotated movement
    q = trial.quat_true[rest & ~missing]
    w, x, y, z = q.T
    up_body = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)  # R^T e_z
    a = trial.acc[rest & ~missing] / np.linalg.norm(trial.acc[rest & ~missing], axis=1, keepdims=True)
    assert np.degrees(np.median(np.arccos(np.clip(np.sum(a * up_body, axis=1), -1, 1)))) < 1.0
    log = datasets.broad_to_log(trial.head(10.0))
    assert log.us.shape == (2857, 3) and log.ys.shape == (2857, 6)
    np.testing.assert_allclose(np.linalg.norm(log.ys[:, :3], axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(log.ys[:, 3:], axis=1), 1.0, rtol=1e-12)


# --- Wifibot with synthetic GPS -------------------------------------------------------------------------------------
def test_wifibot_loader_and_log():
    run = datasets.wifibot(_real("ukfm_wifibot/wifibot1.txt"))
    assert run.ts.shape == run.v.shape == run.omega.shape == (1745,) and run.truth.shape == (1745, 3)
    np.testing.assert_array_equal(run.truth[0], [0.0, 0.0, 0.0])
    log = datasets.wifibot_to_log(run)
    fixes = np.isfinite(log.ys[:, 0])
    assert fixes.sum() == math.ceil(run.ts[-1] - run.ts[0])          # 1 Hz over 32.4 s
    np.testing.assert_array_equal(log.us[:, 1], 0.0)
    np.testing.assert_array_equal(log.us[:, [0, 2]], np.stack([run.v, run.omega], axis=1))
    noise = log.ys[fixes] - run.truth[fixes, 1:]
    assert 0.05 < noise.std() < 0.15
    np.testing.assert_array_equal(datasets.wifibot_to_log(run).ys, log.ys)            # fixed seed
    assert not np.array_equal(datasets.wifibot_to_log(run, seed=1).ys[fixes], log.ys[fixes])


def _dead_reckoning(run):
    dt = np.diff(run.ts)
    th = np.concatenate([[0.0], np.cumsum(run.omega[:-1] * dt)])
    step = np.stack([np.cos(th[:-1]), np.sin(th[:-1])], axis=1) * (run.v[:-1] * dt)[:, None]
    return th, np.concatenate([[[0.0, 0.0]], np.cumsum(step, axis=0)])


def test_wifibot_localization_with_synthetic_gps():
    # Odometry noise per sample at the run's 50 Hz: yaw rate 0.2 rad/s, forward 0.05 m/s, lateral 0.01 m/s (the
    # odometry over-reads the truth by about 5 %, a systematic error that white noise has to cover); GPS 0.1 m
    # at 1 Hz; the start pose is known (the truth is relative to it). Measured: heading rms 5.08 deg, position
    # rms 0.088 m; odometry dead reckoning: 16.5 deg, 0.248 m.
    run = datasets.wifibot(_real("ukfm_wifibot/wifibot1.txt"))
    log = datasets.wifibot_to_log(run, gps_rate=1.0, gps_std=0.1, seed=0)
    system = planar_localization(odometry_std=(0.2, 0.05, 0.01), odometry_rate=50.0, gps_std=0.1)
    flt = MinimumEnergyFilter(system)
    traj = flt.run(flt.init(SE2.identity(), np.diag([0.01**2] * 3)), log.ts, log.us, log.ys)
    assert traj.status.ok, traj.status.message(log.ts)
    c = np.asarray(traj.coords())
    heading = np.degrees(np.sqrt(np.mean(np.asarray(wrap_angle(run.truth[:, 0] - c[:, 0])) ** 2)))
    position = np.sqrt(np.mean(np.sum((run.truth[:, 1:] - c[:, 1:]) ** 2, axis=1)))
    assert heading < 7.0
    assert position < 0.12
    th, p = _dead_reckoning(run)
    assert heading < 0.5 * np.degrees(np.sqrt(np.mean(np.asarray(wrap_angle(run.truth[:, 0] - th)) ** 2)))
    assert position < 0.5 * np.sqrt(np.mean(np.sum((run.truth[:, 1:] - p) ** 2, axis=1)))


# --- every recording present, read from the files themselves ---------------------------------------------------
def _fake_broad(path, N=40, rate=100.0):
    import scipy.io

    rng = np.random.default_rng(0)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
    scipy.io.savemat(path, {"imu_gyr": 0.01 * rng.standard_normal((N, 3)),
                            "imu_acc": np.tile([0.0, 0.0, 9.81], (N, 1)) + 0.05 * rng.standard_normal((N, 3)),
                            "imu_mag": np.tile([0.0, 20.0, -40.0], (N, 1)), "opt_quat": q,
                            "movement": np.r_[np.zeros(10), np.ones(N - 10)].astype(np.uint8),
                            "sampling_rate": rate})


def test_broad_trials_are_found_by_their_content(tmp_path):
    _fake_broad(tmp_path / "05_some_new_trial.mat")
    _fake_broad(tmp_path / "39_another.mat", N=30)
    _fake_broad(tmp_path / "custom.mat")
    import scipy.io

    scipy.io.savemat(tmp_path / "12_not_broad.mat", {"x": np.ones(3)})      # a .mat without BROAD's variables
    (tmp_path / "13_junk.mat").write_text("not a mat file")
    found = datasets.broad_trials(tmp_path)
    assert list(found) == ["05", "39", "custom"]
    trial = datasets.broad(found["39"])
    assert trial.gyr.shape == (30, 3) and trial.rate == 100.0 and trial.name == "39_another"
    assert datasets.broad_trials(tmp_path / "absent") == {}


def test_wifibot_runs_are_found_by_their_header(tmp_path):
    rows = "\n".join(f"{0.02 * k} 0.1 0.5 0 0 {0.01 * k} 0" for k in range(5))
    (tmp_path / "wifibot7.txt").write_text("t gyro vx vy theta px py\n" + rows + "\n")
    (tmp_path / "my_run.txt").write_text("t gyro vx vy theta px py\n" + rows + "\n")
    (tmp_path / "notes.txt").write_text("some notes\n")
    found = datasets.wifibot_runs(tmp_path)
    assert list(found) == ["7", "my_run"]
    assert datasets.wifibot(found["7"]).ts.shape == (5,)


def test_the_comparisons_take_every_trial_present(tmp_path):
    from liemef.studies.compare import BroadComparison, WifibotComparison

    (tmp_path / "broad").mkdir()
    (tmp_path / "ukfm_wifibot").mkdir()
    for name in ("02_a.mat", "16_b.mat", "31_c.mat"):
        _fake_broad(tmp_path / "broad" / name)
    rows = "\n".join(f"{0.02 * k} 0.1 0.5 0 0 {0.01 * k} 0" for k in range(5))
    (tmp_path / "ukfm_wifibot" / "wifibot9.txt").write_text("t gyro vx vy theta px py\n" + rows + "\n")
    assert BroadComparison(realdata=str(tmp_path)).trials == ("02", "16", "31")
    assert BroadComparison(trials="16,2", realdata=str(tmp_path)).trials == ("16", "02")
    with pytest.raises(ValueError, match=r"^trials: expected BROAD trials present .* \['02', '16', '31'\]"):
        BroadComparison(trials="07", realdata=str(tmp_path))
    assert WifibotComparison(realdata=str(tmp_path)).recordings == ("9",)
    # a tuning file reaches only its own model's rows: with none of them among the filters it would change
    # nothing while the table said it was used, so it is refused (attitude-position's rows are not run by default)
    (tmp_path / "tune.json").write_text(json.dumps({"format": "liemef-tune-1", "system": "attitude-position",
                                                    "params": {"position_std": 0.05}}))
    with pytest.raises(ValueError, match=r"^params: expected --filters to hold a row of the file's system "
                                         r"attitude-position \(mef-pos, mef-pos-first, iekf-pos\)"):
        BroadComparison(realdata=str(tmp_path), params=str(tmp_path / "tune.json"))
    assert BroadComparison(realdata=str(tmp_path), params=str(tmp_path / "tune.json"), filters="iekf-pos,vqf").filters \
        == ("iekf-pos", "vqf")


def test_the_shared_folder_holds_every_broad_trial_and_wifibot_run():
    if REALDATA is None or not (REALDATA / "broad").is_dir():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    assert {"01", "07", "24", "10", "16", "28", "33"} <= set(datasets.broad_trials())
    assert {"1", "4"} <= set(datasets.wifibot_runs())
