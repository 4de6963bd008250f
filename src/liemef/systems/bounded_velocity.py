r"""The bounded-motion attitude models: :func:`attitude_velocity`, attitude, gyro bias and a velocity on
SO(3) x R^3 x R^3, the accelerometer both an input (the specific force drives the velocity) and a direction
sensor, with a zero-velocity pseudo-measurement that bounds the velocity of a hand-held IMU; and
:func:`attitude_position`, the same with a position whose zero-position pseudo-measurement bounds where the IMU
goes. Their logs (:func:`imu_velocity_log`, :func:`imu_position_log`), states and K0.
"""

from __future__ import annotations

import math
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from .._linalg import mv
from ..groups import R3, SO3, TSO3, Product
from ._gyro_scale import GyroScaleSystem
from ._sensors import ConstantOutput, Noise, Sensor, SensorSystem, parameter
from .attitude_bias import (
    DIP,
    E_UP,
    IMU_RATE,
    INPUT_NAMES,
    STATE_NAMES,
    STATE_UNITS,
    attitude_gyro_bias,
    imu_log,
    measured_state,
)
from .imu_noise import (
    DIP_STD,
    FIELD,
    GRAVITY,
    IMU_BIAS_WALK,
    MAG_ADAPT,
    NORM_STD,
    MagneticNoise,
)

VELOCITY_STD = 0.010
r"""Default std of the zero-velocity pseudo-measurement of :func:`attitude_velocity`, as a density
(m/s sqrt(s)): the final set of the nested leave-one-out tune on the 7 shared BROAD trials, started from 0.5
(docs/imu.md, "How the defaults are made"). It sits at the search's lower bound, 0.01, in the final set and in six
of the seven folds. It is far stiffer than a hand's velocity statistics suggest: a velocity that stays within
$\sigma_v$ and decorrelates in $\tau$ has the low-frequency density $\sigma_v\sqrt{2\tau}$, 0.2-0.5 for a
hand-held IMU. What the data fit is the rate at which the accelerometer corrects the tilt against the gyro's
errors in motion, not a velocity statistic; the velocity state is then a short low-pass of the specific force in
the world frame. Use 0.2-0.5 where the motion is known to be a hand's and the gyro better than BROAD's."""
VELOCITY_GYRO_STD = 0.0103
"""Default gyro std per sample at ``IMU_RATE`` of :func:`attitude_velocity` (rad/s): the final set of the same
tune, started from the gyro's white noise (0.005). About twice that noise (:data:`GYRO_STD`), because in motion
a MEMS gyro's scale-factor and cross-axis errors (0.5-1 % each on a datasheet) add 0.01-0.02 rad/s at 1-2 rad/s
(folds: 0.0078-0.0122)."""
VELOCITY_MAG_STD = 0.0132
"""Default magnetometer std of :func:`attitude_velocity` (unitless): the final set of the same tune, started from
0.05 (folds: 0.011-0.017)."""
ACC_DENSITY = 0.02
"""Default accelerometer noise density of :func:`attitude_velocity` (m/s^2/sqrt(Hz)): a MEMS accelerometer's
white noise (BROAD at rest: 0.05 m/s^2 per sample at 286 Hz, 0.003 m/s^2/sqrt(Hz)) plus its scale and
misalignment errors in motion."""
VELOCITY_STATE_NAMES = STATE_NAMES + ("vx", "vy", "vz")
VELOCITY_STATE_UNITS = STATE_UNITS + ("m/s",) * 3
VELOCITY_INPUT_NAMES = INPUT_NAMES + ("force_x", "force_y", "force_z")


class VelocityDynamics(eqx.Module):
    r"""$\lambda(g, u) = (u_\omega - b,\ 0,\ R u_a - g\,e_{up})$ on SO(3) x R^3 x R^3: the attitude turns with
    the gyro less its bias, the bias is constant, the world velocity integrates the specific force rotated to the
    world less gravity ``gravity`` (m/s^2)."""

    gravity: Float[Array, ""] = eqx.field(converter=parameter)

    def __call__(self, g, u, t):
        return _moving(g, u, self.gravity)


