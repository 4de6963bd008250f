r"""Attitude with gyro bias on TSO(3) = SO(3) x R^3: an IMU's gyro as the input, gravity and magnetic field
directions as the sensors (the AHRS problem, e.g. the BROAD benchmark's logs).

State $g = (R, b)$: $R$ the rotation body -> world (ENU: x east, y north, z up), $b$ the gyro bias (rad/s,
body frame); algebra order $(\eta_R; \eta_b)$. Input $u$ = the gyro reading (rad/s, body frame), modelled as
$u = \omega + b + n_g$. Kinematics $g^{-1}\dot g = \lambda(g, u) = (u - b,\ 0)$: $R^\top\dot R = [u - b]_\times$,
$\dot b = 0$. Model error $B\delta$: the gyro noise on the rotation block, the bias random walk on the bias block,
$B = \mathrm{diag}(s_g I_3, s_b I_3)$ as densities (:class:`~liemef.systems.Noise`, docs/weights.md).

Sensors (unitless directions in the body frame, each a 3-vector of norm 1):

* ``acc``: $h = R^\top e_{up}$, $e_{up} = (0, 0, 1)$: the normalized accelerometer reading (a specific force
  reads +g along the body axis that points up at rest). Linear acceleration is an error of this model.
* ``mag``: $h = R^\top m_{ref}$, $m_{ref} = (0, \cos\delta, -\sin\delta)$, $\delta$ the magnetic dip (north =
  +y, the field points down in the northern hemisphere): the normalized magnetometer reading. Estimate the dip
  from samples at rest with :func:`magnetic_dip`.

Default noise levels, a MEMS IMU at the BROAD rate (285.714 Hz); each is a std per sample at ``imu_rate`` (a
density is std / sqrt(rate)), or a density where named so:

* gyro ``GYRO_STD`` = 0.005 rad/s per sample (density 3.0e-4 rad/s/sqrt(Hz), 0.017 deg/s/sqrt(Hz)); BROAD's
  gyro at rest shows 0.0015-0.004 rad/s;
* bias random walk ``BIAS_WALK`` = 1e-4 rad/s/sqrt(s) (a density): the bias may drift by about 0.02 deg/s in a
  minute;
* ``ACC_STD`` = 0.02 and ``MAG_STD`` = 0.05 per sample (unitless). The sensors' own noise is smaller (BROAD at
  rest: 0.005 for acc, 0.015 for mag), but their errors in motion are not white: linear acceleration (0.4-1.5
  m/s^2 median-95th percentile in BROAD's slow trial, i.e. 0.04-0.15 of g) and magnetic disturbances last
  seconds. The values set the filter's correction bandwidth (for one axis, about $s_g / s_y$ with densities
  $s_y = \sigma_y/\sqrt{f}$: 0.25 rad/s for acc, 0.1 rad/s for mag), the role of Madgwick's beta or Mahony's
  Kp. They are the best of a 3 x 3 grid (acc 0.01, 0.02, 0.05; mag 0.02, 0.05, 0.1) over BROAD trials 01, 07
  and 24 taken together: total attitude rms 2.35, 3.86 and 1.93 deg over whole trials, against BROAD's
  Madgwick 2.3, 5.0, 1.8 and Mahony 3.4, 5.2, 2.1 deg.

The magnetic dip is a static parameter (a sensor's output map is structure): a new dip compiles the filter anew;
new noise levels do not (:meth:`~liemef.systems.SensorSystem.with_noise`).

Outliers: each sensor may have a gate, a robust loss and ``max_rejections`` (:class:`~liemef.systems.Sensor`).
On BROAD, ``acc_robust="huber"`` lowered the total rms of the fast trial 07 from 3.86 to 3.22 deg and of the
tapping trial 24 from 1.93 to 1.86 deg, while a chi-square gate on ``acc`` (0.999) rejected a third of the
samples and helped less (3.70, 2.17 deg).

Sample semantics and fast rotation: a ``Noise.sample`` direction is held over the interval that follows it,
against an estimate that turns by $|\omega| \Delta$ meanwhile (3.4 deg at 17 rad/s and 286 Hz), which lags the
estimate by about half of it: on a synthetic 17 rad/s log the default filter's error is 1.2 deg rms. With
``directions="density"`` (the same weight on a uniform IMU clock) and a filter with ``interpolation="linear"``,
gyro and directions are interpolated between samples and the error drops to 0.1 deg
(``tests/test_attitude_bias.py``); on BROAD trial 07 ``interpolation="linear"`` gives 3.26 deg instead of 3.86.

K0 guidance: K is the covariance of the left error $\xi$ with $g = \hat g \exp\xi$: the rotation error in rad in
the body frame, then the bias error in rad/s. From a TRIAD estimate (:func:`initial_estimate`) at rest and an
unknown bias, e.g. ``K0 = diag((0.05 rad)^2 I3, (0.01 rad/s)^2 I3)``; an attitude known only to 90 deg gives
``(1.57 rad)^2``. Even K0 = (0.05 rad)^2 makes the first samples stiff (``||K E|| dt`` about 10 at the default
acc std): keep the filter's default ``substeps="auto"``, which splits those intervals; one step per sample loses
the positive definiteness of K on the first interval. With ``integrator="lie-euler"`` fast rotation (17 rad/s)
needs many more sub-steps than ``"auto"`` chooses (64 fixed ones work): prefer RKMK4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .. import _validate
from .._linalg import mv
from ..groups import R3, SO3, TSO3, Product
from ._gyro_scale import GyroScaleSystem
from ._sensors import ConstantOutput, Noise, Sensor, SensorSystem

IMU_RATE = 285.714
"""Default IMU rate (Hz), BROAD's ``sampling_rate`` (2000/7)."""
GYRO_STD = 0.005
"""Default gyro noise std per sample at ``IMU_RATE`` (rad/s)."""
BIAS_WALK = 1e-4
"""Default gyro bias random walk density (rad/s/sqrt(s))."""
ACC_STD = 0.02
"""Default std of one normalized accelerometer sample (unitless)."""
MAG_STD = 0.05
"""Default std of one normalized magnetometer sample (unitless)."""
DIP = math.radians(68.0)
"""Default magnetic dip (rad): Berlin, where BROAD was recorded (67-72 deg measured there); use
:func:`magnetic_dip` on your own data."""
E_UP = (0.0, 0.0, 1.0)
"""The world up direction (ENU)."""

