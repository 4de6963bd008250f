"""What the right error costs: the minimum-energy filter with ``error="right"`` (Theorem 4.1 on the system's
inverted state, each interval's state mapped there and back) against ``error="left"``, per sample, on the
second-order suite's systems where the defaults choose the right error.

Prints one JSON document on one core: for each system and engine, the steady time per sample of ``run`` for
each side (the best of ``--repeats`` runs after a first, compiling one; the two sides alternate, so that a
change of the machine's load hits them alike) and their ratio. Figures from one run on a shared machine:
compare the ratios; ``machine.loadavg`` says how busy the machine was. Nothing here asserts a time.

    python benchmarks/bench_side.py [--seconds 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

# One core, before JAX starts its thread pools (as bench_tse2.py).
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                           " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()

import jax  # noqa: E402
from _provenance import source_version  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

from liemef.filters import MinimumEnergyFilter  # noqa: E402
from liemef.studies.compare._second_order import CASES, trials  # noqa: E402

SYSTEMS = ("se2-near-rb", "attitude", "quad-range")
"""Systems of the suite on which ``error="auto"`` chooses the right error: a landmark, directions, an IMU."""


def measure(case, engine: str, repeats: int) -> dict:
    """Steady seconds per sample of each side's ``run`` on trial 0 of ``case``, and their ratio."""
    _, us, ys, g0s = trials(case, 1, 0, 1.0)
    g0 = jax.tree_util.tree_map(lambda a: a[0], g0s)
    filters = {side: MinimumEnergyFilter(case.system, error=side) for side in ("left", "right")}
    best = dict.fromkeys(filters, math.inf)
    for rep in range(repeats + 1):
        for side, flt in filters.items():
            t0 = time.perf_counter()
            traj = flt.run(flt.init(g0, case.K0), case.ts, us[0], ys[0], engine=engine)
            jax.block_until_ready(traj.K)
            if rep:  # the first call compiles
                best[side] = min(best[side], time.perf_counter() - t0)
    n = case.ts.size - 1
    return {"samples": int(n), **{f"{side}_us_per_sample": best[side] / n * 1e6 for side in filters},
            "right_over_left": best["right"] / best["left"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="Trial length (s).")
    ap.add_argument("--repeats", type=int, default=3, help="Steady runs per side (after the compiling one).")
    args = ap.parse_args()
    out = {"benchmark": "bench_side", "source": source_version(), "seconds": args.seconds,
           "machine": {"python": platform.python_version(), "loadavg": os.getloadavg()}, "systems": {}}
    for name in SYSTEMS:
        case = CASES[name][1](args.seconds)
        out["systems"][name] = {engine: measure(case, engine, args.repeats) for engine in ("c", "xla")}
        print(f"{name}: {out['systems'][name]}", file=sys.stderr, flush=True)
    json.dump(out, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
