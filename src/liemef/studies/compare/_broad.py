r"""``liemef compare broad``: every attitude filter on the BROAD recordings (Laidig et al. 2021, CC BY 4.0).

BROAD (Berlin Robust Orientation Estimation Assessment Dataset) records an IMU (gyro, accelerometer and
magnetometer at 285.7 Hz) with optical motion-capture attitude as the truth. The trials are the ones present in
the real-data folder (:func:`liemef.studies.datasets.realdata_dir`). Every filter gets:

- the same log (:func:`trial_logs`, :func:`liemef.studies.datasets.broad_to_log`), but for the filters of
  :data:`OWN_TIME`, which take gyro sample k over the interval that ends at t_k, as VQF and BROAD do;
- the same initial estimate, TRIAD from the first 50 samples of the initial rest, with zero bias (VQF and Fusion
  start themselves from their first samples);
- for the covariance filters, the same K0 = diag((0.05 rad)^2 I3, (0.01 rad/s)^2 I3).

Nothing from the truth reaches a filter: the initial rest is found from the IMU samples alone
(:func:`~liemef.systems.imu_rest.initial_rest`), and the magnetic dip, gravity and field are measured over
it (:func:`~liemef.systems.imu_rest.rest_constants`); BROAD's ``movement`` annotation and the optical
attitude only score. Not every filter takes every prior: :func:`given` reads off each filter what it uses
(VQF none: its defaults on the raw readings, from its own first samples), and the table says so.

:func:`setup` builds each filter, its state and its log. **Alignment**: every baseline (VQF, Madgwick, Mahony,
Fusion) runs in BROAD's indexing (``broad_indexing=True``): its estimate at t_k has seen gyro, accelerometer and
magnetometer sample k, as BROAD's evaluation and the published figures index them. The minimum-energy, Kalman
and UKF filters record their state at t_k before the sample at t_k acts: one sample late on the accelerometer
and the magnetometer, and on the gyro too but for :data:`OWN_TIME`. The study records every filter's lag per
sensor (:func:`lags`, the ``lags`` of ``broad.json`` and a column of the table); ``tests/test_broad.py`` checks
each by perturbing the samples after the ones it says the estimate has seen. ``vqf-offline`` and
``mef-vel-smooth`` are acausal.

The weights are **one set for all trials**: the defaults of :func:`liemef.systems.attitude_gyro_bias`. The
metrics are the dataset's own: the total, heading and inclination rms of the error
$q_{est} \otimes q_{ref}^{-1}$ (world frame) over BROAD's movement mask, where the optical truth is present
(the dataset README's formulas).

Filters (:data:`BROAD_FILTERS`):

- the MEF (both orders, the three connections);
- ``mef-robust``: Huber losses on the accelerometer (fast translation, tapping) and on the magnetometer
  (magnetic disturbances);
- the invariant EKF and the left UKF-M. On SO(3) x R^3 the local EKF is the invariant one (a multiplicative
  rotation error, an additive bias), so it is not run twice;
- ahrs's Madgwick and Mahony (:mod:`liemef.filters.baselines`), with ahrs's default gains and with the gains published
  with the dataset (Madgwick beta = 0.12; Mahony Kp = 0.74, Ki = 0.0012);
- VQF (Laidig and Seel 2023), online (``vqf``; ``vqf-broad`` is the same filter, its former name) and offline;
- ``mef-pos``, ``mef-pos-first`` and ``iekf-pos``: the bounded-position model
  (:func:`liemef.systems.attitude_position`), its three filters, samples at their own time. Not run by default;
- ``mef-vel-smooth``: beside VQF offline, the minimum-energy smoother of ``mef-vel``'s model
  (:class:`liemef.smoothers.OfflineSmoother`): that filter's cost minimized over the whole trial, from its pass,
  to :data:`SMOOTH_TOL`. Not run by default;
- x-io's Fusion AHRS (the ``imufusion`` package), with its defaults (``fusion``) and with the settings of its
  example ``advanced_example.py`` (``fusion-example``).

Beside them are the published per-trial figures of BROAD's own Madgwick and Mahony. A recording is one trial:
there is no Monte Carlo spread. The reference itself is accurate to about 0.35 deg (the dataset README: at
rest, the accelerometer agrees with the optical attitude within a median of 0.35 deg). A lead below that is
called *within the reference's accuracy*.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...filters.baselines import VQF, Fusion, Madgwick, Mahony
from ...metrics import ATTITUDE_METRICS as METRICS
from ...metrics import attitude_error_per_second, attitude_rms, field_against_reference
from ...reports import io
from ...reports.figures import broad_error_figure as error_figure
from ...smoothers import OfflineSmoother
from ...systems import attitude_field, attitude_gyro_bias
from ...systems.attitude_bias import K0_GYRO_BIAS as K0
from ...systems.attitude_field import K0_FIELD, FieldSystem, attitude_field_state, imu_field_log
from ...systems.bounded_velocity import (
    K0_POSITION,
    K0_VELOCITY,
    PositionDynamics,
    VelocityDynamics,
    attitude_position_state,
    attitude_velocity_state,
    imu_position_log,
    imu_velocity_log,
)
from ...systems.imu_rest import REST_WINDOW, initial_estimate, rest_constants
from .. import datasets
from ._common import fmt, make_filter, parse_names, realdata_present, scoring, unscored_lines

SCHEMA = "liemef.compare.broad/1"
"""Version tag of ``broad.json``."""

REFERENCE_ACCURACY_DEG = 0.35
"""The optical truth's accuracy (the dataset README's median agreement of the accelerometer at rest)."""
SMOOTH_TOL = 1e-6
"""``mef-vel-smooth``'s tolerance (rad, rad/s, m/s^2 steps), 1000 times :func:`liemef.smooth`'s default. On trial
07 (December 2026) its attitudes were within 2.4e-7 deg of those at 1e-9, after 5 iterations instead of 8 (22 s
instead of 32 s, filter pass included): below 1e-6 the steps follow the round-off of a cost of 1e7."""


def _plain(ctx):
    return attitude_gyro_bias(dip=ctx["dip"])


def _tuned(ctx, system):
    """The trial's tuned parameters if the tuning file is for ``system``, else the system's defaults."""
    from ..tune import system_from

    params = ctx["params"] if ctx.get("tuned_system", "attitude-imu") == system else {}
    return system_from(params, {k: ctx[k] for k in ("dip", "gravity", "field")}, system)


def _imu(ctx):
    return _tuned(ctx, "attitude-imu")


def _velocity(ctx):
    return _tuned(ctx, "attitude-velocity")


def _position(ctx):
    return _tuned(ctx, "attitude-position")


def _field(ctx):
    return attitude_field(dip=ctx["dip"], gravity=ctx["gravity"], field=ctx["field"])


BROAD_FILTERS = {
    "mef": ("minimum-energy filter, second order, (0)-connection",
            lambda c: make_filter("mef", _plain(c))),
    "mef-first": ("first-order minimum-energy filter",
                  lambda c: make_filter("mef-first", _plain(c))),
    "mef-minus": ("minimum-energy filter, (-)-connection", lambda c: make_filter("mef-minus", _plain(c))),
    "mef-plus": ("minimum-energy filter, (+)-connection", lambda c: make_filter("mef-plus", _plain(c))),
    "mef-robust": ("minimum-energy filter with Huber losses on the accelerometer and the magnetometer",
                   lambda c: make_filter("mef", attitude_gyro_bias(dip=c["dip"], acc_robust="huber",
                                                                   mag_robust="huber"))),
    "mef-imu": ("minimum-energy filter, IMU noise model (attitude_imu: linear acceleration, magnetic "
                "disturbance, heading-only magnetometer)",
                lambda c: make_filter("mef", _imu(c))),
    "mef-imu-first": ("first-order minimum-energy filter, IMU noise model",
                      lambda c: make_filter("mef-first", _imu(c))),
    "mef-imu-d": ("minimum-energy filter, IMU noise model, samples at their own time (updates='discrete', gyro "
                  "sample k over the interval ending at t_k as in VQF)",
                  lambda c: make_filter("mef", _imu(c), updates="discrete")),
    "mef-imu-d-first": ("first-order minimum-energy filter, IMU noise model, samples at their own time",
                        lambda c: make_filter("mef-first", _imu(c), updates="discrete")),
    "mef-vel": ("minimum-energy filter, bounded-velocity model (attitude_velocity: linear acceleration as a "
                "velocity state, heading-only magnetometer), samples at their own time",
                lambda c: make_filter("mef", _velocity(c), updates="discrete")),
    "mef-vel-safe": ("minimum-energy filter, bounded-velocity model, samples at their own time, the safe curvature "
                     "(the library's default; mef-vel keeps Theorem 4.1's)",
                     lambda c: make_filter("mef-safe", _velocity(c), updates="discrete")),
    "mef-vel-first": ("first-order minimum-energy filter, bounded-velocity model, samples at their own time",
                      lambda c: make_filter("mef-first", _velocity(c), updates="discrete")),
    "mef-vel-smooth": ("minimum-energy smoother, bounded-velocity model: mef-vel's cost minimized over the whole "
                       "trial (liemef.smooth; acausal: estimate k has seen the whole trial)",
                       lambda c: OfflineSmoother(make_filter("mef", _velocity(c), updates="discrete"),
                                                 tol=SMOOTH_TOL)),
    "iekf-vel": ("invariant EKF, bounded-velocity model (its sample updates at t_k)",
                 lambda c: make_filter("iekf", _velocity(c))),
    "mef-pos": ("minimum-energy filter, bounded-position model (attitude_position: the bounded-velocity model with "
                "a position kept near where the IMU hovers), samples at their own time",
                lambda c: make_filter("mef", _position(c), updates="discrete")),
    "mef-pos-first": ("first-order minimum-energy filter, bounded-position model, samples at their own time",
                      lambda c: make_filter("mef-first", _position(c), updates="discrete")),
    "iekf-pos": ("invariant EKF, bounded-position model (its sample updates at t_k)",
                 lambda c: make_filter("iekf", _position(c))),
    "mef-field": ("minimum-energy filter, lasting magnetic disturbances as states (attitude_field: the bounded "
                  "velocity and a world and a body disturbance field), samples at their own time",
                  lambda c: make_filter("mef", _field(c), updates="discrete")),
    "mef-field-first": ("first-order minimum-energy filter, lasting magnetic disturbances as states",
                        lambda c: make_filter("mef-first", _field(c), updates="discrete")),
    "iekf-field": ("invariant EKF, lasting magnetic disturbances as states", lambda c: make_filter("iekf", _field(c))),
    "iekf": ("invariant EKF (= the local EKF on SO(3) x R^3)", lambda c: make_filter("iekf", _plain(c))),
    "iekf-imu": ("invariant EKF, IMU noise model", lambda c: make_filter("iekf", _imu(c))),
    "ukf-left": ("UKF-M, left retraction", lambda c: make_filter("ukf-left", _plain(c))),
    "vqf": ("VQF (Laidig and Seel 2023), online, its defaults; starts from its own first samples",
            lambda c: VQF(_imu(c), broad_indexing=True)),
    "vqf-offline": ("VQF, offline (acausal: estimate k has seen the whole trial), its defaults",
                    lambda c: VQF(_imu(c), offline=True, broad_indexing=True)),
    "vqf-broad": ("VQF, online: the same filter as vqf (its name from when it alone ran in BROAD's indexing)",
                  lambda c: VQF(_imu(c), broad_indexing=True)),
    "madgwick": ("ahrs Madgwick, ahrs's default beta = 0.041",
                 lambda c: Madgwick(_plain(c), broad_indexing=True)),
    "madgwick-broad": ("ahrs Madgwick, BROAD's beta = 0.12",
                       lambda c: Madgwick(_plain(c), gain=0.12, broad_indexing=True)),
    "mahony": ("ahrs Mahony, ahrs's default Kp = 1, Ki = 0.3", lambda c: Mahony(_plain(c), broad_indexing=True)),
    "mahony-broad": ("ahrs Mahony, BROAD's Kp = 0.74, Ki = 0.0012",
                     lambda c: Mahony(_plain(c), k_P=0.74, k_I=0.0012, broad_indexing=True)),
    "fusion": ("x-io Fusion (imufusion), its defaults (gain 0.5, no rejection) at the trial's rate; starts from the "
               "identity with its own 3 s start-up (gain ramped from 10)",
               lambda c: Fusion(_imu(c), broad_indexing=True)),
    "fusion-example": ("x-io Fusion, the settings of its advanced_example.py (gain 0.5, gyroscope range 2000 deg/s, "
                       "acceleration and magnetic rejection 10 deg, rejection timeout 5 s, its gyro offset "
                       "estimator); starts as fusion",
                       lambda c: Fusion(_imu(c), gyroscope_range=2000.0, acceleration_rejection=10.0,
                                        magnetic_rejection=10.0, rejection_timeout=5.0, bias=True,
                                        broad_indexing=True)),
}
"""The filters of the BROAD study: a description and a factory from the trial's context (its magnetic dip,
gravity and field at rest, and the IMU model's parameters)."""
OWN_TIME = frozenset({"mef-imu-d", "mef-imu-d-first", "mef-vel", "mef-vel-safe", "mef-vel-first", "iekf-vel",
                      "mef-pos", "mef-pos-first", "iekf-pos", "mef-field", "mef-field-first", "iekf-field"})
