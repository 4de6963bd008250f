r"""The Madgwick and Mahony AHRS filters of the ``ahrs`` package (0.4) as liemef baselines.

Both wrap ``ahrs.filters.Madgwick`` / ``ahrs.filters.Mahony``: every sample interval is one call of their
``updateMARG`` (or ``updateIMU``), so the numbers are ahrs's own. They have the interface of
:class:`~liemef.filters.MinimumEnergyFilter` (``init`` / ``step`` / ``run`` returning liemef
:class:`~liemef.filters.FilterState` and :class:`~liemef.filters.Trajectory`), so a comparison can swap filters;
they have no gain or covariance (``has_covariance = False``: K is zeros, skip NEES).

System: an attitude :class:`~liemef.systems.SensorSystem` on SO(3) or TSO(3) (e.g.
:func:`liemef.systems.attitude_gyro_bias`) whose input is the gyro (rad/s, body frame) and whose sensors include
``acc`` (reads $R^\top e_{up}$) and ``mag`` (reads $R^\top m_{ref}$, $m_{ref}$ pointing north = +y and down),
found by name among ``system.blocks()``. The sensors' noise levels and the magnetic dip are not used: both
filters take the field's vertical and horizontal parts from the current estimate.

Frames (read off the ahrs 0.4 source; ``tests/test_baselines_ahrs.py`` pins them). Both filters' quaternions
$(w, x, y, z)$ are sensor -> earth, $\dot q = \tfrac12 q \otimes (0, \omega)$, with earth z **up** (the
accelerometer objective is $R^\top e_z - \bar a$, despite the docstrings' "NED"); they differ in the horizontal:

* Madgwick's magnetometer reference is $(b_x, 0, b_z)$: magnetic north on earth **+x**, i.e. a
  north-west-up frame, so liemef's quaternion (body -> ENU) is $q = q_c \otimes q_{ahrs}$ with
  $q_c = (\cos 45°, 0, 0, \sin 45°)$, +90 deg about up (BROAD's example code rotates its Madgwick and Mahony
  outputs by the same $q_c$, for the same reason: both come from Madgwick's C code).
* Mahony's reference is $(0, |h_{xy}|, h_z)$: north on **+y**, ENU already, $q = q_{ahrs}$.

Gyro bias: ahrs's Mahony integral term ``b`` enters as $\Omega = u - b + k_P e$ (and $\dot b = -k_I e$), i.e.
$b$ is a gyro bias estimate in liemef's sense ($u = \omega + b$, $\lambda = u - b$): on a TSO(3) system it is
the state's bias, initialised from ``g0``. Madgwick estimates no bias: the bias of ``g0`` (normally 0) is held
fixed and subtracted from every gyro sample, so that the trajectory's bias column is the one it assumed.
On an SO(3) system the state cannot carry Mahony's integral term: Mahony then needs ``k_I = 0``.

Samples, as in liemef (the default): the log sample $k$ at ``ts[k]`` acts over $[t_k, t_{k+1})$, and the state
$k$ is at ``ts[k]`` (state 0 = the initial state): state $k+1$ is one ahrs update of state $k$ with gyro, acc and
mag sample $k$ and ``dt = ts[k+1] - ts[k]``; the last sample is not used, and state $k$ has seen samples up to
$k - 1$ only. ahrs's own batch mode (and BROAD's example code) instead applies sample $k$ to reach state $k$
(``Q[t] = update(Q[t-1], gyr[t], ...)``, the gyro sample measuring the interval that ends at $t_k$): with
``broad_indexing=True`` :meth:`~_AhrsFilter.run` does so, state $k$ is one update of state $k - 1$ with sample
$k$ and ``dt = ts[k] - ts[k-1]`` (state 0 = the initial state; sample 0 is not used), so state $k$ has seen
sample $k$, as BROAD's estimate at ``ts[k]`` (``liemef compare broad`` runs every baseline so).
:meth:`~_AhrsFilter.step` applies the sample it is given in either case.

Missing samples (NaN, any component of a block): acc missing -> gyro-only propagation with $u - b$ (ahrs has no
magnetometer-only update; ahrs's Mahony itself would integrate the raw gyro without its bias); only mag missing
-> ``updateIMU`` (gravity only). Gyro samples must be finite. Two deliberate deviations from calling ahrs
directly: ahrs skips the whole update (correction included) when a gyro sample is exactly zero; a zero gyro is
passed as $10^{-150}$ rad/s instead, so that noise-free synthetic logs at rest are still corrected. And the state
is frozen at the first quaternion that is not finite or lost its unit norm (an overflow): ``status`` records it
(cause ``CAUSES.NONFINITE``, the interval's index and start time) and the later states of a run are NaN, as in
:meth:`~liemef.filters.MinimumEnergyFilter.run`.

BROAD (Laidig et al. 2021; ``tests/test_baselines_ahrs.py``): ahrs's Mahony is step for step the C code of
Madgwick's that BROAD's example code runs (up to the 90 deg frame and float32), and from BROAD's start
(``quatFromAccMag`` of the first sample) with BROAD's indexing it reproduces the published total rms (3.42, 5.23,
2.15 deg on trials 01, 07, 24 against 3.4, 5.2, 2.1). ahrs's Madgwick follows Madgwick's report (eq. (29): the
predicted field is $R^\top (b_x, 0, b_z)$ with $b_x = |h_{xy}|$) where the C code stores $|h_{xy}|$ in a variable
named ``_2bx`` and uses it as $2 b_x$, which halves the predicted field: the magnetometer weighs twice as much in
ahrs's gradient, and the numbers differ (3.26, 4.51, 2.00 against 2.3, 5.0, 1.8 deg). In liemef's indexing (one sample
late) the fast trial 07 loses a further 0.7 deg (one sample at up to 24 rad/s).

Speed: ahrs is pure numpy, 150-200 us per sample on an idle core: a 3-minute BROAD trial at 286 Hz takes
10-15 s.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import ahrs.filters
import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from ... import _validate
from ...groups import R3, SO3, TSO3, LieGroup
from ...systems import AbstractSystem
from .. import FilterState, Trajectory
from .._base import check_dt, check_element, check_log, check_time, nan_after_failure
from .._status import CAUSES, Status

MADGWICK_GAIN = 0.041
"""ahrs's default Madgwick gain with a magnetometer (``gain_marg``; its IMU-only default is 0.033)."""
MAHONY_K_P = 1.0
"""ahrs's default Mahony proportional gain (rad/s per unit error)."""
MAHONY_K_I = 0.3
"""ahrs's default Mahony integral gain."""

