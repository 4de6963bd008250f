r"""``liemef compare broad-ins``: inertial navigation on SE_2(3) with the real IMU of the BROAD recordings.

BROAD (Laidig et al. 2021, CC BY 4.0) records an IMU at 285.7 Hz with optical motion capture: the attitude
``opt_quat`` and the position ``opt_pos`` (m, ENU world), both aligned to the IMU frame by the authors (the
dataset README). Here the real gyro and accelerometer drive :func:`~liemef.systems.inertial_navigation` with gyro
and accelerometer biases, the fixes' lever arm and the gyro's calibration errors ($SE_2(3) \times \mathbb
R^{18}$), and the optical positions, taken at 10 Hz, are its position fixes, in two variants:

* ``recorded``: the optical positions as recorded;
* ``noisy``: the same plus white noise of ``noise_std`` m per axis (default :data:`ADDED_NOISE_STD` = 0.1 m),
  drawn by ``numpy.random.default_rng([seed, trial])``.

**Lever arm and gyro calibration, as states.** The optical position is of a point about 1 cm from the IMU: a
least-squares fit of the lever arm $r$ in $R\tilde a - g = \ddot p + R([\dot\omega]_\times + [\omega]_\times^2)
r$ (the world specific force against the second difference of the smoothed optical position; :func:`lever_arm`,
reported per trial) gives $|r|$ = 0.7-1.1 cm on every trial, nearly all along the body z axis. That is the
weight of a recorded fix, but not white: it turns with the body, and a filter that takes the fixes as the IMU's
position ties its attitude to it. So every filter estimates it (``lever_arm=True``, the fixes' point at $r$ from
the IMU, prior :data:`LEVER_ARM_STD` = 5 cm per axis), and with it the gyro's calibration errors, scale factors
and cross-axis terms (``gyro_calibration="matrix"``, priors :data:`GYRO_SCALE_STD` = 2 % on the diagonal and
:data:`GYRO_CROSS_STD` = 1 % off it): without a magnetometer the heading of a turning body is observed only
through horizontal acceleration, and a gyro's scale and cross-axis errors grow with the angle turned, which its
white noise cannot account for. The filters' final lever arm (of the fixes' point from the IMU, so about minus the
fit's) and gyro calibration are reported beside the fit.

**Timing.** Every sample acts at its own time, as ``compare broad``'s ``mef-vel`` and ``vqf-broad``: IMU sample
k is the rate and specific force over the interval that ends at $t_k$ (``us[k]`` = sample k + 1, BROAD's
``gyro="backward"``), and the minimum-energy filters take the fixes with ``updates="discrete"`` (state k has
seen fix k). The Kalman baselines update with the fix at $t_k$ then predict (their state k + 1 has seen it).

**Weights: one set for all trials, stated priors, nothing fitted to these recordings** (:func:`system_of`):

* gyro 0.01 rad/s per sample at BROAD's rate (the top of the consumer-MEMS range in
  :mod:`liemef.systems.inertial`; about twice the white noise BROAD's gyro shows at rest, 0.0015-0.004 rad/s,
  for scale-factor and cross-axis errors in motion, as :data:`~liemef.systems.bounded_velocity.VELOCITY_GYRO_STD`
  argues);
* accelerometer 0.02 m/s^2/sqrt(Hz) (:data:`~liemef.systems.bounded_velocity.ACC_DENSITY`: a MEMS accelerometer's
  white noise plus its scale and misalignment errors in motion; 0.34 m/s^2 per sample at 285.7 Hz);
* bias random walks: :func:`~liemef.systems.inertial_navigation`'s defaults (1e-4 rad/s/sqrt(s), 1e-3
  m/s^2/sqrt(s));
* a fix: :data:`RECORDED_FIX_STD` = 1 cm per axis as recorded (motion capture, the synchronisation of two
  systems and what the lever arm's state has not yet learned),
  $\sqrt{0.01^2 + \sigma^2}$ with the added noise $\sigma$;
* gravity 9.81 m/s^2 (Berlin's is 9.813; the accelerometer bias absorbs the rest).

**The gyro's errors in motion as noise, chosen held out** (``gyro_scale_grid``; off by default). The calibration
states take the gyro's constant scale and cross-axis errors; what is left of them (errors that change with the
rate, the temperature or the axis turned about) the white gyro noise covers only on average. ``gyro_scale_std``
$s$ adds $s^2|\omega|^2/f$ to it (:class:`~liemef.systems._gyro_scale.GyroScaleSystem`). With a grid of values,
each filter runs at every value on every trial, and a trial's row is its run at the value chosen on the *other*
trials (:func:`held_out_choice`): the lowest mean :func:`consistency_loss`, how far the attitude, velocity and
position NEES are from 1. The choice reads no accuracy figure, and never the held-out trial's. ``fix_std_grid``
chooses the recorded fix's weight (a stated 1 cm otherwise) the same way, jointly with the gyro's where both are
given.

**Initial state, from the IMU alone, the same for every filter** (:func:`initial_state`): the run starts at the
file's first sample, as ``compare broad``'s. The attitude is TRIAD of the accelerometer and magnetometer over the
first samples of the initial rest found from the IMU (:func:`~liemef.systems.imu_rest.initial_rest`), as
``compare broad``'s filters start; the velocity is zero (at rest); the gyro bias is the mean gyro over that rest,
the accelerometer bias zero; the position is the origin, with a prior wide enough for a laboratory's optical
volume, so the first fixes place it. Nothing of the optical attitude or position enters before the fixes do.
K0 = :data:`K0` = diag((0.05 rad)^2 I3, (0.01 m/s)^2 I3, (2 m)^2 I3, (0.002 rad/s)^2 I3, (0.1 m/s^2)^2 I3,
(0.05 m)^2 I3, the gyro calibration's 0.02^2 on its diagonal and 0.01^2 off it): the attitude's as ``compare
broad``'s (a magnetometer's heading indoors and the accelerometer's tilt at rest), a velocity at rest, the position
unknown within a room, the biases at rest, a mount within a few centimetres and a MEMS gyro's scale and cross-axis
errors before calibration. Each filter reads K0 in its own error coordinates; with these isotropic blocks the
attitude and position priors are the same in the left and the right error to the first order.

**Truth and errors**, over BROAD's movement mask where the optical truth is present (as ``compare broad``). The
filters' state is the IMU's, so the optical position and velocity are carried to the IMU by the fitted lever arm
(:func:`truth_at_imu`; the scoring's only use of it):

* attitude: BROAD's total, heading and inclination rms of $q_{est} \otimes q_{ref}^{-1}$
  (:func:`~liemef.metrics.attitude_rms`), the same definition as the attitude-only filters';
* velocity: the central difference of the optical positions over $\pm$ :data:`VELOCITY_HALF_WINDOW` = 10 ms
  (3 samples; :func:`truth_velocity`). The window is chosen from the optical positions alone, where the
  difference's bias ($h^2 \dddot p / 6$) meets its noise: on the fast translation trial 16 the +-10 ms difference
  departs from the one-sample difference by 0.009 m/s rms, the size of that difference's own high-frequency noise
  (0.010 m/s), while the +-50 ms window used before departs by 0.11 m/s, its bias. The figure is the rms of
  $|\hat v - v|$;
* position: rms of $|\hat p - p|$;
* NEES of the left error $\xi = \log(\hat x^{-1} x)$ on $SE_2(3)$ under K's $9 \times 9$ pose block: attitude,
  velocity and position blocks each divided by 3, and the whole divided by 9 (1 for a consistent filter; the
  differenced truth velocity adds its own noise, a few mm/s), and the fraction of the scored samples whose NEES
  lies in its 95 % band, $\chi^2_d(0.025) \le \epsilon \le \chi^2_d(0.975)$ (0.95 for a consistent filter);
* the innovation monitor's verdict (:func:`liemef.metrics.innovation_monitor`, no truth) and the fixes' mean
  NIS per degree of freedom (1 when the fixes are as the filter predicts them; below 1, it expected worse); none
  for ``mef-smooth``, the smoother of ``mef``'s model over the whole trial (acausal: its residuals have no
  innovation covariance), whose NEES uses its marginal covariances;
* APE and RPE by evo (:func:`liemef.metrics.ape_rpe`, when evo is installed) on the 10 Hz subsample of the
  scored samples: APE translation (m) and rotation (deg); RPE over 10 pairs (1 s where no dropout intervenes).

**The attitude-only filters** of ``compare broad`` (default ``mef-vel`` and ``vqf-broad``, gyro, accelerometer
and magnetometer, no positions) run on the same trials, scored by the same errors over the same samples: the
question is whether the filter that models acceleration (and sees positions) has the lower attitude error on the
translation trials 10 and 16. They use the magnetometer, the inertial filters do not: their heading is observable
only through horizontal acceleration, so the inclination error is the like-for-like figure.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...groups import SE23, Product, Rn
from ...reports import io
from ...smoothers import OfflineSmoother
from ...systems import inertial_navigation
from ...systems._gyro_scale import gyro_scale_value
from .. import datasets
from ._broad import SMOOTH_TOL, check_seconds, trial_ids
from ._common import FILTERS, fmt, make_filter, parse_names, realdata_present, scoring, unscored_lines

SCHEMA = "liemef.compare.broad-ins/1"
"""Version tag of ``broad_ins.json``."""
FIX_RATE = 10.0
"""Default rate of the position fixes (Hz)."""
ADDED_NOISE_STD = 0.1
"""Default std (m, per axis) of the white noise added to the fixes in the ``noisy`` variant."""
RECORDED_FIX_STD = 0.01
"""Std (m, per axis) the filters give a recorded optical fix: motion capture and the unmodelled lever arm."""
GYRO_STD = 0.01
"""Gyro std per sample at BROAD's rate (rad/s), a stated prior (module docstring)."""
ACC_DENSITY = 0.02
"""Accelerometer noise density (m/s^2/sqrt(Hz)), a stated prior (module docstring)."""
GRAVITY = 9.81
"""Gravity (m/s^2)."""
VELOCITY_HALF_WINDOW = 0.01
"""Half the window (s) of the central difference that gives the true velocity (module docstring)."""
INS_GROUP = Product[SE23, Rn[18]]
"""The state: extended pose, gyro and accelerometer biases, the fixes' lever arm, the gyro's calibration matrix."""
LEVER_ARM_STD = 0.05
"""Prior std (m, per axis) of the lever arm of the fixes' point from the IMU: a mount within a few cm."""
GYRO_SCALE_STD = 0.02
"""Prior std (unitless, per axis) of the gyro's scale-factor errors: a MEMS gyro's 1-3 % before calibration."""
GYRO_CROSS_STD = 0.01
"""Prior std (unitless) of each of the gyro's cross-axis errors (misalignment and cross-axis sensitivity: about
1 % on a MEMS datasheet)."""
K0 = np.diag([0.05**2] * 3 + [0.01**2] * 3 + [2.0**2] * 3 + [0.002**2] * 3 + [0.1**2] * 3 + [LEVER_ARM_STD**2] * 3
             + [(GYRO_SCALE_STD if i == j else GYRO_CROSS_STD) ** 2 for i in range(3) for j in range(3)])
