"""What a real-log user pays: compilations, automatic sub-steps, linear interpolation and online step latency.

Prints one JSON document (issue 7) on one core:

* ``compile``: how many times ``run`` and ``step`` are traced (= compiled, ``liemef.filters.TRACES``) when only
  weights change (20 GPS noise levels of the localization system, 20 measurement weights D of the TSE(2)
  system, three inertias J), when only the log length changes (logs padded to power-of-two buckets: one
  compilation per distinct bucket), and for online ``step`` on two filters with different weights; with the
  first call's time (compile + run) beside the steady time.
* ``substeps``: us per step of ``run`` with ``substeps="auto"`` against ``substeps=1`` and with
  ``interpolation="linear"``, on the TSE(2) paper system at 1 ms (where auto never splits an interval: the
  price of deciding) and on the localization scenario (100 Hz odometry, 1 Hz GPS fixes, 45 deg initial
  heading error: where auto does split), with the sub-step counts of ``status`` and the errors.
* ``step_tse2``: median and p90 latency of one online ``step`` call fed numpy arrays.

Figures from one run on a shared machine: compare the ratios, measured together, not absolute numbers across
runs; ``machine.loadavg`` says how busy the machine was. Nothing here asserts a time.

    python benchmarks/bench_real_logs.py [--repeats 3] [--calls 2000]
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
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

import liemef  # noqa: E402
from liemef.engines import bucket
from liemef.filters import TRACES  # noqa: E402
from liemef.groups import SE2  # noqa: E402
from liemef.metrics import state_error  # noqa: E402
from liemef.systems import Noise, PlanarRigidBody, planar_localization, tse2_state  # noqa: E402

# The localization scenario (../shared/scenarios/ukfm_localization.md): a 10 m circle in 40 s.
ODO_RATE, GPS_EVERY = 100.0, 100  # Hz; one GPS fix every 100 odometry samples (1 Hz)
U_CIRCLE = np.array([2 * math.pi * 5.0 / 40.0, 0.0, 2 * math.pi / 40.0])  # (v_x, v_y, omega)
ODO_STD = np.array([0.01, 0.01, math.pi / 180.0])  # per sample, in the input's order (v_x, v_y, omega)
HEADING_ERROR = math.pi / 4  # 45 deg
LENGTHS = (300, 500, 700, 1500, 3000, 5000, 7000, 9000)  # samples; 500 and 7000 share a bucket with a neighbour


def circle_input(t):
    return jnp.asarray(U_CIRCLE) + 0.0 * t


def tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50))
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def localization_log(n_samples, seed=0):
    """Truth and log of the localization scenario: noisy odometry at 100 Hz, a GPS fix every second (NaN
    between fixes; the fix at t = 0 left out, as in ukfm)."""
    system = planar_localization()
    ts = np.arange(n_samples) / ODO_RATE
    truth, log = liemef.simulate(system, SE2.identity(), circle_input, ts, jax.random.key(seed),
                                 input_noise=np.diag(ODO_STD))
    ys = np.array(log.ys)
    k = np.arange(n_samples)
    ys[(k % GPS_EVERY != 0) | (k == 0)] = np.nan
    return truth, (ts, np.asarray(log.us), ys)


def localization_state(flt):
    # heading off by 45 deg, position known exactly: K0 = diag(sigma_theta^2, 0, 0)
    return flt.init(SE2.from_coords(jnp.array([HEADING_ERROR, 0.0, 0.0])), np.diag([HEADING_ERROR**2, 0.0, 0.0]))


def tse2_log(n_intervals, seed=0):
    ts = np.arange(n_intervals + 1) * 1e-3
    truth, log = liemef.simulate(PlanarRigidBody(), tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0), tse2_input,
                                 ts, jax.random.key(seed))
    return truth, (ts, np.asarray(log.us), np.asarray(log.ys))


def tse2_state0(flt):
    return flt.init(tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1), np.eye(6))


def timed(fn, cpu=False):
    """``fn()``'s result and wall time (and, with ``cpu``, the process CPU time: on a shared machine the wall time
    includes waiting for the core, the CPU time does not)."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = jax.block_until_ready(fn())
    wall, used = time.perf_counter() - t0, time.process_time() - c0
    return (out, wall, used) if cpu else (out, wall)


def steady(fn, repeats):
    """Median wall time of ``repeats`` calls after one warm-up call (compiled already or compiled here)."""
    out = jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        out, s = timed(fn)
        times.append(s)
    return out, float(np.median(times))


