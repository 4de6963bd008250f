r"""Rigid-body attitude on TSO(3): Saccon et al. 2016, Sec. V-B, Fig. 3, both connections on the same data.

Printed in the paper (eqs. (79)-(85)): inertia diag(2, 5, 3), torque
$\tau(t) = (\sin(2\pi t/3), \cos(2\pi t), \sin(2\pi t/5))$, T = 50 s, $\Omega(0) = (0.5, 0.6, 0.4)$, R(0) = I,
$\mathring a_1 = (0, 0, 1)$, $\mathring a_2 = (0, 1, 0)$, $\sigma_\varepsilon = 0.5/3$, $\sigma_\delta = 1$,
$D = \sigma_\varepsilon I_6$, $B_2 = \sigma_\delta I_3$, $Q = \sigma_\varepsilon^2 I_6$, $R = \sigma_\delta^2 I_3$,
$\alpha = 0.01$, $K(0) = I_6$, the filter started "with attitude error angle of about 60 deg". The truth is
integrated from the nominal torque by geometric (Lie-)Euler with h = 1 ms; the filter is fed the torque plus
$\mathbb I B_2 \delta$ (eq. (81)), $\delta$ white (per sample, std $\sigma_\delta$), and the two directions with
noise of std $\sigma_\varepsilon$ per component and sample.

**Not printed** (our choices, recorded in ``metrics.json``): the initial estimate. The paper states only its
attitude error; we take $\hat R(0) = R(0) \exp(60^\circ\, \hat n)$ with $\hat n = (1, 1, 1)/\sqrt 3$ and the true
$\hat\Omega(0) = \Omega(0)$ (the paper mentions no velocity error). Also not printed: the filter's integrator
(RKMK4 with one step per 1 ms sample, as for the other experiments).

Errors (Fig. 3): the attitude error angle $e^R = |\log(\hat R^\top R)|$, which equals eq. (86)'s
$\mathrm{acos}(1 - \mathrm{tr}(I - R^\top \hat R)/2)$ but is accurate near 0, in degrees, and the angular
velocity error $|e^\Omega| = |\hat\Omega - \Omega|$ (eq. (87)); also the group error components
$\log(\hat g^{-1} g)$. Both connections ((0), the paper's Prop. 5.1, and (-), Prop. 5.2) filter the same
simulated data. :func:`compare_connections` runs the paired Monte Carlo comparison: the same keys for both
connections, per-trial rms of $e^R$ over the steady window, and how often the (0)-connection's is smaller
(the paper: "the (0)-connection based filter performing best").
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...connections import CARTAN_SCHOUTEN
from ...filters import MinimumEnergyFilter, Trajectory
from ...groups import R3, SO3, TSO3
from ...integrators import INTEGRATORS
from ...metrics import FULL, Window, error_table, gain_stats, group_error, wilson_interval
from ...reports import figures
from ...simulation import SensorLog, Truth, simulate, simulate_core
from ...systems import RigidBodyAttitude
from .. import registry
from ._base import (
    PAPER_SUBSTEPS,
    Experiment,
    FigureSpec,
    Output,
    Reproduction,
    Result,
    RunConfig,
    TrialSpec,
    register,
    setup_cache,
)
from ._evaluate import evaluate
from ._montecarlo import DEFAULT_BATCH_SIZE, MonteCarloResult, montecarlo
from ._reproduce import default_reproduce

ERROR_NAMES = ("e_R", "e_Omega", "log_rx", "log_ry", "log_rz", "log_wx", "log_wy", "log_wz")
ERROR_UNITS = ("deg", "rad/s", "rad", "rad", "rad", "rad/s", "rad/s", "rad/s")
ERROR_DEFINITION = ("e_R = |log(R_hat^T R)| in deg (Saccon et al. 2016, eq. (86)); e_Omega = |Omega_hat - Omega| "
                    "(eq. (87)); log_* = log(g_hat^-1 g) = (log(R_hat^T R), Omega - Omega_hat), body frame")
FIG3_FILE = "fig3_errors.png"
CONNECTION_LABEL = {"zero": "(0)", "minus": "(-)", "plus": "(+)"}


def paper_torque(t):
    r"""The nominal torque of Saccon et al. 2016, eq. (80): $(\sin(2\pi t/3), \cos(2\pi t), \sin(2\pi t/5))$."""
    return jnp.stack([jnp.sin(2.0 * jnp.pi * t / 3.0), jnp.cos(2.0 * jnp.pi * t), jnp.sin(2.0 * jnp.pi * t / 5.0)])


WEIGHTS = {
    "printed": "Q = sigma_eps^2 I6 = D'D, R = sigma_delta^2 I3 = B2'B2 as printed (eqs. (84)-(85)): "
               "D^-T Q D^-1 = I and B R^-1 B' = I on the velocity block, the filter is not weighted by the noise "
               "levels",
    "consistent": "Q = I6, R = I3 (our alternative): the residual weighted by D^-T D^-1 = I6 / sigma_eps^2, the "
                  "model error by B B' = sigma_delta^2 on the velocity block",
}
"""The experiment's weight choices (``AttitudeConfig.weights``) and what they mean."""