"""K0: attitude (rad), velocity (m/s), position (m), gyro bias (rad/s), accelerometer bias (m/s^2), lever arm (m),
the gyro's calibration matrix row by row: the IMU-only start's (module docstring)."""
VARIANTS = ("recorded", "noisy")
"""The fixes: the optical positions as recorded, and with added white noise."""
RPE_DELTA = 10
"""RPE over this many pairs of the 10 Hz subsample (1 s)."""

INS_FILTERS = {
    "mef": ("minimum-energy filter, second order, (0)-connection, samples at their own time",
            lambda s: make_filter("mef", s, updates="discrete")),
    "mef-first": ("first-order minimum-energy filter, samples at their own time",
                  lambda s: make_filter("mef-first", s, updates="discrete")),
    **{n: (FILTERS[n][0], lambda s, n=n: make_filter(n, s))
       for n in ("iekf-right", "iekf", "ekf", "ukf-left", "ukf-right", "ukf-local")},
    "mef-smooth": ("minimum-energy smoother: mef's cost minimized over the whole trial (liemef.smooth, from mef's "
                   "pass; acausal: estimate k has seen the whole trial)",
                   lambda s: OfflineSmoother(make_filter("mef", s, updates="discrete"), tol=SMOOTH_TOL)),
}
"""The inertial filters of the study: a description and a factory from the system."""
DEFAULT_FILTERS = ("mef", "mef-first", "iekf-right", "ekf", "ukf-left", "ukf-right")
"""The inertial filters run by default: the MEF (both orders) and the baselines of ``compare
inertial-navigation`` (the right-invariant EKF, the EKF in SO(3) x R^6 coordinates, the UKF-M left and right)."""
ATTITUDE_FILTERS = ("mef-vel", "vqf-broad")
"""The attitude-only filters of ``compare broad`` run beside them by default."""
METRICS = (("total", "attitude total", "deg"), ("heading", "attitude heading", "deg"),
           ("inclination", "attitude inclination", "deg"), ("velocity", "velocity", "m/s"),
           ("position", "position", "m"))
NEES_KEYS = ("nees_attitude", "nees_velocity", "nees_position", "nees_pose")
BAND_KEYS = ("band_attitude", "band_velocity", "band_position", "band_pose")
"""The fraction of the scored samples whose NEES (attitude, velocity, position: 3 dof; pose: 9) lies in its
two-sided 95 % chi-square band."""
CALIBRATION_KEYS = ("lever_arm_m", "gyro_calibration")
MONITOR_KEYS = ("monitor", "fix_nis")