def progress(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def traces(name):
    return TRACES[name]


def weight_sweep(make_filter, state_of, log, n, expected=1):
    """Run the same log with ``n`` weight settings: the first call compiles, the others must not."""
    before = traces("run")
    first, rest, summaries = None, [], []
    for i in range(n):
        flt = make_filter(i)
        traj, s = timed(lambda flt=flt: flt.run(state_of(flt), *log))
        assert traj.status.ok, traj.status.message(log[0])
        if i == 0:
            first = s
        else:
            rest.append(s)
        summaries.append(float(jnp.trace(traj.final.K)))
    steady_s = float(np.median(rest))
    return {"settings": n, "run_traces": traces("run") - before, "expected_traces": expected,
            "first_call_s": round(first, 3), "median_later_call_s": round(steady_s, 4),
            "max_later_call_s": round(max(rest), 4),
            "compile_s": round(first - steady_s, 3) if expected else None,
            "distinct_final_trace_K": len({round(v, 12) for v in summaries})}


def compile_counts(repeats):
    out = {}
    # 20 GPS noise levels, one localization log
    progress("compile: localization GPS noise sweep")
    _, log = localization_log(4001)
    sigmas = np.geomspace(0.3, 5.0, 20)
    out["localization_gps_noise_sweep"] = weight_sweep(
        lambda i: liemef.MinimumEnergyFilter(planar_localization().with_noise(gps=Noise.sample(sigmas[i]))),
        localization_state, log, 20)
    progress("compile: TSE(2) D sweep")
    # 20 measurement weights of the TSE(2) system (Q = I, so that D^-T Q D^-1 = D^-2 really changes)
    _, tlog = tse2_log(8192)
    scales = np.geomspace(0.25, 4.0, 20)
    out["tse2_D_sweep"] = weight_sweep(
        lambda i: liemef.MinimumEnergyFilter(PlanarRigidBody(D=np.diag([0.5] * 4 + [0.1] * 3) * scales[i],
                                                             Q=np.eye(7))),
        tse2_state0, tlog, 20)
    progress("compile: TSE(2) J sweep")
    # three inertias J on the structure and log just compiled: a physical parameter, so it should be a leaf too
    # (parameters are array leaves) and compile nothing
    out["tse2_inertia_J_sweep"] = weight_sweep(
        lambda i: liemef.MinimumEnergyFilter(PlanarRigidBody(J=(6.125, 7.0, 8.0)[i], D=np.diag([0.5] * 4 + [0.1] * 3),
                                                             Q=np.eye(7))),
        tse2_state0, tlog, 3, expected=0)

    progress("compile: log lengths")
    # logs of different lengths: one compilation per distinct bucket (the GPS sweep compiled the bucket of its log)
    flt = liemef.MinimumEnergyFilter(planar_localization())
    compiled = {bucket(len(log[0]) - 1)}
    _, (ts, us, ys) = localization_log(max(LENGTHS))
    before = traces("run")
    per_log = []
    for n in LENGTHS:
        log_n = (ts[:n], us[:n], ys[:n])
        b0 = traces("run")
        traj, first = timed(lambda log_n=log_n: flt.run(localization_state(flt), *log_n))
        assert traj.status.ok, traj.status.message(log_n[0])
        _, st = steady(lambda log_n=log_n: flt.run(localization_state(flt), *log_n), 1)
        per_log.append({"samples": n, "bucket": bucket(n - 1), "new_traces": traces("run") - b0,
                        "first_call_s": round(first, 3), "steady_call_s": round(st, 4),
                        "us_per_sample_steady": round(st / (n - 1) * 1e6, 2)})
    buckets = {bucket(n - 1) for n in LENGTHS}
    out["log_lengths"] = {"logs": len(LENGTHS), "distinct_buckets": len(buckets),
                          "buckets_compiled_before": len(buckets & compiled), "run_traces": traces("run") - before,
                          "expected_traces": len(buckets - compiled), "per_log": per_log}

    progress("compile: online step")
    # online step: two filters, different weights, one compilation
    fa = liemef.MinimumEnergyFilter(PlanarRigidBody())
    fb = liemef.MinimumEnergyFilter(PlanarRigidBody(D=np.diag([1.0] * 4 + [0.2] * 3), Q=np.eye(7)))
    ts, us, ys = tlog
    before = traces("step")
    res = {}
    for name, f in (("a", fa), ("b", fb)):
        st0 = tse2_state0(f)
        st, first = timed(lambda f=f, st0=st0: f.step(st0, float(ts[0]), us[0], ys[0], 1e-3))
        _, s = steady(lambda f=f, st=st: f.step(st, float(ts[1]), us[1], ys[1], 1e-3), 50)
        res[name] = (first, s, np.asarray(st.K))
    out["online_step_two_weights"] = {
        "step_traces": traces("step") - before, "expected_traces": 1,
        "first_call_s": {k: round(v[0], 4) for k, v in res.items()},
        "steady_call_us": {k: round(v[1] * 1e6, 1) for k, v in res.items()},
        "weights_differ_in_result": bool(not np.allclose(res["a"][2], res["b"][2])),
    }
    return out


def loc_errors(truth, traj, t_from=20.0):
    e = np.asarray(state_error(truth.g, traj.g_hat))
    ts = np.asarray(truth.ts)
    w = ts >= t_from
    return {"heading_rms_deg_t>=20s": round(float(np.degrees(np.sqrt(np.mean(e[w, 0] ** 2)))), 3),
            "position_rms_m_t>=20s": round(float(np.sqrt(np.mean(np.sum(e[w, 1:] ** 2, axis=1)))), 4),
            "heading_error_end_deg": round(float(np.degrees(e[-1, 0])), 3)}


def tse2_errors(truth, traj):
    e = np.asarray(state_error(truth.g, traj.g_hat))
    w = np.asarray(truth.ts) >= 5.0
    return {"theta_rms_mrad_t>=5s": round(float(np.sqrt(np.mean(e[w, 0] ** 2)) * 1e3), 3),
            "position_rms_mm_t>=5s": round(float(np.sqrt(np.mean(np.sum(e[w, 1:3] ** 2, axis=1))) * 1e3), 3)}


def substep_costs(repeats):
    """The variants are timed in interleaved rounds (auto, fixed, linear, auto, ...) so that a change of the
    machine's load hits all of them alike; each figure is the median over the rounds."""
    variants = (("auto", dict()), ("fixed_1", dict(substeps=1)), ("auto_linear", dict(interpolation="linear")))
    out = {}
    for scenario, system, (truth, log), state_of, errors in (
            ("tse2_1ms", PlanarRigidBody(), tse2_log(1 << 15), tse2_state0, tse2_errors),
            ("localization_100Hz_gps_1Hz", planar_localization(), localization_log((1 << 12) + 1), localization_state,
             loc_errors)):
        progress(f"substeps: {scenario}")
        steps = len(log[0]) - 1
        filters = {name: liemef.MinimumEnergyFilter(system, **kw) for name, kw in variants}
        calls = {name: (lambda flt=flt, init=state_of, log=log: flt.run(init(flt), *log))
                 for name, flt in filters.items()}
        trajs = {name: jax.block_until_ready(call()) for name, call in calls.items()}  # compile
        times = {name: [] for name in calls}
        cpus = {name: [] for name in calls}
        for _ in range(repeats):
            for name, call in calls.items():
                _, wall, used = timed(call, cpu=True)
                times[name].append(wall)
                cpus[name].append(used)
        res = {}
        for name, traj in trajs.items():
            st = traj.status
            res[name] = {"us_per_step": round(float(np.median(times[name])) / steps * 1e6, 3),
                         "cpu_us_per_step": round(float(np.median(cpus[name])) / steps * 1e6, 3), "ok": st.ok,
                         "substeps_per_step": round(int(st.substeps_total) / int(st.steps), 4),
                         "substeps_max": int(st.substeps_max), "substeps_capped": int(st.substeps_capped)}
            if st.ok:
                res[name].update(errors(truth, traj))
            else:
                res[name]["failure"] = st.message(log[0])
        res["steps"] = steps
        ratio = lambda a, b, k, res=res: round(res[a][k] / res[b][k], 3)  # noqa: E731
        res["ratios"] = {"auto_over_fixed_1": ratio("auto", "fixed_1", "us_per_step"),
                         "linear_over_hold": ratio("auto_linear", "auto", "us_per_step"),
                         "cpu_auto_over_fixed_1": ratio("auto", "fixed_1", "cpu_us_per_step"),
                         "cpu_linear_over_hold": ratio("auto_linear", "auto", "cpu_us_per_step")}
        out[scenario] = res
    return out


def step_latency(calls):
    progress("step latency")
    flt = liemef.MinimumEnergyFilter(PlanarRigidBody())
    _, (ts, us, ys) = tse2_log(calls)
    st = jax.block_until_ready(flt.step(tse2_state0(flt), float(ts[0]), us[0], ys[0], 1e-3))
    lat, cpu = np.empty(calls), np.empty(calls)
    for k in range(calls):
        c0, t0 = time.process_time(), time.perf_counter()
        st = flt.step(st, float(ts[k]), us[k], ys[k], 1e-3)
        jax.block_until_ready(st.K)
        lat[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
    assert st.status.ok
    us_ = lambda a: round(float(a) * 1e6, 2)  # noqa: E731
    return {"median_us": us_(np.median(lat)), "p90_us": us_(np.quantile(lat, 0.9)), "min_us": us_(lat.min()),
            "cpu_median_us": us_(np.median(cpu)), "cpu_p90_us": us_(np.quantile(cpu, 0.9)), "calls": calls}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--calls", type=int, default=2000)
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    source = source_version()  # at the start: the code this process imported
    t0 = time.perf_counter()
    results = {"compile": compile_counts(args.repeats), "substeps": substep_costs(args.repeats),
               "step_tse2": step_latency(args.calls)}
    c = results["compile"]
    results["checks"] = {k: v["run_traces"] == v["expected_traces"] for k, v in c.items() if "run_traces" in v}
    results["checks"]["online_step_two_weights"] = (c["online_step_two_weights"]["step_traces"]
                                                    == c["online_step_two_weights"]["expected_traces"])
    results["machine"] = {"python": platform.python_version(), "jax": jax.__version__, "liemef": liemef.__version__,
                          "cores_used": 1, "source": source, "loadavg_1min_start": round(load0, 2),
                          "loadavg_1min_end": round(os.getloadavg()[0], 2),
                          "wall_s": round(time.perf_counter() - t0, 1)}
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
