"""Scaling (issue 9): cost per filter step against the state dimension n, for ``run``, batched and exported C.

Systems: linear systems on R^n, n = 3, 6, 12, 24 (``--dims``): a fixed-seed random stable F (spectral abscissa
-0.5), m = 2 inputs, p = ceil(n/2) outputs, B = I (n noise inputs), diagonal D, Q = I, diagonal R; and every
ready system of the papers (``liemef.studies.experiments.SYSTEMS``, ``--systems``) with its algebra dimension n. Every
filter is the default ``MinimumEnergyFilter`` (second order, (0)-connection, RKMK4, adaptive sub-steps), K0 = I,
started off the truth.

Logs are synthetic: R^n simulated with NumPy (Euler-Maruyama, 1 ms); the papers' systems simulated with
``liemef.simulate`` under a smooth input (u_j = 0.5 sin(0.5 (j + 1) t)) at their experiments' rates (1 ms; the
Chaplygin sleigh 10 ms; attitude-bias 3.5 ms, BROAD's rate; localization 10 ms odometry with a GPS fix every
second, NaN between). ``--steps`` intervals, a power of two (``run`` pads a log to one, and a padded tail would
be timed too); ``--batch`` trials share the truth and differ in their measurement noise; trial 0 is the log of
the single-log figures. Every run must stay healthy (status code 0, C return code 0) or the benchmark stops.

Per system, in one JSON document:

* ``run_us_per_step``, ``run_compile_s``: ``flt.run`` on one core (the process is pinned and XLA
  single-threaded, as in bench_tse2.py) after a first call; compile = first call - a run;
* ``batched_us_per_trial_step``, ``batched_compile_s``: ``jax.jit(jax.vmap(lambda ys: flt.scan(state, ts, us,
  ys)))`` over the batch on the log's first ``--batched-steps`` intervals, after an explicit compile. This one
  may use **both cores**: it runs in a child process given back the parent's full CPU affinity, with two XLA
  host devices and the batch sharded across them (8 trials each of 16);
* ``export_c``: ``codegen.export_c`` built at ``-std=c99 -O2`` and run over the same log as ``run`` by
  ``CFilter.run`` (one core): microseconds per step, export and build times, source lines, size of the shared
  library. Backends: ``scalar`` where n <= ``SCALAR_MAX_N`` and ``array`` for every n; ``auto`` is the one of
  them export_c picks (the same code, so not built twice: ``"is"`` says which).

Times per step are medians over repeated runs (at least 3, 2 for batched, more while they take under 1 s), in
wall time and, as ``cpu_``, in process CPU time (all threads: for batched, both cores' time).

And ``slopes``: the least-squares slope of log cost against log n over the R^n points, and between the two
largest n, per series. Figures from one run on a shared machine (the load average is printed with them):
compare figures measured together rather than across runs. ``--out DIR`` writes ``scaling.json`` and
``scaling.png`` (log-log cost against n; the exported C's size and build time); ``--plot JSON`` redraws the
figure from a saved document. The default run takes about 10 min, nearly all of it compiling (JAX and cc).

    python benchmarks/bench_scaling.py [--steps 2048] [--batched-steps 1024] [--batch 16] [--dims 3,6,12,24]
                                       [--systems tse2,attitude,...|none] [--out DIR]
    python benchmarks/bench_scaling.py --quick   # smoke test: 256 steps, R^3, R^6 and unit-circle (1-2 min)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import threading
import time

WORKER = "--batched-worker" in sys.argv
XLA_FLAGS_BEFORE = os.environ.get("XLA_FLAGS", "")
ALL_CORES = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
if WORKER:
    # the batched figures: the cores the parent started with (it was pinned to one), two XLA host devices
    if os.environ.get("BENCH_SCALING_CORES") and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {int(c) for c in os.environ["BENCH_SCALING_CORES"].split(",")})
    os.environ["XLA_FLAGS"] = (XLA_FLAGS_BEFORE + " --xla_force_host_platform_device_count=2").strip()
else:
    # One core, before JAX starts its thread pools (as bench_tse2.py).
    if ALL_CORES:
        os.sched_setaffinity(0, {ALL_CORES[0]})
    os.environ["XLA_FLAGS"] = (XLA_FLAGS_BEFORE +
                               " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _provenance import source_version  # noqa: E402

import liemef  # noqa: E402
from liemef import codegen  # noqa: E402
from liemef.groups import Rn  # noqa: E402
from liemef.simulation import simulate  # noqa: E402
from liemef.studies.experiments import SYSTEMS  # noqa: E402
from liemef.systems import System  # noqa: E402

C_FLAGS = ("-std=c99", "-O2")
STACK_BYTES = 256 * 2**20
PAPER_DT = {"chaplygin": 0.01, "chaplygin-gps": 0.01, "attitude-bias": 1 / 285.714, "localization": 0.01}
Y_EVERY = {"localization": 100}  # GPS at 1 Hz, NaN between fixes


# --- the systems ----------------------------------------------------------------------------------------------
def rn_matrices(n: int) -> dict[str, np.ndarray]:
    """The linear system on R^n: x' = F x + G u + B w, y = H x + D v, fixed seed per n."""
    rng = np.random.default_rng(1000 + n)
    p = -(-n // 2)
    A0 = rng.standard_normal((n, n)) / np.sqrt(n)
    F = A0 - (np.max(np.linalg.eigvals(A0).real) + 0.5) * np.eye(n)  # spectral abscissa -0.5: stable
    return {"F": F, "G": rng.standard_normal((n, 2)), "H": rng.standard_normal((p, n)) / np.sqrt(n),
            "B": np.eye(n), "D": np.diag(0.1 * (1.0 + 0.5 * rng.random(p))), "Q": np.eye(p),
            "R": np.diag(1.0 + rng.random(n))}


def rn_system(n: int) -> System:
    M = rn_matrices(n)
    F, G, H = (jnp.asarray(M[k]) for k in "FGH")
    return System(group_type=Rn[n], dynamics_fn=lambda g, u, t: F @ g.x + G @ u, output_fn=lambda g, t: H @ g.x,
                  B=M["B"], D=M["D"], Q=M["Q"], R=M["R"], n_inputs=2)


def setup(name: str):
    """(system, truth at t = 0, initial estimate, dt) of a case: ``R^n`` or a name of SYSTEMS."""
    if name.startswith("R^"):
        n = int(name[2:])
        G = Rn[n]
        return rn_system(n), G(jnp.ones(n)), G(jnp.zeros(n)), 1e-3
    system = SYSTEMS[name].make()
    G, n = system.group, system.group.tangent_dim
    g_true = G.identity().rplus(0.1 * jnp.ones(n))
    return system, g_true, g_true.rplus(0.05 * jnp.ones(n)), PAPER_DT.get(name, 1e-3)


def smooth_input(m: int):
    w = 0.5 * jnp.arange(1, m + 1)
    return lambda t: 0.5 * jnp.sin(w * t)


def make_log(name: str, steps: int, batch: int):
    """ts (N,), us (N, m), ys (batch, N, p): one truth, ``batch`` draws of the measurement noise."""
    system, g_true, _, dt = setup(name)
    ts = np.arange(steps + 1) * dt
    rng = np.random.default_rng(7)
    if name.startswith("R^"):
        M = rn_matrices(int(name[2:]))
        us = np.column_stack([np.sin(2.0 * ts), np.cos(0.7 * ts)])
        x, xs = np.asarray(g_true.x), np.empty((ts.size, M["F"].shape[0]))
        for k, u in enumerate(us):
            xs[k] = x
            x = x + dt * (M["F"] @ x + M["G"] @ u) + 0.1 * np.sqrt(dt) * M["B"] @ rng.standard_normal(x.size)
        clean = xs @ M["H"].T
        D = M["D"]
    else:
        truth, log = simulate(system, g_true, smooth_input(system.input_dim), ts, jax.random.key(0))
        us = np.asarray(log.us)
        clean = np.asarray(jax.vmap(system.output)(truth.g, jnp.asarray(ts)))
        D = np.asarray(system.D)
    ys = clean[None] + rng.standard_normal((batch,) + clean.shape) @ D.T
    every = Y_EVERY.get(name, 1)
    if every > 1:
        ys[:, np.arange(ts.size) % every != 0, :] = np.nan
    return ts, np.asarray(us, np.float64), ys


def flat_params(g) -> np.ndarray:
    return np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(g)])


