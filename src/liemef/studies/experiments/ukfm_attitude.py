r"""The attitude benchmark of ukfm (gyro at 100 Hz, accelerometer and magnetometer vectors at 100 Hz), rebuilt
exactly.

The source: Brossard, Barrau & Bonnabel, ukfm (BSD-3), its model ``ATTITUDE`` (``python/ukfm/model/attitude.py``:
``f``, ``h``, ``simu_f``, ``simu_h``, ``errors``, ``nees``) and its benchmark ``python/benchmarks/attitude.py``;
after Kok, Hol & Schön 2017, Sec. IV. The state is the attitude $C \in SO(3)$ (body -> world; ukfm's frame x north,
y west, z up). There are N = T / dt = 10000 states $t_n = n\,dt$ (n = 0..9999), and the noisy gyro $u_n$
(n = 0..9998, std 5 deg/s per axis) moves state n to state n + 1: $C_{n+1} = C_n \mathrm{Exp}(u_n dt)$. Every
state has a measurement $y_n = (C_n^\top(g + 0.4\,\epsilon_a),\ C_n^\top(b + 0.3\,\epsilon_m))$ with
$g = (0, 0, -9.82)$ m/s^2 and $b = (0.33, 0, -0.95)$ (the noise drawn in the world frame, then rotated; in
distribution the same as body-frame noise, since it is isotropic); ukfm simulates $y_0$ but never uses it, so the
filters see 9999 measurements, n = 1..9999.

* Truth (:func:`simulate_truth`): $C_0 = I$, the true gyro 0 while ukfm's float accumulator (``n_T``, tested
  *before* adding dt) is at most ``rest`` = 2 s, then the constant ``omega`` = (0, 0, 10 deg/s) (a yaw about the
  vertical): the accumulator passes 2 after 200 additions (2.0000000000000013), so inputs 0..199 are 0 and
  $C_0 = \dots = C_{200} = I$. Then ukfm's step with the matrix Rodrigues formula, in floating point
  (:func:`~liemef.studies.experiments.inertial.exp_so3`).
* Noise (:class:`Draws`): standard normals from a ``jax.random`` key (:func:`jax_draws`), or ukfm's legacy NumPy
  stream for ``rng="numpy"`` (:func:`numpy_draws`): after ``np.random.seed(seed)`` it draws ukfm's normals in
  ukfm's order, ``randn(3)`` per gyro sample n = 1..N-1, then ``randn(3)`` (accelerometer) and ``randn(3)``
  (magnetometer) per state n = 0..N-1, then ``randn(3)`` (the initial error). The data are ukfm's run to
  round-off (``tests/test_ukfm_attitude.py`` rebuilds them from ukfm's equations).
* Initial estimate, **a quirk of the benchmark**: it draws $\hat C_0 = C_0 \mathrm{Exp}(10° \epsilon_0)$ but starts
  its three filters at the true $C_0$ with $P_0 = (10°)^2 I_3$; the drawn $\hat C_0$ is only recorded as the
  n = 0 estimate, so it enters only the n = 0 term of the errors. ``start="truth"`` does the same (and
  :func:`trial` records the drawn estimate at n = 0); ``start="drawn"`` starts the filters there.
* Filter: :func:`~liemef.systems.ukfm_attitude` with the scenario's noise levels: each gyro sample of std 5 deg/s
  at 100 Hz is the process-noise density, each measurement one sample (ukfm's ``Q = (5 deg/s)^2 I3``,
  ``R = blkdiag(0.4^2 I3, 0.3^2 I3)``). ukfm's filters (:data:`UKFM_FILTERS`) are liemef's UKF-M with the left
  and the right retraction and the EKF with the right (world-frame) error. ukfm updates with $y_n$ right after
  the prediction to n; liemef's discrete filters update with $y_n$ and then predict over $[t_n, t_{n+1}]$, so
  liemef's estimate at $t_{n+1}$ is ukfm's estimate at $t_n$ predicted with $u_n$ (step by step the same but
  for ukfm's jitter of 1e-9 I on P: docs/comparisons.md, "ukfm's attitude benchmark", has the measured
  differences). K0 = P0 = (10°)^2 I3 in the left error; P0 is isotropic, so it is also the covariance of the
  right error ukfm's right UKF-M and EKF start from.
* Metrics (:func:`series`; ukfm's ``errors`` and ``nees``): the world-frame error $e_n = \mathrm{Log}(C_n \hat
  C_n^\top)$ per axis [deg]; the NEES $e^\top P'^{-1} e / 3$ with the first-order covariance of $e$,
  $P' = \hat C K \hat C^\top$ ($e \approx \hat C\xi$ for the left error $\xi$), and ukfm's NEES, whose $P'$ for
  its left UKF-M is $\hat C^\top K \hat C$ (**quirk**: conjugated the wrong way round; for its right filters it
  is the first-order one). ukfm's figures (:func:`ukfm_figures`) are the rms over runs, all n = 0..N-1 **and the
  three axes** (a per-axis rms: the rotation angle's is sqrt(3) times larger), and the NEES averaged over all n
  with 0 at n = 0.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ..._linalg import mm
from ...groups import SO3
from ...metrics import nees
from ...simulation import SensorLog
from ...systems import ukfm_attitude
from ._base import UkfmGrid
from .inertial import exp_so3

NAMES = ("error_x", "error_y", "error_z", "nees", "nees_ukfm")
"""The trial's series (:func:`series`): the world-frame error per axis, the NEES and ukfm's NEES (each / 3)."""
UNITS = ("deg", "deg", "deg", "1", "1")
RNGS = ("jax", "numpy")
STARTS = ("truth", "drawn")
UKFM_FILTERS = {"ukf-left": "ukf_left", "ukf-right": "ukf_right", "iekf-right": "ekf"}
"""liemef's name of each of ukfm's filters (:data:`liemef.studies.compare.FILTERS`) -> ukfm's name: the UKF-M
with the left retraction $C = \\hat C\\exp\\xi$ and the right one $C = \\exp(\\xi)\\hat C$, and ukfm's EKF, whose
error is the right (world-frame) one: on SO(3) that is the right-invariant EKF."""
LEFT_NEES = ("ukf-left",)
"""The filters whose ukfm NEES uses ukfm's left conjugation $\\hat C^\\top P \\hat C$ (:func:`series`)."""
PUBLISHED_RUNS = 100
"""The runs behind :data:`PUBLISHED`: ukfm's documentation run of its benchmark (unseeded)."""
PUBLISHED = {
    "ukf-left": {"rms_deg": 1.06, "nees": 1.00},
    "ukf-right": {"rms_deg": 1.05, "nees": 0.99},
    "iekf-right": {"rms_deg": 1.05, "nees": 0.99},
}
"""The figures ukfm's documentation prints for its benchmark (``docs/_sources/auto_benchmark/attitude.rst.txt``,
100 unseeded runs): the per-axis rms over runs, steps and axes (deg) and the NEES (ukfm's definition)."""
PER_SEED_RUNS = 20
"""The runs behind :data:`PER_SEED`: ukfm's own code with ``np.random.seed(k)``, k = 0..19."""
PER_SEED = {
    "ukf-left": (1.0125, 1.2626, 1.1667, 1.1058, 0.8672, 0.9926, 1.4556, 1.1730, 1.0227, 1.0181, 1.0745, 0.9006,
                 0.7524, 1.1968, 1.2564, 0.9711, 1.0295, 1.3200, 0.9647, 0.9796),
    "ukf-right": (1.0629, 1.2134, 1.1368, 1.1030, 0.8454, 1.0057, 1.4662, 1.1805, 1.0231, 0.9865, 1.0782, 0.9162,
                  0.7981, 1.2445, 1.2760, 0.9820, 1.0465, 1.3199, 0.9510, 0.9492),
    "iekf-right": (1.0628, 1.2133, 1.1367, 1.1029, 0.8451, 1.0057, 1.4664, 1.1804, 1.0231, 0.9864, 1.0782, 0.9160,
                   0.7979, 1.2443, 1.2761, 0.9820, 1.0465, 1.3202, 0.9511, 0.9491),
}
"""ukfm's per-axis rms (deg, all n) of its runs 0-19, from its own code (the benchmark's loop body with
``np.random.seed(k)`` before run k; ukfm at commit fa6c135, NumPy 2.4.6, SciPy 1.17.1)."""
PER_SEED_NEES = {
    "ukf-left": (1.0580, 1.0792, 1.0077, 1.0365, 0.8313, 0.9520, 1.2359, 1.0978, 1.1086, 1.0159, 1.0108, 0.8727,
                 0.7427, 1.1354, 1.1942, 0.9995, 0.9993, 1.1923, 0.9081, 1.0008),
    "ukf-right": (1.0690, 1.0546, 0.9888, 1.0257, 0.8199, 0.9528, 1.2603, 1.0831, 1.0818, 0.9961, 1.0022, 0.8648,
                  0.7595, 1.1744, 1.1910, 0.9962, 1.0120, 1.2107, 0.8879, 0.9790),
    "iekf-right": (1.0703, 1.0559, 0.9899, 1.0270, 0.8207, 0.9540, 1.2621, 1.0844, 1.0833, 0.9973, 1.0034, 0.8657,
                   0.7603, 1.1757, 1.1927, 0.9975, 1.0133, 1.2126, 0.8891, 0.9801),
}
"""ukfm's NEES (its definition, all n) of its runs 0-19, from its own code as :data:`PER_SEED`."""
PER_SEED_INITIAL_ERRORS = (19.34, 15.82, 18.79, 18.93, 27.43, 18.49, 19.50, 10.02, 13.80, 13.54, 24.11, 18.18,
                           31.22, 11.61, 14.60, 10.53, 13.49, 28.81, 19.09, 14.78)