@dataclass(frozen=True)
class AttitudeConfig(RunConfig):
    r"""The attitude experiment (Saccon et al. 2016, Sec. V-B).

    Fields:
        seed: the run's key is ``jax.random.key(seed)``.
        duration, dt: final time T and the step of the truth and the filter (one sample per step).
        connection: the connection of the main results (``"zero"``, the paper's Prop. 5.1).
        compare_with: the second connection run on the same data (``"minus"``, Prop. 5.2).
        order: ``"second"`` (the paper's filter) or ``"first"`` (the left-invariant EKF).
        integrator: the filter's integrator; truth_integrator: the truth's (``"lie-euler"``, the paper's
            geometric Euler).
        alpha, K0_diag: forgetting factor and initial gain (the paper's 0.01 and I6).
        sigma_eps, sigma_delta: noise levels (eq. (84)); D = sigma_eps I6, B2 = sigma_delta I3, simulated
            torque noise I B2 delta per sample.
        weights: ``"printed"`` (Q = sigma_eps^2 I6 = D'D, R = sigma_delta^2 I3 = B2'B2, eqs. (84)-(85), so the
            filter is not weighted by the noise levels) or ``"consistent"`` (Q = I6, R = I3: the residual
            weighted by 1/sigma_eps^2, the model error by sigma_delta^2); see :data:`WEIGHTS`.
        inertia_diag, omega0: the body and its initial angular velocity (R(0) = I).
        initial_error_deg, initial_axis: R_hat(0) = R(0) exp(initial_error_deg * axis/|axis|).
        filter_omega0: Omega_hat(0).
        steady: the window (start, stop) of the "after convergence" statistics and of the comparison, in s.
    """

    seed: int = 0
    duration: float = 50.0
    dt: float = 1e-3
    connection: str = "zero"
    compare_with: str = "minus"
    order: str = "second"
    integrator: str = "rkmk4"
    truth_integrator: str = "lie-euler"
    alpha: float = 0.01
    K0_diag: tuple[float, ...] = (1.0,) * 6
    sigma_eps: float = 0.5 / 3.0
    sigma_delta: float = 1.0
    weights: str = "printed"
    inertia_diag: tuple[float, ...] = (2.0, 5.0, 3.0)
    omega0: tuple[float, ...] = (0.5, 0.6, 0.4)
    initial_error_deg: float = 60.0
    initial_axis: tuple[float, ...] = (1.0, 1.0, 1.0)
    filter_omega0: tuple[float, ...] = (0.5, 0.6, 0.4)
    steady: tuple[float, float] = (10.0, 50.0)

    window_times = ("steady",)  # follow a new duration (RunConfig.window_changes)

    def __post_init__(self):
        self._check_run(positive=("sigma_eps", "sigma_delta"))
        _validate.choice("connection", self.connection, set(CARTAN_SCHOUTEN))
        _validate.choice("compare_with", self.compare_with, set(CARTAN_SCHOUTEN) - {self.connection})
        _validate.choice("truth_integrator", self.truth_integrator, set(INTEGRATORS))
        _validate.choice("weights", self.weights, set(WEIGHTS))
        _validate.nonnegative("alpha", self.alpha)
        if _validate.array("K0_diag", self.K0_diag, (6,)).min() < 0:
            raise ValueError(f"K0_diag: expected entries >= 0, got {self.K0_diag}")
        if _validate.array("inertia_diag", self.inertia_diag, (3,)).min() <= 0:
            raise ValueError(f"inertia_diag: expected entries > 0, got {self.inertia_diag}")
        for name in ("omega0", "filter_omega0"):
            _validate.array(name, getattr(self, name), (3,))
        _validate.array("initial_error_deg", self.initial_error_deg, ())
        if np.linalg.norm(_validate.array("initial_axis", self.initial_axis, (3,))) == 0:
            raise ValueError(f"initial_axis: expected a nonzero vector, got {self.initial_axis}")
        lo, hi = _validate.array("steady", self.steady, (2,))
        if not lo < hi:
            raise ValueError(f"steady: expected a window (start, stop) with start < stop, got {self.steady}")
        self._freeze(floats=("alpha", "sigma_eps", "sigma_delta", "initial_error_deg"),
                     tuples=("K0_diag", "inertia_diag", "omega0", "initial_axis", "filter_omega0", "steady"))

    @property
    def connections(self) -> tuple[str, str]:
        """``(connection, compare_with)``: the two filters run on the same data."""
        return (self.connection, self.compare_with)

    @property
    def windows(self) -> tuple[Window, ...]:
        """The whole run, the steady window (cut at the final time) and its second half (the (-)-filter
        converges more slowly); only the whole run if the steady window starts after the final time."""
        lo, hi = self.steady[0], min(self.steady[1], self.duration)
        return (FULL, Window(lo, hi), Window(0.5 * (lo + hi), hi)) if lo < hi else (FULL,)


