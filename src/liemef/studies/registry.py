"""The one registry of liemef's studies and ready systems, readable without JAX.

A study is a name, a frozen config, a trial or run function, and its tables and figures. Here each study is
declared once, by what names and describes it (:class:`Study`: name, kind, title, paper, and for a comparison the
settings it takes). This module imports none of the studies (it sits below them all);
:func:`liemef.studies.load` returns the full object, which imports the module that holds the rest:

* an ``"experiment"``: a paper's experiment, :class:`liemef.studies.experiments.Experiment` (default config,
  ``run``, ``trial_fn``, figures, tables), for ``liemef reproduce``, ``liemef montecarlo`` and campaigns;
* a ``"comparison"``: :class:`liemef.studies.compare.Study` (settings class, runner, Markdown and files), for
  ``liemef compare``.

The experiments and comparisons take their name, title and paper from here (``experiments.register`` refuses
one that disagrees), and the command line builds its choices and help texts from :data:`STUDIES` and
:data:`SYSTEMS`, so that ``liemef --help`` answers before JAX is imported. A new study is one :func:`declare`
here plus its module; a new ready system one entry of :data:`SYSTEMS` plus its spec in
:mod:`liemef.studies.experiments` (``tests/test_cli_startup.py`` checks both sides agree).
"""

from __future__ import annotations

from dataclasses import dataclass

KINDS = ("experiment", "comparison")
"""What a study is: a paper's ``experiment`` (reproduced, Monte Carlo) or a ``comparison`` of filters."""
DEFAULT_BATCH_SIZE = 8
"""Monte Carlo trials per compiled ``vmap`` batch unless told otherwise (the results do not depend on it). On a
2-core CPU, TSE(2) at 1 ms ran 8, 13, 21, 14 and 8 trials/s with batches of 1, 4, 8, 16 and 32 (larger batches
also compile longer)."""
SYSTEM_FILE_TIMEOUT = 60.0
"""Seconds a user's system file (``--system-file``) may take to load before ``liemef run``, ``export-c`` and
``schema`` stop it (``--timeout``; 0: no limit): a file that never returns is stopped, not waited for.
Loading builds the system and traces its functions once (a second or two); a file that computes more asks for
more."""
DURATION_RULE = ("a statistics window that would start at or after T moves in proportion: each of its times t "
                 "becomes t * T / T0, T0 the study's own final time (the 10-50 s window of a 50 s study is 1-5 s "
                 "with T = 5 s); a window that starts before T is kept, cut at T")
"""How ``liemef montecarlo``'s statistics windows follow a shorter final time T (``--duration``; its help):
:func:`liemef.studies.settings.experiment_config`."""


@dataclass(frozen=True)
class Study:
    """A registered study: its name, kind (one of :data:`KINDS`), title, paper (or source), for a comparison
    the keys of its settings (``liemef compare --set``) and its help paragraph (the full object:
    :func:`liemef.studies.load`)."""

    name: str
    kind: str
    title: str
    paper: str = ""
    settings: tuple[str, ...] = ()
    help: str = ""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {list(KINDS)}, got {self.kind!r}")
        if not self.name or not isinstance(self.name, str):
            raise ValueError(f"name: expected a non-empty string, got {self.name!r}")


STUDIES: dict[str, dict[str, Study]] = {kind: {} for kind in KINDS}
"""Every study by kind, then by name, in the order of declaration."""


def declare(study: Study) -> Study:
    """Add ``study`` to :data:`STUDIES`; a ValueError if its name is taken within its kind."""
    if study.name in STUDIES[study.kind]:
        raise ValueError(f"{study.kind} {study.name!r} is already declared")
    STUDIES[study.kind][study.name] = study
    return study


def names(kind: str) -> tuple[str, ...]:
    """The names of the studies of ``kind``, in the order of declaration."""
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {list(KINDS)}, got {kind!r}")
    return tuple(STUDIES[kind])


