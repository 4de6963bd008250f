"""What the smoother costs beside the filter: the whole-log smoother (``liemef.smooth``) at several log lengths,
and the fixed-lag smoother per step at several lags, on ukfm's planar localization (100 Hz odometry, a fix a
second), against the filter's run on the same log.

Prints one JSON document on one core: per log length, the filter's seconds per sample, the smoother's (its
first call, compiling, and the best of ``--repeats`` further calls), their ratio, the iterations, and the
smoother's seconds per sample relative to the shortest log (linear in the log's length: about 1); per lag, the
fixed-lag smoother's median milliseconds per step over a log, and its ratio to the filter's step. With
``--minutes``, logs of that many minutes at 100 Hz smoothed in chunks (``liemef.smooth(..., chunk, overlap)``),
each in a process of its own, and the shortest also as one problem: the seconds, the microseconds per sample
and the process's peak resident memory, with the ratios of each to the shortest chunked run (bounded memory:
a peak that does not grow with the log). Figures from one run on a shared machine: compare the ratios;
``machine.loadavg`` says how busy it was. Nothing asserts a time.

    python benchmarks/bench_smoother.py [--lengths 1000,4000,16000] [--lags 20,100] [--repeats 2]
    python benchmarks/bench_smoother.py --lengths "" --lags "" --minutes 6,60 [--chunk 2000 --overlap 1000]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time

from _timing import cpu_model, one_core

one_core(fresh_kernel_cache=False)

import jax  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402

import liemef  # noqa: E402
from liemef.studies.experiments import localization as loc  # noqa: E402
from liemef.systems import planar_localization  # noqa: E402


def scenario(n: int):
    """ukfm's localization over ``n`` samples (a circle of 5 m radius, driven once a minute)."""
    c = loc.LocalizationConfig(duration=n / 100.0, gps_period=1.0, steady=0.0, radius=5.0)
    vstd, lstd, wstd = c.odometry_std
    system = planar_localization(odometry_std=(wstd, vstd, lstd), odometry_rate=1.0 / c.dt, gps_std=c.gps_std)
    idx = np.arange(c.n_states)
    vx, _, w = loc.true_input(c)
    theta = idx * w * c.dt
    steps = vx * c.dt * np.stack([np.cos(theta), np.sin(theta)], 1)
    p = np.concatenate([np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)])
    truth = liemef.groups.SE2.from_coords(np.concatenate([theta[:, None], p], 1))
    log, g0 = loc.sensor_log(c, truth, loc.jax_draws(c, jax.random.key(0)))
    flt = liemef.MinimumEnergyFilter(system)
    state = flt.init(g0, K0=np.diag([c.theta0_std**2, 1e-6, 1e-6]))
    return flt, state, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys)


def whole_log(n: int, repeats: int) -> dict:
    flt, state, ts, us, ys = scenario(n)
    traj = flt.run(state, ts, us, ys)  # compiles
    t0 = time.perf_counter()
    traj = jax.block_until_ready(flt.run(state, ts, us, ys))
    filt = time.perf_counter() - t0
    t0 = time.perf_counter()
    sm = liemef.smooth(flt, state, ts, us, ys, init=traj.g_hat)
    first = time.perf_counter() - t0
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        sm = liemef.smooth(flt, state, ts, us, ys, init=traj.g_hat)
        best = min(best, time.perf_counter() - t0)
    if not sm.ok:
        raise RuntimeError(f"the smoother did not converge on {n} samples: {sm.message}")
    return {"samples": n, "filter_us_per_sample": filt / n * 1e6, "smoother_first_call_s": first,
            "smoother_us_per_sample": best / n * 1e6, "smoother_over_filter": best / filt,
            "iterations": sm.iterations}


MIN_WINDOWS = 20
"""The fewest fixed-lag windows a lag is timed over (the first tenth, which compile, are not counted)."""