STATE_NAMES = ("rx", "ry", "rz", "bx", "by", "bz")
STATE_UNITS = ("rad", "rad", "rad", "rad/s", "rad/s", "rad/s")
INPUT_NAMES = ("gyro_x", "gyro_y", "gyro_z")


def gyro_bias_dynamics(g, u, t):
    r"""$\lambda(g, u) = (u - b,\ 0)$."""
    b = g.factors[1].x
    return jnp.concatenate([u - b, jnp.zeros(3)])


@dataclass(frozen=True)
class BodyDirection:
    r"""$h(g) = R^\top v$: the fixed world direction ``v`` (a tuple, so that equal directions are one compiled
    structure) seen in the body frame."""

    v: tuple[float, float, float]

    def __call__(self, g, t):
        R = g.factors[0].as_matrix()
        return mv(jnp.swapaxes(R, -1, -2), jnp.asarray(self.v))


def magnetic_reference(dip: float) -> tuple[float, float, float]:
    r"""$m_{ref} = (0, \cos\delta, -\sin\delta)$ in ENU for the dip $\delta$ (rad)."""
    return (0.0, math.cos(dip), -math.sin(dip))


def attitude_gyro_bias(gyro_std=GYRO_STD, imu_rate: float | None = IMU_RATE, bias_walk=BIAS_WALK,
                       acc_std=ACC_STD, mag_std=MAG_STD, dip: float = DIP, *, acc_gate: float | None = None,
                       acc_robust: str | None = None, acc_max_rejections: int | None = None,
                       mag_gate: float | None = None, mag_robust: str | None = None,
                       mag_max_rejections: int | None = None,
                       directions: Literal["sample", "density"] = "sample") -> SensorSystem:
    """The TSO(3) attitude + gyro bias system with accelerometer and magnetometer directions (module docstring).

    Args:
        gyro_std: gyro noise std per sample at ``imu_rate`` (rad/s; one value or 3), or a density
            (rad/s/sqrt(Hz)) if ``imu_rate`` is None.
        imu_rate: the IMU rate (Hz) the gyro std refers to.
        bias_walk: gyro bias random walk density (rad/s/sqrt(s); one value or 3).
        acc_std: std of one normalized accelerometer sample (unitless; one value or 3).
        mag_std: std of one normalized magnetometer sample (unitless; one value or 3).
        dip: magnetic dip (rad), positive when the field points down (:func:`magnetic_dip`).
        acc_gate: the accelerometer's chi-square gate probability (:class:`~liemef.systems.Sensor`).
        acc_robust: ``"huber"`` or ``"cauchy"`` down-weighting of accelerometer outliers (fast translation).
        acc_max_rejections: consecutive rejected accelerometer samples that make the run fail.
        mag_gate: the magnetometer's gate probability.
        mag_robust: its robust loss (magnetic disturbances).
        mag_max_rejections: consecutive rejected magnetometer samples that make the run fail.
        directions: how the direction samples enter: ``"sample"`` (each sample carries its information once,
            ``Noise.sample(std)``: right for any sample times) or ``"density"`` (a measurement held at the IMU
            rate, ``Noise.density(std / sqrt(imu_rate))``: the same weight on a uniform IMU clock, and
            interpolated between samples by a filter with ``interpolation="linear"``, see the module docstring).

    ``B = diag(gyro density, bias walk)`` with ``R = I``; ``D = diag(acc_std, mag_std)`` with ``Q = I``.
    """
    if not (isinstance(dip, int | float) and math.isfinite(dip) and abs(dip) <= math.pi / 2):
        raise ValueError(f"dip: expected a magnetic dip in radians within [-pi/2, pi/2], got {dip!r}")
    gyro = Noise.density(gyro_std) if imu_rate is None else Noise.sample(gyro_std, imu_rate)
    walk = Noise.density(bias_walk)
    if gyro.dim not in (1, 3) or walk.dim not in (1, 3):
        raise ValueError(f"gyro_std, bias_walk: expected 1 or 3 stds each, got {gyro.dim} and {walk.dim}")
    density = jnp.concatenate([jnp.broadcast_to(gyro.density_std("gyro_std"), (3,)),
                               jnp.broadcast_to(walk.std, (3,))])
    _validate.choice("directions", directions, {"sample", "density"})
    if directions == "density" and imu_rate is None:
        raise ValueError("imu_rate: directions='density' holds each sample over 1/imu_rate; expected the IMU rate "
                         "in Hz, got None")

    def noise(std):
        if directions == "sample":
            return Noise.sample(std)
        return Noise.density(np.asarray(std, dtype=np.float64) / math.sqrt(imu_rate))

    xyz = ("x", "y", "z")
    acc = Sensor("acc", BodyDirection(E_UP), noise(acc_std), xyz, ("1",) * 3, gate=acc_gate,
                 robust=acc_robust, max_rejections=acc_max_rejections)
    mag = Sensor("mag", BodyDirection(magnetic_reference(float(dip))), noise(mag_std), xyz, ("1",) * 3,
                 gate=mag_gate, robust=mag_robust, max_rejections=mag_max_rejections)
    return SensorSystem(TSO3, gyro_bias_dynamics, (acc, mag), Noise.density(density), inputs=INPUT_NAMES,
                        input_units=("rad/s",) * 3, state_names=STATE_NAMES, state_units=STATE_UNITS)