NORM_TOL = 1e-6
"""A quaternion returned by ahrs whose norm differs from 1 by more than this is a failure (an overflow)."""
_TINY_GYRO = 1e-150
"""Stands in for an exactly-zero gyro sample (ahrs would skip the update); its square does not underflow."""
_Q_NWU_TO_ENU = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
_Q_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def quat_mul(a: Float[ArrayLike, "... 4"], b: Float[ArrayLike, "... 4"]) -> Float[np.ndarray, "... 4"]:
    """Hamilton product of quaternions ``(w, x, y, z)`` (rotation matrices multiply), batched."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    w1, v1, w2, v2 = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    w = w1 * w2 - np.sum(v1 * v2, axis=-1, keepdims=True)
    return np.concatenate([w, w1 * v2 + w2 * v1 + np.cross(v1, v2)], axis=-1)


def _conj(q):
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def _missing(a) -> bool:
    return not np.all(np.isfinite(a))


def _interval(update, engine, q, b, u, a, m, dt):
    """One interval in ahrs's frame (``update`` the filter's, a and m None if missing): (q, b, ok); on a failure
    the input q and b. A plain function: the run's loop avoids equinox's per-attribute overhead."""
    try:
        with np.errstate(all="ignore"):
            q1, b1 = update(engine, q, b, u, a, m, dt)
    except (ValueError, FloatingPointError):  # ahrs refuses a zero quaternion (an overflow on the way)
        return q, b, False
    q1, b1 = np.asarray(q1, dtype=np.float64), np.asarray(b1, dtype=np.float64)
    ok = bool(np.all(np.isfinite(q1)) and np.all(np.isfinite(b1)) and abs(np.linalg.norm(q1) - 1.0) <= NORM_TOL)
    return (q1, b1, True) if ok else (q, b, False)


def _attitude_sensors(system: AbstractSystem) -> tuple[tuple[int, int], tuple[int, int]]:
    """The output slices of the ``acc`` and ``mag`` sensors of an attitude system on SO3 or TSO3 with the gyro as
    its input, whose sensors read up and a northern field at the identity (ValueError naming ``system``
    otherwise): the checks of every ahrs baseline's constructor."""
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a liemef attitude system (AbstractSystem), got "
                         f"{type(system).__name__}")
    if system.group not in (SO3, TSO3):
        raise ValueError(f"system: expected an attitude system on SO3 or TSO3, got one on "
                         f"{system.group.__name__}")
    if system.input_dim != 3:
        raise ValueError(f"system: expected the gyro as the input (3 components), got {system.input_dim} inputs")
    blocks = {b.name: b for b in system.blocks()}
    for s in ("acc", "mag"):
        if s not in blocks or blocks[s].dim != 3:
            got = [f"{b.name} ({b.dim})" for b in system.blocks()]
            raise ValueError(f"system: expected sensors 'acc' and 'mag' of 3 components each, got sensors {got}")
    acc, mag = (blocks["acc"].start, blocks["acc"].stop), (blocks["mag"].start, blocks["mag"].stop)
    # The frames of the conversion hold only if the system's sensors read up and a northern (+y) field.
    h = np.asarray(system.output(system.group.identity(), jnp.asarray(0.0)))
    a, m = h[slice(*acc)], h[slice(*mag)]
    if not (np.allclose(a, [0.0, 0.0, 1.0], atol=1e-9) and abs(m[0]) < 1e-9 and m[1] > 0):
        raise ValueError("system: expected 'acc' to read the world up (0, 0, 1) and 'mag' a field pointing north "
                         f"(+y, ENU) at the identity attitude, got acc {a.tolist()} and mag {m.tolist()}")
    return acc, mag


