"""What a user waits for on a ready system's first call, and what the process spends: every ready system's
default ``MinimumEnergyFilter`` on the C engine, each in a fresh process into an empty kernel cache (and no JAX
persistent cache of the user's), on one core; then twice more with the caches that process left: the kernel
alone (``warm``), and the kernel with XLA's programs (``warm_xla``, as a second ``liemef`` command runs).

Per system and process it prints, as one JSON document:

* ``first_result_s``: from the filter's construction to its first ``run``'s result on a log of ``--samples``
  samples around a random state (trace, translation to C, the quick ``-O0`` build and the run);
* ``process_s``: the whole process, from its start to its exit (the import, the first result and, if it started,
  the wait for the ``-O2`` build, which a process that ends while it is being built waits for);
* ``cpu_s``: its CPU time with its children's (the C compiler), and ``optimized_builds``: how many ``-O2``
  libraries it left in the kernel cache (none where the quick build served less than
  ``liemef.codegen._kernel.OPTIMIZE_AFTER_S`` of calls);
* ``loadavg_1min`` before and after the run, and the CPU model.

Issue 36's target for the first result is 2 s. Figures of one run on a shared machine: compare the systems with
each other, not absolute numbers across runs.

    python benchmarks/bench_first_call.py [--samples 2000] [--only tse2,attitude]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import cpu_model, one_core  # noqa: E402


def one(name: str, samples: int) -> dict:
    """In this process: the first call of the ready system ``name`` (module docstring)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import liemef
    from liemef.studies.experiments import SYSTEMS

    t0 = time.perf_counter()
    flt = liemef.MinimumEnergyFilter(SYSTEMS[name].make())
    sysm, rng = flt.system, np.random.default_rng(0)
    G = sysm.group
    q = 0.3 * rng.standard_normal(G.coords_dim)
    ts = 0.01 * np.arange(samples, dtype=float)
    us = 0.2 * rng.standard_normal((samples, sysm.input_dim))
    ys = np.asarray(sysm.output(G.from_coords(jnp.asarray(q)), 0.0)) + 0.05 * rng.standard_normal(
        (samples, sysm.output_dim))
    state = flt.init(G.from_coords(jnp.asarray(q + 0.1 * rng.standard_normal(G.coords_dim))), np.eye(flt.n))
    traj = jax.block_until_ready(flt.run(state, ts, us, ys, engine="c"))
    return {"first_result_s": round(time.perf_counter() - t0, 3), "ok": bool(traj.ok)}


def _process(name: str, samples: int, env: dict) -> dict:
    """One child process for ``name`` with ``env``: its own figures, its wall and CPU time and the load."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, __file__, "--one", name, "--samples", str(samples)], capture_output=True,
                          text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    return {**out, "process_s": round(wall, 3),
            "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 3),
            "loadavg_1min": [round(load, 2), round(os.getloadavg()[0], 2)]}


def measure(name: str, samples: int) -> dict:
    """``name`` in three fresh processes sharing one cache folder, empty at first: ``cold`` (no kernel, no XLA
    program on disk; as the command line runs, it keeps XLA's programs), then ``warm`` (the kernel on disk, XLA's
    program cache off: each eager operation compiled again) and ``warm_xla`` (the kernel and XLA's programs on
    disk, as a second ``liemef`` command finds them)."""
    cache = tempfile.mkdtemp(prefix="liemef-bench-first-")
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["LIEMEF_CACHE_DIR"] = cache
    cold = _process(name, samples, {**env, "LIEMEF_XLA_CACHE": "1"})
    if "error" in cold:
        return cold
    cold["optimized_builds"] = len([f for f in os.listdir(cache) if f.startswith("kernel_") and f.endswith(".so")])
    return {"cold": cold, "warm": _process(name, samples, {**env, "LIEMEF_XLA_CACHE": "0"}),
            "warm_xla": _process(name, samples, {**env, "LIEMEF_XLA_CACHE": "1"})}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2000, help="samples of each system's log (default 2000)")
    ap.add_argument("--only", default=None, help="comma-separated ready systems (default: all)")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # the child process's system
    args = ap.parse_args(argv)
    if args.samples < 2:
        ap.error(f"--samples: expected at least 2 samples, got {args.samples}")
    if args.one is not None:
        one_core(fresh_kernel_cache=False)  # before JAX starts; the parent made this process's empty cache
        print(json.dumps(one(args.one, args.samples)), flush=True)
        return
    from liemef.studies.experiments import SYSTEMS

    names = sorted(SYSTEMS) if args.only is None else [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in SYSTEMS]
    if unknown:
        ap.error(f"--only: expected ready systems among {', '.join(sorted(SYSTEMS))}, got {', '.join(unknown)}")
    systems = {}
    for name in names:
        systems[name] = measure(name, args.samples)
        print(f"{name}: {systems[name]}", file=sys.stderr, flush=True)
    print(json.dumps({"samples": args.samples, "cpu": cpu_model(), "systems": systems}, indent=1))


if __name__ == "__main__":
    main()