# --- real IMU effects: a heteroscedastic model of the direction sensors ------------------------------------------
GRAVITY = 9.81
"""Default gravity (m/s^2) for :func:`attitude_imu`; use the accelerometer's norm at rest (:func:`rest_norms`)."""
FIELD = 43.0
"""Default magnetic field strength (uT) for :func:`attitude_imu` (Berlin; BROAD measures 42-44 uT); use
:func:`rest_norms` on your own data."""
ACC_ADAPT = math.sqrt(2.0)
r"""Default gain $c_a$ of the accelerometer's noise model (:class:`AccelerationNoise`): $\sqrt 2$, the tilt a
horizontal linear acceleration causes for the norm it adds."""
IMU_BIAS_WALK = 1e-5
"""Default gyro bias random walk of :func:`attitude_imu` (rad/s/sqrt(s)): a MEMS gyro's rate random walk
(datasheets: 0.5-2e-5 rad/s/sqrt(s)), about 0.008 deg/s over BROAD's 3 minutes. :data:`BIAS_WALK` (1e-4), ten
times that, let the fast-translation trial's accelerometer errors pull the bias by 0.1-0.3 deg/s within seconds."""
ACC_NORM_TOL = 0.03
"""Default $e_0$ of :class:`AccelerationNoise`: the accelerometer norm's own relative error (3 % of g: BROAD's
norm at rest scatters by 0.5 %, and a MEMS accelerometer's scale factors and misalignment add 1-3 %)."""
MAG_ADAPT = 1.0
"""Default gain $c_m$ of the magnetometer's noise model on the field's relative norm and dip errors
(:class:`MagneticNoise`)."""
DIP_STD = 0.1
"""Default std (rad, per sample) of the magnetometer's direction along the dip (:class:`MagneticNoise`): the
local field's dip varies by degrees indoors."""
NORM_STD = (0.1, 1.0)
"""Std of one sample of the norms (accelerometer m/s^2, magnetometer uT): their noise at rest, a few times
BROAD's (0.03 m/s^2, 0.3 uT). They do not depend on the attitude, so they move neither the estimate nor K."""


@dataclass(frozen=True)
class AccelerationNoise:
    r"""The accelerometer direction's noise given the sample. A linear acceleration $a_{lin}$ (world frame)
    tilts the measured direction and changes the norm: with $e = (|a| - g)/g$,

    * a horizontal $a_{lin}$ tilts the direction by $\theta \approx |a_{lin}|/g$ and lengthens the reading to
      $g\sqrt{1 + \theta^2}$: $e \approx \theta^2/2$, i.e. $\theta^2 \approx 2|e|$;
    * a vertical one changes the norm only ($\theta = 0$, $|e| = |a_{lin}|/g$);
    * the norm has errors of its own (noise, scale factors, misalignment: a few percent of g on a MEMS part),
      which say nothing of a tilt.

    So $2|e|$ bounds the squared tilt once $|e|$ is well above the norm's own error level $e_0$, and a small
    $|e|$ says little. The model adds to the sensor's variance

    $$\sigma_a(y)^2 = \sigma_a^2 + c_a^2\, \frac{e^2}{|e| + e_0},$$

    which is $c_a^2 |e|$ for $|e| \gg e_0$ ($c_a = \sqrt 2$ is the bound itself, :data:`ACC_ADAPT`; larger
    values account for accelerations that last several samples, whose errors are not independent) and
    $c_a^2 e^2 / e_0$, quadratic, for $|e| \ll e_0$. A sample whose norm says "accelerating" weighs less,
    smoothly (no threshold). ``params = (c_a, e_0)``; ``norm`` is the index of $|a|$ in the sample (the
    ``norm`` sensor of :func:`attitude_imu`).
    """

    norm: int
    gravity: float

    def __call__(self, std, params, y):
        e = (y[self.norm] - self.gravity) / self.gravity
        s2 = std[0] ** 2
        return s2 / (s2 + params[0] ** 2 * e * e / (jnp.abs(e) + params[1]))