class _AhrsFilter(eqx.Module):
    """The shared driver of the ahrs filters (abstract; its final classes hold the fields): frames, missing
    samples, status, runs."""

    system: eqx.AbstractVar[AbstractSystem]
    acc: eqx.AbstractVar[tuple[int, int]]  # the output slices of the sensors (_attitude_sensors)
    mag: eqx.AbstractVar[tuple[int, int]]
    broad_indexing: eqx.AbstractVar[bool]  # run: state k has seen sample k (module docstring)
    has_covariance: ClassVar[bool] = False
    name: ClassVar[str]
    _frame: ClassVar[np.ndarray]  # q_c with q_liemef = q_c (x) q_ahrs

    @property
    def n(self) -> int:
        """The dimension of the group's algebra (K is n x n, and zero)."""
        return self.system.group.tangent_dim

    # --- the filter, in ahrs's frame ------------------------------------------------------------------------
    @abc.abstractmethod
    def _engine(self):
        """A fresh ahrs filter object with this filter's gains."""

    @staticmethod
    @abc.abstractmethod
    def _update(engine, q, b, u, a, m, dt):
        """One interval in ahrs's frame: the quaternion and the gyro bias after it (a, m: None if missing)."""

    def _interval(self, engine, q, b, u, y, dt):
        """One interval in ahrs's frame, NaN = missing; returns (q, b, ok)."""
        a, m = y[slice(*self.acc)], y[slice(*self.mag)]
        return _interval(type(self)._update, engine, q, b, u, None if _missing(a) else a,
                         None if _missing(m) else m, dt)

    # --- liemef <-> ahrs ------------------------------------------------------------------------------------
    def _split(self, g: LieGroup) -> tuple[np.ndarray, np.ndarray]:
        """(q_ahrs, b) of a liemef element (b = 0 on SO3)."""
        if self.system.group is TSO3:
            q, b = np.asarray(g.factors[0].wxyz), np.asarray(g.factors[1].x)
        else:
            q, b = np.asarray(g.wxyz), np.zeros(g.wxyz.shape[:-1] + (3,))
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return quat_mul(_conj(self._frame), q), np.asarray(b, dtype=np.float64)

    def _join(self, q_ahrs, b) -> LieGroup:
        q = jnp.asarray(quat_mul(self._frame, q_ahrs))
        if self.system.group is TSO3:
            return TSO3((SO3(q), R3(jnp.asarray(b))))
        return SO3(q)

    # --- the liemef interface -------------------------------------------------------------------------------
    def init(self, g0: LieGroup, K0: ArrayLike | None = None) -> FilterState:
        """Initial state ``g_hat = g0`` (on TSO3: the initial gyro bias too). ``K0`` is checked for its shape and
        otherwise ignored: K is zeros (no covariance)."""
        self.check_element("g0", g0)
        n = self.n
        if K0 is not None:
            _validate.square("K0", K0, n)
        q, b = self._split(g0)
        return FilterState(g_hat=self._join(q, b), K=jnp.zeros((n, n)), u_last=jnp.zeros(3),
                           status=Status.initial(len(self.system.blocks())))

    def step(self, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float) -> FilterState:
        """Advance one sample interval ``[t, t + dt]`` with the gyro ``u`` (finite) and the sample ``y`` (NaN =
        missing). On a failure the returned state is the input state with a failed ``status``, and later steps
        leave it unchanged."""
        self.check_state(state)
        u = _validate.array("u", u, (3,))
        y = _validate.array("y", y, (self.system.output_dim,), missing=True)
        t, dt = check_time(t, dt)
        st = state.status
        if int(st.code) != CAUSES.OK.code:
            return state
        q, b = self._split(state.g_hat)
        q1, b1, ok = self._interval(self._engine(), q, b, u, y, dt)
        i32 = lambda v: jnp.asarray(v, jnp.int32)  # noqa: E731
        steps = int(st.steps)
        status = Status(
            code=i32(CAUSES.OK.code if ok else CAUSES.NONFINITE.code), index=i32(-1 if ok else steps),
            time=jnp.asarray(math.nan if ok else t),
            steps=i32(steps + 1), rejected=st.rejected, consecutive=st.consecutive, substeps_max=i32(1),
            substeps_total=i32(int(st.substeps_total) + 1), substeps_capped=st.substeps_capped, gaps=st.gaps,
            longest_gap=jnp.asarray(max(float(st.longest_gap), dt)), inputs_held=st.inputs_held)
        if not ok:
            return FilterState(g_hat=state.g_hat, K=state.K, u_last=state.u_last, status=status)
        return FilterState(g_hat=self._join(q1, b1), K=state.K, u_last=jnp.asarray(u), status=status)

    def run(self, state: FilterState, ts: ArrayLike, us: ArrayLike, ys: ArrayLike, *,
            keep_every: int = 1) -> Trajectory:
        """Filter a whole log: ``ts`` (N,) strictly increasing, ``us`` (N, 3) finite gyro samples, ``ys`` (N, p)
        with NaN = missing. Returns the state at every ``ts[k]`` (every ``keep_every``-th, as
        :meth:`~liemef.filters.MinimumEnergyFilter.run`), the first being ``state``; after a failure the states
        are NaN and ``final`` is the last good state (module docstring). State k + 1 has seen samples up to k;
        with ``broad_indexing`` it has seen sample k + 1 (the update of the interval ``[ts[k], ts[k+1]]`` takes
        the sample at its end)."""
        self.check_state(state)
        self.check_element("state.g_hat", state.g_hat)
        ts, us, ys, _ = check_log(self, ts, us, ys, gap=math.inf, keep_every=keep_every, missing_inputs=False)
        N = ts.shape[0]
        n, st = self.n, state.status
        q, b = self._split(state.g_hat)
        Q, B = np.zeros((N, 4)), np.zeros((N, 3))
        Q[0], B[0] = q, b
        dts = np.diff(ts)
        failed, k_fail, done = int(st.code) != CAUSES.OK.code, -1, 0
        u_last = np.asarray(state.u_last)
        engine, update = self._engine(), type(self)._update
        A, M = ys[:, slice(*self.acc)], ys[:, slice(*self.mag)]
        a_ok, m_ok = np.isfinite(A).all(axis=1), np.isfinite(M).all(axis=1)
        ahead = int(self.broad_indexing)  # the sample that drives the interval [t_k, t_k+1]: k, or k + 1
        for k in range(N - 1):
            if failed:
                break
            j = k + ahead
            q, b, ok = _interval(update, engine, q, b, us[j], A[j] if a_ok[j] else None, M[j] if m_ok[j] else None,
                                 dts[k])
            done += 1
            if not ok:
                failed, k_fail = True, k
                break
            Q[k + 1], B[k + 1], u_last = q, b, us[j]
        steps = int(st.steps) + done
        if k_fail >= 0:
            code, index, time = CAUSES.NONFINITE.code, int(st.steps) + k_fail, float(ts[k_fail])
        else:
            code, index, time = int(st.code), int(st.index), float(st.time)
        status = Status(
            code=jnp.asarray(code, jnp.int32), index=jnp.asarray(index, jnp.int32), time=jnp.asarray(time),
            steps=jnp.asarray(steps, jnp.int32), rejected=st.rejected, consecutive=st.consecutive,
            substeps_max=jnp.asarray(1 if steps else 0, jnp.int32), substeps_total=jnp.asarray(steps, jnp.int32),
            substeps_capped=st.substeps_capped, gaps=st.gaps,
            longest_gap=jnp.maximum(st.longest_gap, jnp.asarray(float(dts[:done].max()) if done else 0.0)),
            inputs_held=st.inputs_held)
        last = done - (k_fail >= 0)  # the last row filled; the rows after it hold the failed status's NaN
        codes = np.where(np.arange(N) <= last, CAUSES.OK.code, code).astype(np.int32)
        Q, B, K = nan_after_failure(codes, (Q, B, np.zeros((N, n, n))), first_given=True)
        final = FilterState(g_hat=self._join(Q[last], B[last]), K=jnp.zeros((n, n)), u_last=jnp.asarray(u_last),
                            status=status)
        M = keep_every
        return Trajectory(ts=jnp.asarray(ts[::M]), g_hat=self._join(Q[::M], B[::M]), K=jnp.asarray(K[::M]),
                          status=status, final=final)

    # --- checks -------------------------------------------------------------------------------------------
    def check_state(self, state):
        """``state`` is a :class:`FilterState` of this filter's group (a ValueError naming ``state`` otherwise)."""
        if not isinstance(state, FilterState):
            raise ValueError(f"state: expected a FilterState (from init or step), got {type(state).__name__}")
        G = self.system.group
        if type(state.g_hat) is not G:
            raise ValueError(f"state: expected g_hat in {G.__name__}, got {type(state.g_hat).__name__}")

    def check_element(self, name, g):
        """``g`` is a finite element of this filter's group with a non-zero quaternion (a ValueError naming
        ``name`` otherwise)."""
        G = self.system.group
        check_element(G, name, g)
        q = np.asarray(g.factors[0].wxyz if G is TSO3 else g.wxyz)
        if not np.linalg.norm(q) > 0:
            raise ValueError(f"{name}: expected a non-zero quaternion, got {q.tolist()}")

    _check_dt = staticmethod(check_dt)


