"""The eight user systems of issue 22 on both engines: does each run on C, does C equal XLA, and how fast.

The systems are those of ``tests/test_user_systems_c.py`` (written as a user writes them from the docs:
``jnp.interp`` over t, a table indexed by a traced integer, ``argmax``, ``sort``, ``expm``, a state-dependent
``inv`` differentiated twice, ``cholesky``, a fixed ``fori_loop``), each filtered by the second-order
``MinimumEnergyFilter`` over a log of ``--steps`` samples (the test's log, longer), on one core. For each
system it prints, as one JSON document:

* ``on_c``: whether ``engine="auto"`` ran it on C (no ``EngineWarning``), else ``fallback``: the warning's
  text (the primitive and the user's line);
* ``max_rel_dev``: the largest deviation of the C run from the XLA run over every float leaf of the trajectory
  (estimates, weights, final state), relative to max(1, |XLA|); ``same_status``: the status counters equal;
* ``first_call_s``: the first ``run`` (trace, translation and the quick -O0 build into a fresh kernel cache;
  by XLA its compilation, with JAX's persistent cache off);
* ``cpu_us_per_step``: the median CPU time (``process_time``, all threads) per sample interval of
  ``--repeats`` runs after the first (by C: the -O2 build, waited for), and ``xla_over_c``, their ratio;
* ``loadavg_1min`` before and after.

The test asks C == XLA to ``USER_SYSTEM_C`` on 60 samples; this runs the same systems longer and times them.
Figures from a shared machine: compare the ratios measured together (C and XLA of one system run back to
back). A short check: ``--steps 200 --repeats 2 --only interp_over_t``.

    python benchmarks/bench_user_systems.py [--steps 2000] [--repeats 5] [--only NAME,NAME]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import cpu_model, one_core  # noqa: E402

one_core()  # before JAX starts its thread pools; each system's first C call is a first build

import jax  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402

import liemef  # noqa: E402
from liemef.engines import EngineWarning, LogGapWarning  # noqa: E402

jax.config.update("jax_enable_compilation_cache", False)  # XLA's first call compiles
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
import test_user_systems_c as users  # noqa: E402


def _cpu_per_step(flt, args, engine, repeats):
    runs = []
    for _ in range(repeats):
        c0 = time.process_time()
        jax.block_until_ready(flt.run(*args, engine=engine))
        runs.append(time.process_time() - c0)
    return round(float(np.median(runs)) / (len(args[1]) - 1) * 1e6, 3)


def _max_rel_dev(c, x) -> tuple[float, bool]:
    """The largest |C - XLA| / max(1, |XLA|) over the float leaves (inf where NaN differ), and whether the
    integer leaves (the status counters) are equal."""
    worst, same = 0.0, True
    for a, b in zip(jax.tree_util.tree_leaves(c), jax.tree_util.tree_leaves(x), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind in "iub":
            same &= bool(np.array_equal(a, b))
        elif not np.array_equal(np.isnan(a), np.isnan(b)):
            worst = float("inf")
        else:
            ok = ~np.isnan(b)
            worst = max(worst, float((np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(b[ok]))).max(initial=0.0)))
    return worst, same


def measure(name: str, steps: int, repeats: int) -> dict:
    system = users.USER_SYSTEMS[name]()
    flt = liemef.MinimumEnergyFilter(system)
    g0, ts, us, ys = users._log(system, n=steps)
    args = (flt.init(g0, np.eye(flt.n)), ts, us, ys)
    out = {}
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("ignore", LogGapWarning)
        warnings.simplefilter("always", EngineWarning)
        t0 = time.perf_counter()
        auto = jax.block_until_ready(flt.run(*args))
        out["first_call_s"] = {"auto": round(time.perf_counter() - t0, 3)}
    fallback = [str(w.message) for w in seen if issubclass(w.category, EngineWarning)]
    out["on_c"] = not fallback
    if fallback:
        out["fallback"] = fallback[0]
    warnings.simplefilter("ignore", LogGapWarning)
    t0 = time.perf_counter()
    x = jax.block_until_ready(flt.run(*args, engine="xla"))
    out["first_call_s"]["xla"] = round(time.perf_counter() - t0, 3)
    out["xla_ok"] = bool(x.ok)
    out["cpu_us_per_step"] = {"xla": _cpu_per_step(flt, args, "xla", repeats)}
    if out["on_c"]:
        kern = liemef.engines.kernel(flt, "c")
        kern.wait()  # time the -O2 build
        c = flt.run(*args, engine="c")
        out["max_rel_dev"], out["same_status"] = _max_rel_dev(c, x)
        out["auto_equals_c"] = _max_rel_dev(auto, c) == (0.0, True)
        out["cpu_us_per_step"]["c"] = _cpu_per_step(flt, args, "c", repeats)
        out["xla_over_c"] = round(out["cpu_us_per_step"]["xla"] / out["cpu_us_per_step"]["c"], 2)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="samples of each log (dt = 0.02 s)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs after the first, per engine")
    ap.add_argument("--only", default="", help="comma-separated system names (default: all eight)")
    a = ap.parse_args(argv)
    names = [n for n in a.only.split(",") if n] or list(users.USER_SYSTEMS)
    unknown = sorted(set(names) - set(users.USER_SYSTEMS))
    if unknown:
        ap.error(f"--only: expected names among {sorted(users.USER_SYSTEMS)}, got {unknown}")
    out = {"cpu": cpu_model(), "source": source_version(), "steps": a.steps, "repeats": a.repeats,
           "loadavg_1min": {"before": round(os.getloadavg()[0], 2)}, "systems": {}}
    for name in names:
        out["systems"][name] = measure(name, a.steps, a.repeats)
        print(f"{name}: {json.dumps(out['systems'][name])}", file=sys.stderr)
    out["loadavg_1min"]["after"] = round(os.getloadavg()[0], 2)
    out["on_c"] = f"{sum(s['on_c'] for s in out['systems'].values())} of {len(names)}"
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
