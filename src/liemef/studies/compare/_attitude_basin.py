r"""``liemef compare attitude-basin``: the convergence basin of the attitude filters in the initial attitude error.

Two systems on TSO(3) = SO(3) x R^3 (``systems``):

* ``rigid-body``: Saccon et al. 2016's rigid body (:mod:`liemef.studies.experiments.attitude`): attitude and angular
  velocity, the paper's inertia, torque, noise levels, weights, forgetting factor alpha = 0.01 and prior
  K0 = I6; the truth and the sensor log are the experiment's own simulation (:func:`~liemef.simulation.simulate_core`
  with its torque and torque noise, per trial key), but on a coarser grid than the paper's 1 ms, to keep the study
  within minutes: ``rigid_body_dt`` (default 20 ms), the truth integrated by RKMK4 instead of Lie-Euler (at 20 ms
  Lie-Euler's truth would differ from the filter's RKMK4 model by more than the noise), and the per-sample noise
  stds scaled by sqrt(1 ms / dt) (sigma_eps = 0.037, sigma_delta = 0.22 at 20 ms) so that the noise density, the
  information per second, is the paper's; with the printed weights (D^-T Q D^-1 = I, B R^-1 B' = I) the filters
  are the same whatever the scale. R(0) = I, and the estimate starts from
  $\hat R_0 = R_0 \exp(\alpha n)$ with the true $\hat\Omega_0 = \Omega_0$. The local EKF is left out: on TSO(3)
  with a multiplicative rotation error and an additive R^3 error it is the invariant EKF.
* ``gyro-bias``: attitude and gyro bias (:func:`liemef.systems.attitude_gyro_bias` at ``imu_rate``, default
  noise levels): a synthetic IMU. The true angular velocity is a fixed sum of sinusoids (:func:`omega_profile`,
  at most 1.6 rad/s), R(0) uniform per trial, the true bias constant, N(0, (0.01 rad/s)^2) per axis; gyro =
  omega + bias + noise (std ``GYRO_STD`` per sample), acc = R^T e_up and mag = R^T m_ref plus noise (the
  sensors' std per sample), normalized. The estimate starts from $\hat R_0 = R_0 \exp(\alpha n)$ and zero bias,
  with K0 = diag((``prior_std_deg``)^2 I3, (0.02 rad/s)^2 I3). ahrs's Madgwick and Mahony (default gains) run
  here only, and only when named in ``filters`` (not by default): they are numpy loops that cannot be vmapped
  (trial by trial, 0.2-0.75 ms per sample on a shared core), so 350 trials of 10 s at 100 Hz take 1-5 min each:
  both would push the default study well past 15 min.

The axis n is a random unit vector per trial (from the trial key). Trial i at every angle uses
``split(key(seed), runs)[i]``, the same for every filter, so the basins are paired; the angle is a traced
argument (one compilation per filter and system).

A trial **converges** when the filter stays healthy and its attitude error $|\log(\hat R^\top R)|$ stays below
``tolerance_deg`` over the last quarter of the run; its **time to converge** is the first time after which the
error stays below the tolerance to the end (:func:`liemef.studies.compare._basins.convergence`). Reported per system,
filter and angle: the fraction that converge with its 95 % Wilson interval, and the median and 90th percentile
of the time to converge over the trials that converge.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ...filters.baselines import Madgwick, Mahony
from ...groups import R3, SO3, TSO3
from ...metrics import chi2_bounds, left_error, nees
from ...metrics._stats import json_number
from ...reports import io
from ...simulation import simulate_core
from ...systems import attitude_gyro_bias
from ...systems.attitude_bias import GYRO_STD
from .. import optimum
from ..experiments import attitude as A
from ._basins import (
    basin_figure,
    basin_row,
    basin_trials,
    convergence,
    fraction_and_time,
    last_quarter,
    progress_line,
)
from ._common import FILTERS, check_counts, fmt, make_filter, parse_names

SCHEMA = "liemef.compare.attitude-basin/1"
"""Version tag of ``attitude_basin.json``."""

SYSTEMS = {
    "rigid-body": "Saccon et al. 2016's rigid body on TSO(3) (attitude, angular velocity; torque input, two "
                  "directions)",
    "gyro-bias": "attitude and gyro bias on SO(3) x R^3 (gyro input, accelerometer and magnetometer directions), "
                 "synthetic IMU",
}
"""The study's systems."""
AHRS = {"madgwick": ("ahrs Madgwick, ahrs's default beta = 0.041 (gyro-bias only)", Madgwick),
        "mahony": ("ahrs Mahony, ahrs's default Kp = 1, Ki = 0.3 (gyro-bias only)", Mahony)}
