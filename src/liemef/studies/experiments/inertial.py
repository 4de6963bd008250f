r"""The inertial-navigation benchmark of ukfm (IMU at 100 Hz, three landmarks at 1 Hz), rebuilt exactly.

The scenario (``../shared/scenarios/ukfm_inertial_navigation.md``; Brossard, Barrau, Bonnabel, ukfm
``benchmarks/inertial_navigation.py``; Barrau & Bonnabel 2017, Sec. V): a vehicle translates once around a
horizontal circle of radius 5 m (10 m across) in T = 30 s, without rotating. The state is the extended pose
$\chi = (C, v, p) \in SE_2(3)$. There are N = T / dt = 3000 states $t_n = n\,dt$ (n = 0..2999), and the noisy IMU
$u_n = (\tilde\omega_n, \tilde a_n)$ (n = 0..2998, std 0.01 rad/s and 0.01 m/s^2 per axis) moves state n to
state n + 1. Observations $y_k = (C^\top(\ell_i - p))_{i=1..3} + \varepsilon_k$ (std 0.1 m) of the landmarks
$\ell_1 = (0, 2, 2)$, $\ell_2 = (-2, -2, -2)$, $\ell_3 = (2, -2, -2)$ arrive at n = 100, 200, ..., 2900: 29
observations, since ukfm simulates $y_0$ but never uses it. The initial attitude error is $\hat C_0 = C_0
\mathrm{Exp}(\sigma_R \epsilon_R)$ with $\sigma_R = 15°/\sqrt 3$ per axis (about 15° in all), the position error
$\sigma_p \epsilon_p$ with $\sigma_p = 1/\sqrt 3$ m per axis (about 1 m), the velocity exact. Gravity is
$g = (0, 0, -9.82)$ m/s^2, ukfm's value (``gravity``).

* Truth (:func:`simulate_truth`): ukfm's reference circle $q_m = 5(\sin 2\pi t_m/T, \cos 2\pi t_m/T, 0)$ on
  ``linspace(0, T, N)``, its finite differences with dt (not T/(N-1)) as the true velocity and acceleration, the
  true IMU $\omega_m = 0$, $a_m = C_m^\top(\ddot q_m - g)$, and ukfm's step $v^+ = v + a_w dt$,
  $p^+ = p + v\,dt + a_w dt^2/2$ with $a_w = C a + g$. Hence $C_n = I$, $v_0 = v_1 = 0$ (a one-step launch), then
  |v| = 1.0475 m/s.
* Noise (:class:`Draws`): standard normals from a ``jax.random`` key (:func:`jax_draws`; Monte Carlo, ``vmap``),
  or ukfm's legacy NumPy stream for ``rng="numpy"`` (:func:`numpy_draws`): with seed k it draws ukfm's
  normals of run k in ukfm's order, so the data are ukfm's run k to round-off, not bit for bit (the operations
  differ in order; the initial errors are the scenario's table to its printed digits, a test checks it).
* Filter: :func:`~liemef.systems.inertial_navigation` with the landmarks, ukfm's noise levels and gravity. The IMU
  samples of std 0.01 at 100 Hz are the process-noise density; each observation (std 0.1 m) is one sample. Each
  IMU sample is held over its interval, and an observation at $t_n$ acts over $[t_n, t_{n+1}]$, which ukfm
  approximates by an update right after the propagation to n: ukfm's estimate at $t_n$ has seen $y_n$, liemef's
  at $t_{n+1}$. K0 = P0 = diag(σ_R² I3, 0, σ_p² I3) in the left error $\xi$ ($\chi = \hat\chi\exp\xi$): P0 is
  isotropic per block, so it is also the covariance of ukfm's SO(3) x R^6 error at $\hat\chi_0$.
* Metrics (scenario §1.5, :func:`series`), per step: the attitude error $|\mathrm{Log}(C_n^\top\hat C_n)|$ [deg], the
  velocity and position errors $|v - \hat v|$, $|p - \hat p|$ [m/s, m]; the attitude NEES
  $e_R^\top K_{RR}^{-1} e_R / 3$ and the position NEES $e^\top K_{pp}^{-1} e / 3$ with $e = \hat C^\top(p - \hat p)$,
  the body-frame position error whose first-order covariance is K's position block (ukfm's figures for its
  left UKF-M, EKF and SO(3) x R^6 UKF-M use the same quantity); and ukfm's position NEES, which for the
  right-invariant filters maps their covariance with ``M[p, phi] = +[p_hat]_x`` where the first-order map has
  a minus sign (scenario §1.5, quirk), and is the first one for every other filter. The rms are pooled over all
  n = 0..2999 (ukfm's figure); the NEES are averaged over n = 1..2999 (ukfm stores 0 at n = 0 and divides by
  3000, a factor 0.9997).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ..._linalg import mm, mv
from ...connections import CARTAN_SCHOUTEN
from ...filters import INTERPOLATIONS, MinimumEnergyFilter
from ...groups import SE23, SO3
from ...metrics import left_error, nees
from ...simulation import SensorLog
from ...systems import inertial_navigation
from ._base import UkfmGrid, setup_cache

NAMES = ("attitude", "velocity", "position", "nees_attitude", "nees_position", "nees_position_ukfm")
"""The trial's series (:func:`series`)."""
UNITS = ("deg", "m/s", "m", "1", "1", "1")
LANDMARKS = ((0.0, 2.0, 2.0), (-2.0, -2.0, -2.0), (2.0, -2.0, -2.0))
"""ukfm's landmarks (world frame, m)."""
RNGS = ("jax", "numpy")
UKFM_FILTERS = {"ukf-local": "ukf_so3xr6", "ukf-left": "ukf_left_se23", "ukf-right": "ukf_right_se23",
                "iekf-right": "iekf", "ekf": "ekf"}
