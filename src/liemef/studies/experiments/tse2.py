r"""Planar rigid body on TSE(2): Rigo et al. 2022, Sec. VI, Figs. 3-4, and the velocity-only sensor of the
Segala poster.

The truth is generated from the nominal input $u_\omega = \sin t$, $u_v = 50 \sin(t/50)$ (no model error by
default, as in the paper); the filter is fed the same nominal input and the noisy measurements, one
measurement per integration step. Experiments:

* ``tse2``: GPS (two antennas) + IMU, the paper's Figs. 3 (pose) and 4 (velocities);
* ``tse2-velocity``: IMU only, ``PlanarRigidBody(sensor="velocity")``: the pose is not observed, the filter
  dead-reckons it from its velocity estimate.

:func:`trial` is the traceable core (simulation + filter for one key, ``vmap``-able over keys);
:func:`run` adds the checked conversions, metrics and arrays of a :class:`~liemef.studies.experiments.Result`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...connections import CARTAN_SCHOUTEN
from ...filters import MinimumEnergyFilter, Trajectory, terms
from ...metrics import FULL, Window, state_error
from ...simulation import SensorLog, Truth, simulate, simulate_core
from ...systems import PlanarRigidBody, tse2_state
from ...systems.planar_rigid_body import SENSORS
from .. import registry
from ._base import PAPER_SUBSTEPS, Experiment, FigureSpec, Result, RunConfig, TrialSpec, register, setup_cache
from ._evaluate import evaluate, state_error_trial


def paper_input(t):
    r"""The nominal input of Rigo et al. 2022, Sec. VI: $(u_\omega, u_v) = (\sin t, 50\sin(t/50))$."""
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


WEIGHTS = {
    "printed": "Q = D'D, R = B'B as printed (Rigo et al. 2022): D^-T Q D^-1 = I and B R^-1 B' = I on the velocity "
               "block, the filter is not weighted by the noise levels",
    "consistent": "Q = I, R = I (our alternative): the residual weighted by D^-T D^-1 (diag(4 x4, 100 x3) with "
                  "GPS + IMU, 100 I3 with the velocity sensor), the model error by B B' = 0.01 I3",
}
"""The experiment's weight choices (``TSE2Config.weights``) and what they mean."""


@dataclass(frozen=True)
class TSE2Config(RunConfig):
    r"""The planar rigid body experiment (Rigo et al. 2022, Sec. VI).

    Printed in the paper: J = 6.125, m = 125, l = 0.2, T = 50 s, RK4 with h = 1 ms, truth from
    ``truth0`` = (pi/6, 1, 2, 0, 0, 0), filter from ``filter0`` = (pi/8, 1.1, 2.1, 0.1, -0.1, -0.1),
    B2 = 0.1 I3, R = B'B, D = diag(0.5 x4, 0.1 x3), Q = D'D (the :class:`~liemef.systems.PlanarRigidBody`
    defaults).

    ``weights="consistent"`` replaces the printed Q = D'D, R = B'B by Q = I, R = I: with the printed choice
    D^-T Q D^-1 = I and B R^-1 B' is the identity on the velocity block, so the filter is not weighted by the
    noise levels (docs/errata.md); with Q = I, R = I it weighs the residual by D^-T D^-1 and the model error by
    B B', which is what a user would tune. The simulated noise is the same for both.

    **Not printed in the paper** (our choice, also recorded in ``metrics.json``): the forgetting factor
    ``alpha`` = 0 and the initial gain K(0) = I6 (``K0_diag``), and a measurement at every integration step.

    Fields:
        seed: the run's key is ``jax.random.key(seed)``.
        duration, dt: final time T and the step of both the truth and the filter (one sample per step).
        connection: ``"zero"`` (c = 1/2, the paper's), ``"minus"`` (c = 0) or ``"plus"`` (c = 1).
        order: ``"second"`` (the paper's filter) or ``"first"`` (the left-invariant EKF).
        integrator: ``"rkmk4"``, ``"rkmk2"`` or ``"lie-euler"``, for the truth and the filter.
        weights: ``"printed"`` (Q = D'D, R = B'B, the paper's) or ``"consistent"`` (Q = I, R = I).
        sensor: ``"gps_imu"`` (the paper) or ``"velocity"`` (IMU only, the Segala poster).
        model_error_std: std of the per-step model error delta in the truth (0: the paper's nominal truth).
        substeps: truth steps per sample interval.
        steady: the window (start, stop) of the "after convergence" statistics, in s.
    """

    seed: int = 0
    duration: float = 50.0
    dt: float = 1e-3
    connection: str = "zero"
    order: str = "second"
    integrator: str = "rkmk4"
    sensor: str = "gps_imu"
    weights: str = "printed"
    alpha: float = 0.0
    K0_diag: tuple[float, ...] = (1.0,) * 6
    truth0: tuple[float, ...] = (math.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0)
    filter0: tuple[float, ...] = (math.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1)
    model_error_std: float = 0.0
    substeps: int = 1
    steady: tuple[float, float] = (10.0, 50.0)

    window_times = ("steady",)  # follow a new duration (RunConfig.window_changes)

    def __post_init__(self):
        self._check_run()
        _validate.choice("connection", self.connection, set(CARTAN_SCHOUTEN))
        _validate.choice("sensor", self.sensor, set(SENSORS))
        _validate.choice("weights", self.weights, set(WEIGHTS))
        _validate.nonnegative("alpha", self.alpha)
        _validate.nonnegative("model_error_std", self.model_error_std)
        _validate.array("K0_diag", self.K0_diag, (6,))
        if min(self.K0_diag) < 0:
            raise ValueError(f"K0_diag: expected entries >= 0, got {self.K0_diag}")
        _validate.array("truth0", self.truth0, (6,))
        _validate.array("filter0", self.filter0, (6,))
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"substeps: expected an integer >= 1, got {self.substeps!r}")
        lo, hi = _validate.array("steady", self.steady, (2,))
        if not lo < hi:
            raise ValueError(f"steady: expected a window (start, stop) with start < stop, got {self.steady}")
        self._freeze(floats=("alpha", "model_error_std"),
                     tuples=("K0_diag", "truth0", "filter0", "steady"))