def fixed_lag(lag: int, n: int) -> dict:
    flt, state, ts, us, ys = scenario(n)
    fl = liemef.smoothers.FixedLagSmoother(flt, state, lag)
    step = []
    for k in range(n):
        t0 = time.perf_counter()
        w = fl.update(ts[k], us[k], ys[k])
        if w is not None:
            jax.block_until_ready(w.P)
            step.append(time.perf_counter() - t0)
            if not w.ok:
                raise RuntimeError(f"a fixed-lag window failed at sample {k}: {w.message}")
    steady = step[len(step) // 10:]  # after the first windows (compiling)
    flt_step = []
    s = state
    for k in range(min(n - 1, 200)):
        t0 = time.perf_counter()
        s = jax.block_until_ready(flt.step(s, ts[k], us[k], ys[k], ts[k + 1] - ts[k]))
        flt_step.append(time.perf_counter() - t0)
    filt = statistics.median(flt_step[20:])
    return {"lag_samples": lag, "windows": len(step), "ms_per_step": statistics.median(steady) * 1e3,
            "filter_step_ms": filt * 1e3, "over_filter_step": statistics.median(steady) / filt}


def one_long_log(minutes: float, chunk: int | None, overlap: int) -> dict:
    """In this process: a log of ``minutes`` at 100 Hz smoothed (in chunks, or as one problem with ``chunk``
    None), timed from the filter's first run to the smoother's result, and this process's peak memory."""
    n = int(round(minutes * 6000))
    flt, state, ts, us, ys = scenario(n)
    t0 = time.perf_counter()
    sm = liemef.smooth(flt, state, ts, us, ys, chunk=chunk, overlap=None if chunk is None else overlap)
    jax.block_until_ready(sm.P)
    seconds = time.perf_counter() - t0
    if not sm.ok:
        raise RuntimeError(f"the smoother did not converge on {n} samples: {sm.message}")
    return {"minutes": minutes, "samples": n, "chunk": chunk, "overlap": overlap if chunk else None,
            "seconds": seconds, "us_per_sample": seconds / n * 1e6, "iterations": sm.iterations,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def long_logs(minutes: list[float], chunk: int, overlap: int) -> list[dict]:
    """:func:`one_long_log` for each length in chunks, and for the shortest as one problem, each in a fresh
    process (so that each peak is its own)."""
    cases = [(minutes[0], None)] + [(m, chunk) for m in minutes]
    rows = []
    for m, c in cases:
        out = subprocess.run([sys.executable, __file__, "--one-long", str(m), "--chunk", str(c or 0), "--overlap",
                              str(overlap)], capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout))
    ref = rows[1]
    for r in rows:
        r["us_per_sample_over_shortest_chunked"] = r["us_per_sample"] / ref["us_per_sample"]
        r["peak_rss_over_shortest_chunked"] = r["peak_rss_mb"] / ref["peak_rss_mb"]
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", default="1000,4000,16000", help="Log lengths (samples), comma separated.")
    ap.add_argument("--lags", default="20,100", help="Fixed-lag windows (samples), comma separated.")
    ap.add_argument("--lag-samples", type=int, default=600, help="Samples of the log each lag is timed over.")
    ap.add_argument("--repeats", type=int, default=2, help="Steady smoother calls per length.")
    ap.add_argument("--minutes", default="", help="Long logs (minutes at 100 Hz) smoothed in chunks, comma "
                                                  "separated, e.g. 6,60.")
    ap.add_argument("--chunk", type=int, default=2000, help="States per window of the long logs.")
    ap.add_argument("--overlap", type=int, default=1000, help="Samples each window adds before and after.")
    ap.add_argument("--one-long", type=float, help=argparse.SUPPRESS)  # a child of --minutes
    a = ap.parse_args()
    if a.one_long is not None:
        json.dump(one_long_log(a.one_long, a.chunk or None, a.overlap), sys.stdout)
        return
    lengths = [int(v) for v in a.lengths.split(",") if v]
    lag_list = [int(v) for v in a.lags.split(",") if v]
    short = [lag for lag in lag_list if a.lag_samples < lag + MIN_WINDOWS]
    if short:  # no window, or too few to time after the first ones (which compile)
        ap.error(f"--lag-samples: expected at least lag + {MIN_WINDOWS} samples for every lag of --lags (the "
                 f"first window comes after lag + 1 samples), got {a.lag_samples} for lag(s) {short}")
    rows = [whole_log(n, a.repeats) for n in lengths]
    for r in rows:
        r["per_sample_over_shortest"] = r["smoother_us_per_sample"] / rows[0]["smoother_us_per_sample"]
    lags = [fixed_lag(lag, a.lag_samples) for lag in lag_list]
    long = long_logs([float(v) for v in a.minutes.split(",")], a.chunk, a.overlap) if a.minutes else []
    json.dump({"benchmark": "smoother", "source": source_version(), "machine": {
        "cpu": cpu_model(), "loadavg": os.getloadavg(), "python": sys.version.split()[0]},
        "whole_log": rows, "fixed_lag": lags, "long_logs_in_chunks": long}, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
