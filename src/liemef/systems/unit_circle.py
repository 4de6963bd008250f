r"""The unit circle with a biased gyro on SO(2) x R (Zamani, Hua, Trumpf, Mahony).

State $(X, b)$: the rotation $X = X(\theta) \in SO(2)$ and the gyro bias $b$; algebra coordinates
$(\theta; b)$. Input: the gyro reading $u = \omega + B_\omega v_\omega + b$ (eq. (7)); bias model
$\dot b = B_b v_b$ (eq. (8)). Left-trivialized dynamics $\lambda = (u - b,\ 0)$ and model error
$B\delta = (-B_\omega v_\omega,\ B_b v_b)$, $\delta = (v_\omega, v_b)$, R = I (cost
$\tfrac12(v_\omega^2 + v_b^2)$), so $B R^{-1} B^\top = \mathrm{diag}(Q_\omega, Q_b)$ with $Q_\omega = B_\omega^2$,
$Q_b = B_b^2$.

Measurements (``measurement=``):

* ``"vector"`` (eq. (9)): $y = X^\top (1, 0)^\top + D w = (\cos\theta, -\sin\theta) + D w$, cost
  $\tfrac12 |w|^2$ (Q = I), so the weighted innovation uses $(D D^\top)^{-1}$, the paper's $R^{-1}$;
* ``"angle"`` (eq. (11), Lemma 2): $y'' = \theta + w'$ with cost $1 - \cos w'$. Since
  $1 - \cos(y'' - \theta) = \tfrac12 |(\cos y'', -\sin y'') - X^\top (1, 0)^\top|^2$ exactly, the angle
  measurement is *represented through the vector output* with D = Q = I: feed the filter
  :meth:`UnitCircleBias.angle_to_vector` of each angle. This is Lemma 2's filter (eq. (40)) with the sign of
  its correction terms as in eq. (39) (the printed eq. (40) has them flipped, see ``docs/errata.md``), and it
  is the vector filter with D = I, which is the equivalence Lemma 2 states.

The paper's filter (eq. (39)) is Theorem 4.1 on this system with the gain $K = P^{-1}$ (P the paper's
information matrix); the group is abelian, so ad = 0, W = 0 and every connection gives the same filter.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from ..groups import SO2R1
from ._base import AbstractSystem, matrix

DEG = math.pi / 180.0
B_OMEGA = 17.0 * DEG
"""Zamani et al., Sec. IV: standard deviation of the gyro error v_omega, 17 deg per time unit (rad/s)."""
B_BIAS = 52.0 * DEG
"""Zamani et al., Sec. IV: standard deviation of the bias rate v_b, 52 deg per squared time unit (rad/s^2)."""
MEASUREMENTS = ("vector", "angle")


class UnitCircleBias(AbstractSystem):
    """Zamani et al.'s unit circle with gyro bias, with the vector (eq. (9)) or angle (eq. (11)) measurement.

    Defaults are the paper's simulation (Sec. IV): B_omega = 17 deg/s, B_b = 52 deg/s^2, D = 0.4 I for the
    vector measurement. The angle measurement has D = Q = I (Lemma 2; a ValueError otherwise).
    """

    measurement: str = eqx.field(static=True)
    B: Float[Array, "2 2"] = eqx.field(converter=matrix)
    D: Float[Array, "2 2"] = eqx.field(converter=matrix)
    Q: Float[Array, "2 2"] = eqx.field(converter=matrix)
    R: Float[Array, "2 2"] = eqx.field(converter=matrix)

    def __init__(self, measurement: str = "vector", B_omega: float = B_OMEGA, B_b: float = B_BIAS, D=None):
        _validate.choice("measurement", measurement, set(MEASUREMENTS))
        for name, v in (("B_omega", B_omega), ("B_b", B_b)):
            if _validate.nonnegative(name, v) == 0.0:
                raise ValueError(f"{name}: expected a number > 0, got {v}")
        if measurement == "angle":
            if D is not None and not np.array_equal(np.asarray(D, dtype=float), np.eye(2)):
                raise ValueError("D: the angle measurement (Lemma 2, cost 1 - cos) is the vector output with "
                                 f"D = I, got D = {np.asarray(D).tolist()}")
            D = np.eye(2)
        self.measurement = measurement
        self.B = matrix(np.diag([-float(B_omega), float(B_b)]))  # omega = u - b - B_omega v_omega, eq. (7)
        self.D = matrix(0.4 * np.eye(2) if D is None else D)
        self.Q = matrix(np.eye(2))
        self.R = matrix(np.eye(2))

    @property
    def group(self):
        """SO(2) x R, algebra coordinates (theta; b)."""
        return SO2R1

    @property
    def input_dim(self) -> int:
        """1: the gyro reading u (rad/s)."""
        return 1

    @property
    def state_names(self) -> tuple[str, ...]:
        """The angle theta and the gyro bias b."""
        return ("theta", "b")

    @property
    def state_units(self) -> tuple[str, ...]:
        """rad and rad/s."""
        return ("rad", "rad/s")

    @property
    def output_names(self) -> tuple[str, ...]:
        """The components of X^T (1, 0): cos(theta) and -sin(theta)."""
        return ("cos_theta", "minus_sin_theta")

    def dynamics(self, g, u, t):
        r"""$\lambda = (u - b,\ 0)$: the bias-corrected gyro rate; the bias is constant up to noise."""
        # Zamani et al., eqs. (1), (7), (8) without the unknown errors: theta_dot = u - b, b_dot = 0
        return jnp.stack([u[0] - g.factors[1].x[0], jnp.zeros(())])

    def output(self, g, t):
        r"""$X^\top (1, 0)^\top = (\cos\theta, -\sin\theta)$ (eq. (9))."""
        # Zamani et al., eq. (9): X^T (1, 0)^T
        return g.factors[0].as_matrix().T @ jnp.array([1.0, 0.0])

    @staticmethod
    def angle_to_vector(angle: Float[ArrayLike, "..."]) -> Float[Array, "... 2"]:
        r"""The vector measurement $(\cos y'', -\sin y'')$ that represents an angle measurement $y''$
        (Lemma 2: $1 - \cos(y'' - \theta) = \tfrac12 |(\cos y'', -\sin y'') - X^\top (1, 0)^\top|^2$)."""
        a = jnp.asarray(angle, dtype=jnp.float64)
        return jnp.stack([jnp.cos(a), -jnp.sin(a)], axis=-1)

    @staticmethod
    def vector_to_angle(y: Float[ArrayLike, "... 2"]) -> Float[Array, "..."]:
        """The angle read off a vector measurement, ``atan2(-y2, y1)`` in (-pi, pi]."""
        y = jnp.asarray(y, dtype=jnp.float64)
        return jnp.arctan2(-y[..., 1], y[..., 0])

    @staticmethod
    def state(theta: float, b: float) -> SO2R1:
        """The element (X(theta), b) of SO(2) x R."""
        return SO2R1.from_coords(jnp.array([theta, b], dtype=jnp.float64))
