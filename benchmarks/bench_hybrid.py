"""What samples at their own time cost: the hybrid minimum-energy filter (``updates="discrete"``) against the
papers' zero-order hold (``updates="hold"``) on a BROAD recording, per sample, with their errors.

Prints one JSON document on one core: for each update mode and engine, the steady time per sample of ``run``
(the best of ``--repeats`` runs after a first, compiling one), the sub-step counts, and BROAD's total and
inclination rms over the movement mask (the system's default noise levels, dip from the rest phase). Figures
from one run on a shared machine: compare the ratios, measured together; ``machine.loadavg`` says how busy the
machine was. Nothing here asserts a time.

    python benchmarks/bench_hybrid.py [--trial 07] [--seconds 60] [--repeats 3]
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
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

from liemef.engines import kernel  # noqa: E402
from liemef.filters import MinimumEnergyFilter  # noqa: E402
from liemef.metrics import attitude_error  # noqa: E402
from liemef.studies import datasets  # noqa: E402
from liemef.systems import attitude_bias as ab  # noqa: E402
from liemef.systems import imu_rest  # noqa: E402

K0 = np.diag([0.05**2] * 3 + [0.01**2] * 3)


def broad_errors(trial, traj) -> tuple[float, float]:
    """Total and inclination rms (deg) over BROAD's movement mask where the optical truth is present."""
    ok = trial.movement & ~np.isnan(trial.quat_true).any(axis=1)
    R_true = np.asarray(ab.quaternion_to_tso3(trial.quat_true[ok]).factors[0].as_matrix())
    R_hat = np.asarray(traj.g_hat.factors[0].as_matrix())[ok]
    total = attitude_error(R_true, R_hat)
    incl = np.arccos(np.clip(np.einsum("ni,ni->n", R_hat[:, 2, :], R_true[:, 2, :]), -1.0, 1.0))
    return (float(np.degrees(np.sqrt(np.mean(total**2)))), float(np.degrees(np.sqrt(np.mean(incl**2)))))


def measure(filters: dict, state_of, log, engine, repeats) -> dict:
    """Each filter's trajectory, first call (s) and best steady time (s) of ``run``; the steady runs alternate
    between the filters, so that a change of the machine's load hits them alike."""
    out = {}
    for name, flt in filters.items():
        t0 = time.perf_counter()
        traj = flt.run(state_of(flt), log.ts, log.us, log.ys, engine=engine)
        jax.block_until_ready(traj.K)
        out[name] = [traj, time.perf_counter() - t0, math.inf]
        if engine == "c":
            kernel(flt, "c").wait()  # the -O2 build, which replaces the first -O0 one in the background
    for _ in range(repeats):
        for name, flt in filters.items():
            t0 = time.perf_counter()
            jax.block_until_ready(flt.run(state_of(flt), log.ts, log.us, log.ys, engine=engine).K)
            out[name][2] = min(out[name][2], time.perf_counter() - t0)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trial", default="07", help="BROAD trial number (default 07, fast rotation)")
    ap.add_argument("--seconds", type=float, default=60.0, help="the first seconds of the trial")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--engines", default="c,xla")
    args = ap.parse_args()
    found = datasets.broad_trials()
    if args.trial not in found:
        sys.exit(f"BROAD trial {args.trial} not found (set {datasets.ENV_VAR})")
    trial = datasets.broad(found[args.trial]).head(args.seconds)
    k = imu_rest.initial_rest(trial.gyr, trial.acc, trial.rate)  # the initial rest, from the IMU alone
    dip = imu_rest.magnetic_dip(trial.acc[:k], trial.mag[:k])
    log = datasets.broad_to_log(trial)
    system = ab.attitude_gyro_bias(dip=dip)
    g0 = imu_rest.initial_estimate(trial.acc[:50], trial.mag[:50])
    out = {"trial": args.trial, "seconds": args.seconds, "samples": int(log.ts.shape[0]), "results": {}}
    n = log.ts.shape[0] - 1
    for engine in args.engines.split(","):
        filters = {u: MinimumEnergyFilter(system, updates=u) for u in ("hold", "discrete")}
        got = measure(filters, lambda f: f.init(g0, K0), log, engine, args.repeats)
        for updates, (traj, first, best) in got.items():
            total, incl = broad_errors(trial, traj)
            out["results"][f"{engine}/{updates}"] = {
                "us_per_sample": 1e6 * best / n, "first_call_s": first, "ok": bool(traj.status.ok),
                "substeps_total": int(traj.status.substeps_total), "total_rms_deg": total, "incl_rms_deg": incl}
            print(f"{engine}/{updates}: {1e6 * best / n:.2f} us/sample, total {total:.3f} deg", file=sys.stderr)
        r = out["results"]
        out[f"{engine}_cost_ratio_discrete_over_hold"] = (r[f"{engine}/discrete"]["us_per_sample"]
                                                         / r[f"{engine}/hold"]["us_per_sample"])
    out["machine"] = {"python": platform.python_version(), "jax": jax.__version__, "loadavg": os.getloadavg(),
                      "source": source_version()}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
