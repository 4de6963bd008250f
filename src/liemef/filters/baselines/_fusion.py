r"""x-io Technologies' Fusion AHRS (the ``imufusion`` package, 1.3) as a liemef baseline.

Fusion (S. Madgwick, https://github.com/xioTechnologies/Fusion, MIT) is a complementary filter of Madgwick's
later design: the gyro integrated with a feedback towards the accelerometer's gravity and the magnetometer's
heading of fixed ``gain``; an acceleration and a magnetic rejection that ignore a sensor whose direction is
more than ``acceleration_rejection`` / ``magnetic_rejection`` degrees off the estimate, for at most
``rejection_timeout`` seconds; a soft restart when the gyro exceeds 98 % of ``gyroscope_range``. It starts
itself: from the identity, with a gain ramped down from 10 to ``gain`` over its first 3 s, so that the first
samples set the attitude (the ``g0`` given to :meth:`~Fusion.init` is not used). Its gyro offset estimator
(``imufusion.Bias``, ``bias=True``) averages the gyro while it stays below 3 deg/s for 3 s.

Units and frames (read off the Fusion C source, ``FusionAhrs.c``; ``tests/test_baselines.py`` checks them on
a rotation): gyro in deg/s, accelerometer in g, magnetometer in any unit; in its ENU convention its quaternion
$(w, x, y, z)$ is body -> earth with z up and the horizontal field along +y, liemef's ENU with north = +y: no
conversion. Its gyro offset is a gyro bias in liemef's sense ($u = \omega + b$), converted to rad/s.

Samples, raw readings and missing samples: as :class:`~liemef.filters.baselines.VQF` (the same driver): a
uniform clock, state $k + 1$ is Fusion after sample $k$ (state 0 = ``g0``), or with ``broad_indexing=True``
state $k$ is Fusion after sample $k$ (Fusion integrates gyro sample $k$ over the interval that ends at $t_k$).
A missing accelerometer or magnetometer sample (NaN) is passed as the zero vector, which Fusion reads as
"no sample" (that sensor's feedback is skipped). ``step`` is not available (Fusion's state is not a liemef
state). Pure C per sample behind a Python call: a few microseconds per sample.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import numpy as np

from ...systems import AbstractSystem
from ._ahrs import _Q_IDENTITY, _attitude_sensors, _flag, _positive
from ._vqf import GRAVITY, _WholeLogFilter, norm_sensor

FUSION_GAIN = 0.5
"""Fusion's default gain (``FusionAhrs.c``, ``fusionAhrsDefaultSettings``)."""


class Fusion(_WholeLogFilter):
    """Fusion (``imufusion``) as a liemef baseline (module docstring: start, units, frames, samples).

    Args:
        system: an attitude system on SO3 or TSO3 with gyro input and ``acc`` and ``mag`` sensors (and, for the
            raw norms, a ``norm`` sensor: :func:`liemef.systems.attitude_imu`).
        gain: the feedback gain > 0; Fusion's default 0.5.
        gyroscope_range: deg/s, the gyro's range (a soft restart above 98 % of it); 0 (Fusion's default) = none.
        acceleration_rejection: deg, the accelerometer's error beyond which it is ignored; 0 (Fusion's
            default) = never ignored.
        magnetic_rejection: deg, the same for the magnetometer.
        rejection_timeout: s, the longest a sensor stays ignored; 0 (Fusion's default) disables the rejection.
        bias: run Fusion's gyro offset estimator (``imufusion.Bias``, its defaults) on the gyro first.
        broad_indexing: state k is Fusion after sample k (BROAD's indexing), instead of liemef's state k + 1.

    The sample rate is the log's (Fusion's default setting of 100 Hz would integrate every sample over 10 ms).
    """

    name: ClassVar[str] = "fusion"
    _frame: ClassVar[np.ndarray] = _Q_IDENTITY
    system: AbstractSystem
    acc: tuple[int, int] = eqx.field(static=True)
    mag: tuple[int, int] = eqx.field(static=True)
    norm: tuple[int, int] | None = eqx.field(static=True)
    gain: float = eqx.field(static=True)
    gyroscope_range: float = eqx.field(static=True)
    acceleration_rejection: float = eqx.field(static=True)
    magnetic_rejection: float = eqx.field(static=True)
    rejection_timeout: float = eqx.field(static=True)
    bias: bool = eqx.field(static=True)
    broad_indexing: bool = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, gain: float = FUSION_GAIN, *, gyroscope_range: float = 0.0,
                 acceleration_rejection: float = 0.0, magnetic_rejection: float = 0.0,
                 rejection_timeout: float = 0.0, bias: bool = False, broad_indexing: bool = False):
        self.acc, self.mag = _attitude_sensors(system)
        self.system = system
        self.norm = norm_sensor(system)
        self.gain = _positive("gain", gain)
        self.gyroscope_range = _positive("gyroscope_range", gyroscope_range, zero=True)
        self.acceleration_rejection = _positive("acceleration_rejection", acceleration_rejection, zero=True)
        self.magnetic_rejection = _positive("magnetic_rejection", magnetic_rejection, zero=True)
        self.rejection_timeout = _positive("rejection_timeout", rejection_timeout, zero=True)
        self.bias, self.broad_indexing = _flag("bias", bias), _flag("broad_indexing", broad_indexing)

    def __repr__(self) -> str:
        return (f"Fusion({type(self.system).__name__}, gain={self.gain}, gyroscope_range={self.gyroscope_range}, "
                f"acceleration_rejection={self.acceleration_rejection}, magnetic_rejection="
                f"{self.magnetic_rejection}, rejection_timeout={self.rejection_timeout}, bias={self.bias}, "
                f"broad_indexing={self.broad_indexing})")

    def _batch(self, gyr, acc, mag, Ts):
        import imufusion

        rate = 1.0 / Ts
        settings = imufusion.AhrsSettings(
            sample_rate=rate, gain=self.gain, gyroscope_range=self.gyroscope_range,
            acceleration_rejection=self.acceleration_rejection, magnetic_rejection=self.magnetic_rejection,
            rejection_timeout=self.rejection_timeout)
        settings.convention = imufusion.CONVENTION_ENU  # imufusion 1.3.3's constructor drops its convention
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(settings)
        offset = imufusion.Bias()
        offset.set_settings(imufusion.BiasSettings(sample_rate=rate))
        g = np.degrees(gyr)
        a = np.where(np.isfinite(acc).all(axis=1, keepdims=True), acc / GRAVITY, 0.0)  # zero = no sample
        m = np.where(np.isfinite(mag).all(axis=1, keepdims=True), mag, 0.0)
        Q, B = np.zeros((g.shape[0], 4)), np.zeros((g.shape[0], 3))
        for k in range(g.shape[0]):
            w = offset.update(g[k]) if self.bias else g[k]
            ahrs.update(np.asarray(w, np.float64), a[k], m[k])
            Q[k] = ahrs.get_quaternion()
            if self.bias:
                B[k] = np.radians(offset.get_offset())
        return Q, B