@dataclass(frozen=True)
class Setup:
    """What a trial needs, independent of the seed (cached per config with ``seed = 0``): the system, one
    filter per connection (``filters[k]`` for ``config.connections[k]``), the initial truth and estimate."""

    config: AttitudeConfig
    system: RigidBodyAttitude
    filters: tuple[MinimumEnergyFilter, MinimumEnergyFilter]
    g0: TSO3
    state0: object
    ts: np.ndarray


def initial_estimate(config: AttitudeConfig) -> TSO3:
    """(R_hat(0), Omega_hat(0)) = (R(0) exp(angle * axis), filter_omega0), R(0) = I."""
    axis = np.asarray(config.initial_axis) / np.linalg.norm(config.initial_axis)
    R_hat0 = SO3.exp(jnp.asarray(math.radians(config.initial_error_deg) * axis))
    return TSO3((R_hat0, R3(jnp.asarray(config.filter_omega0))))


@setup_cache()
def setup(config: AttitudeConfig) -> Setup:
    """The system, filters, initial states and time grid of ``config`` (cached; see :class:`Setup`)."""
    se, sd = config.sigma_eps, config.sigma_delta
    printed = config.weights == "printed"
    system = RigidBodyAttitude(inertia=np.diag(config.inertia_diag),
                               B=np.vstack([np.zeros((3, 3)), sd * np.eye(3)]), D=se * np.eye(6),
                               Q=(se**2 if printed else 1.0) * np.eye(6),
                               R=(sd**2 if printed else 1.0) * np.eye(3))  # eqs. (84)-(85)
    filters = tuple(MinimumEnergyFilter(system, curvature="exact", error="left", connection=conn, order=config.order,
                                        integrator=config.integrator, alpha=config.alpha, substeps=PAPER_SUBSTEPS)
                    for conn in config.connections)
    state0 = filters[0].init(initial_estimate(config), np.diag(config.K0_diag))
    g0 = TSO3((SO3.identity(), R3(jnp.asarray(config.omega0))))
    return Setup(config=config, system=system, filters=filters, g0=g0, state0=state0, ts=config.ts)


