r"""VQF (Laidig and Seel 2023) as a liemef baseline: the ``vqf`` package's online filter (:class:`vqf.VQF`) and
its offline, acausal variant (:func:`vqf.offlineVQF`), with their defaults.

D. Laidig and T. Seel, "VQF: Highly Accurate IMU Orientation Estimation with Bias Estimation and Magnetic
Disturbance Rejection", Information Fusion 91:187-204, 2023. VQF low-pass filters the accelerometer in an almost
inertial frame (linear accelerations average out), estimates the gyro bias at rest and in motion, and corrects
the heading only from the magnetometer, rejecting it while its norm or dip differ from a reference.

Frames (read off the vqf 2.1 source, ``pyvqf.py``; ``tests/test_baselines_vqf.py`` pins them): its 9D
quaternion $(w, x, y, z)$ is body -> earth with z up and the horizontal field along +y, i.e. liemef's ENU
with north = +y: no conversion. Its bias estimate is a gyro bias in liemef's sense ($u = \omega + b$).

Samples: as :class:`~liemef.filters.baselines.Madgwick`, state $k+1$ is VQF after gyro, acc and mag sample $k$
(state 0 = ``g0``; VQF starts from its own first samples: ``g0``'s attitude is not used by it); with
``broad_indexing=True`` state $k$ is VQF after sample $k$, as VQF and BROAD index it (VQF integrates gyro sample
$k$ over the interval that ends at $t_k$). VQF needs the
raw readings (m/s^2 and a field in any unit): its rest detection has thresholds in m/s^2 and its disturbance
detection reads the field's norm. On a system with a ``norm`` sensor (:func:`liemef.systems.attitude_imu`, log
from :func:`~liemef.systems.attitude_bias.imu_log` with ``norms=True``) they are rebuilt from the directions
and the norms; on one without (:func:`liemef.systems.attitude_gyro_bias`) the accelerometer is taken as the
direction times ``GRAVITY`` and the field as a unit vector (so VQF cannot see a norm change). Missing samples
(NaN) are not supported by VQF's batch functions: a log with one is refused (``ValueError``). ``step`` is not
available: VQF's state (filters, rest and disturbance detection) is not a liemef state; use ``run``.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ... import _validate
from ...systems import AbstractSystem
from .. import FilterState, Trajectory
from .._status import CAUSES, Status
from ._ahrs import _Q_IDENTITY, _AhrsFilter, _attitude_sensors, _flag

GRAVITY = 9.81
"""m/s^2: the accelerometer's scale when a system's log holds only its direction."""


def norm_sensor(system: AbstractSystem) -> tuple[int, int] | None:
    """The output slice of a system's ``norm`` sensor (the raw norms of the accelerometer and the magnetometer,
    :func:`liemef.systems.attitude_imu`), or None if it has none."""
    blocks = {b.name: b for b in system.blocks()}
    return (blocks["norm"].start, blocks["norm"].stop) if "norm" in blocks and blocks["norm"].dim == 2 else None


def raw_readings(ys: np.ndarray, acc: tuple[int, int], mag: tuple[int, int],
                 norm: tuple[int, int] | None) -> tuple[np.ndarray, np.ndarray]:
    """The raw accelerometer (m/s^2) and magnetometer readings of a log's ``ys``: the directions times the
    ``norm`` sensor's norms, or without one the accelerometer's direction times ``GRAVITY`` and the field's unit
    direction (module docstring)."""
    a, m = ys[:, slice(*acc)], ys[:, slice(*mag)]
    if norm is None:
        return GRAVITY * a, m
    n = ys[:, slice(*norm)]
    return a * n[:, :1], m * n[:, 1:2]


class _WholeLogFilter(_AhrsFilter):
    """The shared driver of the baselines that run whole logs on a uniform clock in their own library (VQF,
    :class:`~liemef.filters.baselines.Fusion`), whose state is not a liemef state (``step`` refuses): checks,
    the raw readings, the indexing and the status. A final class holds the fields (``system``, ``acc``, ``mag``,
    ``norm``, ``broad_indexing``) and gives :meth:`_batch`."""

    norm: eqx.AbstractVar[tuple[int, int] | None]

    def _engine(self):
        raise NotImplementedError  # pragma: no cover - whole logs only (step refuses)

    @staticmethod
    def _update(engine, q, b, u, a, m, dt):
        raise NotImplementedError  # pragma: no cover

    def step(self, state, t, u, y, dt, **kw) -> FilterState:
        """Not available: the library's internal state is not a liemef state; use :meth:`run`."""
        raise ValueError(f"step: {type(self).__name__} runs whole logs only (its internal state is not a liemef "
                         "state); expected run(state, ts, us, ys)")

    def raw(self, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The raw accelerometer (m/s^2) and magnetometer readings of a log's ``ys`` (module docstring)."""
        return raw_readings(ys, self.acc, self.mag, self.norm)

    @abc.abstractmethod
    def _batch(self, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
        """The library's quaternions (M, 4) in its frame and gyro biases (M, 3) after each of the M samples given
        (gyro rad/s, accelerometer m/s^2, field; NaN = missing), at the sample time ``Ts``."""

    def run(self, state: FilterState, ts: ArrayLike, us: ArrayLike, ys: ArrayLike, *,
            keep_every: int = 1) -> Trajectory:
        """Filter a whole log on a uniform clock (one sample time ``ts[1] - ts[0]``): ``us`` (N, 3) the gyro,
        ``ys`` (N, p). State k + 1 is the filter after sample k, state 0 the given state (module docstring); with
        ``broad_indexing`` state k is the filter after sample k."""
        self.check_state(state)
        self.check_element("state.g_hat", state.g_hat)
        ts = _validate.sorted_times("ts", ts)
        N = ts.shape[0]
        if N < 2:
            raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
        dts = np.diff(ts)
        if not np.allclose(dts, dts[0], rtol=1e-6, atol=0.0):
            raise ValueError(f"ts: expected a uniform clock for {type(self).__name__}, got intervals from "
                             f"{dts.min()} to {dts.max()} s")
        us = _validate.array("us", us, (N, 3))
        ys = _validate.array("ys", ys, (N, self.system.output_dim), missing=True)
        if not (isinstance(keep_every, int) and not isinstance(keep_every, bool) and keep_every >= 1):
            raise ValueError(f"keep_every: expected an integer >= 1, got {keep_every!r}")
        acc, mag = self.raw(ys)
        c = np.ascontiguousarray
        last = N if self.broad_indexing else N - 1
        Q, B = self._batch(c(us[:last], np.float64), c(acc[:last], np.float64), c(mag[:last], np.float64),
                           float(dts[0]))
        if not self.broad_indexing:
            q0, b0 = self._split(state.g_hat)
            Q, B = np.concatenate([q0[None], Q], axis=0), np.concatenate([b0[None], B], axis=0)
        n, st = self.n, state.status
        steps = int(st.steps) + N - 1
        status = Status(
            code=jnp.asarray(CAUSES.OK.code, jnp.int32), index=st.index, time=st.time,
            steps=jnp.asarray(steps, jnp.int32),
            rejected=st.rejected, consecutive=st.consecutive, substeps_max=jnp.asarray(1, jnp.int32),
            substeps_total=jnp.asarray(steps, jnp.int32), substeps_capped=st.substeps_capped, gaps=st.gaps,
            longest_gap=jnp.maximum(st.longest_gap, jnp.asarray(float(dts.max()))), inputs_held=st.inputs_held)
        final = FilterState(g_hat=self._join(Q[-1], B[-1]), K=jnp.zeros((n, n)), u_last=jnp.asarray(us[-2]),
                            status=status)
        M = keep_every
        return Trajectory(ts=jnp.asarray(ts[::M]), g_hat=self._join(Q[::M], B[::M]),
                          K=jnp.zeros((len(ts[::M]), n, n)), status=status, final=final)


class VQF(_WholeLogFilter):
    """VQF (``vqf`` package, its defaults) as a liemef baseline (module docstring: frames, samples, raw data).

    Args:
        system: an attitude system on SO3 or TSO3 with gyro input and ``acc`` and ``mag`` sensors (and, for the
            raw norms, a ``norm`` sensor: :func:`liemef.systems.attitude_imu`).
        offline: use :func:`vqf.offlineVQF` (acausal: forward and backward passes over the whole log).
        params: VQF parameters by name (``tauAcc``, ``tauMag``, ...); default VQF's own.
        broad_indexing: state k is VQF after sample k (VQF's and BROAD's own indexing), instead of liemef's
            state k + 1 (state k has then seen samples up to k - 1 only: one sample late, 3.4 deg at 17 rad/s
            and 286 Hz). ``liemef compare broad`` runs it so, as the other baselines.
    """

    name: ClassVar[str] = "vqf"
    _frame: ClassVar[np.ndarray] = _Q_IDENTITY
    system: AbstractSystem
    acc: tuple[int, int] = eqx.field(static=True)
    mag: tuple[int, int] = eqx.field(static=True)
    offline: bool = eqx.field(static=True)
    params: tuple = eqx.field(static=True)
    norm: tuple[int, int] | None = eqx.field(static=True)
    broad_indexing: bool = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, offline: bool = False, params: dict | None = None, *,
                 broad_indexing: bool = False):
        self.acc, self.mag = _attitude_sensors(system)
        self.system = system
        if params is not None and not isinstance(params, dict):
            raise ValueError(f"params: expected a dict of VQF parameters, got {type(params).__name__}")
        self.offline, self.broad_indexing = _flag("offline", offline), _flag("broad_indexing", broad_indexing)
        self.params = tuple(sorted((params or {}).items()))
        self.norm = norm_sensor(system)

    def __repr__(self) -> str:
        return f"VQF({type(self.system).__name__}, offline={self.offline}, broad_indexing={self.broad_indexing})"

    def _batch(self, gyr, acc, mag, Ts):
        import vqf

        if not (np.isfinite(acc).all() and np.isfinite(mag).all()):
            raise ValueError("ys: expected no missing accelerometer or magnetometer sample for VQF, got NaN in "
                             f"{int((~np.isfinite(acc).all(1) | ~np.isfinite(mag).all(1)).sum())} rows")
        params = dict(self.params)
        if self.offline:
            out = vqf.offlineVQF(gyr, acc, mag, Ts, params or None)
        else:
            out = vqf.VQF(Ts, **params).updateBatchFullState(gyr, acc, mag)
        return np.asarray(out["quat9D"]), np.asarray(out["bias"])
