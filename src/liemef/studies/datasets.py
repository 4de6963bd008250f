"""Loaders for the real sensor logs with ground truth in ``../shared/realdata`` (read in place, never copied),
and their conversion to liemef logs.

* BROAD (Laidig, Caruso, Cereatti, Seel, "BROAD - A Benchmark for Robust Inertial Orientation Estimation",
  Data 6(7):72, 2021, CC BY 4.0): IMU gyro + accelerometer + magnetometer at 285.714 Hz with OptiTrack attitude
  ground truth; :func:`broad`, :func:`broad_to_log` (for :func:`liemef.systems.attitude_gyro_bias`).
* Wifibot (Brossard, Barrau, Bonnabel, "A Code for Unscented Kalman Filtering on Manifolds (UKF-M)", ICRA
  2020, BSD-3-Clause): wheel odometry at about 50 Hz with OptiTrack planar pose; :func:`wifibot`,
  :func:`wifibot_to_log` (for :func:`liemef.systems.planar_localization`, with synthetic GPS fixes as UKF-M
  makes them).

Where the data are: :func:`realdata_dir` (the environment variable ``LIEMEF_REALDATA``, else
``<repo>/../shared/realdata`` beside a source checkout). Cite the dataset authors in anything that reports
results on them.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..reports import io

ENV_VAR = "LIEMEF_REALDATA"
"""Environment variable naming the real-data folder (the one holding ``broad/`` and ``ukfm_wifibot/``)."""

BROAD_DIR = "broad"
"""The BROAD trials' folder inside :func:`realdata_dir`."""
WIFIBOT_DIR = "ukfm_wifibot"
"""The Wifibot runs' folder inside :func:`realdata_dir`."""
BROAD_VARIABLES = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")
"""The variables a ``.mat`` file must hold to be a BROAD trial."""
WIFIBOT_HEADER = ("t", "gyro", "vx", "vy", "theta", "px", "py")
"""The header line a text file must have to be a Wifibot run."""


def _trial_id(stem: str, prefix: str = "") -> str:
    """A recording's id from its file name: the leading number of ``NN_name`` (BROAD: ``"07"``), the number
    after ``prefix`` (``wifibot4`` -> ``"4"``), else the whole stem."""
    m = re.match(rf"^{re.escape(prefix)}(\d+)(?:_|$)", stem)
    return m.group(1) if m else stem


def broad_trials(folder: str | os.PathLike | None = None) -> dict[str, Path]:
    """Every BROAD trial present: the ``.mat`` files of ``folder`` (default ``realdata_dir() / "broad"``) that
    hold BROAD's variables (:data:`BROAD_VARIABLES`, read from the file's directory with
    ``scipy.io.whosmat``, without loading the arrays), by id (the file's leading number, ``"07"``), sorted.
    Other files are ignored; an absent folder gives ``{}``."""
    import scipy.io

    d = _folder(folder, BROAD_DIR)
    out = {}
    for p in sorted(d.glob("*.mat")) if d is not None else ():
        try:
            names = {v[0] for v in scipy.io.whosmat(p)}
        except Exception:  # scipy raises several types on a file that is not a .mat  # noqa: BLE001
            continue
        if names.issuperset(BROAD_VARIABLES):
            out.setdefault(_trial_id(p.stem), p)
    return dict(sorted(out.items()))


def wifibot_runs(folder: str | os.PathLike | None = None) -> dict[str, Path]:
    """Every Wifibot run present: the text files of ``folder`` (default ``realdata_dir() / "ukfm_wifibot"``)
    whose first line is the header :data:`WIFIBOT_HEADER`, by id (``wifibot4.txt`` -> ``"4"``), sorted."""
    d = _folder(folder, WIFIBOT_DIR)
    out = {}
    for p in sorted(d.glob("*.txt")) if d is not None else ():
        try:
            with p.open(encoding="utf-8") as f:
                header = tuple(f.readline().split())
        except (OSError, UnicodeDecodeError):
            continue
        if header == WIFIBOT_HEADER:
            out.setdefault(_trial_id(p.stem, "wifibot"), p)
    return dict(sorted(out.items()))


def _folder(folder, sub: str) -> Path | None:
    if folder is not None:
        p = Path(folder).expanduser()
        return p if p.is_dir() else None
    root = realdata_dir()
    return None if root is None or not (root / sub).is_dir() else root / sub


