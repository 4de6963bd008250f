r"""Attitude with magnetic disturbances that last: the field's disturbance as a state with memory.

:func:`~liemef.systems.attitude_velocity` weighs each magnetometer sample by the inverse of its variance, which
grows with the sample's norm and dip errors (:class:`~liemef.systems.imu_noise.MagneticNoise`). A magnet
beside the path for a minute disturbs every one of the 17 000 samples of that minute by the same field, so the
samples' errors are not independent: however much each is down-weighted, their sum pulls the heading. The model
here says what the disturbance is: a field added to the earth's, with its own dynamics.

**State** $g = (R, b, v, w, c)$ on SO(3) x R^3 x R^3 x R^3 x R^3: :func:`attitude_velocity`'s attitude, gyro
bias and world velocity, then

* $w$ (uT, world frame): a disturbance fixed in the world, e.g. iron or a magnet beside the path; it changes
  only as the IMU moves through it;
* $c$ (uT, body frame): a disturbance that turns with the IMU, e.g. a magnet attached to it (hard iron).

**Measurement**: the raw magnetometer vector (uT), $h = R^\top(B\,m_{ref} + w) + c$, with $B\,m_{ref} =
(0, B\cos\delta, -B\sin\delta)$ the undisturbed field (ENU, north = +y). Its noise is heading first
(:class:`FieldNoise`: extra stds along the sample's dip and norm, the accelerometer being the reference for tilt),
with the sample's accelerometer direction as its covariate, a constant-output sensor ``acc`` as in
:func:`attitude_velocity`. The third sensor is the bounded velocity's pseudo-measurement $v = 0$.

**Dynamics of the disturbances**: each relaxes to zero, $\dot w = -w/\tau_w$, $\dot c = -c/\tau_c$, driven by
a process noise that *grows with the part of the disturbance no attitude explains*:

$$Q_w = \mathrm{diag}(q_{w,e}^2, q_{w,n}^2, q_{w,u}^2) + k_w^2\, e^2\,\frac{x}{1 + x}\, I_3,\qquad
Q_c = q_c^2 I_3 + k_c^2\, e^2\,\frac{x}{1 + x}\, I_3,$$

$$e^2 = (|f| - B)^2 + (f_{up} + B\sin\delta)^2,\qquad x = (e/e_0)^4,$$

with $f = B\,m_{ref} + w + R c$ the estimated field in the world frame. No attitude changes the norm of $f$ or
its vertical part (a heading error turns $f$ about the vertical), so $e$ is the part of the estimated
disturbance that only a disturbance explains.

* Undisturbed, the east component of $w$, the one a heading error imitates (the field points north), is stiff
  ($q_{w,e}$ small): the magnetometer keeps the heading. North and up follow the field's slow changes of norm
  and dip along a path ($q_{w,n}$, $q_{w,u}$ larger), at no cost to the heading.
* A magnet changes the field's norm or dip by more than $e_0$: north and up take the change, $e$ grows, and with
  it the process noise of $w$ in every direction. The east component becomes free too, so the disturbance's
  share of the heading goes to $w$, and the gyro holds the heading for as long as the disturbance lasts.
* When the field returns, $e$ falls below $e_0$, $w$ stiffens, and $-w/\tau_w$ (a short $\tau_w$) hands what is
  left of it, the heading the gyro lost meanwhile, back to the magnetometer within seconds.

It is smooth in the state: no threshold, no switch; VQF's rejection of a disturbed field, written as a process.
The body disturbance $c$ is a slow hard-iron offset by default ($k_c = 0$): a world disturbance that grows also
absorbs a magnet attached to the IMU, and two disturbances that grow together let their difference, which only
the rotation observes, wander.

Theorem 4.1 allows a process noise that depends on the state: it enters the Hamiltonian as
$\mu^\top B R^{-1} B^\top\mu$, whose derivatives in $g$ vanish with the costate at the estimate, so the filters
evaluate it at their estimate (:meth:`~liemef.systems.AbstractSystem.process_noise_at`), exactly.

The log is :func:`imu_field_log`'s: ``us`` = (gyro, accelerometer) (N, 6), ``ys`` = (accelerometer direction,
magnetometer in uT, zero velocity) (N, 9). Measure the undisturbed field's norm $B$ and dip $\delta$ and gravity
over the log's initial rest (:func:`~liemef.systems.imu_rest.rest_constants`). They, the noise levels, $q_w$,
$q_c$, $k_w$, $k_c$, $e_0$, $\tau_w$ and $\tau_c$ are array leaves: a new set never recompiles.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from .._linalg import mv
from ..groups import R3, SO3, Product
from ._sensors import ConstantOutput, Noise, Sensor, SensorSystem, parameter
from .attitude_bias import DIP, E_UP, IMU_RATE, magnetic_reference, measured_state
from .bounded_velocity import ACC_DENSITY, VELOCITY_GYRO_STD, VELOCITY_STD, imu_velocity_log
from .imu_noise import FIELD, GRAVITY, IMU_BIAS_WALK
from .imu_rest import log_arrays, rest_constants

FieldGroup = Product[SO3, R3, R3, R3, R3]
"""SO(3) x R^3 x R^3 x R^3 x R^3: attitude, gyro bias, velocity, world and body disturbance."""
STATE_NAMES = ("rx", "ry", "rz", "bx", "by", "bz", "vx", "vy", "vz", "wx", "wy", "wz", "cx", "cy", "cz")
STATE_UNITS = ("rad",) * 3 + ("rad/s",) * 3 + ("m/s",) * 3 + ("uT",) * 6
INPUT_NAMES = ("gyro_x", "gyro_y", "gyro_z", "force_x", "force_y", "force_z")

FIELD_STD = 1.0
"""Default std of one magnetometer sample (uT): a few times a MEMS magnetometer's noise (BROAD at rest: 0.1-0.3
uT), for its calibration errors in motion."""
WORLD_DENSITY = (0.002, 0.5, 0.5)
r"""Default $q_w$ (uT/sqrt(s)), east, north and up (the undisturbed field points north): the east component is
the one a heading error imitates (1 deg is 0.27 uT of it at Berlin's 15.6 uT horizontal field), stiff, so
that the magnetometer keeps the heading; the field's norm and dip change along an indoor path by uT (BROAD: 41.6
uT at rest and 44.4 uT in motion in trial 01), which north and up follow within seconds at no cost to the
heading."""
BODY_DENSITY = 0.002
r"""Default $q_c$ (uT/sqrt(s)): a hard-iron offset's drift (temperature)."""
WORLD_GAIN = 5.0
r"""Default $k_w$ (1/sqrt(s)): once disturbed by $e$ = 20 uT, $w$ moves by 100 uT/sqrt(s) in every direction."""
BODY_GAIN = 0.0
r"""Default $k_c$ (1/sqrt(s)): 0, the body disturbance does not grow. A world disturbance that grows absorbs a
magnet attached to the IMU too (it turns with the IMU, which a free $w$ follows), and two that grow together
let their difference, which only the rotation observes, wander (measured on BROAD)."""
DISTURBANCE = 12.0
r"""Default $e_0$ (uT): the size of an unexplained departure of the field from which it is a disturbance (the
growth is $k^2 e^2\,x/(1 + x)$, $x = (e/e_0)^4$): 28 % of Berlin's field. Smaller, the field's changes along a
path free the heading where nothing disturbs it (in BROAD, 2-4 uT)."""
WORLD_TAU = 2.0
r"""Default $\tau_w$ (s): how fast what is left of a world disturbance relaxes once the field is back. It is
short: a lasting disturbance holds $w$ at the cost $|w|^2/(\tau_w^2 Q_w)$, small while $Q_w$ is large, and once
the field is back what is left in $w$ is the heading the gyro lost meanwhile, which then returns to the
heading within seconds."""
BODY_TAU = 600.0
r"""Default $\tau_c$ (s): a hard-iron offset lasts."""
DIP_STD = 5.0
"""Default extra std (uT) of a magnetometer sample along its dip (:class:`FieldNoise`): the field's dip varies
by degrees indoors (1 deg is 0.75 uT at 43 uT)."""
NORM_STD = 5.0
"""Default extra std (uT) of a magnetometer sample along its norm (:class:`FieldNoise`)."""

