r"""``liemef compare heading-basin``: the convergence basin of every filter in the initial heading error.

The scenario is ukfm's 2D localization (:mod:`liemef.studies.experiments.localization`), with the initial heading error
set instead of drawn: for each angle $\alpha$ in ``angles_deg`` and each trial, $\hat\theta_0 = \theta_0 \pm
\alpha$ (the sign drawn per trial) and the position exact, while the filters' prior is K0 = diag(s^2, 0, 0)
with ``prior_std_deg`` s. Trial i at every angle uses the noise of ``split(key(seed), runs)[i]``, the same for
every filter, so the basins are paired; the angle is a traced argument (one compilation per filter).

A trial **converges** when the filter stays healthy and its heading error stays below ``tolerance_deg`` over the
last quarter of the run; its **time to converge** is the first time after which the error stays below the
tolerance to the end. Reported per filter and angle: the fraction that converge with its 95 % Wilson interval,
and the median and 90th percentile of the time to converge over the trials that converge.
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

from ...metrics import wilson_interval
from ...metrics._stats import json_number
from ...reports import io
from ...reports.figures import basin_figure
from ..experiments import localization as L
from ._common import FILTERS, check_counts, fmt, make_filter, parse_filters

SCHEMA = "liemef.compare.heading-basin/1"
"""Version tag of ``basin.json``."""

DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf", "ekf", "ukf-left")
DEFAULT_ANGLES = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 179.0)


@dataclass(frozen=True)
class HeadingBasin:
    """The study's settings (module docstring)."""

    runs: int = 50
    seed: int = 0
    duration: float = 40.0
    angles_deg: tuple[float, ...] = DEFAULT_ANGLES
    prior_std_deg: float = 45.0
    tolerance_deg: float = 5.0
    filters: tuple[str, ...] | str | None = DEFAULT_FILTERS
    batch_size: int = 50

    def __post_init__(self):
        check_basin_settings(self, DEFAULT_FILTERS)

    @property
    def config(self) -> L.LocalizationConfig:
        """The scenario with the filters' prior std."""
        return L.LocalizationConfig(duration=self.duration, steady=0.75 * self.duration,
                                    theta0_std=math.radians(self.prior_std_deg))


def _trial_fn(config: L.LocalizationConfig):
    s = L.setup(config)

    def one(flt, state0, key, alpha):
        draws = L.jax_draws(config, key)
        sign = jnp.where(jax.random.bernoulli(jax.random.fold_in(key, 7)), 1.0, -1.0)
        draws = draws._replace(theta0=sign * alpha / config.theta0_std)  # g_hat_0 = g_0 Exp(+-alpha) in heading
        log, g0 = L.sensor_log(config, s.truth, draws)
        traj = flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, g0), log.ts, log.us, log.ys)
        return jnp.abs(L.series(s.truth, traj.g_hat, traj.K)[:, 0]), traj.status.code

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0, None)))


# --- what the basin studies share (heading-basin, attitude-basin, inertial-basin) ---------------------------
def check_basin_settings(settings, default_filters) -> None:
    """Check and normalize a basin study's common settings: ``runs`` and ``batch_size`` (integers >= 1),
    ``angles_deg`` (a non-empty sequence in [0, 180] deg, stored as a tuple of floats), ``prior_std_deg`` and
    ``tolerance_deg`` (positive angles), ``filters`` (:func:`~liemef.studies.compare._common.parse_filters`, default
    ``default_filters``), and the duration through the settings' ``config``."""
    check_counts(settings, "runs", "batch_size")
    angles = tuple(float(a) for a in settings.angles_deg)
    if not angles or any(not (math.isfinite(a) and 0.0 <= a <= 180.0) for a in angles):
        raise ValueError(f"angles_deg: expected angles in [0, 180] deg, got {settings.angles_deg!r}")
    for name in ("prior_std_deg", "tolerance_deg"):
        v = getattr(settings, name)
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a positive angle in deg, got {v!r}")
    object.__setattr__(settings, "angles_deg", angles)
    object.__setattr__(settings, "filters", parse_filters(settings.filters, default_filters))
    settings.config  # noqa: B018  (checks the duration)


