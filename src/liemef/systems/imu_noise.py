r"""Attitude with gyro bias on TSO(3) with the IMU's real effects as a model of the direction sensors'
noise: :func:`attitude_imu`, the heteroscedastic extension of :func:`~liemef.systems.attitude_bias.attitude_gyro_bias`.

A sample's own norm says how far it is from the model: the accelerometer's noise grows with its norm's distance
from gravity (linear acceleration, :class:`AccelerationNoise`), the magnetometer's with its norm's and dip's
distance from the field's (disturbances, :class:`MagneticNoise`), and a ``norm`` sensor carries the raw norms.
Gravity, field and dip are measured at rest from the samples alone
(:func:`~liemef.systems.imu_rest.rest_constants`); they are array leaves, so a recording's values never compile
the filter anew.
"""

from __future__ import annotations

import math
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..groups import TSO3
from ._sensors import ConstantOutput, Noise, Sensor, SensorSystem, parameter
from .attitude_bias import (
    ACC_STD,
    DIP,
    GYRO_STD,
    IMU_RATE,
    INPUT_NAMES,
    MAG_STD,
    STATE_NAMES,
    STATE_UNITS,
    attitude_gyro_bias,
    gyro_bias_dynamics,
)

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


class AccelerationNoise(eqx.Module):
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

    norm: int = eqx.field(static=True)
    gravity: Float[Array, ""] = eqx.field(converter=parameter)

    def __call__(self, std, params, y):
        e = (y[self.norm] - self.gravity) / self.gravity
        s2 = std[0] ** 2
        return s2 / (s2 + params[0] ** 2 * e * e / (jnp.abs(e) + params[1]))


class MagneticNoise(eqx.Module):
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

    acc: int = eqx.field(static=True)
    mag: int = eqx.field(static=True)
    norm: int = eqx.field(static=True)
    field: Float[Array, ""] = eqx.field(converter=parameter)
    dip: Float[Array, ""] = eqx.field(converter=parameter)

    def __call__(self, std, params, y):
        a, m = y[self.acc:self.acc + 3], y[self.mag:self.mag + 3]
        e_norm = (y[self.norm] - self.field) / self.field
        e_dip = (-(a @ m) - jnp.sin(self.dip)) / jnp.cos(self.dip)
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

    ``gravity``, ``field`` and ``dip``, the stds and $c_a$, $c_m$ are leaves: a new value never compiles anew
    (:meth:`~liemef.systems.SensorSystem.with_noise`, :meth:`~liemef.systems.SensorSystem.with_scale_params`).
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
