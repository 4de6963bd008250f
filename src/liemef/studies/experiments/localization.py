r"""The 2D localization benchmark of ukfm (wheel odometry at 100 Hz, GPS at 1 Hz), rebuilt exactly.

The scenario (``../shared/scenarios/ukfm_localization.md``; Brossard, Barrau, Bonnabel, ukfm
``benchmarks/localization.py``; Barrau & Bonnabel 2017, Sec. IV): a robot drives once around a circle of
radius 5 m in T = 40 s. There are N = T / dt = 4000 states $t_n = n\,dt$ (n = 0..3999), and the noisy
odometry $u_n$ (n = 0..3998) moves state n to state n + 1. Fixes $y_k = p_{100k} + \varepsilon_k$
(std 1 m) arrive at n = 100, 200, ..., 3900: 39 fixes, since ukfm simulates $y_0$ but never uses it. The
initial heading error is $\sim N(0, (45°)^2)$; the initial position is exact.

* Truth (:func:`simulate_truth`): ukfm's dynamics with the noise-free input, $C_{n+1} = C_n
  \mathrm{Exp}(\omega\,dt)$ and $p_{n+1} = p_n + C_n v\,dt$. This gives $\theta_n = n\omega\,dt$ and the
  4000-vertex polygon $p_n = v_x dt \sum_{m<n} (\cos m\omega dt, \sin m\omega dt)$.
* Noise (:class:`Draws`): standard normals from a ``jax.random`` key (:func:`jax_draws`; Monte Carlo,
  ``vmap``), or ukfm's legacy NumPy stream for ``rng="numpy"`` (:func:`numpy_draws`). With the same seed, the
  legacy stream draws ukfm's normals in ukfm's order, so the data are ukfm's run to round-off.
* Filter: :func:`~liemef.systems.planar_localization` with the scenario's noise levels. The odometry
  samples of std (0.01 m/s, 0.01 m/s, 1 deg/s) at 100 Hz are the process-noise density; each GPS fix
  (std 1 m) is one sample. The engine is the default one: second order, (0)-connection, RKMK4, sub-steps
  ``"auto"``. Each odometry sample is held over its interval, and a fix at $t_n$ is spread over
  $[t_n, t_{n+1}]$, which ukfm approximates by an update right after the propagation to n. K0 = P0 =
  diag(theta0_std^2, 0, 0) in the left error $\xi$ ($g = \hat g\exp\xi$, ukfm's left SE(2) / IEKF
  coordinates). P0 constrains the heading only, so changing to the (theta, p) coordinates leaves it
  unchanged.
* Metrics (scenario §1.5, :func:`series`): the heading error $e_\theta = \mathrm{wrap}(\hat\theta -
  \theta)$ [deg] and the position error $|p - \hat p|$ [m]. Their rms is reported over t >= 20 s and over
  all n. Two NEES use $P' = M K M^\top$ with $M = \mathrm{blkdiag}(1, R(\hat\theta))$: the heading NEES
  $e_\theta^2/P'_{00}$ and the position NEES $e_p^\top P_{pp}'^{-1} e_p / 2$, each averaged over t >= 20 s
  and the runs (1 for a consistent filter). A trial counts as a heading flip when its final
  $|e_\theta| > 90°$. A trial diverges when the filter status fails or an error is not finite.

:func:`trial_spec` is the Monte Carlo trial: the four series above over the windows full, t >= 20 s and the
final sample, plus the filter status, ``vmap``-ed over keys by :func:`~liemef.studies.experiments.montecarlo`.
:func:`study` condenses a Monte Carlo into the scenario's numbers, next to ukfm's published invariant EKF.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...connections import CARTAN_SCHOUTEN
from ...filters import INTERPOLATIONS, MinimumEnergyFilter, Trajectory
from ...groups import SE2, SO2
from ...metrics import FULL, Window, chi2_bounds, nees, wrap_angle
from ...metrics._stats import json_number
from ...reports import figures, io
from ...simulation import SensorLog, Truth
from ...systems import planar_localization
from .. import registry
from ._base import Experiment, FigureSpec, Output, Reproduction, Result, TrialSpec, UkfmGrid, register, setup_cache
from ._evaluate import evaluate
from ._montecarlo import MonteCarloResult, montecarlo

NAMES = ("heading", "position", "nees_heading", "nees_position")
"""The trial's series: heading error wrap(theta_hat - theta), position error |p - p_hat|, and the heading and
position NEES (scenario §1.5)."""
UNITS = ("deg", "m", "1", "1")
PUBLISHED = {
    "iekf": {"heading_deg": 1.45, "position_m": 0.208,
             "filter": "invariant EKF (and left UKF-M), ukfm's benchmark code, 20 seeds, t >= 20 s"},
    "ekf": {"heading_deg": 4.13, "position_m": 0.748,
            "filter": "EKF in SO(2) x R^2 coordinates, ukfm's benchmark code, 20 seeds, t >= 20 s"},
}
"""The published rms errors of the scenario's filters (pooled over runs and t >= 20 s)."""
FLIP_DEG = 90.0
"""A trial is a heading flip when its final |heading error| exceeds this (deg)."""
RNGS = ("jax", "numpy")