"""The filters that take gyro sample k as the rate over the interval that ends at t_k
(``broad_to_log(..., gyro="backward")``), so that state k has seen gyro sample k, with the hybrid update
(``updates="discrete"``: the accelerometer and magnetometer sample k updates the estimate at t_k, after the state
recorded at t_k: :func:`lags`)."""
TUNED_ROWS = {"attitude-imu": "-imu", "attitude-velocity": "-vel", "attitude-position": "-pos"}
"""Per system a tuning file may be for, the part of the names of the rows its parameters reach (``mef-vel``,
``iekf-vel``, ...): the rows built with that system's tuned parameters (:func:`_tuned`)."""
SENSORS = ("gyro", "acc", "mag")
"""The raw sensors whose lag :func:`lags` gives."""
DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "mef-robust", "mef-imu", "mef-imu-first", "mef-imu-d",
                   "mef-vel", "mef-vel-first", "iekf-vel", "mef-field", "mef-field-first", "iekf-field", "iekf",
                   "ukf-left", "vqf", "vqf-offline", "madgwick", "madgwick-broad", "mahony",
                   "mahony-broad", "fusion", "fusion-example")
"""The filters run by default (every one but ``mef-imu-d-first``, ``mef-vel-safe``, ``iekf-imu``, the
bounded-position rows ``mef-pos``, ``mef-pos-first`` and ``iekf-pos``, and ``vqf-broad``, the same filter as
``vqf``)."""
PUBLISHED = {"01": {"madgwick": 2.3, "mahony": 3.4}, "07": {"madgwick": 5.0, "mahony": 5.2},
             "24": {"madgwick": 1.8, "mahony": 2.1}, "10": {"madgwick": 3.6, "mahony": 2.8},
             "16": {"madgwick": 4.8, "mahony": 20.3}, "28": {"madgwick": 8.3, "mahony": 6.3},
             "33": {"madgwick": 7.1, "mahony": 11.0}}