def trial(s: Setup, key) -> tuple[Truth, SensorLog, tuple[Trajectory, Trajectory]]:
    """Simulation and both filter runs for one key: traceable, so ``jax.vmap`` batches Monte Carlo trials."""
    c = s.config
    truth, log = simulate_core(s.system, s.g0, paper_torque, jnp.asarray(s.ts), key, 0.0, s.system.torque_noise,
                               1, c.truth_integrator)
    return truth, log, tuple(f.scan(s.state0, log.ts, log.us, log.ys, engine=None) for f in s.filters)


def attitude_errors(truth: TSO3, estimate: TSO3) -> jax.Array:
    """(..., 8): e_R [deg], |e_Omega| [rad/s] and log(g_hat^-1 g) (see :data:`ERROR_DEFINITION`); traceable."""
    xi = group_error(truth, estimate)
    e_R = jnp.degrees(jnp.sqrt(jnp.sum(xi[..., :3] ** 2, axis=-1)))
    e_W = jnp.sqrt(jnp.sum(xi[..., 3:] ** 2, axis=-1))
    return jnp.concatenate([e_R[..., None], e_W[..., None], xi], axis=-1)


def measured_state(ys: np.ndarray) -> np.ndarray:
    """The state coordinates read off the direction measurements (N, 6): the attitude's rotation vector by
    TRIAD, trusting a1 = e3 first (R^T e3 and R^T e2 are the third and second rows of R); Omega is not
    measured (NaN)."""
    ys = np.asarray(ys, dtype=np.float64)
    r3 = ys[:, 0:3] / np.linalg.norm(ys[:, 0:3], axis=1, keepdims=True)
    r2 = ys[:, 3:6] - np.sum(ys[:, 3:6] * r3, axis=1, keepdims=True) * r3
    r2 /= np.linalg.norm(r2, axis=1, keepdims=True)
    rows = np.stack([np.cross(r2, r3), r2, r3], axis=1)
    out = np.full((ys.shape[0], 6), np.nan)
    ok = np.all(np.isfinite(rows), axis=(1, 2))  # a missing direction: NaN coordinates, not a matrix to check
    if ok.any():
        out[ok, :3] = np.asarray(SO3.from_matrix(rows[ok]).log())
    return out


def _assumptions(c: AttitudeConfig) -> dict:
    return {
        "initial_estimate": f"R_hat(0) = exp({c.initial_error_deg:g} deg about {list(c.initial_axis)}/|.|), "
                            f"Omega_hat(0) = {list(c.filter_omega0)} (the paper states only 'an attitude error "
                            "angle of about 60 deg'; our choice)",
        "truth": f"{c.truth_integrator} (the paper's geometric Euler) with h = {c.dt:g} s from the nominal "
                 "torque, no model error",
        "filter_input": f"torque + I B2 delta, delta ~ N(0, I3) per sample (eq. (81)), B2 = {c.sigma_delta:g} I3",
        "measurements": f"(R^T a1, R^T a2) + sigma_eps eps, eps ~ N(0, I6) per sample, sigma_eps = {c.sigma_eps:g}",
        "filter": f"{c.integrator} with one step per sample (not printed); alpha = {c.alpha:g}, K(0) = "
                  f"diag({', '.join(f'{v:g}' for v in c.K0_diag)})",
        "connections": f"{c.connection} (main results) and {c.compare_with}, on the same simulated data",
        "weights": WEIGHTS[c.weights],
    }