def get(kind: str, name: str) -> Study:
    """The study ``name`` of ``kind``; a ValueError listing the valid names otherwise."""
    if name not in STUDIES.get(kind, {}):
        raise ValueError(f"{kind}: expected one of {sorted(STUDIES.get(kind, {}))}, got {name!r}")
    return STUDIES[kind][name]


def card(name: str) -> dict[str, str]:
    """The declared ``name``, ``title`` and ``paper`` of the experiment ``name``, as keywords of
    :class:`~liemef.studies.experiments.Experiment`."""
    st = get("experiment", name)
    return {"name": st.name, "title": st.title, "paper": st.paper}


for _name, _title, _paper in (
    ("attitude", "Rigid-body attitude on TSO(3) with two direction sensors, (0)- and (-)-connection filters",
     "Saccon, Trumpf, Mahony, Aguiar 2016, Sec. V-B, Fig. 3"),
    ("chaplygin", "Chaplygin sleigh on SE(2) x R^2, GPS (+ INS), (0)- and (-)-connections",
     "Rigo, Sansonetto, Muradore 2023, Sec. 6, Tables 1-2, Figs. 3-6"),
    ("localization", "Planar localization on SE(2): odometry at 100 Hz, GPS at 1 Hz, 45 deg initial heading error",
     "ukfm 2D localization benchmark (Brossard, Barrau, Bonnabel); Barrau & Bonnabel 2017, Sec. IV"),
    ("tse2", "Planar rigid body on TSE(2) with two GPS antennas and an IMU",
     "Rigo, Segala, Sansonetto, Muradore 2022, Sec. VI, Figs. 3-4"),
    ("tse2-velocity", "Planar rigid body on TSE(2) with the velocity sensor only (pose dead-reckoned)",
     "Segala, Sansonetto, Muradore, poster 'Tracking and filtering on SE(2)'; setup of Rigo et al. 2022"),
    ("unit-circle", "Unit circle with a biased gyro on SO(2) x R: angle and bias tracking through bias jumps",
     "Zamani, Hua, Trumpf, Mahony, 'Minimum-Energy Filtering on the Unit Circle Using Velocity Measurements "
     "with Bias and Vectorial State Measurements', Sec. IV, Figs. 2-3"),
):
    declare(Study(_name, "experiment", _title, _paper))

