r"""The unit circle with a biased gyro on SO(2) x R: Zamani, Hua, Trumpf, Mahony, Sec. IV, Figs. 2-3.

Printed in the paper: $\theta_0$ = 45 deg, initial bias 45 deg per time unit, $B_\omega$ = 17 deg/s,
$B_b$ = 52 deg/s$^2$, D = 0.4 I, $\omega(t) = \sin(0.25 t)$, bias jumps at t = 25 and 75 (Fig. 3), the filter
started at $\hat X(0) = I$, $\hat b(0) = 0$ with $P(0) = \mathrm{diag}(1/K_1, 1/K_2)$ (eq. (39)).

**Not printed** (our choices, recorded in ``metrics.json``): the final time (T = 100, the jumps being "in the
first quarter and the third quarter of the simulation time", Fig. 2), the sizes of the jumps (+45 deg/s at
t = 25 and -90 deg/s at t = 75: the bias goes 45 -> 90 -> 0 deg/s), $K_1 = K_2 = 1$, the sampling
(dt = 0.01, one gyro and one vector sample per step, held), and the noise of the angle measurement of
Lemma 2 (0.4 rad, the scale of D).

The truth is exact: $\theta(t) = \theta_0 + (1 - \cos(t/4))/0.25$ and the bias is piecewise constant (the
jumps are part of the truth's model, not of the filter's, which models the bias as $\dot b = B_b v_b$). The gyro
reads $u_k = \omega(t_k) + b(t_k) + B_\omega v_k$ and the magnetometer-like sensor $y_k = X_k^\top (1, 0)^\top
+ D w_k$, with $v_k \sim N(0, 1)$, $w_k \sim N(0, I_2)$ per sample (the paper's "zero mean random variables
with standard deviations ..."). The filter's initial gain is the paper's $P(0) = \mathrm{diag}(1/K_1, 1/K_2)$,
i.e. $K(0) = \mathrm{diag}(K_1, K_2)$, although the left-trivialized Hessian of the initial cost (12) is
$\mathrm{diag}(2/K_1, 1/K_2)$ (``docs/errata.md``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...connections import CARTAN_SCHOUTEN
from ...filters import MinimumEnergyFilter, Trajectory
from ...groups import R1, SO2, SO2R1
from ...metrics import FULL, Window, state_error
from ...simulation import SensorLog, Truth
from ...systems.unit_circle import DEG, MEASUREMENTS, UnitCircleBias
from .. import registry
from ._base import PAPER_SUBSTEPS, Experiment, FigureSpec, Result, RunConfig, TrialSpec, register, setup_cache
from ._evaluate import evaluate, state_error_trial

OMEGA_RATE = 0.25
"""omega(t) = sin(0.25 t) (Zamani et al., Sec. IV)."""


def angular_velocity(t):
    r"""The true angular velocity $\omega(t) = \sin(0.25\,t)$ (Zamani et al., Sec. IV)."""
    return jnp.sin(OMEGA_RATE * jnp.asarray(t))


@dataclass(frozen=True)
class UnitCircleConfig(RunConfig):
    r"""The unit circle experiment (Zamani et al., Sec. IV). Angles and rates in degrees here.

    Fields:
        seed: the run's key is ``jax.random.key(seed)``.
        duration, dt: final time T and the sample step (one gyro and one measurement sample per filter step).
        measurement: ``"vector"`` (eq. (39), the paper's simulation) or ``"angle"`` (Lemma 2, eq. (40) with
            the corrected sign; the filter then has D = I).
        theta0_deg, bias0_deg: the true initial angle (deg) and bias (deg/s).
        jump_times, jumps_deg: the bias jumps of the truth, at these times by these amounts (deg/s).
        B_omega_deg, B_b_deg: the filter's model-error scales (deg/s, deg/s^2); B_omega_deg is also the std
            of the simulated gyro noise per sample.
        noise_std: std of the measurement noise per sample: D = noise_std I for the vector measurement (the
            filter's D too), in rad for the angle measurement.
        K1, K2: the initial gain P(0) = diag(1/K1, 1/K2), i.e. K(0) = diag(K1, K2).
        settle: seconds after the start and after each jump excluded from the "tracking" windows.
        connection, order, integrator: the filter (SO(2) x R is abelian: every connection gives the same
            filter).
    """

    seed: int = 0
    duration: float = 100.0
    dt: float = 0.01
    measurement: str = "vector"
    theta0_deg: float = 45.0
    bias0_deg: float = 45.0
    jump_times: tuple[float, ...] = (25.0, 75.0)
    jumps_deg: tuple[float, ...] = (45.0, -90.0)
    B_omega_deg: float = 17.0
    B_b_deg: float = 52.0
    noise_std: float = 0.4
    K1: float = 1.0
    K2: float = 1.0
    settle: float = 10.0
    connection: str = "zero"
    order: str = "second"
    integrator: str = "rkmk4"

    def __post_init__(self):
        self._check_run(positive=("B_omega_deg", "B_b_deg", "noise_std", "K1", "K2"))
        _validate.choice("measurement", self.measurement, set(MEASUREMENTS))
        _validate.choice("connection", self.connection, set(CARTAN_SCHOUTEN))
        _validate.nonnegative("settle", self.settle)
        _validate.array("theta0_deg", self.theta0_deg, ())
        _validate.array("bias0_deg", self.bias0_deg, ())
        times = _validate.array("jump_times", self.jump_times, (None,))
        _validate.array("jumps_deg", self.jumps_deg, (times.shape[0],))
        if times.size > 1 and not np.all(np.diff(times) > 0):
            raise ValueError(f"jump_times: expected increasing times, got {self.jump_times}")
        self._freeze(floats=("theta0_deg", "bias0_deg", "B_omega_deg", "B_b_deg", "noise_std", "K1", "K2", "settle"),
                     tuples=("jump_times", "jumps_deg"))

    @property
    def windows(self) -> tuple[Window, ...]:
        """The whole run and, between the jumps, the stretches from ``settle`` s after the start or a jump."""
        edges = self.segment_edges
        return (FULL, *(Window(a + self.settle, b) for a, b in zip(edges[:-1], edges[1:], strict=True)
                        if a + self.settle < b))

    @property
    def segment_edges(self) -> tuple[float, ...]:
        """0, the jump times before the final time, and the final time."""
        return (0.0, *(t for t in self.jump_times if t < self.duration), self.duration)


def true_bias(config: UnitCircleConfig, ts) -> jax.Array:
    """The truth's piecewise-constant bias (rad/s) at times ``ts``: the initial bias plus the jumps so far."""
    ts = jnp.asarray(ts)
    b = jnp.full(ts.shape, config.bias0_deg * DEG)
    for t_j, jump in zip(config.jump_times, config.jumps_deg, strict=True):
        b = b + jnp.where(ts >= t_j, jump * DEG, 0.0)
    return b


def true_angle(config: UnitCircleConfig, ts) -> jax.Array:
    r"""$\theta(t) = \theta_0 + \int_0^t \sin(0.25 s)\,ds$, exact (rad, not wrapped)."""
    ts = jnp.asarray(ts)
    return config.theta0_deg * DEG + (1.0 - jnp.cos(OMEGA_RATE * ts)) / OMEGA_RATE


@dataclass(frozen=True)
class Setup:
    """What a trial needs, independent of the seed (cached per config with ``seed = 0``)."""

    config: UnitCircleConfig
    system: UnitCircleBias
    filter: MinimumEnergyFilter
    state0: object
    ts: np.ndarray


@setup_cache()
def setup(config: UnitCircleConfig) -> Setup:
    """The system, filter, initial state and time grid of ``config`` (cached)."""
    system = UnitCircleBias(measurement=config.measurement, B_omega=config.B_omega_deg * DEG,
                            B_b=config.B_b_deg * DEG,
                            D=config.noise_std * np.eye(2) if config.measurement == "vector" else None)
    flt = MinimumEnergyFilter(system, curvature="exact", error="left", connection=config.connection, order=config.order,
                              integrator=config.integrator, substeps=PAPER_SUBSTEPS)
    # Zamani et al., eq. (39): X_hat(0) = I, b_hat(0) = 0, P(0) = diag(1/K1, 1/K2), K = P^-1
    state0 = flt.init(UnitCircleBias.state(0.0, 0.0), np.diag([config.K1, config.K2]))
    return Setup(config=config, system=system, filter=flt, state0=state0, ts=config.ts)


def simulate_circle(s: Setup, key) -> tuple[Truth, SensorLog]:
    """The exact truth and the noisy gyro and measurement samples for one key (traceable).

    ``log.ys`` are what the filter is fed: the vector samples, or for the angle measurement the vectors
    :meth:`~liemef.systems.UnitCircleBias.angle_to_vector` of the angle samples (Lemma 2).
    """
    c = s.config
    ts = jnp.asarray(s.ts)
    N = ts.shape[0]
    k_u, k_y = jax.random.split(key)
    theta, b = true_angle(c, ts), true_bias(c, ts)
    g = SO2R1((SO2.from_angle(theta), R1(b[:, None])))
    u_nominal = (angular_velocity(ts) + b)[:, None]  # Zamani et al., eq. (7) without v_omega
    us = u_nominal + c.B_omega_deg * DEG * jax.random.normal(k_u, (N, 1))
    if c.measurement == "vector":
        ys = jax.vmap(s.system.output)(g, ts) + jax.random.normal(k_y, (N, 2)) @ s.system.D.T  # eq. (9)
    else:
        ys = UnitCircleBias.angle_to_vector(theta + c.noise_std * jax.random.normal(k_y, (N,)))  # eq. (11)
    return Truth(ts=ts, g=g, u=u_nominal), SensorLog(ts=ts, us=us, ys=ys)


def trial(s: Setup, key) -> tuple[Truth, SensorLog, Trajectory]:
    """Simulation and filter run for one key: traceable, ``vmap``-able over keys."""
    truth, log = simulate_circle(s, key)
    return truth, log, s.filter.scan(s.state0, log.ts, log.us, log.ys, engine=None)


@functools.lru_cache(maxsize=8)
def _simulate_compiled(config: UnitCircleConfig):
    s = setup(config)
    return jax.jit(lambda key: simulate_circle(s, key))


def bias_tracking(config: UnitCircleConfig, ts: np.ndarray, bias_error: np.ndarray, band_deg: float = 10.0) -> list:
    """Per segment (the start, then each jump): the bias error ``b - b_hat`` right after it and the settle
    time, after which |b - b_hat| first falls below ``band_deg`` deg/s (None if not before the next jump)."""
    edges = config.segment_edges
    out = []
    for j, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        seg = (ts >= a) & ((ts < b) if j < len(edges) - 2 else (ts <= b))
        if not seg.any():
            continue
        e, t_seg = bias_error[seg] / DEG, ts[seg]
        inside = np.flatnonzero(np.abs(e) < band_deg)
        out.append({"t": float(a), "jump_deg_s": None if j == 0 else config.jumps_deg[j - 1],
                    "error_after_deg_s": float(e[0]),
                    "settle_time_s": float(t_seg[inside[0]] - a) if inside.size else None,
                    "band_deg_s": band_deg})
    return out


def _assumptions(c: UnitCircleConfig) -> dict:
    jumps = ", ".join(f"{d:+g} deg/s at t = {t:g}" for t, d in zip(c.jump_times, c.jumps_deg, strict=True))
    return {
        "duration": f"T = {c.duration:g} (not printed; the jumps fall in the first and third quarters, Fig. 2)",
        "bias": f"initial {c.bias0_deg:g} deg/s, piecewise constant with jumps {jumps} (sizes not printed; "
                "our choice). The jumps are in the truth only; the filter models b_dot = B_b v_b",
        "K1_K2": f"K1 = {c.K1:g}, K2 = {c.K2:g} (free in the paper); P(0) = diag(1/K1, 1/K2) as the paper states "
                 "(the Hessian of the initial cost (12) would give 2/K1)",
        "sampling": f"one gyro and one measurement sample every dt = {c.dt:g}, held (not printed)",
        "noise": f"per sample: gyro B_omega v, v ~ N(0, 1), B_omega = {c.B_omega_deg:g} deg/s; "
                 + (f"vector D w, w ~ N(0, I2), D = {c.noise_std:g} I" if c.measurement == "vector"
                    else f"angle w' ~ N(0, {c.noise_std:g}^2) rad (not printed), filter D = I (Lemma 2)"),
        "measurement": ("vector, eq. (39)" if c.measurement == "vector" else
                        "angle, Lemma 2 (eq. (40)) with the sign of eq. (39): represented as the vector "
                        "(cos y'', -sin y'') with D = Q = I"),
        "truth": "exact: theta(t) = theta0 + (1 - cos(t/4))/0.25, bias piecewise constant",
    }


def measured_state(ys: np.ndarray) -> np.ndarray:
    """The state coordinates (theta, b) read off vector measurements (N, 2): the angle ``atan2(-y2, y1)``; the
    bias is not measured (NaN)."""
    ys = np.asarray(ys, dtype=np.float64)
    out = np.full((ys.shape[0], 2), np.nan)
    out[:, 0] = np.asarray(UnitCircleBias.vector_to_angle(ys))
    return out


def run(config: UnitCircleConfig | None = None, key=None) -> Result:
    """Simulate, filter and evaluate one run (key ``jax.random.key(config.seed)`` unless given)."""
    c = UnitCircleConfig() if config is None else config
    s = setup(c)
    key = jax.random.key(c.seed) if key is None else key
    truth, log = _simulate_compiled(s.config)(key)
    traj = s.filter.run(s.state0, log.ts, log.us, log.ys)
    ts = np.asarray(s.ts)
    measured = measured_state(np.asarray(log.ys))
    err = np.asarray(state_error(truth.g, traj.g_hat))
    extra = {"bias_tracking": {
        "definition": "per segment (start, then each jump): the bias error b - b_hat right after it and the time "
                      "until |b - b_hat| first falls inside the band (None: not before the next jump)",
        "segments": bias_tracking(c, ts, err[:, 1])}}
    extra_arrays = {"omega_true": np.asarray(angular_velocity(ts)), "measured_angle": measured[:, 0]}
    return evaluate(UNIT_CIRCLE, c, s.filter, truth, log, traj, measured, c.windows, _assumptions(c),
                    extra_metrics=extra, extra_arrays=extra_arrays)


def trial_spec(config: UnitCircleConfig) -> TrialSpec:
    """The Monte Carlo trial of ``config``: (theta, b) errors of one seeded run (traceable in the key)."""
    return state_error_trial(setup(config), trial, config.windows)


QUICK = UnitCircleConfig(dt=0.02)
"""Reduced config for ``liemef reproduce all``: the whole 100 s (the jumps are the point) at 20 ms."""

UNIT_CIRCLE = register(Experiment(
    **registry.card("unit-circle"),
    default_config=UnitCircleConfig(),
    run_fn=run,
    trial_fn=trial_spec,
    runs=100,
    quick_config=QUICK,
    quick_runs=20,
    figures=(
        FigureSpec("fig2_angle.png", ("theta",),
                   "Angle: truth (black), measured (blue), filtered (green); error (red)", "Zamani et al., Fig. 2"),
        FigureSpec("fig3_bias.png", ("b",),
                   "Gyro bias: truth (black, jumps at t = 25 and 75), filtered (green); error (red)",
                   "Zamani et al., Fig. 3"),
    ),
))