"""liemef's name of each of ukfm's filters (:data:`liemef.studies.compare.FILTERS`) -> ukfm's name."""
PUBLISHED_RUNS = 20
"""The runs behind :data:`PUBLISHED`: ukfm's own code with ``np.random.seed(k)``, k = 0..19."""
PUBLISHED = {
    "ukf-local": {"attitude_deg": 2.58, "position_m": 0.286, "nees_attitude": 1.89, "nees_position": 2.59},
    "ukf-left": {"attitude_deg": 2.53, "position_m": 0.252, "nees_attitude": 1.15, "nees_position": 1.01},
    "ukf-right": {"attitude_deg": 2.53, "position_m": 0.255, "nees_attitude": 1.17, "nees_position": 1.02},
    "iekf-right": {"attitude_deg": 2.53, "position_m": 0.256, "nees_attitude": 1.23, "nees_position": 1.26},
    "ekf": {"attitude_deg": 2.88, "position_m": 0.766, "nees_attitude": 9.92, "nees_position": 232.01},
}
"""ukfm's figures from its own code over seeds 0-19 (scenario §1.6): rms over runs and all n, NEES (ukfm's
definitions) averaged over runs and steps."""
PUBLISHED_PER_SEED = {
    "ukf-local": ((3.533, 0.4582), (2.198, 0.2242), (2.828, 0.4849), (4.339, 0.3025), (0.951, 0.1818),
                  (1.524, 0.128), (3.792, 0.3302), (1.951, 0.2755), (2.03, 0.1863), (1.492, 0.2119),
                  (1.146, 0.2725), (2.495, 0.1944), (1.309, 0.3651), (3.426, 0.3958), (2.119, 0.1056),
                  (2.403, 0.2267), (2.637, 0.2353), (4.166, 0.403), (1.913, 0.1876), (1.324, 0.1521)),
    "ukf-left": ((3.524, 0.397), (2.212, 0.2075), (2.758, 0.4422), (4.026, 0.2165), (0.961, 0.179),
                 (1.529, 0.1272), (3.752, 0.2422), (1.955, 0.2519), (2.018, 0.1728), (1.518, 0.2099),
                 (1.149, 0.2737), (2.498, 0.1798), (1.328, 0.3602), (3.416, 0.3247), (2.123, 0.1004),
                 (2.405, 0.2056), (2.631, 0.2174), (3.995, 0.2948), (1.924, 0.1774), (1.322, 0.1473)),
    "ukf-right": ((3.525, 0.4034), (2.211, 0.2081), (2.627, 0.4314), (3.985, 0.2131), (0.951, 0.179),
                  (1.534, 0.1311), (3.777, 0.2706), (1.97, 0.2514), (2.024, 0.1757), (1.554, 0.2072),
                  (1.139, 0.2732), (2.549, 0.178), (1.363, 0.3602), (3.392, 0.3267), (2.108, 0.1088),
                  (2.451, 0.2039), (2.632, 0.2274), (3.99, 0.3154), (1.962, 0.1794), (1.326, 0.1487)),
    "iekf-right": ((3.527, 0.4109), (2.212, 0.2091), (2.689, 0.4385), (3.99, 0.2096), (0.961, 0.1789),
                   (1.528, 0.1301), (3.771, 0.2696), (1.961, 0.2508), (2.023, 0.1768), (1.561, 0.2074),
                   (1.149, 0.2736), (2.503, 0.1774), (1.356, 0.3584), (3.396, 0.3341), (2.123, 0.1104),
                   (2.408, 0.1891), (2.641, 0.2295), (3.985, 0.3217), (1.928, 0.1785), (1.326, 0.1474)),
    "ekf": ((3.722, 1.3105), (2.256, 0.5808), (2.885, 0.8533), (4.34, 1.3284), (0.933, 0.1844), (1.503, 0.2707),
            (4.82, 1.4009), (1.956, 0.4825), (2.088, 0.4214), (1.456, 0.2661), (1.163, 0.2944), (2.382, 0.5572),
            (1.302, 0.4161), (3.41, 1.1753), (2.183, 0.114), (2.36, 0.3188), (2.697, 0.3376), (6.306, 1.4886),
            (1.896, 0.4623), (1.341, 0.1508)),
}
"""ukfm's per-seed rms (attitude deg, position m; all n) of seeds 0-19 (scenario §1.6)."""
PUBLISHED_INITIAL_ERRORS = ((18.87, 1.555), (11.60, 0.645), (13.55, 1.911), (21.02, 0.636), (2.28, 0.807),
                            (7.95, 0.283), (20.38, 0.772), (10.33, 1.224), (10.73, 0.717), (6.60, 0.693),
                            (5.38, 1.224), (12.17, 0.406), (6.22, 1.658), (18.30, 1.109), (11.33, 0.236),
                            (12.59, 0.705), (14.20, 0.930), (21.57, 1.141), (9.60, 0.566), (7.04, 0.657))
