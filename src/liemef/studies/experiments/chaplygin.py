r"""The Chaplygin sleigh on SE(2) x R^2: Rigo, Sansonetto, Muradore 2023, Sec. 6, Tables 1-2, Figs. 3-6.

Printed in the paper (Sec. 6; DESIGN.md §2): J = 6.125, m = 125, a = 0.3, l = 0.2; inputs
$u_\omega = 10\sin(t/2)$, $u_v = \tfrac12\sin(t/5)$; T = 20 s; truth from $(\pi/6, 1, 2, 0, 0)$; the filter starts
at the true state; D = diag(0.4 x4, 0.2, 0.2) (GPS only: 0.4 I4), B2 = diag(10, 10), R = I, Q = I, alpha = 0;
K(0) = I5 for the (0)-connection and the constraint-preserving K(0) of eq. (63) for the (-)-connection; RK4 with
step Ts and a measurement every Ts, Ts = 10 ms (Table 1, Figs. 3-4) and 1 ms (Table 2, Figs. 5-6); GPS + INS and
GPS only. Errors $\delta\theta = \theta - \hat\theta$, ... (truth minus estimate).

Simulation choices the paper leaves open, and what reproduces its tables (DESIGN.md §3, ``docs/chaplygin.md``):

* ``weights``: ``"consistent"`` (default) is Theorem 4.1 with the stated Q = I, so that
  $D^{-\top} Q D^{-1}$ = diag(6.25 x4, 25, 25) weighs the residual (eq. (27)) *and* E. ``"printed"`` is the mix
  the paper prints: residual and Hessian part of E with the weights of eq. (27), the constant part of E as printed
  (2 l^2, 2, 2, 1, 1), which holds only for Q = D'D (:class:`PrintedWeightsFilter`). ``"unweighted"`` is
  Q = D'D throughout (what eqs. (33), (38), (48) presuppose): no weights at all.
* ``model_error_std``: the std of the unit-variance model error $\delta$ of eq. (18) in the truth, drawn per
  sample and held, entering as $B\delta$ = (0, B2 delta). 0 (default): the nominal truth. 1: the printed level,
  $B_2\delta$ of std 10 per sample (:data:`PRINTED_MODEL_ERROR_STD`).

:func:`trial` is the traceable core (one key, ``vmap``-able); :func:`run` one evaluated run;
:func:`reproduce` the whole study (``liemef reproduce chaplygin --runs N --out DIR``): the four configurations
(2 sensor sets x 2 connections) at Ts = 10 ms and 1 ms through :func:`~liemef.studies.experiments.montecarlo`,
Tables 1-2
side by side with the paper, the alternatives' numbers, and Figs. 3-6 from one representative run.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ... import _validate
from ...filters import AbstractFilter, MinimumEnergyFilter, Trajectory
from ...metrics import FULL
from ...reports import io
from ...simulation import SensorLog, Truth, simulate, simulate_core
from ...systems import ChaplyginSleigh
from ...systems.chaplygin import SENSORS, constraint_K0, se2r2_state
from ._base import (
    PAPER_SUBSTEPS,
    Experiment,
    FigureSpec,
    Output,
    Reproduction,
    Result,
    RunConfig,
    TrialSpec,
    config_dict,
    register,
)
from ._evaluate import evaluate, state_error_trial
from ._montecarlo import DEFAULT_BATCH_SIZE, MonteCarloResult, ProgressLine, montecarlo
from ._reproduce import default_reproduce

CONNECTIONS = ("zero", "minus")
"""The paper's two connections: (0) (lambda = 1/2, Prop. 1) and (-) (lambda = 0, Sec. 5)."""
WEIGHTS = ("consistent", "printed", "unweighted")
K0_CHOICES = ("paper", "identity", "constrained")
PRINTED_MODEL_ERROR_STD = 1.0
"""The model error of eq. (18) at the printed level: delta ~ N(0, I2), so B2 delta has std b = 10 per sample."""
PAPER_DTS = (0.01, 0.001)
LABEL = {"zero": "(0)", "minus": "(-)", "gps_ins": "GPS + INS", "gps": "GPS"}
SCALE = 1e3
"""Errors are reported as the paper's tables do: mrad, mm, mrad/s, mm/s."""
TABLE_UNITS = ("mrad", "mm", "mm", "mrad/s", "mm/s")
COMPONENTS = ("theta", "x", "y", "omega", "v")
STATS3 = ("mean", "std", "rms")
GREEK = {"theta": "θ", "omega": "ω", "x": "x", "y": "y", "v": "v"}


def paper_input(t):
    r"""The nominal input of Rigo et al. 2023, Sec. 6: $(u_\omega, u_v) = (10\sin(t/2), \tfrac12\sin(t/5))$."""
    return jnp.stack([10.0 * jnp.sin(t / 2.0), 0.5 * jnp.sin(t / 5.0)])


def _table(rows: dict[str, tuple[tuple[float, float], ...]]) -> dict:
    """{component: ((mean0, mean-), (std0, std-), (rms0, rms-))} -> {connection: {component: (mean, std, rms)}}."""
    return {conn: {c: tuple(v[k] for v in rows[c]) for c in COMPONENTS} for k, conn in enumerate(CONNECTIONS)}


