r"""Inertial navigation on $SE_2(3)$: gyro and accelerometer as the inputs, with gravity; position fixes, known
landmarks, a magnetometer and a barometer as the sensors; gyro and accelerometer biases as an option.

State $g = (R, v, p) \in SE_2(3)$ (:class:`~liemef.groups.SE23`): $R$ the attitude body -> world, $v$ and $p$
the world velocity (m/s) and position (m), in a local level frame with z up (ENU); algebra order
$(\omega; \nu_v; \nu_p)$. With ``biases=True`` the state is $SE_2(3) \times \mathbb R^6$, $(R, v, p; b_g, b_a)$, the
gyro bias (rad/s) and the accelerometer bias (m/s^2) in the body frame, algebra $(\omega; \nu_v; \nu_p; b_g; b_a)$.
With ``lever_arm=True`` the vector factor goes on with the lever arm $r$ (m, body frame) of the position fixes'
point from the IMU, a constant of the mount. With ``gyro_calibration``, it ends with the gyro's calibration
errors $M$, constants of the sensor: $\tilde\omega = (I + M)\omega + b_g + n_g$, with $M = \operatorname{diag}(s)$
for ``"scale"`` (3 scale-factor errors) or a full $3 \times 3$ matrix, row by row, for ``"matrix"`` (scale
factors on its diagonal, cross-axis sensitivities and misalignments off it: 9). None has process noise; all are
estimated as the body turns ($SE_2(3) \times \mathbb R^{6 + 3 + 9}$ with every option). A scale or cross-axis
error is what makes a MEMS gyro's error grow with the angle turned (0.5-3 % of it before calibration) rather
than with time; without its state the white gyro noise cannot account for it, and a filter whose heading no sensor
observes turns overconfident on every revolution.

Inputs $u = (\tilde\omega, \tilde a)$: the gyro (rad/s) and the accelerometer's specific force (m/s^2), body frame,
modelled as $\tilde\omega = \omega + b_g + n_g$, $\tilde a = R^\top(\dot v - g) + b_a + n_a$ with gravity
$g = (0, 0, -g_0)$. Kinematics $\dot R = R[\tilde\omega - b_g]_\times$, $\dot v = R(\tilde a - b_a) + g$,
$\dot p = v$, i.e. left-trivialized

$$\lambda(g, u) = \big(\tilde\omega - b_g,\ \tilde a - b_a + R^\top g,\ R^\top v\ (;\ 0,\ 0)\big),$$

because $g^{-1}\dot g$ has the blocks $R^\top \dot R$, $R^\top \dot v$ and $R^\top \dot p$. Model error
$B\delta$: the gyro noise on $\omega$, the accelerometer noise on $\nu_v$, nothing on $\nu_p$ (the position is
the integral of the velocity), and the bias random walks on the bias blocks, all as densities
(:class:`~liemef.systems.Noise`).

Sensors (any subset; ``gnss_std=None`` turns the position fixes off):

* ``gnss``: $h = p$, the world position (m), one sample per fix (GNSS-like; a motion-capture position too); with
  ``lever_arm=True``, $h = p + R r$, the position of a point rigidly mounted at $r$ from the IMU (a GNSS antenna,
  a motion-capture marker set's origin). Unmodelled, a lever arm of 1 cm turning at a few rad/s makes fixes whose
  error is neither white nor small beside a motion-capture fix, and ties the attitude to it.
* ``landmarks`` (given ``landmarks``, L known world points $\ell_i$): $h_i = R^\top(\ell_i - p)$, each landmark's
  position in the body frame (m), 3L components in landmark order (ukfm's inertial-navigation benchmark).
* ``mag`` (``mag_std`` given): $h = R^\top m_{ref}$, the normalized magnetometer (unitless), $m_{ref} =
  (0, \cos\delta, -\sin\delta)$ for the magnetic dip $\delta$ (as :func:`~liemef.systems.attitude_gyro_bias`).
* ``baro`` (``baro_std`` given): $h = p_z$, the altitude (m) above the frame's origin.

Default noise levels, in the sensors' units: gyro ``GYRO_STD`` = 0.01 rad/s and accelerometer ``ACC_STD`` = 0.01
m/s^2 per sample at ``IMU_RATE`` = 100 Hz (ukfm's benchmark; densities 1e-3 rad/s/sqrt(Hz), 1e-3
m/s^2/sqrt(Hz)); bias random walks ``GYRO_BIAS_WALK`` = 1e-4 rad/s/sqrt(s) and ``ACC_BIAS_WALK`` = 1e-3
m/s^2/sqrt(s) (densities; a MEMS IMU's biases drift by about 0.05 deg/s and 0.008 m/s^2 in a minute); a GNSS fix
``GNSS_STD`` = 1 m per axis; a landmark ``LANDMARK_STD`` = 0.1 m per axis (ukfm's); a magnetometer sample
``MAG_STD`` = 0.05 (unitless, as in :func:`~liemef.systems.attitude_gyro_bias`); a barometer sample
``BARO_STD`` = 0.5 m. A consumer MEMS IMU at 100-400 Hz is noisier: gyro about 0.003-0.01 rad/s and
accelerometer 0.02-0.1 m/s^2 per sample. Gravity ``GRAVITY`` = 9.81 m/s^2 (ukfm uses 9.82). Gravity, the
landmarks, the field's direction and the noise levels are array leaves (data): a new value never compiles the
filter's XLA program anew, nor its C kernel unless the value has new exact zeros (a landmark on the ground at
z = 0 after one above it; :meth:`~liemef.systems.SensorSystem.with_noise`); which sensors there are, and which
biases and calibration errors the state holds, are structure.

K0 guidance: K is the covariance of the left error $\xi$ with $g = \hat g \exp\xi$, in the body frame:
rotation (rad), then velocity and position (m/s, m, for small errors $\hat R^\top(v - \hat v)$ and
$\hat R^\top(p - \hat p)$), then the biases (rad/s, m/s^2). Start from your prior: ukfm's benchmark (15 deg, 1 m,
a known velocity) is ``diag((0.151 rad)^2 I3, eps I3, (0.577 m)^2 I3)``, with a small ``eps`` (1e-6) rather
than 0 if the velocity is only nearly known; unknown biases at rest ``(0.01 rad/s)^2`` and ``(0.1 m/s^2)^2``.
With position fixes alone the yaw is observable only under horizontal acceleration, and the biases only as the
attitude varies; a magnetometer or landmarks make the attitude observable at rest.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from .._linalg import mv, solve3
from ..groups import SE23, Product, Rn
from ._gyro_scale import GyroScaleSystem
from ._sensors import Noise, Sensor, SensorSystem, parameter
from .attitude_bias import DIP, magnetic_reference

IMU_RATE = 100.0
"""Default IMU rate (Hz)."""
GYRO_STD = 0.01
"""Default gyro noise std per sample at ``IMU_RATE`` (rad/s)."""
ACC_STD = 0.01
"""Default accelerometer noise std per sample at ``IMU_RATE`` (m/s^2)."""
GYRO_BIAS_WALK = 1e-4
"""Default gyro bias random walk density (rad/s/sqrt(s))."""
ACC_BIAS_WALK = 1e-3
"""Default accelerometer bias random walk density (m/s^2/sqrt(s))."""
GNSS_STD = 1.0
"""Default std of one position fix (m, per axis)."""
LANDMARK_STD = 0.1
"""Default std of one landmark observation (m, per axis)."""
MAG_STD = 0.05
"""Default std of one normalized magnetometer sample (unitless)."""
BARO_STD = 0.5
"""Default std of one barometric altitude (m)."""
GRAVITY = 9.81
"""Default gravity magnitude (m/s^2); the world z axis points up."""

SE23B = Product[SE23, Rn[6]]
"""$SE_2(3) \\times \\mathbb R^6$: extended pose and the gyro and accelerometer biases."""

INPUT_NAMES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
INPUT_UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
STATE_NAMES = ("rx", "ry", "rz", "vx", "vy", "vz", "x", "y", "z")
STATE_UNITS = ("rad",) * 3 + ("m/s",) * 3 + ("m",) * 3
BIAS_NAMES = ("bgx", "bgy", "bgz", "bax", "bay", "baz")
BIAS_UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
LEVER_NAMES = ("rx_arm", "ry_arm", "rz_arm")
LEVER_UNITS = ("m",) * 3
GYRO_CALIBRATION = {"scale": ("sgx", "sgy", "sgz"),
                    "matrix": tuple(f"mg{a}{b}" for a in "xyz" for b in "xyz")}
"""The gyro's calibration errors a state can hold, by ``gyro_calibration``: their names (unitless)."""


