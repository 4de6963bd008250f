r"""``liemef compare second-order``: is the second-order minimum-energy filter safe as a default? Every filter on
the same Monte Carlo trials of a suite of systems, written as a user writes them.

The second-order terms of Theorem 4.1 (the residual-weighted output Hessian in W and E, and the Newton step of a
discrete update) are exact derivatives of a cost that is not convex: where the residual is large or the output
strongly curved, K can lose positive definiteness, or shrink along directions that the data do not observe and
then say "ok" with an error far outside it (docs/second-order.md). This study puts each variant of the filter
beside the first-order filter, the invariant EKF and the UKF-M on the systems where that happens and on those
where it should not (:data:`CASES`):

* a quadrotor on $SE_2(3)$ (IMU 100 Hz) with a downward range sensor (20 Hz) and a magnetometer (50 Hz), its
  horizontal position unobservable by design; the same with an altimeter instead of the range sensor; and both
  written on $SO(3) \times \mathbb R^3 \times \mathbb R^3$ (world-frame velocity and position,
  :data:`QUAD_WORLD`), the same flight, sensors and noise: which group the filters' errors live in, apart from the
  filters (on $SE_2(3)$ the exponential chart puts the attitude error times the unobservable horizontal position
  error into the observed vertical, docs/second-order.md);
* :func:`~liemef.systems.inertial_navigation` with a barometer and a magnetometer, and with GNSS;
* planar localization on SE(2) from odometry with bearings (``angles=True``), ranges, or range and bearing to
  landmarks (the last one close, with a large initial error: a strongly curved output);
* attitude and gyro bias on TSO(3) at 100 Hz with direction sensors, from a small and from a large (90-179 deg)
  initial attitude error;
* the papers' systems: the planar rigid body on TSE(2), Saccon et al.'s attitude on TSO(3), the Chaplygin sleigh
  (their experiments' systems, inputs and initial estimates, with the noise-consistent weights).

The filters are one table of factories (:data:`FILTERS`); a new option of the filter is one line there. Each
trial i of a system uses the key ``split(key(seed), runs)[i]`` for the simulation and ``default_rng([seed, i])``
for the initial estimate (a draw of N(g0, K0), unless the system fixes it), the same for every filter. Per system
and filter: the attitude (deg) and position (m) rms over the second half of each trial, their mean over the trials
that ran through; the NEES (left error, K its covariance) averaged over that window and those trials, with its
degrees of freedom and the 95 % chi-square band of an average over the trials; the trials that failed (status not
ok) with the first cause and time; and what the innovation monitor says of each trial, without the truth. Failed
trials are left out of the errors and the NEES.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from ...filters import CAUSES, MinimumEnergyFilter
from ...filters.baselines import ExtendedKalmanFilter, ukf_m
from ...groups import R3, SE2, SE23, SO3, TSO3, Product
from ...metrics import chi2_bounds, innovation_monitor, left_error, nees
from ...reports import io
from ...simulation import simulate
from ...systems import (
    Noise,
    Sensor,
    SensorSystem,
    attitude_gyro_bias,
    inertial_navigation,
    invariant_sides,
    natural_error,
)
from ...systems import attitude_bias as ab
from ._common import check_counts, fmt, nees_flag, parse_names

SCHEMA = "liemef.compare.second-order/3"
MONITOR_STATUSES = ("inconsistent", "nonlinear", "consistent", "not applicable")
"""The innovation monitor's statuses (:func:`liemef.metrics.innovation_monitor`), in the order the table counts
them."""

# --- the filters ----------------------------------------------------------------------------------------------
SECOND_ORDER = {"mef-hold": "hold", "mef-discrete": "discrete", "mef-hold-safe": "hold",
                "mef-discrete-safe": "discrete"}
"""The second-order rows and their updates; the first-order row takes the updates of the best of them
(:func:`better_updates`)."""

FILTERS: dict[str, tuple[str, Callable]] = {
    "mef-hold": ("second order, Theorem 4.1's curvature (curvature='exact'), each sample held over the interval "
                 "after it (updates='hold')",
                 lambda system, case, updates: MinimumEnergyFilter(system, updates="hold", curvature="exact")),
    "mef-discrete": ("second order, Theorem 4.1's curvature, each sample at its own time (updates='discrete': "
                     "Newton iterations with a line search on the sample's cost)",
                     lambda system, case, updates: MinimumEnergyFilter(system, updates="discrete",
                                                                        curvature="exact")),
    "mef-hold-safe": ("second order, held samples, the output's curvature kept only where it is safe "
                      "(curvature='safe'): the constructor's defaults",
                      lambda system, case, updates: MinimumEnergyFilter(system, curvature="safe")),
    "mef-discrete-safe": ("second order, samples at their own time, curvature='safe'",
                          lambda system, case, updates: MinimumEnergyFilter(system, updates="discrete",
                                                                            curvature="safe")),
    "mef-first": ("first order (order='first'), with the updates of the best second-order row",
                  lambda system, case, updates: MinimumEnergyFilter(system, order="first", updates=updates)),
    "mef-first-hold": ("first order with held samples: the default's sibling (the same updates)",
                       lambda system, case, updates: MinimumEnergyFilter(system, order="first", updates="hold")),
    "mef-first-iterated": ("first order, samples at their own time, Gauss-Newton iterated to the tolerance "
                           "(iterations=10, as the second order's default)",
                           lambda system, case, updates: MinimumEnergyFilter(system, order="first", updates="discrete",
                                                                             iterations=10)),
    "mef-hold-left": ("the defaults in the left error (error='left'): the side Theorem 4.1 is written in, "
                      "whatever the sensors",
                      lambda system, case, updates: MinimumEnergyFilter(system, error="left")),
    "mef-hold-right": ("the defaults in the right error (error='right': Theorem 4.1 on the system's inverted "
                       "state, liemef.systems.right_error), the invariant EKF's 'right' side. Sensor systems only",
                       lambda system, case, updates: (MinimumEnergyFilter(system, error="right")
                                                      if isinstance(system, SensorSystem) else None)),
    "iekf": ("invariant EKF, the error side that fits the system (column 'side')",
             lambda system, case, updates: ExtendedKalmanFilter(system, case.side)),
    "ukf-m": ("UKF-M, the retraction of the same side",
              lambda system, case, updates: ukf_m(system, case.side)),
}
"""The study's filters: name -> (description, factory(system, case, updates)); ``updates`` is the best
second-order row's (:func:`better_updates`). A factory returns None where its filter does not apply to the
system (a row "not applicable")."""


# --- the systems ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One system of the suite and how its trials are made.

    ``periods``: per sensor, the samples between two of its samples on the grid ``ts`` (NaN between);
    ``initial(i, rng)`` the initial estimate of trial i (default: ``g0 exp(xi)``, xi ~ N(0, K0));
    ``attitude``: the slice of the left error that is the attitude (deg), ``position`` the slice of the
    coordinates that is the position (m), None where the state has none; ``side``: the invariant EKF's and the
    UKF-M's error (``"left"`` or ``"right"``)."""

    name: str
    description: str
    system: object
    g0: object
    inputs: Callable | None
    ts: np.ndarray
    K0: np.ndarray
    periods: dict = dataclasses.field(default_factory=dict)
    input_noise: np.ndarray | None = None
    model_error_std: float = 0.0
    substeps: int = 1
    integrator: str = "rkmk4"
    side: str = "left"
    attitude: tuple[int, int] | None = (0, 3)
    position: tuple[int, int] | None = None
    initial: Callable | None = None
    note: str = ""

    @property
    def dof(self) -> int:
        return self.system.group.tangent_dim

    def initial_estimate(self, i: int, rng: np.random.Generator):
        if self.initial is not None:
            return self.initial(i, rng)
        return self.g0.rplus(jnp.asarray(rng.multivariate_normal(np.zeros(self.dof), self.K0)))