PAPER_TABLES: dict[tuple[float, str], dict[str, dict[str, tuple[float, float, float]]]] = {
    # Table 1, Ts = 10 ms; (0)-connection first, (-)-connection "in bracket" second. Units: mrad, mm, and (the
    # printed "mm/rad" misprints) mrad/s, mm/s.
    (0.01, "gps_ins"): _table({
        "theta": ((28.7, 71.1), (41.1, 32.7), (50.1, 78.2)),
        "x": ((-0.3, -37.8), (19.2, 122.6), (19.2, 128.3)),
        "y": ((-20.5, -281.0), (30.9, 177.6), (37.1, 332.3)),
        "omega": ((12.3, 12.3), (94.2, 94.2), (95.0, 95.0)),
        "v": ((4.9, 4.8), (99.4, 99.4), (99.5, 99.4)),
    }),
    (0.01, "gps"): _table({
        "theta": ((-2.1, -6.8), (180.5, 194.7), (180.4, 194.8)),
        "x": ((4.9, -13.8), (66.8, 77.9), (67.0, 79.1)),
        "y": ((-11.6, -51.9), (59.3, 103.2), (60.4, 115.5)),
        "omega": ((-2.5, 4.4), (208.8, 203.8), (208.8, 203.8)),
        "v": ((0.0, 15.4), (249.5, 251.9), (249.4, 252.3)),
    }),
    # Table 2, Ts = 1 ms
    (0.001, "gps_ins"): _table({
        "theta": ((-0.1, 4.9), (6.6, 9.2), (6.6, 10.4)),
        "x": ((8.3, -0.4), (9.5, 18.0), (12.6, 18.0)),
        "y": ((-6.1, -28.6), (7.3, 22.0), (9.5, 36.1)),
        "omega": ((1.5, 1.5), (31.2, 31.2), (31.2, 31.2)),
        "v": ((-1.8, -1.9), (33.9, 33.9), (33.9, 33.9)),
    }),
    (0.001, "gps"): _table({
        "theta": ((-6.1, -4.0), (44.4, 57.0), (44.8, 57.1)),
        "x": ((5.5, -8.8), (20.9, 31.9), (21.7, 33.1)),
        "y": ((-5.1, -33.5), (16.3, 36.6), (17.1, 49.6)),
        "omega": ((-1.1, -0.4), (54.2, 57.1), (54.2, 57.1)),
        "v": ((2.8, 1.0), (77.1, 80.0), (77.2, 80.0)),
    }),
}
"""Rigo et al. 2023, Tables 1-2: ``PAPER_TABLES[(Ts, sensor)][connection][component] = (mean, std, rms)`` in
mrad, mm, mrad/s, mm/s, of a single run each."""


def paper_value(dt: float, sensor: str, connection: str, component: str, stat: str) -> float | None:
    """The printed Table 1 (Ts = 10 ms) / Table 2 (1 ms) entry in mrad, mm, mrad/s, mm/s; None if not printed."""
    for (ts, sen), table in PAPER_TABLES.items():
        if math.isclose(ts, dt, rel_tol=1e-9) and sen == sensor and connection in table:
            return table[connection][component][STATS3.index(stat)]
    return None


@dataclass(frozen=True)
class ChaplyginConfig(RunConfig):
    r"""The Chaplygin sleigh experiment (Rigo et al. 2023, Sec. 6; DESIGN.md §2-§3).

    Fields:
        seed: the run's key is ``jax.random.key(seed)``; in :func:`reproduce` the Monte Carlo seed.
        sensor: ``"gps_ins"`` (two antennas + INS) or ``"gps"`` (antennas only, Remark 2).
        connection: ``"zero"`` (c = 1/2, Prop. 1) or ``"minus"`` (c = 0, Sec. 5).
        dt: Ts, the step of the truth and of the filter, one measurement per step (paper: 0.01 and 0.001).
        duration: final time T (paper: 20 s).
        order: ``"second"`` (the paper's filter) or ``"first"`` (the left-invariant EKF).
        integrator: ``"rkmk4"`` (the paper's RK4, on the group) or ``"lie-euler"``, truth and filter.
        weights: ``"consistent"`` (default), ``"printed"`` or ``"unweighted"`` (module docstring).
        model_error_std: std of the unit-variance model error delta per sample in the truth (0: nominal truth;
            :data:`PRINTED_MODEL_ERROR_STD` = 1: the printed level, B2 delta of std 10).
        K0: ``"paper"`` (I5 for ``"zero"``, eq. (63) for ``"minus"``), ``"identity"`` or ``"constrained"``
            (eq. (63): I5 with the third row and column zeroed).
        alpha: forgetting factor (paper: 0).
        truth0, filter0: initial truth and estimate (theta, x, y, omega, v); the paper starts the filter at the
            true state.
        table_dts, alternatives: :func:`reproduce` only: the Ts of the tables it writes, and whether it also runs
            the alternative simulation choices (printed weights, printed model error, unweighted).
    """

    seed: int = 0
    sensor: str = "gps_ins"
    connection: str = "zero"
    dt: float = 0.01
    duration: float = 20.0
    order: str = "second"
    integrator: str = "rkmk4"
    weights: str = "consistent"
    model_error_std: float = 0.0
    K0: str = "paper"
    alpha: float = 0.0
    truth0: tuple[float, ...] = (math.pi / 6, 1.0, 2.0, 0.0, 0.0)
    filter0: tuple[float, ...] = (math.pi / 6, 1.0, 2.0, 0.0, 0.0)
    table_dts: tuple[float, ...] = PAPER_DTS
    alternatives: bool = True

    def __post_init__(self):
        self._check_run()
        _validate.choice("sensor", self.sensor, set(SENSORS))
        _validate.choice("connection", self.connection, set(CONNECTIONS))
        _validate.choice("weights", self.weights, set(WEIGHTS))
        _validate.choice("K0", self.K0, set(K0_CHOICES))
        _validate.nonnegative("alpha", self.alpha)
        _validate.nonnegative("model_error_std", self.model_error_std)
        _validate.array("truth0", self.truth0, (5,))
        _validate.array("filter0", self.filter0, (5,))
        dts = _validate.array("table_dts", self.table_dts, (None,))
        if dts.size == 0 or not np.all(dts > 0):
            raise ValueError(f"table_dts: expected one or more steps > 0, got {self.table_dts}")
        if not isinstance(self.alternatives, bool):
            raise ValueError(f"alternatives: expected True or False, got {self.alternatives!r}")
        self._freeze(floats=("alpha", "model_error_std"),
                     tuples=("truth0", "filter0", "table_dts"))

    @property
    def K0_matrix(self) -> np.ndarray:
        """The initial gain: I5, or eq. (63) (``K0="constrained"``, or ``"paper"`` with the (-)-connection)."""
        constrained = self.K0 == "constrained" or (self.K0 == "paper" and self.connection == "minus")
        return constraint_K0() if constrained else np.eye(5)


