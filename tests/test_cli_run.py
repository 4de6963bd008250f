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


def gated_localization(d):
    """In the folder ``d``: the localization log with a 1e4 m GPS outlier (``log.csv``) and a user's system file
    whose GPS has a gate (``my_system.py``). Returns the truth (ts, p, th)."""
    truth = localization_log(d / "log.csv", outlier=True)
    (d / "my_system.py").write_text("from liemef.systems import planar_localization\n"
                                    "system = planar_localization(gate=0.999)\nK0 = [0.01, 0.0, 0.0]\n")
    return truth


@pytest.fixture(scope="module")
def user_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    ts, p, th = gated_localization(d)
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
    localization_log(tmp_path / "log.csv")
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
                 "--start", "acc_std=0.03,mag_std=0.2", "--maxfev", "2", "--fold-maxfev", "1", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "held-out" in res.output and "final set, in-sample" in res.output
    assert (tmp_path / "t" / "tune.json").is_file()
    from liemef.studies import tune

    tuned = tune.load(tmp_path / "t" / "tune.json")
    assert set(tuned["folds"]) == {"01", "02"} and tuned["cross_validation"] == "nested"
    # a fold's search of one point is its start; the final set's two points are the start and a step of it
    assert [f["params"]["acc_std"] for f in tuned["folds"].values()] == pytest.approx([0.03, 0.03])
    assert min(abs(np.log10(tuned["params"]["acc_std"] / 0.03) - d) for d in (0.0, 0.5)) < 1e-9
    assert tuned["params"]["mag_std"] == 0.2  # given, not tuned
    # the dip and the norms were measured over the rest found from the IMU (2 s, then the turn), not the annotation
    assert all(1.5 <= v <= 2.0 for v in tuned["rest_s"].values()) and set(tuned["rest_s"]) == {"01", "02"}
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


def test_set_reaches_a_ready_systems_parameters(tmp_path):
    """`liemef run --system localization --set gps_std=0.5` builds the ready system with that GPS std (not a
    system file), records it in metrics.json, and the estimates differ from the default's."""
    localization_log(tmp_path / "log.csv")
    common = ("--system", "localization", "--log", tmp_path / "log.csv", "--updates", "discrete", "--no-progress")
    assert invoke("run", *common, "--out", tmp_path / "d").exit_code == 0
    res = invoke("run", *common, "--set", "gps_std=0.5", "--set", "gate=0.999", "--out", tmp_path / "s")
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert metrics["config"]["system_settings"] == {"gps_std": 0.5, "gate": 0.999}
    assert "built with gps_std=0.5, gate=0.999 (--set)" in metrics["system"]["description"]
    assert json.loads((tmp_path / "d" / "metrics.json").read_text())["config"]["system_settings"] is None
    default, changed = (np.loadtxt(tmp_path / d / "estimates.csv", delimiter=",", skiprows=1) for d in ("d", "s"))
    assert default.shape == changed.shape and np.abs(default[-1, 1:] - changed[-1, 1:]).max() > 1e-6


@pytest.mark.parametrize(("settings", "words"), [
    (["gps_sd=0.5"], ["--set", "no parameter 'gps_sd'", "gps_std"]),
    (["gps_std=true"], ["--set", "gps_std", "expected a finite number", "'true'"]),
    (["gps_std=nan"], ["--set", "gps_std", "finite number"]),
    (["gps_std=-1"], ["--set", "localization with gps_std=-1.0", "> 0"]),
    (["gps_std=0.5", "gps_std=0.4"], ["--set", "gps_std is set twice"]),
    (["gps_std"], ["--set", "expected KEY=VALUE"]),
])
def test_a_bad_ready_system_setting_is_refused_naming_it(tmp_path, settings, words):
    localization_log(tmp_path / "log.csv", N=300)
    args = [a for s in settings for a in ("--set", s)]
    res = invoke("run", "--system", "localization", "--log", tmp_path / "log.csv", "--out", tmp_path / "o", *args)
    assert res.exit_code == 2, res.output
    for w in words:
        assert w in res.output, (w, res.output)
    assert not (tmp_path / "o").exists()