def _grid(duration: float, rate: float) -> np.ndarray:
    return np.arange(int(round(duration * rate)) + 1) / rate


# A level circle of 5 m in 20 s at 3 m, bobbing 0.5 m every 4 s and rolling 0.1 rad, facing along the path.
GRAVITY = 9.81
_R, _W, _NU, _PHI, _Z0, _AZ = 5.0, 2 * math.pi / 20, 2 * math.pi / 4, 0.1, 3.0, 0.5


def _rz(a):
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a):
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def flight_imu(t):
    r"""The gyro (rad/s) and specific force (m/s^2) of the flight: $R = R_z(\omega t) R_x(\phi(t))$, so
    $\omega_b = \dot\phi e_1 + \omega R_x^\top e_3$, and $f = R^\top(\ddot p - g)$."""
    phi, dphi = _PHI * jnp.sin(_NU * t), _PHI * _NU * jnp.cos(_NU * t)
    R = _rz(_W * t) @ _rx(phi)
    omega = dphi * jnp.array([1.0, 0.0, 0.0]) + _W * (_rx(phi).T @ jnp.array([0.0, 0.0, 1.0]))
    a = jnp.array([-_R * _W**2 * jnp.cos(_W * t), -_R * _W**2 * jnp.sin(_W * t), -_AZ * _NU**2 * jnp.sin(_NU * t)])
    return jnp.concatenate([omega, R.T @ (a - jnp.array([0.0, 0.0, -GRAVITY]))])


FLIGHT_G0 = ((0.0, _R * _W, _AZ * _NU), (_R, 0.0, _Z0))
"""The flight's initial (velocity, position), level and facing +x."""


QUAD_WORLD = Product[SO3, R3, R3]
r"""The quadrotor's second group, $SO(3) \times \mathbb R^3 \times \mathbb R^3$: the attitude with the velocity and the
position in the world frame, each a factor, so that its left error is the body-frame attitude error and the
world-frame velocity and position differences (no rotation of one into the others, as $SE_2(3)$'s exponential has)."""


def _rvp(g):
    """(R, v, p) of a quadrotor state on $SE_2(3)$ or on :data:`QUAD_WORLD`: v and p in the world frame."""
    if isinstance(g, SE23):
        v, p = g.vectors()
        return g.rotation().as_matrix(), v, p
    return g.factors[0].as_matrix(), g.factors[1].x, g.factors[2].x


