"""Speed of the TSE(2) experiment (Rigo et al. 2022): 50 s at 1 ms, 50,000 steps, on one core.

Prints one JSON document: compile time, run time without compile and microseconds per step of ``run`` for
RKMK4 and Lie-Euler (second order) and for the first-order filter, and the latency of one online ``step``
call fed numpy arrays, as a robot loop would (``flt.step``, a FilterState in and out, and ``flt.online(state).step``,
the state kept in C between calls). Both by the default engine (``engine``: "c" where a C compiler is
found, the filter's interval as a compiled C kernel) and, for RKMK4, by XLA (``*_xla``). The C engine's compile
is measured twice: the first build (``run_rkmk4.compile_s``: trace, translation and C compiler at -O0, into a
fresh kernel cache, until the first result; ``optimized_build_s``: until the -O2 build, compiled beside it,
serves) and in a new process that finds the kernel on disk (``compile_new_process``: the trace only).
Figures from one run on a shared machine: compare the ratios printed here, measured together, rather than
absolute numbers across runs; the ``cpu_`` figures (process CPU time) leave out the time spent waiting for a
busy core.

The yardstick (issue 9): a hand-written C99 step of the same filter from the closed forms
(``c/tse2_reference.c``, built by ``c_reference.py`` with the system C compiler, ``$CC`` or ``cc``, at -O2
-march=native -mno-fma on x86-64, the flags of the C engine's kernel), timed on the same log in the same run.
Its microseconds per step for RKMK4 and Lie-Euler are the ``c_reference`` section, and ``ratios`` gives every
speed figure over it (``*_over_c``): ``run`` RKMK4 and its first-order variant over the C RKMK4, ``run``
Lie-Euler over the C Lie-Euler, one ``step`` call over the C RKMK4 step. Without a C compiler the section says
so and the benchmark goes on without those ratios.

The ``export_c`` section times ``liemef export-c``'s C for the same filter (second order, RKMK4, adaptive
sub-steps, health checks), built with the same compiler and flags, alternately with the reference on the same
log, and one online step through ctypes. ``c_reference.generic`` repeats both at plain -O2 (x86-64's SSE2
baseline), where two-operand instructions cost the generated code more than the hand-written.

Targets (issue 9, one core): ``run`` RKMK4 <= 8x the C reference per step; <= 25 us per ``step`` call;
compile of ``run`` < 2 s; the exported C within 2x of the reference.

    python benchmarks/bench_tse2.py [--duration 50] [--calls 2000]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

# One core, before JAX starts its thread pools.
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                           " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

# a fresh kernel cache: the first run's compile is a first build (trace, translation, C compiler)
os.environ["LIEMEF_CACHE_DIR"] = tempfile.mkdtemp(prefix="liemef-bench-kernels-")

import liemef  # noqa: E402
from liemef import codegen  # noqa: E402
from liemef.codegen import _kernel  # noqa: E402
from liemef.simulation import simulate  # noqa: E402
from liemef.systems import PlanarRigidBody, tse2_state  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import c_reference  # noqa: E402


def tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50))
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def time_run(flt, state, log, repeats=3, engine=None):
    args = (state, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys))
    t0 = time.perf_counter()
    jax.block_until_ready(flt.run(*args, engine=engine))  # compile + first run
    first = time.perf_counter() - t0
    kern = liemef.engines.kernel(flt, engine)
    if kern is not None:  # the C engine's first build is quick (-O0): time runs by its -O2 build
        kern.wait()
    built = time.perf_counter() - t0
    runs, cpus = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        traj = jax.block_until_ready(flt.run(*args, engine=engine))
        runs.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    assert bool(traj.ok), "the benchmark run diverged"
    run_s = float(np.median(runs))
    steps = len(log.ts) - 1
    return {"compile_s": round(first - run_s, 3), "optimized_build_s": round(built - run_s, 3) if kern else None,
            "run_s": round(run_s, 4),
            "us_per_step": round(run_s / steps * 1e6, 3),
            "cpu_us_per_step": round(float(np.median(cpus)) / steps * 1e6, 3), "steps": steps}


def time_step(flt, state, log, calls, engine=None):
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    dt = float(ts[1] - ts[0])
    st = jax.block_until_ready(flt.step(state, float(ts[0]), us[0], ys[0], dt, engine=engine))  # compile
    # XLA dispatches asynchronously: its latency includes the wait for the result; the C engine returns NumPy
    wait = jax.block_until_ready if liemef.engines.kernel(flt, engine) is None else (lambda x: x)
    lat, cpu = np.empty(calls), np.empty(calls)
    for k in range(calls):
        c0, t0 = time.process_time(), time.perf_counter()
        st = flt.step(st, float(ts[k]), us[k], ys[k], dt, engine=engine)
        wait(st.K)
        lat[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
    return {"median_us": round(float(np.median(lat)) * 1e6, 2), "p90_us": round(float(np.quantile(lat, 0.9)) * 1e6, 2),
            "cpu_median_us": round(float(np.median(cpu)) * 1e6, 2), "calls": calls}


def time_online(flt, state, log, calls):
    """One ``OnlineFilter.step`` call (``flt.online(state)``: the state kept in C between calls), fed numpy."""
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    dt = float(ts[1] - ts[0])
    online = flt.online(state)
    online.step(float(ts[0]), us[0], ys[0], dt)
    lat, cpu = np.empty(calls), np.empty(calls)
    for k in range(calls):
        c0, t0 = time.process_time(), time.perf_counter()
        code = online.step(float(ts[k]), us[k], ys[k], dt)
        lat[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
    assert code == 0, "the online benchmark filter failed"
    return {"median_us": round(float(np.median(lat)) * 1e6, 2), "p90_us": round(float(np.quantile(lat, 0.9)) * 1e6, 2),
            "cpu_median_us": round(float(np.median(cpu)) * 1e6, 2), "calls": calls}


NATIVE = _kernel.NATIVE
"""The flags the C engine's kernel adds (``liemef.codegen._kernel.KERNEL_CFLAGS``): the host's instruction set,
without fused multiply-adds."""


def time_c_reference(log, g0, repeats=5):
    """The C reference (c_reference.py) and liemef's exported C (``liemef export-c`` of the same filter, built with the
    same compiler and flags) on the same log, timed alternately, with two flag sets: ``-O2`` with :data:`NATIVE`
    (the host's instructions, as the C engine's kernel is built and as a robot's build targets its CPU; the
    yardstick of every ratio) and plain ``-O2`` (x86-64's baseline, SSE2: ``generic``). Build times and median us
    per step (RKMK4 and Lie-Euler for the reference, RKMK4 for the export); ``{"available": False, "reason":
    ...}`` without a C compiler or if a build fails."""
    if c_reference.compiler() is None:
        return {"available": False, "reason": "no C compiler ($CC or cc)"}
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    g0_leaves = np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(g0)])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        try:
            libs = {"native": c_reference.load(c_reference.build(tmp, NATIVE)),
                    "generic": c_reference.load(c_reference.build(tmp))}
        except RuntimeError as err:
            return {"available": False, "reason": str(err)}
        build_s = time.perf_counter() - t0
        flt = liemef.MinimumEnergyFilter(PlanarRigidBody())
        t0 = time.perf_counter()
        exported = codegen.export_c(flt, tmp, name="tse2_export")
        t1 = time.perf_counter()
        cflts = {"native": codegen.CFilter(exported, flags=("-std=c99", "-O2", *NATIVE)),
                 "generic": codegen.CFilter(exported, flags=("-std=c99", "-O2"))}
        t2 = time.perf_counter()
        figures = {}
        for label, lib in libs.items():
            ref, exp = [], []
            for _ in range(repeats):
                ref.append(c_reference.time_per_step(lib, "rkmk4", ts, us, ys, g0, np.eye(6), repeats=1))
                cflts[label].init(g0_leaves, np.eye(6))
                c0 = time.perf_counter()
                code, _, _ = cflts[label].run(ts, us, ys)
                exp.append((time.perf_counter() - c0) / (len(ts) - 1) * 1e6)
                assert code == 0, "the exported filter failed on the benchmark log"
            figures[label] = {"flags": " ".join(c_reference.FLAGS + (NATIVE if label == "native" else ())),
                              "rkmk4_us_per_step": round(float(np.median(ref)), 4),
                              "lie_euler_us_per_step": round(c_reference.time_per_step(
                                  lib, "lie-euler", ts, us, ys, g0, np.eye(6), repeats=repeats), 4),
                              "export_c_rkmk4_us_per_step": round(float(np.median(exp)), 4)}
        # one online step of the export through ctypes, fed numpy arrays (the call overhead of Python included)
        cflt = cflts["native"]
        cflt.init(g0_leaves, np.eye(6))
        lat = []
        for k in range(min(2000, len(ts) - 1)):
            c0 = time.perf_counter()
            cflt.step(ts[k], ts[k + 1] - ts[k], us[k], ys[k])
            lat.append(time.perf_counter() - c0)
        source_lines = sum(1 for _ in open(exported.source))
    nat = figures["native"]
    return {"available": True, "compiler": " ".join(c_reference.compiler()), "flags": nat["flags"],
            "build_s": round(build_s, 3), "rkmk4_us_per_step": nat["rkmk4_us_per_step"],
            "lie_euler_us_per_step": nat["lie_euler_us_per_step"], "generic": figures["generic"],
            "export_c": {"export_s": round(t1 - t0, 3), "build_s": round(t2 - t1, 3),
                         "flags": "-std=c99 -O2 " + " ".join(NATIVE),
                         "source_lines": source_lines,
                         "rkmk4_us_per_step": nat["export_c_rkmk4_us_per_step"],
                         "step_call_ctypes_median_us": round(float(np.median(lat)) * 1e6, 2)}}


WARM = """
import json, time
import numpy as np
t0 = time.perf_counter()
import liemef
from liemef.systems import PlanarRigidBody, tse2_state
flt = liemef.MinimumEnergyFilter(PlanarRigidBody())
g0 = tse2_state(0.3, 1.0, 2.0, 0.1, 0.2, 0.0)
state = flt.init(g0, np.eye(6))
ts = np.arange(101) * 1e-3
us = np.zeros((101, 2))
ys = np.tile(np.asarray(flt.system.output(g0, 0.0)), (101, 1))
t1 = time.perf_counter()
flt.run(state, ts, us, ys)
t2 = time.perf_counter()
flt.run(state, ts, us, ys)
t3 = time.perf_counter()
print(json.dumps({"import_s": round(t1 - t0, 3), "compile_s": round((t2 - t1) - (t3 - t2), 3)}))
"""


def compile_in_new_process() -> dict:
    """The compile time of ``run`` (C engine) in a new Python process whose kernel is on disk already (this
    benchmark built it): the trace of the interval and the load of the library."""
    out = subprocess.run([sys.executable, "-c", WARM], capture_output=True, text=True, env=os.environ.copy())
    if out.returncode != 0:
        return {"error": out.stderr[-2000:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=50.0)
    ap.add_argument("--calls", type=int, default=2000)
    args = ap.parse_args()

    system = PlanarRigidBody()
    ts = np.arange(int(round(args.duration / 1e-3)) + 1) * 1e-3
    _, log = simulate(system, tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0), tse2_input, ts, jax.random.PRNGKey(0))
    g0 = tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1)

    results = {"engine": liemef.engines.engine_of(None)}
    for name, kw in [("rkmk4", dict(integrator="rkmk4")), ("lie_euler", dict(integrator="lie-euler")),
                     ("rkmk4_first_order", dict(integrator="rkmk4", order="first"))]:
        flt = liemef.MinimumEnergyFilter(system, **kw)
        results[f"run_{name}"] = time_run(flt, flt.init(g0, np.eye(6)), log)
    results["compile_new_process"] = compile_in_new_process()
    flt = liemef.MinimumEnergyFilter(system)
    results["run_rkmk4_xla"] = time_run(flt, flt.init(g0, np.eye(6)), log, engine="xla")
    results["step_rkmk4_numpy"] = time_step(flt, flt.init(g0, np.eye(6)), log, args.calls)
    results["online_step_rkmk4_numpy"] = time_online(flt, flt.init(g0, np.eye(6)), log, args.calls)
    results["step_rkmk4_numpy_xla"] = time_step(flt, flt.init(g0, np.eye(6)), log, min(args.calls, 300),
                                                engine="xla")
    results["c_reference"] = c = time_c_reference(log, g0)

    r = results
    results["ratios"] = {
        "rkmk4_over_lie_euler": round(r["run_rkmk4"]["us_per_step"] / r["run_lie_euler"]["us_per_step"], 2),
        "second_over_first_order": round(r["run_rkmk4"]["us_per_step"] / r["run_rkmk4_first_order"]["us_per_step"], 2),
        "step_call_over_run_step": round(r["step_rkmk4_numpy"]["median_us"] / r["run_rkmk4"]["us_per_step"], 2),
    }
    if c["available"]:
        results["ratios"].update({
            "run_rkmk4_over_c": round(r["run_rkmk4"]["us_per_step"] / c["rkmk4_us_per_step"], 2),
            "run_rkmk4_xla_over_c": round(r["run_rkmk4_xla"]["us_per_step"] / c["rkmk4_us_per_step"], 2),
            "step_call_xla_over_c": round(r["step_rkmk4_numpy_xla"]["median_us"] / c["rkmk4_us_per_step"], 2),
            "run_lie_euler_over_c": round(r["run_lie_euler"]["us_per_step"] / c["lie_euler_us_per_step"], 2),
            "run_rkmk4_first_order_over_c": round(r["run_rkmk4_first_order"]["us_per_step"] / c["rkmk4_us_per_step"],
                                                  2),
            "step_call_over_c": round(r["step_rkmk4_numpy"]["median_us"] / c["rkmk4_us_per_step"], 2),
            "online_step_call_over_c": round(r["online_step_rkmk4_numpy"]["median_us"] / c["rkmk4_us_per_step"], 2),
            "export_c_rkmk4_over_c": round(c["export_c"]["rkmk4_us_per_step"] / c["rkmk4_us_per_step"], 2),
            "export_c_rkmk4_over_c_generic": round(c["generic"]["export_c_rkmk4_us_per_step"]
                                                   / c["generic"]["rkmk4_us_per_step"], 2),
            "export_c_step_call_over_c": round(c["export_c"]["step_call_ctypes_median_us"] / c["rkmk4_us_per_step"],
                                               2),
        })
    results["targets"] = {
        "run_rkmk4_over_c<=8": r["run_rkmk4"]["us_per_step"] <= 8 * c["rkmk4_us_per_step"] if c["available"] else None,
        "step_call_us<=25 (flt.step: a FilterState in and out)": r["step_rkmk4_numpy"]["median_us"] <= 25,
        "step_call_us<=25 (flt.online(state).step)": r["online_step_rkmk4_numpy"]["median_us"] <= 25,
        "compile_s<2 (first build, kernel cache empty)": r["run_rkmk4"]["compile_s"] < 2,
        "compile_s<2 (new process, kernel on disk)": r["compile_new_process"].get("compile_s", 1e9) < 2,
        "export_c_over_c<=2 (both -O2 -march=native -mno-fma)":
        c["export_c"]["rkmk4_us_per_step"] <= 2 * c["rkmk4_us_per_step"] if c["available"] else None,
        "export_c_over_c<=2 (both -O2, generic x86-64)": c["generic"]["export_c_rkmk4_us_per_step"]
        <= 2 * c["generic"]["rkmk4_us_per_step"] if c["available"] else None,
    }
    results["machine"] = {"python": platform.python_version(), "jax": jax.__version__, "liemef": liemef.__version__,
                          "cores_used": 1, "loadavg_1min": round(os.getloadavg()[0], 2)}
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