class FieldDynamics(eqx.Module):
    r"""$\lambda = (u_\omega - b,\ 0,\ R u_a - g\,e_{up},\ -w/\tau_w,\ -c/\tau_c)$; every constant a leaf."""

    gravity: Float[Array, ""] = eqx.field(converter=parameter)
    tau_w: Float[Array, ""] = eqx.field(converter=parameter)
    tau_c: Float[Array, ""] = eqx.field(converter=parameter)

    def __call__(self, g, u, t):
        R = g.factors[0].as_matrix()
        b, w, c = g.factors[1].x, g.factors[3].x, g.factors[4].x
        return jnp.concatenate([u[:3] - b, jnp.zeros(3), mv(R, u[3:6]) - jnp.asarray((0.0, 0.0, self.gravity)),
                                -w / self.tau_w, -c / self.tau_c])


class DisturbedField(eqx.Module):
    r"""$h = R^\top(B\,m_{ref} + w) + c$ (uT), ``field`` the undisturbed $B\,m_{ref}$ in ENU (a leaf)."""

    field: Float[Array, "3"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        R = g.factors[0].as_matrix()
        return mv(jnp.swapaxes(R, -1, -2), self.field + g.factors[3].x) + g.factors[4].x


@dataclasses.dataclass(frozen=True)
class FieldNoise:
    r"""The magnetometer's noise given the sample: heading first. A field sample $m$ (uT) with the accelerometer's
    up direction $\bar u$ in the same row has three directions: $t_1 = \bar u\times\bar m/|\cdot|$, along which
    a heading change moves it; $t_2 = \bar m\times t_1$, a change of dip (which a tilt error imitates); and
    $\bar m$, its norm. Indoors the field's dip and norm vary along a path by more than its direction about the
    vertical, and the accelerometer is the reference for tilt, so the noise is
    $\Sigma = \sigma^2 I + \sigma_{dip}^2\, t_2 t_2^\top + \sigma_{norm}^2\, \bar m\bar m^\top$.
    ``params = (sigma_dip, sigma_norm)`` (uT); returns $T$ with $T^\top T = \sigma^2\Sigma^{-1}$. ``acc`` and
    ``mag`` are the indices of $\bar u$ and $m$ in the sample."""

    acc: int
    mag: int

    def __call__(self, std, params, y):
        u, m = y[self.acc:self.acc + 3], y[self.mag:self.mag + 3]
        nm = jnp.sqrt(m @ m)
        m = m / jnp.where(nm > 0, nm, 1.0)
        t1 = jnp.cross(u, m)
        n1 = jnp.sqrt(t1 @ t1)
        t1 = t1 / jnp.where(n1 > 1e-9, n1, 1.0)
        t2 = jnp.cross(m, t1)
        s2 = std[0] ** 2
        a = 1.0 - jnp.sqrt(s2 / (s2 + params[0] ** 2))
        b = 1.0 - jnp.sqrt(s2 / (s2 + params[1] ** 2))
        return jnp.eye(3) - a * jnp.outer(t2, t2) - b * jnp.outer(m, m)


def _velocity(g, t):
    return g.factors[2].x


class FieldSystem(SensorSystem):
    r"""A :class:`~liemef.systems.SensorSystem` on :data:`FieldGroup` whose disturbances' process noise grows
    with the part of the disturbance no attitude explains (:meth:`process_noise_at`). ``gains`` = $(k_w, k_c,
    e_0)$ (1/sqrt(s), 1/sqrt(s), uT), array leaves (:meth:`with_gains`); ``reference`` = $B\,m_{ref}$ (uT, ENU),
    a leaf."""

    gains: Float[Array, "3"]
    reference: Float[Array, "3"]

    def __init__(self, base: SensorSystem, gains, reference):
        super().__init__(base.group, base.dynamics_fn, base.sensors, base.process_noise, base.noise_map,
                         inputs=base.inputs, input_units=base.input_units, state_names=base.coord_names,
                         state_units=base.coord_units)
        self.gains = jnp.asarray(gains, dtype=float)
        self.reference = parameter(reference)

    def process_noise_at(self, g, BRB, u, t):
        r"""$B R^{-1} B^\top$ with the world block's variance plus $k_w^2 e^2 x/(1 + x)$ and the body block's plus
        $k_c^2 e^2 x/(1 + x)$, $x = (e/e_0)^4$: $e$ the disturbance's heading-invariant size, the norm and the
        vertical part of the estimated field's departure from the reference (module docstring)."""
        R = g.factors[0].as_matrix()
        f = self.reference + g.factors[3].x + mv(R, g.factors[4].x)
        B = jnp.sqrt(self.reference @ self.reference)
        e2 = (jnp.sqrt(f @ f) - B) ** 2 + (f[2] - self.reference[2]) ** 2
        x2 = (e2 / self.gains[2] ** 2) ** 2
        e2 = e2 * x2 / (1.0 + x2)
        add = jnp.concatenate([jnp.zeros(9), jnp.full(3, self.gains[0] ** 2 * e2),
                               jnp.full(3, self.gains[1] ** 2 * e2)])
        return BRB + jnp.diag(add)

    def with_gains(self, world=None, body=None, disturbance=None) -> FieldSystem:
        """A copy with new $k_w$, $k_c$ (1/sqrt(s), >= 0) or $e_0$ (uT, > 0); None keeps one. Same structure: a
        filter of the copy reuses the compiled code."""
        s = [self.gains[0] if world is None else _validate.nonnegative("world", world),
             self.gains[1] if body is None else _validate.nonnegative("body", body),
             self.gains[2] if disturbance is None else _validate.positive("disturbance", disturbance)]
        return eqx.tree_at(lambda m: m.gains, self, jnp.asarray(s, dtype=float))


def attitude_field(gyro_std=VELOCITY_GYRO_STD, imu_rate: float | None = IMU_RATE, bias_walk=IMU_BIAS_WALK,
                   field_std=FIELD_STD, dip: float = DIP, *, gravity: float = GRAVITY, field: float = FIELD,
                   acc_density=ACC_DENSITY, velocity_std=VELOCITY_STD, world_density=WORLD_DENSITY,
                   body_density=BODY_DENSITY, world_gain: float = WORLD_GAIN, body_gain: float = BODY_GAIN,
                   world_tau: float = WORLD_TAU, body_tau: float = BODY_TAU, dip_std: float = DIP_STD,
                   norm_std: float = NORM_STD, disturbance: float = DISTURBANCE) -> FieldSystem:
    r"""Attitude, gyro bias, velocity and the magnetic field's world and body disturbances (module docstring).

    Args:
        gyro_std: the gyro's std per sample at ``imu_rate`` (rad/s), or a density if ``imu_rate`` is None.
        imu_rate: the IMU rate (Hz) the gyro std refers to.
        bias_walk: the gyro bias random walk density (rad/s/sqrt(s)).
        field_std: the std of one magnetometer sample (uT; one value or 3).
        dip: the undisturbed field's dip (rad, positive down).
        gravity: $g$ (m/s^2), the accelerometer's norm at rest.
        field: $B$ (uT), the undisturbed field's norm.
        acc_density: the accelerometer's noise density (m/s^2/sqrt(Hz)).
        velocity_std: the zero-velocity pseudo measurement's density (m/s sqrt(s)).
        world_density: $q_w$ (uT/sqrt(s); one value, or east, north and up), the world disturbance's process
            noise undisturbed.
        body_density: $q_c$ (uT/sqrt(s)), the body disturbance's.
        world_gain, body_gain: $k_w$, $k_c$ (1/sqrt(s), >= 0), their growth with the disturbance $e$.
        disturbance: $e_0$ (uT), the size of $e$ from which the growth sets in.
        world_tau, body_tau: $\tau_w$, $\tau_c$ (s), their relaxation times.
        dip_std, norm_std: the magnetometer's extra stds (uT) along its dip and its norm (:class:`FieldNoise`),
            leaves (``with_scale_params(mag=...)``).

    K0 guidance: the disturbances' blocks in uT^2, small, e.g. (0.1 uT)^2, when the reference is the field measured
    where the log starts: a large one frees the heading at rest (w and c imitate a heading error there).
    """
    if not (isinstance(dip, int | float) and math.isfinite(dip) and abs(dip) <= math.pi / 2):
        raise ValueError(f"dip: expected a magnetic dip in radians within [-pi/2, pi/2], got {dip!r}")
    for name, v in (("gravity", gravity), ("field", field), ("world_tau", world_tau), ("body_tau", body_tau)):
        _validate.positive(name, v)
    gains = [_validate.nonnegative("world_gain", world_gain), _validate.nonnegative("body_gain", body_gain),
             _validate.positive("disturbance", disturbance)]
    gyro = Noise.density(gyro_std) if imu_rate is None else Noise.sample(gyro_std, imu_rate)
    parts = {"bias_walk": Noise.density(bias_walk), "acc_density": Noise.density(acc_density),
             "world_density": Noise.density(world_density), "body_density": Noise.density(body_density)}
    bad = [n for n, p in {"gyro_std": gyro, **parts}.items() if p.dim not in (1, 3)]
    if bad:
        raise ValueError(f"{', '.join(bad)}: expected 1 or 3 stds each, got "
                         f"{[({'gyro_std': gyro, **parts})[n].dim for n in bad]}")
    density = jnp.concatenate([jnp.broadcast_to(gyro.density_std("gyro_std"), (3,))]
                              + [jnp.broadcast_to(p.std, (3,)) for p in parts.values()])
    xyz = ("x", "y", "z")
    B = tuple(float(field) * x for x in magnetic_reference(float(dip)))
    for name, v in (("dip_std", dip_std), ("norm_std", norm_std)):
        _validate.nonnegative(name, v)
    acc = Sensor("acc", ConstantOutput(E_UP), Noise.sample(1.0), xyz, ("1",) * 3)
    mag = Sensor("mag", DisturbedField(B), Noise.sample(field_std), xyz, ("uT",) * 3, scale=FieldNoise(0, 3),
                 scale_params=[float(dip_std), float(norm_std)])
    vel_noise = Noise.density(velocity_std)
    if vel_noise.dim not in (1, 3):
        raise ValueError(f"velocity_std: expected 1 or 3 stds, got {vel_noise.dim}")
    vel = Sensor("velocity", _velocity, Noise.density(jnp.broadcast_to(vel_noise.std, (3,))), xyz, ("m/s",) * 3)
    base = SensorSystem(FieldGroup, FieldDynamics(float(gravity), float(world_tau), float(body_tau)), (acc, mag, vel),
                        Noise.density(density), inputs=INPUT_NAMES, input_units=("rad/s",) * 3 + ("m/s^2",) * 3,
                        state_names=STATE_NAMES, state_units=STATE_UNITS)
    return FieldSystem(base, gains, B)


def imu_field_log(gyr: Float[ArrayLike, "N 3"], acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"],
                  rate: float, t0: float = 0.0, *, gyro: str = "backward") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The log of :func:`attitude_field` from raw IMU columns: ``us`` = (gyro, accelerometer) (N, 6) in the
    sample convention ``gyro`` (:func:`~liemef.systems.attitude_bias.imu_log`), ``ys`` = (accelerometer direction,
    magnetometer (uT), zero velocity) (N, 9); a NaN or zero row is a missing sample."""
    ts, us, ys = imu_velocity_log(gyr, acc, mag, rate, t0, gyro=gyro)
    m = _validate.array("mag", np.asarray(mag, dtype=np.float64), (us.shape[0], 3), missing=True)
    m = np.where(np.isfinite(ys[:, 3:4]), m, np.nan)  # the rows imu_log calls missing
    return ts, us, np.concatenate([ys[:, :3], m, ys[:, 8:]], axis=1)


K0_FIELD = np.diag([0.05**2] * 3 + [0.01**2] * 3 + [0.1**2] * 3 + [0.1**2] * 6)
"""A K0 for :func:`attitude_field` from a TRIAD estimate at rest:
:data:`~liemef.systems.bounded_velocity.K0_VELOCITY`'s blocks and (0.1 uT)^2 on each disturbance (the reference
is the field measured over the initial rest, where the run starts); ``liemef compare broad``'s."""


