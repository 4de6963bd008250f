r"""Attitude on SO(3) from an IMU without biases: the gyro as the input, the gravity and magnetic field vectors as
the sensors. This is the model of ukfm's attitude benchmark (Brossard, Barrau & Bonnabel, ukfm, BSD-3: its
``ATTITUDE`` model and ``benchmarks/attitude.py``; after Kok, Hol & Schön 2017, Sec. IV).

State $C \in SO(3)$, the rotation body -> world. The world frame is ukfm's: gravity along $-z$ and the magnetic
field's horizontal part along $+x$, i.e. x north, y west, z up (NWU). The algebra is the body-frame rotation
vector (rad). Input $u = \tilde\omega$, the gyro (rad/s, body frame); kinematics $C^\top\dot C =
[\tilde\omega]_\times$, i.e. $\lambda(C, u) = u$. The gyro's noise is the model error: $B = s_g I_3$ with the
density $s_g$ (docs/weights.md). ukfm's discrete step $C_{n+1} = C_n \mathrm{Exp}(\tilde\omega_n\,dt)$ is this
kinematics with the input held over the step, exactly.

Sensors (body frame; each sample carries its information once, ``Noise.sample``):

* ``acc``: $h = C^\top g$ with $g = (0, 0, -g_0)$, in m/s^2: ukfm's accelerometer model. It is the gravity vector
  seen in the body frame, which is **minus** the specific force a real accelerometer at rest reads ($+g_0$ along
  the body axis that points up): negate a real accelerometer's samples before feeding them to this system, or
  use :func:`~liemef.systems.attitude_imu`. There is no linear acceleration in the model.
* ``mag``: $h = C^\top b$ with ukfm's field $b = (0.33, 0, -0.95)$ (unitless; called "normed" in ukfm, but
  $|b| = 1.0057$): the field points north and down, with a dip of $\arctan(0.95/0.33) = 70.8°$ (Sweden).

Default noise levels are those of ukfm's benchmark, per sample at ``IMU_RATE`` = 100 Hz: gyro ``GYRO_STD`` = 5 deg/s
= 0.0873 rad/s (a density of 0.00873 rad/s/sqrt(Hz), 0.5 deg/s/sqrt(Hz)), accelerometer ``ACC_STD`` = 0.4 m/s^2 and
magnetometer ``MAG_STD`` = 0.3 per component (ukfm's tutorial example uses 0.2 for the magnetometer). Gravity
``GRAVITY`` = 9.82 m/s^2 and the field ``FIELD`` are ukfm's too. They and the noise levels are array leaves
(:meth:`~liemef.systems.SensorSystem.with_noise`): a new value never compiles the filter's XLA program anew,
nor its C kernel unless the value has new exact zeros (a field with a zero component after one without).

K0 guidance: K is the covariance of the left error $\xi$ with $C = \hat C \exp\xi$, three small rotation angles
about the body axes (rad). ukfm's benchmark starts with 10 deg per axis: ``K0 = (0.1745 rad)^2 I3``. From a first
accelerometer and magnetometer sample, :func:`initial_estimate` gives the TRIAD attitude; its error is a few
degrees at these noise levels (about ``acc_std / g0`` in tilt and ``mag_std / 0.33`` in yaw, rad).
"""

from __future__ import annotations

import math
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from .._linalg import mv
from ..groups import SO3
from ._sensors import Noise, Sensor, SensorSystem, parameter
from .imu_rest import triad

IMU_RATE = 100.0
"""Default IMU rate (Hz), ukfm's ``imu_freq``."""
GYRO_STD = math.radians(5.0)
"""Default gyro noise std per sample at ``IMU_RATE`` (rad/s): ukfm's 5 deg/s."""
ACC_STD = 0.4
"""Default accelerometer noise std per sample and component (m/s^2), ukfm's."""
MAG_STD = 0.3
"""Default magnetometer noise std per sample and component (unitless), ukfm's benchmark (its example: 0.2)."""
GRAVITY = 9.82
"""Default gravity magnitude (m/s^2), ukfm's; the vector is ``(0, 0, -GRAVITY)``."""
FIELD = (0.33, 0.0, -0.95)
"""Default magnetic field in the world frame (unitless), ukfm's ``b``."""

INPUT_NAMES = ("gyro_x", "gyro_y", "gyro_z")
STATE_NAMES = ("rx", "ry", "rz")
STATE_UNITS = ("rad", "rad", "rad")


def gyro_dynamics(g, u, t):
    r"""$\lambda(C, u) = u$: the gyro is the body angular velocity."""
    return u