for _name, _title, _settings, _help in (
    ("localization", "ukfm's 2D localization benchmark: every filter on the same trials",
     ("duration", "steady", "optimum_runs", "rng", "batch_size"),
     "ukfm's 2D localization benchmark (odometry 100 Hz, GPS 1 Hz, 45 deg initial heading error); writes "
     "comparison.md (per filter the rms, pooled rms with its bootstrap interval, NEES, the published figures, and "
     "per metric the winner with its paired lead), comparison.csv, comparison.json, arrays.npz and fig_errors.png "
     "(and fig_optimum.png with --set optimum_runs=M)."),
    ("heading-basin", "convergence basin in the initial heading error (0-180 deg) on the same scenario",
     ("duration", "angles_deg", "prior_std_deg", "tolerance_deg", "batch_size"),
     "the fraction of trials that converge and the time to converge against the initial heading error; writes "
     "basin.md, basin.csv, basin.json, arrays.npz and fig_basin.png."),
    ("attitude-basin", "convergence basin in the initial attitude error (0-180 deg) on TSO(3): rigid body and "
     "attitude + gyro bias",
     ("duration", "angles_deg", "tolerance_deg", "systems", "rigid_body_dt", "imu_rate", "prior_std_deg",
      "batch_size", "optimum_runs", "optimum_every"),
     "the same against the initial attitude error (0-180 deg) on TSO(3), Saccon et al.'s rigid body and attitude "
     "+ gyro bias from a synthetic IMU (filters: mef, mef-first, mef-minus, mef-plus, iekf, ukf-left; madgwick "
     "and mahony on request, gyro bias only); writes attitude_basin.md, attitude_basin.csv, attitude_basin.json, "
     "arrays.npz and fig_basin_<system>.png."),
    ("inertial-navigation", "ukfm's inertial-navigation benchmark on SE_2(3): every filter on the same trials",
     ("duration", "steady", "rng", "batch_size", "initial"),
     "ukfm's inertial-navigation benchmark on SE_2(3) (IMU 100 Hz, three landmarks at 1 Hz, 15 deg / 1 m initial "
     "error); writes inertial.md (per filter the attitude and position rms, NEES, ukfm's own figures beside ours, "
     "the winners with their paired lead), inertial.csv, inertial.json, arrays.npz and fig_errors.png. With --set "
     "rng=numpy the trials are ukfm's own runs (seeds 0-19: per-seed differences); with --set initial=ukfm each "
     "filter starts from the initial covariance ukfm hands it."),
    ("inertial-basin", "convergence basin in the initial attitude error (0-180 deg) on ukfm's inertial navigation",
     ("duration", "angles_deg", "prior_std_deg", "tolerance_deg", "batch_size"),
     "the convergence basin in the initial attitude error (0-179 deg about random axes) on the inertial-navigation "
     "scenario; writes inertial_basin.md, inertial_basin.csv, inertial_basin.json, arrays.npz and "
     "fig_basin_inertial_navigation.png."),
    ("broad", "the BROAD attitude recordings: the MEF and its IMU models, the EKF, the UKF-M, VQF, Madgwick, "
     "Mahony and Fusion",
     ("trials", "seconds", "realdata", "params"),
     "the BROAD attitude recordings present in the real-data folder (gyro, accelerometer, magnetometer with "
     "optical truth), with the MEF (attitude + gyro bias, the IMU noise model mef-imu, the bounded-velocity "
     "model mef-vel and, on request, the bounded-position model mef-pos, samples at their own time), the "
     "invariant EKF, the UKF-M, VQF (online and offline), "
     "ahrs's Madgwick and Mahony (default and published gains) and x-io's Fusion (defaults and its example's "
     "settings), every baseline's estimate at t_k made from sample k as BROAD's, and every filter's lag per "
     "sensor stated; one weight set for all trials (--set params=tune.json: a `liemef tune` file, each trial "
     "run with the fold tuned without it); writes broad.md, broad.csv, broad.json and arrays.npz."),
    ("broad-ins", "inertial navigation on SE_2(3) with BROAD's real IMU and optical position fixes at 10 Hz",
     ("trials", "seconds", "attitude_filters", "variants", "fix_rate", "noise_std", "realdata", "ukf_trials",
      "ukf_variants", "gyro_scale_std", "gyro_scale_grid", "fix_std_grid"),
     "inertial navigation on SE_2(3) with gyro and accelerometer biases, driven by the real IMU of the BROAD "
     "recordings, with the optical positions at 10 Hz as position fixes, as recorded and with added white noise "
     "(noise_std m, --seed): the MEF (both orders), the right-invariant EKF, the EKF and the UKF-M (left, right), "
     "with stated prior weights; attitude, velocity and position rms against the optical truth, NEES, APE and RPE "
     "by evo, and the attitude beside compare broad's mef-vel and vqf-broad on the same samples; writes "
     "broad_ins.md, broad_ins.csv, broad_ins.json and arrays.npz."),
    ("second-order", "the second-order safety suite: the minimum-energy filter's orders and updates beside the "
     "first-order filter, the invariant EKF and the UKF-M on 12 systems",
     ("duration", "systems"),
     "the second-order safety suite: a quadrotor on SE_2(3) with a range sensor or an altimeter and a magnetometer, "
     "inertial navigation with barometer + magnetometer or GNSS, SE(2) with bearings, ranges or a near range + "
     "bearing, attitude + gyro bias from a small or a 90-179 deg initial error, and the papers' TSE(2), TSO(3) and "
     "Chaplygin sleigh; per system and filter (mef-hold, mef-discrete, their curvature='safe' variants, mef-first, "
     "iekf, ukf-m) the status and failures, the attitude and position rms, the NEES with its chi-square band and "
     "the innovation monitor's verdicts; writes metrics.json, second_order.md and second_order.csv."),
    ("wifibot", "UKF-M's Wifibot runs: real wheel odometry, optical truth, synthetic GPS over seeds",
     ("recordings", "gps_rate", "gps_std", "realdata"),
     "UKF-M's Wifibot runs (real wheel odometry, optical truth) with synthetic 1 Hz GPS of 0.1 m over --runs "
     "seeds; writes wifibot.md, wifibot.csv, wifibot.json and arrays.npz."),
):
    declare(Study(_name, "comparison", _title, settings=_settings, help=_help))