"""The angle (deg) of the drawn initial error of ukfm's runs 0-19."""


@dataclass(frozen=True)
class UkfmAttitudeConfig(UkfmGrid):
    r"""ukfm's attitude benchmark (module docstring); defaults are ukfm's.

    Fields:
        seed: the run's key is ``jax.random.key(seed)`` (``rng="jax"``) or ``np.random.seed(seed)``
            (``rng="numpy"``, ukfm's legacy stream).
        duration, dt: T and the IMU period: N = round(T / dt) states at t_n = n dt (n < N).
        rest: the truth is at rest until ukfm's float accumulator of dt exceeds ``rest`` (s), then turns at
            ``omega``.
        omega: the true body angular velocity after the rest (rad/s), ukfm's (0, 0, 10 deg/s).
        gravity: its magnitude g0 (m/s^2); the vector is (0, 0, -g0).
        field: the magnetic field in the world frame (unitless), ukfm's (0.33, 0, -0.95).
        imu_std: per-sample std of the gyro (rad/s), the accelerometer (m/s^2) and the magnetometer.
        rot0_std: per-axis std of the initial attitude error (rad); K0 = rot0_std^2 I3.
        start: ``"truth"``: the filters start at the true C_0 and the drawn initial estimate is only recorded at
            n = 0 (ukfm's benchmark code); ``"drawn"``: they start at the drawn estimate.
        rng: ``"jax"`` or ``"numpy"``.
    """

    seed: int = 0
    duration: float = 100.0
    dt: float = 0.01
    rest: float = 2.0
    omega: tuple[float, float, float] = (0.0, 0.0, math.radians(10.0))
    gravity: float = 9.82
    field: tuple[float, float, float] = (0.33, 0.0, -0.95)
    imu_std: tuple[float, float, float] = (math.radians(5.0), 0.4, 0.3)
    rot0_std: float = math.radians(10.0)
    start: str = "truth"
    rng: str = "jax"

    def __post_init__(self):
        self._check_run(positive=("gravity", "rot0_std"))
        _validate.nonnegative("rest", self.rest)
        _validate.choice("rng", self.rng, set(RNGS))
        _validate.choice("start", self.start, set(STARTS))
        _validate.array("omega", self.omega, (3,))
        field = _validate.array("field", self.field, (3,))
        if not np.linalg.norm(field) > 0:
            raise ValueError(f"field: expected a nonzero vector (3,), got {tuple(self.field)}")
        std = _validate.array("imu_std", self.imu_std, (3,))
        if np.any(std <= 0):
            raise ValueError(f"imu_std: expected three stds > 0 (gyro, accelerometer, magnetometer), got "
                             f"{tuple(self.imu_std)}")
        self._freeze(floats=("rest", "gravity", "rot0_std"), tuples=("omega", "field", "imu_std"))
        if self.n_states < 2:
            raise ValueError(f"duration: expected at least two states of dt = {self.dt}, got {self.duration}")

    @property
    def K0(self) -> np.ndarray:
        """rot0_std^2 I3: ukfm's P0, the covariance of the left error (and of the right one: it is isotropic)."""
        return self.rot0_std**2 * np.eye(3)