# --- the measurements -----------------------------------------------------------------------------------------
def timed(fn, min_repeats=3, max_repeats=15, budget_s=1.0):
    """Call ``fn`` at least ``min_repeats`` times, more (up to ``max_repeats``) while the calls so far took less
    than ``budget_s``: the median wall time, the median process CPU time (all threads; it leaves out the time
    spent waiting for a core the other work on the machine holds) and ``fn``'s last result."""
    walls, cpus = [], []
    while len(walls) < min_repeats or (sum(walls) < budget_s and len(walls) < max_repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus)), out


def per_step(seconds: float, steps: int) -> float:
    return round(seconds / steps * 1e6, 3)


def time_run(flt, state, ts, us, ys):
    t0 = time.perf_counter()
    jax.block_until_ready(flt.run(state, ts, us, ys, engine="xla"))  # compile + first run
    first = time.perf_counter() - t0
    wall, cpu, traj = timed(lambda: jax.block_until_ready(flt.run(state, ts, us, ys, engine="xla")))
    if not traj.status.ok:
        raise RuntimeError(f"run failed: {traj.status.cause} at t = {float(traj.status.time):.4g}")
    steps = len(ts) - 1
    return {"us_per_step": per_step(wall, steps), "cpu_us_per_step": per_step(cpu, steps),
            "compile_s": round(first - wall, 3), "substeps_per_step": round(int(traj.status.substeps_total) / steps, 3)}