"""Total rms (deg) of BROAD's own Madgwick (beta = 0.12) and Mahony (Kp = 0.74, Ki = 0.0012) per trial, one
parameter set for all 39 trials (BROAD ``example_code/out/*_average_rmse.json``; the dataset README here)."""
INITIAL_SAMPLES = 50
"""The initial estimate is TRIAD of the mean of the initial rest's first samples, this many (fewer if the rest is
shorter)."""



def given(flt) -> tuple[str, ...]:
    """What the filter ``flt`` (one of :data:`BROAD_FILTERS`) takes besides the log, read off the filter: the
    initial estimate (TRIAD at rest) unless it is VQF, which starts from its own first samples; the dip where its
    system has a magnetometer model it uses (not Madgwick, Mahony or VQF: their docstrings), gravity and field
    where its system has the ``norm`` sensor (not VQF, which reads the raw norms itself); K0 where it has a
    covariance."""
    if isinstance(flt, VQF):
        return ()
    out = ["initial attitude (TRIAD at rest)"]
    if isinstance(flt, Madgwick | Mahony):
        return tuple(out)
    out.append("dip")
    if "norm" in {b.name for b in flt.system.blocks()} or isinstance(flt.system, FieldSystem):
        out += ["gravity", "field"]
    if getattr(flt, "has_covariance", True):
        out.append("K0")
    return tuple(out)