def imu_dynamics(g, u, t):
    """g^-1 dg/dt of (R; v, p) on $SE_2(3)$: the gyro, the specific force plus gravity seen in the body, and R^T v."""
    R, v, _ = _rvp(g)
    return jnp.concatenate([u[:3], u[3:] + R.T @ jnp.array([0.0, 0.0, -GRAVITY]), R.T @ v])


def world_imu_dynamics(g, u, t):
    """g^-1 dg/dt of (R, v, p) on :data:`QUAD_WORLD`: the gyro, the acceleration R f + gravity, and v (the
    translations' algebra is their derivative)."""
    R, v, _ = _rvp(g)
    return jnp.concatenate([u[:3], R @ u[3:] + jnp.array([0.0, 0.0, -GRAVITY]), v])


def downward_range(g, t):
    """The range along the body's -z axis to flat ground at z = 0: p_z / (R e_3)_z."""
    R, _, p = _rvp(g)
    return p[2:3] / R[2, 2]


def altitude(g, t):
    """The altitude p_z (m)."""
    return _rvp(g)[2][2:3]


DIP = math.radians(60.0)
M_REF = (0.0, math.cos(DIP), -math.sin(DIP))


def magnetometer(g, t):
    """The magnetic field's direction in the body frame, R^T m."""
    return _rvp(g)[0].T @ jnp.asarray(M_REF)


TRUTH_SUBSTEPS = 1
"""The flights' truth holds each IMU sample over its interval, as the filters do: the model's own process, so
that no row carries a discretization error of the truth's. (With 4 finer truth steps the first order's NEES on
quad-range was 469, with this 473: the NEES far above the band there is the filters', not the truth's.)"""
QUAD_IMU_STD = (0.01,) * 3 + (0.05,) * 3
"""The quadrotor's IMU noise per sample at 100 Hz: gyro (rad/s), accelerometer (m/s^2)."""


QUAD_K0 = np.diag([math.radians(2.0) ** 2] * 3 + [0.1**2] * 3 + [1.0**2] * 3)
"""The quadrotor's prior: 2 deg per axis, 0.1 m/s, 1 m (the left error's)."""


def _flight_g0(world: bool = False):
    v, p = (jnp.asarray(x) for x in FLIGHT_G0)
    if world:
        return QUAD_WORLD((SO3.identity(), R3(v), R3(p)))
    return SE23.from_rotation_vectors(SO3.identity(), jnp.stack([v, p]))


def _quadrotor(duration: float, altimeter: bool, world: bool = False) -> Case:
    """The quadrotor on $SE_2(3)$, or with ``world`` on :data:`QUAD_WORLD`. There the accelerometer's noise n
    enters the velocity's rate as R n, which has the law of n because its three stds are equal: the same constant
    noise map is the model of both."""
    height = (Sensor("alt", altitude, Noise.sample(0.05), ["z"], ["m"]) if altimeter
              else Sensor("range", downward_range, Noise.sample(0.05), ["r"], ["m"]))
    noise_map = np.zeros((9, 6))
    noise_map[:6, :6] = np.eye(6)
    system = SensorSystem(QUAD_WORLD if world else SE23, world_imu_dynamics if world else imu_dynamics,
                          [height, Sensor("mag", magnetometer, Noise.sample(0.02), ["x", "y", "z"], ["1"] * 3)],
                          process_noise=Noise.sample(QUAD_IMU_STD, rate=100.0), noise_map=noise_map,
                          inputs=["gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"])
    what = "an altimeter p_z" if altimeter else "a downward range sensor p_z / (R e3)_z"
    name = ("quad-altimeter" if altimeter else "quad-range") + ("-world" if world else "")
    group = "SO(3) x R^3 x R^3 (world-frame velocity and position)" if world else "SE_2(3)"
    return Case(name, f"quadrotor on {group}: IMU 100 Hz, {what} (0.05 m, 20 Hz), a magnetometer direction (0.02, "
                "50 Hz); horizontal position unobservable", system, _flight_g0(world), flight_imu,
                _grid(duration, 100.0), QUAD_K0, periods={height.name: 5, "mag": 2},
                input_noise=np.diag(QUAD_IMU_STD), substeps=TRUTH_SUBSTEPS, side="left" if world else "right",
                position=(6, 9))


def _ins(duration: float, gnss: bool) -> Case:
    if gnss:
        system = inertial_navigation(gnss_std=1.0)
        return Case("ins-gnss", "inertial_navigation(gnss_std=1.0): IMU 100 Hz, GNSS 1 Hz; the same flight",
                    system, _flight_g0(), flight_imu, _grid(duration, 100.0),
                    np.diag([math.radians(5.0) ** 2] * 3 + [0.2**2] * 3 + [2.0**2] * 3), periods={"gnss": 100},
                    input_noise=np.diag([0.01] * 6), substeps=TRUTH_SUBSTEPS, side="left", position=(6, 9))
    system = inertial_navigation(gnss_std=None, mag_std=0.02, baro_std=0.05)
    return Case("ins-baro-mag", "inertial_navigation(gnss_std=None, mag_std=0.02, baro_std=0.05): IMU 100 Hz, "
                "magnetometer 50 Hz, barometer 20 Hz; the same flight", system, _flight_g0(), flight_imu,
                _grid(duration, 100.0), QUAD_K0, periods={"mag": 2, "baro": 5}, input_noise=np.diag([0.01] * 6),
                substeps=TRUTH_SUBSTEPS, side="right", position=(6, 9))