# --- the scenario -------------------------------------------------------------------------------------------
def gravity_vector(config: UkfmAttitudeConfig) -> np.ndarray:
    """``(0, 0, -gravity)``: z up."""
    return np.array([0.0, 0.0, -config.gravity])


def first_moving_input(config: UkfmAttitudeConfig) -> int:
    """The index of the first input at ``omega``: ukfm's loop n = 1..N-1 tests its accumulator ``n_T > rest``
    before adding ``dt`` to it (from 0), and input n - 1 turns from there on (200 for ukfm's 2 s at 0.01 s, since
    200 additions of 0.01 give 2.0000000000000013). N - 1 when the run ends first."""
    acc = 0.0
    for n in range(1, config.n_states):
        if acc > config.rest:
            return n - 1
        acc = acc + config.dt
    return config.n_states - 1


def true_inputs(config: UkfmAttitudeConfig) -> np.ndarray:
    """The noise-free gyro ``u[n]`` (N - 1, 3): 0 before :func:`first_moving_input`, ``omega`` from there."""
    u = np.zeros((config.n_states - 1, 3))
    u[first_moving_input(config):] = config.omega
    return u


@functools.lru_cache(maxsize=8)
def _truth_matrices(config: UkfmAttitudeConfig) -> np.ndarray:
    u = true_inputs(config)
    Cs = [np.eye(3)]
    for m in range(config.n_states - 1):
        Cs.append(Cs[-1] @ exp_so3(u[m] * config.dt))  # ukfm's ATTITUDE.f with w = 0
    Cs = np.stack(Cs)
    Cs.flags.writeable = False
    return Cs