FILTER_NAMES = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf", "ukf-left", "madgwick", "mahony")
DEFAULT_FILTERS = FILTER_NAMES[:6]
PAPER_DT = 1e-3
"""The paper's sample step (s): the noise stds are per sample at this step."""
DEFAULT_ANGLES = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 179.0)
TRUE_BIAS_STD = 0.01
"""Std of the true gyro bias per axis (rad/s), gyro-bias system."""
BIAS_PRIOR_STD = 0.02
"""The filters' prior std of the bias (rad/s), gyro-bias system."""


def omega_profile(t):
    """The gyro-bias system's true body angular velocity (rad/s): a fixed sum of sinusoids, at most 1.6 rad/s."""
    w = 2.0 * jnp.pi * t
    return jnp.stack([1.0 * jnp.sin(0.11 * w) + 0.5 * jnp.sin(0.31 * w + 0.4),
                      0.8 * jnp.sin(0.17 * w + 1.1) + 0.4 * jnp.sin(0.43 * w),
                      1.2 * jnp.sin(0.07 * w + 2.0) + 0.3 * jnp.sin(0.53 * w + 0.7)])


@dataclass(frozen=True)
class AttitudeBasin:
    """The study's settings (module docstring). ``optimum_runs`` > 0: on the gyro-bias system, the distance of
    each covariance filter's attitude from the exact minimum-energy estimate
    (:func:`liemef.studies.optimum.map_estimates`
    with the JAX batch solver, every ``optimum_every``-th sample) on the first ``optimum_runs`` trials of each
    angle."""

    runs: int = 50
    seed: int = 0
    duration: float = 10.0
    angles_deg: tuple[float, ...] = DEFAULT_ANGLES
    tolerance_deg: float = 5.0
    systems: tuple[str, ...] | str = tuple(SYSTEMS)
    filters: tuple[str, ...] | str | None = DEFAULT_FILTERS
    rigid_body_dt: float = 0.02
    imu_rate: float = 100.0
    prior_std_deg: float = 90.0
    batch_size: int = 50
    optimum_runs: int = 0
    optimum_every: int = 100

    def __post_init__(self):
        check_counts(self, "runs", "batch_size", "optimum_every")
        if not (isinstance(self.optimum_runs, int) and 0 <= self.optimum_runs <= self.runs):
            raise ValueError(f"optimum_runs: expected an integer in [0, runs = {self.runs}], got {self.optimum_runs!r}")
        angles = tuple(float(a) for a in self.angles_deg)
        if not angles or any(not (math.isfinite(a) and 0.0 <= a <= 180.0) for a in angles):
            raise ValueError(f"angles_deg: expected angles in [0, 180] deg, got {self.angles_deg!r}")
        for name in ("tolerance_deg", "prior_std_deg", "duration", "rigid_body_dt", "imu_rate"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive number, got {v!r}")
        if self.duration * self.imu_rate < 4 or self.duration / self.rigid_body_dt < 4:
            raise ValueError(f"duration: expected at least 4 samples of both systems, got {self.duration!r} s")
        object.__setattr__(self, "angles_deg", angles)
        object.__setattr__(self, "systems", parse_names("systems", self.systems, SYSTEMS, SYSTEMS))
        object.__setattr__(self, "filters", parse_names("filters", self.filters, FILTER_NAMES, DEFAULT_FILTERS))

    def filters_of(self, system: str) -> tuple[str, ...]:
        """The filters run on ``system`` (Madgwick and Mahony need the gyro-bias system's sensors)."""
        return tuple(f for f in self.filters if system == "gyro-bias" or f not in AHRS)

    @property
    def rigid_body_config(self) -> A.AttitudeConfig:
        """The attitude experiment on this study's grid (RKMK4 truth, the paper's noise densities; module
        docstring)."""
        scale = math.sqrt(PAPER_DT / self.rigid_body_dt)
        paper = A.AttitudeConfig()
        return A.AttitudeConfig(duration=self.duration, dt=self.rigid_body_dt, truth_integrator="rkmk4",
                                sigma_eps=paper.sigma_eps * scale, sigma_delta=paper.sigma_delta * scale,
                                steady=(0.75 * self.duration, self.duration))

    @property
    def imu_ts(self) -> np.ndarray:
        """The gyro-bias system's sample times 0, 1/imu_rate, ..., duration."""
        return np.arange(int(round(self.duration * self.imu_rate)) + 1) / self.imu_rate


def _axis(key):
    n = jax.random.normal(jax.random.fold_in(key, 7), (3,))
    return n / jnp.linalg.norm(n)


def _first(g):
    return jax.tree_util.tree_map(lambda a: a[0], g)


def _rigid_body_log(config: A.AttitudeConfig, key, alpha):
    """The experiment's truth and log for ``key`` and the initial estimate (R0 exp(alpha n), Omega0)."""
    s = A.setup(config)
    truth, log = simulate_core(s.system, s.g0, A.paper_torque, jnp.asarray(s.ts), key, 0.0, s.system.torque_noise,
                               1, config.truth_integrator)
    R0, W0 = s.g0.factors
    return truth.g, log, TSO3((R0 @ SO3.exp(alpha * _axis(key)), W0))


def _imu_log(system, ts, key, alpha):
    """A synthetic IMU log for ``key`` (module docstring) and the initial estimate (R0 exp(alpha n), 0)."""
    q = jax.random.normal(jax.random.fold_in(key, 1), (4,))
    R0 = SO3(q / jnp.linalg.norm(q))
    b = TRUE_BIAS_STD * jax.random.normal(jax.random.fold_in(key, 2), (3,))
    truth, log = simulate_core(system, TSO3((R0, R3(b))), lambda t: omega_profile(t) + b, ts, key, 0.0,
                               GYRO_STD * jnp.eye(3), 1, "rkmk4")
    ys = log.ys.reshape(log.ys.shape[0], 2, 3)  # (acc, mag): normalized, as an IMU's directions
    ys = (ys / jnp.linalg.norm(ys, axis=-1, keepdims=True)).reshape(log.ys.shape)
    return truth.g, eqx.tree_at(lambda lg: lg.ys, log, ys), TSO3((R0 @ SO3.exp(alpha * _axis(key)), R3(jnp.zeros(3))))


def _trial_fn(make_log):
    def one(flt, state0, key, alpha):
        g, log, g_hat0 = make_log(key, alpha)
        traj = flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, g_hat0), log.ts, log.us, log.ys)
        # NEES of K as the covariance of the left error, per degree of freedom
        nees_dof = nees(left_error(g, traj.g_hat), traj.K) / traj.K.shape[-1]
        return A.attitude_errors(g, traj.g_hat)[:, 0], traj.status.code, nees_dof

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0, None)))