"""The initial attitude (deg) and position (m) errors of ukfm's runs 0-19 (scenario §1.6)."""


@dataclass(frozen=True)
class InertialConfig(UkfmGrid):
    r"""ukfm's inertial-navigation benchmark (module docstring); defaults are the scenario's.

    Fields:
        seed: the run's key is ``jax.random.key(seed)`` (``rng="jax"``) or ``np.random.seed(seed)``
            (``rng="numpy"``, ukfm's legacy stream).
        duration, dt: T and the IMU period: N = round(T / dt) states at t_n = n dt (n < N).
        radius, period: the circle (m) travelled once in ``period`` (s): ukfm's reference circle on
            ``linspace(0, period, round(period / dt))``; a shorter ``duration`` runs the first part of the same
            motion, a longer one goes on round (ukfm ties the period to T: the defaults are its scenario).
        gravity: magnitude (m/s^2), ukfm's 9.82.
        landmarks: the known world points (m), a tuple of 3-tuples.
        imu_std: per-sample std of the gyro (rad/s) and the accelerometer (m/s^2).
        obs_period: time between observations (s), a whole number of IMU periods; observations at
            n = m, 2m, ... < N, m = obs_period / dt (none at n = 0).
        obs_std: std of one landmark coordinate (m).
        rot0_std, p0_std: per-axis std of the initial attitude (rad) and position (m) errors; K0 =
            diag(rot0_std^2 I3, 0, p0_std^2 I3).
        connection, order, integrator, interpolation: the minimum-energy filter
            (:class:`~liemef.MinimumEnergyFilter`).
        steady: start of the second window of the rms (s): ukfm reports all n, the scenario's t >= 10 s column
            is this window.
        rng: ``"jax"`` or ``"numpy"``.
    """

    seed: int = 0
    duration: float = 30.0
    dt: float = 0.01
    radius: float = 5.0
    period: float = 30.0
    gravity: float = 9.82
    landmarks: tuple[tuple[float, float, float], ...] = LANDMARKS
    imu_std: tuple[float, float] = (0.01, 0.01)
    obs_period: float = 1.0
    obs_std: float = 0.1
    rot0_std: float = math.radians(15.0) / math.sqrt(3.0)
    p0_std: float = 1.0 / math.sqrt(3.0)
    connection: str = "zero"
    order: str = "second"
    integrator: str = "rkmk4"
    interpolation: str = "hold"
    steady: float = 10.0
    rng: str = "jax"

    window_times = ("steady",)  # follow a new duration (RunConfig.window_changes)

    def __post_init__(self):
        self._check_run(positive=("radius", "period", "gravity", "obs_period", "obs_std", "rot0_std", "p0_std"))
        _validate.choice("connection", self.connection, set(CARTAN_SCHOUTEN))
        _validate.choice("interpolation", self.interpolation, set(INTERPOLATIONS))
        _validate.choice("rng", self.rng, set(RNGS))
        pts = _validate.array("landmarks", np.asarray(self.landmarks, dtype=np.float64), (None, 3))
        if pts.shape[0] == 0:
            raise ValueError("landmarks: expected one or more landmark positions (L, 3), got none")
        std = _validate.array("imu_std", self.imu_std, (2,))
        if np.any(std <= 0):
            raise ValueError(f"imu_std: expected two stds > 0 (gyro, accelerometer), got {tuple(self.imu_std)}")
        m = self.obs_period / self.dt
        if abs(m - round(m)) > 1e-9 * m:
            raise ValueError(f"obs_period: expected a whole number of IMU periods dt = {self.dt}, got "
                             f"{self.obs_period}")
        _validate.nonnegative("steady", self.steady)
        self._freeze(floats=("radius", "period", "gravity", "obs_period", "obs_std", "rot0_std", "p0_std", "steady"),
                     tuples=("imu_std",))
        object.__setattr__(self, "landmarks", tuple(tuple(float(c) for c in row) for row in pts))
        if round(self.period / self.dt) < 3:
            raise ValueError(f"period: expected at least 3 steps dt = {self.dt}, got {self.period}")
        if self.n_states < 3 or self.steady > self.ts[-1]:
            raise ValueError(f"steady: expected a start within the run [0, {self.ts[-1]:g}] s, got {self.steady}")
        if self.obs_indices.size == 0:
            raise ValueError(f"duration: expected at least one observation period {self.obs_period:g} s, got "
                             f"{self.duration:g} s")

    @property
    def obs_indices(self) -> np.ndarray:
        """The IMU indices of the observations the filters use: m, 2m, ... < N (ukfm's y_0 is never used)."""
        return self.every(self.obs_period)

    @property
    def K0(self) -> np.ndarray:
        """diag(rot0_std^2 I3, 0 I3, p0_std^2 I3): ukfm's P0, the covariance of the left error too."""
        return np.diag([self.rot0_std**2] * 3 + [0.0] * 3 + [self.p0_std**2] * 3)