# Planar localization: odometry at 100 Hz along a circle of 3 m in 20 s, landmarks around it.
ODOMETRY_STD = (0.02, 0.01, 0.01)
"""Odometry noise per sample at 100 Hz: forward, lateral (m/s), yaw rate (rad/s)."""
LANDMARKS = ((5.0, 0.0), (-3.0, 4.0), (-2.0, -5.0))


def odometry(t):
    """(v_x, v_y, omega) of a circle of 3 m in 20 s."""
    w = 2 * math.pi / 20
    return jnp.array([3.0 * w, 0.0, w]) + 0.0 * t


def odometry_dynamics(g, u, t):
    """The body twist (omega, v_x, v_y) in se(2)'s order from the odometry (v_x, v_y, omega)."""
    return jnp.array([u[2], u[0], u[1]])


def _body(g, points):
    R = g.rotation().as_matrix()
    return (jnp.asarray(points) - g.translation()) @ R  # rows R^T (l_i - p)


def bearings(g, t):
    """The bearings (rad) of the landmarks in the body frame."""
    b = _body(g, LANDMARKS)
    return jnp.arctan2(b[:, 1], b[:, 0])


def ranges(g, t):
    """The distances (m) to the landmarks."""
    return jnp.linalg.norm(_body(g, LANDMARKS), axis=1)


NEAR = ((1.0, 1.0),)
"""One landmark 2.2 m from the circle's start, inside it: a strongly curved range and bearing."""


def near_range_bearing(g, t):
    """Range (m) and bearing (rad) of the near landmark in the body frame."""
    b = _body(g, NEAR)[0]
    return jnp.array([jnp.linalg.norm(b), jnp.arctan2(b[1], b[0])])


def _planar(duration: float, kind: str) -> Case:
    process = Noise.sample(ODOMETRY_STD, rate=100.0)
    names = [f"l{i + 1}" for i in range(len(LANDMARKS))]
    g0 = SE2.from_coords(jnp.array([math.pi / 2, 3.0, 0.0]))
    K0 = np.diag([math.radians(10.0) ** 2, 1.0, 1.0])
    initial = None
    if kind == "bearing":
        sensor = Sensor("bearing", bearings, Noise.sample(0.01), names, ["rad"] * 3, angles=True)
        what = "bearings (0.01 rad, 10 Hz, angles=True) to 3 landmarks"
    elif kind == "range":
        sensor = Sensor("range", ranges, Noise.sample(0.05), names, ["m"] * 3)
        what = "ranges (0.05 m, 10 Hz) to 3 landmarks"
    else:
        sensor = Sensor("rb", near_range_bearing, Noise.sample([0.05, 0.01]), ["r", "b"], ["m", "rad"],
                        angles=["b"])
        what = ("range and bearing (0.05 m, 0.01 rad, 10 Hz) of one landmark 2.2 m away, a rotation about it "
                "unobservable; initial error 60 deg, 2 m")
        K0 = np.diag([math.radians(60.0) ** 2, 2.0**2, 2.0**2])
        initial = _scaled_initial(g0, K0)
    system = SensorSystem(SE2, odometry_dynamics, [sensor], process, inputs=["v_x", "v_y", "omega"])
    return Case({"bearing": "se2-bearing", "range": "se2-range", "rb": "se2-near-rb"}[kind],
                f"planar localization on SE(2): odometry 100 Hz, {what}", system, g0, odometry,
                _grid(duration, 100.0), K0, periods={sensor.name: 10}, input_noise=np.diag(ODOMETRY_STD),
                substeps=4, side="right", attitude=(0, 1), position=(1, 3), initial=initial)


def _scaled_initial(g0, K0):
    """An initial error of one standard deviation per axis with random signs: every trial starts far off."""
    def initial(i, rng):
        return g0.rplus(jnp.asarray(rng.choice([-1.0, 1.0], K0.shape[0]) * np.sqrt(np.diag(K0))))
    return initial


ATT_RATE = 100.0
GYRO_BIAS = (0.01, -0.02, 0.015)


def attitude_gyro(t):
    """The gyro reading of a body turning at up to 3 rad/s, with the constant bias GYRO_BIAS."""
    w = 3.0 / math.sqrt(3.0) * jnp.sin(2 * math.pi * jnp.array([0.31, 0.23, 0.17]) * t + jnp.array([0.3, 1.1, 2.0]))
    return w + jnp.asarray(GYRO_BIAS)