def check_seconds(seconds: float | None) -> None:
    """A BROAD study's ``seconds`` (the head of each trial; None: whole trials): a duration of at least one
    rest-detection window (:data:`~liemef.systems.imu_rest.REST_WINDOW`), in which the initial rest is found; a
    ValueError naming ``seconds`` otherwise."""
    if seconds is not None and not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds: expected a duration > 0 or None, got {seconds!r}")
    if seconds is not None and seconds < REST_WINDOW:
        raise ValueError(f"seconds: expected at least one rest-detection window ({REST_WINDOW} s), got {seconds!r}")


def trial_ids(what: str, trials, present, folder) -> tuple[str, ...]:
    """The BROAD trial ids of the setting ``what``: every trial ``present`` when ``trials`` is None, else the
    ones given (a tuple, or a comma-separated string); ids are two digits ("07"), and a number (7, 24) means the
    same trial. A ValueError names ``what`` when none is given or one is not present in ``folder``."""
    if trials is None:
        return tuple(present)
    if isinstance(trials, str | int):
        trials = tuple(t.strip() for t in str(trials).split(","))
    trials = tuple(f"{int(t):02d}" if str(t).strip().isdigit() else str(t) for t in trials)
    unknown = [t for t in trials if t not in present]
    if not trials or unknown:
        raise ValueError(f"{what}: expected BROAD trials present in {folder} from {list(present)}, got "
                         f"{list(trials)}")
    return trials