@dataclass(frozen=True)
class BroadInsComparison:
    """The study's settings: ``trials`` (ids present; default every one), ``seconds`` (the head of each trial;
    default whole trials), ``filters`` (of :data:`INS_FILTERS`),
    ``attitude_filters`` (of ``compare broad``'s filters, or ``"none"``), ``variants`` (of :data:`VARIANTS`),
    ``fix_rate`` (Hz), ``noise_std`` (m, the ``noisy`` variant's added noise), ``seed`` (of that noise),
    ``realdata`` (the folder; default :func:`liemef.studies.datasets.realdata_dir`), and ``ukf_trials`` and
    ``ukf_variants``: the trials and variants the UKF-M filters run on (default all; the UKF-M costs about ten
    times the EKF here, so a slow machine may limit it, e.g. to ``10,16`` and ``recorded``), and ``gyro_scale_std``
    (unitless, default 0: off): the gyro's noise grows with the rate it measures, every inertial filter alike
    (:func:`system_of`). ``gyro_scale_grid`` (a comma-separated list of at least two values >= 0, or None: off)
    chooses ``gyro_scale_std`` per trial instead, by leave-one-out (:func:`held_out_choice`): each filter runs at
    every value on every trial, and a trial's row is the run at the value whose :func:`consistency_loss` is lowest
    on the mean over the other trials; ``gyro_scale_std`` must then keep its default. ``fix_std_grid`` (at least two
    values > 0, m, or None: :data:`RECORDED_FIX_STD`) chooses the recorded fix's weight the same way, jointly with
    ``gyro_scale_grid`` where both are given (every pair is a grid point; a noisy fix adds its noise to it)."""

    trials: tuple[str, ...] | str | None = None
    seconds: float | None = None
    filters: tuple[str, ...] | str | None = None
    attitude_filters: tuple[str, ...] | str | None = None
    variants: tuple[str, ...] | str | None = None
    fix_rate: float = FIX_RATE
    noise_std: float = ADDED_NOISE_STD
    seed: int = 0
    realdata: str | None = None
    ukf_trials: tuple[str, ...] | str | None = None
    ukf_variants: tuple[str, ...] | str | None = None
    gyro_scale_std: float = 0.0
    gyro_scale_grid: tuple[float, ...] | str | None = None
    fix_std_grid: tuple[float, ...] | str | None = None

    def __post_init__(self):
        from ._broad import BROAD_FILTERS

        folder, present = realdata_present(self.realdata, datasets.broad_trials, datasets.BROAD_DIR)
        trials = trial_ids("trials", self.trials, present, folder)
        ukf = trials if self.ukf_trials is None else trial_ids("ukf_trials", self.ukf_trials, present, folder)
        names = parse_names("filters", self.filters, INS_FILTERS, DEFAULT_FILTERS)
        att = self.attitude_filters
        att = () if att in ("none", "") or att == () else parse_names("attitude_filters", att, BROAD_FILTERS,
                                                                     ATTITUDE_FILTERS)
        variants = parse_names("variants", self.variants, VARIANTS, VARIANTS)
        ukf_variants = parse_names("ukf_variants", self.ukf_variants, VARIANTS, variants)
        for key in ("fix_rate", "noise_std"):
            v = getattr(self, key)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{key}: expected a number > 0, got {v!r}")
        g = float(gyro_scale_value("gyro_scale_std", self.gyro_scale_std))
        grid = _grid_values("gyro_scale_grid", self.gyro_scale_grid, lambda v: v >= 0, ">= 0")
        fixes = _grid_values("fix_std_grid", self.fix_std_grid, lambda v: v > 0, "> 0")
        if grid is not None and g != 0.0:
            raise ValueError(f"gyro_scale_std: expected its default 0 when gyro_scale_grid chooses it, got "
                             f"{self.gyro_scale_std!r}")
        for key, values in (("gyro_scale_grid", grid), ("fix_std_grid", fixes)):
            if values is not None and len(trials) < 2:
                raise ValueError(f"trials: expected at least two for {key}'s leave-one-out, got {trials!r}")
        check_seconds(self.seconds)
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool) and self.seed >= 0):
            raise ValueError(f"seed: expected an integer >= 0, got {self.seed!r}")
        for key, v in (("trials", trials), ("ukf_trials", ukf), ("ukf_variants", ukf_variants), ("filters", names),
                       ("attitude_filters", att),
                       ("variants", variants), ("realdata", str(folder)), ("fix_rate", float(self.fix_rate)),
                       ("noise_std", float(self.noise_std)), ("gyro_scale_std", float(g)),
                       ("gyro_scale_grid", grid), ("fix_std_grid", fixes)):
            object.__setattr__(self, key, v)

    @property
    def points(self) -> list[tuple[float, float]]:
        """The runs of each filter on each trial: (gyro_scale_std, the recorded fix's std) for every pair of the
        grids (a setting's own value where it has none)."""
        return [(g, f) for g in (self.gyro_scale_grid or (self.gyro_scale_std,))
                for f in (self.fix_std_grid or (RECORDED_FIX_STD,))]

    @property
    def searched(self) -> bool:
        """Whether a grid chooses each trial's run by leave-one-out."""
        return bool(self.gyro_scale_grid or self.fix_std_grid)


def _grid_values(name: str, grid, ok, floor: str) -> tuple[float, ...] | None:
    """A grid setting (a comma-separated list, a sequence or None) as sorted distinct floats, at least two, each
    finite and ``ok``; a ValueError naming ``name`` otherwise."""
    if grid is None:
        return None
    items = grid.split(",") if isinstance(grid, str) else list(grid) if isinstance(grid, tuple | list) else [grid]
    try:
        values = [] if any(isinstance(v, bool) for v in items) else sorted(float(v) for v in items)
    except (TypeError, ValueError):
        values = []
    if len(values) < 2 or len(set(values)) != len(values) or not all(math.isfinite(v) and ok(v) for v in values):
        raise ValueError(f"{name}: expected at least two distinct numbers {floor}, got {grid!r}")
    return tuple(values)


# --- the data ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InsTrial:
    """A BROAD trial (:class:`~liemef.studies.datasets.BroadTrial`) and its optical positions ``pos`` (N, 3) in m
    (NaN rows where the tracking dropped out; the fixes and the scoring read them)."""

    trial: datasets.BroadTrial
    pos: np.ndarray
    movement_s: float | None = None
    """When the whole trial's movement starts (:meth:`~liemef.studies.datasets.BroadTrial.movement_start`)."""


def load_trial(path, seconds: float | None = None) -> InsTrial:
    """:class:`InsTrial` of the BROAD file ``path`` (its first ``seconds`` if given), from the file's first sample:
    the start needs no optical data. ValueError naming ``path`` if the file has no ``opt_pos`` of the right
    shape."""
    import scipy.io

    tr = datasets.broad(path)
    d = scipy.io.loadmat(path, variable_names=["opt_pos"], squeeze_me=True)
    pos = np.asarray(d.get("opt_pos", np.zeros((0, 3))), dtype=np.float64)
    N = tr.ts.shape[0]
    if pos.shape != (N, 3):
        raise ValueError(f"path: {str(path)!r}: expected opt_pos of shape ({N}, 3), got {pos.shape}")
    cut = tr if seconds is None else tr.head(seconds)
    return InsTrial(cut, pos[:cut.ts.shape[0]], tr.movement_start())


def truth_velocity(pos: np.ndarray, rate: float, half_window: float = VELOCITY_HALF_WINDOW) -> np.ndarray:
    """The true velocity (N, 3) in m/s: ``(p[k + m] - p[k - m]) / (2 m / rate)`` with ``m = round(half_window
    rate)`` samples (at least 1); NaN where either position is missing or out of range."""
    m = max(1, int(round(half_window * rate)))
    v = np.full(pos.shape, np.nan)
    if pos.shape[0] > 2 * m:
        v[m:-m] = (pos[2 * m:] - pos[:-2 * m]) * (rate / (2 * m))
    return v


def fix_indices(ts: np.ndarray, rate: float) -> np.ndarray:
    """The samples nearest to ``t_0 + j / rate`` (j = 0, 1, ...), each once."""
    grid = np.arange(0.0, ts[-1] - ts[0] + 1e-12, 1.0 / rate)
    idx = np.unique(np.searchsorted(ts - ts[0], grid - 0.5 * (ts[1] - ts[0])))
    return idx[idx < ts.shape[0]]


def fixes(data: InsTrial, tid: str, rate: float, noise_std: float | None, seed: int) -> np.ndarray:
    """The position fixes (N, 3): the optical position at :func:`fix_indices`, plus white noise of ``noise_std``
    m per axis (``numpy.random.default_rng([seed, int(tid)])``, one draw per fix whether or not the optical
    position is present) unless ``noise_std`` is None; NaN elsewhere and where the tracking dropped out."""
    ts = data.trial.ts
    idx = fix_indices(ts, rate)
    ys = np.full((ts.shape[0], 3), np.nan)
    y = data.pos[idx].copy()
    if noise_std is not None:
        key = int(tid) if str(tid).isdigit() else sum(map(ord, str(tid)))
        y = y + noise_std * np.random.default_rng([seed, key]).standard_normal(y.shape)
    ys[idx] = y
    return ys


def ins_log(data: InsTrial, ys: np.ndarray) -> io.RecordedLog:
    """The filters' log: ``us[k]`` = (gyro, accelerometer) sample k + 1, the rate and specific force over the
    interval ending at $t_{k+1}$ (the last one held), and the fixes ``ys``."""
    tr = data.trial
    u = np.concatenate([tr.gyr, tr.acc], axis=1)
    us = np.concatenate([u[1:], u[-1:]], axis=0)
    return io.RecordedLog(ts=tr.ts.copy(), us=us, ys=ys)