def field_measured_state(ys: Float[ArrayLike, "N 9"]) -> Float[np.ndarray, "N 15"]:
    """State coordinates of :func:`attitude_field` read off its log's ``ys`` (:func:`imu_field_log`): the TRIAD
    attitude of the accelerometer direction and the field (uT) where both are present; the bias, the velocity and
    the disturbances are not measured (NaN)."""
    ys = np.asarray(ys, dtype=np.float64)
    return np.concatenate([measured_state(ys[:, :6]), np.full((ys.shape[0], 9), np.nan)], axis=1)


def field_log_rest_constants(ts: Float[ArrayLike, " N"], us: Float[ArrayLike, "N 6"], ys: Float[ArrayLike, "N 9"],
                             **tolerances) -> dict:
    """:func:`~liemef.systems.imu_rest.rest_constants` of an :func:`imu_field_log` log: the gyro and the
    accelerometer are ``us``, the field (uT) is ``ys[:, 3:6]``, the rate the inverse of the median interval of
    ``ts``. A ValueError naming ``us``, ``ys`` or ``ts`` for a log without these columns."""
    us, ys, rate = log_arrays(ts, us, ys, 6, 6, "the gyro and the accelerometer in us[:, :6] and the field in "
                                                "ys[:, 3:6]")
    return rest_constants(us[:, :3], us[:, 3:6], ys[:, 3:6], rate, **tolerances)


def attitude_field_state(g, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), c=(0.0, 0.0, 0.0)):
    """The :func:`attitude_field` state from an attitude-and-bias estimate (e.g.
    :func:`~liemef.systems.imu_rest.initial_estimate`), a velocity (m/s) and the disturbances (uT)."""
    parts = [R3(jnp.asarray(_validate.array(n, np.asarray(x, dtype=np.float64), (3,))))
             for n, x in (("v", v), ("w", w), ("c", c))]
    return FieldGroup((g.factors[0], g.factors[1], *parts))