def _positive(name: str, value, *, zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not math.isfinite(value) \
            or value < 0 or (value == 0 and not zero):
        raise ValueError(f"{name}: expected a finite number {'>= 0' if zero else '> 0'}, got {value!r}")
    return float(value)


def _flag(name: str, value) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{name}: expected True or False, got {value!r}")
    return value


def _gyro(w):
    # ahrs skips the whole update on an exactly-zero gyro sample (module docstring)
    return w if np.any(w != 0) else np.array([_TINY_GYRO, 0.0, 0.0])


class Madgwick(_AhrsFilter):
    r"""ahrs's Madgwick filter (gradient descent on the acc/mag objective, step ``gain`` = $\beta$, rad/s) as a
    liemef baseline (module docstring: frames, samples, bias).

    Args:
        system: an attitude system on SO3 or TSO3 with gyro input and ``acc`` and ``mag`` sensors.
        gain: $\beta > 0$; ahrs's default with a magnetometer is 0.041 (0.033 without); BROAD's best common
            value is 0.12.
        broad_indexing: :meth:`run` makes state k from sample k, as ahrs's batch mode and BROAD do, instead of
            liemef's state k + 1 (module docstring: samples).
    """

    name: ClassVar[str] = "madgwick"
    _frame: ClassVar[np.ndarray] = _Q_NWU_TO_ENU
    system: AbstractSystem
    acc: tuple[int, int] = eqx.field(static=True)
    mag: tuple[int, int] = eqx.field(static=True)
    gain: float = eqx.field(static=True)
    broad_indexing: bool = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, gain: float = MADGWICK_GAIN, *, broad_indexing: bool = False):
        self.acc, self.mag = _attitude_sensors(system)
        self.system = system
        self.gain = _positive("gain", gain)
        self.broad_indexing = _flag("broad_indexing", broad_indexing)

    def __repr__(self) -> str:
        return f"Madgwick({type(self.system).__name__}, gain={self.gain}, broad_indexing={self.broad_indexing})"

    def _engine(self):
        return ahrs.filters.Madgwick(gain=self.gain)

    @staticmethod
    def _update(engine, q, b, u, a, m, dt):
        """One Madgwick interval in ahrs's frame (a, m: None if missing); the bias stays as it is."""
        w = _gyro(u - b)
        if a is None:
            return engine.updateIMU(q, w, np.zeros(3), dt=dt), b     # ahrs: no correction without acc
        if m is None:
            return engine.updateIMU(q, w, a, dt=dt), b
        return engine.updateMARG(q, w, a, m, dt=dt), b


