"""Which compiler makes the C engine's quick (-O0) kernels faster: GCC and Clang on the same translated kernel
sources, one after the other in this process's children, on one core.

For each ready system asked for, the default ``MinimumEnergyFilter``'s kernel source (``liemef.codegen._kernel``'s
translation, as a first call writes it) is compiled with the quick build's flags by each compiler found on the
PATH, ``--repeats`` times; it prints, as one JSON document, the median seconds of each and their ratio
(GCC / Clang), the source's size, the CPU model and the load before and after. The engine takes Clang for its
quick builds where it is on the PATH (``liemef.codegen._export.quick_compiler``): this is why.

    python benchmarks/bench_quick_build.py [--only tse2,attitude-bias,inertial-navigation] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import cpu_model, one_core  # noqa: E402

COMPILERS = ("gcc", "clang")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="tse2,attitude-bias,inertial-navigation", help="comma-separated ready systems")
    ap.add_argument("--repeats", type=int, default=3, help="builds per compiler and system (default 3)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: expected at least 1, got {args.repeats}")
    present = [cc for cc in COMPILERS if shutil.which(cc)]
    if len(present) < 2:
        ap.error(f"expected both of {COMPILERS} on the PATH, found {present}")
    one_core()
    import liemef
    from liemef.codegen import _kernel
    from liemef.codegen._export import run_compiler
    from liemef.studies.experiments import SYSTEMS

    names = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in SYSTEMS]
    if unknown:
        ap.error(f"--only: expected ready systems among {', '.join(sorted(SYSTEMS))}, got {', '.join(unknown)}")
    load = os.getloadavg()[0]
    systems = {}
    for name in names:
        source = _kernel._translate(_kernel._trace(liemef.MinimumEnergyFilter(SYSTEMS[name].make())))
        row = {"source_bytes": len(source)}
        with tempfile.TemporaryDirectory(prefix="liemef-bench-quick-") as tmp:
            with open(os.path.join(tmp, "kernel.c"), "w") as f:
                f.write(source)
            for cc in present:
                times = []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    run_compiler(_kernel.build_args(_kernel.QUICK_CFLAGS), cwd=tmp, cc=cc)
                    times.append(time.perf_counter() - t0)
                row[f"{cc}_s"] = round(statistics.median(times), 3)
        row["gcc_over_clang"] = round(row["gcc_s"] / row["clang_s"], 2)
        systems[name] = row
        print(f"{name}: {row}", file=sys.stderr, flush=True)
    print(json.dumps({"flags": list(_kernel.QUICK_CFLAGS), "repeats": args.repeats, "cpu": cpu_model(),
                      "loadavg_1min": [round(load, 2), round(os.getloadavg()[0], 2)], "systems": systems}, indent=1))


if __name__ == "__main__":
    main()