@dataclass(frozen=True)
class MagneticNoise:
    r"""The magnetometer direction's noise given the sample: anisotropic (the field's dip is local), and larger
    when the field is disturbed.

    *Heading, not tilt.* The accelerometer is the reference for tilt. The field's direction below the horizon
    varies indoors (iron in the building, a translation through an inhomogeneous field) by degrees, and with a
    steep dip $\delta$ a tilt error $\varepsilon$ about north looks to the magnetometer like a heading error
    $\tan\delta\,\varepsilon$ (2.5 times at Berlin's 68 deg). The sample's two tangent directions on the sphere
    are $t_1 = \bar u \times \bar m / |\cdot|$ (a change of heading moves $\bar m$ along it; $\bar u$ the
    accelerometer's up) and $t_2 = \bar m \times t_1$ (a change of dip). The noise is
    $\sigma_m^2 (I - t_2 t_2^\top) + (\sigma_m^2 + \sigma_{dip}^2)\, t_2 t_2^\top$: the magnetometer informs the
    heading with its std and the tilt only through $\sigma_{dip}$.

    *Disturbances.* A magnet or iron changes the field's strength $B$ and its dip; the squared relative norm
    error and the squared dip error bound the disturbance's squared relative size from below, and the whole
    block's variance grows with them:

    $$\sigma_m(y)^2 = \sigma_m^2 + c_m^2 \left[\left(\frac{|m| - B}{B}\right)^2 +
    \left(\frac{-\bar a\cdot\bar m - \sin\delta}{\cos\delta}\right)^2\right]$$

    (the second term is the dip error to first order). ``params = (c_m, sigma_dip)``. The indices are those of
    the sample: ``acc`` and ``mag`` the first components of the two directions, ``norm`` that of $|m|$. Returns
    the transform $T$ with $T^\top T = \sigma_m^2 \Sigma(y)^{-1}$.
    """

    acc: int
    mag: int
    norm: int
    field: float
    dip: float

    def __call__(self, std, params, y):
        a, m = y[self.acc:self.acc + 3], y[self.mag:self.mag + 3]
        e_norm = (y[self.norm] - self.field) / self.field
        e_dip = (-(a @ m) - math.sin(self.dip)) / math.cos(self.dip)
        s2 = std[0] ** 2
        f = s2 / (s2 + params[0] ** 2 * (e_norm ** 2 + e_dip ** 2))
        t1 = jnp.cross(a, m)
        n1 = jnp.sqrt(t1 @ t1)
        t1 = t1 / jnp.where(n1 > 1e-9, n1, 1.0)
        t2 = jnp.cross(m, t1)
        # (I - c t2 t2^T)^2 = I - kappa t2 t2^T for a unit t2, kappa = sigma_dip^2 / (sigma_m^2 + sigma_dip^2)
        kappa = params[1] ** 2 / (s2 + params[1] ** 2)
        c = 1.0 - jnp.sqrt(1.0 - kappa)
        return jnp.sqrt(f) * (jnp.eye(3) - c * jnp.outer(t2, t2))