def _estimates_fn(make_log):
    def one(flt, state0, key, alpha):
        g, log, g_hat0 = make_log(key, alpha)
        return flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, g_hat0), log.ts, log.us, log.ys).g_hat

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0, None)))


def _optimum_distances(st: AttitudeBasin, flt, state0, make_log, system, K0, keys, alpha, cache: dict) -> dict:
    """Attitude distance (deg) of the filter's estimates from the per-step MAP at its checkpoints, on ``keys``
    (the MAP per trial and angle is computed once, in ``cache``): the mean over the checkpoints after the first,
    and at the last, averaged over the trials."""
    g_f = _estimates_fn(make_log)(flt, state0, keys, alpha)
    means, finals = [], []
    for i in range(keys.shape[0]):
        ck = (float(alpha), i)
        if ck not in cache:
            g, log, g_hat0 = make_log(keys[i], alpha)
            cache[ck] = optimum.map_estimates(system, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys),
                                              g_hat0, K0, solver="jax", every=st.optimum_every)
        est = cache[ck]
        idx = np.searchsorted(np.asarray(st.imu_ts), np.asarray(est.ts) - 1e-9)
        gi = jax.tree_util.tree_map(lambda a, i=i, idx=idx: a[i][idx], g_f)
        d = np.degrees(np.asarray(optimum.distance_components(gi, est.g)["0.angle"]))
        means.append(float(np.mean(d[1:])) if d.size > 1 else float(d[0]))
        finals.append(float(d[-1]))
    return {"optimum_deg_mean": json_number(float(np.mean(means))),
            "optimum_deg_final": json_number(float(np.mean(finals)))}