@dataclass(frozen=True)
class BroadComparison:
    """The study's settings: ``trials`` (ids of the trials present, read from the files by
    :func:`liemef.studies.datasets.broad_trials`; default: every one), ``seconds`` (the head of each trial;
    default: whole trials), ``filters``, ``realdata`` (the folder;
    default :func:`liemef.studies.datasets.realdata_dir`), ``params``: a tuning file (``liemef tune``) for the
    IMU model it names (its rows, :data:`TUNED_ROWS`: ``mef-imu``, ``mef-vel``, ``mef-pos``, ..., one of them
    among ``filters``): trial i uses the parameters tuned without it when the file has that fold (leave-one-out,
    held-out errors), else its final set; default: each model's own defaults."""

    trials: tuple[str, ...] | str | None = None
    seconds: float | None = None
    filters: tuple[str, ...] | str | None = None
    realdata: str | None = None
    params: str | None = None

    def __post_init__(self):
        folder, present = realdata_present(self.realdata, datasets.broad_trials, datasets.BROAD_DIR)
        trials = trial_ids("trials", self.trials, present, folder)
        names = parse_names("filters", self.filters, BROAD_FILTERS, DEFAULT_FILTERS)
        if self.params is not None:
            from ..tune import load

            system = load(self.params)["system"]  # checked before any run
            rows = [n for n in BROAD_FILTERS if TUNED_ROWS[system] in n]
            if not set(rows) & set(names):  # the file would change nothing, and the table would say it was used
                raise ValueError(f"params: expected --filters to hold a row of the file's system {system} "
                                 f"({', '.join(rows)}), got {', '.join(names)}")
        check_seconds(self.seconds)
        object.__setattr__(self, "trials", tuple(trials))
        object.__setattr__(self, "filters", names)
        object.__setattr__(self, "realdata", str(folder))


def trial_context(trial: datasets.BroadTrial, params: dict | None = None, tuned_system: str | None = None) -> dict:
    """What every filter of a trial starts from (the factories' ``ctx``), from the IMU samples alone: the magnetic
    dip and the norms of gravity and of the field measured over the initial rest found in them
    (:func:`~liemef.systems.imu_rest.rest_constants`; its length ``rest_s``), the initial estimate ``g0``
    (TRIAD of the rest's first :data:`INITIAL_SAMPLES` samples, zero bias), and the IMU model's tuned ``params``
    (for ``tuned_system``; default none)."""
    rest = rest_constants(trial.gyr, trial.acc, trial.mag, trial.rate)
    first = min(INITIAL_SAMPLES, rest["rest_samples"])
    return {"dip": rest["dip"], "gravity": rest["gravity"], "field": rest["field"], "rest_s": rest["rest_s"],
            "rest_samples": rest["rest_samples"],
            "params": {} if params is None else params, "tuned_system": tuned_system,
            "g0": initial_estimate(trial.acc[:first], trial.mag[:first])}


def trial_logs(trial: datasets.BroadTrial) -> dict[str, io.RecordedLog]:
    """A trial's logs by the gyro's convention (:func:`liemef.studies.datasets.broad_to_log`, with the raw norms):
    ``"forward"`` (gyro sample k over the interval that starts at t_k), ``"backward"`` (the interval that ends at
    t_k), ``"velocity"`` and ``"position"`` (the bounded-motion models', backward) and ``"field"``
    (:func:`attitude_field`'s, backward)."""
    logs = {g: datasets.broad_to_log(trial, norms=True, gyro=g) for g in ("forward", "backward")}
    logs["velocity"] = io.RecordedLog(*imu_velocity_log(trial.gyr, trial.acc, trial.mag, trial.rate,
                                                        float(trial.ts[0]), gyro="backward"))
    logs["position"] = io.RecordedLog(*imu_position_log(trial.gyr, trial.acc, trial.mag, trial.rate,
                                                        float(trial.ts[0]), gyro="backward"))
    logs["field"] = io.RecordedLog(*imu_field_log(trial.gyr, trial.acc, trial.mag, trial.rate, float(trial.ts[0]),
                                                  gyro="backward"))
    return logs


def log_kind(name: str, flt) -> str:
    """Which of :func:`trial_logs` the filter ``name`` runs on: the bounded-velocity or bounded-position model's
    (by the model's dynamics), the field model's, the backward one for :data:`OWN_TIME`, else the forward one (the
    baselines index it themselves: ``broad_indexing``)."""
    dynamics = getattr(flt.system, "dynamics_fn", None)
    if isinstance(dynamics, VelocityDynamics):
        return "velocity"
    if isinstance(dynamics, PositionDynamics):
        return "position"
    if isinstance(flt.system, FieldSystem):
        return "field"
    return "backward" if name in OWN_TIME else "forward"


