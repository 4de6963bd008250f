r"""Rigid-body attitude on TSO(3) = SO(3) x R^3 (Saccon et al. 2016, Section V).

State $(R, \Omega)$, body angular velocity $\Omega$; input the torque $\tau$. Left-trivialized dynamics
(eqs. (55)-(56)): $\lambda = (\Omega,\ \mathbb I^{-1}((\mathbb I\Omega) \times \Omega + \tau))$; model error
$B\delta = (0, B_2\delta)$.
Output (eq. (57)): two known inertial directions seen in the body frame, $(R^\top a_1, R^\top a_2)$; p = 6.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from ..groups import TSO3
from ._base import AbstractSystem, matrix

SIGMA_EPS = 0.5 / 3.0
SIGMA_DELTA = 1.0


class RigidBodyAttitude(AbstractSystem):
    """Saccon et al. 2016's rigid body with two direction sensors.

    Defaults are the paper's experiment: inertia diag(2, 5, 3), a1 = (0, 0, 1), a2 = (0, 1, 0),
    D = sigma_eps I6, B2 = sigma_delta I3, Q = sigma_eps^2 I6, R = sigma_delta^2 I3 (eqs. (84)-(85)).
    """

    inertia: Float[Array, "3 3"] = eqx.field(converter=matrix)
    a1: Float[Array, " 3"] = eqx.field(converter=matrix)
    a2: Float[Array, " 3"] = eqx.field(converter=matrix)
    B: Float[Array, "6 3"] = eqx.field(converter=matrix)
    D: Float[Array, "6 6"] = eqx.field(converter=matrix)
    Q: Float[Array, "6 6"] = eqx.field(converter=matrix)
    R: Float[Array, "3 3"] = eqx.field(converter=matrix)

    def __init__(self, inertia=None, a1=(0.0, 0.0, 1.0), a2=(0.0, 1.0, 0.0), B=None, D=None, Q=None, R=None):
        self.inertia = matrix(_validate.symmetric_psd("inertia", np.diag([2.0, 5.0, 3.0]) if inertia is None
                                                      else inertia, 3))
        self.a1, self.a2 = matrix(_direction("a1", a1)), matrix(_direction("a2", a2))
        self.B = matrix(np.vstack([np.zeros((3, 3)), SIGMA_DELTA * np.eye(3)]) if B is None else B)
        self.D = matrix(SIGMA_EPS * np.eye(6) if D is None else D)
        self.Q = matrix(SIGMA_EPS**2 * np.eye(6) if Q is None else Q)
        self.R = matrix(SIGMA_DELTA**2 * np.eye(3) if R is None else R)

    @property
    def group(self):
        """TSO(3) = SO(3) x R^3, algebra coordinates (eta_R; eta_Omega)."""
        return TSO3

    @property
    def input_dim(self) -> int:
        """3: the torque tau (body frame)."""
        return 3

    @property
    def output_names(self) -> tuple[str, ...]:
        """The body-frame components of R^T a1, then of R^T a2."""
        return ("a1x", "a1y", "a1z", "a2x", "a2y", "a2z")

    @property
    def output_units(self) -> tuple[str, ...]:
        """Metres, as the paper states sigma_eps (0.5/3 m), for all six components."""
        return ("m",) * 6  # Saccon et al. 2016, Sec. V: sigma_eps = 0.5/3 m

    @property
    def state_names(self) -> tuple[str, ...]:
        """The rotation vector (axis times angle) of R, then Omega."""
        return ("rx", "ry", "rz", "wx", "wy", "wz")

    @property
    def state_units(self) -> tuple[str, ...]:
        """rad for the rotation vector, rad/s for Omega."""
        return ("rad", "rad", "rad", "rad/s", "rad/s", "rad/s")

    @property
    def torque_noise(self) -> Float[Array, "3 3"]:
        r"""$\mathbb I B_2$: the model error $B_2\delta$ of eq. (60) seen as an error of the measured torque,
        $\tau + \mathbb I B_2 \delta$ (Saccon et al. 2016, eq. (81)); the ``input_noise`` of a simulation."""
        return self.inertia @ self.B[3:]

    def dynamics(self, g, u, t):
        r"""$\lambda = (\Omega,\ \mathbb I^{-1}((\mathbb I\Omega) \times \Omega + \tau))$ with $u = \tau$."""
        # Saccon et al. 2016, eqs. (55)-(56)
        Omega = g.factors[1].x
        I = self.inertia
        Omega_dot = jnp.linalg.solve(I, jnp.cross(I @ Omega, Omega) + u)
        return jnp.concatenate([Omega, Omega_dot])

    def output(self, g, t):
        r"""$(R^\top a_1, R^\top a_2)$: the two known inertial directions in the body frame."""
        # Saccon et al. 2016, eq. (57): R^T a_i
        Rt = g.factors[0].as_matrix().T
        return jnp.concatenate([Rt @ self.a1, Rt @ self.a2])


def _direction(name: str, v) -> np.ndarray:
    """A known direction: a finite nonzero 3-vector."""
    a = _validate.array(name, v, (3,))
    if not np.linalg.norm(a) > 0:
        raise ValueError(f"{name}: expected a nonzero direction, got {a}")
    return a
