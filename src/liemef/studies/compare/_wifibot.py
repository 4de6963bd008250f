r"""``liemef compare wifibot``: every planar filter on the Wifibot runs of UKF-M (Brossard, Barrau & Bonnabel
2020, BSD-3): real wheel odometry, optical ground truth, and synthetic GPS.

The robot's wheel odometry (forward speed and yaw rate, about 50 Hz, irregular time stamps) is the input of
:func:`liemef.systems.planar_localization`. Its noise levels per sample at 50 Hz are: yaw rate 0.2 rad/s, forward
speed 0.05 m/s and lateral speed 0.01 m/s. The odometry over-reads the truth by about 5 %, a systematic error
that this white noise has to cover. The GPS is UKF-M's synthetic one: the optical position plus N(0, 0.1^2 I) m,
at 1 Hz. The GPS noise is the only random part, so ``runs`` seeds (``seed``, ``seed + 1``, ...; numpy's
``default_rng``, :func:`liemef.studies.datasets.synthetic_gps`) give the Monte Carlo spread. Every filter starts at the
true start pose with K0 = diag(0.01^2 I3). The metrics over the whole run, per seed, are the heading and
position rms against the optical truth and the heading and position NEES. Winners are named by paired
differences over the seeds (:func:`~liemef.studies.compare.paired_comparison`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ...groups import SE2
from ...metrics import chi2_bounds
from ...reports import io
from ...systems import planar_localization
from .. import datasets
from ..experiments import localization as L
from ._common import (
    FILTERS,
    check_counts,
    fmt,
    make_filter,
    nees_cell,
    nees_flag,
    paired_comparison,
    parse_filters,
    realdata_present,
    unranked_filters,
    winners_markdown,
)

SCHEMA = "liemef.compare.wifibot/1"
"""Version tag of ``wifibot.json``."""

DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf", "ekf", "ukf-left")
ODOMETRY_STD = (0.2, 0.05, 0.01)
"""Per-sample std at 50 Hz of (yaw rate rad/s, forward m/s, lateral m/s)."""
METRICS = (("heading_rms", "heading rms", "deg"), ("position_rms", "position rms", "m"))


@dataclass(frozen=True)
class WifibotComparison:
    """The study's settings: the Wifibot ``recordings`` present (ids of
    :func:`liemef.studies.datasets.wifibot_runs`, read from the files; default all present), ``runs`` GPS seeds
    from ``seed``, the GPS ``gps_rate`` (Hz) and ``gps_std`` (m), ``filters``, and ``realdata``
    (default :func:`liemef.studies.datasets.realdata_dir`)."""

    recordings: tuple[str, ...] | str | None = None
    runs: int = 20
    seed: int = 0
    gps_rate: float = 1.0
    gps_std: float = 0.1
    filters: tuple[str, ...] | str | None = DEFAULT_FILTERS
    realdata: str | None = None

    def __post_init__(self):
        folder, present = realdata_present(self.realdata, datasets.wifibot_runs, datasets.WIFIBOT_DIR)
        rec = tuple(present) if self.recordings is None else tuple(str(r).strip() for r in (
            str(self.recordings).split(",") if isinstance(self.recordings, str | int) else self.recordings))
        if not rec or any(r not in present for r in rec):
            raise ValueError(f"recordings: expected Wifibot runs present in {folder} from {list(present)}, got "
                             f"{list(rec)}")
        check_counts(self, "runs")
        for name in ("gps_rate", "gps_std"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a number > 0, got {v!r}")
        object.__setattr__(self, "recordings", rec)
        object.__setattr__(self, "filters", parse_filters(self.filters, DEFAULT_FILTERS))
        object.__setattr__(self, "realdata", str(folder))


@eqx.filter_jit
def _runs(flt, state0, ts, us, ys_batch, truth):
    def one(ys):
        traj = flt.scan(state0, ts, us, ys)
        return L.series(truth, traj.g_hat, traj.K), traj.status.code

    return jax.vmap(one)(ys_batch)


def compare_wifibot(study: WifibotComparison | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "recordings", "arrays"}``."""
    st = WifibotComparison() if study is None else study
    folder = Path(st.realdata)
    system = planar_localization(odometry_std=ODOMETRY_STD, odometry_rate=50.0, gps_std=st.gps_std)
    out, arrays = {}, {}
    for rid in st.recordings:
        run = datasets.wifibot(datasets.wifibot_runs(folder / datasets.WIFIBOT_DIR)[rid])
        logs = [datasets.wifibot_to_log(run, st.gps_rate, st.gps_std, seed=st.seed + i) for i in range(st.runs)]
        ys = np.stack([lg.ys for lg in logs])
        ts, us = logs[0].ts, logs[0].us
        truth = SE2.from_coords(run.truth)
        trials, summary = {}, {}
        for name in st.filters:
            t0 = time.perf_counter()
            flt = make_filter(name, system)
            state0 = flt.init(SE2.identity(), np.diag([0.01**2] * 3))
            ser, code = (np.asarray(a) for a in _runs(flt, state0, ts, us, ys, truth))
            ok = (code == 0) & np.all(np.isfinite(ser[..., :2]), axis=(1, 2))
            rms = lambda x: np.sqrt(np.mean(np.square(x), axis=1))  # noqa: E731
            m = {"heading_rms": rms(ser[:, :, 0]), "position_rms": rms(ser[:, :, 1]),
                 "nees_heading": ser[:, :, 2].mean(axis=1), "nees_position": ser[:, :, 3].mean(axis=1)}
            trials[name] = {k: np.where(ok, v, np.nan) for k, v in m.items()}
            summary[name] = {"filter": FILTERS[name][0], "status_ok": int(ok.sum()), "runs": st.runs,
                             "failed": int((~ok).sum()), "elapsed_s": time.perf_counter() - t0}
            for k, v in trials[name].items():
                x = v[np.isfinite(v)]
                summary[name][k] = ({"mean": float(x.mean()), "p5": float(np.percentile(x, 5)),
                                     "p95": float(np.percentile(x, 95))} if x.size else
                                    {"mean": None, "p5": None, "p95": None})
            for k, dof in (("nees_heading", 1), ("nees_position", 2)):
                bounds = chi2_bounds(dof, st.runs, 0.95, per_dof=True)
                summary[name][k].update({"chi2_bounds": list(bounds), "flag": nees_flag(summary[name][k]["mean"],
                                                                                        bounds)})
            for k in ("heading_rms", "position_rms"):
                arrays[f"{rid}/{name}/{k}"] = trials[name][k]
            ab = np.abs(ser[ok][..., :2])
            arrays[f"{rid}/{name}/bands"] = (np.percentile(ab, (5, 50, 95), axis=0) if ok.any()
                                             else np.full((3, ts.shape[0], 2), np.nan))
            if progress:
                print(f"  run {rid} {name:10s} heading {fmt(summary[name]['heading_rms']['mean'])} deg, position "
                      f"{fmt(summary[name]['position_rms']['mean'])} m; {summary[name]['elapsed_s']:.1f} s",
                      file=sys.stderr, flush=True)
        arrays[f"{rid}/ts"] = ts
        out[rid] = {"file": run.name, "rows": int(ts.shape[0]), "seconds": float(ts[-1] - ts[0]),
                    "filters": summary, "trials": trials}
    # A filter that failed on a seed of any recording, or whose K is far off on one, wins on none.
    unranked = {}
    for rec in out.values():
        for name, why in unranked_filters(rec["filters"], ("nees_heading", "nees_position")).items():
            unranked[name] = "; ".join(filter(None, (unranked.get(name), f"{rec['file']}: {why}")))
    for rec in out.values():
        trials = rec.pop("trials")
        rec["winners"] = {label: paired_comparison({n: trials[n][key] for n in st.filters}, unranked=unranked)
                          for key, label, _ in METRICS}
    return {"study": {**dataclasses.asdict(st), "odometry_std": ODOMETRY_STD,
                      "gps": f"optical position + N(0, {st.gps_std:g}^2 I) at {st.gps_rate:g} Hz, numpy "
                             f"default_rng(seed + i) for run i"},
            "recordings": out, "arrays": arrays}