class Mahony(_AhrsFilter):
    r"""ahrs's Mahony filter (explicit complementary filter: $\Omega = u - b + k_P e$, $\dot b = -k_I e$, $e$ the
    sum of measured x estimated directions) as a liemef baseline (module docstring: frames, samples, bias).

    Args:
        system: an attitude system on SO3 or TSO3 with gyro input and ``acc`` and ``mag`` sensors.
        k_P: proportional gain > 0 (rad/s); ahrs's default 1.0, BROAD's best common value 0.74.
        k_I: integral gain >= 0 (rad/s^2); ahrs's default 0.3, BROAD's 0.0012. 0 on an SO3 system (no bias in
            its state to carry the integral term).
        broad_indexing: :meth:`run` makes state k from sample k, as ahrs's batch mode and BROAD do, instead of
            liemef's state k + 1 (module docstring: samples).
    """

    name: ClassVar[str] = "mahony"
    _frame: ClassVar[np.ndarray] = _Q_IDENTITY
    system: AbstractSystem
    acc: tuple[int, int] = eqx.field(static=True)
    mag: tuple[int, int] = eqx.field(static=True)
    k_P: float = eqx.field(static=True)
    k_I: float = eqx.field(static=True)
    broad_indexing: bool = eqx.field(static=True)

    def __init__(self, system: AbstractSystem, k_P: float = MAHONY_K_P, k_I: float = MAHONY_K_I, *,
                 broad_indexing: bool = False):
        self.acc, self.mag = _attitude_sensors(system)
        self.system = system
        self.k_P = _positive("k_P", k_P)
        self.k_I = _positive("k_I", k_I, zero=True)
        self.broad_indexing = _flag("broad_indexing", broad_indexing)
        if system.group is SO3 and self.k_I != 0:
            raise ValueError(f"k_I: expected 0 on an SO3 system (its state has no gyro bias to carry the integral "
                             f"term; use a TSO3 system such as attitude_gyro_bias()), got {k_I!r}")

    def __repr__(self) -> str:
        return (f"Mahony({type(self.system).__name__}, k_P={self.k_P}, k_I={self.k_I}, "
                f"broad_indexing={self.broad_indexing})")

    def _engine(self):
        engine = ahrs.filters.Mahony(k_P=self.k_P, k_I=1.0)
        engine.k_I = self.k_I  # ahrs's constructor refuses k_I = 0, its update does not
        return engine

    @staticmethod
    def _update(engine, q, b, u, a, m, dt):
        """One Mahony interval in ahrs's frame (a, m: None if missing), with its bias estimate."""
        if a is None:  # ahrs would integrate the raw gyro; integrate u - b (module docstring)
            return engine.updateIMU(q, _gyro(u - b), np.zeros(3), dt=dt), b
        engine.b = np.array(b, dtype=np.float64)  # ahrs updates it in place
        q1 = engine.updateIMU(q, _gyro(u), a, dt=dt) if m is None else engine.updateMARG(q, _gyro(u), a, m, dt=dt)
        return q1, np.array(engine.b)