class BodyVector(eqx.Module):
    r"""$h(C) = C^\top v$: the fixed world vector ``v`` (a leaf) seen in the body frame of a plain SO(3) state."""

    v: Float[Array, "3"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        return mv(jnp.swapaxes(g.as_matrix(), -1, -2), self.v)


def _vector(name: str, value) -> tuple[float, float, float]:
    v = _validate.array(name, np.asarray(_validate.numeric(name, value), dtype=np.float64), (3,))
    if not np.linalg.norm(v) > 0:
        raise ValueError(f"{name}: expected a nonzero vector (3,), got {v.tolist()}")
    return tuple(float(c) for c in v)


def ukfm_attitude(gyro_std=GYRO_STD, imu_rate: float | None = IMU_RATE, acc_std=ACC_STD, mag_std=MAG_STD,
                  gravity: float = GRAVITY, field=FIELD) -> SensorSystem:
    """The SO(3) attitude system of ukfm's benchmark: gyro input, gravity and magnetic field vectors as the
    sensors (module docstring).

    Args:
        gyro_std: gyro noise std per sample at ``imu_rate`` (rad/s; one value or 3), or a density
            (rad/s/sqrt(Hz)) if ``imu_rate`` is None.
        imu_rate: the IMU rate (Hz) the gyro std refers to.
        acc_std: std of one accelerometer sample (m/s^2; one value or 3).
        mag_std: std of one magnetometer sample (the field's units; one value or 3).
        gravity: the magnitude g0 (m/s^2) of the gravity vector ``(0, 0, -g0)``.
        field: the magnetic field in the world frame (3,), in the magnetometer's units.

    ``B = gyro density I3`` with ``R = I``; ``D = diag(acc_std, mag_std)`` with ``Q = I``.
    """
    g0 = _validate.positive("gravity", gravity)
    b = _vector("field", field)
    process = Noise.density(gyro_std) if imu_rate is None else Noise.sample(gyro_std, imu_rate)
    if process.dim not in (1, 3):
        raise ValueError(f"gyro_std: expected 1 or 3 stds, got {process.dim}")
    xyz = ("x", "y", "z")
    acc = Sensor("acc", BodyVector((0.0, 0.0, -g0)), Noise.sample(acc_std), xyz, ("m/s^2",) * 3)
    mag = Sensor("mag", BodyVector(b), Noise.sample(mag_std), xyz, ("1",) * 3)
    return SensorSystem(SO3, gyro_dynamics, (acc, mag), process, inputs=INPUT_NAMES, input_units=("rad/s",) * 3,
                        state_names=STATE_NAMES, state_units=STATE_UNITS)


def triad_nwu(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> Float[np.ndarray, "N 3 3"]:
    """Rotations body -> world (ukfm's NWU frame) from this system's accelerometer (the gravity vector, pointing
    down) and magnetometer samples: TRIAD trusting gravity first (:func:`~liemef.systems.imu_rest.triad` on
    ``-acc`` gives east-north-up axes with north along the field, turned here to north-west-up). Rows with a
    NaN, or with a field parallel to gravity, give NaN."""
    acc = _validate.array("acc", np.atleast_2d(_validate.numeric("acc", acc)), (None, 3), missing=True)
    enu = triad(-acc, mag)  # rows: east, north (the field), up in the body frame
    return np.stack([enu[:, 1], -enu[:, 0], enu[:, 2]], axis=1)  # north, west = up x north, up


def initial_estimate(acc: Float[ArrayLike, "N 3"], mag: Float[ArrayLike, "N 3"]) -> SO3:
    """An SO(3) estimate from the first accelerometer and magnetometer samples (one sample or N at rest): the
    TRIAD attitude (:func:`triad_nwu`) of their means."""
    a, m = (_validate.array(name, np.atleast_2d(_validate.numeric(name, v)), (None, 3), missing=True)
            for name, v in (("acc", acc), ("mag", mag)))
    with warnings.catch_warnings():  # a column without a sample: NaN, refused below
        warnings.simplefilter("ignore", RuntimeWarning)
        a, m = np.nanmean(a, axis=0), np.nanmean(m, axis=0)
    R = triad_nwu(a[None], m[None])[0]
    if not np.all(np.isfinite(R)):
        raise ValueError(f"acc, mag: expected finite, non-parallel vectors, got means {a.tolist()} and {m.tolist()}")
    return SO3.from_matrix(jnp.asarray(R))


def measured_state(ys: Float[ArrayLike, "N 6"]) -> Float[np.ndarray, "N 3"]:
    """State coordinates read off the measurements ``ys = (acc, mag)`` (N, 6): the TRIAD attitude's rotation
    vector where both vectors are present, NaN elsewhere."""
    ys = _validate.array("ys", np.asarray(ys, dtype=np.float64), (None, 6), missing=True)
    R = triad_nwu(ys[:, 0:3], ys[:, 3:6])
    ok = np.all(np.isfinite(R), axis=(1, 2))
    out = np.full((ys.shape[0], 3), np.nan)
    if ok.any():
        out[ok] = np.asarray(SO3.from_matrix(jnp.asarray(R[ok])).log())
    return out
