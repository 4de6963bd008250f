"""Speed of the TSE(2) experiment (Rigo et al. 2022): 50 s at 1 ms, 50,000 steps, on one core.

Prints one JSON document: compile time, run time without compile and microseconds per step of ``run`` for
RKMK4 and Lie-Euler (second order) and for the first-order filter, and the latency of one online ``step``
call fed numpy arrays, as a robot loop would (``flt.step``, a FilterState in and out, and ``flt.online(state).step``,
the state kept in C between calls). Both by the default engine (``engine``: "c" where a C compiler is
found, the filter's interval as a compiled C kernel) and, for RKMK4, by XLA (``*_xla``). The C engine's compile
is measured twice: the first build (``run_rkmk4.compile_s``: trace, translation and C compiler at -O0, into a
fresh kernel cache, until the first result; ``optimized_build_s``: from then until the -O2 build serves, which
``Kernel.wait()`` starts: a first call this short never pays for it, ``OPTIMIZE_AFTER_S``) and in a new
process that finds the kernel on disk (``compile_new_process``: the trace only).
Every figure is repeated (``--repeats``, default 5) and reported as its minimum and median (``min``,
``median``, and ``all``); the targets are decided on the **median** of the repeats, so that one noisy repeat
decides nothing, and the minimum shows what the machine does when nothing interferes. On a shared machine
compare the ratios, measured together, rather than absolute numbers across runs; the ``cpu_`` figures
(process CPU time) leave out the time spent waiting for a busy core.

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

The first build is timed in new processes (``first_build``), each with an empty kernel cache: the first ``run``
of a 100-sample log (the interval's trace, its translation to C, the C compiler at -O0, the load, the run)
until its result, wall and CPU time (the process's and its compilers'). ``compile_new_process`` does the same
with the kernel on disk (the trace only). ``batch`` runs ``bench_batch.py --quick`` (256 trials of 2 s, both
cores, the batch kernel in SIMD groups of 4) in a subprocess free to use every core.

Targets (issue 22; on the median of the repeats; ``run``, ``step`` and the export on one core):

* ``run`` RKMK4 <= 3x the C reference per step, both built -O2 with the host's instructions (the reference
  with ``c_reference.FLAGS`` + :data:`NATIVE`, the kernel with ``KERNEL_CFLAGS``; ``machine`` prints both);
* ``flt.step`` (a FilterState in and out, numpy samples) <= 20 us per call;
* ``flt.online(state).step`` <= 5 us per call;
* the first build (empty kernel cache, new process) < 2 s;
* the exported C <= 2x the reference (same compiler and flags);
* batched throughput >= 4e6 trial-steps/s on the 2 cores (``bench_batch.py``).

Why the figures moved between machines and runs (issue 22). The targets were set on an AMD EPYC Zen 1 (family
23, 2 cores) and missed on a Zen 4 (family 25 model 17, AVX-512, 2 cores; a KVM guest), where ``run`` went
from 1.42x to 3.42x the reference and the export from about 1.7x to 2.13x:

* **The reference is vectorized, the generated code is not.** gcc vectorizes the reference's loops (K E K row
  by row, 4 doubles to an AVX2 instruction); the generated step is straight-line scalar code (no packed
  arithmetic at all in its core: about 3,700 scalar operations a step, and 2,200 spill loads and stores).
  Zen 1 executes a 256-bit instruction as two 128-bit halves, Zen 4 at full width: the reference gained,
  the generated code did not. On the Zen 4, in C alone (``P_run`` against ``tse2_ref_run``, alternated in one
  process, CPU time): the export 1.76-1.92x the reference; the reference built ``-fno-tree-vectorize`` takes
  0.66-0.77 us a step instead of 0.47-0.49, with 128-bit vectors 0.52-0.54 (the export then 1.25-1.35x and
  1.63-1.66x). Both at plain ``-O2`` (SSE2) the export loses its three-operand instructions too: 2.2x.
* **Fresh memory.** On the Zen 4 guest the first touch of a fresh page is slow and uneven: 17 MB of new
  NumPy arrays took 0.7 to 40 ms to fill (1,100 page faults, sys time), where reused memory takes 0.75 ms.
  ``run``'s history is fresh memory every call: the kernel wrote packed rows (22.8 MB for 50,000 steps),
  copied into the estimate's and gain's arrays (17.2 MB) and the integer leaves (2.4 MB) before JAX took
  them: up to 0.9 us a step of sys time in one repeat, none in the next: ``run`` could show 1.8
  against the export's 1.1 us. The kernel now writes the kept estimates, gains and codes straight into the
  arrays JAX takes over (``kernel_history``: 17.6 MB, no copy). The export was timed through ``CFilter.run``,
  which allocates and NaN-fills a new 17 MB history every call, while the reference writes into buffers
  made before its timed run: both now write into buffers made once (``_export_run``).
* **Host flags.** The kernel is built with ``-march=native`` (``KERNEL_CFLAGS``). A reference built with plain
  ``-O2`` (x86-64's SSE2 baseline; ``c_reference.generic``) is slower per step than one built for the host, so
  the same kernel is a smaller multiple of it (issue 22: 3.0x against a plain ``-O2`` reference, where this
  benchmark printed 4.55x against its ``-march=native`` one). A ratio means something only with the same
  flags on both sides: ``machine`` prints both. A CPU with AVX-512 also gets ``-mno-avx512f`` (``NATIVE``).
* **The -O2 kernel not yet in place.** The first build serves at ``-O0`` (about 3x slower per step) until the
  ``-O2`` build, started after 2 s of calls or by ``Kernel.wait()``, replaces it; a ``run`` timed before
  ``Kernel.wait()`` measures the ``-O0`` kernel.
  Every timed run here waits for it. The first build is timed in its own process on a 100-sample log: the
  previous ``compile_s`` subtracted the ``-O2`` run from a first call that filtered 50,000 samples at ``-O0``
  while the ``-O2`` compiler ran on the same pinned core.
* **Timer resolution and noise.** ``perf_counter`` resolves well under a microsecond here, but a single
  online call of a few microseconds is easily doubled by an interrupt or a neighbour: latencies are medians
  over ``--calls`` calls, repeated, and the ``cpu_`` (``process_time``) figures are given beside them.
* **The Python path.** On the Zen 1 a ctypes call costs about 0.3 us per argument and a small NumPy operation
  0.5-3 us, so the online step (a 2-3 us kernel) was mostly Python: 12 us for ``online.step`` and 54 us for
  ``flt.step``. The step now goes through a small CPython extension (``liemef.codegen._fast``: one call, the
  samples read through the buffer protocol, the state's leaves and nodes made in C); where it cannot be built
  (no Python headers) the ctypes path serves and these two targets are not expected to hold.

    python benchmarks/bench_tse2.py [--duration 50] [--calls 2000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

# One core, before JAX starts its thread pools (the batch benchmark's subprocess gets them all back).
ALL_CPUS = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
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
from liemef.codegen import _fast, _kernel  # noqa: E402
from liemef.simulation import simulate  # noqa: E402
from liemef.systems import PlanarRigidBody, tse2_state  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import c_reference  # noqa: E402
from _timing import cpu_model  # noqa: E402


def tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50))
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def stats(values, digits=3) -> dict:
    """The minimum, median and every value of a repeated figure."""
    values = [float(v) for v in values]
    return {"min": round(min(values), digits), "median": round(float(np.median(values)), digits),
            "all": [round(v, digits) for v in values]}


def time_run(flt, state, log, repeats=5, engine=None):
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
    per_step = stats([r / steps * 1e6 for r in runs])
    return {"first_call_s": round(first, 3), "optimized_build_s": round(built - run_s, 3) if kern else None,
            "run_s": round(run_s, 4), "us_per_step": per_step["median"], "us_per_step_min": per_step["min"],
            "us_per_step_all": per_step["all"], "cpu_us_per_step": stats([c / steps * 1e6 for c in cpus]),
            "steps": steps, "loadavg_1min": round(os.getloadavg()[0], 2)}


def _latency(call, calls, repeats, start=0):
    """``call(k)`` for ``calls`` successive samples k from ``start``, ``repeats`` times (the samples going on
    from one repeat to the next): per repeat the median latency (wall and CPU), in us."""
    med, cpu_med, p90 = [], [], []
    for r in range(repeats):
        lat, cpu = np.empty(calls), np.empty(calls)
        for k in range(calls):
            i = start + r * calls + k
            c0, t0 = time.process_time(), time.perf_counter()
            call(i)
            lat[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
        med.append(np.median(lat) * 1e6)
        cpu_med.append(np.median(cpu) * 1e6)
        p90.append(np.quantile(lat, 0.9) * 1e6)
    m = stats(med, 2)
    return {"median_us": m["median"], "median_us_min": m["min"], "median_us_all": m["all"],
            "p90_us": round(float(np.median(p90)), 2), "cpu_median_us": stats(cpu_med, 2), "calls": calls,
            "repeats": repeats, "loadavg_1min": round(os.getloadavg()[0], 2)}


def time_step(flt, state, log, calls, engine=None, repeats=5):
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    dt = float(ts[1] - ts[0])
    st = [jax.block_until_ready(flt.step(state, float(ts[0]), us[0], ys[0], dt, engine=engine))]  # compile
    # XLA dispatches asynchronously: its latency includes the wait for the result; the C engine returns NumPy
    wait = jax.block_until_ready if liemef.engines.kernel(flt, engine) is None else (lambda x: x)
    tk = [float(t) for t in ts]

    def call(k):
        st[0] = flt.step(st[0], tk[k], us[k], ys[k], dt, engine=engine)
        wait(st[0].K)

    _latency(call, calls, 1, start=1)  # warm-up
    out = _latency(call, calls, repeats, start=1 + calls)
    assert int(st[0].status.code) == 0, "the step benchmark filter failed"
    return out


def time_online(flt, state, log, calls, repeats=5):
    """One ``OnlineFilter.step`` call (``flt.online(state)``: the state kept in C between calls), fed numpy."""
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    dt = float(ts[1] - ts[0])
    tk = [float(t) for t in ts]

    online = flt.online(state)
    online.step(tk[0], us[0], ys[0], dt)

    def call(k):
        online.step(tk[k], us[k], ys[k], dt)

    _latency(call, calls, 1, start=1)  # warm-up
    out = _latency(call, calls, repeats, start=1 + calls)
    assert online.code == 0, "the online benchmark filter failed"
    return out


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
    ts, us, ys = (np.ascontiguousarray(a, np.float64) for a in (log.ts, log.us, log.ys))
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
            run_export = _export_run(cflts[label], exported, len(ts))
            cflts[label].init(g0_leaves, np.eye(6))
            run_export(ts, us, ys)  # warm-up, as the reference's first run
            for _ in range(repeats):
                ref.append(c_reference.time_per_step(lib, "rkmk4", ts, us, ys, g0, np.eye(6), repeats=1))
                cflts[label].init(g0_leaves, np.eye(6))
                c0 = time.perf_counter()
                code = run_export(ts, us, ys)
                exp.append((time.perf_counter() - c0) / (len(ts) - 1) * 1e6)
                assert code == 0, "the exported filter failed on the benchmark log"
            figures[label] = {"flags": " ".join(c_reference.FLAGS + (NATIVE if label == "native" else ())),
                              "rkmk4_us_per_step": round(float(np.median(ref)), 4),
                              "rkmk4_us_per_step_min": round(float(np.min(ref)), 4),
                              "export_c_rkmk4_us_per_step_min": round(float(np.min(exp)), 4),
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
            "rkmk4_us_per_step_min": nat["rkmk4_us_per_step_min"], "repeats": repeats,
            "lie_euler_us_per_step": nat["lie_euler_us_per_step"], "generic": figures["generic"],
            "export_c": {"export_s": round(t1 - t0, 3), "build_s": round(t2 - t1, 3),
                         "flags": "-std=c99 -O2 " + " ".join(NATIVE),
                         "source_lines": source_lines,
                         "rkmk4_us_per_step": nat["export_c_rkmk4_us_per_step"],
                         "rkmk4_us_per_step_min": nat["export_c_rkmk4_us_per_step_min"],
                         "step_call_ctypes_median_us": round(float(np.median(lat)) * 1e6, 2)}}


def _export_run(cflt, exported, N: int):
    """The export's ``P_run`` over a log of N samples into output buffers made once, as the reference is timed
    (``c_reference.time_per_step``): ``CFilter.run`` allocates and NaN-fills a fresh (N-1) x 43 history every
    call, 17 MB here, whose first touch (page faults: 1-40 ms on this VM) is no part of the filter."""
    g = np.empty((N - 1, exported.group_params))
    K = np.empty((N - 1, exported.n, exported.n))
    fn = getattr(cflt.lib, f"{exported.prefix}_run")
    dp = ctypes.POINTER(ctypes.c_double)
    fn.argtypes = [ctypes.c_void_p, ctypes.c_int, dp, dp, dp, dp, dp]
    fn.restype = ctypes.c_int
    ptr = lambda a: a.ctypes.data_as(dp)  # noqa: E731

    def run(ts, us, ys) -> int:
        return int(fn(ctypes.addressof(cflt.state), N, ptr(ts), ptr(us), ptr(ys), ptr(g), ptr(K)))

    return run


FIRST = """
import json, os, resource, sys, time
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
c1, k1 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
flt.run(state, ts, us, ys)
t2 = time.perf_counter()
c2, k2 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
kern = liemef.engines.kernel(flt, None)
print(json.dumps({"import_s": round(t1 - t0, 3), "first_run_s": round(t2 - t1, 4),
                  "cpu_s": round(c2 - c1 + (k2.ru_utime + k2.ru_stime) - (k1.ru_utime + k1.ru_stime), 4),
                  "optimized": bool(kern.optimized)}), flush=True)