def truth_matrices(config: UkfmAttitudeConfig) -> np.ndarray:
    """The true rotation matrices ``C[n]`` (N, 3, 3) by ukfm's step in floating point (read-only, cached)."""
    return _truth_matrices(_scenario_only(config))


def simulate_truth(config: UkfmAttitudeConfig) -> tuple[SO3, np.ndarray]:
    """The true states ``C[n]`` (an :class:`~liemef.groups.SO3` of batch shape (N,), from
    :func:`truth_matrices`; concrete also under a trace, cached) and the true gyro ``u[n]`` (N - 1, 3)
    (:func:`true_inputs`)."""
    return _truth_states(_scenario_only(config)), true_inputs(config)


@functools.lru_cache(maxsize=8)
def _truth_states(config: UkfmAttitudeConfig) -> SO3:
    with jax.ensure_compile_time_eval():
        return SO3.from_matrix(jnp.asarray(truth_matrices(config)))


def _scenario_only(config: UkfmAttitudeConfig) -> UkfmAttitudeConfig:
    """``config`` without what does not change the truth (seed, rng, start), for the caches."""
    return dataclasses.replace(config, seed=0, rng="jax", start="truth")


class Draws(NamedTuple):
    """The standard normals of one run: ``gyro`` (N-1, 3) per input sample, ``acc`` and ``mag`` (N, 3) per state
    (row 0 is ukfm's unused y_0), ``rot0`` (3,) the initial error."""

    gyro: jax.Array
    acc: jax.Array
    mag: jax.Array
    rot0: jax.Array


def jax_draws(config: UkfmAttitudeConfig, key) -> Draws:
    """The draws of one run from a ``jax.random`` key (traceable)."""
    n = config.n_states
    k_g, k_a, k_m, k_r = jax.random.split(key, 4)
    return Draws(jax.random.normal(k_g, (n - 1, 3)), jax.random.normal(k_a, (n, 3)), jax.random.normal(k_m, (n, 3)),
                 jax.random.normal(k_r, (3,)))