@dataclass(frozen=True)
class LocalizationConfig(UkfmGrid):
    r"""The ukfm 2D localization benchmark (module docstring); defaults are the scenario's.

    Fields:
        seed: the run's key is ``jax.random.key(seed)`` (``rng="jax"``) or ``np.random.seed(seed)``
            (``rng="numpy"``, ukfm's legacy stream; single runs only, a Monte Carlo draws from jax keys).
        duration, dt: T and the odometry period: N = round(T / dt) states at t_n = n dt (n < N).
        radius: of the circle driven once in T (m).
        odometry_std: per-sample std of (v_x m/s, v_y m/s, omega rad/s), ukfm's input order.
        gps_period: time between fixes (s), a whole number of odometry periods; fixes at n = m, 2m, ... < N,
            m = gps_period / dt (none at n = 0).
        gps_std: std of a fix per axis (m).
        theta0_std: std of the initial heading error (rad); K0 = diag(theta0_std^2, 0, 0).
        connection, order, integrator, interpolation: the filter (:class:`~liemef.MinimumEnergyFilter`).
        steady: start of the window of the reported rms and NEES (s).
        rng: ``"jax"`` or ``"numpy"``.
    """

    seed: int = 0
    duration: float = 40.0
    dt: float = 0.01
    radius: float = 5.0
    odometry_std: tuple[float, ...] = (0.01, 0.01, math.pi / 180.0)
    gps_period: float = 1.0
    gps_std: float = 1.0
    theta0_std: float = math.pi / 4.0
    connection: str = "zero"
    order: str = "second"
    integrator: str = "rkmk4"
    interpolation: str = "hold"
    steady: float = 20.0
    rng: str = "jax"

    window_times = ("steady",)  # follow a new duration (RunConfig.window_changes)

    def __post_init__(self):
        self._check_run(positive=("radius", "gps_period", "gps_std", "theta0_std"))
        _validate.choice("connection", self.connection, set(CARTAN_SCHOUTEN))
        _validate.choice("interpolation", self.interpolation, set(INTERPOLATIONS))
        _validate.choice("rng", self.rng, set(RNGS))
        std = _validate.array("odometry_std", self.odometry_std, (3,))
        if np.any(std <= 0):
            raise ValueError(f"odometry_std: expected three stds > 0, got {tuple(self.odometry_std)}")
        m = self.gps_period / self.dt
        if abs(m - round(m)) > 1e-9 * m:
            raise ValueError(f"gps_period: expected a whole number of odometry periods dt = {self.dt}, got "
                             f"{self.gps_period}")
        _validate.nonnegative("steady", self.steady)
        self._freeze(floats=("radius", "gps_period", "gps_std", "theta0_std", "steady"), tuples=("odometry_std",))
        if self.n_states < 2 or self.steady > self.ts[-1]:
            raise ValueError(f"steady: expected a start within the run [0, {self.ts[-1]:g}] s, got {self.steady}")

    @property
    def gps_indices(self) -> np.ndarray:
        """The odometry indices of the fixes the filter uses: m, 2m, ... < N (ukfm's y_0 is never used)."""
        return self.every(self.gps_period)

    @property
    def windows(self) -> tuple[Window, ...]:
        """full, t >= ``steady`` (the scenario's window) and the final sample."""
        return (FULL, Window(self.steady, self.duration), Window(float(self.ts[-1]), self.duration))