def lags(name: str, flt) -> dict[str, int | None]:
    """By how many samples the estimate at t_k trails the newest gyro, accelerometer and magnetometer sample that
    reaches it, for the filter ``name`` built by :func:`setup` (``flt``); None for an acausal filter (its estimate
    k has seen the samples after k). The baselines with ``broad_indexing`` make estimate k from sample k (0); in
    liemef's indexing, as the minimum-energy and Kalman filters record it, the state at t_k comes before the sample
    at t_k acts (1: held over the interval after t_k, or a discrete update at t_k that the state at t_k+1 has
    seen), but for the inputs of the backward logs (the gyro, and on the bounded-motion models the accelerometer
    too), which measure the interval that ends at t_k (0). ``tests/test_broad.py`` checks every filter's lags by
    perturbing the samples."""
    if getattr(flt, "offline", False):
        return dict.fromkeys(SENSORS)
    if hasattr(flt, "broad_indexing"):
        lag = 0 if flt.broad_indexing else 1
        return dict.fromkeys(SENSORS, lag)
    kind = log_kind(name, flt)
    inputs = ("velocity", "position", "field")  # the logs whose accelerometer is an input
    return {"gyro": 0 if kind in ("backward", *inputs) else 1, "acc": 0 if kind in inputs else 1, "mag": 1}


def lag_text(lag: dict[str, int | None]) -> str:
    """A filter's :func:`lags` as a table cell: "acausal", or the gyro, accelerometer and magnetometer lags."""
    if any(v is None for v in lag.values()):
        return "acausal"
    return " / ".join(str(lag[s]) for s in SENSORS)


def setup(name: str, ctx: dict, logs: dict[str, io.RecordedLog]):
    """The filter ``name`` of :data:`BROAD_FILTERS` for a trial, its initial state and its log (the trial's
    ``ctx`` from :func:`trial_context`, ``logs`` from :func:`trial_logs`): ``(filter, state, log)``, the log's
    ``ys`` cut to the filter's sensors. The one place that builds what a filter runs on (the study and the
    alignment test use it)."""
    flt = BROAD_FILTERS[name][1](ctx)
    kind = log_kind(name, flt)
    g0 = ctx["g0"]
    if kind == "velocity":
        state = flt.init(attitude_velocity_state(g0), K0_VELOCITY)
    elif kind == "position":
        state = flt.init(attitude_position_state(g0), K0_POSITION)
    elif kind == "field":
        state = flt.init(attitude_field_state(g0), K0_FIELD)
    else:
        state = flt.init(g0, K0) if getattr(flt, "has_covariance", True) else flt.init(g0)
    log = logs[kind]
    p = flt.system.output_dim
    return flt, state, io.RecordedLog(log.ts, log.us, log.ys if p == log.ys.shape[1] else log.ys[:, :p])