def test_set_is_refused_for_the_papers_systems_and_system_files(tmp_path):
    localization_log(tmp_path / "log.csv", N=300)
    res = invoke("run", "--system", "tse2", "--log", tmp_path / "log.csv", "--out", tmp_path / "o", "--set",
                 "q=1")
    assert res.exit_code == 2 and "has no parameters to set" in res.output
    (tmp_path / "s.py").write_text("from liemef.systems import planar_localization\nsystem = planar_localization()\n")
    res = invoke("run", "--system-file", tmp_path / "s.py", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--set", "gps_std=1")
    assert res.exit_code == 2 and "a system file sets its own parameters" in res.output


def test_a_setting_that_changes_the_state_no_longer_reads_it_off_the_measurements():
    """inertial-navigation with biases=true is SE_2(3) x R^6: its initial guess is the identity's coordinates,
    not a position read off the first fix into the wrong slots; the noise and gravity are as set."""
    from liemef.studies.logs import resolve_system, with_settings

    source = with_settings(resolve_system("inertial-navigation"), ["biases=true", "gnss_std=0.5", "robust=huber"])
    assert source.system.group.coords_dim == 15 and source.measured is None
    np.testing.assert_array_equal(source.initial_guess(np.array([1.0, 2.0, 3.0])), np.zeros(15))
    assert source.settings == {"biases": True, "gnss_std": 0.5, "robust": "huber"}
    same = with_settings(resolve_system("inertial-navigation"), ["gnss_std=0.5,0.5,1.0"])
    assert same.measured is not None and same.settings == {"gnss_std": [0.5, 0.5, 1.0]}
    np.testing.assert_array_equal(same.initial_guess(np.array([1.0, 2.0, 3.0])), [0] * 6 + [1.0, 2.0, 3.0])


# --- the IMU models from a BROAD recording: the user's path to compare broad's best model -----------------------
def broad_mat(path, rest_s=2.0, seconds=4.0, rate=100.0, seed=0):
    """A BROAD-shaped .mat trial: at rest for ``rest_s`` s (gyro bias 0.01 rad/s), then a turn about z at 0.5 rad/s;
    a field of 16 uT north and 40 uT down (dip 68.2 deg), gravity 9.81, accelerometer noise 0.05 m/s^2; its
    movement annotation starts 1 s late, so that a rest taken from it would hold the turn's start."""
    import scipy.io
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    N, k = int(seconds * rate), int(rest_s * rate)
    w = np.zeros((N, 3))
    w[k:, 2] = 0.5
    R = Rotation.from_rotvec(np.concatenate([np.zeros((1, 3)), np.cumsum(w, axis=0)[:-1] / rate]))
    scipy.io.savemat(path, {
        "imu_gyr": w + [0.0, 0.0, 0.01] + 0.001 * rng.standard_normal((N, 3)),
        "imu_acc": R.inv().apply([0.0, 0.0, 9.81]) + 0.05 * rng.standard_normal((N, 3)),
        "imu_mag": R.inv().apply([0.0, 16.0, -40.0]), "opt_quat": R.as_quat()[:, [3, 0, 1, 2]],
        "movement": (np.arange(N) >= k + int(rate)).astype(np.uint8), "sampling_rate": rate})
    return R


def test_dataset_broad_writes_the_best_model_and_run_filters_it(tmp_path):
    """`liemef dataset broad` writes the bounded-velocity model's log by default and prints the command that runs
    it; `liemef run --system attitude-velocity` runs it as compare broad's mef-vel (discrete updates, exact
    curvature, left error, its K0), with the dip and the norms measured over the rest found in the log."""
    from liemef.systems.bounded_velocity import K0_VELOCITY

    R = broad_mat(tmp_path / "01_synthetic.mat")
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--out", tmp_path / "log.csv")
    assert res.exit_code == 0, res.output
    assert f"Filter it with: liemef run --system attitude-velocity --log {tmp_path / 'log.csv'} --out DIR" \
        in res.output and "best model" not in res.output
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert header[:7] == ["t", "gyro_x", "gyro_y", "gyro_z", "force_x", "force_y", "force_z"]
    res = invoke("run", "--system", "attitude-velocity", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--no-monitor", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "Measured over the initial rest detected from the IMU (1.5 s): dip 68.1" in res.output  # <= 0.5 s early
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    config = metrics["config"]
    assert (config["updates"], config["curvature"], config["error"]) == ("discrete", "exact", "left")
    np.testing.assert_allclose(config["K0_diag"], np.diag(K0_VELOCITY))
    rest = config["rest"]
    assert rest["found"] and 1.5 <= rest["rest_s"] <= 2.0 and rest["measured"] == ["dip", "field", "gravity"]
    assert rest["dip_deg"] == pytest.approx(68.2, abs=0.2) and rest["gravity"] == pytest.approx(9.81, abs=0.01)
    assert "dip, field, gravity measured over the initial rest detected from the IMU" in \
        metrics["system"]["description"]
    est = np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)
    from scipy.spatial.transform import Rotation

    err = (Rotation.from_rotvec(est[:, 1:4]) * R.inv()).magnitude()
    assert np.degrees(np.max(err[200:])) < 2.0  # the turn is followed
    assert est[-1, 6] == pytest.approx(0.01, abs=0.005)  # the z gyro bias
    # what the user sets is kept; the rest is still measured
    res = invoke("run", "--system", "attitude-velocity", "--log", tmp_path / "log.csv", "--out", tmp_path / "s",
                 "--set", "dip=1.2", "--updates", "hold", "--no-monitor", "--no-progress")
    assert res.exit_code == 0, res.output
    config = json.loads((tmp_path / "s" / "metrics.json").read_text())["config"]
    assert config["rest"]["measured"] == ["field", "gravity"] and config["system_settings"] == {"dip": 1.2}
    assert config["updates"] == "hold" and config["curvature"] == "exact"
    # the other models' logs, and the hint that names the best one
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--norms", "--out", tmp_path / "imu.csv")
    assert res.exit_code == 0, res.output
    assert "liemef run --system attitude-imu" in res.output
    assert "The best model of `liemef compare broad` is attitude-velocity" in res.output
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--system", "localization", "--out",
                 tmp_path / "x.csv")
    assert res.exit_code == 2 and "--system" in res.output and "attitude-velocity" in res.output
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--norms", "--system", "attitude-bias",
                 "--out", tmp_path / "x.csv")
    assert res.exit_code == 2 and "--norms" in res.output