@dataclass(frozen=True)
class ReadySystem:
    """A ready system of the command line, declared without JAX (its factory is
    :data:`liemef.studies.experiments.SYSTEMS`'s, under the same name).

    ``description``: what ``--help`` and ``liemef schema`` say of it. ``run_options``: the filter options
    ``liemef run`` runs it with unless the user gives them. ``datasets``: the recordings ``liemef dataset KIND``
    converts into its log, best model first among each recording's (:func:`dataset_systems`). ``tune``: what
    ``liemef tune --system`` says of it (None: not tunable); ``tunable``: the parameters a tuning file for it may
    set, in the file's order; ``tune_defaults``: those ``liemef tune`` fits unless told which."""

    description: str
    run_options: tuple[tuple[str, str], ...] = ()
    datasets: tuple[tuple[str, int], ...] = ()
    tune: str | None = None
    tunable: tuple[str, ...] = ()
    tune_defaults: tuple[str, ...] = ()


SYSTEMS: dict[str, ReadySystem] = {
    "tse2": ReadySystem(
        "planar rigid body on TSE(2), GPS (x1, y1, x2, y2) + IMU (omega, vx, vy); input (u_omega, u_v)"),
    "tse2-velocity": ReadySystem(
        "planar rigid body on TSE(2), IMU only (omega, vx, vy); input (u_omega, u_v)"),
    "attitude": ReadySystem(
        "rigid-body attitude on TSO(3) (Saccon et al. 2016), two body-frame directions of e3 and e2; input "
        "the torque (3); the weights of the paper's experiment"),
    "chaplygin": ReadySystem(
        "Chaplygin sleigh on SE(2) x R^2 (Rigo et al. 2023), GPS (x1, y1, x2, y2) + INS (omega, v); input "
        "(u_omega, u_v); the weights of the paper's experiment"),
    "chaplygin-gps": ReadySystem(
        "Chaplygin sleigh on SE(2) x R^2 (Rigo et al. 2023), GPS only (x1, y1, x2, y2); input "
        "(u_omega, u_v)"),
    "unit-circle": ReadySystem(
        "unit circle with a biased gyro on SO(2) x R (Zamani et al.), vector measurement (cos theta, "
        "-sin theta) with D = 0.4 I; input the gyro reading (1)"),
    "attitude-bias": ReadySystem(
        "attitude and gyro bias on TSO(3) from an IMU at 285.714 Hz (BROAD's rate): input the gyro (3, "
        "rad/s), normalized accelerometer and magnetometer directions (acc_x..z, mag_x..z); the default "
        "MEMS noise levels and a dip of 68 deg (liemef.systems.attitude_bias)",
        datasets=(("broad", 2),)),
    "attitude-imu": ReadySystem(
        "attitude and gyro bias on TSO(3) with the IMU noise model (linear acceleration, magnetic "
        "disturbance, heading-only magnetometer): input the gyro (3, rad/s), the accelerometer and "
        "magnetometer directions and their raw norms (norm_acc m/s^2, norm_mag uT); defaults of "
        "liemef.systems.attitude_imu",
        datasets=(("broad", 1),), tune="direction sensors with noise from their norms",
        tunable=("acc_std", "mag_std", "acc_adapt", "acc_norm_tol", "mag_adapt", "dip_std", "bias_walk", "gyro_std"),
        tune_defaults=("acc_std", "mag_std", "acc_adapt", "acc_norm_tol", "mag_adapt", "dip_std", "bias_walk")),
    "attitude-velocity": ReadySystem(
        "attitude, gyro bias and velocity on SO(3) x R^3 x R^3, the bounded-velocity model (linear "
        "acceleration as a velocity kept near zero, heading-only magnetometer), compare broad's "
        "best: input the gyro (3, rad/s, sample k over the interval ending at t_k) and the "
        "accelerometer (3, m/s^2), the accelerometer and magnetometer directions, their raw norms "
        "and a zero velocity (pseudo measurement); defaults of liemef.systems.attitude_velocity, run "
        "with samples at their own time",
        # as compare broad's mef-vel: samples at their own time, Theorem 4.1's curvature, the left error
        run_options=(("updates", "discrete"), ("curvature", "exact"), ("error", "left")),
        datasets=(("broad", 0),), tune="linear acceleration as a bounded velocity; always with --updates discrete",
        tunable=("mag_std", "mag_adapt", "dip_std", "bias_walk", "gyro_std", "acc_density", "velocity_std",
                 "gyro_scale_std"),
        tune_defaults=("mag_std", "mag_adapt", "bias_walk", "gyro_std", "velocity_std")),
    "attitude-position": ReadySystem(
        "attitude, gyro bias, velocity and position on SO(3) x R^3 x R^3 x R^3, the bounded-position model (the "
        "bounded-velocity model with the position, the accelerometer's double integral, kept near where the IMU "
        "hovers): the log of attitude-velocity and a zero position (pseudo measurement); defaults of "
        "liemef.systems.attitude_position, run with samples at their own time",
        run_options=(("updates", "discrete"), ("curvature", "exact"), ("error", "left")),
        datasets=(("broad", 4),), tune="linear acceleration as a bounded position; always with --updates discrete",
        tunable=("mag_std", "mag_adapt", "dip_std", "bias_walk", "gyro_std", "acc_density", "velocity_std",
                 "position_std", "position_walk", "gyro_scale_std"),
        tune_defaults=("gyro_std", "acc_density", "position_std", "mag_std")),
    "attitude-field": ReadySystem(
        "attitude, gyro bias, velocity and two lasting magnetic disturbances (a world field near the path and a "
        "body field carried by the IMU, uT) on SO(3) x R^3 x R^3 x R^3 x R^3, the bounded-velocity model with the "
        "magnetometer's field as it is measured: input the gyro (3, rad/s, sample k over the interval ending at "
        "t_k) and the accelerometer (3, m/s^2), the accelerometer direction, the magnetometer (mag_x..z, uT) and "
        "a zero velocity (pseudo measurement); defaults of liemef.systems.attitude_field, run with samples at "
        "their own time",
        run_options=(("updates", "discrete"), ("curvature", "exact"), ("error", "left")),
        datasets=(("broad", 3),)),
    "pose3d": ReadySystem(
        "rigid body on SE(3): input the body twist (omega_x..z rad/s, v_x..z m/s), position fixes "
        "(position_x..z, m) with NaN between fixes; the default noise levels (liemef.systems.pose3d)"),
    "inertial-navigation": ReadySystem(
        "inertial navigation on SE_2(3): input the gyro (rad/s) and the accelerometer's specific "
        "force (m/s^2) at 100 Hz, GNSS position fixes (gnss_x..z, m) with NaN between fixes; the "
        "default noise levels (liemef.systems.inertial_navigation)"),
    "localization": ReadySystem(
        "planar localization on SE(2): input the odometry (v_x, v_y, omega), GPS fixes (gps_x, gps_y) "
        "with NaN between fixes; the default noise levels (liemef.systems.localization)",
        datasets=(("wifibot", 0),)),
    "ukfm-attitude": ReadySystem(
        "attitude on SO(3) of ukfm's attitude benchmark: input the gyro (rad/s) at 100 Hz, the gravity "
        "vector (acc_x..z, m/s^2, pointing down) and the magnetic field (mag_x..z) in the body frame; "
        "ukfm's noise levels (liemef.systems.ukfm_attitude)"),
}
"""The ready systems of ``liemef run --system NAME`` (and ``export-c``, ``schema``, ``dataset``, ``tune``): the one
table of their names and what the command line says and does with each; each is built by
:data:`liemef.studies.experiments.SYSTEMS` with the weights of its paper's experiment."""


