"""Batched throughput of the TSE(2) filter (issue 9): trial-steps per second against the batch size, on every core.

The Monte Carlo workload of Rigo et al. 2022's experiment: second order, RKMK4 with adaptive sub-steps, the
(0)-connection, 1 ms samples; each trial its own simulated log and initial state. Three figures per batch size B:

* ``c``: :meth:`liemef.MinimumEnergyFilter.run_batch` by the C engine, the trials shared among the cores
  (``threads``) in SIMD groups of 4 (the batch kernel, ``liemef.codegen._kernel``), every ``keep_every``-th
  state kept; the median of ``--repeats`` calls;
* ``xla``: the same call by the XLA engine (``vmap`` of ``scan``; compile excluded), for B <= 64;
* ``simulation``: the logs' simulation (``jax.vmap`` of ``simulate_core``, XLA), for scale.

``montecarlo`` is the end-to-end command ``liemef montecarlo tse2`` (simulation, filter by the C engine through
``scan(engine=None)``, error statistics), second call (compile excluded). ``memory`` is the bytes a trial
holds: its kept states (packed, 8 bytes a number) and its log. The target (issue 22): the filter at >= 4e6
trial-steps/s on the 2 cores, decided on the median of the ``--repeats`` calls (``c_trial_steps_per_s``; the
fastest call's figure is ``c_trial_steps_per_s_best``). Figures from one run on a shared machine;
``loadavg_1min`` says how shared. ``--quick`` times only the C engine on 256 trials of 2 s (no XLA, no
``montecarlo``): the figure ``bench_tse2.py`` reports. Beside it, per batch size, the C calls alone
(``c_kernel_trial_steps_per_s``: ``Kernel.batch``, no Python before or after, the -O2 kernel waited for), on
one thread (``thread_scaling`` the ratio) and their CPU time per trial-step (``*_cpu_us_per_trial_step``).

On an AMD EPYC of the first Zen generation (2 cores) the target is out of reach with the same numbers: its
floating-point units are 128 bits wide, so a group of 4 AVX2 lanes does at best twice a scalar trial's
arithmetic per instruction; the batch kernel is at 2.5x the scalar kernel per trial, 0.71 us of CPU a
trial-step (at most 2.8e6 trial-steps/s on two cores). The breakdown: ``docs/performance.md``, "Where the
batch's time goes".

    python benchmarks/bench_batch.py [--duration 5] [--batches 1 4 16 64 256] [--keep-every 10] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import liemef
from liemef.simulation import simulate_core
from liemef.studies.experiments import montecarlo
from liemef.studies.experiments._montecarlo import resolve_experiment
from liemef.systems import PlanarRigidBody, tse2_state

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import cpu_model  # noqa: E402


def tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50))
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def logs(system, ts, B, seed=0):
    """B simulated logs (the nominal truth of the experiment, the sensors' noise drawn per trial) and B perturbed
    initial estimates."""
    sim = jax.jit(jax.vmap(lambda k: simulate_core(system, tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0),
                                                   tse2_input, jnp.asarray(ts), k)[1]))
    keys = jax.random.split(jax.random.PRNGKey(seed), B)
    jax.block_until_ready(sim(keys))  # compile
    t0 = time.perf_counter()
    log = jax.block_until_ready(sim(keys))
    sim_s = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    q0 = np.array([np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1]) + 0.05 * rng.standard_normal((B, 6))
    return np.asarray(log.us), np.asarray(log.ys), q0, sim_s


def kernel_only(flt, states, ts, us, ys, keep_every, threads, repeats) -> dict:
    """The C calls alone (``Kernel.batch``: the trials' threads and SIMD groups, no Python before or after),
    on ``threads`` threads and on one: the fastest of ``repeats`` calls each. The -O2 kernel is waited for
    first (on a fresh kernel cache it builds in the background, on a core the timing would share), and
    whether the SIMD groups serve is said (``lanes``; else why not). ``*_cpu_us_per_trial_step``: the
    process's CPU time per trial-step (every thread's), which a shared machine moves less than wall time."""
    kern = liemef.engines.kernel(flt, "c").wait()
    B, steps = us.shape[0], len(ts) - 1
    x = np.stack([kern.pack(jax.tree_util.tree_map(lambda a, b=b: np.asarray(a)[b], states)) for b in range(B)])
    theta, us, ys = kern.theta(flt), np.ascontiguousarray(us, np.float64), np.ascontiguousarray(ys, np.float64)
    out = {"lanes": kern.lanes() is not None, "lanes_error": kern.lanes_error, "kernel_optimized": kern.optimized}
    for name, th in (("c_kernel", threads), ("c_kernel_1thread", 1)):
        times, cpu = [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            kern.batch(theta, x, ts, us, ys, np.inf, keep_every, threads=th)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        out[f"{name}_trial_steps_per_s"] = round(B * steps / min(times))
        out[f"{name}_cpu_us_per_trial_step"] = round(min(cpu) / (B * steps) * 1e6, 4)
    out["thread_scaling"] = round(out["c_kernel_trial_steps_per_s"] / out["c_kernel_1thread_trial_steps_per_s"], 3)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 4, 16, 64, 256])
    ap.add_argument("--keep-every", type=int, default=10)
    ap.add_argument("--xla-max", type=int, default=64, help="largest batch also timed with the XLA engine")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls of the C engine per batch (the median)")
    ap.add_argument("--quick", action="store_true", help="the C engine on 256 trials of 2 s only")
    args = ap.parse_args()
    if args.quick:
        args.duration, args.batches, args.xla_max = 2.0, [256], 0

    system = PlanarRigidBody()
    flt = liemef.MinimumEnergyFilter(system)
    ts = np.arange(int(round(args.duration / 1e-3)) + 1) * 1e-3
    steps = len(ts) - 1
    threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    rows = []
    for B in args.batches:
        us, ys, q0, sim_s = logs(system, ts, B)
        states = jax.tree_util.tree_map(lambda *a: jnp.stack(a),
                                        *[flt.init(tse2_state(*q), np.eye(6)) for q in q0])
        row = {"batch": B, "simulation_trial_steps_per_s": round(B * steps / sim_s)}
        for engine in ("c", "xla"):
            if engine == "xla" and B > args.xla_max:
                continue
            flt.run_batch(states, ts[:3], us[:, :3], ys[:, :3], engine=engine, keep_every=1)  # build / compile
            if engine == "c":
                row.update(kernel_only(flt, states, ts, us, ys, args.keep_every, threads, args.repeats))
            if engine == "xla":
                jax.block_until_ready(flt.run_batch(states, ts, us, ys, engine=engine, keep_every=args.keep_every))
            times = []
            for _ in range(args.repeats if engine == "c" else 1):
                t0 = time.perf_counter()
                traj = jax.block_until_ready(flt.run_batch(states, ts, us, ys, engine=engine,
                                                           keep_every=args.keep_every))
                times.append(time.perf_counter() - t0)
            dt = float(np.median(times))
            assert np.all(np.asarray(traj.status.code) == 0), "a benchmark trial failed"
            row[f"{engine}_trial_steps_per_s"] = round(B * steps / dt)
            if engine == "c":
                row["c_trial_steps_per_s_best"] = round(B * steps / min(times))
                row["c_trial_steps_per_s_all"] = [round(B * steps / x) for x in times]
            row[f"{engine}_us_per_trial_step"] = round(dt / (B * steps) * 1e6, 4)
        rows.append(row)
        print(json.dumps(row), flush=True)

    kern_state = flt.init(tse2_state(0, 0, 0, 0, 0, 0), np.eye(6))
    n_state = sum(np.size(x) for x in jax.tree_util.tree_leaves(kern_state))
    kept = 1 + steps // args.keep_every
    memory = {"state_numbers": int(n_state),
              "kept_states_bytes_per_trial": int(kept * n_state * 8),
              "all_states_bytes_per_trial": int((steps + 1) * n_state * 8),
              "log_bytes_per_trial": int((steps + 1) * (system.input_dim + system.output_dim) * 8)}

    mc = None
    if not args.quick:
        exp = resolve_experiment("tse2")
        cfg = exp.config(duration=args.duration)
        mc_runs, mc_batch = 256, 64
        montecarlo(exp, cfg, runs=mc_batch, batch_size=mc_batch, progress=False)  # compile
        t0 = time.perf_counter()
        montecarlo(exp, cfg, runs=mc_runs, batch_size=mc_batch, progress=False)
        mc_s = time.perf_counter() - t0
        mc = {"runs": mc_runs, "batch_size": mc_batch, "seconds": round(mc_s, 3),
              "trial_steps_per_s": round(mc_runs * steps / mc_s)}

    best = max(r["c_trial_steps_per_s"] for r in rows)  # the best batch size's median
    out = {"steps_per_trial": steps, "keep_every": args.keep_every, "threads": threads, "batches": rows,
           "memory": memory, "montecarlo": mc, "best_filter_trial_steps_per_s": best,
           "targets": {"filter_trial_steps_per_s>=4e6": best >= 4e6, "best_filter_trial_steps_per_s": best},
           "machine": {"python": platform.python_version(), "jax": jax.__version__, "liemef": liemef.__version__,
                       "cores": threads, "cpu_model": cpu_model(), "loadavg_1min": round(os.getloadavg()[0], 2)}}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