class PrintedWeightsFilter(AbstractFilter):
    r"""The filter as Rigo et al. 2023 print it with the stated Q = I: residual (27)/(30) and the Hessian part
    of E with the weights $q_i/d_i^2$, but the constant part of E as printed in eqs. (33), (48), (58), (62),
    $Dh^\top Dh$ = diag(2 l^2, 2, 2, 1, 1), which is the theorem's only for Q = D'D:
    $E_{printed} = E - Dh^\top (D^{-\top} Q D^{-1} - I) Dh$ (pinned in ``tests/test_chaplygin_closed_forms.py``).

    A reproduction of a misprint, not a filter to use: a wrapper (final) of the minimum-energy filter with
    ``constant_E="unit"``, the field that makes this variant; every other term, the interval and the
    integrators are that filter's, and its attributes (``system``, ``terms``, ...) read through.
    """

    filter: MinimumEnergyFilter

    def __init__(self, system: ChaplyginSleigh, **options):
        self.filter = MinimumEnergyFilter(system, constant_E="unit", **options)

    def __repr__(self) -> str:
        return "PrintedWeightsFilter" + repr(self.filter).removeprefix("MinimumEnergyFilter").replace(
            ", constant_E='unit'", "")

    def __getattr__(self, name: str):
        if name == "filter" or name.startswith("__"):  # not set yet, or a protocol the wrapper does not have
            raise AttributeError(name)
        return getattr(self.filter, name)

    def _interval(self, state, t, dt, u0, u1, y0, y1, gap):
        return self.filter._interval(state, t, dt, u0, u1, y0, y1, gap)


@dataclass(frozen=True)
class Setup:
    """Everything a trial needs, built once from a config, independent of the seed (``config.seed = 0``;
    cached): runs that differ only in the seed share one compiled filter and simulation."""

    config: ChaplyginConfig
    system: ChaplyginSleigh
    filter: MinimumEnergyFilter
    g0: object
    state0: object
    ts: np.ndarray


def make_system(config: ChaplyginConfig) -> ChaplyginSleigh:
    """The paper's sleigh with ``config.sensor``; Q = D'D for ``weights="unweighted"``, else Q = I."""
    system = ChaplyginSleigh(sensor=config.sensor)
    if config.weights == "unweighted":
        D = np.asarray(system.D)
        system = ChaplyginSleigh(sensor=config.sensor, Q=D.T @ D)
    return system


def setup(config: ChaplyginConfig) -> Setup:
    """The system, filter, initial states and time grid of ``config`` (cached; see :class:`Setup`)."""
    return _setup(dataclasses.replace(config, seed=0, table_dts=PAPER_DTS, alternatives=True))


@functools.lru_cache(maxsize=16)
def _setup(config: ChaplyginConfig) -> Setup:
    system = make_system(config)
    cls = PrintedWeightsFilter if config.weights == "printed" else MinimumEnergyFilter
    flt = cls(system, connection=config.connection, order=config.order, integrator=config.integrator,
              alpha=config.alpha, substeps=PAPER_SUBSTEPS)
    state0 = flt.init(se2r2_state(*config.filter0), config.K0_matrix)
    return Setup(config=config, system=system, filter=flt, g0=se2r2_state(*config.truth0), state0=state0,
                 ts=config.ts)


def trial(s: Setup, key) -> tuple[Truth, SensorLog, Trajectory]:
    """Simulation and filter run for one key: traceable, so ``jax.vmap(lambda k: trial(s, k))(keys)`` batches
    Monte Carlo trials. The simulated data depend on the key, the sensor, T, Ts and the model error only, so
    the two connections (and the weight choices) see the same data for the same key."""
    c = s.config
    truth, log = simulate_core(s.system, s.g0, paper_input, jnp.asarray(s.ts), key, c.model_error_std, None, 1,
                               c.integrator)
    return truth, log, s.filter.scan(s.state0, log.ts, log.us, log.ys, engine=None)


def group_velocity(flt: MinimumEnergyFilter, traj: Trajectory, us, ys) -> jax.Array:
    r"""The estimate's left-trivialized velocity $\hat g^{-1}\dot{\hat g} = \lambda + K r$ at every sample but
    the last (N - 1, 5), from the state and the sample held over the interval that starts there (traceable).
    Its third component is the lateral velocity, which the nonholonomic constraint keeps at zero."""
    n = traj.ts.shape[0] - 1
    g = jax.tree_util.tree_map(lambda a: a[:n], traj.g_hat)
    f = lambda gk, Kk, uk, yk, tk: flt.vector_field(gk, Kk, uk, yk, tk)[0]  # noqa: E731
    return jax.vmap(f)(g, traj.K[:n], jnp.asarray(us)[:n], jnp.asarray(ys)[:n], traj.ts[:n])