def compare_broad(study: BroadComparison | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "trials", "winners", "arrays"}``."""
    st = BroadComparison() if study is None else study
    from ..tune import UNSAID_INTEGRATOR, load, params_for

    paths = datasets.broad_trials(Path(st.realdata) / datasets.BROAD_DIR)
    tuned = None if st.params is None else load(st.params)
    per_trial, winners, arrays, lag = {}, {}, {}, {}
    for tid in st.trials:
        trial = datasets.broad(paths[tid])
        movement_s = trial.movement_start()
        if st.seconds is not None:
            trial = trial.head(st.seconds)
        params = {} if tuned is None else params_for(tuned, tid)
        ctx = trial_context(trial, params, None if tuned is None else tuned["system"])
        logs = trial_logs(trial)
        rows = {}
        for name in st.filters:
            t0 = time.perf_counter()
            flt, state, log = setup(name, ctx, logs)
            lag[name] = lags(name, flt)
            traj = flt.run(state, log.ts, log.us, log.ys)
            q = np.asarray(traj.g_hat.factors[0].wxyz)
            status = traj.status
            arrays[f"{tid}/{name}/error_1s"] = attitude_error_per_second(trial.ts, q, trial.quat_true, trial.movement)
            ok = bool(int(status.code) == 0)
            # a failed run has no error figures: its states before the failure are not the whole trial's
            errors = attitude_rms(q, trial.quat_true, trial.movement) if ok else dict.fromkeys(METRICS)
            rows[name] = {"filter": BROAD_FILTERS[name][0], "ok": ok, "given": list(given(flt)),
                          "status": status.message(log.ts) if not ok else "ok", **errors,
                          "elapsed_s": time.perf_counter() - t0}
            arrays[f"{tid}/{name}"] = np.array([np.nan if rows[name][m] is None else rows[name][m] for m in METRICS])
            if progress:
                r = rows[name]
                print(f"  trial {tid} {name:15s} total {fmt(r['total'])}, heading {fmt(r['heading'])}, inclination "
                      f"{fmt(r['inclination'])} deg; {r['elapsed_s']:.1f} s", file=sys.stderr, flush=True)
        per_trial[tid] = {"file": trial.name, "seconds": float(trial.ts[-1] - trial.ts[0]),
                          "dip_deg": math.degrees(ctx["dip"]), "gravity": ctx["gravity"],
                          "field_uT": ctx["field"], "rest_s": ctx["rest_s"],
                          "imu_params": params, "filters": rows,
                          "field_vs_truth": field_vs_truth(trial, ctx["rest_samples"]),
                          "published": PUBLISHED.get(tid) if st.seconds is None else None,
                          **scoring(trial.movement & np.isfinite(trial.quat_true).all(axis=1),
                                    trial.ts[-1] - trial.ts[0], movement_s)}
        winners[tid] = {}
        for m in METRICS:
            ranked = sorted((r[m], n) for n, r in rows.items() if r["ok"] and r[m] is not None)
            if not ranked:
                winners[tid][m] = {"winner": None}
                continue
            (best, w), rest = ranked[0], ranked[1:]
            lead = rest[0][0] - best if rest else None
            winners[tid][m] = {"winner": w, "value": best, "runner_up": rest[0][1] if rest else None,
                               "lead": lead, "beyond_reference_accuracy": None if lead is None else
                               bool(lead > REFERENCE_ACCURACY_DEG)}
    def mean(n, m):
        v = [per_trial[t]["filters"][n][m] for t in st.trials]
        return None if any(x is None for x in v) else float(np.mean(v))

    means = {n: {m: mean(n, m) for m in METRICS} for n in st.filters}
    ratio = {}
    if "vqf" in st.filters:
        for n in st.filters:
            v = [(per_trial[t]["filters"][n]["total"], per_trial[t]["filters"]["vqf"]["total"]) for t in st.trials]
            ratio[n] = None if any(a is None or b is None for a, b in v) else float(max(a / b for a, b in v))
    rests = ", ".join(f"{t} {per_trial[t]['rest_s']:.1f} s" for t in st.trials)
    return {"study": {**dataclasses.asdict(st), "weights": "attitude_gyro_bias() defaults for every trial",
                      "measured": "dip, gravity and field measured over the initial rest detected from the IMU "
                                  f"(initial_rest: {rests})",
                      "given": {n: per_trial[st.trials[0]]["filters"][n]["given"] for n in st.filters},
                      "K0": "diag(0.05^2 I3, 0.01^2 I3)",
                      "initial": f"TRIAD of the first {INITIAL_SAMPLES} samples of the initial rest, zero bias",
                      "imu_params": "attitude_imu() defaults" if tuned is None else
                      f"tuned ({st.params}): trial i uses the fold tuned without it where the file has one"
                      + ("" if tuned.get("integrator", UNSAID_INTEGRATOR) == "rkmk4" else
                         f"; the file was tuned with integrator={tuned['integrator']!r}, and this study's filters "
                         "run RKMK4")},
            "lags": lag, "trials": per_trial, "means": means, "ratio_to_vqf": ratio, "winners": winners,
            "arrays": arrays}


def field_vs_truth(trial: datasets.BroadTrial, rest_samples: int) -> dict[str, float | None]:
    """The trial's magnetometer read through the optical attitude (:func:`liemef.metrics.field_against_reference`):
    its azimuth and dip over BROAD's movement mask against the initial rest found from the IMU (its first
    ``rest_samples`` samples), in degrees. Scoring's diagnosis only: no filter sees it."""
    rest = np.arange(trial.ts.size) < rest_samples
    return field_against_reference(trial.mag, trial.quat_true, rest, trial.movement)