def markdown(result: dict) -> str:
    """Per recording: each filter's heading and position rms and NEES across the GPS seeds, and the winners."""
    st = result["study"]
    lines = ["# Planar filters on the Wifibot runs of UKF-M (Brossard, Barrau & Bonnabel 2020, BSD-3)", "",
             f"Real wheel odometry, optical truth; GPS: {st['gps']}; {st['runs']} seeds. Odometry noise per sample "
             f"at 50 Hz (yaw rate, forward, lateral): {st['odometry_std']}. Per seed: rms over the whole run; "
             "across seeds: mean [p5, p95].", ""]
    for rec in result["recordings"].values():
        lo1, hi1 = chi2_bounds(1, st["runs"], 0.95, per_dof=True)
        lo2, hi2 = chi2_bounds(2, st["runs"], 0.95, per_dof=True)
        lines += [f"## {rec['file']} ({rec['rows']} rows, {rec['seconds']:.1f} s)", "",
                  "| filter | status ok | heading rms [deg] | position rms [m] | heading NEES | position NEES / 2 |",
                  "|---|---:|---:|---:|---:|---:|"]
        for name, e in rec["filters"].items():
            cell = lambda d: f"{fmt(d['mean'])} [{fmt(d['p5'])}, {fmt(d['p95'])}]"  # noqa: E731
            lines.append(f"| {name} | {e['status_ok']}/{e['runs']} | {cell(e['heading_rms'])} | "
                         f"{cell(e['position_rms'])} | {nees_cell(e['nees_heading']['mean'], (lo1, hi1))} | "
                         f"{nees_cell(e['nees_position']['mean'], (lo2, hi2))} |")
        lines += ["", f"NEES: mean over the run and the seeds, 1 for a consistent filter; the 95 % chi-square bounds "
                  f"of one step's average over {st['runs']} seeds: {lo1:.3f}-{hi1:.3f} (heading), {lo2:.3f}-"
                  f"{hi2:.3f} (position / 2); '(far above!)' marks a NEES beyond 10 times the upper bound. Status "
                  "ok: the seeds the filter ran through without a failure, not that it converged. The seeds share "
                  "the odometry, so the bounds are optimistic.", "",
                  *winners_markdown(rec["winners"], {label: unit for _, label, unit in METRICS}), ""]
    return "\n".join(lines)


