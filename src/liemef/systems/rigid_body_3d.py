r"""A rigid body in space on SE(3): a body twist as the input, position fixes or full-pose fixes as the sensors.

State $g = (R, p) \in$ SE(3): $R$ the rotation body -> world, $p$ the world position (m); algebra order
$(\omega; v)$ (rotation first). Input $u = (\omega_x, \omega_y, \omega_z, v_x, v_y, v_z)$: the body-frame angular
velocity (rad/s) and linear velocity (m/s), as visual or wheel odometry with a gyro gives them. Kinematics
$g^{-1}\dot g = \lambda(u) = (\omega, v)$: $\dot R = R[\omega]_\times$, $\dot p = R v$. The twist's noise is the
model error, $B = \mathrm{diag}(s_\omega I_3, s_v I_3)$ as densities, in the body frame where it arises: the
left-trivialized $B$ rotates it into the world frame with the estimate, which a constant ``noise_map`` on
SO(3) x R^3 cannot.

Sensors:

* ``position`` (``fixes="position"`` or ``"pose"``): $h = p$, the world position (m), one sample per fix
  (``Noise.sample``), e.g. GNSS or a motion-capture marker.
* ``attitude`` (``fixes="pose"``): $h = \mathrm{vec}(R)$, the nine entries of the rotation matrix (row by row),
  from a full-pose fix such as motion capture or a map-matching pose. An attitude error $\varepsilon$ (rad, body
  frame) moves the columns of $R$ by $R(\varepsilon \times e_i)$, so independent entry noise of std
  $\sqrt 2\,\sigma$ carries exactly the information $I_3/\sigma^2$ on the rotation to first order
  ($\sum_i [e_i]_\times^\top [e_i]_\times = 2 I$): ``attitude_std`` is $\sigma$ in rad per axis, and the sensor's
  std per entry is $\sqrt 2\,\sigma$. To simulate the sensor, perturb $R$ by $\exp(\sigma\,\varepsilon)$ and read
  the entries (:func:`pose_fix`).

Default noise levels: a twist from odometry at 100 Hz with ``TWIST_STD`` = 0.01 rad/s per axis and 0.05 m/s per
axis per sample (densities 1e-3 rad/s/sqrt(Hz) and 5e-3 m/s/sqrt(Hz)); position fixes of ``POSITION_STD`` = 0.1 m
per axis (a motion-capture or RTK fix; use 1-3 m for plain GNSS), attitude fixes of ``ATTITUDE_STD`` = 0.02 rad
(1.1 deg) per axis.

K0 guidance: K is the covariance of the left error $\xi = (\xi_\omega, \xi_v)$ with $g = \hat g \exp\xi$: the
rotation error in rad and the position error in m, **both in the body frame** (for small errors $\xi_v \approx
\hat R^\top (p - \hat p)$). An attitude known to 10 deg and a position to 1 m give
``K0 = diag((0.17 rad)^2 I3, (1 m)^2 I3)``; the position variance does not depend on the frame when it is the same
on every axis. With position fixes only, the attitude is observable only while the body moves (the fixes constrain
the rotation through $\dot p = R v$).
"""

from __future__ import annotations

import math
from typing import Literal

import jax.numpy as jnp

from .. import _validate
from ..groups import SE3, SO3
from ._sensors import Noise, Sensor, SensorSystem

TWIST_STD = (0.01, 0.01, 0.01, 0.05, 0.05, 0.05)
"""Default twist noise per sample at ``TWIST_RATE``, in the algebra's order: angular (rad/s), linear (m/s)."""
TWIST_RATE = 100.0
"""Default twist (odometry) rate (Hz)."""
POSITION_STD = 0.1
"""Default std of one position fix (m, per axis)."""
ATTITUDE_STD = 0.02
"""Default std of the attitude of one pose fix (rad, per axis)."""