def _attitude(duration: float, large: bool) -> Case:
    system = attitude_gyro_bias(imu_rate=ATT_RATE)
    g0 = TSO3((SO3.exp(jnp.array([0.3, -0.2, 1.0])), R3(jnp.asarray(GYRO_BIAS))))
    K0 = np.diag([0.05**2] * 3 + [0.01**2] * 3)
    initial, what, name = None, "", "attitude"
    if large:
        K0 = np.diag([math.radians(90.0) ** 2] * 3 + [0.01**2] * 3)
        initial, what, name = _large_initial(g0), "; initial attitude error 90-179 deg about random axes", \
            "attitude-large"
    return Case(name, "attitude + gyro bias on TSO(3) (attitude_gyro_bias(imu_rate=100)): gyro, accelerometer and "
                f"magnetometer directions at 100 Hz, up to 3 rad/s{what}", system, g0, attitude_gyro,
                _grid(duration, ATT_RATE), K0, input_noise=np.diag([ab.GYRO_STD] * 3), side="right",
                initial=initial)


LARGE_ANGLES_DEG = (90.0, 120.0, 150.0, 179.0)


def _large_initial(g0):
    """Trial i starts LARGE_ANGLES_DEG[i mod 4] off about a random axis, the bias exact."""
    def initial(i, rng):
        n = rng.standard_normal(3)
        xi = np.r_[math.radians(LARGE_ANGLES_DEG[i % len(LARGE_ANGLES_DEG)]) * n / np.linalg.norm(n), np.zeros(3)]
        return g0.rplus(jnp.asarray(xi))
    return initial


def _fixed(g_hat):
    return lambda i, rng: g_hat


def _tse2(duration: float) -> Case:
    from ..experiments import tse2 as T

    c = T.TSE2Config(duration=duration, dt=0.01, weights="consistent", steady=(0.0, duration))
    s = T.setup(c)
    return Case("tse2", "planar rigid body on TSE(2) (Rigo et al. 2022): two GPS antennas and an IMU, density "
                "sensors, 100 Hz (the paper: 1 kHz), the paper's input and initial estimate, Q = I, R = I",
                s.system, s.g0, T.paper_input, s.ts, np.diag(c.K0_diag), attitude=(0, 1), position=(1, 3),
                initial=_fixed(s.state0.g_hat), note="density sensors: updates do not apply")


def _saccon(duration: float) -> Case:
    from ..experiments import attitude as A

    c = A.AttitudeConfig(duration=duration, weights="consistent", steady=(0.0, duration))
    s = A.setup(c)
    return Case("tso3-saccon", "rigid-body attitude on TSO(3) (Saccon et al. 2016): torque input, two direction "
                "sensors (density), 1 kHz, 60 deg initial error, Q = I, R = I", s.system, s.g0, A.paper_torque,
                s.ts, np.diag(c.K0_diag), input_noise=np.asarray(s.system.torque_noise),
                integrator=c.truth_integrator, initial=_fixed(s.state0.g_hat),
                note="density sensors: updates do not apply")


def _chaplygin(duration: float) -> Case:
    from ..experiments import chaplygin as C

    c = C.ChaplyginConfig(duration=duration, dt=0.01)
    s = C.setup(c)
    return Case("chaplygin", "Chaplygin sleigh on SE(2) x R^2 (Rigo et al. 2023): GPS antennas and INS, density "
                "sensors, 100 Hz, the paper's input and (exact) initial estimate, Q = I", s.system, s.g0,
                C.paper_input, s.ts, np.asarray(c.K0_matrix), attitude=(0, 1), position=(1, 3),
                initial=_fixed(s.state0.g_hat), note="density sensors: updates do not apply")


CASES: dict[str, tuple[str, Callable[[float], Case]]] = {
    "quad-range": ("quadrotor, range sensor + magnetometer", lambda d: _quadrotor(d, False)),
    "quad-altimeter": ("quadrotor, altimeter + magnetometer", lambda d: _quadrotor(d, True)),
    "quad-range-world": ("the quadrotor with its range sensor on SO(3) x R^6", lambda d: _quadrotor(d, False, True)),
    "quad-altimeter-world": ("the quadrotor with its altimeter on SO(3) x R^6", lambda d: _quadrotor(d, True, True)),
    "ins-baro-mag": ("inertial navigation, barometer + magnetometer", lambda d: _ins(d, False)),
    "ins-gnss": ("inertial navigation, GNSS", lambda d: _ins(d, True)),
    "se2-bearing": ("SE(2), bearings to 3 landmarks", lambda d: _planar(d, "bearing")),
    "se2-range": ("SE(2), ranges to 3 landmarks", lambda d: _planar(d, "range")),
    "attitude": ("attitude + gyro bias, discrete direction samples", lambda d: _attitude(d, False)),
    "attitude-large": ("attitude + gyro bias, 90-179 deg initial error", lambda d: _attitude(d, True)),
    "se2-near-rb": ("SE(2), range + bearing of a near landmark, large initial error", lambda d: _planar(d, "rb")),
    "tse2": ("the planar rigid body of Rigo et al. 2022", _tse2),
    "tso3-saccon": ("the attitude of Saccon et al. 2016", _saccon),
    "chaplygin": ("the Chaplygin sleigh of Rigo et al. 2023", _chaplygin),
}
"""The suite: name -> (short description, builder from the duration in s)."""