def _logs_fn(make_log):
    return eqx.filter_jit(eqx.filter_vmap(make_log, in_axes=(0, None)))


def _make_filter(name: str, system, alpha: float):
    if name in AHRS:
        return AHRS[name][1](system)
    # the minimum-energy filters with the study's forgetting factor and Theorem 4.1's curvature
    return make_filter(name, system, **({"alpha": alpha, "curvature": "exact"} if name.startswith("mef") else {}))


def _description(name: str) -> str:
    return AHRS[name][0] if name in AHRS else FILTERS[name][0]


def _row(angle: float, ok: np.ndarray, t_conv: np.ndarray, code: np.ndarray, nees_last: np.ndarray | None) -> dict:
    """:func:`~liemef.studies.compare._basins.basin_row` with the mean NEES per degree of freedom over the last
    quarter of the trials that converge (``nees_last`` per trial; None without it or when none converges)."""
    k = int(ok.sum())
    nees_mean = None if nees_last is None or k == 0 else json_number(float(np.mean(nees_last[ok])))
    return {**basin_row(angle, ok, t_conv, code), "nees_per_dof": nees_mean}


def _system(st: AttitudeBasin, name: str):
    """(system, ts, log maker (key, alpha), K0, alpha, description of the setup)."""
    if name == "rigid-body":
        config = st.rigid_body_config
        s = A.setup(config)
        return (s.system, np.asarray(s.ts), lambda key, alpha: _rigid_body_log(config, key, alpha),
                np.diag(config.K0_diag), config.alpha,
                f"Saccon et al. 2016 rigid body (printed weights, alpha = {config.alpha:g}, K0 = I6), truth by "
                f"RKMK4 at dt = {config.dt:g} s, per-sample noise stds sigma_eps = {config.sigma_eps:.3g}, "
                f"sigma_delta = {config.sigma_delta:.3g} (the paper's densities), R0 = I, Omega_hat0 = Omega0")
    system = attitude_gyro_bias(imu_rate=st.imu_rate)
    ts = jnp.asarray(st.imu_ts)
    K0 = np.diag([math.radians(st.prior_std_deg) ** 2] * 3 + [BIAS_PRIOR_STD**2] * 3)
    return (system, st.imu_ts, lambda key, alpha: _imu_log(system, ts, key, alpha), K0, 0.0,
            f"synthetic IMU at {st.imu_rate:g} Hz (attitude_gyro_bias defaults), R0 uniform, true bias "
            f"N(0, ({TRUE_BIAS_STD:g} rad/s)^2), bias estimate 0, K0 = diag(({st.prior_std_deg:g} deg)^2 I3, "
            f"({BIAS_PRIOR_STD:g} rad/s)^2 I3)")


def _ahrs_trials(flt, logs_fn, keys, alpha, batch_size, ts):
    """Errors and codes of a numpy filter, trial by trial on the same logs as the others."""
    errs, codes = [], []
    for i in range(0, keys.shape[0], batch_size):
        g, log, g_hat0 = logs_fn(keys[i:i + batch_size], alpha)
        for j in range(log.ts.shape[0]):
            gj, g0j = jax.tree_util.tree_map(lambda a, j=j: a[j], g), jax.tree_util.tree_map(lambda a, j=j: a[j],
                                                                                              g_hat0)
            traj = flt.run(flt.init(g0j), ts, np.asarray(log.us[j]), np.asarray(log.ys[j]))
            errs.append(np.asarray(A.attitude_errors(gj, traj.g_hat)[:, 0]))
            codes.append(int(np.asarray(traj.status.code)))
    return np.stack(errs), np.asarray(codes)


