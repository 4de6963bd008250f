"""Speed of the baselines beside the minimum-energy filter, on both engines, on ukfm's 2D localization.

The system and the data are ukfm's localization benchmark (``liemef.studies.experiments.localization``: a
circle at 100 Hz odometry, GPS at 1 Hz; ``--duration`` seconds of it, 4,000 steps by default), one core. For
each filter (the minimum-energy filter, the invariant EKF, the EKF in local coordinates and the left UKF-M)
and each engine (``c``: the filter's interval as a compiled C kernel, the same path for every filter;
``xla``: the jitted ``lax.scan``) it prints, as one JSON document:

* ``first_call_s``: the first ``run`` in this process, until its result: the trace of the interval, its
  translation and the quick (-O0) C build into a fresh kernel cache, or XLA's compilation (with JAX's
  persistent compilation cache off);
* ``us_per_step``: the median of ``--repeats`` further runs, per sample interval (by C: the -O2 build, waited
  for);
* ``cpu_us_per_step``: the CPU time of this process per sample interval (all its threads: the C kernel runs in
  the calling one, XLA in its pool), a figure a loaded machine disturbs less than the wall clock (it leaves
  out the time the process waits for a core);
* ``c_over_mef``, ``cpu_c_over_mef`` and ``first_call_c_over_mef``: a filter's C ``us_per_step``,
  ``cpu_us_per_step`` and ``first_call_s`` over the minimum-energy filter's, and whether the targets of issue 18
  hold (C within 2x of the MEF per step, first call under 5 s on an idle machine);
* ``loadavg_1min`` before and after: the machine's load beside the figures.

Figures from one run on a shared machine: compare the ratios measured together rather than absolute numbers
across runs. A short check: ``--duration 10 --repeats 3``.

    python benchmarks/bench_baselines.py [--duration 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import one_core, time_run  # noqa: E402

one_core()  # before JAX starts its thread pools; each filter's first C call is a first build

import jax  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402

import liemef  # noqa: E402
from liemef.filters.baselines import invariant_ekf, local_ekf, ukf_m  # noqa: E402
from liemef.studies.experiments import localization as L  # noqa: E402

jax.config.update("jax_enable_compilation_cache", False)  # XLA's first call compiles

FILTERS = {"mef": liemef.MinimumEnergyFilter, "iekf": invariant_ekf, "ekf": local_ekf, "ukf-left": ukf_m}
ENGINES = ("c", "xla")
MAX_RATIO, MAX_FIRST_S = 2.0, 5.0
"""Issue 18's targets: a baseline's C ``run`` within 2x of the MEF's us/step, its first call under 5 s."""


def cpu_per_step(flt, args, engine, repeats: int) -> float:
    """The median CPU time of this process (all its threads) per sample interval (us) over ``repeats`` runs."""
    runs = []
    for _ in range(repeats):
        t0 = time.process_time()
        jax.block_until_ready(flt.run(*args, engine=engine))
        runs.append(time.process_time() - t0)
    return round(float(np.median(runs)) / (len(args[1]) - 1) * 1e6, 3)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=40.0, help="seconds of the localization log (100 Hz)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs after the first")
    a = ap.parse_args(argv)
    c = L.LocalizationConfig(duration=a.duration, steady=a.duration / 2)
    s = L.setup(c)
    log, g0 = L.sensor_log(c, s.truth, L.jax_draws(c, jax.random.key(0)))
    K0 = np.diag([c.theta0_std**2, 1e-6, 1e-6])
    ts, us, ys = (np.asarray(x) for x in (log.ts, log.us, log.ys))
    out = {"system": "ukfm 2D localization (SE(2), 100 Hz odometry, 1 Hz GPS)", "filters": {},
           "machine": platform.machine(), "source": source_version(),
           "loadavg_1min": {"before": round(os.getloadavg()[0], 2)}}
    for name, make in FILTERS.items():
        flt = make(s.system)
        args = (flt.init(g0, K0), ts, us, ys)
        out["filters"][name] = {engine: time_run(flt, args, engine, a.repeats) for engine in ENGINES}
        for engine in ENGINES:
            out["filters"][name][engine]["cpu_us_per_step"] = cpu_per_step(flt, args, engine, a.repeats)
    out["loadavg_1min"]["after"] = round(os.getloadavg()[0], 2)
    mef = out["filters"]["mef"]["c"]
    for fig in out["filters"].values():
        fig["c_over_mef"] = round(fig["c"]["us_per_step"] / mef["us_per_step"], 2)
        fig["cpu_c_over_mef"] = round(fig["c"]["cpu_us_per_step"] / mef["cpu_us_per_step"], 2)
        fig["first_call_c_over_mef"] = round(fig["c"]["first_call_s"] / mef["first_call_s"], 2)
        fig["c_over_xla"] = round(fig["c"]["us_per_step"] / fig["xla"]["us_per_step"], 3)
        fig["targets_met"] = min(fig["c_over_mef"], fig["cpu_c_over_mef"]) <= MAX_RATIO \
            and fig["c"]["first_call_s"] < MAX_FIRST_S
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
