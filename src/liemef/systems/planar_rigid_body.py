r"""Planar rigid body on TSE(2) = SE(2) x R^3 (Rigo, Segala, Saccon, ... 2022; Segala poster).

State $(g, \Omega)$ with $g = (\theta, x, y) \in$ SE(2) and body velocities $\Omega = (\omega, v_x, v_y)$;
input $u = (u_\omega, u_v)$ (torque, forward force). Left-trivialized dynamics (Rigo et al. 2022, eqs. (7)-(8),
(11)): $\lambda = (\Omega,\ (u_\omega / J,\ \omega v_y + u_v/m,\ -\omega v_x))$, model error $B\delta = (0, B_2\delta)$.

Sensors (``sensor=``):

* ``"gps_imu"`` (Rigo et al. 2022, eq. (13)): two GPS antennas at $\pm\ell$ along the body x axis,
  $(x \pm \ell\cos\theta,\ y \pm \ell\sin\theta)$, plus an IMU measuring $(\omega, v_x, v_y)$; p = 7.
* ``"velocity"`` (Segala poster): the IMU alone, $(\omega, v_x, v_y)$; p = 3. The pose is then dead-reckoned.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from ..groups import R3, SE2, TSE2
from ._base import AbstractSystem, matrix

Sensor = Literal["gps_imu", "velocity"]
SENSORS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "gps_imu": (("x1", "y1", "x2", "y2", "omega", "vx", "vy"), ("m", "m", "m", "m", "rad/s", "m/s", "m/s")),
    "velocity": (("omega", "vx", "vy"), ("rad/s", "m/s", "m/s")),
}
"""Output names and units of each sensor."""


class PlanarRigidBody(AbstractSystem):
    """The planar rigid body of Rigo et al. 2022 with its GPS + IMU (or IMU-only) sensor.

    Defaults are the paper's Section VI: J = 6.125 kg m^2, m = 125 kg, l = 0.2 m, B2 = 0.1 I3, R = B^T B,
    D = diag(0.5 x4, 0.1 x3), Q = D^T D (for ``"velocity"``: D = 0.1 I3, Q = D^T D).
    """

    J: float = 6.125
    m: float = 125.0
    l: float = 0.2
    sensor: Sensor = eqx.field(static=True, default="gps_imu")
    B: Float[Array, "6 3"] = eqx.field(converter=matrix, default=None)
    D: Float[Array, "p p"] = eqx.field(converter=matrix, default=None)
    Q: Float[Array, "p p"] = eqx.field(converter=matrix, default=None)
    R: Float[Array, "3 3"] = eqx.field(converter=matrix, default=None)

    def __init__(self, J=6.125, m=125.0, l=0.2, sensor: Sensor = "gps_imu", B=None, D=None, Q=None, R=None):
        if sensor not in SENSORS:
            raise ValueError(f"sensor: expected one of {sorted(SENSORS)}, got {sensor!r}")
        self.J, self.m, self.l = _validate.positive("J", J), _validate.positive("m", m), _validate.positive("l", l)
        self.sensor = sensor
        B = np.vstack([np.zeros((3, 3)), 0.1 * np.eye(3)]) if B is None else B
        D = (np.diag([0.5] * 4 + [0.1] * 3) if sensor == "gps_imu" else 0.1 * np.eye(3)) if D is None else D
        self.B, self.D = matrix(B), matrix(D)
        self.Q = matrix(self.D.T @ self.D if Q is None else Q)
        self.R = matrix(self.B.T @ self.B if R is None else R)

    @property
    def group(self):
        """TSE(2) = SE(2) x R^3; algebra coordinates: se(2) (omega, vx, vy), then the velocities (R^3)."""
        return TSE2

    @property
    def input_dim(self) -> int:
        """2: the torque u_omega and the forward force u_v."""
        return 2

    @property
    def output_names(self) -> tuple[str, ...]:
        """The antennas' (x1, y1, x2, y2) with ``"gps_imu"``, then the IMU's (omega, vx, vy)."""
        return SENSORS[self.sensor][0]

    @property
    def output_units(self) -> tuple[str, ...]:
        """m for the antennas, rad/s and m/s for the IMU."""
        return SENSORS[self.sensor][1]

    @property
    def state_names(self) -> tuple[str, ...]:
        """The pose (theta, x, y), then the body velocities (omega, vx, vy)."""
        return ("theta", "x", "y", "omega", "vx", "vy")

    @property
    def state_units(self) -> tuple[str, ...]:
        """rad, m, m, rad/s, m/s, m/s."""
        return ("rad", "m", "m", "rad/s", "m/s", "m/s")

    def dynamics(self, g, u, t):
        r"""$\lambda = (\Omega,\ (u_\omega / J,\ \omega v_y + u_v/m,\ -\omega v_x))$ (eqs. (8), (11))."""
        # Rigo et al. 2022, eqs. (8), (11)
        Omega = g.factors[1].x
        w, vx, vy = Omega[0], Omega[1], Omega[2]
        u_w, u_v = u[0], u[1]
        return jnp.concatenate([Omega, jnp.stack([u_w / self.J, w * vy + u_v / self.m, -w * vx])])

    def output(self, g, t):
        r"""The antennas $(x \pm \ell\cos\theta, y \pm \ell\sin\theta)$ and the IMU $\Omega$ (eq. (13));
        $\Omega$ alone with ``"velocity"``."""
        # Rigo et al. 2022, eq. (13)
        pose, Omega = g.factors[0], g.factors[1].x
        if self.sensor == "velocity":
            return Omega
        c, s = pose.cos_sin_xy[0], pose.cos_sin_xy[1]
        x, y = pose.cos_sin_xy[2], pose.cos_sin_xy[3]
        lc, ls = self.l * c, self.l * s
        return jnp.concatenate([jnp.stack([x + lc, y + ls, x - lc, y - ls]), Omega])


def tse2_state(theta, x, y, omega, vx, vy) -> TSE2:
    """A TSE(2) element from the papers' coordinates (theta, x, y, omega, vx, vy)."""
    return TSE2((SE2.from_coords(jnp.array([theta, x, y], dtype=jnp.float64)),
                 R3(jnp.array([omega, vx, vy], dtype=jnp.float64))))
