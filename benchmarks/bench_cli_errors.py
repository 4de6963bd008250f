"""How fast ``liemef`` reports bad input: issue 19's target, a missing log column reported in under 2 s on an
idle machine, before JAX is imported.

Each case runs in a fresh interpreter (``python -c`` calling :func:`liemef.cli.main`, as the ``liemef`` script
does), ``--repeats`` times; the wall time is from the process start to its exit. The JSON printed has, per case,
the exit status, the min and median wall time (s), whether JAX was imported, and whether the 2 s target holds.
Cases: ``run`` with a CSV log missing a column (exit 2), ``run`` with an unknown ``--system`` choice (exit 2),
``schema localization`` (exit 0) and ``--help`` (exit 0, the startup floor).

    python benchmarks/bench_cli_errors.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _provenance import source_version  # noqa: E402

TARGET_S = 2.0
"""Issue 19's target: a missing column reported in under 2 s on an idle machine."""
PROBE = """
import sys
from liemef.cli import main
try:
    main(sys.argv[1:])
    code = 0
except SystemExit as exit:
    code = exit.code or 0
sys.stderr.write("\\nJAX_IMPORTED=%d\\n" % ("jax" in sys.modules))
sys.exit(code)
"""


def case(args: list[str], repeats: int) -> dict:
    """``liemef ARGS`` ``repeats`` times in fresh interpreters: exit status, wall times, JAX imported."""
    walls, codes, jax = [], set(), set()
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=600)
        walls.append(time.perf_counter() - t0)
        codes.add(res.returncode)
        jax.add("JAX_IMPORTED=1" in res.stderr)
    return {"args": args, "exit": sorted(codes), "wall_min_s": round(min(walls), 3),
            "wall_median_s": round(statistics.median(walls), 3), "jax_imported": sorted(jax) != [False],
            "under_target": max(walls) < TARGET_S}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="liemef-bench-cli-") as d:
        log = os.path.join(d, "missing.csv")
        with open(log, "w") as f:
            f.write("t,v_x,v_y,omega,gps_x\n0,1,0,0,0\n0.01,1,0,0,\n")
        cases = {
            "run, log missing a column": ["run", "--system", "localization", "--log", log, "--out",
                                          os.path.join(d, "out")],
            "run, unknown system": ["run", "--system", "nope", "--log", log, "--out", os.path.join(d, "out")],
            "schema localization": ["schema", "localization"],
            "--help": ["--help"],
        }
        results = {name: case(args, a.repeats) for name, args in cases.items()}
        for r in results.values():
            r["args"] = " ".join(x.replace(d, "TMP") for x in r["args"])
    print(json.dumps({"benchmark": "cli_errors", "target_s": TARGET_S, "repeats": a.repeats,
                      "python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count(),
                      "load_average": os.getloadavg(), "liemef": source_version(), "cases": results}, indent=2))


if __name__ == "__main__":
    main()
