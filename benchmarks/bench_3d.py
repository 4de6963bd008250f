"""Speed of the ready 3D systems on the C engine: ``pose3d()`` on SE(3) and ``inertial_navigation()`` on
SE_2(3) (and SE_2(3) x R^6 with biases), second order, RKMK4, one core.

For each system a log is simulated (``liemef.simulation.simulate``: a smooth body twist, or an IMU that turns
and accelerates against gravity) at 100 Hz, with sensors at their own rates (position fixes at 10 Hz for pose3d;
ukfm's three landmarks at 1 Hz for inertial navigation; GNSS at 10 Hz and a magnetometer at 100 Hz with
biases). It prints, as one JSON document:

* ``run``: the filter's ``run`` on the C engine, samples held over their interval (``updates="hold"``, the
  papers' scheme) and used at their own time (``updates="discrete"``, the hybrid filter): ``first_call_s``
  (trace, translation and the -O0 build into a fresh kernel cache, until the first result) and
  ``us_per_step``, per IMU sample (the -O2 kernel, median of ``--repeats`` runs), and ``substeps_per_sample``,
  the RKMK4 steps per IMU sample (the adaptive sub-steps split the intervals of a held sample with a large
  gain: held landmarks at 1 Hz, a magnetometer at 100 Hz);
* ``export_c``: ``liemef export-c``'s C of the same filter (hold), built with the kernel's flags, its export
  and build times and us per step on the same log, and its ratio to ``run``;
* ``targets`` (issue 21): ``inertial_navigation()`` ``run`` at most 10 us per IMU sample, and the exported C
  within 2x of it.

Figures from one run on a shared machine: compare the ratios measured together rather than absolute numbers
across runs.

    python benchmarks/bench_3d.py [--duration 20] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import one_core, time_run  # noqa: E402

one_core()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _provenance import source_version  # noqa: E402

import liemef  # noqa: E402
from liemef import codegen  # noqa: E402
from liemef.codegen import _kernel  # noqa: E402
from liemef.groups import SE3, SE23, Rn  # noqa: E402
from liemef.simulation import simulate  # noqa: E402
from liemef.systems import inertial_navigation, pose3d  # noqa: E402

RATE = 100.0
LANDMARKS = np.array([[0.0, 2.0, 2.0], [-2.0, -2.0, -2.0], [2.0, -2.0, -2.0]])  # ukfm's
MAX_INS_US, MAX_EXPORT_RATIO = 10.0, 2.0
"""Issue 21's targets on the C engine: inertial navigation at most 10 us per IMU sample, the export within 2x."""


def imu_input(t):
    """A body that turns about all three axes and accelerates, the accelerometer reading gravity too (world z
    up, the body near level)."""
    return jnp.array([0.1 * jnp.sin(t), 0.1 * jnp.cos(0.7 * t), 0.3, 0.5 * jnp.sin(0.5 * t), 0.2, 9.81])


def twist_input(t):
    return jnp.array([0.1, -0.05, 0.2, 1.0, 0.0, 0.2 * jnp.sin(0.5 * t)])


def thin(ys, every, columns=slice(None)):
    """Measurements of ``columns`` kept every ``every``-th row (NaN elsewhere and at t = 0)."""
    ys = np.array(ys)
    drop = np.arange(ys.shape[0]) % every != 0
    drop[0] = True
    ys[np.ix_(drop, np.arange(ys.shape[1])[columns])] = np.nan
    return ys