def realdata_dir() -> Path | None:
    """The real-data folder, or None when it is absent.

    In order: the folder named by the environment variable ``LIEMEF_REALDATA`` (None if it is set but is not a
    directory: a wrong setting is never silently replaced by another folder); else ``../shared/realdata``
    beside the repository checkout that holds this package (``<repo>/src/liemef/datasets.py``); else
    ``../shared/realdata`` beside the current working directory or one of its parents (a checkout run from
    inside, e.g. ``<repo>/tests``).
    """
    env = os.environ.get(ENV_VAR)
    if env:
        p = Path(env).expanduser()
        return p.resolve() if p.is_dir() else None
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / ".." / "shared" / "realdata"] if len(here.parents) > 2 else []
    cwd = Path.cwd().resolve()
    candidates += [d / ".." / "shared" / "realdata" for d in (cwd, *cwd.parents)]
    for c in candidates:
        if c.is_dir():
            return c.resolve()
    return None


# --- BROAD ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BroadTrial:
    """One BROAD trial (N samples at ``rate`` Hz; every vector in the IMU body frame).

    Attributes:
        ts: (N,) s, ``k / rate`` (BROAD's clock is uniform and has no time column).
        gyr: (N, 3) gyroscope, rad/s.
        acc: (N, 3) accelerometer (specific force, +9.81 along the body axis pointing up at rest), m/s^2.
        mag: (N, 3) magnetometer, uT.
        quat_true: (N, 4) OptiTrack attitude, unit quaternion (w, x, y, z) body -> ENU; NaN rows where the
            optical tracking dropped out.
        movement: (N,) bool, BROAD's evaluation mask (the authors' metrics use only these samples): for scoring
            only; a filter's rest is found from the IMU (:func:`liemef.systems.imu_rest.initial_rest`).
        rate: sample rate, Hz.
        name: the file's stem.
    """

    ts: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    quat_true: np.ndarray
    movement: np.ndarray
    rate: float
    name: str

    def movement_start(self) -> float | None:
        """When BROAD's movement mask first holds (s from the first sample; None: never): the scoring starts
        there. For the reports only (no filter sees the mask)."""
        k = np.flatnonzero(self.movement)
        return float(self.ts[k[0]] - self.ts[0]) if k.size else None

    def head(self, seconds: float) -> BroadTrial:
        """The first ``seconds`` of the trial."""
        if not (math.isfinite(seconds) and seconds > 0):
            raise ValueError(f"seconds: expected a duration > 0, got {seconds}")
        k = max(2, int(round(seconds * self.rate)))
        return BroadTrial(self.ts[:k], self.gyr[:k], self.acc[:k], self.mag[:k], self.quat_true[:k],
                          self.movement[:k], self.rate, self.name)


def broad(path: str | os.PathLike) -> BroadTrial:
    """A BROAD trial from its ``.mat`` file (MATLAB v5, read with scipy), as :class:`BroadTrial`.

    ValueError naming ``path`` if the file is missing or is not a BROAD trial.
    """
    import scipy.io

    p = io._existing_file(path, "path")
    try:
        d = scipy.io.loadmat(p, squeeze_me=True)
    except Exception as err:  # scipy raises several types on a file that is not a .mat
        raise ValueError(f"path: cannot read {str(p)!r} as a MATLAB .mat file ({err})") from err
    keys = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")
    missing = [k for k in keys if k not in d]
    if missing:
        raise ValueError(f"path: expected a BROAD trial with variables {list(keys)}, got {str(p)!r} without "
                         f"{missing}")
    rate = float(np.asarray(d["sampling_rate"]).reshape(()))
    gyr, acc, mag, quat = (np.asarray(d[k], dtype=np.float64) for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat"))
    N = gyr.shape[0]
    for k, a, w in (("imu_gyr", gyr, 3), ("imu_acc", acc, 3), ("imu_mag", mag, 3), ("opt_quat", quat, 4)):
        if a.shape != (N, w):
            raise ValueError(f"path: {str(p)!r}: expected {k} of shape ({N}, {w}), got {a.shape}")
    movement = np.asarray(d["movement"]).astype(bool).reshape(-1)
    if movement.shape != (N,) or not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"path: {str(p)!r}: expected movement of shape ({N},) and a rate > 0, got "
                         f"{movement.shape} and {rate}")
    return BroadTrial(ts=np.arange(N) / rate, gyr=gyr, acc=acc, mag=mag, quat_true=quat, movement=movement,
                      rate=rate, name=p.stem)