# --- the scenario -------------------------------------------------------------------------------------------
def gravity_vector(config: InertialConfig) -> np.ndarray:
    """``(0, 0, -gravity)``: z up."""
    return np.array([0.0, 0.0, -config.gravity])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    r"""ukfm's ``SO3.exp`` in NumPy (scenario §1.2): Rodrigues' formula, $I + [\phi]_\times$ below 1e-8 rad."""
    a = float(np.linalg.norm(phi))
    S = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if a < 1e-8:
        return np.eye(3) + S
    u = phi / a
    return math.cos(a) * np.eye(3) + (1.0 - math.cos(a)) * np.outer(u, u) + math.sin(a) * S / a


def ukfm_step(C, v, p, omega, a, g, dt):
    r"""ukfm's ``INERTIAL_NAVIGATION.f`` (scenario §1.2), in NumPy: $a_w = C a + g$, $C^+ = C\,\mathrm{Exp}(\omega dt)$,
    $v^+ = v + a_w dt$, $p^+ = p + v dt + a_w dt^2 / 2$ (the attitude and velocity before the step)."""
    a_w = C @ a + g
    return C @ exp_so3(omega * dt), v + a_w * dt, p + v * dt + 0.5 * a_w * dt**2


@functools.lru_cache(maxsize=8)
def _truth_arrays(config: InertialConfig):
    n, dt, T = config.n_states, config.dt, config.period
    t = np.arange(n) * (T / (round(T / dt) - 1))  # ukfm's linspace(0, T, N): not m dt (scenario §1.3)
    q = config.radius * np.column_stack([np.sin(2 * np.pi * t / T), np.cos(2 * np.pi * t / T), np.zeros(n)])
    vc, ac = np.zeros_like(q), np.zeros_like(q)
    vc[1:] = (q[1:] - q[:-1]) / dt
    ac[1:] = (vc[1:] - vc[:-1]) / dt
    g = gravity_vector(config)
    C, v, p = np.eye(3), vc[0].copy(), q[0].copy()
    Cs, vs, ps = [C], [v], [p]
    us = np.zeros((n - 1, 6))  # the true gyro is 0, so C stays I (scenario §1.3)
    for m in range(n - 1):
        us[m, 3:] = C.T @ (ac[m] - g)
        C, v, p = ukfm_step(C, v, p, us[m, :3], us[m, 3:], g, dt)
        Cs.append(C), vs.append(v), ps.append(p)
    return np.stack(Cs), np.stack(vs), np.stack(ps), us


