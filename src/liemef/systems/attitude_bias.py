r"""Attitude with gyro bias on TSO(3) = SO(3) x R^3: an IMU's gyro as the input, gravity and magnetic field
directions as the sensors (the AHRS problem, e.g. the BROAD benchmark's logs), and the log of the family.

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
  from samples at rest with :func:`~liemef.systems.imu_rest.magnetic_dip`.

The default noise levels are a MEMS IMU's at the BROAD rate (285.714 Hz), each a std per sample at ``imu_rate``
(a density is std / sqrt(rate)) or a density where named so; the direction stds are above the sensors' own noise,
because their errors in motion (linear acceleration, magnetic disturbances) are not white, and set the filter's
correction bandwidth, the role of Madgwick's beta or Mahony's Kp (docs/imu.md). The magnetic dip and the noise
levels are array leaves (:class:`BodyDirection`, :meth:`~liemef.systems.SensorSystem.with_noise`): a new dip, a
recording's, never compiles the filter anew. Each sensor may have a gate, a robust loss and
``max_rejections`` (:class:`~liemef.systems.Sensor`).

Fast rotation: a ``Noise.sample`` direction is held over the interval that follows it, against an estimate that
turns meanwhile, which lags the estimate by about half a sample's turn. With ``directions="density"`` (the same
weight on a uniform IMU clock) and a filter with ``interpolation="linear"``, gyro and directions are
interpolated between samples (``tests/test_attitude_bias.py``).

K0: K is the covariance of the left error $\xi$ with $g = \hat g \exp\xi$, the rotation error in rad in the body
frame, then the bias error in rad/s (:data:`K0_GYRO_BIAS` from a TRIAD estimate at rest). A stiff first sample
(``||K E|| dt`` about 10 at the default acc std) is split by the filter's default ``substeps="auto"``; with
``integrator="lie-euler"`` fast rotation needs many more sub-steps than ``"auto"`` chooses: prefer RKMK4.
"""

from __future__ import annotations

import math
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from .._linalg import mv
from ..groups import R3, SO3, TSO3
from ._sensors import Noise, Sensor, SensorSystem, parameter
from .imu_rest import _unit_rows, triad

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


class BodyDirection(eqx.Module):
    r"""$h(g) = R^\top v$: the fixed world direction ``v`` seen in the body frame. ``v`` is a leaf: every
    direction (a recording's dip) is one compiled structure."""

    v: Float[Array, "3"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        R = g.factors[0].as_matrix()
        return mv(jnp.swapaxes(R, -1, -2), self.v)


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


K0_GYRO_BIAS = np.diag([0.05**2] * 3 + [0.01**2] * 3)
"""A K0 for :func:`attitude_gyro_bias` from a TRIAD estimate at rest
(:func:`~liemef.systems.imu_rest.initial_estimate`): (0.05 rad)^2 on the attitude and (0.01 rad/s)^2 on an
unknown bias; ``liemef compare broad``'s."""


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