def markdown(result: dict) -> str:
    """Per trial: every filter's total, heading and inclination rms, the published figures, and the winners."""
    st = result["study"]
    lines = ["# Attitude filters on BROAD (Laidig et al. 2021, CC BY 4.0)", "",
             f"Weights: {st['weights']}; K0 = {st['K0']}; initial estimate: {st['initial']}; {st['measured']}. "
             "Metrics: BROAD's "
             "total, heading and inclination rms [deg] over its movement mask where the optical truth is present. "
             "One recording per trial: no Monte Carlo spread; the optical truth is accurate to about "
             f"{REFERENCE_ACCURACY_DEG} deg. Lag: by how many samples the estimate at t_k trails the newest gyro / "
             "accelerometer / magnetometer sample that reaches it (0: sample k; acausal: it has seen the samples "
             "after k).", ""]
    lines += unscored_lines(result["trials"])
    names = st["filters"]
    lag = result.get("lags", {})
    if "given" in st:
        lines += ["What each filter is given besides the log (read off the filter): " + "; ".join(
            f"{n}: {', '.join(g) if g else 'none (its defaults on the raw readings)'}" for n, g in st["given"].items())
            + ".", ""]
    lines += ["| filter | lag [samples] | " + " | ".join(f"{t} total / heading / incl." for t in st["trials"])
              + " | mean total |", "|---|---|" + "---:|" * (len(st["trials"]) + 1)]
    for n in names:
        cells = []
        for t in st["trials"]:
            r = result["trials"][t]["filters"][n]
            cells.append(f"{fmt(r['total'])} / {fmt(r['heading'])} / {fmt(r['inclination'])}"
                         + ("" if r["ok"] else f" ({r['status']})"))
        lines.append(f"| {n} | {lag_text(lag[n]) if n in lag else '-'} | " + " | ".join(cells)
                     + f" | {fmt(result['means'][n]['total'])} |")
    lines += ["", "## Total rms per trial [deg], and against VQF", "",
              "| filter | " + " | ".join(st["trials"]) + " | mean | worst ratio to vqf |",
              "|---|" + "---:|" * (len(st["trials"]) + 2)]
    for n in names:
        tot = [result["trials"][t]["filters"][n]["total"] for t in st["trials"]]
        ratio = result.get("ratio_to_vqf", {}).get(n)
        lines.append(f"| {n} | " + " | ".join(fmt(v) for v in tot) + f" | {fmt(result['means'][n]['total'])} | "
                     + ("-" if ratio is None else f"{ratio:.2f}") + " |")
    pub = [result["trials"][t]["published"] for t in st["trials"]]
    if all(p is not None for p in pub):  # BROAD publishes the total rms only: rows of this table
        for who in ("madgwick", "mahony"):
            lines.append(f"| BROAD's own {who} (published) | " + " | ".join(f"{p[who]:g}" for p in pub)
                         + f" | {fmt(float(np.mean([p[who] for p in pub])))} | - |")
    lines += ["", "## Winners", "", "| trial | metric | winner | rms [deg] | runner-up | lead [deg] | beyond the "
              "reference's accuracy? |", "|---|---|---|---:|---|---:|---|"]
    for t, per in result["winners"].items():
        for m, w in per.items():
            if w["winner"] is None:
                continue
            beyond = "-" if w["beyond_reference_accuracy"] is None else ("yes" if w["beyond_reference_accuracy"]
                                                                         else "no")
            lines.append(f"| {t} | {m} | {w['winner']} | {w['value']:.3f} | {w['runner_up'] or '-'} | "
                         f"{fmt(w['lead'], 3)} | {beyond} |")
    fields = {t: per.get("field_vs_truth") for t, per in result["trials"].items()}
    if all(f is not None for f in fields.values()):
        lines += ["", "## The magnetometer against the optical truth", "",
                  "Each magnetometer sample turned into the world by the optical attitude, over the movement mask, "
                  "against its direction over the initial rest: the median offset of its azimuth and of its dip, and "
                  "the 90th percentile of the azimuth offset's size [deg]. Zero where the magnetometer agrees with "
                  "the truth; an offset that lasts through the motion is a heading the magnetometer tells every "
                  "filter that trusts it. Scoring's diagnosis only: no filter sees it.", "",
                  "| trial | azimuth (median) | azimuth (90th percentile of the size) | dip (median) |",
                  "|---|---:|---:|---:|"]
        for t, f in fields.items():
            lines.append(f"| {t} | {fmt(f['azimuth'])} | {fmt(f['azimuth_p90'])} | {fmt(f['dip'])} |")
    return "\n".join(lines + [""])


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``broad.json``, ``broad.md``, ``broad.csv``, ``arrays.npz`` and per trial ``fig_errors_<id>.png``
    (each filter's attitude error over time) to ``out``."""
    from ...reports import plots

    out = io.ensure_dir(out)
    rows = [[t, n, r["ok"], r["total"], r["heading"], r["inclination"]]
            for t, per in result["trials"].items() for n, r in per["filters"].items()]
    written = [io.write_npz(out / "arrays.npz", result["arrays"]),
               io.write_json(out / "broad.json",
                             {"schema": SCHEMA, **{k: v for k, v in result.items() if k != "arrays"}}),
               io.write_text(out / "broad.md", markdown(result)),
               io.write_rows(out / "broad.csv", ["trial", "filter", "ok", "total_deg", "heading_deg",
                                                 "inclination_deg"], rows)]
    a = io.read_arrays(out / "arrays.npz")
    for tid, per in result["trials"].items():
        fig = error_figure(a, tid, list(result["study"]["filters"]), f"BROAD trial {tid} ({per['file']})")
        written.append(plots.save_figure(fig, out / f"fig_errors_{tid}.png"))
    return written