def numpy_draws(config: UkfmAttitudeConfig, seed: int) -> Draws:
    """The draws of ukfm's run after ``np.random.seed(seed)``, in its order (module docstring). The legacy
    Gaussian caches its second value across calls, so consecutive ``randn(3)`` calls are one stream."""
    _validate.integer("seed", seed, 0, 2**32 - 1)  # the legacy seed's range
    rs = np.random.RandomState(seed)
    n = config.n_states
    gyro = rs.randn(3 * (n - 1)).reshape(n - 1, 3)
    meas = rs.randn(6 * n).reshape(n, 6)
    return Draws(jnp.asarray(gyro), jnp.asarray(meas[:, :3]), jnp.asarray(meas[:, 3:]), jnp.asarray(rs.randn(3)))


def stacked_draws(config: UkfmAttitudeConfig, rng: str, seed: int, runs: int) -> Draws:
    """The draws of ``runs`` trials stacked (leading axis: trial): ``rng="jax"``: trial i from
    ``split(key(seed), runs)[i]``; ``rng="numpy"``: ukfm's legacy stream after ``np.random.seed(seed + i)``,
    the data of ukfm's own runs."""
    _validate.choice("rng", rng, set(RNGS))
    _validate.integer("runs", runs, 1)
    if rng == "numpy":
        draws = [numpy_draws(config, seed + i) for i in range(runs)]
        return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *draws)
    keys = jax.random.split(jax.random.key(seed), runs)
    return jax.jit(jax.vmap(lambda k: jax_draws(config, k)))(keys)


def draws_of(config: UkfmAttitudeConfig, key=None) -> Draws:
    """The draws of ``config``'s run: ukfm's stream after ``np.random.seed(config.seed)`` (``rng="numpy"``, no
    ``key``), or ``jax.random.key(config.seed)`` unless a ``key`` is given."""
    if config.rng == "numpy":
        if key is not None:
            raise ValueError("key: rng='numpy' draws from np.random.seed(config.seed); expected key=None")
        return numpy_draws(config, config.seed)
    return jax_draws(config, jax.random.key(config.seed) if key is None else key)


def measurements(config: UkfmAttitudeConfig, C, eps_acc, eps_mag) -> jax.Array:
    r"""ukfm's ``simu_h``: $(C^\top(g + \sigma_a \epsilon_a),\ C^\top(b + \sigma_m \epsilon_m))$, (..., 6), for
    rotation matrices ``C`` (..., 3, 3) and the world-frame normals (..., 3) (traceable)."""
    _, acc_std, mag_std = config.imu_std
    Ct = jnp.swapaxes(jnp.asarray(C), -1, -2)
    a = jnp.asarray(gravity_vector(config)) + acc_std * eps_acc
    m = jnp.asarray(config.field) + mag_std * eps_mag
    return jnp.concatenate([jnp.einsum("...ij,...j->...i", Ct, a), jnp.einsum("...ij,...j->...i", Ct, m)], axis=-1)


def sensor_log(config: UkfmAttitudeConfig, truth: SO3, draws: Draws) -> tuple[SensorLog, SO3, SO3]:
    """The filters' log, their initial estimate and the drawn initial estimate, from the truth and the draws
    (traceable): ``us[n] = u_n + gyro_std eps`` (n < N-1; the last row repeats, it is never used), ``ys[n]`` =
    :func:`measurements` for n >= 1 and NaN at n = 0 (ukfm's y_0 is never used), the drawn ``C_0 Exp(rot0_std
    eps_0)``, and the filters' start: the true C_0 (``start="truth"``, ukfm's code) or the drawn one."""
    u = jnp.asarray(true_inputs(config)) + config.imu_std[0] * draws.gyro
    us = jnp.concatenate([u, u[-1:]])
    ys = measurements(config, truth.as_matrix(), draws.acc, draws.mag).at[0].set(jnp.nan)
    g0 = jax.tree_util.tree_map(lambda a: a[0], truth)
    drawn = g0 @ SO3.exp(config.rot0_std * draws.rot0)
    start = g0 if config.start == "truth" else drawn
    return SensorLog(ts=jnp.asarray(config.ts), us=us, ys=ys), start, drawn