def broad_to_log(trial: BroadTrial, *, norms: bool = False, gyro: str = "forward") -> io.RecordedLog:
    """The liemef log of a BROAD trial for :func:`liemef.systems.attitude_gyro_bias`: ``us`` the gyro (N, 3),
    ``ys`` the normalized accelerometer and magnetometer (N, 6); with ``norms=True``, for
    :func:`liemef.systems.attitude_imu`, also their raw norms (N, 8). ``gyro="backward"`` takes gyro sample k as
    the rate over the interval that ends at $t_k$, BROAD's and VQF's convention
    (:func:`~liemef.systems.attitude_bias.imu_log`)."""
    from ..systems.attitude_bias import imu_log

    if not isinstance(trial, BroadTrial):
        raise ValueError(f"trial: expected a BroadTrial (from broad()), got {type(trial).__name__}")
    ts, us, ys = imu_log(trial.gyr, trial.acc, trial.mag, trial.rate, t0=float(trial.ts[0]), norms=norms,
                         gyro=gyro)
    return io.RecordedLog(ts=ts, us=us, ys=ys)


# --- Wifibot ----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class WifibotRun:
    """One Wifibot run of UKF-M (rows at about 50 Hz, irregular: always use ``ts``).

    Attributes:
        ts: (N,) s.
        v: (N,) forward body speed from wheel odometry, m/s (the lateral speed is 0: nonholonomic).
        omega: (N,) yaw rate from differential odometry, rad/s.
        truth: (N, 3) OptiTrack planar pose (theta rad, x m, y m), relative to the start pose.
        name: the file's stem.
    """

    ts: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    truth: np.ndarray
    name: str


def wifibot(path: str | os.PathLike) -> WifibotRun:
    """A Wifibot run from its text file (header ``t gyro vx vy theta px py``), as :class:`WifibotRun`.

    ValueError naming ``path`` if the file is missing or is not such a run.
    """
    p = io._existing_file(path, "path")
    try:
        with p.open(encoding="utf-8") as f:
            header = f.readline().split()
        data = np.loadtxt(p, skiprows=1, ndmin=2)
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"path: cannot read {str(p)!r} as a Wifibot run ({err})") from err
    want = list(WIFIBOT_HEADER)
    if header != want or data.shape[1] != len(want) or data.shape[0] < 2:
        raise ValueError(f"path: expected a Wifibot run with the header {' '.join(want)} and 7 numeric columns, "
                         f"got {str(p)!r} with header {header} and data of shape {data.shape}")
    t, w, vx, _, th, px, py = data.T
    if not np.all(np.isfinite(data)) or not np.all(np.diff(t) > 0):
        raise ValueError(f"path: {str(p)!r}: expected finite values and strictly increasing times")
    return WifibotRun(ts=t, v=vx, omega=w, truth=np.stack([th, px, py], axis=1), name=p.stem)


def synthetic_gps(run: WifibotRun, rate: float = 1.0, std: float = 0.1, seed: int = 0) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """UKF-M's synthetic GPS: at times ``t0 + k / rate`` the first row at or after it, whose true position
    plus N(0, std^2 I) (numpy ``default_rng(seed)``) is the fix. Returns the rows (K,) and the fixes (K, 2)."""
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate: expected a GPS rate > 0 in Hz, got {rate}")
    if not (math.isfinite(std) and std >= 0):
        raise ValueError(f"std: expected a GPS std >= 0 in m, got {std}")
    rng = np.random.default_rng(seed)
    tg = np.arange(run.ts[0], run.ts[-1], 1.0 / rate)
    idx = np.unique(np.searchsorted(run.ts, tg))
    idx = idx[idx < run.ts.shape[0]]
    return idx, run.truth[idx, 1:3] + std * rng.standard_normal((idx.shape[0], 2))


def wifibot_to_log(run: WifibotRun, gps_rate: float = 1.0, gps_std: float = 0.1, seed: int = 0) -> io.RecordedLog:
    """The liemef log of a Wifibot run for :func:`liemef.systems.planar_localization`: ``us = (v_x, v_y = 0,
    omega)`` (N, 3), ``ys`` = synthetic GPS fixes (N, 2) at ``gps_rate`` Hz (:func:`synthetic_gps`), NaN
    between fixes."""
    if not isinstance(run, WifibotRun):
        raise ValueError(f"run: expected a WifibotRun (from wifibot()), got {type(run).__name__}")
    idx, fixes = synthetic_gps(run, gps_rate, gps_std, seed)
    N = run.ts.shape[0]
    ys = np.full((N, 2), np.nan)
    ys[idx] = fixes
    us = np.stack([run.v, np.zeros(N), run.omega], axis=1)
    return io.RecordedLog(ts=run.ts.copy(), us=us, ys=ys)