@dataclass(frozen=True)
class Setup:
    """Everything a trial needs, built once from a config. It does not depend on the seed: ``config`` is the
    config with ``seed = 0``, and setups are cached, so runs that differ only in the seed share one compiled
    filter and simulation."""

    config: TSE2Config
    system: PlanarRigidBody
    filter: MinimumEnergyFilter
    g0: object
    state0: object
    ts: np.ndarray


@setup_cache()
def setup(config: TSE2Config) -> Setup:
    """The system, filter, initial states and time grid of ``config`` (cached; see :class:`Setup`)."""
    system = PlanarRigidBody(sensor=config.sensor)
    if config.weights == "consistent":
        system = PlanarRigidBody(sensor=config.sensor, Q=np.eye(system.output_dim), R=np.eye(system.B.shape[1]))
    flt = MinimumEnergyFilter(system, curvature="exact", error="left", connection=config.connection, order=config.order,
                              integrator=config.integrator, alpha=config.alpha, substeps=PAPER_SUBSTEPS)
    state0 = flt.init(tse2_state(*config.filter0), np.diag(config.K0_diag))
    return Setup(config=config, system=system, filter=flt, g0=tse2_state(*config.truth0), state0=state0,
                 ts=config.ts)


def trial(s: Setup, key) -> tuple[Truth, SensorLog, Trajectory]:
    """Simulation and filter run for one key: traceable, so ``jax.vmap(lambda k: trial(s, k))(keys)`` batches
    Monte Carlo trials."""
    c = s.config
    truth, log = simulate_core(s.system, s.g0, paper_input, jnp.asarray(s.ts), key, c.model_error_std, None,
                               c.substeps, c.integrator)
    return truth, log, s.filter.scan(s.state0, log.ts, log.us, log.ys, engine=None)


def measured_state(sensor: str, ys: np.ndarray) -> np.ndarray:
    """The state coordinates read off the measurements, NaN where not measured.

    GPS: heading ``atan2(y1 - y2, x1 - x2)`` and position the antennas' midpoint; IMU: the velocities.
    """
    ys = np.asarray(ys)
    out = np.full((ys.shape[0], 6), np.nan)
    if sensor == "gps_imu":
        x1, y1, x2, y2 = ys[:, 0], ys[:, 1], ys[:, 2], ys[:, 3]
        out[:, 0] = np.arctan2(y1 - y2, x1 - x2)
        out[:, 1], out[:, 2] = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
        out[:, 3:6] = ys[:, 4:7]
    else:
        out[:, 3:6] = ys[:, 0:3]
    return out


def _assumptions(c: TSE2Config) -> dict:
    return {
        "alpha": f"{c.alpha:g} (not printed in Rigo et al. 2022; our choice)",
        "K0": f"diag({', '.join(f'{v:g}' for v in c.K0_diag)}) (not printed in Rigo et al. 2022; our choice)",
        "weights": WEIGHTS[c.weights],
        "sampling": f"one measurement per integration step, dt = {c.dt:g} s, inputs and measurements held "
                    "(zero-order hold)",
        "truth": ("generated from the nominal input without model error, as in the paper"
                  if c.model_error_std == 0
                  else f"model error B delta, delta ~ N(0, {c.model_error_std:g}^2 I3) per truth step"),
        "filter_input": "the nominal input u(t)",
    }