def system_of(rate: float, fix_std: float, gyro_scale_std: float = 0.0):
    """:func:`~liemef.systems.inertial_navigation` with biases, the fixes' lever arm and the gyro's calibration,
    the study's priors (module docstring) and position fixes of ``fix_std`` m per axis. The accelerometer's prior
    is a density, given as its std per sample at ``rate`` beside the gyro's. ``gyro_scale_std`` (unitless, an
    array leaf) makes the gyro's noise grow with the rate it measures (0: off, the study's default)."""
    return inertial_navigation(gyro_std=GYRO_STD, acc_std=ACC_DENSITY * math.sqrt(rate), imu_rate=rate,
                               biases=True, gnss_std=fix_std, gravity=GRAVITY, lever_arm=True,
                               gyro_calibration="matrix", gyro_scale_std=gyro_scale_std)


def initial_state(data: InsTrial) -> INS_GROUP:
    """The initial estimate from the IMU alone (module docstring): TRIAD of the initial rest's first samples (as
    ``compare broad``'s :func:`~liemef.studies.compare._broad.trial_context`), zero velocity, the origin, the
    mean gyro over the rest as the gyro bias, zero accelerometer bias, lever arm and gyro calibration errors."""
    from ...systems.imu_rest import initial_estimate, initial_rest
    from ._broad import INITIAL_SAMPLES

    tr = data.trial
    rest = initial_rest(tr.gyr, tr.acc, tr.rate)
    first = min(INITIAL_SAMPLES, rest)
    R = initial_estimate(tr.acc[:first], tr.mag[:first]).factors[0]
    bg = tr.gyr[:rest].mean(axis=0)
    x = SE23.from_rotation_velocity_position(R, np.zeros(3), np.zeros(3))
    return INS_GROUP((x, Rn[18](np.concatenate([bg, np.zeros(15)]))))


def lever_arm(data: InsTrial, smooth: float = 0.05) -> tuple[np.ndarray, float, float]:
    r"""The least-squares lever arm $r$ (m, body frame) of the IMU from the optical position's point, from
    $R\tilde a - g e_z - \ddot p = R([\dot\omega]_\times + [\omega]_\times^2) r$ with the smoothed second difference
    of the positions (a box filter of ``smooth`` s applied twice) over the samples with the optical pose; also the
    rms residual before and after (m/s^2). A diagnostic, not used by the filters."""
    from scipy.ndimage import uniform_filter1d

    tr = data.trial
    n, rate = tr.ts.shape[0], tr.rate
    w = max(1, int(round(smooth * rate)))
    okq = np.isfinite(tr.quat_true).all(axis=1)
    okp = np.isfinite(data.pos).all(axis=1)
    k = np.arange(n)
    p = np.stack([np.interp(k, k[okp], data.pos[okp, i]) for i in range(3)], axis=1)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(np.where(okq[:, None], tr.quat_true, [1.0, 0, 0, 0])[:, [1, 2, 3, 0]]).as_matrix()
    sm = lambda x: uniform_filter1d(uniform_filter1d(x, w, axis=0), w, axis=0)  # noqa: E731
    ps, aw = sm(p), sm(np.einsum("nij,nj->ni", R, tr.acc) - [0.0, 0.0, GRAVITY])
    pdd = np.zeros_like(p)
    pdd[1:-1] = (ps[2:] - 2 * ps[1:-1] + ps[:-2]) * rate**2
    om = sm(tr.gyr)
    al = np.zeros_like(om)
    al[1:-1] = (om[2:] - om[:-2]) * rate / 2

    def skew(v):
        z = np.zeros(v.shape[0])
        return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1), np.stack([v[:, 2], z, -v[:, 0]], -1),
                         np.stack([-v[:, 1], v[:, 0], z], -1)], -2)

    use = (uniform_filter1d((okq & okp).astype(float), 6 * w) > 0.999) & (k >= 6 * w) & (k < n - 6 * w)
    if use.sum() < 10:
        return np.full(3, np.nan), math.nan, math.nan
    e = (aw - pdd)[use]
    A = np.einsum("nij,njk->nik", R, skew(al) + skew(om) @ skew(om))[use]
    r, *_ = np.linalg.lstsq(A.reshape(-1, 3), e.reshape(-1), rcond=None)
    rms = lambda x: float(np.sqrt(np.mean(np.sum(x**2, axis=1))))  # noqa: E731
    return r, rms(e), rms(e - np.einsum("nij,j->ni", A, r))


# --- the errors -------------------------------------------------------------------------------------------------
def scored(data: InsTrial) -> np.ndarray:
    """(N,) bool: the samples scored for position (and, where the velocity's truth is present too, velocity and
    NEES): BROAD's movement mask where the optical attitude and position are present. The attitude figures use
    BROAD's own samples, the movement mask where the optical attitude is present, as ``compare broad``."""
    tr = data.trial
    return tr.movement & np.isfinite(tr.quat_true).all(axis=1) & np.isfinite(data.pos).all(axis=1)


def truth_at_imu(data: InsTrial, arm=None) -> tuple[np.ndarray, np.ndarray]:
    r"""The true position and velocity (N, 3) of the IMU, the filters' state, from the optical point's:
    $p + R r$ and $v + R(\omega \times r)$ with the optical attitude $R$, the lever arm ``arm`` $r$ of the IMU
    from the optical point (m, body frame; :func:`lever_arm`, fitted to the optical data, for the scoring only;
    None or NaN: the optical point's own) and $\omega$ the gyro less its mean over the initial rest; $v$ is
    :func:`truth_velocity`. NaN where the optical pose is missing."""
    from scipy.spatial.transform import Rotation

    from ...systems.imu_rest import initial_rest

    tr = data.trial
    v = truth_velocity(data.pos, tr.rate)
    if arm is None or not np.all(np.isfinite(arm)):
        return data.pos, v
    r = np.asarray(arm, dtype=np.float64)
    ok = np.isfinite(tr.quat_true).all(axis=1)
    R = Rotation.from_quat(np.where(ok[:, None], tr.quat_true, [1.0, 0, 0, 0])[:, [1, 2, 3, 0]]).as_matrix()
    R[~ok] = np.nan
    w = tr.gyr - tr.gyr[:initial_rest(tr.gyr, tr.acc, tr.rate)].mean(axis=0)
    return data.pos + R @ r, v + np.einsum("nij,nj->ni", R, np.cross(w, r))


def errors(data: InsTrial, traj, arm=None, truth=None) -> tuple[dict, np.ndarray]:
    """One run's figures against the optical truth (module docstring) carried to the IMU by the lever arm ``arm``
    (:func:`truth_at_imu`), and its attitude error per second (for the figure): ``total``, ``heading``,
    ``inclination`` (deg), ``velocity`` (m/s), ``position`` (m) rms, the NEES (:data:`NEES_KEYS`) and
    ``samples``, the samples scored. ``truth``: :func:`truth_at_imu`'s result, when the caller already has it."""
    from ...metrics import attitude_error_per_second, attitude_rms

    tr = data.trial
    x = traj.g_hat.factors[0]
    q = np.asarray(x.wxyz_p[:, :4])
    v_hat, p_hat = np.asarray(x.velocity()), np.asarray(x.position())
    mask = scored(data)
    p_true, v_true = truth_at_imu(data, arm) if truth is None else truth
    vmask = mask & np.isfinite(v_true).all(axis=1)
    out = attitude_rms(q, tr.quat_true, tr.movement)  # as compare broad: movement mask, optical attitude present
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if e.size else None  # noqa: E731
    out["velocity"] = rms(v_hat[vmask] - v_true[vmask])
    out["position"] = rms(p_hat[mask] - p_true[mask])
    out["samples"] = int(mask.sum())
    if vmask.any():
        i = np.flatnonzero(vmask)
        q_true = tr.quat_true[i] / np.linalg.norm(tr.quat_true[i], axis=1, keepdims=True)
        true = np.concatenate([q_true, v_true[i], p_true[i]], axis=1)
        values = _nees_blocks(true, np.asarray(x.wxyz_p)[i], np.asarray(traj.K)[i][:, :9, :9])
        out.update({key: float(v) for key, v in zip(NEES_KEYS, values.mean(axis=0), strict=True)})
        out.update({key: float(f) for key, f in zip(BAND_KEYS, in_band(values), strict=True)})
    else:
        out.update(dict.fromkeys(NEES_KEYS + BAND_KEYS))
    return out, attitude_error_per_second(tr.ts, q, tr.quat_true, tr.movement)