def _moving(g, u, gravity):
    """The attitude's, the bias's and the velocity's rows of the bounded-motion models' dynamics."""
    R = g.factors[0].as_matrix()
    b = g.factors[1].x
    return jnp.concatenate([u[:3] - b, jnp.zeros(3), mv(R, u[3:6]) - jnp.asarray((0.0, 0.0, gravity))])


def _velocity(g, t):
    return g.factors[2].x


def attitude_velocity(gyro_std=VELOCITY_GYRO_STD, imu_rate: float | None = IMU_RATE, bias_walk=IMU_BIAS_WALK,
                      mag_std=VELOCITY_MAG_STD, dip: float = DIP, *, gravity: float = GRAVITY, field: float = FIELD,
                      acc_density=ACC_DENSITY, velocity_std=VELOCITY_STD, mag_adapt: float = MAG_ADAPT,
                      dip_std: float = DIP_STD, norm_std=NORM_STD, gyro_scale_std=0.0) -> GyroScaleSystem:
    r"""Attitude, gyro bias and velocity: linear acceleration in the minimum-energy framework, VQF's idea
    (low-pass the accelerometer in an almost inertial frame) written as a model.

    State $g = (R, b, v)$ on SO(3) x R^3 x R^3, $v$ the IMU's velocity in the world frame (m/s). Inputs: the gyro
    (rad/s) and the accelerometer's specific force $u_a$ (m/s^2, body frame), both with white noise:
    $R^\top\dot R = [u_\omega - b]_\times$, $\dot b = 0$ (walk ``bias_walk``), $\dot v = R u_a - g\,e_{up}$
    (noise ``acc_density``, :class:`VelocityDynamics`). A hand-held or body-worn IMU goes nowhere fast: its
    velocity stays small, so the model measures $v = 0$ continuously, with density ``velocity_std`` (a pseudo
    measurement, the ``velocity`` sensor; the log holds zeros). A tilt error $\varepsilon$ makes $R u_a$ leak
    $g\,\varepsilon$ into $\dot v$, which the pseudo measurement sees within a second; a linear acceleration
    integrates to the bounded velocity it causes, and moves the tilt only as much as that velocity's std allows.
    The accelerometer is never a gravity direction: there is no white-noise assumption on linear acceleration,
    and no threshold.

    The magnetometer is :func:`attitude_imu`'s: heading only, down-weighted by its norm and dip errors
    (:class:`MagneticNoise`). Its covariates are the sample's accelerometer direction and the two norms, which
    the log carries as the sensors ``acc`` and ``norm``. They are constants to the model ($h$ does not depend on
    the state), so they add nothing to the residual or to E. The log is :func:`imu_velocity_log`'s: ``us``
    (gyro, accelerometer) (N, 6) and ``ys`` (acc direction, mag direction, norms, zero velocity) (N, 11).

    Args:
        gyro_std: the gyro's std per sample at ``imu_rate`` (rad/s), as :func:`attitude_imu`'s; this model's
            default is :data:`VELOCITY_GYRO_STD`.
        imu_rate: the IMU rate (Hz) the gyro std refers to (None: ``gyro_std`` is a density).
        bias_walk: the gyro bias random walk density (rad/s/sqrt(s)).
        mag_std: the magnetometer direction's std per sample (unitless); default :data:`VELOCITY_MAG_STD`.
        dip: the magnetic dip (rad): a leaf, as every constant here.
        gravity: $g$ (m/s^2), the accelerometer's norm at rest (:func:`rest_norms`).
        field: $B$ (uT), the undisturbed field's norm.
        acc_density: the accelerometer's noise density (m/s^2/sqrt(Hz); one value or 3).
        velocity_std: the zero-velocity pseudo measurement's density (m/s sqrt(s); one value or 3).
        mag_adapt: $c_m \ge 0$ of :class:`MagneticNoise`, as :func:`attitude_imu`'s.
        dip_std: $\sigma_{dip} \ge 0$ (rad) of :class:`MagneticNoise`.
        norm_std: the norms' per-sample stds (2 values; they move nothing).
        gyro_scale_std: the gyro's scale-factor and cross-axis errors $s$ (unitless, >= 0): the gyro's noise
            grows with the rate it measures, $(\sigma_g^2 + s^2|u_\omega|^2)$ per sample at ``imu_rate``
            (:class:`~liemef.systems._gyro_scale.GyroScaleSystem`, an array leaf); 0 (default) turns it off.

    K0 guidance: the velocity block in (m/s)^2, e.g. (0.1 m/s)^2 at rest.
    """
    for name, v in (("gravity", gravity), ("field", field)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a norm > 0, got {v!r}")
    for name, v in (("mag_adapt", mag_adapt), ("dip_std", dip_std)):
        if not (isinstance(v, int | float | np.floating) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a gain >= 0, got {v!r}")
    base = attitude_gyro_bias(gyro_std, imu_rate, bias_walk, 1.0, mag_std, dip)
    acc_noise, vel_noise = Noise.density(acc_density), Noise.density(velocity_std)
    if acc_noise.dim not in (1, 3) or vel_noise.dim not in (1, 3):
        raise ValueError(f"acc_density, velocity_std: expected 1 or 3 stds each, got {acc_noise.dim} and "
                         f"{vel_noise.dim}")
    density = jnp.concatenate([base.process_noise.std, jnp.broadcast_to(acc_noise.std, (3,))])
    xyz = ("x", "y", "z")
    _, mag = base.sensors
    acc = Sensor("acc", ConstantOutput(E_UP), Noise.sample(1.0), xyz, ("1",) * 3)
    mag = Sensor("mag", mag.fn, mag.noise, mag.components, mag.units,
                 scale=MagneticNoise(acc=0, mag=3, norm=7, field=float(field), dip=float(dip)),
                 scale_params=[float(mag_adapt), float(dip_std)])
    norm = Sensor("norm", ConstantOutput((float(gravity), float(field))), Noise.sample(norm_std), ("acc", "mag"),
                  ("m/s^2", "uT"))
    vel = Sensor("velocity", _velocity, Noise.density(jnp.broadcast_to(vel_noise.std, (3,))), xyz, ("m/s",) * 3)
    system = SensorSystem(Product[SO3, R3, R3], VelocityDynamics(float(gravity)), (acc, mag, norm, vel),
                          Noise.density(density), inputs=VELOCITY_INPUT_NAMES,
                          input_units=("rad/s",) * 3 + ("m/s^2",) * 3, state_names=VELOCITY_STATE_NAMES,
                          state_units=VELOCITY_STATE_UNITS)
    return GyroScaleSystem(system, gyro_scale_std, imu_rate)


def imu_velocity_log(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
                     rate: float, t0: float = 0.0, *,
                     gyro: Literal["forward", "backward"] = "forward") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The log of :func:`attitude_velocity` from raw IMU columns: ``us`` = (gyro, accelerometer) (N, 6), the
    inputs, in the sample convention ``gyro`` for both (:func:`imu_log`); ``ys`` = (accelerometer direction,
    magnetometer direction, their norms, zero velocity) (N, 11), at their own time."""
    ts, us, ys = imu_log(gyr, acc, mag, rate, t0, norms=True, gyro=gyro)
    a = _validate.array("acc", np.asarray(acc, dtype=np.float64), (us.shape[0], 3), missing=True)
    if gyro == "backward":
        a = np.concatenate([a[1:], a[-1:]], axis=0)
    return ts, np.concatenate([us, a], axis=1), np.concatenate([ys, np.zeros((ys.shape[0], 3))], axis=1)


K0_VELOCITY = np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3)
"""A K0 for :func:`attitude_velocity` from a TRIAD estimate at rest (:func:`initial_estimate`): (0.05 rad)^2 on
the attitude, (0.01 rad/s)^2 on an unknown bias and (0.1 m/s)^2 on the velocity (at rest); ``liemef compare
broad``'s and ``liemef run --system attitude-velocity``'s."""


def velocity_measured_state(ys: Float[ArrayLike, "N 11"]) -> Float[np.ndarray, "N 9"]:
    """State coordinates of :func:`attitude_velocity` read off its log's ``ys`` (:func:`imu_velocity_log`): the
    TRIAD attitude of :func:`measured_state`; the bias and the velocity are not measured (NaN: the zero velocity
    in the log is a pseudo measurement)."""
    ys = np.asarray(ys, dtype=np.float64)
    return np.concatenate([measured_state(ys[:, :6]), np.full((ys.shape[0], 3), np.nan)], axis=1)


def attitude_velocity_state(g: TSO3, v=(0.0, 0.0, 0.0)):
    """The :func:`attitude_velocity` state from an attitude-and-bias estimate (e.g. :func:`initial_estimate`) and a
    velocity (m/s, default at rest)."""
    v = _validate.array("v", np.asarray(v, dtype=np.float64), (3,))
    return Product[SO3, R3, R3]((g.factors[0], g.factors[1], R3(jnp.asarray(v))))


POSITION_STD = 0.0333
r"""Default density of :func:`attitude_position`'s zero-position pseudo-measurement (m sqrt(s)): the final set of
the nested leave-one-out tune on the 7 shared BROAD trials, started from a hand's position statistics (0.6:
within 0.3 m, decorrelating in 2 s; docs/imu.md, "Linear acceleration as a bounded position"). Its folds chose
0.0054-0.15: the data ask for a stiff position, as they ask the bounded-velocity model for a stiff velocity."""
POSITION_GYRO_STD = 0.012
"""Default gyro std per sample at ``IMU_RATE`` of :func:`attitude_position` (rad/s): the final set of the same
tune, started from the gyro's white noise (0.005) (folds: 0.0061-0.0104)."""
POSITION_MAG_STD = 0.0357
"""Default magnetometer std of :func:`attitude_position` (unitless): the final set of the same tune, started from
0.05 (folds: 0.0041-0.025)."""
POSITION_ACC_DENSITY = 0.0116
"""Default accelerometer noise density of :func:`attitude_position` (m/s^2/sqrt(Hz)): the final set of the same
tune, started from :data:`ACC_DENSITY` (folds: 0.0005-0.011)."""
POSITION_WALK = 1e-3
"""Default density of the position's own process noise (m/sqrt(s)): how far the point the IMU hovers about may
wander, beside the double integral of the accelerometer."""
POSITION_STATE_NAMES = VELOCITY_STATE_NAMES + ("px", "py", "pz")
POSITION_STATE_UNITS = VELOCITY_STATE_UNITS + ("m",) * 3


class PositionDynamics(eqx.Module):
    r"""$\lambda(g, u) = (u_\omega - b,\ 0,\ R u_a - g\,e_{up},\ v)$ on SO(3) x R^3 x R^3 x R^3:
    :class:`VelocityDynamics`'s and the world position $p$, which integrates the velocity."""

    gravity: Float[Array, ""] = eqx.field(converter=parameter)

    def __call__(self, g, u, t):
        return jnp.concatenate([_moving(g, u, self.gravity), g.factors[2].x])


def _position(g, t):
    return g.factors[3].x


def attitude_position(gyro_std=POSITION_GYRO_STD, imu_rate: float | None = IMU_RATE, bias_walk=IMU_BIAS_WALK,
                      mag_std=POSITION_MAG_STD, dip: float = DIP, *, gravity: float = GRAVITY,
                      field: float = FIELD, acc_density=POSITION_ACC_DENSITY, velocity_std=1.0,
                      position_std=POSITION_STD,
                      position_walk=POSITION_WALK, mag_adapt: float = MAG_ADAPT, dip_std: float = DIP_STD,
                      norm_std=NORM_STD, gyro_scale_std=0.0) -> GyroScaleSystem:
    r"""Attitude, gyro bias, velocity and position: :func:`attitude_velocity` with the position bounded instead
    of (or beside) the velocity.

    State $g = (R, b, v, p)$ on SO(3) x R^3 x R^3 x R^3, $p$ the IMU's position in the world frame (m) about the
    point it hovers over: $\dot p = v$ (noise ``position_walk``, :class:`PositionDynamics`), the rest as
    :func:`attitude_velocity`'s. A hand-held or body-worn IMU stays within reach: the model measures $p = 0$
    continuously, with density ``position_std`` (the ``position`` sensor; the log holds zeros), and the velocity's
    pseudo-measurement is loose (``velocity_std`` 1 m/s sqrt(s) by default).

    Why: a tilt error $\varepsilon$ leaks $g\,\varepsilon$ into $\dot v$, so $p$ drifts as
    $\tfrac12 g\varepsilon t^2$, while a hand's motion back and forth integrates twice to a position that stays
    within reach. The velocity model must tell the two apart by a velocity that a translation makes large; the
    double integral attenuates the motion by the square of its frequency and lets the tilt's leak grow with
    time, so the same stiffness suits a turn in place and a translation.

    The log is :func:`imu_position_log`'s (``ys`` (N, 14): :func:`imu_velocity_log`'s and a zero position), the
    state :func:`attitude_position_state`, K0 :data:`K0_POSITION`. The defaults of ``gyro_std``, ``mag_std``,
    ``acc_density`` and ``position_std`` are the final set of a nested leave-one-out tune on the 7 shared BROAD
    trials (:data:`POSITION_STD`). Arguments as :func:`attitude_velocity`'s, and:

    Args:
        position_std: the zero-position pseudo-measurement's density (m sqrt(s); one value or 3).
        position_walk: the position's process noise density (m/sqrt(s); one value or 3), > 0.
    """
    base = attitude_velocity(gyro_std, imu_rate, bias_walk, mag_std, dip, gravity=gravity, field=field,
                             acc_density=acc_density, velocity_std=velocity_std, mag_adapt=mag_adapt,
                             dip_std=dip_std, norm_std=norm_std, gyro_scale_std=gyro_scale_std)
    pos_noise, walk = Noise.density(position_std), Noise.density(position_walk)
    if pos_noise.dim not in (1, 3) or walk.dim not in (1, 3):
        raise ValueError(f"position_std, position_walk: expected 1 or 3 stds each, got {pos_noise.dim} and "
                         f"{walk.dim}")
    pos = Sensor("position", _position, Noise.density(jnp.broadcast_to(pos_noise.std, (3,))), ("x", "y", "z"),
                 ("m",) * 3)
    density = jnp.concatenate([base.process_noise.std, jnp.broadcast_to(walk.std, (3,))])
    system = SensorSystem(Product[SO3, R3, R3, R3], PositionDynamics(float(gravity)), (*base.sensors, pos),
                          Noise.density(density), inputs=VELOCITY_INPUT_NAMES, input_units=base.input_units,
                          state_names=POSITION_STATE_NAMES, state_units=POSITION_STATE_UNITS)
    return GyroScaleSystem(system, gyro_scale_std, imu_rate)


def imu_position_log(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
                     rate: float, t0: float = 0.0, *,
                     gyro: Literal["forward", "backward"] = "forward") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The log of :func:`attitude_position`: :func:`imu_velocity_log`'s, and a zero position (``ys`` (N, 14))."""
    ts, us, ys = imu_velocity_log(gyr, acc, mag, rate, t0, gyro=gyro)
    return ts, us, np.concatenate([ys, np.zeros((ys.shape[0], 3))], axis=1)


K0_POSITION = np.diag(np.concatenate([np.diag(K0_VELOCITY), [0.05**2] * 3]))
"""A K0 for :func:`attitude_position`: :data:`K0_VELOCITY` and (0.05 m)^2 on the position (the origin is where
the IMU starts, at rest)."""


def position_measured_state(ys: Float[ArrayLike, "N 14"]) -> Float[np.ndarray, "N 12"]:
    """State coordinates of :func:`attitude_position` read off its log's ``ys`` (:func:`imu_position_log`):
    :func:`velocity_measured_state`'s, and the position not measured (NaN: the zero position is a pseudo
    measurement)."""
    ys = np.asarray(ys, dtype=np.float64)
    return np.concatenate([velocity_measured_state(ys[:, :11]), np.full((ys.shape[0], 3), np.nan)], axis=1)


def attitude_position_state(g: TSO3, v=(0.0, 0.0, 0.0), p=(0.0, 0.0, 0.0)):
    """The :func:`attitude_position` state from an attitude-and-bias estimate, a velocity (m/s) and a position (m),
    both at the origin at rest by default."""
    p = _validate.array("p", np.asarray(p, dtype=np.float64), (3,))
    return Product[SO3, R3, R3, R3]((*attitude_velocity_state(g, v).factors, R3(jnp.asarray(p))))