def test_dataset_broad_writes_the_position_model_s_log(tmp_path):
    """`liemef dataset broad --system attitude-position` writes the bounded-position model's log: the
    bounded-velocity model's columns (the gyro over the interval ending at each sample), then a zero position,
    and prints the command that runs it."""
    broad_mat(tmp_path / "01_synthetic.mat")
    for system in ("attitude-velocity", "attitude-position"):
        res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--system", system, "--out",
                     tmp_path / f"{system}.csv")
        assert res.exit_code == 0, res.output
        assert f"liemef run --system {system}" in res.output
    vel = (tmp_path / "attitude-velocity.csv").read_text().splitlines()
    pos = (tmp_path / "attitude-position.csv").read_text().splitlines()
    assert pos[0].split(",")[-3:] == ["position_x", "position_y", "position_z"]
    v, p = (np.loadtxt(t, delimiter=",", skiprows=1) for t in (vel, pos))
    np.testing.assert_array_equal(p[:, :v.shape[1]], v)
    assert p.shape[1] == v.shape[1] + 3 and np.all(p[:, -3:] == 0.0)


def run_as_compare_broad(tmp_path, system: str, K0, R) -> tuple[dict, np.ndarray]:
    """`liemef run --system SYSTEM` on the log in tmp_path/log.csv: it runs as compare broad does (discrete
    updates, exact curvature, left error, the model's K0) and follows the synthetic trial's turn (``R``). Returns
    the run's config and its estimates."""
    from scipy.spatial.transform import Rotation

    res = invoke("run", "--system", system, "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--no-monitor", "--no-progress")
    assert res.exit_code == 0, res.output
    config = json.loads((tmp_path / "o" / "metrics.json").read_text())["config"]
    assert (config["updates"], config["curvature"], config["error"]) == ("discrete", "exact", "left")
    np.testing.assert_allclose(config["K0_diag"], np.diag(K0))
    est = np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)
    err = (Rotation.from_rotvec(est[:, 1:4]) * R.inv()).magnitude()
    assert np.degrees(np.max(err[200:])) < 2.0  # the turn is followed
    return config, est


