"""A user's experiment for ``liemef campaign``: heading on SO(2) from a gyro and a direction sensor.

The truth turns at the rate omega(t) = w0 + a sin(t); the filter is driven by that rate and measures the
heading as a unit vector (cos theta, sin theta) with white noise of std ``meas_std`` per sample; the truth
has a model error of std ``model_std`` per step. A campaign file names this file as ``experiment_file``; its
text is sent to the Dask workers, which execute it and call ``experiment.trial_fn``.

Any field of :class:`HeadingConfig` can be a grid axis of the campaign (e.g. ``meas_std``, ``connection``,
``order``, ``alpha``, ``dt``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from liemef import MinimumEnergyFilter
from liemef.connections import CARTAN_SCHOUTEN
from liemef.filters import ORDERS
from liemef.groups import SO2
from liemef.metrics import FULL, Window, state_error, state_labels
from liemef.simulation import simulate_core
from liemef.studies.experiments import Experiment, TrialSpec, evaluate
from liemef.systems import System


@dataclass(frozen=True)
class HeadingConfig:
    """seed, duration (s), dt (s, one sample per step), the filter's connection, order and forgetting factor,
    the noise stds (measurement per sample, truth model error per step), the initial heading error (rad),
    the steady-state window start (s) and the filter's integrator steps per sample (``"auto"``: adaptive,
    the default for real data; 1: one step, which a small ``meas_std`` makes stiff enough to diverge)."""

    seed: int = 0
    duration: float = 4.0
    dt: float = 0.02
    connection: str = "zero"
    order: str = "second"
    alpha: float = 0.0
    meas_std: float = 0.2
    model_std: float = 0.01
    initial_error: float = 1.0
    steady_from: float = 2.0
    substeps: str | int = "auto"

    def __post_init__(self):
        if self.connection not in CARTAN_SCHOUTEN:
            raise ValueError(f"connection: expected one of {sorted(CARTAN_SCHOUTEN)}, got {self.connection!r}")
        if self.order not in ORDERS:
            raise ValueError(f"order: expected one of {list(ORDERS)}, got {self.order!r}")
        for name in ("duration", "dt", "meas_std", "model_std"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {v!r}")
        if not 0 <= self.steady_from < self.duration:
            raise ValueError(f"steady_from: expected a time in [0, {self.duration}), got {self.steady_from!r}")

    @property
    def ts(self) -> np.ndarray:
        """The sample grid 0, dt, ..., duration."""
        return np.arange(int(round(self.duration / self.dt)) + 1) * self.dt


def rate(t):
    """The true turn rate omega(t), rad/s."""
    return jnp.array([0.3 + 0.5 * jnp.sin(t)])


def _turn(g, u, t):
    return u  # the body turns at the measured rate


def _direction(g, t):
    return g.as_matrix()[:, 0]  # (cos theta, sin theta)


@functools.lru_cache(maxsize=8)
def _setup(config: HeadingConfig):
    """The system, the filter and its initial state. Only arrays depend on the noise levels, alpha and the
    initial error; the functions are module-level: settings that differ in those values share one compiled
    Monte Carlo batch (see ``trial_errors``)."""
    system = System(group_type=SO2, dynamics_fn=_turn, output_fn=_direction,
                    B=[[config.model_std / math.sqrt(config.dt)]], D=config.meas_std * np.eye(2),
                    Q=np.eye(2), R=np.eye(1), n_inputs=1, names=("cos", "sin"))
    flt = MinimumEnergyFilter(system, connection=config.connection, order=config.order, alpha=config.alpha,
                              substeps=config.substeps)
    state0 = flt.init(SO2.from_angle(jnp.asarray(config.initial_error)), np.eye(1))
    return flt, state0


def _params(config: HeadingConfig):
    flt, state0 = _setup(config)
    return flt, state0, jnp.asarray(config.model_std), jnp.asarray(config.ts)


def trial_errors(params, key):
    """One seeded trial: simulate, filter, and return the heading error and the filter's status. A function
    of the parameters (filter, initial state, model error std, time grid) and the key, so that the Monte
    Carlo batch takes the parameters as data (``TrialSpec.params``)."""
    flt, state0, model_std, ts = params
    truth, log = simulate_core(flt.system, SO2.identity(), rate, ts, key, model_std)
    traj = flt.scan(state0, log.ts, log.us, log.ys)
    return state_error(truth.g, traj.g_hat), traj.status


def _windows(config: HeadingConfig) -> tuple[Window, ...]:
    return (FULL, Window(config.steady_from, config.duration))


def trial_fn(config: HeadingConfig) -> TrialSpec:
    """The Monte Carlo trial of ``config``: :func:`trial_errors` with this config's parameters."""
    flt, _ = _setup(config)
    names, units = state_labels(flt.system)
    return TrialSpec(ts=config.ts, names=names, units=units, windows=_windows(config), errors=trial_errors,
                     params=_params(config))


def run_fn(config: HeadingConfig, key=None):
    """One seeded run as a liemef Result (``experiment.run``)."""
    key = jax.random.key(config.seed) if key is None else key
    flt, state0, model_std, ts = _params(config)
    truth, log = simulate_core(flt.system, SO2.identity(), rate, ts, key, model_std)
    traj = flt.scan(state0, log.ts, log.us, log.ys)
    ys = np.asarray(log.ys)
    measured = np.arctan2(ys[:, 1], ys[:, 0])[:, None]
    return evaluate(experiment, config, flt, truth, log, traj, measured, _windows(config), {
        "truth": "omega(t) = 0.3 + 0.5 sin t rad/s from heading 0; model error model_std per step",
        "sensor": "unit vector (cos, sin) of the heading, meas_std per sample"})


experiment = Experiment(name="heading", title="Heading on SO(2) from a gyro and a direction sensor",
                        paper="(a user's experiment)", default_config=HeadingConfig(), run_fn=run_fn,
                        trial_fn=trial_fn)