def convert(kind: str, path: str | os.PathLike, out: str | os.PathLike, truth: str | os.PathLike | None = None,
            seconds: float | None = None, gps_std: float = 0.1, norms: bool = False, system: str | None = None
            ) -> tuple[io.RecordedLog, str, list[Path]]:
    """A real recording as a log for ``liemef run``: ``kind`` ``"broad"`` (a BROAD ``.mat`` trial) or
    ``"wifibot"`` (a Wifibot ``.txt`` run with synthetic GPS of ``gps_std`` m, system ``localization``), only its
    first ``seconds`` if given, written to ``out`` (``.csv`` or ``.npz``) and its ground truth to ``truth`` (CSV).
    ``system``: the ready system whose log to write (:func:`liemef.studies.registry.dataset_systems`; default the
    first: for BROAD ``attitude-velocity``, the bounded-velocity model, whose log holds the gyro as the rate over
    the interval that ends at each sample, :func:`~liemef.systems.bounded_velocity.imu_velocity_log`;
    ``attitude-imu``, also ``norms=True``: directions and raw norms; ``attitude-bias``: the directions;
    ``attitude-field``: :func:`~liemef.systems.attitude_field.imu_field_log`, the field in uT;
    ``attitude-position``: :func:`~liemef.systems.bounded_velocity.imu_position_log`). ``path``
    may also be the id of a recording present in the real-data folder (``"16"``; :func:`broad_trials`,
    :func:`wifibot_runs`). Returns the log, the ready system's name and the files written."""
    from ..systems.attitude_field import imu_field_log
    from ..systems.bounded_velocity import imu_position_log, imu_velocity_log
    from . import registry
    from .experiments import get_system

    if kind not in ("broad", "wifibot"):
        raise ValueError(f"kind: expected 'broad' or 'wifibot', got {kind!r}")
    choices = registry.dataset_systems(kind)
    if norms and system not in (None, "attitude-imu"):
        raise ValueError(f"system: --norms writes the log of attitude-imu, got --system {system} too")
    system = "attitude-imu" if norms else choices[0] if system is None else system
    if system not in choices:
        raise ValueError(f"system: expected a system whose log a {kind} recording gives, one of {list(choices)}, got "
                         f"{system!r}")
    if seconds is not None and not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds: expected a duration > 0 (none: the whole recording), got {seconds!r}")
    if Path(out).suffix.lower() not in (".csv", ".npz"):  # liemef run reads these two only
        raise ValueError(f"out: expected a .csv or .npz file, got {str(out)!r}")
    if not Path(path).exists():  # an id of a recording present, found by reading the files
        found = (broad_trials if kind == "broad" else wifibot_runs)()
        key = f"{int(str(path)):02d}" if kind == "broad" and str(path).isdigit() else str(path)
        path = found.get(key, path)
    if kind == "broad":
        rec = broad(path)
        rec = rec.head(seconds) if seconds is not None else rec
        if system in ("attitude-velocity", "attitude-position"):
            make = imu_velocity_log if system == "attitude-velocity" else imu_position_log
            log = io.RecordedLog(*make(rec.gyr, rec.acc, rec.mag, rec.rate, float(rec.ts[0]), gyro="backward"))
        elif system == "attitude-field":
            log = io.RecordedLog(*imu_field_log(rec.gyr, rec.acc, rec.mag, rec.rate, float(rec.ts[0]),
                                                gyro="backward"))
        else:
            log = broad_to_log(rec, norms=system == "attitude-imu")
        header = ["t", "q_w", "q_x", "q_y", "q_z", "movement"]
        columns = [rec.ts, *rec.quat_true.T, rec.movement.astype(np.float64)]
    else:
        rec = wifibot(path)
        if seconds is not None:
            k = max(2, int(np.searchsorted(rec.ts, rec.ts[0] + seconds)))
            rec = WifibotRun(rec.ts[:k], rec.v[:k], rec.omega[:k], rec.truth[:k], rec.name)
        log = wifibot_to_log(rec, gps_std=gps_std)
        header, columns = ["t", "theta", "x", "y"], [rec.ts, *rec.truth.T]
    written = [io.write_log(out, get_system(system).make(), log.ts, log.us, log.ys)]
    if truth is not None:
        written.append(io.write_csv(truth, header, columns))
    return log, system, written