@pytest.mark.slow  # a C kernel of the 12-state model
def test_run_filters_the_position_model_s_log_as_compare_broad_s_mef_pos(tmp_path):
    from liemef.systems.bounded_velocity import K0_POSITION

    R = broad_mat(tmp_path / "01_synthetic.mat")
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--system", "attitude-position", "--out",
                 tmp_path / "log.csv")
    assert res.exit_code == 0, res.output
    run_as_compare_broad(tmp_path, "attitude-position", K0_POSITION, R)


def test_dataset_broad_writes_the_field_model_s_log_and_run_filters_it(tmp_path):
    """The lasting-disturbance model, compare broad's mef-field, is a ready system too: `liemef dataset broad
    --system attitude-field` writes its log (the field in uT) and `liemef run --system attitude-field` runs it
    as mef-field (discrete updates, exact curvature, left error, its K0), with the dip, gravity and field
    measured over the rest found in the log."""
    from liemef.systems.attitude_field import K0_FIELD

    R = broad_mat(tmp_path / "01_synthetic.mat")
    res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--system", "attitude-field", "--out",
                 tmp_path / "log.csv")
    assert res.exit_code == 0, res.output
    assert "liemef run --system attitude-field" in res.output
    assert "The best model of `liemef compare broad` is attitude-velocity" in res.output
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert header[7:13] == ["acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z"]
    log = np.loadtxt(tmp_path / "log.csv", delimiter=",", skiprows=1)
    assert np.linalg.norm(log[0, 10:13]) == pytest.approx(np.hypot(16.0, 40.0))  # the field in uT, not a direction
    config, est = run_as_compare_broad(tmp_path, "attitude-field", K0_FIELD, R)
    rest = config["rest"]
    assert rest["found"] and rest["measured"] == ["dip", "field", "gravity"]
    assert rest["dip_deg"] == pytest.approx(68.2, abs=0.2) and rest["field"] == pytest.approx(43.08, abs=0.05)
    assert np.abs(est[-1, 10:16]).max() < 2.0  # no disturbance in an undisturbed field (uT)


