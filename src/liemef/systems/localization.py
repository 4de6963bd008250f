r"""Planar localization on SE(2): a wheeled robot with odometry as the input and position fixes (GPS).

State $g = (\theta, x, y) \in$ SE(2) (heading and world position; algebra order $(\omega, v_x, v_y)$).
Input $u = (v_x, v_y, \omega)$: body-frame forward and lateral speed (m/s) and yaw rate (rad/s), as wheel
odometry or an odometry + gyro pair gives them (the order of ukfm's 2D localization benchmark). Kinematics
$g^{-1}\dot g = \lambda(u) = (\omega, v_x, v_y)$: $\dot\theta = \omega$, $\dot p = R(\theta) v$. The odometry's
noise is the model error, $B = \mathrm{diag}(\sigma_\omega, \sigma_{v_x}, \sigma_{v_y})$ as densities.

Sensor ``gps``: the position $(x, y)$ in metres, one sample per fix (``Noise.sample``: each fix carries its
information once, however fast the filter runs).

Default noise levels are those of the ukfm benchmark (``../shared/scenarios/ukfm_localization.md``): odometry
0.01 m/s, 0.01 m/s and 1 deg/s per sample at 100 Hz, GPS 1 m. K0 guidance: K is the covariance of the left
error $\xi$ with $g = \hat g \exp\xi$, in (rad, m, m) of the body frame: start from your prior,
e.g. ``diag(sigma_theta0^2, sigma_p0^2, sigma_p0^2)``; a heading known to 45 deg gives (0.785 rad)^2. A zero
entry is allowed (a coordinate known exactly).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ..groups import SE2
from ._sensors import Noise, Sensor, SensorSystem

ODOMETRY_STD = (math.pi / 180.0, 0.01, 0.01)
"""Default odometry noise per sample, in the algebra's order: yaw rate (rad/s), forward and lateral speed (m/s)."""
ODOMETRY_RATE = 100.0
"""Default odometry rate (Hz)."""
GPS_STD = 1.0
"""Default GPS std per fix (m)."""


def odometry_dynamics(g, u, t):
    r"""$\lambda(g, u) = (\omega, v_x, v_y)$ from $u = (v_x, v_y, \omega)$."""
    return jnp.stack([u[2], u[0], u[1]])


def gps_position(g, t):
    """The world position ``(x, y)`` of the robot."""
    return g.cos_sin_xy[..., 2:4]


def planar_localization(odometry_std=ODOMETRY_STD, odometry_rate: float | None = ODOMETRY_RATE,
                        gps_std=GPS_STD, *, gate: float | None = None, robust: str | None = None,
                        max_rejections: int | None = None) -> SensorSystem:
    """The SE(2) localization system with odometry input and GPS fixes (see the module docstring).

    Args:
        odometry_std: (yaw rate rad/s, forward m/s, lateral m/s) stds of one odometry sample at
            ``odometry_rate`` Hz, or densities if ``odometry_rate`` is None.
        gps_std: std of one GPS fix (m), one value or (x, y).
        gate: the GPS sensor's chi-square gate probability (:class:`~liemef.systems.Sensor`).
        robust: ``"huber"`` or ``"cauchy"`` down-weighting of GPS outliers.
        max_rejections: consecutive rejected fixes that make the run fail (cause ``gate``).
    """
    process = Noise.density(odometry_std) if odometry_rate is None else Noise.sample(odometry_std, odometry_rate)
    gps = Sensor("gps", gps_position, Noise.sample(gps_std), ("x", "y"), ("m", "m"), gate=gate, robust=robust,
                 max_rejections=max_rejections)
    return SensorSystem(SE2, odometry_dynamics, (gps,), process, inputs=("v_x", "v_y", "omega"),
                        input_units=("m/s", "m/s", "rad/s"), state_names=("theta", "x", "y"),
                        state_units=("rad", "m", "m"))