def compare_attitude_basin(study: AttitudeBasin | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "systems", "arrays"}`` (per system, filter and angle: converged
    fraction, its interval and times to converge)."""
    st = AttitudeBasin() if study is None else study
    keys = jax.random.split(jax.random.key(st.seed), st.runs)
    systems, arrays = {}, {"angles_deg": np.asarray(st.angles_deg), "systems": np.array(st.systems)}
    for sname in st.systems:
        system, ts, make_log, K0, alpha, setup = _system(st, sname)
        fn, logs_fn = _trial_fn(make_log), _logs_fn(make_log)
        g0 = _first(make_log(keys[0], jnp.asarray(0.0))[0])
        per_filter, frac, t_med = {}, [], []
        map_cache: dict = {}
        with_optimum = sname == "gyro-bias" and st.optimum_runs > 0
        if progress:
            print(f"{sname}:", file=sys.stderr, flush=True)
        for name in st.filters_of(sname):
            t0 = time.perf_counter()
            flt = _make_filter(name, system, alpha)
            rows = []
            for a in st.angles_deg:
                alpha_rad = jnp.asarray(math.radians(a))
                nees_last = None
                if name in AHRS:
                    err, code = _ahrs_trials(flt, logs_fn, keys, alpha_rad, st.batch_size, ts)
                else:
                    state0 = flt.init(g0, K0)
                    err, code, nees_dof = basin_trials(fn, flt, state0, keys, a, st.batch_size)
                    nees_last = nees_dof[:, last_quarter(ts)].mean(axis=1)
                ok, t_conv = convergence(ts, err, code, st.tolerance_deg)
                rows.append(_row(a, ok, t_conv, code, nees_last))
                if with_optimum and name not in AHRS:
                    rows[-1].update(_optimum_distances(st, flt, state0, make_log, system, K0,
                                                       keys[:st.optimum_runs], alpha_rad, map_cache))
            per_filter[name] = {"filter": _description(name), "angles": rows, "elapsed_s": time.perf_counter() - t0}
            fr, tm = fraction_and_time(rows)
            frac.append(fr)
            t_med.append(tm)
            if progress:
                print(progress_line(name, rows, per_filter[name]["elapsed_s"]), file=sys.stderr, flush=True)
        systems[sname] = {"description": SYSTEMS[sname], "setup": setup, "samples": int(len(ts)),
                          "filters": per_filter}
        key = sname.replace("-", "_")
        arrays[f"{key}_filters"] = np.array(st.filters_of(sname))
        arrays[f"{key}_fraction"] = np.asarray(frac)
        arrays[f"{key}_time_median"] = np.asarray(t_med)
    return {"study": {**dataclasses.asdict(st),
                      "initial_estimate": "R_hat0 = R0 exp(alpha n), n a random unit axis per trial (from the trial "
                                          "key); the other factor true (rigid body) or zero (gyro bias)",
                      "keys": f"trial i uses jax.random.split(jax.random.key({st.seed}), {st.runs})[i] at every "
                              "angle and for every filter"},
            "systems": systems, "arrays": arrays}


def markdown(result: dict) -> str:
    """The basin tables, one per system: per filter and angle, converged k/n [95 % interval] and the median
    time to converge."""
    st = result["study"]
    angles = st["angles_deg"]
    lines = [f"# Convergence basin in the initial attitude error ({st['runs']} trials per angle, seed {st['seed']})",
             "", f"{st['initial_estimate']}; {st['keys']}. A trial converges when its attitude error |log(R_hat^T R)| "
             f"stays below {st['tolerance_deg']:g} deg over the last quarter of the {st['duration']:g} s run; time "
             "to converge: from then on below the tolerance (median over the trials that converge).", ""]
    for sname, sysr in result["systems"].items():
        lines += [f"## {sname}: {sysr['description']}", "", f"{sysr['setup']}; {sysr['samples']} samples.", "",
                  "| filter | " + " | ".join(f"{a:g} deg" for a in angles) + " |", "|---|" + "---:|" * len(angles)]
        for name, e in sysr["filters"].items():
            cells = []
            for r in e["angles"]:
                lo, hi = r["wilson95"]
                t = "" if r["time_median_s"] is None else f", {r['time_median_s']:.3g} s"
                f = f" ({r['failed']} failed)" if r["failed"] else ""
                cells.append(f"{r['converged']}/{r['trials']} [{fmt(lo, 2)}-{fmt(hi, 2)}]{t}{f}")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        with_nees = {n: e for n, e in sysr["filters"].items() if any(r["nees_per_dof"] is not None
                                                                     for r in e["angles"])}
        if with_nees:
            dof = sysr.get("dof", 6)  # TSO(3): 6
            lo, hi = chi2_bounds(dof, st["runs"], 0.95, per_dof=True)
            lines += ["", f"NEES per degree of freedom over the last quarter, mean over the trials that converge "
                      f"(K as the covariance of the left error; 1 for a consistent filter; 95 % chi-square bounds "
                      f"of one step's average over {st['runs']} trials: {lo:.3f}-{hi:.3f}; a cell averages only "
                      "the trials that converged, and its bounds are wider when they are fewer):", "",
                      "| filter | " + " | ".join(f"{a:g} deg" for a in angles) + " |",
                      "|---|" + "---:|" * len(angles)]
            for name, e in with_nees.items():
                lines.append(f"| {name} | " + " | ".join(fmt(r["nees_per_dof"], 3) for r in e["angles"]) + " |")
        with_opt = {n: e for n, e in sysr["filters"].items() if "optimum_deg_mean" in e["angles"][0]}
        if with_opt:
            lines += ["", f"Distance of the attitude from the exact minimum-energy estimate (the per-step MAP by "
                      f"liemef.studies.optimum's JAX Levenberg-Marquardt, every {st['optimum_every']}-th sample, "
                      f"on the first "
                      f"{st['optimum_runs']} trials of each angle), deg: mean over the checkpoints / at the last:", "",
                      "| filter | " + " | ".join(f"{a:g} deg" for a in angles) + " |",
                      "|---|" + "---:|" * len(angles)]
            for name, e in with_opt.items():
                lines.append(f"| {name} | " + " | ".join(f"{fmt(r['optimum_deg_mean'], 3)} / "
                                                         f"{fmt(r['optimum_deg_final'], 3)}" for r in e["angles"])
                             + " |")
        lines.append("")
    return "\n".join(lines + ["Cells: converged/trials [95 % Wilson interval of the fraction], median time to "
                              "converge.", ""])


def csv_rows(result: dict) -> tuple[list[str], list[list]]:
    """One row per system, filter and angle."""
    header = ["system", "filter", "angle_deg", "converged", "trials", "fraction", "wilson_lo", "wilson_hi", "failed",
              "time_median_s", "time_p90_s", "nees_per_dof"]
    rows = [[sname, name, r["angle_deg"], r["converged"], r["trials"], r["fraction"], *r["wilson95"], r["failed"],
             r["time_median_s"], r["time_p90_s"], r["nees_per_dof"]]
            for sname, sysr in result["systems"].items() for name, e in sysr["filters"].items() for r in e["angles"]]
    return header, rows


def save(result: dict, out: str | Path, stem: str = "attitude_basin") -> list[Path]:
    """Write ``<stem>.json``, ``<stem>.md``, ``<stem>.csv``, ``arrays.npz`` and ``fig_basin_<system>.png`` to
    ``out`` (``stem``: ``attitude_basin``; ``inertial_basin`` for ``liemef compare inertial-basin``)."""
    from ...reports import plots

    out = io.ensure_dir(out)
    header, rows = csv_rows(result)
    written = [io.write_npz(out / "arrays.npz", result["arrays"]),
               io.write_json(out / f"{stem}.json",  # the inertial basin has the same layout under its own name
                             {"schema": SCHEMA.replace("attitude-basin", stem.replace("_", "-")),
                              **{k: v for k, v in result.items() if k != "arrays"}}),
               io.write_text(out / f"{stem}.md", markdown(result)),
               io.write_rows(out / f"{stem}.csv", header, rows)]
    arrays = io.read_arrays(out / "arrays.npz")
    for sname in (str(s) for s in arrays["systems"]):
        key = sname.replace("-", "_")
        fig = basin_figure({"angles_deg": arrays["angles_deg"], "filters": arrays[f"{key}_filters"],
                            "fraction": arrays[f"{key}_fraction"], "time_median": arrays[f"{key}_time_median"]},
                           title=f"convergence basin in the initial attitude error: {sname}")
        fig.axes[-1].set_xlabel("initial attitude error [deg]")
        written.append(plots.save_figure(fig, out / f"fig_basin_{key}.png"))
    return written