"""


def _in_new_process(script: str, cache: str) -> dict:
    env = dict(os.environ, LIEMEF_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    if out.returncode != 0:
        return {"error": out.stderr[-2000:]}
    return json.loads(out.stdout.strip().splitlines()[0])


def first_build(repeats: int) -> dict:
    """The first ``run`` of a new process (on this process's core) with an empty kernel cache, until its result:
    the trace, the translation, the C compiler at -O0, the load and a 100-sample run (``first_run_s``, and
    ``cpu_s``: the process's CPU time and its compilers'); ``repeats`` new processes, each with its own cache."""
    got = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="liemef-bench-first-") as cache:
            got.append(_in_new_process(FIRST, cache))
    if any("error" in g for g in got):
        return next(g for g in got if "error" in g)
    return {"first_run_s": stats([g["first_run_s"] for g in got]), "cpu_s": stats([g["cpu_s"] for g in got]),
            "import_s": stats([g["import_s"] for g in got]), "repeats": repeats,
            "loadavg_1min": round(os.getloadavg()[0], 2)}


def compile_in_new_process(repeats: int) -> dict:
    """The first ``run`` of a new process whose kernel is on disk already (this benchmark built it): the trace
    of the interval, the check and load of the library and the run."""
    got = [_in_new_process(FIRST, os.environ["LIEMEF_CACHE_DIR"]) for _ in range(repeats)]
    if any("error" in g for g in got):
        return next(g for g in got if "error" in g)
    return {"first_run_s": stats([g["first_run_s"] for g in got]), "cpu_s": stats([g["cpu_s"] for g in got]),
            "import_s": stats([g["import_s"] for g in got]), "repeats": repeats}


def batch_throughput(repeats: int) -> dict:
    """``bench_batch.py --quick`` in a subprocess that may use every core this benchmark was given."""
    here = os.path.dirname(os.path.abspath(__file__))
    pre = (lambda: os.sched_setaffinity(0, ALL_CPUS)) if ALL_CPUS is not None else None
    out = subprocess.run([sys.executable, os.path.join(here, "bench_batch.py"), "--quick", "--repeats",
                          str(repeats)], capture_output=True, text=True, preexec_fn=pre)
    if out.returncode != 0:
        return {"error": out.stderr[-2000:]}
    return json.loads(out.stdout[out.stdout.index("\n{\n"):] if "\n{\n" in out.stdout else out.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=50.0)
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5, help="repeats of every figure (minimum and median reported)")
    ap.add_argument("--no-batch", action="store_true", help="leave out bench_batch.py's throughput")
    args = ap.parse_args()
    R = args.repeats
    load_start = round(os.getloadavg()[0], 2)

    system = PlanarRigidBody()
    ts = np.arange(int(round(args.duration / 1e-3)) + 1) * 1e-3
    _, log = simulate(system, tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0), tse2_input, ts, jax.random.PRNGKey(0))
    g0 = tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1)

    results = {"engine": liemef.engines.engine_of(None), "repeats": R}
    for name, kw in [("rkmk4", dict(integrator="rkmk4")), ("lie_euler", dict(integrator="lie-euler")),
                     ("rkmk4_first_order", dict(integrator="rkmk4", order="first"))]:
        flt = liemef.MinimumEnergyFilter(system, **kw)
        results[f"run_{name}"] = time_run(flt, flt.init(g0, np.eye(6)), log, repeats=R)
    results["first_build"] = first_build(R)
    results["compile_new_process"] = compile_in_new_process(R)
    flt = liemef.MinimumEnergyFilter(system)
    results["run_rkmk4_xla"] = time_run(flt, flt.init(g0, np.eye(6)), log, engine="xla", repeats=min(R, 3))
    results["step_rkmk4_numpy"] = time_step(flt, flt.init(g0, np.eye(6)), log, args.calls, repeats=R)
    results["online_step_rkmk4_numpy"] = time_online(flt, flt.init(g0, np.eye(6)), log, args.calls, repeats=R)
    results["step_rkmk4_numpy_xla"] = time_step(flt, flt.init(g0, np.eye(6)), log, min(args.calls, 300),
                                                engine="xla", repeats=1)
    results["c_reference"] = c = time_c_reference(log, g0, repeats=R)
    results["batch"] = None if args.no_batch else batch_throughput(R)

    r = results
    results["ratios"] = {
        "rkmk4_over_lie_euler": round(r["run_rkmk4"]["us_per_step"] / r["run_lie_euler"]["us_per_step"], 2),
        "second_over_first_order": round(r["run_rkmk4"]["us_per_step"] / r["run_rkmk4_first_order"]["us_per_step"], 2),
        "step_call_over_run_step": round(r["step_rkmk4_numpy"]["median_us"] / r["run_rkmk4"]["us_per_step"], 2),
    }
    if c["available"]:
        results["ratios"].update({
            "run_rkmk4_over_c": round(r["run_rkmk4"]["us_per_step"] / c["rkmk4_us_per_step"], 2),
            "run_rkmk4_over_c_of_minima": round(r["run_rkmk4"]["us_per_step_min"] / c["rkmk4_us_per_step_min"], 2),
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
    fb, batch = r["first_build"], r["batch"]
    best_batch = batch.get("best_filter_trial_steps_per_s") if isinstance(batch, dict) else None
    # decided on the medians of the repeats (the minima are printed beside each figure)
    results["targets"] = {
        "run_rkmk4_over_c<=3 (both -O2 with the host's instructions)":
        r["run_rkmk4"]["us_per_step"] <= 3 * c["rkmk4_us_per_step"] if c["available"] else None,
        "step_call_us<=20 (flt.step: a FilterState in and out)": r["step_rkmk4_numpy"]["median_us"] <= 20,
        "online_step_call_us<=5 (flt.online(state).step)": r["online_step_rkmk4_numpy"]["median_us"] <= 5,
        "first_build_s<2 (new process, kernel cache empty)":
        fb["first_run_s"]["median"] < 2 if "first_run_s" in fb else None,
        "export_c_over_c<=2 (both -O2 with the host's instructions)":
        c["export_c"]["rkmk4_us_per_step"] <= 2 * c["rkmk4_us_per_step"] if c["available"] else None,
        "batch_trial_steps_per_s>=4e6 (bench_batch.py, every core)": best_batch >= 4e6 if best_batch else None,
    }
    results["machine"] = {"cpu_model": cpu_model(), "cpus": len(ALL_CPUS) if ALL_CPUS else os.cpu_count(),
                          "cores_used": 1, "python": platform.python_version(), "jax": jax.__version__,
                          "liemef": liemef.__version__, "compiler": codegen.compiler(),
                          "kernel_cflags": " ".join(_kernel.KERNEL_CFLAGS),
                          "first_build_cflags": " ".join(_kernel.QUICK_CFLAGS),
                          "reference_cflags": " ".join(c_reference.FLAGS + NATIVE),
                          "fast_step": _fast.error() or "the CPython extension (liemef.codegen._fast)",
                          "loadavg_1min_start": load_start, "loadavg_1min_end": round(os.getloadavg()[0], 2)}
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