STATE_NAMES = ("rx", "ry", "rz", "x", "y", "z")
STATE_UNITS = ("rad", "rad", "rad", "m", "m", "m")
INPUT_NAMES = ("omega_x", "omega_y", "omega_z", "v_x", "v_y", "v_z")
INPUT_UNITS = ("rad/s",) * 3 + ("m/s",) * 3


def twist_dynamics(g, u, t):
    r"""$\lambda(g, u) = (\omega, v) = u$: the body twist is the left-trivialized velocity itself."""
    return u


def position(g, t):
    """The world position ``p`` (m)."""
    return g.translation()


def attitude_entries(g, t):
    """The nine entries of the rotation matrix R (body to world), row by row."""
    return g.rotation().as_matrix().reshape(9)


def pose_fix(g: SE3, attitude_noise, position_noise):
    """A simulated full-pose fix of ``g`` ``(12,)``: position plus ``position_noise`` (m, 3), then the entries of
    ``R exp(attitude_noise)`` (``attitude_noise`` in rad, body frame, 3): the sensor of ``fixes="pose"``."""
    R = (g.rotation() @ SO3.exp(jnp.asarray(attitude_noise))).as_matrix()
    return jnp.concatenate([g.translation() + jnp.asarray(position_noise), R.reshape(9)])


def pose3d(twist_std=TWIST_STD, twist_rate: float | None = TWIST_RATE, position_std=POSITION_STD,
           attitude_std=ATTITUDE_STD, *, fixes: Literal["position", "pose"] = "position",
           gate: float | None = None, robust: str | None = None) -> SensorSystem:
    """The SE(3) rigid body with a body-twist input and position or full-pose fixes (see the module docstring).

    Args:
        twist_std: stds of one twist sample at ``twist_rate`` Hz, (omega rad/s, v m/s): one value, 2 (angular,
            linear) or 6; densities (rad/s/sqrt(Hz), m/s/sqrt(Hz)) if ``twist_rate`` is None.
        twist_rate: the twist's rate (Hz).
        position_std: std of one position fix (m; one value or 3).
        attitude_std: std of the attitude of one pose fix (rad per axis, one value); used with
            ``fixes="pose"``.
        fixes: ``"position"`` (sensor ``position``) or ``"pose"`` (sensors ``position`` and ``attitude``).
        gate: the fixes' chi-square gate probability (:class:`~liemef.systems.Sensor`).
        robust: ``"huber"`` or ``"cauchy"`` down-weighting of outlying fixes.

    ``B = diag(twist density)`` with ``R = I``; ``D = diag(position_std, sqrt(2) attitude_std)`` with ``Q = I``.
    """
    _validate.choice("fixes", fixes, {"position", "pose"})
    std = jnp.atleast_1d(jnp.asarray(twist_std, dtype=jnp.float64))
    if std.shape not in ((1,), (2,), (6,)):
        raise ValueError(f"twist_std: expected 1, 2 (angular, linear) or 6 stds, got {std.shape[0]}")
    std = jnp.repeat(std, 3) if std.shape == (2,) else jnp.broadcast_to(std, (6,))
    process = Noise.density(std) if twist_rate is None else Noise.sample(std, twist_rate)
    xyz = ("x", "y", "z")
    sensors = [Sensor("position", position, Noise.sample(position_std), xyz, ("m",) * 3, gate=gate,
                      robust=robust)]
    if fixes == "pose":
        att = Noise.sample(attitude_std)
        if att.dim != 1:
            raise ValueError(f"attitude_std: expected one std (rad, the same on every axis), got {att.dim}")
        entries = math.sqrt(2.0) * att.std  # module docstring: sqrt(2) sigma per entry carries I / sigma^2
        sensors.append(Sensor("attitude", attitude_entries, Noise.sample(entries),
                              tuple(f"r{i}{j}" for i in range(1, 4) for j in range(1, 4)), ("1",) * 9,
                              gate=gate, robust=robust))
    return SensorSystem(SE3, twist_dynamics, sensors, process, inputs=INPUT_NAMES, input_units=INPUT_UNITS,
                        state_names=STATE_NAMES, state_units=STATE_UNITS)