def last_quarter(ts: np.ndarray) -> np.ndarray:
    """The samples of the last quarter of the run: t >= t_0 + 3/4 (t_end - t_0)."""
    ts = np.asarray(ts)
    return ts >= ts[0] + 0.75 * (ts[-1] - ts[0])


def basin_trials(fn, flt, state0, keys, angle_deg: float, batch_size: int) -> tuple[np.ndarray, ...]:
    """The outputs of a study's trial function ``fn(flt, state0, keys, alpha)`` (vmapped over the keys, the angle
    in rad a traced argument) over all ``keys`` at ``angle_deg``, in batches of ``batch_size``, concatenated."""
    alpha = jnp.asarray(math.radians(angle_deg))
    parts = [fn(flt, state0, keys[i:i + batch_size], alpha) for i in range(0, keys.shape[0], batch_size)]
    return tuple(np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(len(parts[0])))


def basin_row(angle: float, ok: np.ndarray, t_conv: np.ndarray, code: np.ndarray) -> dict:
    """One angle's row: converged k of n, the fraction with its 95 % Wilson interval, the failed trials, and the
    median and 90th percentile of the time to converge over the trials that converge (None when none does)."""
    n, k = ok.size, int(ok.sum())
    times = t_conv[ok]
    return {"angle_deg": angle, "converged": k, "trials": n, "fraction": k / n,
            "wilson95": list(wilson_interval(k, n)), "failed": int(np.sum(code != 0)),
            "time_median_s": json_number(float(np.median(times))) if k else None,
            "time_p90_s": json_number(float(np.percentile(times, 90))) if k else None}


def fraction_and_time(rows: list[dict]) -> tuple[list[float], list[float]]:
    """Per angle: the fraction converged and the median time to converge (NaN when none converges), for the
    figure's arrays."""
    return ([r["fraction"] for r in rows],
            [np.nan if r["time_median_s"] is None else r["time_median_s"] for r in rows])


def progress_line(name: str, rows: list[dict], elapsed: float) -> str:
    """The progress line of one filter: converged k/n per angle, the failures and the time taken."""
    failed = sum(r["failed"] for r in rows)
    return (f"  {name:10s} converged: " + ", ".join(f"{r['angle_deg']:g} deg {r['converged']}/{r['trials']}"
                                                     for r in rows)
            + (f"; {failed} failed" if failed else "") + f"; {elapsed:.1f} s")


def convergence(ts: np.ndarray, abs_err: np.ndarray, code: np.ndarray, tolerance: float) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """Per trial: whether it converges (healthy, |error| < tolerance over the last quarter) and its time to
    converge (the first time after which |error| stays below the tolerance; NaN when it does not converge)."""
    bad = ~(abs_err < tolerance)  # NaN counts as bad
    ok = (code == 0) & ~np.any(bad[:, last_quarter(ts)], axis=1)
    # index of the last bad sample, -1 when none
    last_bad = np.where(bad.any(axis=1), bad.shape[1] - 1 - np.argmax(bad[:, ::-1], axis=1), -1)
    t_conv = ts[np.minimum(last_bad + 1, ts.size - 1)]
    return ok, np.where(ok, t_conv, np.nan)