# --- the study ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SecondOrderSuite:
    """The study's settings (module docstring): ``runs`` trials per system from ``seed``, ``duration`` s each,
    the ``systems`` and ``filters`` (comma-separated names; default all); ``initial_scale`` scales every
    trial's drawn initial error (0: every filter starts at the truth, with the same K0), to tell what the initial
    error does from what the model does."""

    runs: int = 5
    seed: int = 0
    duration: float = 20.0
    systems: tuple[str, ...] | str | None = None
    filters: tuple[str, ...] | str | None = None
    initial_scale: float = 1.0

    def __post_init__(self):
        check_counts(self, "runs")
        if not (isinstance(self.duration, int | float) and math.isfinite(self.duration) and self.duration >= 1.0):
            raise ValueError(f"duration: expected a duration >= 1 s, got {self.duration!r}")
        scale = self.initial_scale
        if isinstance(scale, bool) or not (isinstance(scale, int | float) and math.isfinite(scale) and scale >= 0):
            raise ValueError(f"initial_scale: expected a finite number >= 0, got {scale!r}")
        object.__setattr__(self, "initial_scale", float(scale))
        object.__setattr__(self, "systems", parse_names("systems", self.systems, CASES, tuple(CASES)))
        object.__setattr__(self, "filters", parse_names("filters", self.filters, FILTERS, tuple(FILTERS)))


def _stack(items):
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *items)


def trials(case: Case, runs: int, seed: int, initial_scale: float = 1.0):
    """The truth (batched (runs, N)), the inputs (runs, N, m), the measurements with NaN between each sensor's
    samples (runs, N, p) and the initial estimates (batched (runs,)) of ``case``: each drawn estimate's error
    ``xi = log(g0^-1 g_hat0)`` scaled by ``initial_scale`` (1: as drawn; 0: the estimate starts at the truth, with
    the same K0)."""
    keys = jax.random.split(jax.random.key(seed), runs)
    k = np.arange(case.ts.size)
    truths, us, ys, g0s = [], [], [], []
    for i in range(runs):
        truth, log = simulate(case.system, case.g0, case.inputs, case.ts, keys[i], input_noise=case.input_noise,
                              model_error_std=case.model_error_std, substeps=case.substeps,
                              integrator=case.integrator)
        y = np.array(log.ys)
        for b in case.system.blocks():
            y[k % case.periods.get(b.name, 1) != 0, b.start:b.stop] = np.nan
        truths.append(truth.g)
        us.append(np.asarray(log.us))
        ys.append(y)
        g_hat0 = case.initial_estimate(i, np.random.default_rng([seed, i]))
        if initial_scale != 1.0:
            g_hat0 = case.g0.rplus(initial_scale * g_hat0.rminus(case.g0))
        g0s.append(g_hat0)
    return _stack(truths), np.stack(us), np.stack(ys), _stack(g0s)


def _rms(x, axis=-1):
    return np.sqrt(np.mean(np.square(x), axis=axis))


def evaluate(case: Case, truth, traj) -> dict:
    """Per trial over the second half: attitude and position rms, mean NEES; and the status of each trial."""
    late = case.ts >= 0.5 * case.ts[-1]
    e = np.asarray(left_error(truth, traj.g_hat))
    q = np.asarray(nees(jnp.asarray(e), traj.K))[:, late].mean(axis=1)
    out = {"nees": q}
    if case.attitude is not None:
        a0, a1 = case.attitude
        out["attitude_deg"] = np.degrees(_rms(np.linalg.norm(e[:, late, a0:a1], axis=-1)))
    if case.position is not None:
        p0, p1 = case.position
        d = np.asarray(truth.coords())[..., p0:p1] - np.asarray(traj.g_hat.coords())[..., p0:p1]
        out["position_m"] = _rms(np.linalg.norm(d[:, late], axis=-1))
    code = np.asarray(traj.status.code)
    out["ok"] = code == 0
    out["failures"] = [{"trial": int(i), "cause": str(CAUSES[int(code[i])]),
                        "time": float(np.asarray(traj.status.time)[i])} for i in np.flatnonzero(code != 0)]
    return out


def summary(case: Case, per_trial: dict) -> dict:
    """The row of a system and filter: means over the trials that ran through, the NEES band and flag, the
    failures and the status."""
    ok = per_trial["ok"]
    n_ok, runs = int(ok.sum()), int(ok.size)
    mean = lambda x: float(np.mean(x[ok])) if n_ok and np.all(np.isfinite(x[ok])) else None  # noqa: E731
    band = chi2_bounds(case.dof, max(n_ok, 1))
    row = {"runs": runs, "failed": runs - n_ok, "failures": per_trial["failures"],
           "attitude_deg": mean(per_trial["attitude_deg"]) if "attitude_deg" in per_trial else None,
           "position_m": mean(per_trial["position_m"]) if "position_m" in per_trial else None,
           "nees": mean(per_trial["nees"]), "dof": case.dof, "nees_band": list(band)}
    row["nees_flag"] = nees_flag(row["nees"], band)
    if row["failed"]:
        f = per_trial["failures"][0]
        row["status"] = f"{row['failed']}/{runs} failed ({f['cause']} at {f['time']:.2f} s)"
    else:
        row["status"] = "ok"
    return row