def time_export(flt, g0, ts, us, ys, backend, tmp):
    t0 = time.perf_counter()
    exported = codegen.export_c(flt, tmp, name=f"scaling_{backend}", backend=backend)
    t1 = time.perf_counter()
    lib = codegen.build_shared(exported, flags=C_FLAGS)
    t2 = time.perf_counter()
    cflt = codegen.CFilter(exported, library=lib)
    g0_flat, K0 = flat_params(g0), np.eye(flt.n)

    def run():
        assert cflt.init(g0_flat, K0) == 0
        code, _, _ = cflt.run(ts, us, ys)
        if code != 0:
            raise RuntimeError(f"the exported C ({backend}) failed with code {code}")

    wall, cpu, _ = on_big_stack(lambda: timed(run))
    steps = len(ts) - 1
    source = exported.source.read_text()
    return {"us_per_step": per_step(wall, steps), "cpu_us_per_step": per_step(cpu, steps),
            "export_s": round(t1 - t0, 3), "build_s": round(t2 - t1, 3), "source_lines": source.count("\n"),
            "library_bytes": os.path.getsize(lib),
            # the exported C keeps its arrays on the stack: their declared size, against the usual 8 MiB
            "local_array_bytes": 8 * sum(int(k) for k in re.findall(r"^ +double \w+\[(\d+)\];", source, re.M))}


def on_big_stack(fn, stack_bytes=STACK_BYTES):
    """``fn()`` in a thread with a ``stack_bytes`` stack: the exported C keeps every intermediate on the stack
    (no heap), which for large n outgrows the main thread's (8 MiB by default; the array backend at n = 48
    needs about 13 MB)."""
    out = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as err:  # noqa: BLE001 - handed back to the caller's thread
            out["error"] = err

    old = threading.stack_size(stack_bytes)
    try:
        th = threading.Thread(target=target)
        th.start()
    finally:
        threading.stack_size(old)
    th.join()
    if "error" in out:
        raise out["error"]
    return out["value"]


def backends(n: int) -> list[str]:
    """The translators measured: "array" for every n, "scalar" where n <= SCALAR_MAX_N. "auto" is one of them
    (export_c resolves it to scalar up to SCALAR_MAX_N, array above: the same code), so it is not built twice."""
    return (["scalar"] if n <= codegen.SCALAR_MAX_N else []) + ["array"]