# --- the scenario -------------------------------------------------------------------------------------------
def ukfm_step(g: SE2, u, w, dt) -> SE2:
    r"""ukfm's ``LOCALIZATION.f``: $C^+ = C\,\mathrm{Exp}((\omega + w_2) dt)$, $p^+ = p + C (v + w_{0:2}) dt$
    (the heading before the update), ``u = (v_x, v_y, omega)``."""
    rot = g.rotation()
    p = g.translation() + rot.act((u[:2] + w[:2]) * dt)
    return SE2.from_rotation_translation(rot @ SO2.from_angle((u[2] + w[2]) * dt), p)


def true_input(config: LocalizationConfig) -> np.ndarray:
    """The constant true input ``(v_x, v_y, omega) = (2 pi r / T, 0, 2 pi / T)``."""
    return np.array([2.0 * math.pi * config.radius / config.duration, 0.0, 2.0 * math.pi / config.duration])


def simulate_truth(config: LocalizationConfig) -> SE2:
    """The true states ``g[n]``, n = 0..N-1, from the identity with the noise-free input (:func:`ukfm_step`
    propagated by ``lax.scan``); an :class:`~liemef.groups.SE2` of batch shape (N,)."""
    u, dt = jnp.asarray(true_input(config)), config.dt

    def body(g, _):
        nxt = ukfm_step(g, u, jnp.zeros(3), dt)
        return nxt, nxt

    g0 = SE2.identity()
    _, gs = jax.lax.scan(body, g0, None, length=config.n_states - 1)
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), g0, gs)


class Draws(NamedTuple):
    """The standard normals of one run: ``odometry`` (N-1, 3) per input sample in the order (v_x, v_y,
    omega), ``gps`` (K, 2) per fix used, ``theta0`` the initial heading error."""

    odometry: jax.Array
    gps: jax.Array
    theta0: jax.Array


def jax_draws(config: LocalizationConfig, key) -> Draws:
    """The draws of one run from a ``jax.random`` key (traceable)."""
    k_odo, k_gps, k_theta = jax.random.split(key, 3)
    return Draws(jax.random.normal(k_odo, (config.n_states - 1, 3)),
                 jax.random.normal(k_gps, (config.gps_indices.size, 2)), jax.random.normal(k_theta, ()))


def numpy_draws(config: LocalizationConfig, seed: int) -> Draws:
    """The draws of ukfm's run after ``np.random.seed(seed)``, in its order: for n = 1..N-1 ``randn(2)``
    (velocity) then ``randn(1)`` (yaw rate); for each fix k = 0, 1, ... (including the unused y_0)
    ``randn(2)``; then ``randn(1)`` (initial heading). The legacy Gaussian caches its second value across
    calls, so ``randn(2); randn(1)`` is ``randn(3)``."""
    rs = np.random.RandomState(seed)
    n = config.n_states
    odometry = rs.randn(3 * (n - 1)).reshape(n - 1, 3)
    fixes = 1 + config.gps_indices.size  # with y_0
    gps = rs.randn(2 * fixes).reshape(fixes, 2)[1:]
    return Draws(jnp.asarray(odometry), jnp.asarray(gps), jnp.asarray(rs.randn()))


def sensor_log(config: LocalizationConfig, truth: SE2, draws: Draws) -> tuple[SensorLog, SE2]:
    """The filter's log and initial estimate from the truth and the draws (traceable): ``us[n] = u + std
    eps`` (n < N-1; the last row repeats, it is never used), ``ys`` NaN except ``p_n + gps_std eps`` at the
    fixes, ``g_hat_0 = g_0 Exp(theta0_std eps_0)`` (heading only; ukfm's ``C_0 Exp(.)``, ``p_0``)."""
    ts = jnp.asarray(config.ts)
    u = jnp.asarray(true_input(config)) + jnp.asarray(config.odometry_std) * draws.odometry
    us = jnp.concatenate([u, u[-1:]])
    idx = jnp.asarray(config.gps_indices)
    p = truth.translation()
    ys = jnp.full((config.n_states, 2), jnp.nan).at[idx].set(p[idx] + config.gps_std * draws.gps)
    g0 = jax.tree_util.tree_map(lambda a: a[0], truth)
    g0_hat = g0 @ SE2.exp(jnp.stack([config.theta0_std * draws.theta0, 0.0, 0.0]))
    return SensorLog(ts=ts, us=us, ys=ys), g0_hat