def run(config: AttitudeConfig | None = None, key=None) -> Result:
    """Simulate once, filter with both connections and evaluate (key ``jax.random.key(config.seed)``)."""
    c = AttitudeConfig() if config is None else config
    s = setup(c)
    key = jax.random.key(c.seed) if key is None else key
    truth, log = simulate(s.system, s.g0, paper_torque, s.ts, key, input_noise=s.system.torque_noise,
                          integrator=c.truth_integrator)
    trajs = tuple(f.run(s.state0, log.ts, log.us, log.ys) for f in s.filters)
    ts = np.asarray(s.ts)
    errs = {conn: np.asarray(attitude_errors(truth.g, tr.g_hat)) for conn, tr in zip(c.connections, trajs,
                                                                                     strict=True)}
    tables = {conn: error_table(ts, e, ERROR_NAMES, ERROR_UNITS, c.windows) for conn, e in errs.items()}
    single = {}
    for w, window in enumerate(c.windows[1:], start=1):
        rms = {conn: float(t.rms[w, 0]) for conn, t in tables.items()}
        single[window.label] = {"rms_e_R_deg": rms, "smaller": min(rms, key=rms.get)}
    extra = {
        "attitude_errors": {"definition": ERROR_DEFINITION,
                            "connections": {conn: t.to_dict() for conn, t in tables.items()}},
        "gain_by_connection": {conn: gain_stats(np.asarray(tr.K)) for conn, tr in zip(c.connections, trajs,
                                                                                        strict=True)},
        "comparison": {
            "criterion": "rms of e_R over each window after the transient; both connections filter the same "
                         "simulated data",
            "single_run": single,
            "monte_carlo": None,
        },
        "figure3": {"file": FIG3_FILE, "paper_figure": "Saccon et al. 2016, Fig. 3",
                    "title": "attitude error angle and angular velocity error, both connections"},
    }
    extra_arrays = {
        "connections": np.array(c.connections),
        "attitude_error_names": np.array(ERROR_NAMES), "attitude_error_units": np.array(ERROR_UNITS),
        **{f"attitude_error_{conn}": e for conn, e in errs.items()},
        **{f"K_diag_{conn}": np.diagonal(np.asarray(tr.K), axis1=1, axis2=2)
           for conn, tr in zip(c.connections, trajs, strict=True)},
    }
    result = evaluate(ATTITUDE, c, s.filters[0], truth, log, trajs[0], measured_state(np.asarray(log.ys)),
                      c.windows, _assumptions(c), extra_metrics=extra, extra_arrays=extra_arrays)
    names, units = _comparison_labels(c)
    summary = error_table(ts, np.concatenate([errs[conn][:, :2] for conn in c.connections], axis=1), names, units,
                          c.windows)
    raw = {**result.raw, "trajectories": dict(zip(c.connections, trajs, strict=True))}
    return dataclasses.replace(result, table=summary, raw=raw)