def attitude_imu(gyro_std=GYRO_STD, imu_rate: float | None = IMU_RATE, bias_walk=IMU_BIAS_WALK, acc_std=ACC_STD,
                 mag_std=MAG_STD, dip: float = DIP, *, gravity: float = GRAVITY, field: float = FIELD,
                 acc_adapt: float = ACC_ADAPT, acc_norm_tol: float = ACC_NORM_TOL, mag_adapt: float = MAG_ADAPT,
                 dip_std: float = DIP_STD,
                 norm_std=NORM_STD,
                 directions: Literal["sample", "density"] = "sample") -> SensorSystem:
    r"""Attitude + gyro bias with a heteroscedastic model of the direction sensors (real IMU effects).

    :func:`attitude_gyro_bias` with a third sensor, ``norm`` = $(|a|, |m|)$ (m/s^2, uT), the raw norms of the
    two readings (:func:`imu_log` with ``norms=True``). The norms do not depend on the attitude
    ($h_{norm} = (g, B)$, a constant: they add nothing to the residual or to E). They are the covariates of the
    direction sensors' noise: each direction sample's std is a function of the sample, the accelerometer's by
    :class:`AccelerationNoise` (linear acceleration), the magnetometer's by :class:`MagneticNoise` (magnetic
    disturbance). This is a measurement model, not a switch: the cost's weight on a sample is the inverse of
    its variance under the model, and every factor is smooth in the sample.

    Args (beyond :func:`attitude_gyro_bias`'s, whose defaults it keeps but ``bias_walk`` =
    :data:`IMU_BIAS_WALK`):
        gravity: $g$ (m/s^2), the accelerometer's norm at rest (:func:`rest_norms`).
        field: $B$ (uT), the magnetometer's norm in the undisturbed field (:func:`rest_norms`).
        acc_adapt: $c_a \ge 0$ (0: the plain model).
        acc_norm_tol: $e_0 > 0$, the accelerometer norm's own relative error.
        mag_adapt: $c_m \ge 0$ (0 and ``dip_std=0``: the plain model).
        dip_std: $\sigma_{dip} \ge 0$ (rad), the magnetometer's extra std along the dip.
        norm_std: the norms' per-sample stds (2 values).

    ``gravity``, ``field`` and ``dip`` are structure (a new value compiles anew); the stds and $c_a$, $c_m$
    are leaves (:meth:`~liemef.systems.SensorSystem.with_noise`,
    :meth:`~liemef.systems.SensorSystem.with_scale_params`).
    """
    for name, v in (("gravity", gravity), ("field", field)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a norm > 0, got {v!r}")
    if not (isinstance(acc_norm_tol, int | float | np.floating) and math.isfinite(acc_norm_tol) and acc_norm_tol > 0):
        raise ValueError(f"acc_norm_tol: expected a relative error > 0, got {acc_norm_tol!r}")
    for name, v in (("acc_adapt", acc_adapt), ("mag_adapt", mag_adapt), ("dip_std", dip_std)):
        if not (isinstance(v, int | float | np.floating) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a gain >= 0, got {v!r}")
    base = attitude_gyro_bias(gyro_std, imu_rate, bias_walk, acc_std, mag_std, dip, directions=directions)
    acc, mag = base.sensors
    acc = Sensor("acc", acc.fn, acc.noise, acc.components, acc.units,
                 scale=AccelerationNoise(norm=6, gravity=float(gravity)),
                 scale_params=[float(acc_adapt), float(acc_norm_tol)])
    mag = Sensor("mag", mag.fn, mag.noise, mag.components, mag.units,
                 scale=MagneticNoise(acc=0, mag=3, norm=7, field=float(field), dip=float(dip)),
                 scale_params=[float(mag_adapt), float(dip_std)])
    norm = Sensor("norm", ConstantOutput((float(gravity), float(field))), Noise.sample(norm_std), ("acc", "mag"),
                  ("m/s^2", "uT"))
    return SensorSystem(TSO3, gyro_bias_dynamics, (acc, mag, norm), base.process_noise, inputs=INPUT_NAMES,
                        input_units=("rad/s",) * 3, state_names=STATE_NAMES, state_units=STATE_UNITS)


# --- linear acceleration as a state: the velocity of a hand-held IMU is bounded ---------------------------------
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


@dataclass(frozen=True)
class VelocityDynamics:
    r"""$\lambda(g, u) = (u_\omega - b,\ 0,\ R u_a - g\,e_{up})$ on SO(3) x R^3 x R^3: the attitude turns with
    the gyro less its bias, the bias is constant, the world velocity integrates the specific force rotated to the
    world less gravity ``gravity`` (m/s^2)."""

    gravity: float

    def __call__(self, g, u, t):
        R = g.factors[0].as_matrix()
        b = g.factors[1].x
        return jnp.concatenate([u[:3] - b, jnp.zeros(3), mv(R, u[3:6]) - jnp.asarray((0.0, 0.0, self.gravity))])


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
        dip: the magnetic dip (rad): structure.
        gravity: $g$ (m/s^2), the accelerometer's norm at rest (:func:`rest_norms`): structure.
        field: $B$ (uT), the undisturbed field's norm: structure.
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


K0_GYRO_BIAS = np.diag([0.05**2] * 3 + [0.01**2] * 3)
"""A K0 for :func:`attitude_gyro_bias` from a TRIAD estimate at rest (:func:`initial_estimate`): (0.05 rad)^2 on
the attitude and (0.01 rad/s)^2 on an unknown bias; ``liemef compare broad``'s."""

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


def rest_norms(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> tuple[float, float]:
    """The medians of the accelerometer's and the magnetometer's norms over samples at rest (their units):
    ``gravity`` and ``field`` of :func:`attitude_imu` (rows with a NaN are skipped)."""
    a = np.linalg.norm(np.atleast_2d(np.asarray(acc, dtype=np.float64)), axis=1)
    m = np.linalg.norm(np.atleast_2d(np.asarray(mag, dtype=np.float64)), axis=1)
    a, m = a[np.isfinite(a) & (a > 0)], m[np.isfinite(m) & (m > 0)]
    if a.size == 0 or m.size == 0:
        raise ValueError("acc, mag: expected samples at rest with finite, non-zero vectors, got none")
    return float(np.median(a)), float(np.median(m))


# --- helpers for recorded IMU data ----------------------------------------------------------------------------
def _unit_rows(name: str, v) -> np.ndarray:
    a = _validate.array(name, np.atleast_2d(np.asarray(v, dtype=np.float64)), (None, 3), missing=True)
    n = np.linalg.norm(a, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, a / n, np.nan)


def magnetic_dip(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> float:
    r"""The magnetic dip (rad) from accelerometer and magnetometer samples taken at rest (any units).

    At rest the normalized accelerometer reads up, $a = R^\top e_{up}$, so the angle between $a$ and the field
    direction $m$ is $90° + \delta$: $\delta = \arcsin(-a \cdot m)$, the median over the samples (rows with a
    NaN are skipped).
    """
    a, m = _unit_rows("acc", acc), _unit_rows("mag", mag)
    if a.shape != m.shape:
        raise ValueError(f"mag: expected the shape of acc {a.shape}, got {m.shape}")
    s = -np.sum(a * m, axis=1)
    s = s[np.isfinite(s)]
    if s.size == 0:
        raise ValueError("acc, mag: expected at least one sample with both vectors finite and non-zero, got none")
    return float(np.median(np.arcsin(np.clip(s, -1.0, 1.0))))


REST_WINDOW = 0.5
"""Default window (s) of :func:`initial_rest`."""
REST_GYRO_TOL = 0.1
"""Default gyro tolerance (rad/s) of :func:`initial_rest`: the rms gyro norm over a window at rest stays below it
(BROAD's seven trials at rest: at most 0.061 rad/s over 0.5 s, bias and noise together)."""
REST_ACC_TOL = 0.5
"""Default accelerometer tolerance (m/s^2) of :func:`initial_rest`: the rms spread of the accelerometer vector about
its window mean stays below it at rest (BROAD at rest: at most 0.30 m/s^2 over 0.5 s)."""


def initial_rest(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], rate: float, *,
                 window: float = REST_WINDOW, gyro_tol: float = REST_GYRO_TOL, acc_tol: float = REST_ACC_TOL) -> int:
    r"""The length ``k`` (samples) of a log's initial rest, from the IMU samples alone: samples ``[0, k)``.

    A window of ``window`` s (``w = round(window * rate)`` samples, at least 2) is *still* when the rms of the gyro
    norm over it is below ``gyro_tol`` (rad/s; it includes the gyro's bias, so a bias near it needs a higher
    tolerance) and the rms distance of the accelerometer vectors from their window mean is below ``acc_tol``
    (the accelerometer's units, m/s^2: it sees a change of the norm and of the direction alike). The rest ends at
    the first sample of the first window that is not still: every sample before it lies in a still window, and the
    motion that ended it lies within the ``window`` s after it, so the detected rest ends up to ``window`` s early,
    never late. On BROAD's seven trials the defaults end the rest 0.08 to 0.26 s before the dataset's movement
    annotation (``tests/test_attitude_bias.py``). A row with a NaN counts as absent; a window without two
    present rows is not still.

    A log whose every window is still is all rest (``k`` = N: the caller sees it). A log that does not start at
    rest (its first window is not still) or is shorter than one window is a ValueError naming ``gyr`` and
    ``acc`` with the first window's figures.
    """
    gyr = _validate.array("gyr", np.asarray(gyr, dtype=np.float64), (None, 3), missing=True)
    acc = _validate.array("acc", np.asarray(acc, dtype=np.float64), (gyr.shape[0], 3), missing=True)
    for name, v, unit in (("rate", rate, "a sample rate > 0 in Hz"), ("window", window, "a duration > 0 in s"),
                          ("gyro_tol", gyro_tol, "a tolerance > 0 in rad/s"),
                          ("acc_tol", acc_tol, "a tolerance > 0 in m/s^2")):
        number = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        if not (number and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected {unit}, got {v!r}")
    N, w = gyr.shape[0], max(2, int(round(window * rate)))
    if N < w:
        raise ValueError(f"gyr, acc: expected a log of at least one window ({w} samples, {window} s at {rate} Hz) "
                         f"to find its initial rest, got {N} samples")
    ok = np.all(np.isfinite(gyr), axis=1) & np.all(np.isfinite(acc), axis=1)
    g, a = np.where(ok[:, None], gyr, 0.0), np.where(ok[:, None], acc, 0.0)

    def window_sums(x):
        c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
        return c[w:] - c[:-w]

    n = window_sums(ok.astype(np.float64))
    m = np.maximum(n, 1.0)
    gyro_rms = np.sqrt(window_sums(np.sum(g**2, axis=1)) / m)
    mean = window_sums(a) / m[:, None]
    spread = np.sqrt(np.maximum(window_sums(np.sum(a**2, axis=1)) / m - np.sum(mean**2, axis=1), 0.0))
    still = (n >= 2) & (gyro_rms < gyro_tol) & (spread < acc_tol)
    if not still[0]:
        raise ValueError(f"gyr, acc: expected a log that starts at rest (a first window of {window} s with an rms gyro "
                         f"norm < gyro_tol = {gyro_tol} rad/s and an accelerometer spread < acc_tol = {acc_tol} "
                         f"m/s^2), got {gyro_rms[0]:.3g} rad/s and {spread[0]:.3g} m/s^2 over {int(n[0])} present "
                         "samples; measure gravity, field and dip on samples at rest yourself (rest_norms, "
                         "magnetic_dip)")
    return N if still.all() else int(np.argmin(still))


def rest_constants(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
                   rate: float, **tolerances) -> dict:
    """The structural constants of :func:`attitude_imu` and :func:`attitude_velocity` measured over a log's initial
    rest, found from the IMU samples alone (:func:`initial_rest`, with its ``tolerances``): ``dip`` (rad,
    :func:`magnetic_dip`), ``gravity`` (m/s^2) and ``field`` (uT) (:func:`rest_norms`), and the rest's extent
    ``rest_samples`` and ``rest_s`` (s), so that a study can say what its filters were given."""
    k = initial_rest(gyr, acc, rate, **tolerances)
    acc, mag = np.asarray(acc, dtype=np.float64)[:k], np.asarray(mag, dtype=np.float64)[:k]
    gravity, field = rest_norms(acc, mag)
    return {"dip": magnetic_dip(acc, mag), "gravity": gravity, "field": field, "rest_samples": k,
            "rest_s": k / float(rate)}


def log_rest_constants(ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N m"], ys: Float[ArrayLike, "N p"],
                       **tolerances) -> dict:
    """:func:`rest_constants` of a filter log with the raw norms (:func:`imu_log` with ``norms=True``, for
    :func:`attitude_imu`, or :func:`imu_velocity_log`): the gyro is ``us[:, :3]``, the accelerometer and the
    magnetometer are their directions ``ys[:, 0:6]`` times their norms ``ys[:, 6:8]``, the rate is the inverse of
    the median interval of ``ts``. A ValueError naming ``us``, ``ys`` or ``ts`` for a log without these columns."""
    ts = _validate.array("ts", np.asarray(ts, dtype=np.float64), (None,))
    us = _validate.array("us", np.asarray(us, dtype=np.float64), (ts.shape[0], None), missing=True)
    ys = _validate.array("ys", np.asarray(ys, dtype=np.float64), (ts.shape[0], None), missing=True)
    if us.shape[1] < 3 or ys.shape[1] < 8:
        raise ValueError(f"us, ys: expected the gyro in us[:, :3] and the directions and norms in ys[:, :8], got "
                         f"{us.shape[1]} input and {ys.shape[1]} output columns")
    dt = np.diff(ts)
    if ts.shape[0] < 2 or not np.median(dt) > 0:
        raise ValueError(f"ts: expected increasing times, got {ts.shape[0]} samples with median interval "
                         f"{float(np.median(dt)) if dt.size else float('nan')}")
    acc, mag = ys[:, 0:3] * ys[:, 6:7], ys[:, 3:6] * ys[:, 7:8]
    return rest_constants(us[:, :3], acc, mag, 1.0 / float(np.median(dt)), **tolerances)


def triad(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> Float[np.ndarray, "N 3 3"]:
    r"""Rotations body -> ENU from accelerometer and magnetometer vectors (TRIAD, trusting gravity first).

    The rows of $R$ are the world axes seen in the body frame: $R^\top e_{up} = \bar a$ (the normalized
    accelerometer), $R^\top e_{north}$ = the part of the field orthogonal to it, normalized, and
    $R^\top e_{east}$ = north x up. The dip does not enter. Rows with a NaN, or with a field parallel to gravity,
    give NaN.
    """
    up = _unit_rows("acc", acc)
    m = _unit_rows("mag", mag)
    if up.shape != m.shape:
        raise ValueError(f"mag: expected the shape of acc {up.shape}, got {m.shape}")
    north = m - np.sum(m * up, axis=1, keepdims=True) * up
    n = np.linalg.norm(north, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        north = np.where(n > 1e-9, north / n, np.nan)
    return np.stack([np.cross(north, up), north, up], axis=1)


def initial_estimate(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"], bias=(0.0, 0.0, 0.0)) -> TSO3:
    """A TSO(3) estimate ``(R, b)`` from the first accelerometer and magnetometer samples (at rest): TRIAD of
    their means (one sample or N), and the bias ``bias`` (rad/s; e.g. the mean gyro reading at rest)."""
    a = np.nanmean(_unit_rows("acc", acc), axis=0)
    m = np.nanmean(_unit_rows("mag", mag), axis=0)
    R = triad(a, m)[0]
    if not np.all(np.isfinite(R)):
        raise ValueError(f"acc, mag: expected finite, non-parallel vectors, got mean directions {a.tolist()} and "
                         f"{m.tolist()}")
    b = _validate.array("bias", np.asarray(bias, dtype=np.float64), (3,))
    return TSO3((SO3.from_matrix(jnp.asarray(R)), R3(jnp.asarray(b))))


def measured_state(ys: Float[ArrayLike, "N 6"]) -> Float[np.ndarray, "N 6"]:
    """State coordinates read off the measurements ``ys = (acc, mag)`` (N, 6): the TRIAD attitude's rotation
    vector where both directions are present, NaN elsewhere; the bias is not measured (NaN)."""
    ys = np.asarray(ys, dtype=np.float64)
    R = triad(ys[:, 0:3], ys[:, 3:6])
    ok = np.all(np.isfinite(R), axis=(1, 2))
    out = np.full((ys.shape[0], 6), np.nan)
    if ok.any():
        out[ok, :3] = np.asarray(SO3.from_matrix(jnp.asarray(R[ok])).log())
    return out


def imu_log(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
            rate: float, t0: float = 0.0, *, norms: bool = False,
            gyro: Literal["forward", "backward"] = "forward") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""A filter log ``(ts, us, ys)`` from raw IMU columns (BROAD's ``imu_gyr``, ``imu_acc``, ``imu_mag``).

    ``ts = t0 + k / rate`` (a uniform clock), ``us`` the gyro (N, 3) in rad/s, ``ys`` the normalized
    accelerometer and magnetometer (N, 6) in the order of :func:`attitude_gyro_bias`'s sensors; a NaN or a zero
    vector is a missing sample (NaN). ``norms=True`` appends the raw norms ``(|acc|, |mag|)`` (N, 8), the
    ``norm`` sensor of :func:`attitude_imu`.

    ``gyro`` says which interval a gyro sample measures. ``"forward"``: sample k is the rate over
    $[t_k, t_{k+1})$, the library's input convention (``us[k]`` = sample k). ``"backward"``: sample k is the rate
    over $(t_{k-1}, t_k]$, as an IMU that averages over its sample period reports it, and as VQF and BROAD
    integrate it ($q_k = q_{k-1} \otimes \exp(\omega_k T)$, BROAD's truth aligned to that): ``us[k]`` = sample
    k + 1 (the last one is held). At fast rotation the choice moves the estimate by one sample's turn (3.4 deg
    at 17 rad/s and 286 Hz).
    """
    _validate.choice("gyro", gyro, {"forward", "backward"})
    gyr = _validate.array("gyr", np.asarray(gyr, dtype=np.float64), (None, 3), missing=True)
    N = gyr.shape[0]
    a, m = _unit_rows("acc", acc), _unit_rows("mag", mag)
    for name, v in (("acc", a), ("mag", m)):
        if v.shape[0] != N:
            raise ValueError(f"{name}: expected {N} rows (as gyr), got {v.shape[0]}")
    if not (isinstance(rate, int | float) and math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate: expected a sample rate > 0 in Hz, got {rate!r}")
    ts = float(t0) + np.arange(N) / float(rate)
    if gyro == "backward":
        gyr = np.concatenate([gyr[1:], gyr[-1:]], axis=0)
    ys = [a, m]
    if norms:
        n = [np.linalg.norm(np.asarray(v, dtype=np.float64), axis=1, keepdims=True) for v in (acc, mag)]
        ys += [np.where(np.isfinite(v) & (v > 0), v, np.nan) for v in n]
    return ts, gyr, np.concatenate(ys, axis=1)


def quaternion_to_tso3(quat_wxyz: Float[ArrayLike, "N 4"], bias=None) -> TSO3:
    """TSO(3) elements (batch N) from unit quaternions ``(w, x, y, z)`` body -> world (e.g. BROAD's
    ``opt_quat``) and biases (N, 3) (default 0); NaN rows stay NaN."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    b = np.zeros(q.shape[:-1] + (3,)) if bias is None else np.asarray(bias, dtype=np.float64)
    return TSO3((SO3(jnp.asarray(q)), R3(jnp.asarray(b))))


def attitude_error(R_true: Float[ArrayLike, "N 3 3"], R_hat: Float[ArrayLike, "N 3 3"]) -> Float[np.ndarray, " N"]:
    r"""The total attitude error angle (rad) of $E = \hat R R^\top$ per row, as BROAD's total error, by
    ``atan2(sin, cos)`` (accurate at small angles, unlike ``arccos``); NaN rows stay NaN."""
    R_true, R_hat = np.asarray(R_true, dtype=np.float64), np.asarray(R_hat, dtype=np.float64)
    E = R_hat @ np.swapaxes(R_true, -1, -2)
    s = 0.5 * np.linalg.norm(np.stack([E[..., 2, 1] - E[..., 1, 2], E[..., 0, 2] - E[..., 2, 0],
                                       E[..., 1, 0] - E[..., 0, 1]], -1), axis=-1)
    c = 0.5 * (np.trace(E, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)