def run(config: TSE2Config | None = None, key=None) -> Result:
    """Simulate, filter and evaluate one run (key ``jax.random.key(config.seed)`` unless given)."""
    c = TSE2Config() if config is None else config
    s = setup(c)
    key = jax.random.key(c.seed) if key is None else key
    truth, log = simulate(s.system, s.g0, paper_input, s.ts, key, model_error_std=c.model_error_std,
                          substeps=c.substeps, integrator=c.integrator)
    traj = s.filter.run(s.state0, log.ts, log.us, log.ys)
    extra = {"pose_residual": pose_residual(s.filter, traj, log)} if c.sensor == "velocity" else None
    return evaluate(EXPERIMENTS_BY_SENSOR[c.sensor], c, s.filter, truth, log, traj,
                    measured_state(c.sensor, np.asarray(log.ys)), (FULL, Window(*map(float, c.steady))),
                    _assumptions(c), extra_metrics=extra)


def pose_residual(flt: MinimumEnergyFilter, traj: Trajectory, log: SensorLog) -> dict:
    r"""The residual $r = Dh^\top \tilde y$ of Theorem 4.1 (``flt``'s terms) at every sample of a run, split
    into its pose part $r^g$ and velocity part $r^\Omega$: ``{"max_abs_r_g", "max_abs_r_Omega", ...}``.

    With the velocity sensor nothing measured depends on the pose, so $r^g = 0$ exactly: the pose is
    dead-reckoned from the velocity estimate, corrected only through the gain's pose-velocity block
    $K_{12} r^\Omega$ (Segala poster)."""
    second = flt.order == "second"
    r_of = jax.jit(jax.vmap(lambda g, K, u, y, t: terms(flt.system, flt.weights, flt.connection, second, g, K, u, y,
                                                         t).r))
    r = np.asarray(r_of(traj.g_hat, traj.K, log.us, log.ys, log.ts))
    return {"definition": "max over the samples k of |r^g| and |r^Omega| (Euclidean norms), r the residual of "
                          "Theorem 4.1 at (g_hat_k, K_k, u_k, y_k)",
            "max_abs_r_g": float(np.linalg.norm(r[:, :3], axis=1).max()),
            "max_abs_r_Omega": float(np.linalg.norm(r[:, 3:], axis=1).max()), "samples": int(r.shape[0])}


def trial_spec(config: TSE2Config) -> TrialSpec:
    """The Monte Carlo trial of ``config``: coordinate errors of one seeded run (traceable in the key) and the
    filter's status, so that the Monte Carlo counts diverged trials by cause."""
    s = setup(config)
    spec = state_error_trial(s, trial, (FULL, Window(*map(float, config.steady))))

    def errors(key):
        truth, _, traj = trial(s, key)
        return state_error(truth.g, traj.g_hat), traj.status

    return dataclasses.replace(spec, errors=errors)


def _run_velocity(config: TSE2Config | None = None, key=None) -> Result:
    c = TSE2Config(sensor="velocity") if config is None else config
    if c.sensor != "velocity":
        raise ValueError(f"sensor: the tse2-velocity experiment expects sensor='velocity', got {c.sensor!r}")
    return run(c, key)


_POSE = ("theta", "x", "y")
_VEL = ("omega", "vx", "vy")

TSE2 = register(Experiment(
    **registry.card("tse2"),
    default_config=TSE2Config(),
    run_fn=run,
    trial_fn=trial_spec,
    runs=20,
    quick_config=TSE2Config(duration=20.0, steady=(10.0, 20.0)),
    quick_runs=8,
    figures=(
        FigureSpec("fig3_pose.png", _POSE,
                   "Pose: truth (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2022, Fig. 3"),
        FigureSpec("fig4_velocity.png", _VEL,
                   "Velocities: truth (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2022, Fig. 4"),
    ),
))

TSE2_VELOCITY = register(Experiment(
    **registry.card("tse2-velocity"),
    default_config=TSE2Config(sensor="velocity"),
    run_fn=_run_velocity,
    trial_fn=trial_spec,
    runs=20,
    quick_config=TSE2Config(sensor="velocity", duration=20.0, steady=(10.0, 20.0)),
    quick_runs=8,
    figures=(
        FigureSpec("fig_pose.png", _POSE,
                   "Pose, not measured: truth (black), dead-reckoned estimate (green); errors (red)",
                   "Segala poster (pose)"),
        FigureSpec("fig_velocity.png", _VEL,
                   "Velocities: truth (black), measured (blue), filtered (green); errors (red)",
                   "Segala poster (velocities)"),
    ),
))

EXPERIMENTS_BY_SENSOR = {"gps_imu": TSE2, "velocity": TSE2_VELOCITY}
