r"""A gyro whose error grows with the rate it measures: a process noise that depends on the input.

A MEMS gyro reads $(I + M)\omega + b + n$. Besides the white noise $n$ and the bias $b$, its scale-factor errors
(M's diagonal) and cross-axis errors (M off its diagonal; 0.5-1 % each on a datasheet) make an error $M\omega$
that grows with the rate. Let M's nine entries be independent with std $s$: then
$E[M\omega\,\omega^\top M^\top] = s^2|\omega|^2 I_3$, the same in every direction whatever the axis of the turn
and the body frame. A diagonal $\mathrm{diag}(\omega_i^2)$ would be the scale factors alone, and would leave an
axis noiseless in a turn about another, which the cross-axis errors contradict. So the gyro's block of the
process-noise density is

$$\frac{\sigma_g^2 + s^2|u_\omega|^2}{f}\,I_3,$$

with $\sigma_g$ (``gyro_std``) and $s$ (``gyro_scale_std``, unitless) per sample at the IMU rate f, as the gyro's
white noise is given; with no rate (``imu_rate=None``) both are densities. $u_\omega$ is the gyro's sample, the
input: its bias is a few mrad/s, negligible where the term matters.

$M\omega$ is not white (M is nearly constant): the model covers it as white noise, as a tuned ``gyro_std`` does,
but only while the body turns. M itself as a state (``inertial_navigation(gyro_calibration=...)``) is the other
answer, and without positions it is not observable enough (docs/imu.md).

Theorem 4.1 allows it: the noise map B enters the Hamiltonian only through $\mu^\top B R^{-1} B^\top \mu$, and
B(u(t)) is a known function of time, so the filters use $B(u) R^{-1} B(u)^\top$ at each interval's input
(:meth:`~liemef.systems.AbstractSystem.process_noise_at`); the EKF and UKF baselines read the same.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import _validate
from ._sensors import SensorSystem


def gyro_scale_value(name: str, value):
    """``value`` as the float64 leaf of a scale std: one finite number >= 0 (``liemef._validate.nonnegative``),
    not a bool; a traced value passes unchecked."""
    if isinstance(value, jax.core.Tracer):
        return jnp.asarray(value, dtype=jnp.float64)
    if isinstance(value, bool):
        raise ValueError(f"{name}: expected a number >= 0 (unitless), got {value!r}")
    return jnp.asarray(_validate.nonnegative(name, value))


class GyroScaleSystem(SensorSystem):
    r"""A :class:`~liemef.systems.SensorSystem` whose gyro noise grows with the measured rate (module docstring):
    :meth:`process_noise_at` adds $s^2|u_\omega|^2/f$ to the diagonal of the gyro's block, $u_\omega$ the inputs
    ``gyro_at`` to ``gyro_at + 3`` and the block the algebra's rows ``rows_at`` to ``rows_at + 3``. ``gyro_scale``
    = $s$ is an array leaf (:meth:`with_gyro_scale`): a new value reuses the compiled filter."""

    gyro_scale: Float[Array, ""]
    scale_rate: float | None = eqx.field(static=True)
    gyro_at: int = eqx.field(static=True)
    rows_at: int = eqx.field(static=True)

    def __init__(self, base: SensorSystem, gyro_scale_std, imu_rate: float | None, *, gyro_at: int = 0,
                 rows_at: int = 0):
        super().__init__(base.group, base.dynamics_fn, base.sensors, base.process_noise, base.noise_map,
                         inputs=base.inputs, input_units=base.input_units, state_names=base.coord_names,
                         state_units=base.coord_units)
        if not (0 <= gyro_at <= len(base.inputs) - 3 and 0 <= rows_at <= base.group.tangent_dim - 3):
            raise ValueError(f"gyro_at, rows_at: expected a gyro of 3 inputs and 3 algebra rows within the "
                             f"system's {len(base.inputs)} inputs and {base.group.tangent_dim} rows, got {gyro_at} "
                             f"and {rows_at}")
        self.gyro_scale = gyro_scale_value("gyro_scale_std", gyro_scale_std)
        self.scale_rate = None if imu_rate is None else float(imu_rate)
        self.gyro_at, self.rows_at = int(gyro_at), int(rows_at)

    def process_noise_at(self, g, BRB, u, t):
        r"""$B R^{-1} B^\top$ plus $s^2|u_\omega|^2/f$ on the gyro block's diagonal."""
        w = u[self.gyro_at:self.gyro_at + 3]
        q = self.gyro_scale**2 * (w @ w)
        if self.scale_rate is not None:
            q = q / self.scale_rate
        i = jnp.arange(self.rows_at, self.rows_at + 3)
        return BRB.at[i, i].add(q)

    @property
    def constant_process_noise(self) -> bool:
        """Whether the scale is 0 (as a value, not traced): the noise is then the nominal at every input."""
        s = self.gyro_scale
        return not isinstance(s, jax.core.Tracer) and float(s) == 0.0

    def with_gyro_scale(self, gyro_scale_std) -> GyroScaleSystem:
        """A copy with a new scale std $s$ (>= 0, unitless): same structure, so a filter of the copy reuses the
        compiled code."""
        return eqx.tree_at(lambda m: m.gyro_scale, self, gyro_scale_value("gyro_scale_std", gyro_scale_std))
