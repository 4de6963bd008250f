"""What every speed benchmark shares: one core before JAX starts, a fresh kernel cache, timing a filter's
``run`` (first call, then the median of further runs by the -O2 kernel), and the CPU model to print beside
the figures."""

from __future__ import annotations

import os
import platform
import tempfile
import time


def one_core(fresh_kernel_cache: bool = True) -> None:
    """Pin this process to one core and keep XLA to one thread (call before importing JAX). With
    ``fresh_kernel_cache``, the C engine builds into a new empty kernel cache, so a first call is a first build
    (trace, translation and the C compiler)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                               " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()
    if fresh_kernel_cache:
        os.environ["LIEMEF_CACHE_DIR"] = tempfile.mkdtemp(prefix="liemef-bench-kernels-")


def time_run(flt, args, engine, repeats: int) -> dict:
    """``flt.run(*args, engine=engine)``: the first call (s, until its result: trace, translation and the quick
    -O0 build, or XLA's compilation) and the median us per sample interval of ``repeats`` further runs (by C:
    the -O2 build, waited for). Raises if the run failed: a benchmark of a failed run measures nothing."""
    import jax
    import numpy as np

    import liemef

    t0 = time.perf_counter()
    traj = jax.block_until_ready(flt.run(*args, engine=engine))
    first = time.perf_counter() - t0
    if not bool(traj.ok):
        raise RuntimeError(f"{flt!r} by {engine} failed: {traj.status.message()}")
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


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``) with its family and model numbers (a VM may name only "AMD EPYC":
    family 23 is Zen 1 and 2, 25 Zen 3 and 4), else what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo") as fh:
            info = {}
            for ln in fh:
                if not ln.strip():
                    break  # the first CPU's block
                key, _, value = ln.partition(":")
                info.setdefault(key.strip(), value.strip())
    except OSError:
        return platform.processor() or platform.machine()
    name = info.get("model name") or platform.processor() or platform.machine()
    ids = [f"{k} {info[k]}" for k in ("cpu family", "model", "stepping") if k in info]
    return f"{name} ({', '.join(ids)})" if ids else name
