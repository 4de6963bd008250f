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
* ``c_over_mef``: a filter's C ``us_per_step`` over the minimum-energy filter's, and whether the targets of
  issue 18 hold (C within 2x of the MEF per step, first call under 5 s on an idle machine).

Figures from one run on a shared machine: compare the ratios measured together rather than absolute numbers
across runs.

    python benchmarks/bench_baselines.py [--duration 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

# One core, before JAX starts its thread pools.
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                           " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()
# a fresh kernel cache: each filter's first C call is a first build (trace, translation, C compiler)
os.environ["LIEMEF_CACHE_DIR"] = tempfile.mkdtemp(prefix="liemef-bench-kernels-")

import jax  # noqa: E402
import numpy as np  # noqa: E402

import liemef  # noqa: E402
from liemef.filters.baselines import invariant_ekf, local_ekf, ukf_m  # noqa: E402
from liemef.studies.experiments import localization as L  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _provenance import source_version  # noqa: E402

jax.config.update("jax_enable_compilation_cache", False)  # XLA's first call compiles

FILTERS = {"mef": liemef.MinimumEnergyFilter, "iekf": invariant_ekf, "ekf": local_ekf, "ukf-left": ukf_m}
ENGINES = ("c", "xla")
MAX_RATIO, MAX_FIRST_S = 2.0, 5.0
"""Issue 18's targets: a baseline's C ``run`` within 2x of the MEF's us/step, its first call under 5 s."""


def time_run(flt, args, engine, repeats):
    """First call (s) and the median us per step of ``repeats`` more runs."""
    t0 = time.perf_counter()
    traj = jax.block_until_ready(flt.run(*args, engine=engine))
    first = time.perf_counter() - t0
    assert bool(traj.ok), f"{flt!r} by {engine} failed: {traj.status.message()}"
    kern = liemef.engines.kernel(flt, engine)
    if kern is not None:
        kern.wait()  # time the -O2 build
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(flt.run(*args, engine=engine))
        runs.append(time.perf_counter() - t0)
    steps = len(args[1]) - 1
    return {"first_call_s": round(first, 3), "us_per_step": round(float(np.median(runs)) / steps * 1e6, 3),
            "steps": steps}


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
           "machine": platform.machine(), "source": source_version()}
    for name, make in FILTERS.items():
        flt = make(s.system)
        args = (flt.init(g0, K0), ts, us, ys)
        out["filters"][name] = {engine: time_run(flt, args, engine, a.repeats) for engine in ENGINES}
    mef = out["filters"]["mef"]["c"]["us_per_step"]
    for fig in out["filters"].values():
        fig["c_over_mef"] = round(fig["c"]["us_per_step"] / mef, 2)
        fig["c_over_xla"] = round(fig["c"]["us_per_step"] / fig["xla"]["us_per_step"], 3)
        fig["targets_met"] = fig["c_over_mef"] <= MAX_RATIO and fig["c"]["first_call_s"] < MAX_FIRST_S
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
