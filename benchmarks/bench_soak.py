"""Soak: one hour at 1 kHz (3.6 million steps) of the TSE(2) paper filter, simulated and filtered chunk by chunk.

The planar rigid body of Rigo et al. 2022 (GPS + IMU, second order, (0)-connection, RKMK4, K0 = I, the paper's
input u = (sin t, 50 sin(t / 50))) is simulated one chunk at a time (``--chunk-seconds``, default 60 s = 60,000
samples), each chunk continuing from the previous chunk's last truth state with its own key
(``fold_in(key, chunk)``), and filtered by ``run(..., keep_every=1000)`` from the previous chunk's
``traj.final``. Nothing grows with the log: memory must stay flat and all chunks share one compilation.

Prints one JSON document: the drift of the group constraint of the estimate (SE(2) stores (cos, sin, x, y):
``|cos^2 + sin^2 - 1|``), the asymmetry ``max|K - K^T|`` and the smallest eigenvalue of K over the decimated
history and at the end, the status (must be ok), the estimation error at the end against the truth, the peak
RSS after the first chunk and at the end (flat: ratio ~1), wall times and the compile count of ``run``.
Progress goes to stderr, one line per chunk. Nothing here asserts a time.

    python benchmarks/bench_soak.py [--minutes 60] [--chunk-seconds 60]   # the hour (11 min on a busy core)
    python benchmarks/bench_soak.py --minutes 2                          # smoke test, 1-2 min (compilation)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import sys
import time

# One core, before JAX starts its thread pools (as bench_tse2.py).
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                           " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

import liemef  # noqa: E402
from liemef.engines import bucket
from liemef.filters import TRACES  # noqa: E402
from liemef.groups import SE2, SO2, SO3, Product  # noqa: E402
from liemef.metrics import state_error  # noqa: E402
from liemef.systems import PlanarRigidBody, tse2_state  # noqa: E402

DT = 1e-3


def tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50))
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def constraint_drift(g) -> float:
    """Largest violation of the group's storage constraint over the elements of ``g`` (any batch shape): unit
    (cos, sin) for SO(2) and SE(2), unit quaternion for SO(3); vector groups have none (0)."""
    if isinstance(g, Product):
        return max(constraint_drift(f) for f in g.factors)
    if isinstance(g, SE2 | SO2):
        cs = np.asarray(g.cos_sin_xy[..., :2] if isinstance(g, SE2) else g.cos_sin)
        return float(np.max(np.abs(np.sum(cs**2, axis=-1) - 1.0)))
    if isinstance(g, SO3):
        return float(np.max(np.abs(np.linalg.norm(np.asarray(g.wxyz), axis=-1) - 1.0)))
    return 0.0


def gain_health(K) -> tuple[float, float]:
    """``max|K - K^T|`` and the smallest eigenvalue of sym(K), over a stack of gains (..., n, n)."""
    K = np.asarray(K).reshape((-1,) + np.shape(K)[-2:])
    asym = float(np.max(np.abs(K - np.swapaxes(K, -1, -2))))
    eig = float(np.min(np.linalg.eigvalsh(0.5 * (K + np.swapaxes(K, -1, -2)))))
    return asym, eig


def rss_mb() -> tuple[float, float]:
    """(peak RSS, current RSS) of this process in MB (Linux: ru_maxrss in KB)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    cur = math.nan
    try:
        with open("/proc/self/statm") as f:
            cur = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        pass
    return peak, cur


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="simulated duration (default 60: 3.6 M steps)")
    ap.add_argument("--chunk-seconds", type=float, default=60.0, help="chunk length (default 60 s = 60,000 samples)")
    ap.add_argument("--keep-every", type=int, default=1000, help="keep every M-th state of a chunk (default 1000)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = int(round(args.chunk_seconds / DT))  # intervals per chunk
    n_chunks = int(round(args.minutes * 60.0 / args.chunk_seconds))
    if n < 1 or n_chunks < 1 or not math.isclose(n_chunks * args.chunk_seconds, args.minutes * 60.0):
        ap.error(f"--minutes {args.minutes} must be a positive multiple of --chunk-seconds {args.chunk_seconds}")
    M = args.keep_every

    load0 = os.getloadavg()[0]
    source = source_version()  # at the start: the code this process imported
    wall0 = time.perf_counter()
    system = PlanarRigidBody()
    flt = liemef.MinimumEnergyFilter(system, connection="zero", order="second", integrator="rkmk4")
    g_true = tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0)
    state = flt.init(tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1), np.eye(6))
    key = jax.random.key(args.seed)
    traces0 = TRACES["run"]

    drift_max, asym_max, eig_min, err_max_late = 0.0, 0.0, math.inf, np.zeros(6)
    sim_s, run_s, run_later_s, first_chunk_s, rss_first, timeline = 0.0, 0.0, 0.0, None, None, []
    status = state.status
    for c in range(n_chunks):
        tc = time.perf_counter()
        ts = (c * n + np.arange(n + 1)) * DT
        truth, log = liemef.simulate(system, g_true, tse2_input, ts, jax.random.fold_in(key, c))
        jax.block_until_ready(log.ys)
        t_sim = time.perf_counter() - tc
        tr = time.perf_counter()
        traj = flt.run(state, ts, log.us, log.ys, keep_every=M)
        jax.block_until_ready(traj.K)
        t_run = time.perf_counter() - tr
        status = traj.status
        if not status.ok:
            print(f"chunk {c}: {status.message()}", file=sys.stderr)
            break
        sim_s, run_s = sim_s + t_sim, run_s + t_run
        drift_max = max(drift_max, constraint_drift(traj.g_hat))
        asym, eig = gain_health(traj.K)
        asym_max, eig_min = max(asym_max, asym), min(eig_min, eig)
        err = np.abs(np.asarray(state_error(truth.g[::M], traj.g_hat)))
        if ts[0] >= 10.0:  # after the initial offset is corrected
            err_max_late = np.maximum(err_max_late, err.max(axis=0))
        state, g_true = traj.final, truth.g[-1]
        peak, cur = rss_mb()
        if c == 0:
            first_chunk_s, rss_first = time.perf_counter() - tc, (peak, cur)
        else:
            run_later_s += t_run
        timeline.append({"t_end_s": round(float(ts[-1]), 1), "rss_peak_mb": round(peak, 1),
                         "rss_now_mb": round(cur, 1), "run_us_per_step": round(t_run / n * 1e6, 2)})
        print(f"chunk {c + 1}/{n_chunks} t={ts[-1]:.0f}s sim {t_sim:.2f}s run {t_run:.2f}s "
              f"({t_run / n * 1e6:.1f} us/step) rss {cur:.0f}/{peak:.0f} MB drift {drift_max:.2e} "
              f"asym {asym_max:.1e} eig_min {eig_min:.3e}", file=sys.stderr, flush=True)

    final = state
    e_end = np.asarray(state_error(g_true, final.g_hat))
    asym_end, eig_end = gain_health(final.K)
    peak_end, cur_end = rss_mb()
    chunks_done = len(timeline)
    step = max(1, chunks_done // 12)
    results = {
        "setup": {"system": "PlanarRigidBody (Rigo et al. 2022, GPS + IMU)", "filter": repr(flt), "K0": "I6",
                  "dt_s": DT, "minutes": args.minutes, "chunk_seconds": args.chunk_seconds, "chunks": n_chunks,
                  "chunks_done": chunks_done, "steps": int(status.steps), "keep_every": M,
                  "bucket_per_chunk": -(-bucket(n) // M) * M, "seed": args.seed},
        "status": status.as_dict(),
        "group_constraint": {"what": "|cos^2 + sin^2 - 1| of the SE(2) factor of g_hat",
                             "max_over_history": drift_max, "end": constraint_drift(final.g_hat)},
        "gain": {"asymmetry_max_over_history": asym_max, "asymmetry_end": asym_end,
                 "min_eigenvalue_over_history": eig_min, "min_eigenvalue_end": eig_end,
                 "trace_end": float(np.trace(np.asarray(final.K)))},
        "error_end": {"theta_mrad": round(float(e_end[0]) * 1e3, 4), "x_mm": round(float(e_end[1]) * 1e3, 3),
                      "y_mm": round(float(e_end[2]) * 1e3, 3), "omega_mrad_s": round(float(e_end[3]) * 1e3, 4),
                      "vx_mm_s": round(float(e_end[4]) * 1e3, 3), "vy_mm_s": round(float(e_end[5]) * 1e3, 3)},
        "error_max_abs_after_10s": dict(zip(("theta_rad", "x_m", "y_m", "omega_rad_s", "vx_m_s", "vy_m_s"),
                                            (round(float(v), 5) for v in err_max_late), strict=True)),
        "memory": {"rss_peak_mb_after_first_chunk": round(rss_first[0], 1), "rss_peak_mb_end": round(peak_end, 1),
                   "rss_peak_ratio_end_over_first": round(peak_end / rss_first[0], 3),
                   "rss_now_mb_after_first_chunk": round(rss_first[1], 1), "rss_now_mb_end": round(cur_end, 1),
                   # creep once everything is compiled and allocated: over the second half of the chunks
                   "rss_now_growth_mb_per_chunk_second_half": round(
                       (cur_end - timeline[chunks_done // 2 - 1]["rss_now_mb"]) / (chunks_done - chunks_done // 2), 4)
                   if chunks_done >= 4 else None},
        "compile": {"run_traces": TRACES["run"] - traces0, "expected": 1},
        "time": {"wall_s": round(time.perf_counter() - wall0, 1), "first_chunk_s": round(first_chunk_s, 2),
                 "simulate_s": round(sim_s, 1), "run_s": round(run_s, 1),
                 "run_us_per_step_after_first_chunk": round(run_later_s / max(1, (chunks_done - 1) * n) * 1e6, 2),
                 "simulated_over_wall": round(chunks_done * args.chunk_seconds / (time.perf_counter() - wall0), 1)},
        "timeline": timeline[::step] + ([timeline[-1]] if (chunks_done - 1) % step else []),
        "machine": {"python": platform.python_version(), "jax": jax.__version__, "liemef": liemef.__version__,
                    "cores_used": 1, "source": source, "loadavg_1min_start": round(load0, 2),
                    "loadavg_1min_end": round(os.getloadavg()[0], 2)},
    }
    print(json.dumps(results, indent=2))
    return 0 if status.ok else 1


if __name__ == "__main__":
    sys.exit(main())
