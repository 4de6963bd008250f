"""``liemef compare broad-ins``: inertial navigation on SE_2(3) with BROAD's real IMU and optical position fixes
(liemef.studies.compare._broad_ins), and the APE/RPE of ``compare inertial-navigation``.

* The truth's velocity is the central difference: exact on a parabola; a missing position makes it NaN.
* The fixes are the optical positions at 10 Hz, each once, with seeded noise of the stated std.
* The scoring: an estimate equal to the truth has zero errors and NEES; a position offset shows as itself in the
  position rms and in evo's APE, not in its RPE.
* On the real data (skipped when the folder is absent): the first optical pose and the lever-arm diagnostic; the
  whole study at a small size (slow).
"""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from liemef import cli
from liemef.groups import SE23, SO3, Rn
from liemef.studies import datasets
from liemef.studies.compare import _broad_ins as B

RATE = 285.714


def _synthetic(seconds: float = 4.0) -> B.InsTrial:
    """A trial that moves on a parabola and whose gyro reads a bias of 0.02 rad/s about z at rest for the first
    0.5 s, then a turn at 0.5 rad/s (the optical attitude turns from the start: only the initial state reads the
    gyro); one optical dropout row."""
    n = int(seconds * RATE)
    ts = np.arange(n) / RATE
    half = 0.25 * ts  # half the angle 0.5 t
    quat = np.stack([np.cos(half), 0 * ts, 0 * ts, np.sin(half)], axis=1)
    pos = np.stack([0.3 * ts**2, -0.1 * ts, 1.0 + 0 * ts], axis=1)
    quat[n // 2] = np.nan
    movement = ts >= 0.5
    gyr = np.outer(np.where(ts < 0.5, 0.02, 0.5), [0.0, 0.0, 1.0])
    tr = datasets.BroadTrial(ts=ts, gyr=gyr, acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
                             mag=np.tile([0.0, 20.0, -40.0], (n, 1)), quat_true=quat, movement=movement, rate=RATE,
                             name="synthetic")
    return B.InsTrial(tr, pos)


def _perfect_run(data: B.InsTrial, offset=(0.0, 0.0, 0.0)):
    """A filter run whose estimate is the truth (the position moved by ``offset``), with K = I."""
    tr = data.trial
    q = np.where(np.isfinite(tr.quat_true), tr.quat_true, [1.0, 0.0, 0.0, 0.0])
    v = np.nan_to_num(B.truth_velocity(data.pos, tr.rate))
    x = SE23.from_rotation_velocity_position(SO3(q), v, data.pos + np.asarray(offset))
    n = tr.ts.shape[0]
    g = B.INS_GROUP((x, Rn[18](jnp.zeros((n, 18)))))
    return SimpleNamespace(g_hat=g, K=np.broadcast_to(np.eye(27), (n, 27, 27)))


def test_the_true_velocity_is_the_central_difference():
    rate = 100.0
    t = np.arange(200) / rate
    pos = np.stack([0.5 * 2.0 * t**2, 3.0 * t, np.ones_like(t)], axis=1)
    v = B.truth_velocity(pos, rate, half_window=0.05)
    m = 5
    assert np.isnan(v[:m]).all() and np.isnan(v[-m:]).all() and np.isfinite(v[m:-m]).all()
    np.testing.assert_allclose(v[m:-m, 0], 2.0 * t[m:-m], rtol=0, atol=1e-12)  # exact on a parabola
    np.testing.assert_allclose(v[m:-m, 1], 3.0, rtol=0, atol=1e-12)
    pos[100] = np.nan
    v = B.truth_velocity(pos, rate, half_window=0.05)
    assert np.isnan(v[95]).all() and np.isnan(v[105]).all() and np.isfinite(v[100]).all()


def test_the_fixes_are_the_optical_positions_at_10_hz_with_seeded_noise():
    data = _synthetic()
    ts = data.trial.ts
    idx = B.fix_indices(ts, 10.0)
    assert idx[0] == 0 and np.all(np.abs(ts[idx] - np.arange(idx.size) / 10.0) <= 0.5 / RATE + 1e-12)
    assert idx.size == 40  # 0, 0.1, ..., 3.9 s
    rec = B.fixes(data, "16", 10.0, None, 0)
    have = np.isfinite(rec).all(axis=1)
    np.testing.assert_array_equal(np.flatnonzero(have), idx)
    np.testing.assert_array_equal(rec[idx], data.pos[idx])
    noisy = B.fixes(data, "16", 10.0, 0.1, 0)
    np.testing.assert_array_equal(noisy, B.fixes(data, "16", 10.0, 0.1, 0))  # seeded
    assert not np.array_equal(noisy[idx], B.fixes(data, "10", 10.0, 0.1, 0)[idx])  # a stream per trial
    e = noisy[idx] - data.pos[idx]
    assert 0.07 < e.std() < 0.13  # 120 draws of std 0.1
    log = B.ins_log(data, rec)
    np.testing.assert_array_equal(log.us[:-1, :3], data.trial.gyr[1:])  # sample k + 1 over [t_k, t_k+1]
    np.testing.assert_array_equal(log.us[:, 3:], np.concatenate([data.trial.acc[1:], data.trial.acc[-1:]]))


def test_the_truth_scores_zero_and_an_offset_scores_itself():
    data = _synthetic()
    figs, per_s = B.errors(data, _perfect_run(data))
    for key in ("total", "heading", "inclination", "velocity", "position"):
        assert figs[key] == pytest.approx(0.0, abs=1e-6), key
    for key in B.NEES_KEYS:
        assert figs[key] == pytest.approx(0.0, abs=1e-12), key
    assert figs["samples"] == int(B.scored(data).sum()) < data.trial.ts.shape[0]
    off = (0.03, -0.04, 0.0)  # 5 cm
    figs, _ = B.errors(data, _perfect_run(data, off))
    assert figs["position"] == pytest.approx(0.05, rel=1e-9)
    assert figs["total"] == pytest.approx(0.0, abs=1e-6)
    # the left error's position block is R^T (p - p_hat) with K = I: NEES / 3 = |offset|^2 / 3
    assert figs["nees_position"] == pytest.approx(0.05**2 / 3, rel=1e-6)
    assert np.nanmax(per_s) < 1e-4
    pytest.importorskip("evo")
    ev = B.trajectory_errors(data, _perfect_run(data, off))
    assert ev["ape_translation"]["rmse"] == pytest.approx(0.05, rel=1e-9)
    assert ev["rpe_translation"]["rmse"] == pytest.approx(0.0, abs=1e-9)
    assert ev["ape_rotation"]["rmse"] == pytest.approx(0.0, abs=1e-5)


def test_the_initial_state_comes_from_the_imu_alone():
    """TRIAD of the accelerometer and magnetometer at rest, the origin, zero velocity, the rest's mean gyro as the
    bias: the optical attitude and position (here a turned attitude and a far position) are not read."""
    from liemef.systems.imu_rest import initial_estimate

    data = _synthetic()
    turned = np.tile([0.0, 1.0, 0.0, 0.0], (data.trial.ts.shape[0], 1))
    far = B.InsTrial(dataclasses.replace(data.trial, quat_true=turned), data.pos + 100.0)
    for d in (data, far):
        x, b = B.initial_state(d).factors
        np.testing.assert_allclose(np.asarray(x.position()), 0.0)
        np.testing.assert_allclose(np.asarray(x.velocity()), 0.0)
        R = np.asarray(x.rotation().as_matrix())
        R_triad = np.asarray(initial_estimate(d.trial.acc[:50], d.trial.mag[:50]).factors[0].as_matrix())
        np.testing.assert_allclose(R, R_triad, atol=1e-12)
        # the mean gyro over the rest found from the IMU (it ends within a window, 0.5 s, of the turn at 0.5 s)
        np.testing.assert_allclose(np.asarray(b.x), [0.0, 0.0, 0.02] + [0.0] * 15, atol=1e-12)
    # the field (0, 20, -40) in the body at rest with gravity up: TRIAD's heading is the identity's
    np.testing.assert_allclose(R_triad, np.eye(3), atol=1e-12)
    sysm = B.system_of(RATE, 0.01)
    assert sysm.group is B.INS_GROUP and sysm.output_dim == 3 and sysm.group.tangent_dim == 27
    np.testing.assert_allclose(np.linalg.eigvalsh(B.K0), np.sort(np.diag(B.K0)))
    assert B.K0[6, 6] == 2.0**2  # the position unknown within a room: the first fixes place it
    assert B.K0.shape == (27, 27) and B.K0[15, 15] == B.LEVER_ARM_STD**2
    assert B.K0[18, 18] == B.K0[22, 22] == B.K0[26, 26] == B.GYRO_SCALE_STD**2 and B.K0[19, 19] == B.GYRO_CROSS_STD**2


def test_the_truth_is_carried_to_the_imu_by_the_lever_arm():
    """p + R r and v + R (w x r), w the gyro less its mean over the initial rest; no arm (or a failed fit) is the
    optical point itself, and a run that sits on the carried truth scores zero."""
    data = _synthetic()
    arm = np.array([0.1, 0.0, 0.02])
    p, v = B.truth_at_imu(data, arm)
    p0, v0 = B.truth_at_imu(data, None)
    np.testing.assert_array_equal(p0, data.pos)
    np.testing.assert_array_equal(v0, B.truth_velocity(data.pos, data.trial.rate))
    np.testing.assert_array_equal(B.truth_at_imu(data, np.full(3, np.nan))[0], data.pos)
    k = 600  # turning at 0.5 rad/s about z, the gyro's rest mean 0.02 rad/s
    th = 0.5 * data.trial.ts[k]
    R = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(p[k], data.pos[k] + R @ arm, atol=1e-12)
    np.testing.assert_allclose(v[k], v0[k] + R @ np.cross([0.0, 0.0, 0.48], arm), atol=1e-12)
    assert np.isnan(p[data.trial.ts.shape[0] // 2]).all()  # the optical attitude's dropout


def test_compare_inertial_navigation_reports_evo_errors_of_an_offset():
    pytest.importorskip("evo")
    from liemef.studies.compare._inertial import EVO_KEYS, trajectory_errors
    from liemef.studies.experiments import inertial as I

    c = I.InertialConfig(duration=3.0, steady=1.0)
    truth = I.setup(c).truth
    est = np.asarray(truth.wxyz_p).copy()
    est[:, 7:10] += [0.0, 0.3, 0.4]  # a constant 0.5 m position offset
    out = {"wxyz_p": np.stack([est, est]), "code": np.array([0, 3])}
    r = trajectory_errors(c, out)
    assert set(r) == {k for k, _, _ in EVO_KEYS}
    assert r["ape_translation"][0] == pytest.approx(0.5, rel=1e-9) and np.isnan(r["ape_translation"][1])
    assert r["rpe_translation"][0] == pytest.approx(0.0, abs=1e-9)
    assert r["ape_rotation"][0] == pytest.approx(0.0, abs=1e-5)


def _broad_present(tid: str = "16"):
    if datasets.realdata_dir() is None or tid not in datasets.broad_trials():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    return datasets.broad_trials()[tid]


def test_a_broad_trial_starts_at_the_file_s_first_sample():
    path = _broad_present("16")
    data = B.load_trial(path, seconds=60.0)
    whole = datasets.broad(path)
    np.testing.assert_array_equal(data.trial.gyr, whole.gyr[:data.trial.ts.shape[0]])
    assert not np.isfinite(data.trial.quat_true[0]).all()  # trial 16's optical attitude is missing at first
    assert data.trial.ts.shape[0] == data.pos.shape[0] == round(60.0 * data.trial.rate)
    r, before, after = B.lever_arm(data)
    assert np.linalg.norm(r) < 0.02 and after <= before  # the optical point is the IMU's to about a centimetre
    with pytest.raises(ValueError, match="trials"):
        B.BroadInsComparison(trials="99")
    with pytest.raises(ValueError, match="variants"):
        B.BroadInsComparison(trials="16", variants="noisier")
    with pytest.raises(ValueError, match="noise_std"):
        B.BroadInsComparison(trials="16", noise_std=0.0)
    with pytest.raises(ValueError, match="^gyro_scale_std: expected a number >= 0"):
        B.BroadInsComparison(trials="16", gyro_scale_std=-0.01)
    assert B.system_of(RATE, 0.01, 0.02).gyro_scale == 0.02  # every inertial filter's system
    st = B.BroadInsComparison(trials=16, ukf_trials="16", attitude_filters="none")
    assert st.trials == ("16",) and st.attitude_filters == () and st.ukf_variants == B.VARIANTS


@pytest.mark.slow  # about 3 min on a shared core: compiles two SE_2(3) x R^6 filters and VQF's run
def test_compare_broad_ins_on_a_short_slice(tmp_path):
    _broad_present("16")
    out = tmp_path / "bins"
    res = CliRunner().invoke(cli.cli, ["compare", "broad-ins", "--set", "trials=16", "--set", "seconds=45",
                                       "--filters", "mef,iekf-right", "--set", "attitude_filters=vqf-broad",
                                       "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    for f in ("broad_ins.md", "broad_ins.csv", "broad_ins.json", "arrays.npz"):
        assert (out / f).stat().st_size > 0, f
    meta = json.loads((out / "broad_ins.json").read_text())
    assert meta["schema"] == B.SCHEMA
    t = meta["per_trial"]["16"]
    for variant, bound in (("recorded", 0.03), ("noisy", 0.15)):
        for name in ("mef", "iekf-right"):
            r = t["variants"][variant]["filters"][name]
            assert r["ok"] and r["position"] < bound and r["inclination"] < 3.0, (variant, name)
            assert r["velocity"] < 0.5 and math.isfinite(r["nees_pose"])
    assert t["variants"]["noisy"]["added_noise_m"] == 0.1
    assert meta["attitude_only"]["16"]["vqf-broad"]["ok"]
    md = (out / "broad_ins.md").read_text()
    assert "## Attitude against the attitude-only filters" in md and "NaN" not in md


@pytest.mark.slow  # about 2 min: the filter, then the smoother of its 27-dimensional model over 45 s at 286 Hz
def test_the_smoother_row_beats_its_filter_and_has_no_monitor(tmp_path):
    _broad_present("16")
    out = tmp_path / "bins"
    res = CliRunner().invoke(cli.cli, ["compare", "broad-ins", "--set", "trials=16", "--set", "seconds=45",
                                       "--filters", "mef,mef-smooth", "--set", "attitude_filters=none",
                                       "--set", "variants=recorded", "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    rows = json.loads((out / "broad_ins.json").read_text())["per_trial"]["16"]["variants"]["recorded"]["filters"]
    f, s = rows["mef"], rows["mef-smooth"]
    assert f["ok"] and s["ok"] and f["monitor"] is not None and s["monitor"] is None and s["fix_nis"] is None
    assert s["position"] < f["position"] and s["total"] < f["total"], (f, s)
    assert math.isfinite(s["nees_pose"]) and "no monitor (acausal)" in (out / "broad_ins.md").read_text()


@pytest.mark.slow  # 2 and 4 min: one SE_2(3) x R^18 filter at each grid point on 50 s of two trials
@pytest.mark.parametrize("fix_grid", [None, "0.003,0.01"])
def test_the_grid_chooses_each_trial_s_point_from_the_other_trial(tmp_path, fix_grid):
    """Each trial's row is its run at the grid point (gyro_scale_std, and the fix's std where fix_std_grid is
    given) whose loss on the other trial is lowest; the CSV and the report say which."""
    _broad_present("10")
    _broad_present("16")
    # 50 s: both trials rest for their first 35-37 s, where nothing is scored
    st = B.BroadInsComparison(trials="10,16", seconds=50.0, filters="mef", attitude_filters="none",
                              variants="recorded", gyro_scale_grid="0,0.05", fix_std_grid=fix_grid)
    result = B.compare_broad_ins(st, progress=False)
    grid = result["grid"]["recorded"]["mef"]
    points = st.points
    assert len(points) == (2 if fix_grid is None else 4) and sorted(grid) == sorted(B._point_label(st, p)
                                                                                  for p in points)
    loss = {(p, t): grid[B._point_label(st, p)][t]["loss"] for p in points for t in ("10", "16")}
    assert all(v is not None and math.isfinite(v) for v in loss.values()), loss  # every run scored
    assert len({loss[p, "10"] for p in points}) == len(points)  # the grid's points differ
    for held, other in (("10", "16"), ("16", "10")):
        r = result["per_trial"][held]["variants"]["recorded"]["filters"]["mef"]
        best = min(points, key=lambda p: (loss[p, other], p))
        assert (r["gyro_scale_std"], r["fix_std_m"]) == best and r["training_loss"] == loss[best, other]
        assert r["total"] == grid[B._point_label(st, best)][held]["total"] and r["ok"]
    header, rows = B.csv_rows(result)
    assert [(r[header.index("gyro_scale_std")], r[header.index("fix_std_m")]) for r in rows] == [
        (result["per_trial"][t]["variants"]["recorded"]["filters"]["mef"]["gyro_scale_std"],
         result["per_trial"][t]["variants"]["recorded"]["filters"]["mef"]["fix_std_m"]) for t in ("10", "16")]
    assert "chosen per trial and filter by leave-one-out" in result["study"]["weights"]
    what = "gyro_scale_std" if fix_grid is None else "gyro_scale_std and the recorded fix's std"
    assert f"## {what} by leave-one-out, fixes recorded" in B.markdown(result)


def test_the_report_names_the_translation_trials_that_were_run():
    """The attitude section says which of the trials run are translation trials, from their files, not a fixed
    list."""
    files = {"07": "07_undisturbed_fast_rotation_B", "10": "10_undisturbed_slow_translation_A",
             "16": "16_undisturbed_fast_translation_B"}
    result = {"per_trial": {t: {"file": f} for t, f in files.items()}}
    assert B._translation_sentence(result, ["07", "10", "16"]) == " Trials 10 and 16 are translation trials."
    assert B._translation_sentence(result, ["07", "16"]) == " Trial 16 is a translation trial."
    assert B._translation_sentence(result, ["07"]) == ""


def test_the_band_fraction_is_095_for_consistent_nees_and_falls_for_overconfidence():
    rng = np.random.default_rng(0)
    n = 200_000
    values = np.stack([rng.chisquare(3, n) / 3, rng.chisquare(3, n) / 3, rng.chisquare(3, n) / 3,
                       rng.chisquare(9, n) / 9], axis=1)
    np.testing.assert_allclose(B.in_band(values), 0.95, atol=0.003)
    assert np.all(B.in_band(4.0 * values) < 0.6)  # errors twice the stated spread
    assert np.all(B.in_band(0.1 * values) < 0.6)  # an underconfident filter leaves the band too


def test_the_consistency_loss_is_zero_when_consistent_and_counts_each_factor_of_e():
    row = {"ok": True, "nees_attitude": 1.0, "nees_velocity": 1.0, "nees_position": 1.0, "nees_pose": 1.0}
    assert B.consistency_loss(row) == 0.0
    assert B.consistency_loss({**row, "nees_attitude": math.e}) == pytest.approx(1.0)  # too confident
    assert B.consistency_loss({**row, "nees_position": math.exp(-2.0)}) == pytest.approx(2.0)  # too cautious
    for bad in ({**row, "ok": False}, {**row, "nees_velocity": None}, {**row, "nees_attitude": math.nan},
                {**row, "nees_position": 0.0}):
        assert B.consistency_loss(bad) == math.inf


def test_the_leave_one_out_choice_never_reads_the_held_out_trial():
    rng = np.random.default_rng(3)
    grid = (0.0, 0.01, 0.02, 0.05)
    losses = {t: dict(zip(grid, rng.uniform(0, 5, len(grid)), strict=True)) for t in ("01", "07", "10", "16")}
    choice = B.held_out_choice(losses)
    for held in losses:
        others = [t for t in losses if t != held]
        means = {g: np.mean([losses[t][g] for t in others]) for g in grid}
        best = min(grid, key=lambda g: means[g])
        assert choice[held] == {"value": best, "training": pytest.approx(means[best])}
        # the held-out trial's own losses, however they change, do not move its choice
        moved = {**losses, held: {g: (0.0 if g != best else 99.0) for g in grid}}
        assert B.held_out_choice(moved)[held] == choice[held]
    # a failed run (infinite loss) on a training trial rules its value out; a tie goes to the smaller value
    tied = {"a": {0.0: 1.0, 0.1: 1.0}, "b": {0.0: math.inf, 0.1: 2.0}, "c": {0.0: 2.0, 0.1: 2.0}}
    assert B.held_out_choice(tied)["a"]["value"] == 0.1 and B.held_out_choice(tied)["b"]["value"] == 0.0
    assert B.held_out_choice({"a": {0.0: 1.0}}) == {}  # no other trial: no choice


def test_the_grid_setting_is_checked_and_names_its_argument(tmp_path):
    import scipy.io

    (tmp_path / "broad").mkdir()
    for tid in ("10", "16"):  # the settings read only which trials a folder holds: two files with BROAD's names
        scipy.io.savemat(tmp_path / "broad" / f"{tid}_stub.mat", dict.fromkeys(datasets.BROAD_VARIABLES, 0.0))
    study = lambda **kw: B.BroadInsComparison(realdata=str(tmp_path), **kw)  # noqa: E731
    st = study(trials="10,16", gyro_scale_grid="0.02,0,0.01")
    assert st.trials == ("10", "16") and st.gyro_scale_grid == (0.0, 0.01, 0.02)
    assert study(gyro_scale_grid=(0.05, 0)).gyro_scale_grid == (0.0, 0.05) and study().gyro_scale_grid is None
    for bad in ("0.01", "0,x", "0,0", "0,-0.1", 0.02, "0,nan", (True, 0.0)):
        with pytest.raises(ValueError, match="^gyro_scale_grid: expected at least two distinct numbers >= 0"):
            study(gyro_scale_grid=bad)
    with pytest.raises(ValueError, match="^gyro_scale_std: expected its default 0 when gyro_scale_grid"):
        study(gyro_scale_grid="0,0.01", gyro_scale_std=0.01)
    with pytest.raises(ValueError, match="^trials: expected at least two for gyro_scale_grid"):
        study(trials="16", gyro_scale_grid="0,0.01")
    # the recorded fix's std, alone or jointly: every pair is a point, the tables name both where it is searched
    st = study(trials="10,16", gyro_scale_grid="0.02,0.01", fix_std_grid="0.01,0.003")
    assert st.fix_std_grid == (0.003, 0.01) and st.searched
    assert st.points == [(0.01, 0.003), (0.01, 0.01), (0.02, 0.003), (0.02, 0.01)]
    assert B._point_label(st, (0.02, 0.003)) == "0.02, 0.003"
    alone = study(fix_std_grid="0.005,0.01")
    assert alone.points == [(0.0, 0.005), (0.0, 0.01)] and alone.searched
    assert study().points == [(0.0, B.RECORDED_FIX_STD)] and not study().searched
    assert B._point_label(study(gyro_scale_grid="0,0.01"), (0.01, B.RECORDED_FIX_STD)) == "0.01"  # as before
    for bad in ("0.01", "0,0.01", "0.01,x", "0.01,0.01", "0.01,-1", "0.01,inf", (True, 0.5)):
        with pytest.raises(ValueError, match="^fix_std_grid: expected at least two distinct numbers > 0"):
            study(fix_std_grid=bad)
    with pytest.raises(ValueError, match="^trials: expected at least two for fix_std_grid"):
        study(trials="16", fix_std_grid="0.003,0.01")
    with pytest.raises(ValueError, match=r"^seconds: expected at least one rest-detection window \(0.5 s\)"):
        study(seconds=0.1)  # the rest is found in windows: a shorter slice failed naming gyr and acc


def test_the_grid_tables_give_each_fold_s_choice_and_each_value_s_means():
    def row(total, nees, s, training=None):
        r = {"ok": True, "total": total, "inclination": 0.1, "velocity": 0.01, "position": 0.001,
             "nees_attitude": nees, "nees_velocity": 1.0, "nees_position": 1.0, "gyro_scale_std": s}
        return r if training is None else {**r, "training_loss": training}

    grid = {"0": {"10": B._grid_cell(row(1.0, 4.0, 0.0)), "16": B._grid_cell(row(2.0, math.e, 0.0))},
            "0.02": {"10": B._grid_cell(row(0.5, 1.0, 0.02)), "16": B._grid_cell(row(1.0, 1.0, 0.02))}}
    assert grid["0"]["16"]["loss"] == pytest.approx(1.0) and grid["0.02"]["10"]["loss"] == 0.0
    result = {"grid": {"recorded": {"mef": grid}}, "study": {"filters": ("mef",)},
              "per_trial": {t: {"variants": {"recorded": {"filters": {"mef": row(0.5, 1.0, 0.02, 0.0)}}}}
                            for t in ("10", "16")}}
    lines = B._grid_lines(result, ["10", "16"])
    assert "| mef | 0.02 (0) | 0.02 (0) |" in lines
    assert "| mef | 0 | 2 | 1.5 | 3.36 | 1 | 1 | 1.19 |" in lines  # (4 + e) / 2, (ln 4 + 1) / 2
    assert "| mef | 0.02 | 2 | 0.75 | 1 | 1 | 1 | 0 |" in lines
    assert B._grid_lines({"per_trial": {}}, []) == []