def system_of(config: UkfmAttitudeConfig):
    """:func:`~liemef.systems.ukfm_attitude` with the scenario's noise levels, rate, gravity and field."""
    gyro_std, acc_std, mag_std = config.imu_std
    return ukfm_attitude(gyro_std=gyro_std, imu_rate=1.0 / config.dt, acc_std=acc_std, mag_std=mag_std,
                         gravity=config.gravity, field=config.field)


# --- one trial and the metrics ------------------------------------------------------------------------------
def series(truth: SO3, g_hat: SO3, K, *, left_nees: bool = False) -> jax.Array:
    r"""(N, 5), the :data:`NAMES` (module docstring), traceable: the world-frame error $e = \mathrm{Log}(C\hat
    C^\top)$ per axis [deg], the NEES $e^\top(\hat C K \hat C^\top)^{-1}e/3$ (K: the covariance of the left
    error, every liemef filter's) and ukfm's NEES: the same for its right filters, and with
    $P' = \hat C^\top K \hat C$ for its left UKF-M (``left_nees``, ukfm's quirk)."""
    e = (truth @ g_hat.inverse()).log()
    R = g_hat.as_matrix()
    Rt = jnp.swapaxes(R, -1, -2)
    first = nees(e, mm(R, mm(K, Rt))) / 3.0
    ukfm = nees(e, mm(Rt, mm(K, R))) / 3.0 if left_nees else first
    return jnp.concatenate([jnp.degrees(e), first[..., None], ukfm[..., None]], axis=-1)


def initial_state(flt, config: UkfmAttitudeConfig):
    """The filter ``flt``'s state at the true C_0 with K0 (checked; not traceable): :func:`trial` moves its estimate
    to the run's start."""
    truth, _ = simulate_truth(config)
    return flt.init(jax.tree_util.tree_map(lambda a: a[0], truth), config.K0)


def trial(flt, state0, config: UkfmAttitudeConfig, draws: Draws):
    """One run of the filter ``flt`` (a liemef filter on :func:`system_of`) from ``state0``
    (:func:`initial_state`) moved to the run's start: its sensor log from ``draws``, the scan, and :func:`series`
    against the truth with ukfm's records at n = 0: the drawn initial estimate and a NEES of 0. Returns
    ``(series, trajectory)``; traceable (``vmap`` over draws)."""
    truth, _ = simulate_truth(config)
    log, start, drawn = sensor_log(config, truth, draws)
    traj = flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, start), log.ts, log.us, log.ys)
    g_hat = jax.tree_util.tree_map(lambda a, b: a.at[0].set(b), traj.g_hat, drawn)
    ser = series(truth, g_hat, traj.K, left_nees=getattr(flt, "name", "") in LEFT_NEES)
    return ser.at[0, 3:].set(0.0), traj


def trial_fn(flt, config: UkfmAttitudeConfig):
    """``draws -> series`` (runs, N, 5): :func:`trial` from :func:`initial_state`, compiled and ``vmap``-ed over
    stacked draws (:func:`stacked_draws`)."""
    state0 = initial_state(flt, config)
    return eqx.filter_jit(eqx.filter_vmap(lambda d: trial(flt, state0, config, d)[0]))


def ukfm_figures(ser) -> dict:
    """ukfm's figures from the series (runs, N, 5) or (N, 5) of :func:`trial`: ``rms_deg``, the rms over runs,
    all n and the three axes (per axis, degrees), and ``nees``, ukfm's NEES averaged over runs and all n (0 at
    n = 0)."""
    ser = np.asarray(ser)
    return {"rms_deg": float(np.sqrt(np.mean(np.square(ser[..., :3])))), "nees": float(np.mean(ser[..., 4]))}


__all__ = ["UkfmAttitudeConfig", "Draws", "jax_draws", "numpy_draws", "stacked_draws", "draws_of", "simulate_truth",
           "truth_matrices", "true_inputs", "first_moving_input", "measurements", "sensor_log", "system_of",
           "series", "initial_state", "trial", "trial_fn", "ukfm_figures", "gravity_vector", "NAMES", "UNITS",
           "RNGS", "STARTS", "UKFM_FILTERS", "LEFT_NEES", "PUBLISHED", "PUBLISHED_RUNS", "PER_SEED", "PER_SEED_NEES",
           "PER_SEED_RUNS", "PER_SEED_INITIAL_ERRORS"]