# --- the filter and one trial -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Setup:
    """Everything a trial needs, independent of the seed (cached per config with ``seed = 0``): the system,
    the filter, its initial state at the identity with K0 and the truth."""

    config: LocalizationConfig
    filter: MinimumEnergyFilter
    state0: object
    truth: SE2

    @property
    def system(self):
        """The filter's :class:`~liemef.systems.SensorSystem`."""
        return self.filter.system

    @property
    def ts(self) -> np.ndarray:
        """The sample times (``config.ts``)."""
        return self.config.ts


@setup_cache(rng="jax")
def setup(config: LocalizationConfig) -> Setup:
    """The filter and truth of ``config`` (cached; the seed and the RNG do not enter)."""
    vx, vy, w = config.odometry_std
    system = planar_localization(odometry_std=(w, vx, vy), odometry_rate=1.0 / config.dt, gps_std=config.gps_std)
    flt = MinimumEnergyFilter(system, curvature="exact", error="left", connection=config.connection, order=config.order,
                              integrator=config.integrator, interpolation=config.interpolation)
    state0 = flt.init(SE2.identity(), np.diag([config.theta0_std**2, 0.0, 0.0]))
    return Setup(config=config, filter=flt, state0=state0, truth=jax.jit(simulate_truth, static_argnums=0)(config))


def trial(s: Setup, draws: Draws) -> tuple[Truth, SensorLog, Trajectory]:
    """Sensor log and filter run for one set of draws: traceable, ``vmap``-able over draws (or keys)."""
    log, g0_hat = sensor_log(s.config, s.truth, draws)
    state = eqx.tree_at(lambda st: st.g_hat, s.state0, g0_hat)
    traj = s.filter.scan(state, log.ts, log.us, log.ys, engine=None)
    u = jnp.broadcast_to(jnp.asarray(true_input(s.config)), log.us.shape)
    return Truth(ts=log.ts, g=s.truth, u=u), log, traj


def series(truth: SE2, g_hat: SE2, K) -> jax.Array:
    r"""(N, 4): heading error $\mathrm{wrap}(\hat\theta - \theta)$ [deg], position error $|p - \hat p|$ [m],
    heading NEES $e_\theta^2/P'_{00}$ and position NEES $e_p^\top P_{pp}'^{-1} e_p/2$, with $P' = M K M^\top$,
    $M = \mathrm{blkdiag}(1, R(\hat\theta))$ (scenario §1.5). Traceable."""
    e_theta = wrap_angle(g_hat.rotation().angle() - truth.rotation().angle())
    e_p = truth.translation() - g_hat.translation()
    R = g_hat.rotation().as_matrix()
    P_pp = R @ K[..., 1:3, 1:3] @ jnp.swapaxes(R, -1, -2)
    return jnp.stack([jnp.degrees(e_theta), jnp.linalg.norm(e_p, axis=-1),
                      nees(e_theta[..., None], K[..., :1, :1]), nees(e_p, P_pp) / 2.0], axis=-1)


def trial_spec(config: LocalizationConfig) -> TrialSpec:
    """The Monte Carlo trial of ``config``: :func:`series` of one keyed run and the filter status."""
    if config.rng != "jax":
        raise ValueError(f"rng: a Monte Carlo draws from jax.random keys; expected rng='jax', got {config.rng!r} "
                         "(ukfm's legacy stream is for single runs)")
    s = setup(config)

    def errors(key):
        truth, _, traj = trial(s, jax_draws(config, key))
        return series(truth.g, traj.g_hat, traj.K), traj.status

    return TrialSpec(ts=s.ts, names=NAMES, units=UNITS, windows=config.windows, errors=errors)