_group_velocity_jit = jax.jit(group_velocity, static_argnums=0)


def measured_state(sensor: str, ys: np.ndarray) -> np.ndarray:
    """The state coordinates read off the measurements (N, 5), NaN where not measured: the heading
    ``atan2(y1 - y2, x1 - x2)`` and the antennas' midpoint (the blade's contact point) from the GPS, and
    (omega, v) from the INS."""
    ys = np.asarray(ys)
    out = np.full((ys.shape[0], 5), np.nan)
    x1, y1, x2, y2 = ys[:, 0], ys[:, 1], ys[:, 2], ys[:, 3]
    out[:, 0] = np.arctan2(y1 - y2, x1 - x2)
    out[:, 1], out[:, 2] = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    if sensor == "gps_ins":
        out[:, 3:5] = ys[:, 4:6]
    return out


def _assumptions(c: ChaplyginConfig) -> dict:
    weights = {
        "consistent": "Theorem 4.1 with the stated Q = I: D^-T Q D^-1 = diag(q/d^2) weighs the residual (eq. 27) "
                      "and E (DESIGN.md §3)",
        "printed": "as printed: residual and Hessian part of E with q/d^2 (eq. 27), constant part of E as printed "
                   "(2 l^2, 2, 2, 1, 1; valid only for Q = D'D)",
        "unweighted": "Q = D'D throughout (D^-T Q D^-1 = I), what eqs. (33), (38), (48) presuppose",
    }[c.weights]
    return {
        "K0": f"{'eq. (63), I5 with the third row and column zeroed' if c.K0_matrix[2, 2] == 0 else 'I5'} "
              f"(K0 = {c.K0!r})",
        "weights": weights,
        "sampling": f"one measurement per integration step, Ts = {c.dt:g} s, inputs and measurements held "
                    "(zero-order hold); RK4 on the group (RKMK4) for truth and filter"
                    if c.integrator == "rkmk4" else f"{c.integrator}, Ts = {c.dt:g} s",
        "truth": ("the nominal input without model error" if c.model_error_std == 0
                  else f"model error B delta, delta ~ N(0, {c.model_error_std:g}^2 I2) per sample (B2 = 10 I2)"),
        "filter_input": "the nominal input u(t)",
        "initial_estimate": "the true initial state (the paper's)" if c.filter0 == c.truth0
        else f"{list(c.filter0)}",
    }


def run(config: ChaplyginConfig | None = None, key=None) -> Result:
    """Simulate, filter and evaluate one run (key ``jax.random.key(config.seed)`` unless given). Besides the
    errors, ``metrics.json`` records the largest lateral velocity of the estimate (``constraint``) and
    ``arrays.npz`` its time series (``lateral_velocity``)."""
    c = ChaplyginConfig() if config is None else config
    s = setup(c)
    key = jax.random.key(c.seed) if key is None else key
    truth, log = simulate(s.system, s.g0, paper_input, s.ts, key, model_error_std=c.model_error_std,
                          integrator=c.integrator)
    traj = s.filter.run(s.state0, log.ts, log.us, log.ys)
    lateral = np.asarray(_group_velocity_jit(s.filter, traj, log.us, log.ys))[:, 2]
    K = np.asarray(traj.K)
    extra = {"constraint": {
        "definition": "lateral velocity of the estimate, the third component of lambda + K r at each sample "
                      "(Rigo et al. 2023, Sec. 5); zero to round-off with the (-)-connection and K(0) of eq. (63)",
        "max_abs_lateral_velocity": float(np.max(np.abs(lateral))),
        "max_abs_K_third_row_column": float(max(np.abs(K[:, 2, :]).max(), np.abs(K[:, :, 2]).max())),
    }}
    return evaluate(CHAPLYGIN, c, s.filter, truth, log, traj, measured_state(c.sensor, np.asarray(log.ys)),
                    (FULL,), _assumptions(c), extra_metrics=extra,
                    extra_arrays={"lateral_velocity": np.append(lateral, np.nan)})


def trial_spec(config: ChaplyginConfig) -> TrialSpec:
    """The Monte Carlo trial of ``config``: coordinate errors (theta, x, y, omega, v) of one seeded run over the
    whole run, as the paper's tables (traceable in the key)."""
    return state_error_trial(setup(config), trial, (FULL,))


# --- the reproduction of Tables 1-2 and Figs. 3-6 ---------------------------------------------------------------
@dataclass(frozen=True)
class Entry:
    """One cell of Tables 1-2 against the Monte Carlo: per-trial statistic ``stat`` of error ``component``
    (scaled to mrad, mm, mrad/s, mm/s) across the finite trials of one configuration."""

    dt: float
    sensor: str
    connection: str
    component: str
    stat: str
    mc_mean: float
    mc_spread: float
    p5: float
    p50: float
    p95: float
    paper: float | None
    percentile: float | None

    @property
    def inside(self) -> bool | None:
        """Whether the paper's value lies in the 5-95 % band of the Monte Carlo (None if not printed)."""
        return None if self.paper is None else bool(self.p5 <= self.paper <= self.p95)