def not_applicable(case: Case, runs: int) -> dict:
    """The row of a filter that does not apply to the system."""
    return {"runs": runs, "failed": 0, "failures": [], "attitude_deg": None, "position_m": None, "nees": None,
            "dof": case.dof, "nees_band": list(chi2_bounds(case.dof, runs)), "nees_flag": None,
            "status": "not applicable", "monitor_trials": [], "leak_trials": [], "monitor": "-", "leak": None,
            "elapsed_s": 0.0}


def better_updates(rows: dict) -> str:
    """The updates of the best second-order row present (:data:`SECOND_ORDER`): fewer failures, then a NEES
    closer to its dof (by ratio); ``"discrete"`` without any, or on a tie."""
    def badness(name):
        r = rows[name]
        q = r["nees"]
        return (r["failed"], abs(math.log(q / r["dof"])) if q and q > 0 else math.inf,
                SECOND_ORDER[name] != "discrete")
    present = [n for n in SECOND_ORDER if n in rows]
    if not present:
        return "discrete"
    return SECOND_ORDER[min(present, key=badness)]


def monitor(flt, traj, ts, us, ys) -> tuple[list[str], list[float | None]]:
    """The innovation monitor's status (:func:`liemef.metrics.innovation_monitor`) of each trial of a batched
    run, and its largest median window leak over the sensors (None where not applicable)."""
    statuses, leaks = [], []
    for i in range(ys.shape[0]):
        one = SimpleNamespace(ts=traj.ts if np.ndim(traj.ts) == 1 else traj.ts[i], K=traj.K[i],
                              g_hat=jax.tree_util.tree_map(lambda a, i=i: a[i], traj.g_hat))
        report = innovation_monitor(flt, one, ts, us[i], ys[i])
        statuses.append(report.status)
        medians = [s.leak_median for s in report.sensors if s.leak_median is not None]
        leaks.append(max(medians) if medians else None)
    return statuses, leaks


def monitor_cell(statuses: Sequence[str]) -> str:
    """``"consistent 3, inconsistent 2"``: how many trials the monitor gave each status."""
    counts = {s: statuses.count(s) for s in MONITOR_STATUSES if s in statuses}
    return ", ".join(f"{s} {n}" for s, n in counts.items()) or "-"


def run_case(case: Case, filters: Sequence[str], runs: int, seed: int, progress: bool = False,
             initial_scale: float = 1.0) -> dict:
    """Every filter of ``filters`` on the trials of ``case``: the rows by filter, and the updates the
    first-order row used."""
    truth, us, ys, g0s = trials(case, runs, seed, initial_scale)
    order = [n for n in filters if n in SECOND_ORDER] + [n for n in filters if n not in SECOND_ORDER]
    rows, updates = {}, "discrete"
    for name in order:
        if name not in SECOND_ORDER:
            updates = better_updates(rows)
        t0 = time.perf_counter()
        flt = FILTERS[name][1](case.system, case, updates)
        if flt is None:
            rows[name] = not_applicable(case, runs)
            continue
        states = _stack([flt.init(jax.tree_util.tree_map(lambda a, i=i: a[i], g0s), case.K0) for i in range(runs)])
        traj = flt.run_batch(states, case.ts, us, ys)
        rows[name] = summary(case, evaluate(case, truth, traj))
        rows[name]["monitor_trials"], rows[name]["leak_trials"] = monitor(flt, traj, case.ts, us, ys)
        rows[name]["monitor"] = monitor_cell(rows[name]["monitor_trials"])
        measured = [v for v in rows[name]["leak_trials"] if v is not None]
        rows[name]["leak"] = float(np.median(measured)) if measured else None
        rows[name]["elapsed_s"] = time.perf_counter() - t0
        if progress:
            r = rows[name]
            print(f"{case.name:>15} {name:>13}: {r['status']}, attitude {fmt(r['attitude_deg'], 3)} deg, position "
                  f"{fmt(r['position_m'], 3)} m, NEES {fmt(r['nees'], 3)} ({case.dof} dof) "
                  f"[{r['elapsed_s']:.1f} s]", file=sys.stderr, flush=True)
    return {"filters": {n: rows[n] for n in filters}, "first_order_updates": updates}


def compare_second_order(study: SecondOrderSuite | None = None, *, progress: bool = True) -> dict:
    """Run the study: ``{"study", "cases"}``, per system its description, setup and rows by filter."""
    st = SecondOrderSuite() if study is None else study
    t0 = time.perf_counter()
    systems = {}
    for name in st.systems:
        case = CASES[name][1](st.duration)
        res = run_case(case, st.filters, st.runs, st.seed, progress, st.initial_scale)
        sensor_system = isinstance(case.system, SensorSystem)
        systems[name] = {"description": case.description, "dof": case.dof, "side": case.side,
                         "error": natural_error(case.system),
                         "sensor_sides": invariant_sides(case.system) if sensor_system else None,
                         "samples": int(case.ts.size), "note": case.note, **res}
    return {"study": {**dataclasses.asdict(st), "filters_described": {n: FILTERS[n][0] for n in st.filters},
                      "keys": f"trial i: simulation key jax.random.split(jax.random.key({st.seed}), {st.runs})[i], "
                              f"initial estimate from numpy.random.default_rng([{st.seed}, i])",
                      "window": "the second half of each trial", "elapsed_s": time.perf_counter() - t0},
            "cases": systems}


