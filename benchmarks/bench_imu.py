"""The real-data filter against VQF, per sample, in one process (issue 36, item 1): ``compare broad``'s
``mef-vel``, ``mef-vel-first`` and ``iekf-vel`` on a whole BROAD trial by the C engine, beside VQF 2.1.2's
``updateBatch`` (C++) on the same trial's raw samples, each the median of ``--repeats`` runs after a first one
(the kernel's -O2 build waited for), on one core; and ``mef-vel`` with the explicit-midpoint integrator
(``mef-vel-rkmk2``: RKMK2, two evaluations of the field a sub-step against RKMK4's four), with its largest
attitude difference from ``mef-vel`` and both filters' total rms on the trial.

Prints one JSON document: per filter the microseconds per sample and the ratio to VQF's, the first call's
seconds, the integration sub-steps per sample and the integrator (for a variant also the filter it varies, its
total rms on the trial, the varied filter's (``base_total_rms_deg``) and their largest attitude
difference, None where the varied filter failed), the trial, its samples, the load average
before and after, and the CPU model. Issue 36's target is a
ratio of at most 3, idle and under load. Nothing here asserts a time; compare the ratios of one run.

    python benchmarks/bench_imu.py [--trial 07] [--repeats 5] [--realdata DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import cpu_model, one_core  # noqa: E402

FILTERS = ("mef-vel", "mef-vel-first", "iekf-vel")
VARIANTS = {"mef-vel-rkmk2": ("mef-vel", "rkmk2")}
"""Filters of ``compare broad`` with another integrator: the name, the filter it varies and the integrator."""
TARGET = 3.0
"""Issue 36's target: at most 3 times VQF's time per sample."""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trial", default="07", help="the BROAD trial (default 07, 52,518 samples)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs of each filter (default 5)")
    ap.add_argument("--realdata", default=None, help="the real-data folder (default: found as liemef finds it)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: expected at least 1, got {args.repeats}")
    one_core(fresh_kernel_cache=False)

    from pathlib import Path

    import equinox as eqx
    import jax
    import numpy as np
    import vqf

    import liemef
    from liemef.integrators import integrator
    from liemef.metrics import attitude_rms
    from liemef.studies import datasets
    from liemef.studies.compare import _broad

    paths = datasets.broad_trials(None if args.realdata is None else Path(args.realdata) / datasets.BROAD_DIR)
    if args.trial not in paths:
        ap.error(f"--trial: expected one of {sorted(paths)} (the BROAD trials present), got {args.trial!r}")
    trial = datasets.broad(paths[args.trial])
    ctx, logs = _broad.trial_context(trial), _broad.trial_logs(trial)
    load0 = os.getloadavg()[0]
    n = len(trial.ts)

    gyr, acc, mag = (np.ascontiguousarray(a, dtype=np.float64) for a in (trial.gyr, trial.acc, trial.mag))

    def vqf_once():
        vqf.VQF(1.0 / trial.rate).updateBatch(gyr, acc, mag)

    vqf_once()
    runs = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        vqf_once()
        runs.append(time.perf_counter() - t0)
    ref = statistics.median(runs) / n * 1e6
    out = {"vqf": {"us_per_sample": round(ref, 3)}}
    quats = {}
    for name in FILTERS + tuple(VARIANTS):
        t0 = time.perf_counter()
        base, other = VARIANTS.get(name, (name, None))
        flt, state, log = _broad.setup(base, ctx, logs)
        if other is not None:  # compare broad's filter, its integrator replaced: nothing else differs
            flt = eqx.tree_at(lambda f: f.integrator, flt, integrator(other))
        traj = jax.block_until_ready(flt.run(state, log.ts, log.us, log.ys, engine="c"))
        first = time.perf_counter() - t0
        if not bool(traj.ok):
            out[name] = {"error": traj.status.message(log.ts)}
            continue
        kern = liemef.engines.kernel(flt, "c")
        if kern is not None:
            kern.wait()  # time the -O2 build
        runs = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(flt.run(state, log.ts, log.us, log.ys, engine="c"))
            runs.append(time.perf_counter() - t0)
        us = statistics.median(runs) / (len(log.ts) - 1) * 1e6
        st = traj.status
        substeps = (int(st.substeps_total) / (len(log.ts) - 1)) if hasattr(st, "substeps_total") else None
        out[name] = {"us_per_sample": round(us, 3), "ratio_to_vqf": round(us / ref, 2),
                     "within_target": us / ref <= TARGET, "first_call_s": round(first, 3),
                     "substeps_per_sample": None if substeps is None else round(substeps, 3),
                     "integrator": getattr(getattr(flt, "integrator", None), "name", None)}
        quats[name] = np.asarray(traj.g_hat.factors[0].wxyz)
        if other is not None:
            row = {"varies": base, "total_rms_deg": attitude_rms(
                quats[name], trial.quat_true, trial.movement)["total"], "max_attitude_difference_deg": None,
                   "base_total_rms_deg": None}
            if base in quats:  # the filter it varies ran (it failed otherwise: its row says why)
                dot = np.abs(np.sum(quats[name] * quats[base], axis=1))  # unit quaternions: the angle between
                row["max_attitude_difference_deg"] = float(np.degrees(2.0 * np.arccos(np.clip(dot, 0.0, 1.0))).max())
                row["base_total_rms_deg"] = attitude_rms(quats[base], trial.quat_true, trial.movement)["total"]
            out[name].update(row)
        print(f"{name}: {out[name]}", file=sys.stderr, flush=True)
    print(json.dumps({"trial": args.trial, "samples": n, "target_ratio": TARGET, "filters": out,
                      "loadavg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)], "cpu": cpu_model(),
                      "vqf_version": getattr(vqf, "__version__", None)}, indent=1))


if __name__ == "__main__":
    main()