def entries(mc: MonteCarloResult, dt: float, sensor: str, connection: str) -> list[Entry]:
    """Every (component, statistic) of one Monte Carlo against the printed table."""
    out = []
    pct = mc.percentiles  # (5 percentiles, windows, components, 3)
    for c, comp in enumerate(mc.names):
        for k, stat in enumerate(STATS3):
            paper = paper_value(dt, sensor, connection, comp, stat)
            where = None if paper is None or mc.n_finite == 0 else mc.percentile_of(paper / SCALE, comp, 0, stat)
            out.append(Entry(dt=dt, sensor=sensor, connection=connection, component=comp, stat=stat,
                             mc_mean=SCALE * float(mc.mean[0, c, k]), mc_spread=SCALE * float(mc.spread[0, c, k]),
                             p5=SCALE * float(pct[0, 0, c, k]), p50=SCALE * float(pct[2, 0, c, k]),
                             p95=SCALE * float(pct[4, 0, c, k]), paper=paper, percentile=where))
    return out


def band_fraction(es: list[Entry], stats=("std", "rms")) -> tuple[int, int]:
    """(inside, total): how many printed ``stats`` entries lie in the 5-95 % Monte Carlo band."""
    sel = [e for e in es if e.stat in stats and e.paper is not None and e.inside is not None]
    return sum(e.inside for e in sel), len(sel)


def _f(x: float | None, nd: int = 1) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


def _ms(dt: float) -> str:
    return f"{1e3 * dt:g} ms"


def _table_number(dt: float) -> str:
    return {0.01: "Table 1", 0.001: "Table 2"}.get(round(dt, 9), "(no printed table)")