def _pose(g) -> SE23:
    """The SE_2(3) part of the state."""
    return g.factors[0] if isinstance(g, Product) else g


class ImuDynamics(eqx.Module):
    r"""$\lambda(g, u) = ((I + M)^{-1}(\tilde\omega - b_g),\ \tilde a - b_a + R^\top g,\ R^\top v\ (;\ 0))$ for
    gravity ``(0, 0, -gravity)``. The vector factor holds the biases at its start when ``biases`` (else they are
    zero) and the gyro's calibration errors $M$ from ``gyro_at`` on, of the kind ``gyro`` (``"scale"``: the
    diagonal; ``"matrix"``: the whole matrix row by row; None: $M = 0$); every component of it (biases, lever arm,
    calibration) is constant."""

    gravity: Float[Array, ""] = eqx.field(converter=parameter)
    biases: bool = eqx.field(static=True, default=True)
    gyro: str | None = eqx.field(static=True, default=None)
    gyro_at: int = eqx.field(static=True, default=0)

    def __call__(self, g, u, t):
        x = _pose(g)
        Rt = jnp.swapaxes(x.rotation().as_matrix(), -1, -2)
        w, a = u[0:3], u[3:6]
        if isinstance(g, Product):
            z = g.factors[1].x
            if self.biases:
                w, a = w - z[0:3], a - z[3:6]
            if self.gyro == "scale":
                w = w / (1.0 + z[self.gyro_at:self.gyro_at + 3])
            elif self.gyro == "matrix":
                w = solve3(jnp.eye(3) + z[self.gyro_at:self.gyro_at + 9].reshape(3, 3), w)
        lam = [w, a + mv(Rt, jnp.array([0.0, 0.0, -self.gravity])), mv(Rt, x.velocity())]
        if isinstance(g, Product):
            lam.append(jnp.zeros(g.factors[1].x.shape[-1]))
        return jnp.concatenate(lam)