# --- tables and files -----------------------------------------------------------------------------------------
COLUMNS = ("system", "filter", "status", "attitude [deg]", "position [m]", "NEES", "dof", "95 % band",
           "NEES vs band", "leak", "monitor")


def table_rows(result: dict) -> list[list[str]]:
    """The cells of the table, one row per system and filter."""
    rows = []
    for sname, s in result["cases"].items():
        for name, r in s["filters"].items():
            label = f"{name} ({s['first_order_updates']})" if name == "mef-first" else name
            if name in ("iekf", "ukf-m"):
                label += f" ({s['side']})"
            lo, hi = r["nees_band"]
            rows.append([sname, label, r["status"], fmt(r["attitude_deg"], 3), fmt(r["position_m"], 3),
                         fmt(r["nees"], 3), str(r["dof"]), f"{lo:.3g}-{hi:.3g}", r["nees_flag"] or "-",
                         fmt(r["leak"], 2), r["monitor"]])
    return rows


SIDE_COLUMNS = ("system", "sensors: where their observed directions stay fixed", "the default's error",
                "iekf, ukf-m")


def side_rows(result: dict) -> list[list[str]]:
    """The second table: per system its sensors' :func:`~liemef.systems.invariant_sides`, the error the defaults
    choose (``error="auto"``) and the side the Kalman baselines were given."""
    rows = []
    for sname, s in result["cases"].items():
        sides = s.get("sensor_sides")
        cell = ", ".join(f"{k}: {v}" for k, v in sides.items()) if sides else "- (not a sensor system)"
        rows.append([sname, cell, s.get("error", "-"), s["side"]])
    return rows


def markdown(result: dict) -> str:
    """The study's report: the settings, the filters, the table and what its columns mean."""
    st = result["study"]
    lines = ["# Second-order safety suite", "",
             f"{len(result['cases'])} systems x {len(st['filters'])} filters, {st['runs']} trials of "
             f"{st['duration']:g} s each (seed {st['seed']}); errors and NEES over {st['window']}, means over the "
             "trials that ran through.", "",
             "Filters (every mef row but mef-hold-left and mef-hold-right in the error the defaults choose, "
             "error='auto': the second table):", ""]
    lines += [f"* `{n}`: {d}" for n, d in st["filters_described"].items()]
    lines += ["", "Systems:", ""]
    lines += [f"* `{n}`: {s['description']}" + (f" ({s['note']})" if s["note"] else "")
              for n, s in result["cases"].items()]
    lines += ["", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(r) + " |" for r in table_rows(result)]
    lines += ["", "The sides (liemef.systems.invariant_sides per sensor; the defaults' error='auto' takes the right "
              "error where some sensor is 'right' and none 'left', liemef.systems.natural_error):", "",
              "| " + " | ".join(SIDE_COLUMNS) + " |", "|" + "---|" * len(SIDE_COLUMNS)]
    lines += ["| " + " | ".join(r) + " |" for r in side_rows(result)]
    lines += ["", "status: `ok` when every trial ran through, else the number that failed and the first failure's "
              "cause and time. NEES: the mean of the left error's NEES over the window and the trials that ran "
              "through, for a consistent filter about its dof; the band is the 95 % chi-square band of one "
              "step's average over those trials (a mean over time as well is tighter, so 'above' and 'below' are "
              "the conservative reading); 'far above' is beyond 10 times the band's top: K does not describe the "
              "error whatever the status says. mef-first ran with the updates shown, those of the better "
              "second-order row; iekf and ukf-m with the error side shown. leak: the median over the trials of "
              "the largest sensor's median window leak (liemef.metrics.linearization_leak summed over the "
              "monitor's windows; 1 is the monitor's limit). monitor: how many trials the innovation "
              "monitor (liemef.metrics.innovation_monitor, from the innovations and the outputs' curvature, no "
              "truth) called inconsistent, nonlinear (innovations in band, but an output so curved over K's "
              "spread that K may understate the errors where no sensor looks), consistent or not applicable, "
              "failed trials included.", ""]
    return "\n".join(lines)


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``metrics.json``, ``second_order.md`` and ``second_order.csv`` to ``out``."""
    out = io.ensure_dir(out)
    return [io.write_json(out / "metrics.json", {"schema": SCHEMA, **result}),
            io.write_text(out / "second_order.md", markdown(result)),
            io.write_rows(out / "second_order.csv", list(COLUMNS), table_rows(result))]


__all__ = ["SecondOrderSuite", "compare_second_order", "markdown", "save", "CASES", "FILTERS", "Case",
           "better_updates", "run_case", "trials"]