def simulate_truth(config: InertialConfig) -> tuple[SE23, np.ndarray]:
    """The true states ``chi[n]`` (an :class:`~liemef.groups.SE23` of batch shape (N,)) and the true IMU
    ``u[n] = (omega, a)`` (N - 1, 6), by ukfm's step in floating point (:func:`ukfm_step`; the true attitude is
    I throughout)."""
    Cs, vs, ps, us = _truth_arrays(dataclasses.replace(config, seed=0, rng="jax"))
    return SE23.from_rotation_velocity_position(SO3.from_matrix(jnp.asarray(Cs)), vs, ps), us


class Draws(NamedTuple):
    """The standard normals of one run: ``gyro`` and ``acc`` (N-1, 3) per IMU sample, ``obs`` (K, 9) per
    observation used (landmark 1 xyz, 2 xyz, 3 xyz), ``rot0`` and ``p0`` (3,) the initial errors."""

    gyro: jax.Array
    acc: jax.Array
    obs: jax.Array
    rot0: jax.Array
    p0: jax.Array


def jax_draws(config: InertialConfig, key) -> Draws:
    """The draws of one run from a ``jax.random`` key (traceable)."""
    n, k, p = config.n_states, config.obs_indices.size, 3 * len(config.landmarks)
    k_g, k_a, k_o, k_r, k_p = jax.random.split(key, 5)
    return Draws(jax.random.normal(k_g, (n - 1, 3)), jax.random.normal(k_a, (n - 1, 3)),
                 jax.random.normal(k_o, (k, p)), jax.random.normal(k_r, (3,)), jax.random.normal(k_p, (3,)))


def numpy_draws(config: InertialConfig, seed: int) -> Draws:
    """The draws of ukfm's run after ``np.random.seed(seed)``, in its order (scenario §1.3): for n = 1..N-1
    ``randn(3)`` (gyro) then ``randn(3)`` (accelerometer); for each observation k = 0, 1, ... (including the
    unused y_0) ``randn(9)``; then ``randn(3)`` (attitude) and ``randn(3)`` (position). The legacy Gaussian
    caches its second value across calls, so consecutive calls are one stream."""
    rs = np.random.RandomState(seed)
    n, p = config.n_states, 3 * len(config.landmarks)
    imu = rs.randn(6 * (n - 1)).reshape(n - 1, 6)
    k = 1 + config.obs_indices.size  # with y_0
    obs = rs.randn(p * k).reshape(k, p)[1:]
    rot0 = rs.randn(3)
    return Draws(jnp.asarray(imu[:, :3]), jnp.asarray(imu[:, 3:]), jnp.asarray(obs), jnp.asarray(rot0),
                 jnp.asarray(rs.randn(3)))


def stacked_draws(config: InertialConfig, rng: str, seed: int, runs: int) -> Draws:
    """The draws of ``runs`` trials stacked (leading axis: trial): ``rng="jax"``: trial i from
    ``split(key(seed), runs)[i]``; ``rng="numpy"``: ukfm's legacy stream after ``np.random.seed(seed + i)``,
    the data of ukfm's own runs."""
    _validate.choice("rng", rng, set(RNGS))
    if rng == "numpy":
        draws = [numpy_draws(config, seed + i) for i in range(runs)]
        return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *draws)
    keys = jax.random.split(jax.random.key(seed), runs)
    return jax.jit(jax.vmap(lambda k: jax_draws(config, k)))(keys)