def test_run_says_when_a_log_has_no_initial_rest(tmp_path):
    """A log that starts in motion keeps the factory's dip and norms, and the run says so (a warning, and
    metrics.json's config.rest)."""
    broad_mat(tmp_path / "01_moving.mat", rest_s=0.0)
    assert invoke("dataset", "broad", tmp_path / "01_moving.mat", "--out", tmp_path / "log.csv").exit_code == 0
    res = invoke("run", "--system", "attitude-velocity", "--log", tmp_path / "log.csv", "--out", tmp_path / "o",
                 "--no-monitor", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "WARNING: no initial rest found in the log (gyr, acc: expected a log that starts at rest" in res.output
    assert "--set dip=RAD" in res.output
    rest = json.loads((tmp_path / "o" / "metrics.json").read_text())["config"]["rest"]
    assert rest["found"] is False and rest["measured"] == [] and "starts at rest" in rest["why"]


def test_run_takes_an_attitude_velocity_tuning_file(tmp_path):
    """`--params` takes a tuning file for attitude-velocity with --system attitude-velocity (not another
    model's); the system is built with its values and the dip and norms measured in the log."""
    broad_mat(tmp_path / "01_synthetic.mat")
    assert invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--out", tmp_path / "log.csv").exit_code == 0
    tuned = {"format": "liemef-tune-1", "system": "attitude-velocity", "params": {"velocity_std": 0.02}}
    (tmp_path / "tune.json").write_text(json.dumps(tuned))
    res = invoke("run", "--system", "attitude-velocity", "--params", tmp_path / "tune.json", "--log",
                 tmp_path / "log.csv", "--out", tmp_path / "o", "--no-monitor", "--no-progress")
    assert res.exit_code == 0, res.output
    params = json.loads((tmp_path / "o" / "metrics.json").read_text())["config"]["params"]
    assert params["system"] == "attitude-velocity" and params["from_file"] == ["velocity_std"]
    assert params["values"]["velocity_std"] == 0.02 and params["values"]["dip"] == pytest.approx(1.190, abs=0.004)
    assert invoke("dataset", "broad", tmp_path / "01_synthetic.mat", "--system", "attitude-imu", "--out",
                  tmp_path / "imu.csv").exit_code == 0
    res = invoke("run", "--system", "attitude-imu", "--params", tmp_path / "tune.json", "--log",
                 tmp_path / "imu.csv", "--out", tmp_path / "x", "--no-progress")
    assert res.exit_code == 2 and "tuned for 'attitude-velocity'" in res.output


def test_the_printed_command_runs_a_broad_head(tmp_path):
    """On BROAD trial 07's first 28 s (26.4 s of rest, then the fast rotation starts), the commands `liemef dataset
    broad` prints run the bounded-velocity model; its attitude error over BROAD's movement mask is small."""
    from liemef.metrics import attitude_rms
    from liemef.studies import datasets

    if "07" not in datasets.broad_trials():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    res = invoke("dataset", "broad", "07", "--seconds", "28", "--out", tmp_path / "log.npz", "--truth",
                 tmp_path / "truth.csv")
    assert res.exit_code == 0, res.output
    command = res.output.split("Filter it with: liemef ")[1].split()
    assert command[:2] == ["run", "--system"] and command[2] == "attitude-velocity"
    res = invoke(*command[:-1], tmp_path / "o", "--no-progress")
    assert res.exit_code in (0, 3), res.output  # 3: the monitor's verdict; the outputs are written
    assert "Measured over the initial rest detected from the IMU (26.4 s)" in res.output
    from scipy.spatial.transform import Rotation

    est = np.loadtxt(tmp_path / "o" / "estimates.csv", delimiter=",", skiprows=1)
    truth = np.loadtxt(tmp_path / "truth.csv", delimiter=",", skiprows=1)
    q = Rotation.from_rotvec(est[:, 1:4]).as_quat()[:, [3, 0, 1, 2]]
    assert attitude_rms(q, truth[:, 1:5], truth[:, 5] > 0)["total"] < 3.0


def test_dataset_refuses_an_output_liemef_run_cannot_read_and_names_each_option(tmp_path):
    """`liemef dataset` wrote w.txt (CSV inside) and then printed a `liemef run --log w.txt` that refuses it: the
    suffix is checked first, naming --out; a bad --seconds names --seconds, not PATH. Nothing is written."""
    broad_mat(tmp_path / "01_synthetic.mat")
    for args, said in ((["--out", tmp_path / "w.txt"], "Invalid value for '--out': out: expected a .csv or .npz"),
                       (["--out", tmp_path / "w.csv", "--seconds", -1], "Invalid value for '--seconds'"),
                       (["--out", tmp_path / "w.csv", "--seconds", 0], "expected a duration > 0 (none: the whole")):
        res = invoke("dataset", "broad", tmp_path / "01_synthetic.mat", *args)
        assert res.exit_code == 2 and said in res.output, res.output
    assert not (tmp_path / "w.txt").exists() and not (tmp_path / "w.csv").exists()


def test_the_integrator_is_an_option_of_run(tmp_path):
    """`liemef run --integrator rkmk2` filters with RKMK2 (two evaluations of the field a step) and records it in
    metrics.json; its estimate is RKMK4's to far below the estimate's own uncertainty, and not the same numbers.
    An integrator the run does not offer is refused, naming the option and the choices."""
    localization_log(tmp_path / "log.csv")
    common = ("--system", "localization", "--log", tmp_path / "log.csv", "--updates", "discrete", "--no-progress")
    runs = {}
    for name in ("rkmk4", "rkmk2"):
        extra = () if name == "rkmk4" else ("--integrator", name)  # rkmk4 is the default
        res = invoke("run", *common, *extra, "--out", tmp_path / name)
        assert res.exit_code == 0, res.output
        assert json.loads((tmp_path / name / "metrics.json").read_text())["config"]["integrator"] == name
        runs[name] = np.loadtxt(tmp_path / name / "estimates.csv", delimiter=",", skiprows=1)
    (a, b), n = runs.values(), 3  # t, the 3 coordinates, then K's diagonal
    assert a.shape == b.shape
    diff, sigma = np.abs(a[:, 1:1 + n] - b[:, 1:1 + n]), np.sqrt(a[:, 1 + n:1 + 2 * n])
    assert 0 < diff.max() and (diff / sigma).max() < 1e-2
    res = invoke("run", *common, "--integrator", "rk45", "--out", tmp_path / "bad")
    assert res.exit_code == 2 and "--integrator" in res.output and "rkmk2" in res.output
    assert not (tmp_path / "bad").exists()