def compare_heading_basin(study: HeadingBasin | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "filters", "arrays"}`` (per filter and angle: converged fraction,
    its interval and times to converge)."""
    st = HeadingBasin() if study is None else study
    config = st.config
    s = L.setup(config)
    keys = jax.random.split(jax.random.key(st.seed), st.runs)
    fn = _trial_fn(config)
    K0 = np.diag([config.theta0_std**2, 0.0, 0.0])
    per_filter, frac, t_med = {}, [], []
    for name in st.filters:
        t0 = time.perf_counter()
        flt = make_filter(name, s.system)
        state0 = flt.init(s.truth[0], K0)
        rows = []
        for a in st.angles_deg:
            err, code = basin_trials(fn, flt, state0, keys, a, st.batch_size)
            rows.append(basin_row(a, *convergence(config.ts, err, code, st.tolerance_deg), code))
        per_filter[name] = {"filter": FILTERS[name][0], "angles": rows, "elapsed_s": time.perf_counter() - t0}
        fr, tm = fraction_and_time(rows)
        frac.append(fr)
        t_med.append(tm)
        if progress:
            print(progress_line(name, rows, per_filter[name]["elapsed_s"]), file=sys.stderr, flush=True)
    return {"study": {**dataclasses.asdict(st),
                      "scenario": "ukfm 2D localization benchmark with the initial heading error set to +-alpha "
                                  "(sign drawn per trial), position exact",
                      "keys": f"trial i uses jax.random.split(jax.random.key({st.seed}), {st.runs})[i] at every "
                              "angle and for every filter"},
            "filters": per_filter,
            "arrays": {"angles_deg": np.asarray(st.angles_deg), "filters": np.array(st.filters),
                       "fraction": np.asarray(frac), "time_median": np.asarray(t_med)}}


def markdown(result: dict) -> str:
    """The basin table: per filter and angle, converged k/n [95 % interval] and the median time to converge."""
    st, pf = result["study"], result["filters"]
    angles = st["angles_deg"]
    lines = [f"# Convergence basin in the initial heading error ({st['runs']} trials per angle, seed {st['seed']})",
             "", f"{st['scenario']}; {st['keys']}. Prior K0 = diag(({st['prior_std_deg']:g} deg)^2, 0, 0). A trial "
             f"converges when its heading error stays below {st['tolerance_deg']:g} deg over the last quarter of "
             f"the {st['duration']:g} s run; time to converge: from then on below the tolerance (median over the "
             "trials that converge).", "",
             "| filter | " + " | ".join(f"{a:g} deg" for a in angles) + " |",
             "|---|" + "---:|" * len(angles)]
    for name, e in pf.items():
        cells = []
        for r in e["angles"]:
            lo, hi = r["wilson95"]
            t = "" if r["time_median_s"] is None else f", {r['time_median_s']:.3g} s"
            cells.append(f"{r['converged']}/{r['trials']} [{fmt(lo, 2)}-{fmt(hi, 2)}]{t}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines + ["", "Cells: converged/trials [95 % Wilson interval of the fraction], median time to "
                              "converge.", ""])


def csv_rows(result: dict) -> tuple[list[str], list[list]]:
    """One row per filter and angle."""
    header = ["filter", "angle_deg", "converged", "trials", "fraction", "wilson_lo", "wilson_hi", "failed",
              "time_median_s", "time_p90_s"]
    rows = [[name, r["angle_deg"], r["converged"], r["trials"], r["fraction"], *r["wilson95"], r["failed"],
             r["time_median_s"], r["time_p90_s"]] for name, e in result["filters"].items() for r in e["angles"]]
    return header, rows


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``basin.json``, ``basin.md``, ``basin.csv``, ``arrays.npz`` and ``fig_basin.png`` to ``out``."""
    from ...reports import plots

    out = io.ensure_dir(out)
    header, rows = csv_rows(result)
    written = [io.write_npz(out / "arrays.npz", result["arrays"]),
               io.write_json(out / "basin.json",
                             {"schema": SCHEMA, **{k: v for k, v in result.items() if k != "arrays"}}),
               io.write_text(out / "basin.md", markdown(result)), io.write_rows(out / "basin.csv", header, rows)]
    written.append(plots.save_figure(basin_figure(io.read_arrays(out / "arrays.npz")), out / "fig_basin.png"))
    return written
