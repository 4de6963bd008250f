"""`liemef run` on real-log shapes: missing samples, a user's system file, gates, failures as a non-zero exit
with nothing written as if it had worked, and `liemef schema`."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from liemef.cli import cli
from liemef.reports import io
from liemef.systems import planar_localization
from localization_scenario import circle_samples


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def localization_log(path, outlier=False, N=1000):
    """A circle at 0.785 m/s with 100 Hz odometry and 1 Hz GPS (empty fields elsewhere)."""
    ts, p, th, us, ys = circle_samples(N, np.arange(100, N, 100), 1.0)
    if outlier:
        ys[500] = [1e4, 0.0]
    io.write_log(path, planar_localization(), ts, us, ys)
    return ts, p, th


@pytest.fixture(scope="module")
def user_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    ts, p, th = localization_log(d / "log.csv", outlier=True)
    (d / "my_system.py").write_text("from liemef.systems import planar_localization\n"
                                    "system = planar_localization(gate=0.999)\nK0 = [0.01, 0.0, 0.0]\n")
    res = invoke("run", "--system-file", d / "my_system.py", "--log", d / "log.csv", "--out", d / "out",
                 "--no-progress")
    return d, res, ts, p, th


def test_run_with_a_system_file_a_sparse_sensor_and_a_gate(user_run):
    d, res, ts, p, th = user_run
    assert res.exit_code == 0, res.output
    assert "Gate rejected samples: gps 1" in res.output
    rows = io.read_arrays(d / "out" / "arrays.npz")
    est = np.loadtxt(d / "out" / "estimates.csv", delimiter=",", skiprows=1)
    header = (d / "out" / "estimates.csv").read_text().splitlines()[0]
    assert header == "t,theta,x,y,K_e0e0,K_e1e1,K_e2e2"
    assert np.isfinite(est).all()
    assert np.max(np.linalg.norm(est[:, 2:4] - p, axis=1)) < 1.0  # the 1e4 m outlier was rejected
    innov = (d / "out" / "innovations.csv").read_text().splitlines()
    assert innov[1] == "0.0,," and innov[0] == "t,gps_x,gps_y"  # no GPS at t = 0: no innovation
    assert np.isfinite(rows["innovation"][100]).all()
    metrics = json.loads((d / "out" / "metrics.json").read_text())
    assert metrics["status"]["ok"] and metrics["status"]["rejected"] == {"gps": 1}
    assert metrics["innovation"]["components"]["gps_x"]["count"] == 9


def test_a_failed_run_exits_non_zero_and_writes_only_the_failure(tmp_path):
    localization_log(tmp_path / "log.csv", N=300)
    res = invoke("run", "--system-file", tmp_path / "none.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "o")
    assert res.exit_code != 0 and "--system-file" in res.output and "not found" in res.output
    (tmp_path / "s.py").write_text("from liemef.systems import planar_localization\nsystem = planar_localization()\n")
    # K0 = 1e4 with one explicit step per interval: the first GPS fix makes K indefinite
    res = invoke("run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--k0", 1e4, "--substeps", 1, "--no-progress")
    assert res.exit_code == 1
    assert "filter failed over the sample interval 100 ([1, 1.01] s)" in res.output
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["failure.json"]
    failure = json.loads((tmp_path / "o" / "failure.json").read_text())
    assert failure["status"]["index"] == 100 and failure["last_good_state"]["sample"] == 100
    assert all(np.isfinite(list(failure["last_good_state"]["coords"].values())))
    # the same run with automatic sub-steps copes
    res = invoke("run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "o2",
                 "--k0", 1e4, "--no-progress")
    assert res.exit_code == 0, res.output


def test_schema_and_system_choice_errors(tmp_path):
    res = invoke("schema", "tse2")
    assert res.exit_code == 0 and "CSV header: t,u1,u2,x1,y1,x2,y2,omega,vx,vy" in res.output
    (tmp_path / "s.py").write_text("from liemef.systems import planar_localization\nsystem = planar_localization()\n")
    res = invoke("schema", "--system-file", tmp_path / "s.py")
    assert "gps_x   m      sensor gps  std 1 m per sample" in res.output
    res = invoke("run", "--system", "tse2", "--system-file", tmp_path / "s.py", "--log", "x.csv", "--out", tmp_path)
    assert res.exit_code != 0 and "expected exactly one of --system NAME" in res.output


def test_dataset_converts_a_real_recording_for_run(tmp_path):
    from liemef.studies import datasets

    root = datasets.realdata_dir()
    if root is None or not (root / "ukfm_wifibot" / "wifibot1.txt").is_file():
        pytest.skip("real recordings absent (../shared/realdata or LIEMEF_REALDATA)")
    res = invoke("dataset", "wifibot", root / "ukfm_wifibot" / "wifibot1.txt", "--out", tmp_path / "log.csv",
                 "--truth", tmp_path / "truth.csv", "--seconds", 30)
    assert res.exit_code == 0, res.output
    log = io.read_log(tmp_path / "log.csv", planar_localization())
    assert 25 <= np.isfinite(log.ys[:, 0]).sum() <= 31  # 1 Hz synthetic GPS, empty fields between fixes
    truth = np.loadtxt(tmp_path / "truth.csv", delimiter=",", skiprows=1)
    res = invoke("run", "--system", "localization", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--x0", ",".join(map(str, truth[0, 1:])), "--k0-diag", "0.01,0.01,0.01", "--no-progress")
    assert res.exit_code == 0, res.output
    est = np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)
    assert np.sqrt(np.mean(np.sum((est[:, 2:4] - truth[:, 2:4]) ** 2, axis=1))) < 0.5
    res = invoke("dataset", "broad", tmp_path / "missing.mat", "--out", tmp_path / "x.csv")
    assert res.exit_code == 2 and "path:" in res.output


def test_dataset_takes_the_id_of_a_recording_present(tmp_path, monkeypatch):
    import scipy.io

    root = tmp_path / "realdata"
    (root / "broad").mkdir(parents=True)
    N = 30
    scipy.io.savemat(root / "broad" / "05_new_trial.mat", {
        "imu_gyr": np.zeros((N, 3)), "imu_acc": np.tile([0.0, 0.0, 9.81], (N, 1)),
        "imu_mag": np.tile([0.0, 20.0, -40.0], (N, 1)), "opt_quat": np.tile([1.0, 0, 0, 0], (N, 1)),
        "movement": np.ones(N, np.uint8), "sampling_rate": 100.0})
    monkeypatch.setenv("LIEMEF_REALDATA", str(root))
    res = invoke("dataset", "broad", "5", "--out", tmp_path / "log.csv")
    assert res.exit_code == 0, res.output
    assert f"{N} samples" in res.output
    res = invoke("dataset", "broad", "6", "--out", tmp_path / "log.csv")
    assert res.exit_code == 2 and "path:" in res.output


def test_tune_writes_a_file_that_run_accepts(tmp_path, monkeypatch):
    import scipy.io
    from scipy.spatial.transform import Rotation

    root = tmp_path / "realdata"
    (root / "broad").mkdir(parents=True)
    rng = np.random.default_rng(0)
    N, rate = 400, 100.0
    R = Rotation.from_rotvec(np.outer(np.r_[np.zeros(200), np.linspace(0, 1, 200)], [0.0, 0.0, 1.0]))
    q = R.as_quat()[:, [3, 0, 1, 2]]
    for name in ("01_a.mat", "02_b.mat"):
        scipy.io.savemat(root / "broad" / name, {
            "imu_gyr": np.r_[np.zeros((200, 3)), np.tile([0, 0, 100.0 / 199], (200, 1))]
            + 0.001 * rng.standard_normal((N, 3)),
            "imu_acc": R.inv().apply([0.0, 0.0, 9.81]) + 0.05 * rng.standard_normal((N, 3)),
            "imu_mag": R.inv().apply([0.0, 16.0, -40.0]), "opt_quat": q,
            "movement": np.r_[np.zeros(200), np.ones(200)].astype(np.uint8), "sampling_rate": rate})
    monkeypatch.setenv("LIEMEF_REALDATA", str(root))
    res = invoke("tune", "broad", "--out", tmp_path / "t", "--params", "acc_std", "--seconds", "1",
                 "--maxfev", "2", "--fold-maxfev", "1", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "held-out" in res.output and (tmp_path / "t" / "tune.json").is_file()
    from liemef.studies import tune

    tuned = tune.load(tmp_path / "t" / "tune.json")
    assert set(tuned["folds"]) == {"01", "02"}
    res = invoke("run", "--system", "attitude-bias", "--params", tmp_path / "t" / "tune.json", "--log",
                 tmp_path / "none.csv", "--out", tmp_path / "o")
    assert res.exit_code == 2 and "--params" in res.output


def test_run_with_discrete_updates(tmp_path):
    """``--updates discrete`` (the hybrid filter): the same log, GPS fixes used at their own time; the outlier
    is still rejected by the gate, which reads the same residual."""
    ts, p, th = localization_log(tmp_path / "log.csv", outlier=True)
    (tmp_path / "s.py").write_text("from liemef.systems import planar_localization\n"
                                   "system = planar_localization(gate=0.999)\nK0 = [0.01, 0.0, 0.0]\n")
    res = invoke("run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--updates", "discrete", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "Gate rejected samples: gps 1" in res.output
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["config"]["updates"] == "discrete" and "updates='discrete'" in metrics["system"]["filter"]
    assert metrics["config"]["params"] is None  # no tuning file
    est = np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)
    assert np.max(np.linalg.norm(est[:, 2:4] - p, axis=1)) < 1.0
