"""Distance to optimality in the localization comparison: each filter's estimate against the exact
minimum-energy (per-step MAP) estimate of the same data (:func:`liemef.studies.optimum.map_estimates`, GTSAM iSAM2)."""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

from ...groups import SE2
from ...metrics._stats import json_number
from .. import optimum
from ..experiments import localization as L
from ._common import paired_comparison


def localization_distances(config: L.LocalizationConfig, draws: L.Draws, coords: dict[str, np.ndarray], *,
                           progress: bool = True, unranked: dict[str, str] | None = None) -> dict:
    """For each trial of ``draws`` (the first trials of the comparison, stacked) the per-step MAP by iSAM2, and for each
    filter the heading (deg) and position (m) distance of its estimates ``coords[name][i]`` (N, 3) from it:
    per trial the mean over the run and over t >= steady; across trials their means and the paired winner (never
    one of ``unranked``, the comparison's filters that may not win, :func:`~._common.unranked_filters`);
    the mean curves over time for the figure (``arrays``)."""
    s = L.setup(config)
    K0 = np.diag([config.theta0_std**2, 0.0, 0.0])
    steady = config.ts >= config.steady
    names = list(coords)
    head = {n: [] for n in names}
    pos = {n: [] for n in names}
    per = {n: {"heading_mean": [], "heading_steady": [], "position_mean": [], "position_steady": []} for n in names}
    elapsed, solver = [], None
    runs = int(draws.theta0.shape[0])
    for i in range(runs):
        log, g0 = L.sensor_log(config, s.truth, jax.tree_util.tree_map(lambda a, i=i: a[i], draws))
        t0 = time.perf_counter()
        est = optimum.map_estimates(s.system, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys), g0, K0)
        elapsed.append(time.perf_counter() - t0)
        solver = est.solver
        for n in names:
            d = optimum.distance_components(SE2.from_coords(coords[n][i]), est.g)
            h, p = np.degrees(np.asarray(d["heading"])), np.asarray(d["position"])
            head[n].append(h)
            pos[n].append(p)
            for key, x, m in (("heading_mean", h, slice(None)), ("heading_steady", h, steady),
                              ("position_mean", p, slice(None)), ("position_steady", p, steady)):
                per[n][key].append(float(np.mean(x[m])))
        if progress:
            print(f"  optimum, trial {i}: {solver} in {elapsed[-1]:.1f} s", file=sys.stderr, flush=True)
    filters = {n: {k: json_number(float(np.mean(v))) for k, v in per[n].items()} for n in names}
    labels = {"heading_mean": "heading distance, whole run", "heading_steady": "heading distance t >= steady",
              "position_mean": "position distance, whole run", "position_steady": "position distance t >= steady"}
    winners = {label: paired_comparison({n: np.array(per[n][key]) for n in names}, unranked=unranked)
               for key, label in labels.items()}
    return {"definition": f"the exact minimum-energy estimate: the MAP of the current pose given every sample "
                          f"before it, on the same discretized cost, by {solver} "
                          f"(liemef.studies.optimum.map_estimates); "
                          f"distance of each filter's estimate from it at every step: heading [deg] and position "
                          f"[m], averaged over the run and over t >= {config.steady:g} s, then over "
                          f"{runs} trials (the comparison's first).",
            "solver": solver, "trials": runs, "elapsed_s": elapsed, "filters": filters,
            "winners": winners,
            "arrays": {"optimum_heading_deg": np.stack([np.mean(head[n], axis=0) for n in names]),
                       "optimum_position_m": np.stack([np.mean(pos[n], axis=0) for n in names]),
                       "optimum_filters": np.array(names)}}