def tables_markdown(es: list[Entry], runs: dict, heading: str = "") -> str:
    """Tables 1-2 side by side with the paper: one table per Ts, one row per (sensor, connection, error);
    per statistic the Monte Carlo mean +- seed-to-seed spread [5 %, 95 %] and the paper's value with its
    percentile in the Monte Carlo (``*``: outside the 5-95 % band)."""
    lines = [heading] if heading else []
    for dt in sorted({e.dt for e in es}, reverse=True):
        sel = [e for e in es if e.dt == dt]
        k, n = band_fraction(sel)
        lines += [f"## {_table_number(dt)}: Ts = {_ms(dt)}", "",
                  f"Paper's std and rms entries inside the 5-95 % Monte Carlo band: **{k} of {n}**.", "",
                  "| sensor | connection | error | unit | " + " | ".join(
                      f"{s}: MC mean ± spread [p5, p95] | {s}: paper (pct)" for s in STATS3) + " |",
                  "|---|---|---|---|" + "---:|" * 6]
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                rows = {(e.component, e.stat): e for e in sel if e.sensor == sensor and e.connection == conn}
                if not rows:
                    continue
                r = runs.get((dt, sensor, conn), {})
                tag = f"{LABEL[sensor]} | {LABEL[conn]}" + (f" ({r['nonfinite']} of {r['runs']} diverged)"
                                                            if r.get("nonfinite") else "")
                for comp, unit in zip(COMPONENTS, TABLE_UNITS, strict=True):
                    cells = []
                    for stat in STATS3:
                        e = rows[(comp, stat)]
                        cells.append(f"{_f(e.mc_mean)} ± {_f(e.mc_spread)} [{_f(e.p5)}, {_f(e.p95)}]")
                        mark = "" if e.inside in (None, True) else "*"
                        cells.append("-" if e.paper is None else f"{e.paper:.1f} ({_f(e.percentile, 0)} %){mark}")
                    lines.append(f"| {tag} | δ{GREEK[comp]} | {unit} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def velocity_markdown(es: list[Entry]) -> str:
    """The velocity rows (the sharpest check, DESIGN.md §3): rms of delta omega and delta v, Monte Carlo against
    the paper."""
    lines = ["| Ts | sensor | connection | δω rms MC [mrad/s] | δω rms paper (pct) | δv rms MC [mm/s] | "
             "δv rms paper (pct) |", "|---|---|---|---:|---:|---:|---:|"]
    for dt in sorted({e.dt for e in es}, reverse=True):
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                cells = []
                for comp in ("omega", "v"):
                    e = next((e for e in es if (e.dt, e.sensor, e.connection, e.component, e.stat)
                              == (dt, sensor, conn, comp, "rms")), None)
                    if e is None:
                        break
                    cells += [f"{_f(e.mc_mean)} ± {_f(e.mc_spread)}",
                              "-" if e.paper is None else f"{e.paper:.1f} ({_f(e.percentile, 0)} %)"]
                if len(cells) == 4:
                    lines.append(f"| {_ms(dt)} | {LABEL[sensor]} | {LABEL[conn]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


CSV_HEADER = ("choice", "Ts_s", "sensor", "connection", "error", "unit", "stat", "mc_mean", "mc_spread", "p5",
              "p50", "p95", "paper", "paper_percentile", "paper_inside_5_95", "runs", "nonfinite")


def _csv_rows(choice: str, es: list[Entry], runs: dict) -> list[tuple]:
    unit = dict(zip(COMPONENTS, TABLE_UNITS, strict=True))
    rows = []
    for e in es:
        r = runs.get((e.dt, e.sensor, e.connection), {})
        rows.append((choice, e.dt, e.sensor, e.connection, e.component, unit[e.component], e.stat, e.mc_mean,
                     e.mc_spread, e.p5, e.p50, e.p95, "" if e.paper is None else e.paper,
                     "" if e.percentile is None else e.percentile, "" if e.inside is None else e.inside,
                     r.get("runs", ""), r.get("nonfinite", "")))
    return rows


def alternatives_markdown(results: dict[str, tuple[list[Entry], dict]]) -> str:
    """One row per (choice, Ts, sensor, connection): velocity and pose rms against the paper, diverged trials,
    and the fraction of the printed std/rms entries in the 5-95 % band."""
    lines = ["| choice | Ts | sensor | connection | diverged | δθ rms [mrad] | δx rms [mm] | δy rms [mm] | "
             "δω rms [mrad/s] | δv rms [mm/s] | std/rms in 5-95 % band |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for choice, (es, runs) in results.items():
        for dt in sorted({e.dt for e in es}, reverse=True):
            for sensor in SENSORS:
                for conn in CONNECTIONS:
                    sel = [e for e in es if (e.dt, e.sensor, e.connection) == (dt, sensor, conn)]
                    if not sel:
                        continue
                    rms = {e.component: e for e in sel if e.stat == "rms"}
                    r = runs.get((dt, sensor, conn), {})
                    k, n = band_fraction(sel)
                    cells = [f"{_f(rms[c].mc_mean)} (paper {_f(rms[c].paper)})" for c in COMPONENTS]
                    lines.append(f"| {choice} | {_ms(dt)} | {LABEL[sensor]} | {LABEL[conn]} | "
                                 f"{r.get('nonfinite', 0)} of {r.get('runs', 0)} | " + " | ".join(cells)
                                 + f" | {k} of {n} |")
    return "\n".join(lines)


def representative_trial(mc: MonteCarloResult) -> int:
    """The finite trial whose rms errors are closest to the Monte Carlo medians (sum over the components of
    |log(rms / median)|): the run Figs. 3-6 are drawn from."""
    rms = mc.stats[:, 0, :, 2]
    ok = np.flatnonzero(mc.finite & np.all(rms > 0, axis=1))
    if ok.size == 0:
        return 0
    med = np.median(rms[ok], axis=0)
    return int(ok[np.argmin(np.sum(np.abs(np.log(rms[ok] / med)), axis=1))])


FIGURES = {(0.01, "gps_ins"): "Fig. 3", (0.01, "gps"): "Fig. 4", (0.001, "gps_ins"): "Fig. 5",
           (0.001, "gps"): "Fig. 6"}


def figure_arrays(config: ChaplyginConfig, key, trial_index: int | None = None) -> dict[str, np.ndarray]:
    """Both connections filtering the same simulated data (``key``): what Figs. 3-6 show."""
    results = {conn: run(dataclasses.replace(config, connection=conn), key) for conn in CONNECTIONS}
    a0 = results["zero"].arrays
    arrays = {k: a0[k] for k in ("ts", "names", "units", "truth", "measured")}
    for conn, res in results.items():
        arrays[f"filtered_{conn}"] = res.arrays["filtered"]
        arrays[f"error_{conn}"] = res.arrays["error"]
        arrays[f"lateral_velocity_{conn}"] = res.arrays["lateral_velocity"]
    arrays["trial"] = np.array(-1 if trial_index is None else trial_index)
    arrays["sensor"], arrays["dt"] = np.array(config.sensor), np.array(config.dt)
    return arrays


def figure(arrays) -> object:
    """Figs. 3-6 of Rigo et al. 2023 from saved arrays (:func:`figure_arrays`): for each of theta, x, y, omega,
    v the nominal (black), measured (blue), (0)-filtered (green) and (-)-filtered (red) trajectories on the left,
    their errors on the right; the x-y path in the last row."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts = np.asarray(arrays["ts"])
    names = [str(s) for s in arrays["names"]]
    units = [str(s) for s in arrays["units"]]
    colors = {"zero": "tab:green", "minus": "tab:red"}
    sym = {"theta": r"\theta", "omega": r"\omega", "x": "x", "y": "y", "v": "v"}
    fig = Figure(figsize=(11, 2.0 * (len(names) + 1) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(len(names) + 1, 2, squeeze=False))
    truth, meas = np.asarray(arrays["truth"]), np.asarray(arrays["measured"])
    for k, name in enumerate(names):
        ax = axes[k, 0]
        if np.isfinite(meas[:, k]).any():
            ax.plot(ts, meas[:, k], color="tab:blue", lw=0.3, alpha=0.5, label="measured", zorder=1)
        ax.plot(ts, truth[:, k], color="black", lw=1.3, label="nominal", zorder=2)
        for conn in CONNECTIONS:
            ax.plot(ts, np.asarray(arrays[f"filtered_{conn}"])[:, k], color=colors[conn], lw=0.9, ls="--",
                    label=f"filtered {LABEL[conn]}", zorder=3)
        ref = np.concatenate([truth[:, k]] + [np.asarray(arrays[f"filtered_{c}"])[:, k] for c in CONNECTIONS])
        lo, hi = float(np.nanmin(ref)), float(np.nanmax(ref))
        pad = 0.25 * max(hi - lo, 1e-3)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"${sym.get(name, name)}$ [{units[k]}]")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax = axes[k, 1]
        for conn in CONNECTIONS:
            ax.plot(ts, np.asarray(arrays[f"error_{conn}"])[:, k], color=colors[conn], lw=0.7,
                    label=f"{LABEL[conn]}")
        ax.axhline(0.0, color="0.5", lw=0.5)
        ax.set_ylabel(rf"$\delta {sym.get(name, name)}$ [{units[k]}]")
        ax.grid(True, lw=0.3, alpha=0.5)
    for k in (0, 1):
        axes[-2, k].set_xlabel("t [s]")
    ax = axes[-1, 0]
    ax.plot(truth[:, 1], truth[:, 2], color="black", lw=1.3, label="nominal")
    for conn in CONNECTIONS:
        f = np.asarray(arrays[f"filtered_{conn}"])
        ax.plot(f[:, 1], f[:, 2], color=colors[conn], lw=0.9, ls="--", label=f"filtered {LABEL[conn]}")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax = axes[-1, 1]
    for conn in CONNECTIONS:
        ax.plot(ts, np.asarray(arrays[f"lateral_velocity_{conn}"]), color=colors[conn], lw=0.7, label=LABEL[conn])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("lateral velocity\nof the estimate [m/s]")
    ax.grid(True, lw=0.3, alpha=0.5)
    axes[0, 0].legend(loc="upper left", fontsize="small", ncols=2)
    axes[0, 1].legend(loc="upper right", fontsize="small", ncols=2)
    dt, sensor = float(arrays["dt"]), str(arrays["sensor"])
    trial_note = "" if int(arrays["trial"]) < 0 else f", Monte Carlo trial {int(arrays['trial'])}"
    fig.suptitle(f"Chaplygin sleigh, {LABEL[sensor]}, Ts = {_ms(dt)} (Rigo et al. 2023, "
                 f"{FIGURES.get((round(dt, 9), sensor), 'cf. Figs. 3-6')}){trial_note}", fontsize="medium")
    return fig


def _figure_stem(dt: float, sensor: str) -> str:
    fig = FIGURES.get((round(dt, 9), sensor), "fig")
    return f"{fig.lower().replace('. ', '').replace(' ', '')}_{sensor}_{1e3 * dt:g}ms"


def _alternative_configs(config: ChaplyginConfig) -> dict[str, ChaplyginConfig]:
    alts = {}
    if config.weights != "printed":
        alts["printed weights"] = dataclasses.replace(config, weights="printed")
    if config.model_error_std != PRINTED_MODEL_ERROR_STD:
        alts["printed model error"] = dataclasses.replace(config, model_error_std=PRINTED_MODEL_ERROR_STD)
    if config.weights != "unweighted":
        alts["unweighted (Q = D'D)"] = dataclasses.replace(config, weights="unweighted")
    return alts


def _slug(text: str) -> str:
    return "_".join("".join(ch if ch.isalnum() else " " for ch in text).split())


def _grid(config: ChaplyginConfig, runs: int, progress: bool, out: Path, choice: str,
          batch_size: int) -> tuple[list[Entry], dict, dict]:
    """The four configurations at every Ts of ``config.table_dts``, each a Monte Carlo of ``runs`` trials
    (saved under ``out/montecarlo/``): (entries, {(Ts, sensor, connection): run info}, {...: result})."""
    es, info, results = [], {}, {}
    for dt in config.table_dts:
        for sensor in SENSORS:
            for conn in CONNECTIONS:
                cfg = dataclasses.replace(config, dt=dt, sensor=sensor, connection=conn)
                label = f"{choice}, Ts = {_ms(dt)}, {LABEL[sensor]}, {LABEL[conn]}"
                mc = montecarlo(CHAPLYGIN, cfg, runs, seed=config.seed, batch_size=batch_size,
                                progress=ProgressLine(f"chaplygin {label}") if progress else False)
                mc.save(out / "montecarlo", _slug(f"{choice}_{1e3 * dt:g}ms_{sensor}_{conn}"))
                es += entries(mc, dt, sensor, conn)
                info[(dt, sensor, conn)] = {"runs": mc.runs, "nonfinite": mc.n_nonfinite,
                                            "elapsed_s": mc.elapsed}
                results[(dt, sensor, conn)] = mc
    return es, info, results


def reproduce(config: ChaplyginConfig, out: Path, runs: int = 100, progress: bool = True,
              batch_size: int = DEFAULT_BATCH_SIZE) -> Reproduction:
    """Tables 1-2 and Figs. 3-6 of Rigo et al. 2023 into the folder ``out`` (the ``reproduce_fn`` of the
    ``chaplygin`` experiment; ``liemef reproduce chaplygin --runs N --out DIR``).

    For each Ts in ``config.table_dts`` (paper: 10 ms and 1 ms), sensor set and connection, a Monte Carlo of
    ``runs`` trials seeded with ``config.seed`` (the other fields of ``config``, e.g. ``weights`` and
    ``model_error_std``, apply to all): ``tables.md``/``tables.csv`` put every entry of Tables 1-2 next to the
    Monte Carlo mean, seed-to-seed spread and 5-95 % band, with the paper's percentile; ``velocity.md`` the
    velocity rows. With ``config.alternatives`` the same grid for the alternative simulation choices (printed
    weights, printed model error, Q = D'D): ``alternatives.md`` and rows in ``tables.csv``. Figs. 3-6: both
    connections on the data of the representative trial of the (0)-connection Monte Carlo
    (:func:`representative_trial`), arrays saved next to the figures and drawn from them. ``runs = 0``: the
    single seeded run of ``config`` only (:func:`~liemef.studies.experiments.default_reproduce`).
    """
    if runs == 0:
        return default_reproduce(CHAPLYGIN, config, out, 0, progress)
    from ...reports import plots

    out = io.ensure_dir(out)
    t0 = time.perf_counter()
    main_choice = f"weights {config.weights}, model error {config.model_error_std:g}"
    es, info, mcs = _grid(config, runs, progress, out, "main", batch_size)
    alts: dict[str, tuple[list[Entry], dict]] = {}
    if config.alternatives:
        for name, cfg in _alternative_configs(config).items():
            a_es, a_info, _ = _grid(cfg, runs, progress, out, name, batch_size)
            alts[name] = (a_es, a_info)

    # Figs. 3-6 from the representative trial of each (Ts, sensor)
    figures, files = [], []
    for dt in config.table_dts:
        for sensor in SENSORS:
            mc = mcs[(dt, sensor, "zero")]
            i = representative_trial(mc)
            arrays = figure_arrays(dataclasses.replace(config, dt=dt, sensor=sensor), mc.trial_key(i), i)
            stem = _figure_stem(dt, sensor)
            files.append(io.write_npz(out / f"{stem}.npz", arrays))
            png = plots.save_figure(figure(io.read_arrays(out / f"{stem}.npz")), out / f"{stem}.png")
            files.append(png)
            caption = (f"{FIGURES.get((round(dt, 9), sensor), 'cf. Figs. 3-6')}: {LABEL[sensor]}, Ts = {_ms(dt)}, "
                       f"both connections on the data of Monte Carlo trial {i}")
            figures.append(Output(png, caption))

    k_all, n_all = band_fraction(es)
    size_note = f"{runs} Monte Carlo trials per configuration (seed {config.seed}); T = {config.duration:g} s"
    runs_note = f"{size_note}; {main_choice}; the paper's values are single runs"
    heading = (f"# Chaplygin sleigh: Rigo et al. 2023, Tables 1-2 against a Monte Carlo\n\n{runs_note}. Each cell: "
               "the Monte Carlo mean of the per-trial statistic ± its seed-to-seed spread (std across trials) "
               "[5 %, 95 % percentiles]; the paper's value with its percentile in the Monte Carlo (* outside the "
               "5-95 % band). Units: mrad, mm, mrad/s, mm/s (the velocity rows are printed 'mm/rad' in the paper)."
               f"\n\nAll Ts: **{k_all} of {n_all}** printed std/rms entries inside the 5-95 % band.\n")
    md = tables_markdown(es, info, heading)
    vel = ("# Velocity rows of Tables 1-2 (rms)\n\n" + runs_note + ".\n\n" + velocity_markdown(es) + "\n")
    rows = _csv_rows("main", es, info)
    files += [io.write_text(out / "tables.md", md), io.write_text(out / "velocity.md", vel)]
    tables = [Output(out / "tables.md", "Tables 1-2 side by side with the paper"),
              Output(out / "velocity.md", "Velocity rows (rms) against the paper")]
    summary = {"runs": runs, "band_std_rms": {"inside": k_all, "total": n_all},
               "nonfinite": int(sum(v["nonfinite"] for v in info.values()))}
    alt_text = ""
    if alts:
        for name, (a_es, a_info) in alts.items():
            rows += _csv_rows(name, a_es, a_info)
            k, n = band_fraction(a_es)
            summary[f"band_std_rms_{_slug(name)}"] = {"inside": k, "total": n}
        alt_text = ("# Alternative simulation choices against Tables 1-2\n\n" + size_note
                    + f"; the paper's values are single runs. Main choice: {main_choice}; each alternative changes "
                    "one of them. Cells: Monte Carlo "
                    "mean of the per-trial rms (the paper's value).\n\n"
                    + alternatives_markdown({f"main ({main_choice})": (es, info), **alts}) + "\n")
        files.append(io.write_text(out / "alternatives.md", alt_text))
        tables.append(Output(out / "alternatives.md", "Alternative simulation choices (weights, model error)"))
    files.append(io.write_rows(out / "tables.csv", CSV_HEADER, rows))
    tables.append(Output(out / "tables.csv", "Tables 1-2 and alternatives (CSV)"))
    elapsed = time.perf_counter() - t0
    files.append(io.write_json(out / "reproduction.json", {
        "experiment": CHAPLYGIN.name, "paper": CHAPLYGIN.paper, "config": config_dict(config),
        "runs": runs, "elapsed_s": elapsed, "summary": summary,
        "figures": [{"file": f.path.name, "caption": f.caption} for f in figures]}))
    warnings = []
    if summary["nonfinite"]:
        warnings.append(f"WARNING: {summary['nonfinite']} Monte Carlo trials of the main choice were non-finite "
                        "(diverged) and are left out of the statistics")
    text = "\n".join([f"{CHAPLYGIN.name}: {CHAPLYGIN.title}", f"  {CHAPLYGIN.paper}; {runs_note} ({elapsed:.0f} s)",
                      "", md, "", vel, *([alt_text] if alt_text else []),
                      f"Wrote {len(files)} files (and montecarlo/) to {out}"])
    mc_files = tuple(sorted((out / "montecarlo").glob("*")))
    return Reproduction(experiment=CHAPLYGIN.name, out=out, figures=tuple(figures), tables=tuple(tables),
                        files=tuple(files) + mc_files, text=text, warnings=tuple(warnings), summary=summary)


def _reproduce_hook(config, out, runs, progress) -> Reproduction:
    return reproduce(config, out, runs, progress)


_POSE = ("theta", "x", "y")
_VEL = ("omega", "v")

CHAPLYGIN = register(Experiment(
    name="chaplygin",
    title="Chaplygin sleigh on SE(2) x R^2, GPS (+ INS), (0)- and (-)-connections",
    paper="Rigo, Sansonetto, Muradore 2023, Sec. 6, Tables 1-2, Figs. 3-6",
    default_config=ChaplyginConfig(),
    run_fn=run,
    trial_fn=trial_spec,
    figures=(
        FigureSpec("pose.png", _POSE, "Pose: nominal (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2023, Figs. 3-6 (pose)"),
        FigureSpec("velocity.png", _VEL,
                   "Velocities: nominal (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2023, Figs. 3-6 (velocities)"),
    ),
    tables=("Table 1 (Ts = 10 ms)", "Table 2 (Ts = 1 ms)"),
    runs=100,
    quick_config=ChaplyginConfig(table_dts=(0.01,), alternatives=False),
    quick_runs=8,
    reproduce_fn=_reproduce_hook,
))
"""``chaplygin``: one run of a :class:`ChaplyginConfig`; ``reproduce`` writes Tables 1-2 and Figs. 3-6."""