def gnss_position(g, t):
    """The world position ``p`` (m)."""
    return _pose(g).position()


class MountedPosition(eqx.Module):
    r"""$h = p + R r$: the world position (m) of the point at the lever arm $r$ (body frame), the vector factor's
    components ``start`` to ``start + 3``."""

    start: int = eqx.field(static=True)

    def __call__(self, g, t):
        x = _pose(g)
        r = g.factors[1].x[self.start:self.start + 3]
        return x.position() + mv(x.rotation().as_matrix(), r)


def barometric_altitude(g, t):
    """The altitude ``p_z`` (m)."""
    return _pose(g).position()[2:3]


class BodyLandmarks(eqx.Module):
    r"""$h_i = R^\top(\ell_i - p)$ for the known world points ``points`` (L x 3, a leaf: other landmarks are
    data), concatenated."""

    points: Float[Array, "L 3"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        x = _pose(g)
        Rt = jnp.swapaxes(x.rotation().as_matrix(), -1, -2)
        rel = self.points - x.position()
        return jnp.sum(Rt[None, :, :] * rel[:, None, :], axis=-1).reshape(-1)


class BodyField(eqx.Module):
    r"""$h = R^\top m$: the fixed world direction ``m`` (a leaf) seen in the body frame (the magnetometer)."""

    m: Float[Array, "3"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        Rt = jnp.swapaxes(_pose(g).rotation().as_matrix(), -1, -2)
        return mv(Rt, self.m)


def _imu_noise(name, std, rate):
    noise = Noise.density(std) if rate is None else Noise.sample(std, rate)
    if noise.dim not in (1, 3):
        raise ValueError(f"{name}: expected 1 or 3 stds, got {noise.dim}")
    return jnp.broadcast_to(noise.density_std(name), (3,))


def inertial_navigation(gyro_std=GYRO_STD, acc_std=ACC_STD, imu_rate: float | None = IMU_RATE, *,
                        biases: bool = False, gyro_bias_walk=GYRO_BIAS_WALK, acc_bias_walk=ACC_BIAS_WALK,
                        gnss_std=GNSS_STD, landmarks=None, landmark_std=LANDMARK_STD, mag_std=None,
                        dip: float = DIP, baro_std=None, gravity: float = GRAVITY,
                        gate: float | None = None, robust: str | None = None,
                        lever_arm: bool = False, gyro_calibration: str | None = None,
                        gyro_scale_std=None) -> SensorSystem:
    """The inertial-navigation system on SE_2(3) (SE_2(3) x R^k with ``biases``, 6, ``lever_arm``, 3 more, and
    ``gyro_calibration``, 3 or 9 more), module docstring.

    Args:
        gyro_std: gyro noise std per sample at ``imu_rate`` (rad/s; one value or 3), or a density
            (rad/s/sqrt(Hz)) if ``imu_rate`` is None.
        acc_std: accelerometer noise std per sample (m/s^2; one value or 3), or a density (m/s^2/sqrt(Hz)).
        imu_rate: the IMU rate (Hz) the stds refer to.
        biases: estimate the gyro and accelerometer biases (state SE_2(3) x R^6).
        gyro_bias_walk: gyro bias random walk density (rad/s/sqrt(s); one value or 3), with ``biases``.
        acc_bias_walk: accelerometer bias random walk density (m/s^2/sqrt(s); one value or 3), with ``biases``.
        gnss_std: std of one position fix (m; one value or 3), or None for no position fixes.
        landmarks: known landmark positions (L, 3) in the world frame (m), or None.
        landmark_std: std of one landmark observation in the body frame (m; one value or 3 L).
        mag_std: std of one normalized magnetometer sample (unitless), or None (default) for no magnetometer.
        dip: magnetic dip (rad), positive when the field points down.
        baro_std: std of one barometric altitude (m), or None (default) for no barometer.
        gravity: gravity magnitude (m/s^2); the world z axis points up.
        gate: every sensor's chi-square gate probability (:class:`~liemef.systems.Sensor`).
        robust: ``"huber"`` or ``"cauchy"`` down-weighting of outliers on every sensor.
        lever_arm: estimate the lever arm r (m, body frame) of the fixes' point from the IMU: ``gnss`` is then
            p + R r, and r the 3 components of the state after the biases (constant, no process noise). Needs
            ``gnss_std``.
        gyro_calibration: estimate the gyro's calibration errors M (unitless; the gyro reads (I + M) omega
            + b_g): ``"scale"``, its scale-factor errors (M diagonal, 3), or ``"matrix"``, scale factors and
            cross-axis errors (9, row by row); the state's last components (constant, no process noise).
        gyro_scale_std: the gyro's scale-factor and cross-axis errors s as noise (unitless, >= 0): the gyro's
            noise grows with the rate it measures, (gyro_std^2 + s^2 |u_omega|^2) per sample at ``imu_rate``
            (:class:`~liemef.systems._gyro_scale.GyroScaleSystem`, s an array leaf); None (default) builds the
            plain system.

    ``B = noise_map diag(densities)`` with ``R = I``; ``D = diag(sensor stds)`` with ``Q = I``.
    """
    if not (isinstance(gravity, int | float) and math.isfinite(gravity) and gravity >= 0):
        raise ValueError(f"gravity: expected a gravity magnitude >= 0 in m/s^2, got {gravity!r}")
    if not (isinstance(dip, int | float) and math.isfinite(dip) and abs(dip) <= math.pi / 2):
        raise ValueError(f"dip: expected a magnetic dip in radians within [-pi/2, pi/2], got {dip!r}")
    for key, flag in (("biases", biases), ("lever_arm", lever_arm)):
        if not isinstance(flag, bool):
            raise ValueError(f"{key}: expected True or False, got {flag!r}")
    if gyro_calibration is not None and gyro_calibration not in GYRO_CALIBRATION:
        raise ValueError(f"gyro_calibration: expected None or one of {sorted(GYRO_CALIBRATION)}, got "
                         f"{gyro_calibration!r}")
    calibration = GYRO_CALIBRATION.get(gyro_calibration, ())
    if lever_arm and gnss_std is None:
        raise ValueError("lever_arm: expected position fixes (gnss_std) for a lever arm to act on, got gnss_std=None")
    density = [_imu_noise("gyro_std", gyro_std, imu_rate), _imu_noise("acc_std", acc_std, imu_rate)]
    arm = 6 if biases else 0  # where the lever arm starts in the vector factor, then the gyro's calibration
    gyro_at = arm + (3 if lever_arm else 0)
    k = gyro_at + len(calibration)
    n, d = 9 + k, (12 if biases else 6)
    noise_map = np.zeros((n, d))
    noise_map[0:3, 0:3] = np.eye(3)  # gyro noise on omega
    noise_map[3:6, 3:6] = np.eye(3)  # accelerometer noise on nu_v
    if biases:
        for name, walk in (("gyro_bias_walk", gyro_bias_walk), ("acc_bias_walk", acc_bias_walk)):
            density.append(_imu_noise(name, walk, None))
        noise_map[9:15, 6:12] = np.eye(6)
    xyz = ("x", "y", "z")
    sensors = []
    if gnss_std is not None:
        sensors.append(Sensor("gnss", MountedPosition(arm) if lever_arm else gnss_position,
                              Noise.sample(gnss_std), xyz, ("m",) * 3, gate=gate, robust=robust))
    if landmarks is not None:
        pts = _validate.array("landmarks", np.asarray(landmarks, dtype=np.float64), (None, 3))
        if pts.shape[0] == 0:
            raise ValueError("landmarks: expected one or more landmark positions (L, 3), got none")
        points = tuple(tuple(float(c) for c in row) for row in pts)
        sensors.append(Sensor("landmarks", BodyLandmarks(points), Noise.sample(landmark_std),
                              tuple(f"{i + 1}{c}" for i in range(len(points)) for c in xyz),
                              ("m",) * (3 * len(points)), gate=gate, robust=robust))
    if mag_std is not None:
        sensors.append(Sensor("mag", BodyField(magnetic_reference(float(dip))), Noise.sample(mag_std), xyz,
                              ("1",) * 3, gate=gate, robust=robust))
    if baro_std is not None:
        sensors.append(Sensor("baro", barometric_altitude, Noise.sample(baro_std), ("z",), ("m",), gate=gate,
                              robust=robust))
    if not sensors:
        raise ValueError("gnss_std, landmarks, mag_std, baro_std: expected at least one sensor, got none")
    group = SE23 if k == 0 else Product[SE23, Rn[k]]
    names = (STATE_NAMES + (BIAS_NAMES if biases else ()) + (LEVER_NAMES if lever_arm else ())
             + calibration)
    units = (STATE_UNITS + (BIAS_UNITS if biases else ()) + (LEVER_UNITS if lever_arm else ())
             + ("1",) * len(calibration))
    dynamics = ImuDynamics(float(gravity), biases, gyro_calibration, gyro_at)
    system = SensorSystem(group, dynamics, sensors, Noise.density(jnp.concatenate(density)), noise_map=noise_map,
                          inputs=INPUT_NAMES, input_units=INPUT_UNITS, state_names=names, state_units=units)
    return system if gyro_scale_std is None else GyroScaleSystem(system, gyro_scale_std, imu_rate)
