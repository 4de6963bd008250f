"""Key figures of the reproductions, Monte Carlo and comparisons, computed small: what ``test_pinned_figures``
pins bit for bit, so that a restructuring that changes no mathematics provably changes no number.

``OPENBLAS_CORETYPE=Haswell python tests/pinned_figures.py`` prints the figures as the JSON of
``tests/pinned_figures.json`` (the Haswell kernels, as tests/conftest.py asks: on an AVX-512 CPU OpenBLAS's own
kernels move a few figures at 1e-9). Write that
file anew only for a change that is meant to move numbers, and say which and why in the commit.
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np


def figures() -> dict[str, list[str]]:
    """Each figure's float64 values as ``float.hex`` strings, by name (engine: the default, then XLA)."""
    from liemef.studies.compare import LocalizationComparison, compare_localization
    from liemef.studies.experiments import chaplygin, localization, montecarlo, tse2

    out: dict[str, list[str]] = {}

    def put(name, values):
        out[name] = [float(x).hex() for x in np.ravel(np.asarray(values, dtype=np.float64))]

    mc = montecarlo(tse2.TSE2, tse2.TSE2Config(duration=2.0), runs=4, seed=0, batch_size=4, progress=False)
    put("montecarlo.tse2.mean", mc.mean)
    put("montecarlo.tse2.spread", mc.spread)
    mc = montecarlo("localization", localization.LocalizationConfig(duration=10.0, steady=5.0), runs=4, seed=0,
                    batch_size=4, progress=False)
    put("montecarlo.localization.mean", mc.mean)
    mc = montecarlo(chaplygin.CHAPLYGIN, chaplygin.ChaplyginConfig(duration=2.0, connection="minus"), runs=3, seed=1,
                    batch_size=3, progress=False)
    put("montecarlo.chaplygin-minus.mean", mc.mean)
    run = tse2.run(tse2.TSE2Config(duration=1.0))
    put("reproduce.tse2.error", run.arrays["error"][-1])
    put("reproduce.tse2.K_diag", run.arrays["K_diag"][-1])
    cmp = compare_localization(LocalizationComparison(runs=2, duration=10.0, steady=5.0, batch_size=2))
    for key in ("heading_rms", "position_rms", "nees_heading", "nees_position"):
        put(f"compare.localization.{key}", cmp["arrays"][key])
    saved = os.environ.get("LIEMEF_ENGINE")
    os.environ["LIEMEF_ENGINE"] = "xla"
    try:
        mc = montecarlo(tse2.TSE2, tse2.TSE2Config(duration=1.0), runs=2, seed=3, batch_size=2, progress=False)
        put("montecarlo.tse2.xla.mean", mc.mean)
    finally:
        if saved is None:
            del os.environ["LIEMEF_ENGINE"]
        else:
            os.environ["LIEMEF_ENGINE"] = saved
    return out


if __name__ == "__main__":
    import contextlib
    import math

    import liemef._config  # noqa: F401
    from liemef.codegen import _kernel

    # no background -O2 build (tests/conftest.py's _no_background_optimized_builds): it computes the quick
    # build's bits, and would only take a core from the suite's other worker
    _kernel.OPTIMIZE_AFTER_S = math.inf
    with contextlib.redirect_stdout(sys.stderr):  # the studies print their progress
        pinned = figures()
    json.dump(pinned, sys.stdout, indent=1, sort_keys=True)
    print()