def measure_single(name, ts, us, ys):
    """``run`` and the exported C on one core, for one case."""
    system, _, g0, _ = setup(name)
    flt = liemef.MinimumEnergyFilter(system)
    state = flt.init(g0, np.eye(flt.n))
    out = {"n": flt.n, "m": system.input_dim, "p": system.output_dim, "dt": ts[1] - ts[0], "steps": len(ts) - 1}
    r = time_run(flt, state, ts, us, ys)
    out.update(run_us_per_step=r["us_per_step"], run_cpu_us_per_step=r["cpu_us_per_step"], run_compile_s=r["compile_s"],
               substeps_per_step=r["substeps_per_step"])
    out["export_c"] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for backend in backends(flt.n):
            out["export_c"][backend] = time_export(flt, g0, ts, us, ys, backend, tmp)
    auto = "scalar" if flt.n <= codegen.SCALAR_MAX_N else "array"
    out["export_c"] = {"auto": {"is": auto, **out["export_c"][auto]}, **out["export_c"]}
    return out


def measure_batched(name, ts, us, ys_b):
    """The batch sharded over the XLA host devices (two in the worker): us per trial-step and compile time."""
    system, _, g0, _ = setup(name)
    flt = liemef.MinimumEnergyFilter(system)
    state = flt.init(g0, np.eye(flt.n))
    tsj, usj = jnp.asarray(ts), jnp.asarray(us)
    devices = jax.devices()
    if ys_b.shape[0] % len(devices):
        devices = devices[:1]
    mesh = jax.sharding.Mesh(np.array(devices), ("trials",))
    ys_b = jax.device_put(jnp.asarray(ys_b), jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("trials")))
    fn = jax.jit(jax.vmap(lambda ys: flt.scan(state, tsj, usj, ys)))
    t0 = time.perf_counter()
    compiled = fn.lower(ys_b).compile()
    compile_s = time.perf_counter() - t0
    wall, cpu, traj = timed(lambda: jax.block_until_ready(compiled(ys_b)), min_repeats=2, max_repeats=5)
    codes = np.asarray(traj.status.code)
    if np.any(codes != 0):
        raise RuntimeError(f"batched run of {name}: {int(np.sum(codes != 0))} trial(s) failed")
    trial_steps = ys_b.shape[0] * (len(ts) - 1)
    return {"batched_us_per_trial_step": per_step(wall, trial_steps),
            "batched_cpu_us_per_trial_step": per_step(cpu, trial_steps), "batched_compile_s": round(compile_s, 3),
            "batched_devices": len(devices), "batched_steps": len(ts) - 1}