def _comparison_labels(config: AttitudeConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and units of the columns ``e_R_<connection>, e_Omega_<connection>`` of both connections."""
    names = tuple(f"{n}_{conn}" for conn in config.connections for n in ERROR_NAMES[:2])
    units = tuple(u for _ in config.connections for u in ERROR_UNITS[:2])
    return names, units


def trial_spec(config: AttitudeConfig) -> TrialSpec:
    """The Monte Carlo trial of ``config``: e_R [deg] and |e_Omega| of both connections on the same simulated
    data, columns ``e_R_<connection>, e_Omega_<connection>`` for ``config.connections`` (traceable in the key)."""
    s = setup(config)

    def errors(key):
        truth, _, trajs = trial(s, key)
        return jnp.concatenate([attitude_errors(truth.g, tr.g_hat)[:, :2] for tr in trajs], axis=1)

    names, units = _comparison_labels(config)
    return TrialSpec(ts=s.ts, names=names, units=units, windows=config.windows, errors=errors)


# --- the paired Monte Carlo comparison of the two connections -------------------------------------------------
def _summary(x: np.ndarray) -> dict | None:
    if x.size == 0:
        return None
    return {"mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)) if x.size > 1 else None,
            "median": float(np.median(x)), "min": float(np.min(x)), "max": float(np.max(x))}


def comparison(mc: MonteCarloResult, config: AttitudeConfig) -> dict:
    """The paired comparison of the two connections from a Monte Carlo of :func:`trial_spec` (every trial
    filters the same simulated data with both): per window after the transient (``config.steady`` and its
    second half), the number of finite trials in which ``config.connection`` has the smaller rms of e_R, that
    fraction with a 95 % Wilson interval, the per-trial rms of each connection and their paired differences.
    JSON-ready."""
    a, b = config.connection, config.compare_with
    out = {"criterion": "per-trial rms of e_R = |log(R_hat^T R)| [deg] over the window; paired trials (both "
                        "connections filter the same simulated data)",
           "runs": mc.runs, "seed": mc.seed, "finite_runs": mc.n_finite, "connection": a, "compare_with": b,
           "windows": {}}
    for window in config.windows[1:]:
        ra, rb = (mc.values(f"e_R_{conn}", window, "rms") for conn in (a, b))
        wa, wb = (mc.values(f"e_Omega_{conn}", window, "rms") for conn in (a, b))
        ok = np.isfinite(ra) & np.isfinite(rb) & np.isfinite(wa) & np.isfinite(wb)
        ra, rb, wa, wb = ra[ok], rb[ok], wa[ok], wb[ok]
        wins, n = int(np.sum(ra < rb)), int(ra.size)
        out["windows"][window.label] = {
            "wins": wins, "trials": n, "fraction": wins / n if n else None, "wilson95": list(wilson_interval(wins, n)),
            "rms_e_R_deg": {a: _summary(ra), b: _summary(rb)},
            "rms_e_Omega": {a: _summary(wa), b: _summary(wb)},
            "difference_deg": {"definition": f"rms e_R({b}) - rms e_R({a}) per trial", **(_summary(rb - ra) or {})},
            "per_trial_rms_e_R_deg": {a: [float(v) for v in ra], b: [float(v) for v in rb]},
        }
    return out


def compare_connections(config: AttitudeConfig | None = None, runs: int = 20, seed: int | None = None,
                        batch_size: int = DEFAULT_BATCH_SIZE,
                        progress: bool = False) -> tuple[dict, MonteCarloResult]:
    """A Monte Carlo of ``runs`` trials (:func:`liemef.studies.experiments.montecarlo`, seed ``config.seed`` unless
    given) and its :func:`comparison` of the two connections."""
    c = AttitudeConfig() if config is None else config
    mc = montecarlo(ATTITUDE, c, runs, seed=c.seed if seed is None else seed, batch_size=batch_size,
                    progress=progress)
    return comparison(mc, c), mc


def format_comparison(cmp: dict) -> str:
    """The comparison (:func:`comparison`) for the terminal: one paragraph per window."""
    a, b = cmp["connection"], cmp["compare_with"]
    la, lb = CONNECTION_LABEL.get(a, a), CONNECTION_LABEL.get(b, b)
    lines = [f"{la}- vs {lb}-connection over {cmp['finite_runs']} paired trials (seed {cmp['seed']}): "
             f"rms of the attitude error angle e_R per trial"]
    for label, w in cmp["windows"].items():
        if not w["trials"]:
            lines.append(f"  {label}: no finite trial")
            continue
        ra, rb, d = w["rms_e_R_deg"][a], w["rms_e_R_deg"][b], w["difference_deg"]
        lo, hi = w["wilson95"]
        sd = lambda x: "" if x["std"] is None else f" +- {x['std']:.3f}"  # noqa: E731
        lines.append(f"  {label}: {la} smaller in {w['wins']} of {w['trials']} trials ({100 * w['fraction']:.0f} %, "
                     f"95 % interval {100 * lo:.0f}-{100 * hi:.0f} %); rms e_R {la} {ra['mean']:.3f}{sd(ra)} deg, "
                     f"{lb} {rb['mean']:.3f}{sd(rb)} deg, paired difference {d['mean']:.3f}{sd(d)} deg")
    return "\n".join(lines)


# --- Fig. 3 -----------------------------------------------------------------------------------------------------
def figure3(arrays: dict, steady: tuple[float, float] | None = None):
    """Saccon et al. 2016, Fig. 3 from saved arrays, drawn by :func:`liemef.reports.figures.attitude_figure3` with
    this study's connection labels."""
    return figures.attitude_figure3(arrays, steady, connection_labels=CONNECTION_LABEL)


def write_figure3(out: str | os.PathLike) -> Path:
    """Draw :func:`figure3` from the result saved in the folder ``out`` (``arrays.npz``, ``metrics.json``)."""
    from ...reports import io, plots

    d = Path(out)
    arrays = io.read_arrays(d / io.ARRAYS_FILE)
    cfg = io.read_metrics(d / io.METRICS_FILE)["config"]
    lo, hi = cfg["steady"][0], min(cfg["steady"][1], cfg["duration"])
    return plots.save_figure(figure3(arrays, (lo, hi) if lo < hi else None), d / FIG3_FILE)


# --- reproduction ---------------------------------------------------------------------------------------------
COMPARISON_FILE = "comparison.md"


def reproduce(config: AttitudeConfig, out: Path, runs: int = 0, progress: bool = True) -> Reproduction:
    """``liemef reproduce attitude``: the seeded run (:func:`~liemef.studies.experiments.default_reproduce`: metrics,
    arrays, figures, error tables), Fig. 3 (:func:`write_figure3`) and, with ``runs > 0``, a Monte Carlo of
    ``runs`` paired trials (``montecarlo.*``) whose :func:`comparison` of the connections goes into
    ``metrics.json`` (``comparison.monte_carlo``), ``comparison.md`` and the printed text."""
    from ...reports import io

    rep = default_reproduce(ATTITUDE, config, out, runs=0, progress=progress)
    fig3 = write_figure3(out)
    figures = (Output(fig3, "Saccon et al. 2016, Fig. 3: attitude error angle and angular velocity error, "
                            "(0)-connection (black) and (-)-connection (dashed red)"), *rep.figures)
    files, tables, summary = [*rep.files, fig3], list(rep.tables), dict(rep.summary)
    gains = io.read_metrics(out / io.METRICS_FILE)["gain_by_connection"]
    text = [rep.text, "Gain K by connection: " + "; ".join(
        f"{conn}: max |K - K'|/|K| = {g['max_rel_asymmetry']:.2e}" for conn, g in gains.items())]
    warnings = list(rep.warnings)
    if runs > 0:
        cmp, mc = compare_connections(config, runs, seed=config.seed, progress=progress)
        written = mc.save(out, "montecarlo")
        metrics = io.read_metrics(out / io.METRICS_FILE)
        metrics["comparison"]["monte_carlo"] = cmp
        written.append(io.write_json(out / io.METRICS_FILE, metrics))
        paragraph = format_comparison(cmp)
        written.append(io.write_text(out / COMPARISON_FILE, f"# attitude: (0)- vs (-)-connection\n\n"
                                                            f"{ATTITUDE.paper}.\n\n```\n{paragraph}\n```\n"))
        files += [p for p in written if p not in files]
        tables += [Output(out / COMPARISON_FILE, f"How often the {config.connection}-connection beats the "
                                                 f"{config.compare_with}-connection ({runs} paired trials)"),
                   Output(out / "montecarlo.md", f"Monte Carlo over {runs} seeds")]
        text += ["", mc.format(), "", paragraph]
        summary.update(runs=mc.runs, nonfinite=mc.n_nonfinite,
                       wins={k: f"{w['wins']}/{w['trials']}" for k, w in cmp["windows"].items()})
        if mc.n_nonfinite:
            warnings.append(f"WARNING: {mc.n_nonfinite} of {mc.runs} Monte Carlo trials were non-finite "
                            "(diverged) and are left out of the comparison")
    return Reproduction(experiment=ATTITUDE.name, out=out, figures=figures, tables=tuple(tables),
                        files=tuple(files), text="\n".join(text), warnings=tuple(warnings), summary=summary)


QUICK = AttitudeConfig(duration=20.0, steady=(10.0, 20.0))
"""Reduced config for ``liemef reproduce all``: 20 s (the (0)-filter's transient is over by 10 s) at 1 ms."""

ATTITUDE = register(Experiment(
    **registry.card("attitude"),
    default_config=AttitudeConfig(),
    run_fn=run,
    trial_fn=trial_spec,
    runs=20,
    quick_config=QUICK,
    quick_runs=8,
    reproduce_fn=reproduce,
    figures=(
        FigureSpec("fig_angular_velocity.png", ("wx", "wy", "wz"),
                   "Angular velocity: truth (black), (0)-connection estimate (green); errors (red)",
                   "Saccon et al. 2016, Fig. 3 (e_Omega components)"),
    ),
))
