"""Output files are written completely or not at all; recorded logs are read with errors a person can act
on."""

import json
import os

import numpy as np
import pytest

from liemef.reports import io


def leftovers(d):
    return sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp"))


# --- output folder
def test_out_folder_is_created_with_its_parents(tmp_path):
    d = io.ensure_dir(tmp_path / "a" / "b" / "c")
    assert d.is_dir()
    assert io.ensure_dir(d) == d  # existing is fine


def test_unwritable_out_paths_raise_a_value_error(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(ValueError, match="out: expected a directory, got an existing file"):
        io.ensure_dir(f)
    with pytest.raises(ValueError, match="out: cannot create the directory"):
        io.ensure_dir(f / "sub")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes through permission bits")
def test_read_only_folder_raises_a_value_error(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    try:
        with pytest.raises(ValueError, match="expected a writable directory"):
            io.ensure_dir(d)
    finally:
        d.chmod(0o700)


# --- atomic writes
def test_failure_mid_write_keeps_the_old_file(tmp_path):
    p = tmp_path / "metrics.json"
    io.write_json(p, {"version": 1})
    with pytest.raises(RuntimeError, match="disk on fire"):
        with io.atomic_open(p, "w") as f:
            f.write('{"version": 2, "half": ')
            raise RuntimeError("disk on fire")
    assert json.loads(p.read_text()) == {"version": 1}
    assert leftovers(tmp_path) == []


def test_failed_rename_keeps_the_old_file(tmp_path, monkeypatch):
    p = tmp_path / "arrays.npz"
    io.write_npz(p, {"a": np.arange(3.0)})

    def broken_replace(src, dst):
        raise OSError("simulated crash before the rename")

    monkeypatch.setattr(io.os, "replace", broken_replace)
    with pytest.raises(OSError, match="simulated crash"):
        io.write_npz(p, {"a": np.arange(1000.0)})
    monkeypatch.undo()
    np.testing.assert_array_equal(io.read_arrays(p)["a"], np.arange(3.0))
    assert leftovers(tmp_path) == []


def test_unserializable_json_never_touches_the_file(tmp_path):
    p = tmp_path / "m.json"
    io.write_json(p, {"ok": True})
    with pytest.raises(ValueError):
        io.write_json(p, {"bad": float("nan")})  # strict JSON: NaN must be written as null
    with pytest.raises(TypeError):
        io.write_json(p, {"bad": object()})
    assert json.loads(p.read_text()) == {"ok": True}
    assert leftovers(tmp_path) == []


def test_written_files_are_complete_and_readable(tmp_path):
    arrays = {"ts": np.linspace(0, 1, 5), "names": np.array(["theta", "x"]), "K": np.eye(3)}
    paths = io.write_result(tmp_path / "out", {"schema": "x", "v": [1, 2]}, arrays)
    assert [p.name for p in paths] == ["arrays.npz", "metrics.json"]
    back = io.read_arrays(tmp_path / "out" / "arrays.npz")
    assert list(back["names"]) == ["theta", "x"]
    np.testing.assert_array_equal(back["K"], np.eye(3))
    assert io.read_metrics(tmp_path / "out" / "metrics.json") == {"schema": "x", "v": [1, 2]}
    assert (paths[0].stat().st_mode & 0o777) == 0o644
    with pytest.raises(ValueError, match="expected a numeric or string array, got dtype object"):
        io.write_npz(tmp_path / "o.npz", {"x": np.array([{}, 1], dtype=object)})


def test_unwritable_target_raises_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="cannot write"):
        io.write_json(tmp_path / "missing-folder" / "m.json", {})


# --- recorded logs
def write_log_csv(path, ts, us, ys, header=None):
    header = header or io.log_header(us.shape[1], ys.shape[1])
    io.write_csv(path, header, [ts, *us.T, *ys.T])
    return path


@pytest.fixture
def log_arrays():
    rng = np.random.default_rng(0)
    ts = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    return ts, rng.normal(size=(6, 2)), rng.normal(size=(6, 7))


def test_csv_log_round_trip_with_full_precision_and_any_column_order(tmp_path, log_arrays):
    ts, us, ys = log_arrays
    log = io.read_log(write_log_csv(tmp_path / "log.csv", ts, us, ys), 2, 7)
    np.testing.assert_array_equal(log.ts, ts)
    np.testing.assert_array_equal(log.us, us)
    np.testing.assert_array_equal(log.ys, ys)
    header = io.log_header(2, 7)
    perm = [3, 0, 8, 1, 2, 4, 5, 6, 7, 9]
    cols = [ts, *us.T, *ys.T]
    p = tmp_path / "shuffled.csv"
    io.write_csv(p, [" " + header[i] for i in perm], [cols[i] for i in perm])
    np.testing.assert_array_equal(io.read_log(p, 2, 7).ys, ys)


def test_npz_log_round_trip(tmp_path, log_arrays):
    ts, us, ys = log_arrays
    io.write_npz(tmp_path / "log.npz", {"ts": ts, "us": us, "ys": ys, "other": np.zeros(2)})
    log = io.read_log(tmp_path / "log.npz", 2, 7)
    np.testing.assert_array_equal(log.ys, ys)


def test_log_errors_name_what_was_expected(tmp_path, log_arrays):
    ts, us, ys = log_arrays
    with pytest.raises(ValueError, match="log: file not found"):
        io.read_log(tmp_path / "nope.csv", 2, 7)
    with pytest.raises(ValueError, match=r"log: expected a \.csv or \.npz file"):
        (tmp_path / "log.txt").write_text("t\n")
        io.read_log(tmp_path / "log.txt", 2, 7)
    p = write_log_csv(tmp_path / "a.csv", ts, us, ys[:, :6], header=io.log_header(2, 6))
    with pytest.raises(ValueError, match=r"missing column\(s\) \['y7'\].*expected the header t,u1,u2,y1"):
        io.read_log(p, 2, 7)
    p = write_log_csv(tmp_path / "b.csv", ts, us, np.hstack([ys, ys[:, :1]]), header=io.log_header(2, 8))
    with pytest.raises(ValueError, match=r"unexpected column\(s\) \['y8'\]"):
        io.read_log(p, 2, 7)
    bad = ys.copy()
    bad[3, 4] = np.inf
    p = write_log_csv(tmp_path / "c.csv", ts, us, bad)
    with pytest.raises(ValueError, match=r"got inf in column y5 at sample 3 \(t = 0\.3\)"):
        io.read_log(p, 2, 7)
    bad_t = ts.copy()
    bad_t[2] = np.nan
    p = write_log_csv(tmp_path / "c2.csv", bad_t, us, ys)
    with pytest.raises(ValueError, match=r"expected finite time stamps, got nan in column t at sample 2"):
        io.read_log(p, 2, 7)
    p = write_log_csv(tmp_path / "d.csv", ts[[0, 1, 3, 2, 4, 5]], us, ys)
    with pytest.raises(ValueError, match="expected strictly increasing time stamps, got t = 0.3 at sample 2"):
        io.read_log(p, 2, 7)
    p = tmp_path / "e.csv"
    p.write_text(",".join(io.log_header(2, 7)) + "\n" + ",".join(["0"] * 9 + ["abc"]) + "\n")
    with pytest.raises(ValueError, match=r"expected numbers or empty fields \(missing samples\) on line 2"):
        io.read_log(p, 2, 7)
    (tmp_path / "f.csv").write_text("")
    with pytest.raises(ValueError, match="the file is empty"):
        io.read_log(tmp_path / "f.csv", 2, 7)
    io.write_npz(tmp_path / "g.npz", {"ts": ts, "ys": ys})
    with pytest.raises(ValueError, match=r"missing array\(s\) \['us'\]"):
        io.read_log(tmp_path / "g.npz", 2, 7)
    io.write_npz(tmp_path / "h.npz", {"ts": ts, "us": us, "ys": ys[:, :3]})
    with pytest.raises(ValueError, match=r"expected ys of shape \(6, 7\) \(N = 6 samples\), got \(6, 3\)"):
        io.read_log(tmp_path / "h.npz", 2, 7)
    io.write_npz(tmp_path / "i.npz", {"ts": ts[:1], "us": us[:1], "ys": ys[:1]})
    with pytest.raises(ValueError, match="expected at least 2 samples"):
        io.read_log(tmp_path / "i.npz", 2, 7)


# --- missing samples, system column names, per-sensor time vectors
def test_empty_fields_and_nan_are_missing_samples(tmp_path, log_arrays):
    ts, us, ys = log_arrays
    p = tmp_path / "gaps.csv"
    lines = [",".join(io.log_header(2, 7))]
    for k in range(6):
        y = ["" if (k % 2 and j < 4) else repr(float(ys[k, j])) for j in range(7)]
        u = ["nan" if k == 4 else repr(float(us[k, 0])), repr(float(us[k, 1]))]
        lines.append(",".join([repr(float(ts[k])), *u, *y]))
    p.write_text("\n".join(lines) + "\n")
    log = io.read_log(p, 2, 7)
    assert np.isnan(log.ys[1, :4]).all() and np.isnan(log.ys[3, :4]).all() and np.isfinite(log.ys[:, 4:]).all()
    np.testing.assert_array_equal(log.ys[0], ys[0])
    assert np.isnan(log.us[4, 0]) and log.us[4, 1] == us[4, 1]


def test_system_column_names_and_write_log_round_trip(tmp_path):
    from liemef.systems import planar_localization

    system = planar_localization()
    ts = np.arange(5) * 0.01
    us = np.column_stack([np.full(5, 0.7), np.zeros(5), np.full(5, 0.1)])
    ys = np.full((5, 2), np.nan)
    ys[3] = [1.5, -2.0]
    p = io.write_log(tmp_path / "loc.csv", system, ts, us, ys)
    assert p.read_text().splitlines()[0] == "t,v_x,v_y,omega,gps_x,gps_y"
    assert p.read_text().splitlines()[1].endswith(",,")  # missing GPS written as empty fields
    log = io.read_log(p, system)
    np.testing.assert_array_equal(log.us, us)
    np.testing.assert_array_equal(log.ys, ys)  # NaN == NaN for assert_array_equal
    with pytest.raises(ValueError, match=r"missing column\(s\) \['gps_y'\].*expected the header t,v_x,v_y,omega"):
        (tmp_path / "bad.csv").write_text("t,v_x,v_y,omega,gps_x\n0,1,0,0,\n0.1,1,0,0,\n")
        io.read_log(tmp_path / "bad.csv", system)


def test_npz_with_a_time_vector_per_sensor_is_merged_on_the_union_of_times(tmp_path):
    from liemef.systems import planar_localization

    system = planar_localization()
    ts_u = np.arange(0, 31) * 0.1
    us = np.column_stack([np.ones(31), np.zeros(31), np.zeros(31)])
    t_gps = np.array([0.05, 1.0, 2.0, 2.95])  # 0.05 and 2.95 fall between odometry samples
    gps = np.arange(8.0).reshape(4, 2)
    io.write_npz(tmp_path / "s.npz", {"ts": ts_u, "us": us, "gps": gps, "t_gps": t_gps})
    log = io.read_log(tmp_path / "s.npz", system)
    assert log.ts.shape == (33,)  # 31 odometry times + 2 GPS-only times
    rows = np.flatnonzero(np.isfinite(log.ys[:, 0]))
    np.testing.assert_allclose(log.ts[rows], t_gps)
    np.testing.assert_array_equal(log.ys[rows], gps)
    assert np.isnan(log.us[np.searchsorted(log.ts, 0.05)]).all()  # no odometry then: held by the filter
    io.write_npz(tmp_path / "s2.npz", {"ts": ts_u, "us": us, "gps": gps})
    with pytest.raises(ValueError, match="sensor 'gps' has no time vector; expected an array t_gps"):
        io.read_log(tmp_path / "s2.npz", system)