def cases(duration: float):
    """(name, system, g0 of the truth, K0, input function, sensor thinning). K0: the initial uncertainties of
    tests/test_systems_3d.py (attitude 0.35-0.5 rad, velocity 0.1 m/s, position 2 m, gyro bias 0.03 rad/s,
    accelerometer bias 0.2 m/s^2)."""
    ins_b = inertial_navigation(biases=True, gnss_std=0.5, mag_std=0.02)
    return [
        ("pose3d (position fixes at 10 Hz)", pose3d(), SE3.identity(), np.diag([0.5**2] * 3 + [2.0**2] * 3),
         twist_input,
         lambda ys: thin(ys, 10)),
        ("inertial_navigation (3 landmarks at 1 Hz)", inertial_navigation(landmarks=LANDMARKS), SE23.identity(),
         np.diag([0.5**2] * 3 + [0.1**2] * 3 + [2.0**2] * 3), imu_input, lambda ys: thin(ys, 100)),
        ("inertial_navigation biases=True (GNSS at 10 Hz, magnetometer at 100 Hz)", ins_b,
         ins_b.group((SE23.identity(), Rn[6](np.zeros(6)))),
         np.diag([0.35**2] * 3 + [0.1**2] * 3 + [2.0**2] * 3 + [0.03**2] * 3 + [0.2**2] * 3), imu_input,
         lambda ys: thin(thin(ys, 10, slice(0, 3)), 1)),
    ]


def time_export(flt, g0, K0, args, repeats):
    ts, us, ys = args[1:]
    g0_flat = np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(g0)])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        exported = codegen.export_c(flt, tmp, name="bench3d")
        t1 = time.perf_counter()
        cflt = codegen.CFilter(exported, flags=("-std=c99", "-O2", *_kernel.NATIVE))
        t2 = time.perf_counter()
        runs = []
        for _ in range(repeats):
            assert cflt.init(g0_flat, K0) == 0
            c0 = time.perf_counter()
            code, _, _ = cflt.run(ts, us, ys)
            runs.append(time.perf_counter() - c0)
            if code != 0:
                raise RuntimeError(f"the exported C failed with code {code}")
    return {"export_s": round(t1 - t0, 3), "build_s": round(t2 - t1, 3),
            "us_per_step": round(float(np.median(runs)) / (len(ts) - 1) * 1e6, 3)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of log at 100 Hz")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs after the first")
    a = ap.parse_args(argv)
    if codegen.compiler() is None:
        raise SystemExit("bench_3d: the C engine needs a C compiler ($CC, cc, gcc or clang); none was found")
    ts = np.arange(int(round(a.duration * RATE)) + 1) / RATE
    out = {"systems": {}, "source": source_version(), "machine": platform.machine(),
           "loadavg_1min": round(os.getloadavg()[0], 2)}
    for name, system, g0, K0, u_fn, thinning in cases(a.duration):
        _, log = simulate(system, g0, u_fn, ts, jax.random.key(0), substeps=4)
        args = (None, np.asarray(log.ts), np.asarray(log.us), thinning(log.ys))
        fig = {"n": system.group.tangent_dim, "run": {}}
        for updates in ("hold", "discrete"):
            flt = liemef.MinimumEnergyFilter(system, updates=updates)
            fig["run"][updates] = time_run(flt, (flt.init(g0, K0), *args[1:]), "c", a.repeats)
            status = flt.run(flt.init(g0, K0), *args[1:], engine="c").status
            fig["run"][updates]["substeps_per_sample"] = round(int(status.substeps_total) / (len(ts) - 1), 3)
        flt = liemef.MinimumEnergyFilter(system)
        fig["export_c"] = ex = time_export(flt, g0, K0, args, a.repeats)
        ex["over_run"] = round(ex["us_per_step"] / fig["run"]["hold"]["us_per_step"], 2)
        out["systems"][name] = fig
    ins = [f for k, f in out["systems"].items() if k.startswith("inertial_navigation (")][0]
    out["targets"] = {
        f"inertial_navigation run us/step <= {MAX_INS_US} (hold)": ins["run"]["hold"]["us_per_step"] <= MAX_INS_US,
        f"inertial_navigation run us/step <= {MAX_INS_US} (discrete)":
            ins["run"]["discrete"]["us_per_step"] <= MAX_INS_US,
        f"export_c over run <= {MAX_EXPORT_RATIO} (every system)":
            all(f["export_c"]["over_run"] <= MAX_EXPORT_RATIO for f in out["systems"].values()),
    }
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
