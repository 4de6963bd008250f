"""liemef tune (liemef.studies.tune): the likelihood fit recovers known noise levels on simulated data within
the Monte Carlo spread, leave-one-out bookkeeping, the tuned set as a file, and its checks."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import minimize

from liemef import cli
from liemef.groups import R3, SO3, TSO3
from liemef.studies import tune as T
from liemef.systems import attitude_bias as ab
from liemef.systems import bounded_velocity as ab_vel
from test_attitude_imu import simulate

ACC, MAG = 0.03, 0.06                     # the truth the fit must find
FIXED = {"acc_adapt": 0.0, "mag_adapt": 0.0, "dip_std": 0.0, "gyro_std": ab.GYRO_STD, "bias_walk": 1e-5}


def _recording(seed):
    ts, us, ys, R, bias = simulate(seed=seed, duration=10.0, bursts=False, magnet=False)
    rng = np.random.default_rng(100 + seed)
    # directions with the known noise levels (the simulated ones replaced), renormalized
    up = np.einsum("nji,j->ni", R, [0.0, 0.0, 1.0]) + ACC * rng.standard_normal((len(ts), 3))
    m = np.einsum("nji,j->ni", R, ab.magnetic_reference(ab.DIP)) + MAG * rng.standard_normal((len(ts), 3))
    ys = ys.copy()
    ys[:, 0:3] = up / np.linalg.norm(up, axis=1, keepdims=True)
    ys[:, 3:6] = m / np.linalg.norm(m, axis=1, keepdims=True)
    g0 = TSO3((SO3.from_matrix(jnp.asarray(R[0])), R3(jnp.asarray(bias))))
    return T.Recording(f"s{seed}", ts, us, ys, {"dip": ab.DIP, "gravity": 9.81, "field": 43.0}, g0,
                       np.diag([1e-4] * 3 + [1e-6] * 3))


@pytest.fixture(scope="module")
def recordings():
    return [_recording(s) for s in range(4)]


@pytest.fixture(scope="module")
def short():
    return [T.Recording(r.name, r.ts[:300], r.us[:300], r.ys[:300], r.constants, r.g0, r.K0)
            for r in (_recording(0), _recording(1))]


@pytest.mark.slow  # about 2 minutes on a busy 2-core machine
def test_the_likelihood_fit_recovers_the_noise_levels(recordings):
    def fit(rec):
        f = lambda x: T.evaluate(rec, {**FIXED, "acc_std": 10 ** x[0], "mag_std": 10 ** x[1]}, "nll")  # noqa: E731
        return 10 ** minimize(f, np.log10([0.02, 0.05]), method="Nelder-Mead",
                              options={"xatol": 1e-3, "fatol": 1e-6, "maxfev": 60}).x

    fits = np.array([fit(r) for r in recordings])             # one per seed: the Monte Carlo spread
    mean, sd = fits.mean(axis=0), fits.std(axis=0, ddof=1)
    truth = np.array([ACC, MAG])
    # the truth lies within 3 standard errors of the mean fit (plus 2 % for the model's own approximations)
    assert np.all(np.abs(mean - truth) <= 3 * sd / 2 + 0.02 * truth), (fits, truth)
    res = T.tune(recordings, names=("acc_std", "mag_std"), objective="nll", start={**FIXED, "acc_std": 0.02,
                 "mag_std": 0.05}, maxfev=30, fold_maxfev=8, progress=False)
    final = np.array([res["params"]["acc_std"], res["params"]["mag_std"]])
    assert np.all(np.abs(final - truth) <= 3 * sd + 0.05 * truth), (final, fits)
    assert set(res["folds"]) == {"s0", "s1", "s2", "s3"}
    for f in res["folds"].values():
        assert np.isfinite(f["held_out"]) and np.isfinite(f["train"])


def test_the_tuned_set_as_a_file(tmp_path, short):
    recordings = short
    res = T.tune(recordings, names=("acc_std",), objective="nll",
                 start={**FIXED, "mag_std": MAG}, maxfev=4, fold_maxfev=2, progress=False)
    path = T.save(res, tmp_path / "tune.json")
    back = T.load(path)
    assert set(res) == set(T.FILE_KEYS)  # the file's schema is every key tune writes
    assert back["params"] == pytest.approx(res["params"])
    assert T.params_for(back, "s0") == res["folds"]["s0"]["params"]
    assert T.params_for(back, "other") == res["params"]
    system = T.system_from(back["params"], recordings[0].constants)
    assert float(system.sensors[0].noise.std[0]) == pytest.approx(res["params"]["acc_std"])
    assert "held-out" in T.markdown(res)
    (tmp_path / "bad.json").write_text('{"format": "liemef-tune-1", "system": "attitude-imu", "params": {"x": 1}}')
    with pytest.raises(ValueError, match="^params: .*: params.x: unknown parameter of attitude-imu"):
        T.load(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="^params: .*: format: expected a liemef tuning file"):
        T.load(_write(tmp_path / "other.json", "{}"))


TARGETS = {"r0": (-1.5, -1.0), "r1": (-1.2, -1.4), "r2": (-1.8, -1.1), "r3": (-1.0, -1.6)}
"""Per recording, the log10 (acc_std, mag_std) where the fake loss of :func:`_nested` is least."""


def _nested(monkeypatch, targets, fails=lambda name, x: False, workers=None):
    """tune on four recordings whose loss is a cheap quadratic in log10 (acc_std, mag_std) around ``targets``
    (``evaluate`` replaced; a run where ``fails(name, x)`` fails: inf), with every filter run and every search's
    start and end logged in order."""
    log = []

    def evaluate(rec, params, objective="truth", **kw):
        x = np.log10([params["acc_std"], params["mag_std"]])
        log.append(("run", rec.name, tuple(np.round(x, 9))))
        return math.inf if fails(rec.name, x) else float(np.sum((x - np.array(targets[rec.name])) ** 2))

    def search(loss_of, train, x0, maxfev, step):
        log.append(("search", tuple(train)))
        x = real_search(loss_of, train, x0, maxfev, step)
        log.append(("fixed", tuple(train)))
        return x

    real_search = T._search
    monkeypatch.setattr(T, "evaluate", evaluate)
    monkeypatch.setattr(T, "_search", search)
    recs = [T.Recording(n, np.zeros(1), np.zeros((1, 3)), np.zeros((1, 6)), {}, None, np.eye(6)) for n in targets]
    res = T.tune(recs, names=("acc_std", "mag_std"), start={"acc_std": 0.02, "mag_std": 0.05}, maxfev=40,
                 progress=False, workers=workers)
    return res, log


def test_no_fold_s_search_sees_its_held_out_recording(monkeypatch):
    res, log = _nested(monkeypatch, TARGETS)
    names = list(TARGETS)
    starts = [k for k, e in enumerate(log) if e[0] == "search"]
    assert len(starts) == len(names) + 1  # a search per fold, then the final one on every recording
    for k in starts:
        train = log[k][1]
        end = log.index(("fixed", train), k)
        runs = {e[1] for e in log[k:end] if e[0] == "run"}
        held = [n for n, t in zip(names, train, strict=True) if not t]
        assert not runs & set(held), (held, runs)  # no run of the held-out recording before the point is fixed
    for name, fold in res["folds"].items():  # the held-out error is that recording's loss at the fold's point
        x = np.log10([fold["params"]["acc_std"], fold["params"]["mag_std"]])
        assert fold["held_out"] == pytest.approx(np.sum((x - np.array(TARGETS[name])) ** 2))
    # a (point, recording) runs once: the start, where every search begins, once per recording
    runs = [e for e in log if e[0] == "run"]
    assert res["evaluations"] == len(runs) == len(set(runs))
    x0 = tuple(np.round(np.log10([0.02, 0.05]), 9))
    assert sorted(e[1] for e in runs if e[2] == x0) == names
    assert res["cross_validation"] == "nested" and res["params_from"] == "search-on-all-recordings"
    # changing recording r0's losses leaves the fold without it unchanged, and moves the others and the final set
    moved, _ = _nested(monkeypatch, {**TARGETS, "r0": (-2.5, -0.5)})
    assert moved["folds"]["r0"]["params"] == res["folds"]["r0"]["params"]
    assert moved["folds"]["r0"]["train"] == res["folds"]["r0"]["train"]
    assert moved["folds"]["r0"]["held_out"] != res["folds"]["r0"]["held_out"]
    for name in names[1:]:
        assert moved["folds"][name]["params"] != res["folds"][name]["params"], name
    assert moved["params"] != res["params"]
    text = T.markdown(res)
    assert "held-out (fold without it)" in text and "final set, in-sample" in text
    assert f"| mean | {res['held_out_mean']:.3f} | {res['train_mean']:.3f} | {res['train']:.3f} |" in text


def test_threads_change_no_result(monkeypatch, short):
    """A point's recordings run side by side in threads: the tune's result is the same with one thread or four,
    and every (point, recording) still runs once."""
    one, log1 = _nested(monkeypatch, TARGETS, workers=1)
    four, log4 = _nested(monkeypatch, TARGETS, workers=4)
    for res in (one, four):
        res.pop("elapsed_s")
    assert one == four
    assert sorted(e for e in log1 if e[0] == "run") == sorted(e for e in log4 if e[0] == "run")
    monkeypatch.undo()  # the real filter, run by two threads at once
    kw = dict(names=("acc_std",), objective="nll", start={**FIXED, "mag_std": MAG}, maxfev=3, fold_maxfev=2,
              progress=False)
    a, b = T.tune(short, workers=1, **kw), T.tune(short, workers=2, **kw)
    assert a["evaluations"] == b["evaluations"] > 2
    assert {k: v for k, v in a.items() if k != "elapsed_s"} == {k: v for k, v in b.items() if k != "elapsed_s"}
    with pytest.raises(ValueError, match="^workers: expected an integer >= 1 and <= .*, got 0"):
        T.tune(short, workers=0, **kw)


def test_a_failed_held_out_run_is_kept_as_a_failure(monkeypatch, tmp_path):
    """A run that fails scores inf, which JSON cannot hold: the file keeps it as null, reads back, and the report
    says "failed" (before, the tune's last step, the save, raised and its hours of work were not written)."""
    # r0 fails wherever acc_std < 10^-1.3: its fold's point (the others' optimum) is there, its training never is
    res, _ = _nested(monkeypatch, TARGETS, fails=lambda name, x: name == "r0" and x[0] < -1.3)
    assert res["folds"]["r0"]["held_out"] is None and res["held_out_mean"] is None
    assert all(f["held_out"] is not None for n, f in res["folds"].items() if n != "r0")
    path = T.save(res, tmp_path / "tune.json")
    back = T.load(path)
    assert back["folds"]["r0"]["held_out"] is None and back["held_out_mean"] is None
    text = T.markdown(back)
    assert "| r0 | failed |" in text and "| mean | failed |" in text
    with pytest.raises(ValueError, match=r"folds\.r0\.held_out: expected a finite number, or null"):
        T.read(_write(tmp_path / "bad.json", path.read_text().replace('"held_out": null', '"held_out": "x"', 1)))


def _write(path, text):
    path.write_text(text)
    return path


def test_bad_settings_are_refused(short):
    recordings = short
    with pytest.raises(ValueError, match="^recordings:"):
        T.tune(recordings[:1])
    with pytest.raises(ValueError, match="^names:"):
        T.tune(recordings[:2], names=("nope",))
    with pytest.raises(ValueError, match="^objective:"):
        T.tune(recordings[:2], objective="mse")
    with pytest.raises(ValueError, match="^maxfev: expected an integer >= 1"):
        T.tune(recordings[:2], maxfev=0)
    with pytest.raises(ValueError, match="^fold_maxfev: expected an integer >= 1"):
        T.tune(recordings[:2], fold_maxfev=2.5)
    with pytest.raises(ValueError, match="^objective: 'truth' needs a truth"):
        T.evaluate(recordings[0], FIXED, "truth")
    with pytest.raises(ValueError, match="^params.nope: unknown parameter of attitude-imu"):
        T.system_from({"nope": 1.0}, {})


@pytest.mark.slow  # two compilations of the 9-state model: about 30 s of CPU
def test_the_velocity_model_tunes_and_its_file_names_it(tmp_path):
    from test_attitude_imu import simulate_translation

    recs = []
    for seed in (0, 1):
        ts, gyr, acc, mag, R, v = simulate_translation(seed=seed, duration=3.0)
        _, us, ys = ab_vel.imu_velocity_log(gyr, acc, mag, 100.0)
        g0 = ab_vel.attitude_velocity_state(TSO3((SO3.from_matrix(jnp.asarray(R[0])), R3(jnp.zeros(3)))), v[0])
        recs.append(T.Recording(f"v{seed}", ts, us, ys, {"dip": ab.DIP, "gravity": 9.81, "field": 43.0}, g0,
                                np.diag([1e-4] * 3 + [1e-4] * 3 + [1e-2] * 3), system="attitude-velocity"))
    with pytest.raises(ValueError, match="^names:"):
        T.tune(recs, names=("acc_std",))  # a parameter of the other model
    res = T.tune(recs, names=("velocity_std",), objective="nll", maxfev=2, fold_maxfev=1, progress=False)
    assert res["system"] == "attitude-velocity" and np.isfinite(res["held_out_mean"])
    back = T.load(T.save(res, tmp_path / "tune.json"))
    system = T.system_from(T.params_for(back, "v0"), recs[0].constants, back["system"])
    assert system.group.tangent_dim == 9
    with pytest.raises(ValueError, match="^system:"):
        T.system_from({}, {}, "attitude-gps")


def test_the_integrator_reaches_every_run_and_the_file(monkeypatch, tmp_path):
    """``tune(integrator="rkmk2")`` runs every point's filter with it (the real ``evaluate`` builds the filter with
    its keyword), records it in the result and the file, and the file reads back with it; the default is RKMK4."""
    seen = []

    def evaluate(rec, params, objective="truth", **kw):
        seen.append(kw["integrator"])
        return float(np.log10(params["acc_std"]) ** 2)

    monkeypatch.setattr(T, "evaluate", evaluate)
    recs = [T.Recording(n, np.zeros(1), np.zeros((1, 3)), np.zeros((1, 6)), {}, None, np.eye(6)) for n in "ab"]
    res = T.tune(recs, names=("acc_std",), maxfev=4, progress=False, integrator="rkmk2")
    assert res["integrator"] == "rkmk2" and seen and set(seen) == {"rkmk2"}
    assert T.load(T.save(res, tmp_path / "tune.json"))["integrator"] == "rkmk2"
    seen.clear()
    assert T.tune(recs, names=("acc_std",), maxfev=4, progress=False)["integrator"] == "rkmk4"
    assert set(seen) == {"rkmk4"}
    seen.clear()  # an alias is the integrator's own name in the file (which reads only those); a bad one runs nothing
    assert T.tune(recs, names=("acc_std",), maxfev=4, progress=False, integrator="midpoint")["integrator"] == "rkmk2"
    assert set(seen) == {"rkmk2"}
    seen.clear()
    with pytest.raises(ValueError, match="^integrator: expected one of"):
        T.tune(recs, names=("acc_std",), maxfev=4, progress=False, integrator="rk45")
    assert not seen
    monkeypatch.undo()  # the real evaluate builds the filter with it

    class Built(Exception):
        pass

    def built(system, **kw):
        raise Built(kw["integrator"])

    import liemef.filters

    monkeypatch.setattr(liemef.filters, "MinimumEnergyFilter", built)
    with pytest.raises(Built, match="^rkmk2$"):
        T.evaluate(recs[0], {}, integrator="rkmk2")


def test_the_gyro_scale_is_a_velocity_parameter_that_starts_above_zero():
    recs = [T.Recording(f"v{i}", np.arange(3) / 100.0, np.zeros((3, 6)), np.zeros((3, 11)), {}, None, np.eye(9),
                        system="attitude-velocity") for i in range(2)]
    with pytest.raises(ValueError, match=r"^start: expected a value > 0 .* \['gyro_scale_std'\]"):
        T.tune(recs, names=("gyro_scale_std",), progress=False)  # its default 0 has no logarithm
    assert T.check_params({"gyro_scale_std": 0.0}, "attitude-velocity") == {"gyro_scale_std": 0.0}
    system = T.system_from({"gyro_scale_std": 0.01}, {"dip": ab.DIP, "gravity": 9.81, "field": 43.0},
                           "attitude-velocity")
    assert float(system.gyro_scale) == 0.01
    with pytest.raises(ValueError, match="^params.gyro_scale_std: unknown parameter of attitude-imu"):
        T.check_params({"gyro_scale_std": 0.01})


def test_a_start_beyond_the_bounds_is_refused_not_moved():
    """The search keeps to each parameter's bounds (PARAMETERS); a start beyond them was clipped without a word
    and the file recorded the clipped value as if it were the start. It is refused, naming the bounds."""
    recs = [T.Recording(f"v{i}", np.arange(3) / 100.0, np.zeros((3, 6)), np.zeros((3, 11)), {}, None, np.eye(9),
                        system="attitude-velocity") for i in range(2)]
    with pytest.raises(ValueError, match=r"^start: expected each searched parameter within its bounds, velocity_std "
                                         r"in \[0.01, 10\], got \{'velocity_std': 0.001\}"):
        T.tune(recs, names=("velocity_std",), start={"velocity_std": 1e-3}, progress=False)


def test_a_trial_given_twice_is_refused(tmp_path):
    """--trials 16,16: the fold "without" 16 would have trained on 16, and its held-out error would be in-sample. It
    is refused by name, as is a single trial (no leave-one-out)."""
    import scipy.io

    from liemef.studies import datasets

    (tmp_path / "broad").mkdir()
    for tid in ("16", "24"):
        scipy.io.savemat(tmp_path / "broad" / f"{tid}_stub.mat", dict.fromkeys(datasets.BROAD_VARIABLES, 0.0))
    with pytest.raises(ValueError, match=r"^trials: expected each trial once, got \['16', '16'\]"):
        T.broad_recordings(["16", "16"], realdata=str(tmp_path))
    res = CliRunner().invoke(cli.cli, ["tune", "broad", "--trials", "16", "--realdata", str(tmp_path), "--out",
                                       str(tmp_path / "t")])
    assert res.exit_code == 2 and "--trials" in res.output and "two or more" in res.output, res.output


@pytest.mark.parametrize("system, p, n", [("attitude-imu", 8, 6), ("attitude-velocity", 11, 9),
                                          ("attitude-position", 14, 12)])
def test_each_model_tunes_on_its_own_log_state_and_k0(tmp_path, system, p, n):
    """broad_recordings gives each IMU model its own log (outputs p), its state at rest (tangent n) and its K0,
    whole or in a window (where the attitude and bias blocks are what a user measures at rest and the blocks
    beyond them the model's own K0's); the system built from it takes that log. On a synthetic BROAD trial."""
    from test_cli_run import broad_mat

    (tmp_path / "broad").mkdir()
    broad_mat(tmp_path / "broad" / "16_synthetic.mat", rest_s=2.0, seconds=4.0)
    whole, = T.broad_recordings(["16"], None, str(tmp_path), system=system, gyro="backward")
    window, = T.broad_recordings(["16"], 1.0, str(tmp_path), lead=0.5, system=system, gyro="backward")
    for rec in (whole, window):
        assert rec.ys.shape[1] == p and rec.K0.shape == (n, n) and rec.system == system
        assert T.system_from({}, rec.constants, system).output_dim == p
        assert jnp.asarray(rec.g0.rminus(rec.g0)).shape == (n,)
    np.testing.assert_array_equal(np.diag(window.K0)[:6], [0.05**2] * 3 + [0.002**2] * 3)
    np.testing.assert_array_equal(np.diag(window.K0)[6:], np.diag(whole.K0)[6:])
    assert window.ts[-1] - window.ts[0] < whole.ts[-1] - whole.ts[0]


def test_every_search_starts_from_its_own_model_s_defaults():
    """A tune of the bounded-position model starts from attitude_position's defaults (a loose velocity, its
    position's stiffness), not the bounded-velocity model's stiff velocity: the one table of factories serves the
    search as it serves the systems it builds; ``start`` wins over a default."""
    from liemef.systems import imu_noise

    pos = T.start_set("attitude-position")
    assert pos["velocity_std"] == 1.0 and pos["position_std"] == ab_vel.POSITION_STD
    assert pos["position_walk"] == ab_vel.POSITION_WALK and pos["acc_density"] == ab_vel.POSITION_ACC_DENSITY
    assert T.start_set("attitude-velocity")["velocity_std"] == ab_vel.VELOCITY_STD
    assert "velocity_std" not in T.start_set("attitude-imu")
    assert T.start_set("attitude-imu")["bias_walk"] == imu_noise.IMU_BIAS_WALK != ab.BIAS_WALK
    assert T.start_set("attitude-position", {"position_std": 0.6})["position_std"] == 0.6
    assert set(pos) == set(T.SYSTEMS["attitude-position"])
    with pytest.raises(ValueError, match="^start.velocity_std: expected a finite number > 0"):
        T.start_set("attitude-position", {"velocity_std": -1.0})