# --- one seeded run -----------------------------------------------------------------------------------------
def _assumptions(c: LocalizationConfig) -> dict:
    return {
        "scenario": "ukfm 2D localization benchmark (../shared/scenarios/ukfm_localization.md), rebuilt "
                    f"exactly: N = {c.n_states} states at dt = {c.dt:g} s, {c.gps_indices.size} fixes at n = "
                    f"{c.gps_indices[0]}..{c.gps_indices[-1]} (y_0 unused)",
        "noise": f"odometry per sample std {tuple(c.odometry_std)} (v_x, v_y, omega) at {1 / c.dt:g} Hz as the "
                 f"process-noise density std / sqrt(rate); GPS one sample per fix, std {c.gps_std:g} m",
        "K0": f"P0 = diag({c.theta0_std:g}^2, 0, 0) in the left error (g = g_hat exp(xi)); heading only, so "
              "the (theta, p) coordinates give the same matrix",
        "sampling": "odometry held over each interval; a fix at t_n spread over [t_n, t_n+1] (ukfm: update "
                    "right after the propagation to n)",
        "model": "the truth follows ukfm's Euler step (p_{n+1} = p_n + C_n v dt); the filter integrates the "
                 "continuous kinematics (a constant twist over each interval), a difference of order "
                 "omega dt / 2 = 8e-4 rad in the chord direction",
        "rng": "jax.random key" if c.rng == "jax" else "ukfm's legacy NumPy stream (np.random.seed(seed))",
    }


def run(config: LocalizationConfig | None = None, key=None) -> Result:
    """One seeded run (key ``jax.random.key(config.seed)`` unless given; ``rng="numpy"``: ukfm's stream),
    filtered by the checked :meth:`~liemef.MinimumEnergyFilter.run`, with the scenario's metrics."""
    c = LocalizationConfig() if config is None else config
    s = setup(c)
    if c.rng == "numpy":
        if key is not None:
            raise ValueError("key: rng='numpy' draws from np.random.seed(config.seed); expected key=None")
        draws = numpy_draws(c, c.seed)
    else:
        draws = jax_draws(c, jax.random.key(c.seed) if key is None else key)
    log, g0_hat = sensor_log(c, s.truth, draws)
    traj = s.filter.run(eqx.tree_at(lambda st: st.g_hat, s.state0, g0_hat), np.asarray(log.ts),
                        np.asarray(log.us), np.asarray(log.ys))
    truth = Truth(ts=log.ts, g=s.truth, u=jnp.broadcast_to(jnp.asarray(true_input(c)), log.us.shape))
    ser = np.asarray(series(s.truth, traj.g_hat, traj.K))
    measured = np.full((c.n_states, 3), np.nan)
    measured[:, 1:] = np.asarray(log.ys)
    return evaluate(LOCALIZATION, c, s.filter, truth, log, traj, measured, c.windows[:2],
                    _assumptions(c), extra_metrics={"scenario_metrics": run_metrics(c, ser, traj)},
                    extra_arrays={"series": ser, "series_names": np.array(NAMES), "series_units": np.array(UNITS)})