def landmark_output(config: InertialConfig, g: SE23) -> jax.Array:
    r"""$h(\chi) = (C^\top(\ell_i - p))_i$, (..., 3L): ukfm's observation (its code's sign)."""
    Rt = jnp.swapaxes(g.rotation().as_matrix(), -1, -2)
    rel = jnp.asarray(config.landmarks) - g.position()[..., None, :]
    return jnp.einsum("...ij,...lj->...li", Rt, rel).reshape(*rel.shape[:-2], -1)


def sensor_log(config: InertialConfig, truth: SE23, u_true, draws: Draws) -> tuple[SensorLog, SE23]:
    """The filters' log and initial estimate from the truth and the draws (traceable): ``us[n] = u_n + std
    eps`` (n < N-1; the last row repeats, it is never used), ``ys`` NaN except :func:`landmark_output` plus
    ``obs_std eps`` at the observations, and ``chi_hat_0 = (C_0 Exp(rot0_std eps_R), v_0, p_0 + p0_std eps_p)``."""
    gyro_std, acc_std = config.imu_std
    u = jnp.asarray(u_true) + jnp.concatenate([gyro_std * draws.gyro, acc_std * draws.acc], axis=-1)
    us = jnp.concatenate([u, u[-1:]])
    idx = jnp.asarray(config.obs_indices)
    at = jax.tree_util.tree_map(lambda a: a[idx], truth)
    ys = (jnp.full((config.n_states, 3 * len(config.landmarks)), jnp.nan)
          .at[idx].set(landmark_output(config, at) + config.obs_std * draws.obs))
    g0 = jax.tree_util.tree_map(lambda a: a[0], truth)
    g0_hat = SE23.from_rotation_velocity_position(g0.rotation() @ SO3.exp(config.rot0_std * draws.rot0),
                                                  g0.velocity(), g0.position() + config.p0_std * draws.p0)
    return SensorLog(ts=jnp.asarray(config.ts), us=us, ys=ys), g0_hat


def system_of(config: InertialConfig):
    """:func:`~liemef.systems.inertial_navigation` with the scenario's landmarks, noise levels and gravity."""
    gyro_std, acc_std = config.imu_std
    return inertial_navigation(gyro_std=gyro_std, acc_std=acc_std, imu_rate=1.0 / config.dt, gnss_std=None,
                               landmarks=np.asarray(config.landmarks), landmark_std=config.obs_std,
                               gravity=config.gravity)


@dataclass(frozen=True)
class Setup:
    """Everything a trial needs, independent of the seed (cached per config): the system, the configured
    minimum-energy filter, the truth and the true IMU."""

    config: InertialConfig
    system: object
    filter: MinimumEnergyFilter
    truth: SE23
    u_true: np.ndarray


@setup_cache(rng="jax")
def setup(config: InertialConfig) -> Setup:
    """The system, filter and truth of ``config`` (cached; the seed and the RNG do not enter)."""
    system = system_of(config)
    flt = MinimumEnergyFilter(system, curvature="exact", error="left", connection=config.connection, order=config.order,
                              integrator=config.integrator, interpolation=config.interpolation)
    truth, u_true = simulate_truth(config)
    return Setup(config=config, system=system, filter=flt, truth=truth, u_true=u_true)