def dataset_systems(kind: str) -> tuple[str, ...]:
    """The ready systems whose log ``liemef dataset KIND --system NAME`` writes, the default (the best model of
    ``liemef compare``'s table for those recordings) first."""
    ranked = sorted((rank, name) for name, s in SYSTEMS.items() for k, rank in s.datasets if k == kind)
    return tuple(name for _, name in ranked)


def tune_systems() -> tuple[str, ...]:
    """The ready systems ``liemef tune --system`` fits, in :data:`SYSTEMS`' order."""
    return tuple(name for name, s in SYSTEMS.items() if s.tune is not None)



def system_schema(name: str) -> dict:
    """The log schema of the ready system ``name`` (:data:`SYSTEMS`), without JAX: its description, ``inputs``,
    ``outputs``, sensor ``blocks`` ``[name, start, stop]``, ``coords_dim``, ``tangent_dim`` and the ``text`` that
    ``liemef schema`` prints (:func:`liemef.studies.logs.system_schema`, generated into
    :mod:`liemef.studies._schemas`). A ValueError for an unknown name."""
    from ._schemas import SCHEMAS

    if name not in SCHEMAS:
        raise ValueError(f"system: expected one of {sorted(SCHEMAS)}, got {name!r}")
    return SCHEMAS[name]