def run_metrics(config: LocalizationConfig, ser: np.ndarray, traj: Trajectory) -> dict:
    """The scenario's numbers of one run (JSON-ready): rms over t >= steady and over all n, NEES over
    t >= steady, the final heading error, the flip flag and the filter status."""
    late = config.ts >= config.steady
    rms = lambda x: json_number(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    final = float(ser[-1, 0])
    return {"definition": "heading error wrap(theta_hat - theta) [deg], position error |p - p_hat| [m]; NEES "
                          "with P' = M K M^T, M = blkdiag(1, R(theta_hat)) (scenario §1.5)",
            "rms_steady": {"heading_deg": rms(ser[late, 0]), "position_m": rms(ser[late, 1])},
            "rms_all": {"heading_deg": rms(ser[:, 0]), "position_m": rms(ser[:, 1])},
            "nees_steady": {"heading": json_number(np.mean(ser[late, 2])),
                            "position": json_number(np.mean(ser[late, 3]))},
            "final_heading_error_deg": json_number(final), "heading_flip": bool(abs(final) > FLIP_DEG),
            "status": traj.status.as_dict(["gps"])}


# --- the Monte Carlo study ----------------------------------------------------------------------------------
def study(mc: MonteCarloResult, prob: float = 0.95) -> dict:
    """The scenario's numbers from a Monte Carlo of :func:`trial_spec` (JSON-ready), over the healthy trials:
    per metric the mean over trials, percentiles 5 and 95 and the pooled value; the published invariant
    EKF's rms with its percentile in the distribution; the NEES with the two-sided chi-square bounds of the
    per-step average over the trials; heading flips; diverged trials by cause; wall time."""
    full, steady, final = mc.window_labels
    n = mc.n_finite

    def dist(name, window, stat="rms", pooled=True):
        x = mc.values(name, window, stat)
        if x.size == 0:
            return {"mean": None, "p5": None, "p95": None}
        out = {"mean": float(np.mean(x)), "p5": float(np.percentile(x, 5)), "p95": float(np.percentile(x, 95))}
        if pooled:
            out["pooled"] = float(np.sqrt(np.mean(x**2)))  # = sqrt(mean over runs and steps), ukfm's figure
        return out

    def nees_entry(name, dof):
        d = dist(name, steady, "mean", pooled=False)
        lo, hi = chi2_bounds(dof, max(n, 1), prob, per_dof=True)
        return {**d, "chi2_bounds": [lo, hi], "dof": dof}

    final_heading = mc.values("heading", final, "mean")
    flips = np.flatnonzero(mc.finite)[np.abs(final_heading) > FLIP_DEG]
    rms = {m: {"heading_deg": dist("heading", w), "position_m": dist("position", w)}
           for m, w in (("steady", steady), ("all", full))}
    iekf = PUBLISHED["iekf"]
    for key, name in (("heading_deg", "heading"), ("position_m", "position")):
        rms["steady"][key]["published_iekf"] = iekf[key]
        rms["steady"][key]["published_iekf_percentile"] = json_number(mc.percentile_of(iekf[key], name, steady,
                                                                                       "rms"))
    return {
        "definition": "per trial: rms over time of the heading error [deg] and of the position error norm [m] "
                      f"(window {steady}: the scenario's t >= {mc.windows[1].start:g} s; {full}: all n), mean "
                      "of the NEES over the window; across the healthy trials: mean, percentiles 5 and 95, "
                      "pooled = sqrt(mean of squares) = the rms over runs and steps (ukfm's definition). "
                      f"chi2_bounds: two-sided {prob:g} bounds of the average over {n} runs of one step's NEES "
                      "(divided by its dof); the time average of a consistent filter lies well inside them.",
        "runs": mc.runs, "healthy": n, "seed": mc.seed, "config": mc.config,
        "rms": rms,
        "nees": {"heading": nees_entry("nees_heading", 1), "position": nees_entry("nees_position", 2)},
        "heading_flips": {"count": int(flips.size), "trials": [int(i) for i in flips],
                          "definition": f"final |heading error| > {FLIP_DEG:g} deg"},
        "diverged": {"count": mc.n_nonfinite, "by_cause": mc.diverged(),
                     "trials": [int(i) for i in mc.nonfinite_trials], "summary": mc.divergence_summary()},
        "published": PUBLISHED,
        "elapsed_s": json_number(mc.elapsed),
    }


def study_markdown(st: dict, title: str = "") -> str:
    """The :func:`study` numbers as a Markdown table."""
    f = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
    lines = [f"# {title or 'ukfm 2D localization benchmark'}", "",
             f"{st['runs']} trials (seed {st['seed']}), {st['healthy']} healthy; {st['diverged']['summary']}; "
             f"{st['heading_flips']['count']} heading flips (final |error| > {FLIP_DEG:g} deg); "
             f"{f(st['elapsed_s'])} s.", "",
             "| metric | window | mean over trials | p5 | p95 | pooled | published IEKF | its percentile |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for window, label in (("steady", "t >= 20 s"), ("all", "all n")):
        for key, name in (("heading_deg", "heading rms [deg]"), ("position_m", "position rms [m]")):
            d = st["rms"][window][key]
            lines.append(f"| {name} | {label} | {f(d['mean'])} | {f(d['p5'])} | {f(d['p95'])} | "
                         f"{f(d.get('pooled'))} | {f(d.get('published_iekf'))} | "
                         f"{f(d.get('published_iekf_percentile'))} |")
    for key, name in (("heading", "heading NEES"), ("position", "position NEES / 2")):
        d = st["nees"][key]
        lo, hi = d["chi2_bounds"]
        lines.append(f"| {name} | t >= 20 s | {f(d['mean'])} | {f(d['p5'])} | {f(d['p95'])} | - | "
                     f"1 (chi2 95 %: {lo:.3f}-{hi:.3f}) | - |")
    return "\n".join(lines + ["", st["definition"], ""])


def band_figure(bands_npz: str | Path):
    """The error bands from a saved ``bands.npz``, drawn by :func:`liemef.reports.figures.localization_band_figure`
    against the published IEKF figures."""
    return figures.localization_band_figure(bands_npz, published=PUBLISHED)


def reproduce(config: LocalizationConfig, out: Path, runs: int = 100, progress: bool = True) -> Reproduction:
    """The seeded run (:func:`~liemef.studies.experiments.default_reproduce`: ``metrics.json``, ``arrays.npz``,
    ``fig_pose.png``, ``errors.*``) and, with ``runs > 0``, a Monte Carlo (``montecarlo.*``), the study
    (``localization.md``/``.json``) and the error band figure (``bands.npz``, ``fig_errors.png``)."""
    from ...reports import plots
    from ._reproduce import default_reproduce

    rep = default_reproduce(LOCALIZATION, config, out, runs=0, progress=progress)
    if runs == 0:
        return rep
    mc_config = dataclasses.replace(config, rng="jax")
    t0 = time.perf_counter()
    mc = montecarlo(LOCALIZATION, mc_config, runs, seed=config.seed, progress=progress, keep_every=5)
    st = study(mc)
    st["elapsed_s"] = time.perf_counter() - t0
    written = mc.save(out)
    filt = repr(setup(mc_config).filter)
    bands = io.write_npz(out / "bands.npz", {"ts": mc.series_ts, "bands": mc.bands((5, 50, 95), absolute=True)[..., :2],
                                             "percentiles": np.array([5, 50, 95]), "runs": np.array(mc.runs),
                                             "healthy": np.array(mc.n_finite), "filter": np.array(
                                                 f"{config.order} order, {config.connection}-connection")})
    fig = plots.save_figure(band_figure(bands), out / "fig_errors.png")
    md = io.write_text(out / "localization.md", study_markdown(st, f"ukfm 2D localization benchmark: {filt}"))
    js = io.write_json(out / "localization.json", {"schema": "liemef.study.localization/1", **st})
    text = [rep.text, "", mc.format(), "", study_markdown(st, filt)]
    warnings = list(rep.warnings)
    if mc.n_nonfinite:
        warnings.append(f"WARNING: {mc.divergence_summary()}; left out of the statistics")
    if st["heading_flips"]["count"]:
        warnings.append(f"WARNING: {st['heading_flips']['count']} of {mc.runs} trials ended with the heading "
                        f"flipped (final |error| > {FLIP_DEG:g} deg)")
    return Reproduction(
        experiment=LOCALIZATION.name, out=out,
        figures=(*rep.figures, Output(fig, "Heading and position error: median and 5-95 % band across trials")),
        tables=(*rep.tables, Output(md, f"The scenario's metrics over {runs} trials"),
                Output(out / "montecarlo.md", f"Monte Carlo over {runs} seeds")),
        files=(*rep.files, *written, bands, fig, md, js), text="\n".join(text), warnings=tuple(warnings),
        summary={**rep.summary, "runs": mc.runs, "nonfinite": mc.n_nonfinite, "diverged": mc.diverged(),
                 "heading_flips": st["heading_flips"]["count"]})


LOCALIZATION = register(Experiment(
    **registry.card("localization"),
    default_config=LocalizationConfig(),
    run_fn=run,
    trial_fn=trial_spec,
    runs=100,
    quick_runs=20,
    tables=("rms heading and position error (t >= 20 s and all n), NEES, flips, against the published IEKF",),
    figures=(FigureSpec("fig_pose.png", ("theta", "x", "y"),
                        "Pose: truth (black), filtered (green); errors truth - estimate (red); GPS fixes in "
                        "arrays.npz (measured)"),),
    reproduce_fn=reproduce,
))