def save(result: dict, out: str | Path) -> list[Path]:
    """Write ``wifibot.json``, ``wifibot.md``, ``wifibot.csv``, ``arrays.npz`` and per recording
    ``fig_errors_<id>.png`` (per filter the median and 5-95 % band across the GPS seeds of the heading and
    position errors over time) to ``out``."""
    from ...reports import plots
    from ._localization import band_figure

    out = io.ensure_dir(out)
    rows = [[rid, name, e["status_ok"], e["runs"], e["heading_rms"]["mean"], e["position_rms"]["mean"],
             e["nees_heading"]["mean"], e["nees_position"]["mean"]]
            for rid, rec in result["recordings"].items() for name, e in rec["filters"].items()]
    written = [io.write_npz(out / "arrays.npz", result["arrays"]),
               io.write_json(out / "wifibot.json",
                             {"schema": SCHEMA, **{k: v for k, v in result.items() if k != "arrays"}}),
               io.write_text(out / "wifibot.md", markdown(result)),
               io.write_rows(out / "wifibot.csv", ["recording", "filter", "status_ok", "runs", "heading_rms_deg",
                                                   "position_rms_m", "nees_heading", "nees_position"], rows)]
    a = io.read_arrays(out / "arrays.npz")
    names = result["study"]["filters"]
    for rid, rec in result["recordings"].items():
        fig = band_figure({"ts": a[f"{rid}/ts"], "filters": np.array(names),
                           "bands": np.stack([a[f"{rid}/{n}/bands"] for n in names])},
                          f"{rec['file']}: median and 5-95 % band across {result['study']['runs']} GPS seeds")
        written.append(plots.save_figure(fig, out / f"fig_errors_{rid}.png"))
    return written