def in_band(values: np.ndarray, prob: float = 0.95) -> np.ndarray:
    """(4,): of the rows of :func:`_nees_blocks` (the NEES per degree of freedom of the attitude, velocity,
    position and pose), the fraction inside the two-sided ``prob`` chi-square band of each block's 3, 3, 3 and 9
    degrees of freedom."""
    from scipy.stats import chi2

    out = []
    for j, d in enumerate((3, 3, 3, 9)):
        lo, hi = chi2.ppf([(1 - prob) / 2, (1 + prob) / 2], d) / d
        out.append(float(np.mean((values[:, j] >= lo) & (values[:, j] <= hi))))
    return np.asarray(out)


_CHUNK = 4096
"""Rows per call of the compiled NEES (one compilation for every trial's length)."""


@functools.cache
def _nees_fn():
    import jax
    import jax.numpy as jnp

    from ...metrics import left_error, nees

    def f(true, est, K):
        xi = left_error(SE23(true), SE23(est))
        return jnp.stack([nees(xi[:, a:b], K[:, a:b, a:b]) / (b - a) for a, b in ((0, 3), (3, 6), (6, 9), (0, 9))],
                         axis=1)

    return jax.jit(f)


def _nees_blocks(true: np.ndarray, est: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(M, 4): the attitude, velocity and position NEES / 3 and the pose NEES / 9 of the left error of the
    :class:`~liemef.groups.SE23` rows ``est`` (M, 10) against ``true`` (M, 10) under ``K`` (M, 9, 9), in chunks of
    :data:`_CHUNK` rows (padded with the identity) so that every trial uses one compiled function."""
    f, m, out = _nees_fn(), true.shape[0], []
    pad_row = np.array([1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    for a in range(0, m, _CHUNK):
        n = min(_CHUNK, m - a)
        T, E, C = (np.concatenate([x[a:a + n], np.broadcast_to(p, (_CHUNK - n, *p.shape))])
                   for x, p in ((true, pad_row), (est, pad_row), (K, np.eye(9))))
        out.append(np.asarray(f(T, E, C))[:n])
    return np.concatenate(out)


def trajectory_errors(data: InsTrial, traj, rate: float = FIX_RATE, delta: int = RPE_DELTA,
                      arm=None, truth=None) -> dict | None:
    """APE and RPE by evo (:func:`liemef.metrics.ape_rpe`) of a run against the optical poses carried to the IMU
    by the lever arm ``arm`` (:func:`truth_at_imu`), on the samples of
    :func:`fix_indices` at ``rate`` that are scored (:func:`scored`); RPE over ``delta`` pairs. None when evo is
    not installed or fewer than ``delta + 1`` samples qualify. ``truth`` as :func:`errors`'."""
    try:
        import evo  # noqa: F401
    except ImportError:
        return None
    from ...metrics import ape_rpe

    tr = data.trial
    i = fix_indices(tr.ts, rate)
    i = i[scored(data)[i]]
    x = traj.g_hat.factors[0]
    wxyz = np.asarray(x.wxyz_p[:, :4])[i]
    ok = np.isfinite(wxyz).all(axis=1)
    i, wxyz = i[ok], wxyz[ok]
    if i.size < delta + 1:
        return None
    q_true = tr.quat_true[i] / np.linalg.norm(tr.quat_true[i], axis=1, keepdims=True)
    p_est = np.asarray(x.position())[i]
    xyzw = lambda q: np.concatenate([q[:, 1:], q[:, :1]], axis=1)  # noqa: E731
    p_true = (truth_at_imu(data, arm) if truth is None else truth)[0][i]
    return ape_rpe(tr.ts[i], (p_est, xyzw(wxyz)), tr.ts[i], (p_true, xyzw(q_true)), max_diff=1e-6,
                   delta=delta)


def _evo_summary(res: dict | None) -> dict | None:
    if res is None:
        return None
    return {"ape_translation_rmse": res["ape_translation"]["rmse"], "ape_rotation_rmse": res["ape_rotation"]["rmse"],
            "rpe_translation_rmse": res["rpe_translation"]["rmse"], "rpe_rotation_rmse": res["rpe_rotation"]["rmse"],
            "pairs": res["pairs"]}


# --- the study --------------------------------------------------------------------------------------------------
def run_ins(name: str, data: InsTrial, log: io.RecordedLog, fix_std: float, gyro_scale_std: float = 0.0):
    """The inertial filter ``name`` (:data:`INS_FILTERS`) on ``log`` from :func:`initial_state` and :data:`K0`."""
    return _run(_ins_filter(name, data, fix_std, gyro_scale_std), data, log)


def _ins_filter(name: str, data: InsTrial, fix_std: float, gyro_scale_std: float):
    return INS_FILTERS[name][1](system_of(data.trial.rate, fix_std, gyro_scale_std))


def _run(flt, data: InsTrial, log: io.RecordedLog):
    return flt.run(flt.init(initial_state(data), K0), log.ts, log.us, log.ys)


def _calibration(traj) -> dict:
    """The run's final lever arm (m; of the fixes' point from the IMU, so about minus :func:`lever_arm`'s) and
    gyro calibration errors (row by row, unitless)."""
    z = np.asarray(traj.g_hat.factors[1].x)[-1]
    return {"lever_arm_m": [float(c) for c in z[6:9]], "gyro_calibration": [float(c) for c in z[9:18]]}


def _monitor(flt, log: io.RecordedLog, traj) -> dict:
    """The innovation monitor's verdict on the run ``traj`` of ``flt`` (:func:`liemef.metrics.innovation_monitor`,
    no truth) and the fixes' mean NIS per degree of freedom (1 for a consistent filter). None for a smoother: its
    residuals have no innovation covariance to be judged against."""
    from ...metrics import innovation_monitor

    if getattr(flt, "offline", False):
        return dict.fromkeys(MONITOR_KEYS)
    report = innovation_monitor(flt, traj, log.ts, log.us, log.ys)
    gnss = next(v for v in report.sensors if v.name == "gnss")
    return {"monitor": report.status, "fix_nis": None if gnss.mean_nis is None else gnss.mean_nis / gnss.dof}


def _score(name: str, data: InsTrial, log: io.RecordedLog, fix_std: float, gyro_scale_std: float, truth,
           fix_rate: float) -> tuple[dict, np.ndarray | None]:
    """One run of the inertial filter ``name``, scored: its row of figures and its attitude error per second."""
    t0 = time.perf_counter()
    flt = _ins_filter(name, data, fix_std, gyro_scale_std)  # run and monitored: built once
    traj = _run(flt, data, log)
    ok = bool(int(traj.status.code) == 0)
    run_s = time.perf_counter() - t0
    if ok:
        figs, per_s = errors(data, traj, truth=truth)
        evo_res = _evo_summary(trajectory_errors(data, traj, fix_rate, truth=truth))
        figs.update(_calibration(traj))
        figs.update(_monitor(flt, log, traj))
    else:
        figs, per_s, evo_res = {k: None for k, _, _ in METRICS}, None, None
        figs.update(dict.fromkeys(NEES_KEYS + BAND_KEYS + CALIBRATION_KEYS + MONITOR_KEYS))
    return ({"filter": INS_FILTERS[name][0], "ok": ok, "status": "ok" if ok else traj.status.message(log.ts), **figs,
             "evo": evo_res, "gyro_scale_std": float(gyro_scale_std), "run_s": run_s,
             "elapsed_s": time.perf_counter() - t0}, per_s)


def consistency_loss(row: dict) -> float:
    r"""How far a scored run's covariance is from its errors: $\sum_b |\ln \bar\epsilon_b|$ over the attitude,
    velocity and position blocks, $\bar\epsilon_b$ the block's NEES per degree of freedom averaged over the
    scored samples (0 for a filter whose covariance matches its errors on the average; a factor of e too
    confident or too cautious in one block costs 1). Infinite for a run that failed or has no NEES."""
    values = [row.get(k) for k in NEES_KEYS[:3]]
    if not row.get("ok") or any(v is None or not math.isfinite(v) or v <= 0 for v in values):
        return math.inf
    return float(sum(abs(math.log(v)) for v in values))


def held_out_choice(losses: dict[str, dict[float, float]]) -> dict[str, dict]:
    """Leave-one-out over trials: ``losses[trial][value]`` is a run's loss at each grid value. For each trial, the
    value whose mean loss over the *other* trials is lowest (the smallest value on a tie), with that training mean
    (``{"value", "training"}``): the held-out trial's own losses never enter its choice. A trial with no other
    trial gets no choice (KeyError is not raised: it is left out)."""
    out = {}
    for held in losses:
        others = [t for t in losses if t != held]
        if not others:
            continue
        grid = sorted(losses[held])
        mean = {v: float(np.mean([losses[t].get(v, math.inf) for t in others])) for v in grid}
        best = min(grid, key=lambda v: (mean[v], v))
        out[held] = {"value": best, "training": mean[best]}
    return out


def compare_broad_ins(study: BroadInsComparison | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "per_trial", "means", "attitude_only", "arrays"}``, and ``"grid"``
    where ``gyro_scale_grid`` chose ``gyro_scale_std`` per trial (each grid value's rows, every trial)."""
    st = BroadInsComparison() if study is None else study
    grid = st.points
    paths = datasets.broad_trials(Path(st.realdata) / datasets.BROAD_DIR)
    per_trial, runs = {}, {}
    for tid in st.trials:
        data = load_trial(paths[tid], st.seconds)
        r, before, after = lever_arm(data)
        truth = truth_at_imu(data, r)  # once per trial: every run is scored against it
        entry = {"file": data.trial.name,
                 "seconds": float(data.trial.ts[-1] - data.trial.ts[0]),
                 "lever_arm_m": [float(c) for c in r], "lever_arm_residual": [before, after],
                 "fixes": int(fix_indices(data.trial.ts, st.fix_rate).size), "variants": {},
                 **scoring(scored(data), data.trial.ts[-1] - data.trial.ts[0], data.movement_s)}
        for variant in st.variants:
            noise = None if variant == "recorded" else st.noise_std
            log = ins_log(data, fixes(data, tid, st.fix_rate, noise, st.seed))
            for name in st.filters:
                if name.startswith("ukf") and (tid not in st.ukf_trials or variant not in st.ukf_variants):
                    continue
                for point in grid:
                    g, recorded = point
                    fix_std = _fix_weight(recorded, noise)
                    row, per_s = runs[tid, variant, name, point] = _score(name, data, log, fix_std, g, truth,
                                                                          st.fix_rate)
                    row["fix_std_m"] = fix_std
                    if st.searched:
                        row["grid_point"] = _point_label(st, point)
                    if progress:
                        at = f" at {_point_label(st, point)}" if st.searched else ""
                        print(f"  trial {tid} {variant:8s} {name:10s}{at} attitude {fmt(row['total'])} (incl. "
                              f"{fmt(row['inclination'])}) deg, velocity {fmt(row['velocity'])} m/s, position "
                              f"{fmt(row['position'])} m, NEES {fmt(row['nees_pose'], 3)}, {row.get('monitor')}; "
                              f"run {row['run_s']:.1f} s, with the scoring {row['elapsed_s']:.1f} s",
                              file=sys.stderr, flush=True)
            entry["variants"][variant] = {"fix_std_m": _fix_weight(RECORDED_FIX_STD, noise),
                                          "added_noise_m": noise, "filters": {}}
        per_trial[tid] = entry
    arrays, grid_rows = {}, {}
    for variant in st.variants:
        for name in st.filters:
            ran = [t for t in st.trials if (t, variant, name, grid[0]) in runs]
            if st.searched:
                choice = held_out_choice({t: {p: consistency_loss(runs[t, variant, name, p][0]) for p in grid}
                                          for t in ran})
                grid_rows.setdefault(variant, {})[name] = {
                    _point_label(st, p): {t: _grid_cell(runs[t, variant, name, p][0]) for t in ran} for p in grid}
            else:
                choice = {t: {"value": grid[0], "training": None} for t in ran}
            for t in ran:
                if t not in choice:  # a filter run on one trial only (the UKF-M's subset): no fold to choose it
                    continue
                row, per_s = runs[t, variant, name, choice[t]["value"]]
                if st.searched:
                    row = {**row, "training_loss": _finite(choice[t]["training"])}
                per_trial[t]["variants"][variant]["filters"][name] = row
                if per_s is not None:
                    arrays[f"{t}/{variant}/{name}/error_1s"] = per_s
    attitude_only = _attitude_only(st, progress)
    system = "inertial_navigation(biases=True, lever_arm=True, gyro_calibration='matrix')"
    return {"study": {**dataclasses.asdict(st), "system": system,
                      "weights": f"gyro {GYRO_STD} rad/s per sample"
                                 + (f" plus {st.gyro_scale_std:g} times the rate it measures" if st.gyro_scale_std
                                    else "")
                                 + (" plus gyro_scale_std times the rate it measures" if st.gyro_scale_grid
                                    else "")
                                 + (", the recorded fix's std" if st.fix_std_grid else "")
                                 + (" (" + " and ".join(f"{k} from {{{', '.join(f'{v:g}' for v in vs)}}}"
                                                        for k, vs in (("gyro_scale_std", st.gyro_scale_grid),
                                                                      ("the fix's std [m]", st.fix_std_grid)) if vs)
                                    + ") chosen per trial and filter by leave-one-out (the lowest mean consistency "
                                    "loss over the other trials: the sum over attitude, velocity and position of "
                                    "|ln NEES per dof|; the trial's own runs never enter its choice)"
                                    if st.searched else "")
                                 + f", accelerometer {ACC_DENSITY} m/s^2/sqrt(Hz), "
                                 "bias walks inertial_navigation()'s defaults, gravity 9.81: stated priors"
                                 + (" (the grid apart)" if st.searched else "")
                                 + ", one set for all trials",
                      "K0": "diag(0.05^2 I3, 0.01^2 I3, 2^2 I3, 0.002^2 I3, 0.1^2 I3, "
                            f"{LEVER_ARM_STD}^2 I3, gyro calibration {GYRO_SCALE_STD}^2 on the "
                            f"diagonal and {GYRO_CROSS_STD}^2 off it)",
                      "initial": "from the IMU alone at the file's first sample: TRIAD over the initial rest "
                                 "detected from the IMU, zero velocity, the origin, gyro bias = mean gyro over that "
                                 "rest, zero accelerometer bias, lever arm and gyro calibration errors",
                      "fix_std_recorded_m": RECORDED_FIX_STD, "velocity_truth": f"central difference over +-"
                      f"{VELOCITY_HALF_WINDOW * 1e3:g} ms", "rpe_delta_pairs": RPE_DELTA},
            "per_trial": per_trial, "means": _means(st, per_trial), "attitude_only": attitude_only,
            **({"grid": grid_rows} if st.searched else {}), "arrays": arrays}


def _fix_weight(recorded: float, noise: float | None) -> float:
    """The std (m) a fix is weighted with: the recorded fix's, with the added white ``noise`` (None: none)."""
    return recorded if noise is None else math.hypot(recorded, noise)


def _point_label(st: BroadInsComparison, point: tuple[float, float]) -> str:
    """A grid point as the grid's tables name it: its gyro_scale_std (and the recorded fix's std in m, where
    ``fix_std_grid`` is searched)."""
    g, f = point
    return f"{g:g}, {f:g}" if st.fix_std_grid else f"{g:g}"


def _grid_cell(row: dict) -> dict:
    """A grid run's figures for the grid table: attitude total, the NEES per block and the loss."""
    return {**{k: row[k] for k in ("ok", "total", "inclination", "velocity", "position") + NEES_KEYS[:3]},
            "loss": _finite(consistency_loss(row))}


def _finite(v: float) -> float | None:
    """``v``, or None where it is infinite (a failed run's loss; JSON has no infinity)."""
    return v if math.isfinite(v) else None


def _attitude_only(st: BroadInsComparison, progress: bool) -> dict:
    """``compare broad``'s attitude-only filters on the same trials: their total, heading and inclination rms over
    the same samples (both start at the file's first sample and cover the same ``seconds``)."""
    if not st.attitude_filters:
        return {}
    from ._broad import BroadComparison, compare_broad

    out = {}
    for tid in st.trials:
        res = compare_broad(BroadComparison(trials=(tid,), seconds=st.seconds, filters=st.attitude_filters,
                                            realdata=st.realdata), progress=progress)
        out[tid] = {n: {k: r[k] for k in ("ok", "total", "heading", "inclination")}
                    for n, r in res["trials"][tid]["filters"].items()}
    return out


def _means(st: BroadInsComparison, per_trial: dict) -> dict:
    """Per variant and filter, the mean over the trials of each figure (None if a trial is missing or failed),
    and the trials it covers."""
    keys = [k for k, _, _ in METRICS] + list(NEES_KEYS) + list(BAND_KEYS) + ["fix_nis"]
    evo_keys = ("ape_translation_rmse", "ape_rotation_rmse", "rpe_translation_rmse", "rpe_rotation_rmse")
    out = {}
    for variant in st.variants:
        out[variant] = {}
        for name in st.filters:
            rows = [per_trial[t]["variants"][variant]["filters"].get(name) for t in st.trials]
            rows = [r for r in rows if r is not None]
            m = {"trials": len(rows)}
            for k in keys:
                v = [r[k] for r in rows]
                m[k] = None if not v or any(x is None for x in v) else float(np.mean(v))
            for k in evo_keys:
                v = [None if r["evo"] is None else r["evo"][k] for r in rows]
                m[k] = None if not v or any(x is None for x in v) else float(np.mean(v))
            m["monitor"] = {status: sum(r.get("monitor") == status for r in rows)
                            for status in sorted({r.get("monitor") for r in rows if r.get("monitor")})}
            out[variant][name] = m
    return out


# --- tables and files -------------------------------------------------------------------------------------------
def _translation_sentence(result: dict, trials) -> str:
    """" Trials 10 and 16 are translation trials." for the trials run whose file names a translation, else ""."""
    moving = [t for t in trials if "translation" in str(result["per_trial"][t].get("file", ""))]
    if not moving:
        return ""
    names = moving[0] if len(moving) == 1 else ", ".join(moving[:-1]) + " and " + moving[-1]
    return f" Trial{'s' if len(moving) > 1 else ''} {names} {'are' if len(moving) > 1 else 'is a'} translation " \
           f"trial{'s' if len(moving) > 1 else ''}."


def markdown(result: dict) -> str:
    """Per variant: the means over the trials, the figures per trial, and the attitude against the attitude-only
    filters."""
    st = result["study"]
    trials = list(st["trials"])
    lines = ["# Inertial navigation on BROAD's real IMU (Laidig et al. 2021, CC BY 4.0)", "",
             f"System: {st['system']}; weights: {st['weights']}; K0 = {st['K0']}; initial: {st['initial']}. "
             f"Position fixes at {st['fix_rate']:g} Hz from the optical positions (recorded: weighted "
             + ("with the std the grid chose" if st.get("fix_std_grid") else f"{st['fix_std_recorded_m']} m")
             + f"; noisy: plus white noise of {st['noise_std']:g} m per axis, seed "
             f"{st['seed']}). Errors over BROAD's movement mask where the optical truth is present: attitude as "
             f"BROAD (total, heading, inclination rms), velocity against the {st['velocity_truth']} of the optical "
             "positions, position; NEES of the left error on SE_2(3) under K (per block / 3, pose / 9); APE and RPE "
             f"by evo on the {st['fix_rate']:g} Hz subsample (RPE over {st['rpe_delta_pairs']} pairs). One "
             "recording per trial: no Monte Carlo spread.", "", *unscored_lines(result["per_trial"])]
    for variant in st["variants"]:
        means = result["means"][variant]
        lines += [f"## Fixes {variant}: means over the trials", "",
                  "| filter | trials | attitude [deg] | heading [deg] | inclination [deg] | velocity [m/s] | position "
                  "[m] | NEES att. | NEES vel. | NEES pos. | NEES pose | APE trans. [m] | APE rot. [deg] | RPE trans. "
                  "[m] | RPE rot. [deg] |", "|---|---:|" + "---:|" * 13]
        for name, m in means.items():
            cells = [fmt(m[k]) for k, _, _ in METRICS] + [fmt(m[k], 3) for k in NEES_KEYS]
            cells += [fmt(m[k]) for k in ("ape_translation_rmse", "ape_rotation_rmse", "rpe_translation_rmse",
                                          "rpe_rotation_rmse")]
            lines.append(f"| {name} | {m['trials']} | " + " | ".join(cells) + " |")
        lines += ["", f"Per trial (fixes {variant}): attitude total / inclination [deg], velocity [m/s], position "
                  "[m].", "", "| filter | " + " | ".join(trials) + " |", "|---|" + "---:|" * len(trials)]
        lines += _trial_rows(result, variant, trials, lambda r: f"{fmt(r['total'])} / {fmt(r['inclination'])}, "
                                                             f"{fmt(r['velocity'])}, {fmt(r['position'])}")
        lines.append("")
    att = result.get("attitude_only") or {}
    if att:
        names = list(next(iter(att.values())))
        lines += ["## Attitude against the attitude-only filters", "",
                  "Total / inclination rms [deg] over the same samples, BROAD's definition. The attitude-only filters "
                  "(`compare broad`) use the magnetometer and no position; the inertial filters the positions and "
                  "no magnetometer, so their heading is observable only through horizontal acceleration: the "
                  "inclination is the like-for-like figure." + _translation_sentence(result, trials), "",
                  "| trial | " + " | ".join(f"{n} ({v})" for v in st["variants"] for n in st["filters"])
                  + " | " + " | ".join(names) + " |",
                  "|---|" + "---:|" * (len(st["variants"]) * len(st["filters"]) + len(names))]
        for t in trials:
            cells = []
            for v in st["variants"]:
                for n in st["filters"]:
                    r = result["per_trial"][t]["variants"][v]["filters"].get(n)
                    cells.append("-" if r is None or not r["ok"] else f"{fmt(r['total'])} / {fmt(r['inclination'])}")
            for n in names:
                r = att[t][n]
                cells.append("-" if not r["ok"] else f"{fmt(r['total'])} / {fmt(r['inclination'])}")
            lines.append(f"| {t} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += _consistency_lines(result, trials)
    lines += _grid_lines(result, trials)
    variant = "recorded" if "recorded" in st["variants"] else st["variants"][0]
    vec = lambda v, k: "-" if v is None else "(" + ", ".join(f"{k * c:.2f}" for c in v) + ")"  # noqa: E731
    lines += ["## Lever arm and gyro calibration", "", "The least-squares lever arm of the IMU from the optical "
              "position's point fitted to the optical data (body frame, cm; the scoring's, not the filters') and the "
              "rms of the specific-force residual before / after it [m/s^2]; then each filter's final estimate (fixes "
              f"{variant}) of the lever arm of the fixes' point from the IMU (about minus the fit) [cm], of the "
              "gyro's scale-factor errors (its calibration matrix's diagonal) [%] and the largest of its cross-axis "
              "errors [%].", "",
              "| trial | fitted r [cm] | residual | " + " | ".join(f"{n} r [cm] | {n} scale [%] | {n} cross [%]"
                                                              for n in st["filters"]) + " |",
              "|---|---|---|" + "---|---|---:|" * len(st["filters"])]
    for t in trials:
        e = result["per_trial"][t]
        cells = []
        for n in st["filters"]:
            r = e["variants"][variant]["filters"].get(n) or {}
            m = r.get("gyro_calibration")
            m = None if m is None else np.reshape(m, (3, 3))
            cross = None if m is None else float(100 * np.max(np.abs(m - np.diag(np.diag(m)))))
            cells += [vec(r.get("lever_arm_m"), 100), vec(None if m is None else np.diag(m), 100), fmt(cross, 2)]
        lines.append(f"| {t} | {vec(e['lever_arm_m'], 100)} | {fmt(e['lever_arm_residual'][0])} / "
                     f"{fmt(e['lever_arm_residual'][1])} | " + " | ".join(cells) + " |")
    return "\n".join(lines + [""])


def _trial_rows(result: dict, variant: str, trials, cell) -> list[str]:
    """One table row per filter of the study, one cell per trial: ``cell(row)`` of a run that worked, else "not
    run" or "failed: " and its status."""
    lines = []
    for name in result["study"]["filters"]:
        cells = []
        for t in trials:
            r = result["per_trial"][t]["variants"][variant]["filters"].get(name)
            cells.append("not run" if r is None else f"failed: {r['status']}" if not r["ok"] else cell(r))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _consistency_cell(r: dict) -> str:
    """NEES per block with its fraction in band, the fixes' NIS and the monitor's verdict."""
    blocks = " / ".join(f"{fmt(r[k], 3)} ({fmt(r[b], 2)})" for k, b in zip(NEES_KEYS[:3], BAND_KEYS[:3], strict=True))
    return f"{blocks}; NIS {fmt(r['fix_nis'], 2)}, {r['monitor'] or 'no monitor (acausal)'}"


def _consistency_lines(result: dict, trials) -> list[str]:
    """Per variant, each filter's NEES per block with the fraction of samples in its 95 % band, the fixes' NIS and
    the innovation monitor's verdict, per trial."""
    st = result["study"]
    lines = []
    for variant in st["variants"]:
        lines += [f"## Consistency, fixes {variant}", "", "Per trial: the NEES per degree of freedom of the "
                  "attitude / velocity / position (1 when consistent) with, in brackets, the fraction of the scored "
                  "samples whose NEES lies in its 95 % band (0.95 when consistent); then the fixes' mean NIS per "
                  "degree of freedom and the innovation monitor's verdict (no truth).", "",
                  "| filter | " + " | ".join(trials) + " |", "|---|" + "---|" * len(trials)]
        lines += _trial_rows(result, variant, trials, _consistency_cell)
        lines.append("")
    return lines


def _grid_lines(result: dict, trials) -> list[str]:
    """Where a grid chose ``gyro_scale_std`` (and the recorded fix's std): per variant, each trial's choice with its
    training loss, then each grid point's means over every trial (in-sample, for reading: no choice uses them)."""
    grid = result.get("grid")
    if not grid:
        return []
    lines = []
    both = bool(result["study"].get("fix_std_grid"))
    what = "gyro_scale_std and the recorded fix's std" if both else "gyro_scale_std"
    column = "gyro_scale_std, fix std [m]" if both else "gyro_scale_std"
    for variant, per_filter in grid.items():
        lines += [f"## {what} by leave-one-out, fixes {variant}", "",
                  "Per trial: the value chosen without it (the lowest mean consistency loss over the other trials) "
                  "and that training loss; the trial's rows above are its runs at that value, held out.", "",
                  "| filter | " + " | ".join(trials) + " |", "|---|" + "---:|" * len(trials)]
        lines += _trial_rows(result, variant, trials,
                             lambda r: f"{r.get('grid_point', r['gyro_scale_std'])} ({fmt(r.get('training_loss'), 3)})")
        lines += ["", f"Each value on every trial (fixes {variant}; in-sample, for reading): means of the attitude "
                  "total [deg], of the NEES per dof of the attitude / velocity / position and of the consistency "
                  f"loss.", "", f"| filter | {column} | trials | attitude [deg] | NEES att. | NEES vel. | NEES "
                  "pos. | loss |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for name, per_value in per_filter.items():
            for value, cells in per_value.items():
                rows = list(cells.values())
                mean = {k: None if any(r[k] is None for r in rows) else float(np.mean([r[k] for r in rows]))
                        for k in ("total",) + NEES_KEYS[:3] + ("loss",)}
                lines.append(f"| {name} | {value} | {len(rows)} | {fmt(mean['total'])} | "
                             + " | ".join(fmt(mean[k], 3) for k in NEES_KEYS[:3]) + f" | {fmt(mean['loss'], 3)} |")
        lines.append("")
    return lines


def csv_rows(result: dict) -> tuple[list[str], list[list]]:
    """One row per trial, variant and filter (inertial; with the ``gyro_scale_std`` it ran at), then one per trial
    and attitude-only filter."""
    evo_keys = ("ape_translation_rmse", "ape_rotation_rmse", "rpe_translation_rmse", "rpe_rotation_rmse")
    header = (["trial", "variant", "filter", "ok"] + [k for k, _, _ in METRICS] + list(NEES_KEYS) + list(BAND_KEYS)
              + ["fix_nis", "monitor"] + list(evo_keys) + ["gyro_scale_std", "elapsed_s", "fix_std_m"])
    rows = []
    for t, e in result["per_trial"].items():
        for v, ve in e["variants"].items():
            for n, r in ve["filters"].items():
                ev = r["evo"] or {}
                rows.append([t, v, n, r["ok"], *(r[k] for k, _, _ in METRICS), *(r[k] for k in NEES_KEYS),
                             *(r[k] for k in BAND_KEYS), r["fix_nis"], r["monitor"], *(ev.get(k) for k in evo_keys),
                             r.get("gyro_scale_std"), r["elapsed_s"], r.get("fix_std_m")])
    for t, per in (result.get("attitude_only") or {}).items():
        for n, r in per.items():
            rows.append([t, "attitude-only", n, r["ok"], r["total"], r["heading"], r["inclination"]]
                        + [None] * (len(header) - 7))
    return header, rows


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``broad_ins.json``, ``broad_ins.md``, ``broad_ins.csv`` and ``arrays.npz`` (each run's attitude error
    per second) to ``out``."""
    out = io.ensure_dir(out)
    header, rows = csv_rows(result)
    return [io.write_npz(out / "arrays.npz", result["arrays"]),
            io.write_json(out / "broad_ins.json", {"schema": SCHEMA, **{k: v for k, v in result.items()
                                                                        if k != "arrays"}}),
            io.write_text(out / "broad_ins.md", markdown(result)),
            io.write_rows(out / "broad_ins.csv", header, rows)]


__all__ = ["BroadInsComparison", "compare_broad_ins", "markdown", "save", "load_trial", "InsTrial", "truth_velocity",
           "fix_indices", "fixes", "ins_log", "system_of", "initial_state", "lever_arm", "errors",
           "trajectory_errors", "run_ins", "INS_FILTERS", "DEFAULT_FILTERS", "ATTITUDE_FILTERS", "K0", "VARIANTS"]
