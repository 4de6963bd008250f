r"""The Chaplygin sleigh on SE(2) x R^2 (Rigo, Sansonetto, Muradore 2023).

State $(g, V)$ with $g = (\theta, x, y) \in$ SE(2) the pose of the blade's contact point and $V = (\omega, v)$
the angular and forward velocities; the lateral velocity is constrained to zero (nonholonomic blade), so the
group velocity is $(\omega, v, 0)$. Algebra coordinates $(\eta^\theta, \eta^x, \eta^y; \eta^\omega, \eta^v)$.
Input $u = (u_\omega, u_v)$: torque about the contact point and forward force. Left-trivialized dynamics
(eqs. (20)-(21), from Hamel's equations (5)):

$$\lambda = \Big((\omega, v, 0),\ \big(-\tfrac{m a}{J + m a^2}\,\omega v + \tfrac{u_\omega}{J + m a^2},\
a\omega^2 + \tfrac{u_v}{m}\big)\Big),$$

model error $B\delta = (0, B_2\delta)$ on the velocities only (eq. (19)).

Sensors (``sensor=``), eq. (10):

* ``"gps_ins"``: two GPS antennas at $\pm\ell$ along the blade, $(x \pm \ell\cos\theta,\ y \pm \ell\sin\theta)$,
  plus an INS measuring $(\omega, v)$; p = 6.
* ``"gps"``: the antennas only (Remark 2); p = 4.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from ..groups import R2, SE2, SE2R2
from ._base import AbstractSystem, matrix

Sensor = Literal["gps_ins", "gps"]
SENSORS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "gps_ins": (("x1", "y1", "x2", "y2", "omega", "v"), ("m", "m", "m", "m", "rad/s", "m/s")),
    "gps": (("x1", "y1", "x2", "y2"), ("m", "m", "m", "m")),
}
"""Output names and units of each sensor."""
STATE_NAMES = ("theta", "x", "y", "omega", "v")
"""The state coordinates: the pose (theta, x, y), then the velocities (omega, v)."""
CONNECTIONS = ("zero", "minus")
"""The paper's two connections: (0) (lambda = 1/2, Prop. 1) and (-) (lambda = 0, Sec. 5; with :func:`constraint_K0`
it keeps the nonholonomic constraint)."""


class ChaplyginSleigh(AbstractSystem):
    """The Chaplygin sleigh of Rigo et al. 2023 with GPS + INS (or GPS-only) sensing.

    Defaults are the paper's Sec. 6: J = 6.125 kg m^2, m = 125 kg, a = 0.3 m, l = 0.2 m, B = [0; B2] with
    B2 = diag(10, 10), R = I2, D = diag(0.4 x4, 0.2, 0.2) (GPS only: 0.4 I4), Q = I (Sec. 4, text after
    eq. (26)). With Q = I the weighted innovation is D^-T Q D^-1 (y - h) = diag(q_i / d_i^2)(y - h), eq. (27).
    """

    J: float = 6.125
    m: float = 125.0
    a: float = 0.3
    l: float = 0.2
    sensor: Sensor = eqx.field(static=True, default="gps_ins")
    B: Float[Array, "5 2"] = eqx.field(converter=matrix, default=None)
    D: Float[Array, "p p"] = eqx.field(converter=matrix, default=None)
    Q: Float[Array, "p p"] = eqx.field(converter=matrix, default=None)
    R: Float[Array, "2 2"] = eqx.field(converter=matrix, default=None)

    def __init__(self, J=6.125, m=125.0, a=0.3, l=0.2, sensor: Sensor = "gps_ins", B=None, D=None, Q=None,
                 R=None):
        if sensor not in SENSORS:
            raise ValueError(f"sensor: expected one of {sorted(SENSORS)}, got {sensor!r}")
        self.J, self.m = _validate.positive("J", J), _validate.positive("m", m)
        self.a, self.l = _validate.real("a", a), _validate.positive("l", l)
        self.sensor = sensor
        p = len(SENSORS[sensor][0])
        B = np.vstack([np.zeros((3, 2)), 10.0 * np.eye(2)]) if B is None else B
        D = np.diag([0.4] * 4 + [0.2] * (p - 4)) if D is None else D
        self.B, self.D = matrix(B), matrix(D)
        self.Q = matrix(np.eye(p) if Q is None else Q)
        self.R = matrix(np.eye(2) if R is None else R)

    @property
    def group(self):
        """SE(2) x R^2, algebra coordinates (theta, x, y; omega, v)."""
        return SE2R2

    @property
    def input_dim(self) -> int:
        """2: the torque u_omega and the forward force u_v."""
        return 2

    @property
    def output_names(self) -> tuple[str, ...]:
        """The antennas' (x1, y1, x2, y2), then (omega, v) with the INS."""
        return SENSORS[self.sensor][0]

    @property
    def output_units(self) -> tuple[str, ...]:
        """m for the antennas, rad/s and m/s for the INS."""
        return SENSORS[self.sensor][1]

    @property
    def state_names(self) -> tuple[str, ...]:
        """The pose (theta, x, y), then the velocities (omega, v)."""
        return STATE_NAMES

    @property
    def state_units(self) -> tuple[str, ...]:
        """rad, m, m, rad/s, m/s."""
        return ("rad", "m", "m", "rad/s", "m/s")

    def dynamics(self, g, u, t):
        """The left-trivialized sleigh dynamics of eq. (21) (module docstring); lateral velocity zero."""
        # Rigo et al. 2023, eq. (21)
        V = g.factors[1].x
        w, v = V[0], V[1]
        Ja = self.J + self.m * self.a**2
        return jnp.stack([w, v, jnp.zeros_like(w),
                          -(self.m * self.a / Ja) * w * v + u[0] / Ja,
                          self.a * w**2 + u[1] / self.m])

    def output(self, g, t):
        r"""The antennas $(x \pm \ell\cos\theta, y \pm \ell\sin\theta)$, then $(\omega, v)$ with the INS (eq. (10))."""
        # Rigo et al. 2023, eq. (10)
        pose, V = g.factors[0], g.factors[1].x
        c, s = pose.cos_sin_xy[0], pose.cos_sin_xy[1]
        x, y = pose.cos_sin_xy[2], pose.cos_sin_xy[3]
        lc, ls = self.l * c, self.l * s
        gps = jnp.stack([x + lc, y + ls, x - lc, y - ls])
        return gps if self.sensor == "gps" else jnp.concatenate([gps, V])


def se2r2_state(theta, x, y, omega, v) -> SE2R2:
    """An SE(2) x R^2 element from the paper's coordinates (theta, x, y, omega, v)."""
    return SE2R2((SE2.from_coords(jnp.array([theta, x, y], dtype=jnp.float64)),
                  R2(jnp.array([omega, v], dtype=jnp.float64))))


def constraint_K0(diag=(1.0,) * 5) -> np.ndarray:
    """The constraint-preserving initial gain of Rigo et al. 2023, eq. (63): ``diag(diag)`` with the third row
    and column (the lateral velocity y of the group velocity) zeroed. With the (-)-connection (W = 0, A of
    eq. (60) with a zero third row) the third row and column of K stay zero, so the estimate's lateral velocity
    (lambda + K r)_y is exactly zero. (The printed ``1_{2x2}`` blocks read I2.)"""
    d = np.array(diag, dtype=np.float64)
    if d.shape != (5,):
        raise ValueError(f"diag: expected 5 numbers, got shape {d.shape}")
    d[2] = 0.0
    return np.diag(d)