FILTERS: dict[str, str] = {
    "mef": "minimum-energy filter, second order, (0)-connection, Theorem 4.1's curvature (curvature='exact')",
    "mef-safe": "minimum-energy filter, second order, (0)-connection, the safe curvature (the default's), left error",
    "mef-minus": "minimum-energy filter, second order, (-)-connection",
    "mef-plus": "minimum-energy filter, second order, (+)-connection",
    "mef-first": "first-order minimum-energy filter (continuous-time left-invariant EKF)",
    "iekf": "invariant EKF (left-invariant error), discrete",
    "iekf-right": "invariant EKF with the right-invariant error (ukfm's iekf of inertial navigation), discrete",
    "ekf": "EKF in local coordinates (rotation multiplicative, position additive), discrete",
    "ukf-left": "UKF-M with the left retraction (ukfm's ukf_left), discrete",
    "ukf-right": "UKF-M with the right retraction (ukfm's ukf_right), discrete",
    "ukf-local": "UKF-M in local coordinates (rotation multiplicative, position additive; ukfm's ukf_so3xr6), "
                 "discrete",
}
"""The filters of the comparisons (``liemef compare --filters``) with their descriptions; each is built by
:data:`liemef.studies.compare._common.FILTERS`."""

DATASETS = ("broad", "wifibot")
"""The real recordings ``liemef dataset KIND`` converts into logs (:mod:`liemef.studies.datasets`)."""
TUNE_DATA = ("broad",)
"""The recordings ``liemef tune DATA`` fits noise levels to (:func:`liemef.studies.tune.broad_recordings`)."""
TUNE_OBJECTIVES: dict[str, str] = {
    "truth": "BROAD's total attitude rms",
    "nll": "the innovations' negative log-likelihood (no truth)",
}
"""The objectives of ``liemef tune --objective`` with their descriptions (:data:`liemef.studies.tune.OBJECTIVES`)."""
