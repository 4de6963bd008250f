"""What a campaign on Dask costs: throughput with 1 and 2 local workers, the overhead per task, and an estimate
for a million seeds on a hundred machines.

Prints one JSON document (issue 10):

* ``throughput``: the same campaign (``examples/campaign/heading_experiment.py`` at 100 Hz for ``--duration``
  s, one setting, ``--seeds`` seeds in tasks of ``--trials-per-task``) on a ``LocalCluster`` of 1 and of 2
  single-threaded worker processes: trial-steps/s from the first result on (compilation excluded: the first
  result of each worker includes it) and over the whole run (start-up and compilation included), with the
  worker-side seconds per task. Both runs are measured in this one process, one after the other: compare
  their ratio, not absolute numbers across runs (``machine.loadavg`` says how busy the machine was).
* ``overhead``: per task, what is not the filter: a Dask round trip of an empty task (``--empty-tasks`` of them
  through the same 2-worker cluster: the scheduler's and the transport's cost per task), and the client's
  recording of one task (npz written atomically, SHA-256, manifest line with fsync).
* ``estimate_1e6_seeds_100_machines``: tasks, data volume, compile time, the load of the scheduler and of the
  client's recording, and which of them bounds the wall time, for 10^6 seeds of this campaign on 100 machines
  like this one (2 workers each), at the benchmarked task size and at the smallest task size that keeps the
  scheduler below 10 % busy; every assumption stated, derived from the measurements above, not measured.

    python benchmarks/bench_campaign.py [--seeds 512] [--duration 20] [--trials-per-task 64]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _provenance import source_version  # benchmarks/ is on sys.path when run as a script

from liemef.studies.campaign import Campaign, Store, run_campaign

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "campaign" / "heading_experiment.py"


def progress(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def campaign(out: Path, args) -> Campaign:
    return Campaign(name="bench", out=out, experiment_file=EXAMPLE, seeds=args.seeds, batch_size=args.batch_size,
                    trials_per_task=args.trials_per_task, base={"duration": args.duration, "dt": 0.01})


def throughput(workers: int, args, tmp: Path) -> dict:
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        started = time.perf_counter() - t0
        result = run_campaign(campaign(tmp / f"w{workers}", args), client=client, progress=False)
    store = Store(result.campaign)
    done = store.finished().values()
    seconds = [e.seconds for e in done]
    return {"workers": workers, "tasks": result.computed, "trial_steps": result.steps_computed,
            "cluster_start_s": round(started, 2), "campaign_s": round(result.elapsed, 2),
            "trial_steps_per_s": None if result.rate is None else round(result.rate),
            "trial_steps_per_s_wall": round(result.rate_wall),
            "worker_s_per_task": {"max_first_tasks": round(max(seconds), 3),
                                  "median": round(float(np.median(seconds)), 3)},
            "task_npz_bytes": int(np.median([(store.out / e.file).stat().st_size for e in done]))}


def _empty(i):
    return i


def overhead(args, tmp: Path) -> dict:
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        client.gather(client.map(_empty, range(10), pure=False))  # warm the connections
        t0 = time.perf_counter()
        client.gather(client.map(_empty, range(args.empty_tasks), pure=False))
        batch = (time.perf_counter() - t0) / args.empty_tasks
        lat = []
        for i in range(50):
            t0 = time.perf_counter()
            client.submit(_empty, i, pure=False).result()
            lat.append(time.perf_counter() - t0)
    c = campaign(tmp / "record", args)
    store = Store.open(c)
    task = c.tasks()[0]
    n = task.trials
    rec = []
    for _ in range(20):
        t0 = time.perf_counter()
        store.record(task, np.zeros((n, 2, 1, 3)), np.ones(n, bool), np.zeros(n, np.int32), 1, 0.0, "bench")
        rec.append(time.perf_counter() - t0)
    return {"empty_tasks": args.empty_tasks, "empty_task_s_in_a_batch": round(batch, 6),
            "empty_task_round_trip_s_median": round(float(np.median(lat)), 6),
            "record_task_s_median": round(float(np.median(rec)), 6)}


def _load(tpt: int, seeds: int, samples: int, per_worker: float, workers: int, sched_per_task: float,
          record_s: float, npz_bytes: int, compile_s: float) -> dict:
    tasks = -(-seeds // tpt)
    compute_s = seeds * samples / (per_worker * workers)
    busy = {"workers": 1.0, "scheduler": tasks * sched_per_task / compute_s,
            "client_recording": tasks * record_s / compute_s}
    return {"trials_per_task": tpt, "tasks": tasks, "task_compute_s": round(tpt * samples / per_worker, 2),
            "compute_s": round(compute_s, 1), "scheduler_tasks_per_s_needed": round(tasks / compute_s, 1),
            "scheduler_busy_fraction": round(busy["scheduler"], 3),
            "client_recording_busy_fraction": round(busy["client_recording"], 3),
            "bottleneck": max(busy, key=busy.get),
            "wall_s": round(compute_s * max(busy.values()) + compile_s, 1),
            "data_volume_bytes": tasks * npz_bytes, "manifest_bytes": tasks * 330}


def estimate(tp2: dict, tp1: dict, ov: dict, args) -> dict:
    seeds, machines, workers_per_machine = 10**6, 100, 2
    workers = machines * workers_per_machine
    samples = int(round(args.duration / 0.01)) + 1
    per_worker = tp1["trial_steps_per_s"]  # one worker process on one core, compilation excluded
    sched_per_task, record_s = ov["empty_task_s_in_a_batch"], ov["record_task_s_median"]
    compile_s = round(tp1["worker_s_per_task"]["max_first_tasks"] - args.trials_per_task * samples / per_worker, 1)
    as_run = _load(args.trials_per_task, seeds, samples, per_worker, workers, sched_per_task,
                   record_s, tp2["task_npz_bytes"], compile_s)
    # the smallest task (a whole number of batches) that keeps the scheduler below 10 % busy
    tpt = args.batch_size
    while _load(tpt, seeds, samples, per_worker, workers, sched_per_task, record_s, tp2["task_npz_bytes"],
                compile_s)["scheduler_busy_fraction"] > 0.1:
        tpt += args.batch_size
    return {
        "assumptions": [
            f"one setting of this campaign ({samples} samples per trial), {seeds} seeds",
            f"{machines} machines like this one, {workers_per_machine} single-threaded workers each "
            f"({workers} workers), each at the 1-worker rate measured here ({per_worker} trial-steps/s)",
            f"one Dask scheduler, {sched_per_task * 1e3:.2f} ms per task as measured here for empty tasks "
            "(on this 2-core machine beside its workers; it grows with the number of workers)",
            "results gathered to the client and written there one by one (file, SHA-256, fsync'd manifest line: "
            f"{record_s * 1e3:.2f} ms per task as measured here); the network moves the task files only",
            "each worker compiles the setting once, in parallel with the others (the first result's extra "
            "time measured here)"],
        "compile_s_per_worker_once": compile_s,
        "with_trials_per_task_as_benchmarked": as_run,
        "with_trials_per_task_for_scheduler_below_10_percent": _load(
            tpt, seeds, samples, per_worker, workers, sched_per_task, record_s, tp2["task_npz_bytes"], compile_s)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=512)
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of each trial at 100 Hz")
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--trials-per-task", type=int, default=64)
    ap.add_argument("--empty-tasks", type=int, default=1000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        progress("1 worker")
        tp1 = throughput(1, args, tmp)
        progress("2 workers")
        tp2 = throughput(2, args, tmp)
        progress("overhead per task")
        ov = overhead(args, tmp)
    ratio = None if not (tp1["trial_steps_per_s"] and tp2["trial_steps_per_s"]) else \
        round(tp2["trial_steps_per_s"] / tp1["trial_steps_per_s"], 2)
    doc = {"benchmark": "campaign", "source": source_version(),
           "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                       "loadavg": [round(v, 2) for v in os.getloadavg()]},
           "campaign": {"experiment": str(EXAMPLE.relative_to(ROOT)), "duration_s": args.duration, "dt_s": 0.01,
                        "seeds": args.seeds, "batch_size": args.batch_size,
                        "trials_per_task": args.trials_per_task},
           "throughput": {"1_worker": tp1, "2_workers": tp2, "speedup_2_over_1": ratio},
           "overhead": ov,
           "estimate_1e6_seeds_100_machines": estimate(tp2, tp1, ov, args)}
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