def batched_worker(log_dir: str, names: list[str]) -> None:
    out = {}
    for name in names:
        with np.load(os.path.join(log_dir, f"{names.index(name)}.npz")) as z:
            out[name] = measure_batched(name, z["ts"], z["us"], z["ys"])
        print(f"batched {name}: {out[name]}", file=sys.stderr, flush=True)
    print(json.dumps({"results": out, "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                      else os.cpu_count(), "devices": len(jax.devices())}))


def run_batched_child(log_dir: str, names: list[str]) -> dict:
    env = {**os.environ, "XLA_FLAGS": XLA_FLAGS_BEFORE, "BENCH_SCALING_CORES": ",".join(map(str, ALL_CORES))}
    proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--batched-worker", log_dir, *names],
                          env=env, stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        raise RuntimeError("the batched worker failed (its messages are above)")
    return json.loads(proc.stdout)


def slopes(results: dict, names: list[str]) -> dict:
    """Slope of log cost against log n over the R^n points, per series (wall and ``_cpu`` time): the least-squares
    fit over all of them, and between neighbours (``pairwise``; the last is between the two largest n)."""
    fields = {"run": ("run_us_per_step", "run_cpu_us_per_step"),
              "batched": ("batched_us_per_trial_step", "batched_cpu_us_per_trial_step")}

    def value(r, key, cpu):
        if key.startswith("export_c_"):
            return r["export_c"].get(key[len("export_c_"):], {}).get("cpu_us_per_step" if cpu else "us_per_step")
        return r.get(fields[key][cpu])

    out = {}
    rn = sorted((nm for nm in names if nm.startswith("R^")), key=lambda nm: results[nm]["n"])
    for key in ("run", "batched", "export_c_auto", "export_c_array", "export_c_scalar"):
        for cpu in (False, True):
            pts = [(results[nm]["n"], value(results[nm], key, cpu)) for nm in rn
                   if value(results[nm], key, cpu) is not None]
            if len(pts) < 2:
                continue
            x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
            pairwise = [round(float(d), 2) for d in np.diff(y) / np.diff(x)]
            out[key + ("_cpu" if cpu else "")] = {
                "fit_all": round(float(np.polyfit(x, y, 1)[0]), 2), "pairwise": pairwise, "last_two": pairwise[-1],
                "n": [int(p[0]) for p in pts]}
    return out


# --- the figure (from the results, never recomputing) ---------------------------------------------------------
def plot(doc: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import NullFormatter

    res = doc["systems"]
    rn = sorted((nm for nm in res if nm.startswith("R^")), key=lambda nm: res[nm]["n"])
    papers = [nm for nm in res if not nm.startswith("R^")]
    c_us = lambda b: lambda r: r["export_c"].get(b, {}).get("us_per_step")  # noqa: E731
    # (label, colour, value, line width, marker size): the C translators "auto" picks between drawn thin
    series = [("run, 1 core", "C0", lambda r: r["run_us_per_step"], 2.0, 7),
              ("batched, per trial-step, 2 cores allowed", "C1", lambda r: r.get("batched_us_per_trial_step"), 2.0, 7),
              ("exported C, auto", "C2", c_us("auto"), 4.0, 10),
              ("exported C, scalar", "C4", c_us("scalar"), 1.0, 4),
              ("exported C, array", "C3", c_us("array"), 1.0, 4)]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [3, 2]})
    handles = []
    for label, colour, get, lw, ms in series:
        pts = [(res[nm]["n"], get(res[nm])) for nm in rn if get(res[nm]) is not None]
        if pts:
            ax.plot(*zip(*pts, strict=True), "o-", color=colour, lw=lw, ms=ms, alpha=0.6 if lw > 2 else 1.0)
        pp = [(res[nm]["n"], get(res[nm])) for nm in papers if get(res[nm]) is not None]
        if pp:
            ax.plot(*zip(*pp, strict=True), "^", color=colour, mfc="none", ms=ms)
        handles.append(Line2D([], [], color=colour, lw=lw, label=label))
    if rn:
        n_max = res[rn[-1]]["n"]
        ns = np.geomspace(min(res[nm]["n"] for nm in res), n_max, 50)
        for _, colour, get, _, _ in series[:3]:
            c = get(res[rn[-1]])
            if c is not None:
                ax.plot(ns, c * (ns / n_max) ** 3, ":", color=colour, lw=1)
        handles.append(Line2D([], [], color="grey", ls=":", label=f"n^3 through n = {n_max}"))
    handles += [Line2D([], [], color="grey", marker="o", label="R^n (joined)"),
                Line2D([], [], color="grey", marker="^", mfc="none", ls="", label="the papers' systems")]
    ticks = sorted({res[nm]["n"] for nm in res})
    ax.set(xscale="log", yscale="log", xlabel="algebra dimension n", ylabel="microseconds per step",
           title=f"Cost per filter step (second order, RKMK4), {doc['steps']}-step logs")
    ax.set_xticks(ticks, labels=[str(t) for t in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(handles=handles, fontsize=8)
    for b, colour in (("scalar", "C4"), ("array", "C3")):
        pts = sorted((res[nm]["n"], res[nm]["export_c"][b]["source_lines"], res[nm]["export_c"][b]["build_s"])
                     for nm in rn if b in res[nm]["export_c"])
        if pts:
            ns_, lines, build = zip(*pts, strict=True)
            ax2.plot(ns_, lines, "o-", color=colour, label=f"{b}: source lines")
            ax2.plot(ns_, np.asarray(build) * 1000, "s--", color=colour, label=f"{b}: build ms (cc -O2)")
    ticks = sorted(res[nm]["n"] for nm in rn)
    ax2.set(xscale="log", yscale="log", xlabel="n (R^n)", title="Exported C: size and build time")
    ax2.set_xticks(ticks, labels=[str(t) for t in ticks])
    ax2.xaxis.set_minor_formatter(NullFormatter())
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    if WORKER:
        i = sys.argv.index("--batched-worker")
        return batched_worker(sys.argv[i + 1], sys.argv[i + 2:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, help="sample intervals per log, a power of two (default 2048; quick 256)")
    ap.add_argument("--batched-steps", type=int,
                    help="the first intervals of the log the batched figures use (default 1024; quick 256)")
    ap.add_argument("--batch", type=int, default=16, help="trials of the batched figures (default 16)")
    ap.add_argument("--dims", help="the n of the R^n systems, comma-separated (default 3,6,12,24; quick 3,6)")
    ap.add_argument("--systems", help="the papers' systems, comma-separated names of "
                    "liemef.studies.experiments.SYSTEMS, "
                                      "or none (default all; quick unit-circle)")
    ap.add_argument("--quick", action="store_true", help="smoke test: the defaults marked quick (under 2 min)")
    ap.add_argument("--out", help="folder for scaling.json and scaling.png")
    ap.add_argument("--plot", metavar="JSON", help="only draw scaling.png (into --out) from a saved scaling.json")
    args = ap.parse_args()
    if args.plot:
        with open(args.plot) as fh:
            doc = json.load(fh)
        plot(doc, os.path.join(args.out or os.path.dirname(os.path.abspath(args.plot)), "scaling.png"))
        return
    q = args.quick
    steps = args.steps or (256 if q else 2048)
    batched_steps = min(steps, args.batched_steps or (256 if q else 1024))
    dims = [int(d) for d in (args.dims or ("3,6" if q else "3,6,12,24")).split(",")]
    systems = args.systems or ("unit-circle" if q else ",".join(SYSTEMS))
    systems = [] if systems == "none" else systems.split(",")
    unknown = [name for name in systems if name not in SYSTEMS]
    if unknown:
        ap.error(f"--systems: expected names of {sorted(SYSTEMS)} or none, got {unknown}")
    for k, v in (("--steps", steps), ("--batched-steps", batched_steps)):
        if v < 2 or v & (v - 1):
            ap.error(f"{k}: expected a power of two >= 2 (run pads a log to one), got {v}")
    if args.batch < 1:
        ap.error(f"--batch: expected >= 1, got {args.batch}")
    source = source_version()
    t_start = time.perf_counter()
    names = [f"R^{d}" for d in dims] + systems
    results = {}
    with tempfile.TemporaryDirectory() as log_dir:
        for i, name in enumerate(names):
            ts, us, ys_b = make_log(name, steps, args.batch)
            nb = batched_steps + 1
            np.savez(os.path.join(log_dir, f"{i}.npz"), ts=ts[:nb], us=us[:nb], ys=ys_b[:, :nb])
            results[name] = measure_single(name, ts, us, ys_b[0])
            print(f"{name}: run {results[name]['run_us_per_step']} us/step, C "
                  f"{ {b: e['us_per_step'] for b, e in results[name]['export_c'].items()} }", file=sys.stderr,
                  flush=True)
        child = run_batched_child(log_dir, names)
    for name in names:
        results[name].update(child["results"][name])
    doc = {"benchmark": "scaling", "source": source, "steps": steps, "batched_steps": batched_steps,
           "batch": args.batch,
           "systems": results, "slopes": slopes(results, names),
           "machine": {"python": platform.python_version(), "jax": jax.__version__, "liemef": liemef.__version__,
                       "cc": codegen.compiler(), "c_flags": " ".join(C_FLAGS),
                       "cores_run_and_c": 1, "cores_batched": child["cores"], "devices_batched": child["devices"],
                       "loadavg_1min": round(os.getloadavg()[0], 2)},
           "wall_s": round(time.perf_counter() - t_start, 1)}
    text = json.dumps(doc, indent=2, default=float)
    print(text)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "scaling.json"), "w") as fh:
            fh.write(text + "\n")
        plot(json.loads(text), os.path.join(args.out, "scaling.png"))


if __name__ == "__main__":
    main()