def ukfm_initial_K(name: str, config: InertialConfig, g0_hat: SE23) -> jax.Array:
    r"""The initial covariance ukfm's benchmark gives its filter ``name`` (a key of :data:`UKFM_FILTERS`), as the
    covariance of the left error at ``g0_hat`` (traceable; scenario §1.4, "initial covariance conversion").

    ukfm hands ``P0`` to its SO(3) x R^6 and left UKF-M, and ``right_P0 = J_0 P_0 J_0^\top`` ($J_0 = I$ except
    $J_0[p, \phi] = [\hat p_0]_\times$, the first-order map to the right-invariant error) to its IEKF, each in its
    own coordinates. Two quirks: the EKF, whose coordinates are SO(3) x R^6, also gets ``right_P0``, and the
    right UKF-M, whose coordinates are right-invariant, gets the unconverted ``P0``. The matrix is mapped to the
    left error by the exact Jacobian of each chart at ``g0_hat`` (SO(3) x R^6 with ukfm's world-frame rotation
    error, $C = \mathrm{Exp}(e_\phi)\hat C$)."""
    _validate.choice("name", name, set(UKFM_FILTERS))
    P0 = jnp.asarray(config.K0)
    J0 = jnp.eye(9).at[6:9, 0:3].set(_skew(g0_hat.position()))
    right_P0 = J0 @ P0 @ J0.T
    world = lambda g, e: SE23.from_rotation_velocity_position(  # noqa: E731
        SO3.exp(e[:3]) @ g.rotation(), g.velocity() + e[3:6], g.position() + e[6:9])
    right = lambda g, e: SE23.exp(e) @ g  # noqa: E731
    plus, P = {"ukf-local": (world, P0), "ukf-left": (lambda g, e: g @ SE23.exp(e), P0), "ukf-right": (right, P0),
               "iekf-right": (right, right_P0), "ekf": (world, right_P0)}[name]
    J = jax.jacfwd(lambda e: left_error(plus(g0_hat, e), g0_hat))(jnp.zeros(9))
    return J @ P @ J.T


# --- the metrics --------------------------------------------------------------------------------------------
def _skew(w):
    z = jnp.zeros(w.shape[:-1])
    return jnp.stack([jnp.stack([z, -w[..., 2], w[..., 1]], -1), jnp.stack([w[..., 2], z, -w[..., 0]], -1),
                      jnp.stack([-w[..., 1], w[..., 0], z], -1)], -2)


def series(truth: SE23, g_hat: SE23, K, *, right: bool = False) -> jax.Array:
    r"""(N, 6), the :data:`NAMES` (module docstring; scenario §1.5), traceable. ``K`` is the covariance of the
    left error (every liemef filter's); ``right``: the filter's own error is right-invariant, and ukfm's position
    NEES maps its covariance $P = \mathrm{Ad}_{\hat\chi} K \mathrm{Ad}_{\hat\chi}^\top$ by ukfm's
    $M$ ($M_{p\phi} = +[\hat p]_\times$)."""
    xi = left_error(truth, g_hat)
    e_R = xi[..., :3]  # Log(C_hat^T C) exactly: minus ukfm's Log(C^T C_hat), the same norm
    e_v = truth.velocity() - g_hat.velocity()
    e_p = truth.position() - g_hat.position()
    Rt = jnp.swapaxes(g_hat.rotation().as_matrix(), -1, -2)
    nees_p = nees(mv(Rt, e_p), K[..., 6:9, 6:9]) / 3.0
    if right:
        Ad = g_hat.Ad()
        P = mm(Ad, mm(K, jnp.swapaxes(Ad, -1, -2)))
        S = _skew(g_hat.position())
        P_pp = (mm(S, mm(P[..., 0:3, 0:3], jnp.swapaxes(S, -1, -2))) + mm(S, P[..., 0:3, 6:9])
                + mm(P[..., 6:9, 0:3], jnp.swapaxes(S, -1, -2)) + P[..., 6:9, 6:9])
        nees_ukfm = nees(e_p, P_pp) / 3.0
    else:
        nees_ukfm = nees_p
    return jnp.stack([jnp.degrees(jnp.linalg.norm(e_R, axis=-1)), jnp.linalg.norm(e_v, axis=-1),
                      jnp.linalg.norm(e_p, axis=-1), nees(e_R, K[..., 0:3, 0:3]) / 3.0, nees_p, nees_ukfm], axis=-1)


__all__ = ["InertialConfig", "Draws", "jax_draws", "numpy_draws", "stacked_draws", "simulate_truth", "sensor_log",
           "landmark_output", "system_of", "setup", "Setup", "series", "ukfm_initial_K", "ukfm_step", "exp_so3",
           "NAMES", "UNITS",
           "PUBLISHED", "PUBLISHED_PER_SEED", "PUBLISHED_INITIAL_ERRORS", "PUBLISHED_RUNS", "UKFM_FILTERS",
           "LANDMARKS"]
