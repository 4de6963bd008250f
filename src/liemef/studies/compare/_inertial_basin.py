r"""``liemef compare inertial-basin``: the convergence basin of every filter in the initial attitude error, on ukfm's
inertial-navigation benchmark (SE_2(3)).

The scenario is :mod:`liemef.studies.experiments.inertial` with the initial attitude error set instead of drawn:
for each angle $\alpha$ in ``angles_deg`` and each trial, $\hat C_0 = C_0 \exp(\alpha n)$ about a random unit axis
n (from the trial key, as in ``liemef compare attitude-basin``), the initial position error drawn as in the
scenario (1/sqrt(3) m per axis) and the velocity exact. The filters' prior is K0 = diag(s^2 I3, 0, p0_std^2 I3)
with ``prior_std_deg`` s per axis: the scenario's 15/sqrt(3) deg would tell every filter that a 90 deg error is
a 10-sigma event, so the default is 90 deg, as in the attitude basin. Trial i at every angle uses the noise of
``split(key(seed), runs)[i]``, the same for every filter, so the basins are paired; the angle is a traced argument
(one compilation per filter).

A trial **converges** when the filter stays healthy and its attitude error $|\mathrm{Log}(C^\top\hat C)|$ stays
below ``tolerance_deg`` over the last quarter of the run; its **time to converge** is the first time after which
the error stays below the tolerance to the end (:func:`liemef.studies.compare._basins.convergence`). Reported per
filter and angle: the fraction that converge with its 95 % Wilson interval, the median and 90th percentile of the
time to converge, and the NEES per degree of freedom over the last quarter (K as the covariance of the 9-dim left
error) of the trials that converge. The tables and figure are those of ``attitude-basin``
(:mod:`liemef.studies.compare._attitude_basin`), with this study as its one system.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
import time
from dataclasses import dataclass

import equinox as eqx
import jax
import numpy as np

from ...groups import SE23, SO3
from ...metrics import left_error, nees
from ..experiments import inertial as I
from . import _attitude_basin
from ._attitude_basin import _axis, _row
from ._basins import basin_trials, check_basin_settings, convergence, fraction_and_time, last_quarter, progress_line
from ._common import FILTERS, make_filter

SYSTEM = "inertial-navigation"
DEFAULT_FILTERS = ("mef", "mef-first", "mef-minus", "mef-plus", "iekf-right", "ekf", "ukf-left", "ukf-right",
                   "ukf-local")
DEFAULT_ANGLES = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 179.0)


@dataclass(frozen=True)
class InertialBasin:
    """The study's settings (module docstring)."""

    runs: int = 20
    seed: int = 0
    duration: float = 30.0
    angles_deg: tuple[float, ...] = DEFAULT_ANGLES
    prior_std_deg: float = 90.0
    tolerance_deg: float = 5.0
    filters: tuple[str, ...] | str | None = DEFAULT_FILTERS
    batch_size: int = 1  # liemef.studies.compare._inertial.BATCH_NOTE

    def __post_init__(self):
        check_basin_settings(self, DEFAULT_FILTERS)

    @property
    def config(self) -> I.InertialConfig:
        """The scenario on this study's duration (the window of the steady rms is unused here)."""
        return I.InertialConfig(duration=self.duration, steady=0.0)

    @property
    def K0(self) -> np.ndarray:
        """diag((prior_std_deg)^2 I3, 0, p0_std^2 I3)."""
        c = self.config
        return np.diag([math.radians(self.prior_std_deg) ** 2] * 3 + [0.0] * 3 + [c.p0_std**2] * 3)


@functools.lru_cache(maxsize=4)
def _trial_fn(config: I.InertialConfig):
    s = I.setup(config)

    def one(flt, state0, key, alpha):
        draws = I.jax_draws(config, key)
        log, g0_hat = I.sensor_log(config, s.truth, s.u_true, draws)
        g0 = jax.tree_util.tree_map(lambda a: a[0], s.truth)
        g0_hat = SE23.from_rotation_velocity_position(g0.rotation() @ SO3.exp(alpha * _axis(key)),
                                                      g0_hat.velocity(), g0_hat.position())
        traj = flt.scan(eqx.tree_at(lambda st: st.g_hat, state0, g0_hat), log.ts, log.us, log.ys)
        err = I.series(s.truth, traj.g_hat, traj.K)[:, 0]
        return err, traj.status.code, nees(left_error(s.truth, traj.g_hat), traj.K) / 9.0

    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, 0, None)))


def compare_inertial_basin(study: InertialBasin | None = None, *, progress: bool = True) -> dict:
    """Run the study; returns ``{"study", "systems", "arrays"}`` in the layout of ``attitude-basin``, with one
    system (per filter and angle: converged fraction, its Wilson interval, times to converge, NEES)."""
    st = InertialBasin() if study is None else study
    config = st.config
    s = I.setup(config)
    ts = config.ts
    keys = jax.random.split(jax.random.key(st.seed), st.runs)
    fn = _trial_fn(config)
    g0 = jax.tree_util.tree_map(lambda a: a[0], s.truth)
    last = last_quarter(ts)
    per_filter, frac, t_med = {}, [], []
    for name in st.filters:
        t0 = time.perf_counter()
        flt = make_filter(name, s.system)
        state0 = flt.init(g0, st.K0)
        rows = []
        for a in st.angles_deg:
            err, code, nees_dof = basin_trials(fn, flt, state0, keys, a, st.batch_size)
            rows.append(_row(a, *convergence(ts, err, code, st.tolerance_deg), code, nees_dof[:, last].mean(axis=1)))
        per_filter[name] = {"filter": FILTERS[name][0], "angles": rows, "elapsed_s": time.perf_counter() - t0}
        fr, tm = fraction_and_time(rows)
        frac.append(fr)
        t_med.append(tm)
        if progress:
            print(progress_line(name, rows, per_filter[name]["elapsed_s"]), file=sys.stderr, flush=True)
    key = SYSTEM.replace("-", "_")
    setup = (f"ukfm's inertial-navigation benchmark (../shared/scenarios/ukfm_inertial_navigation.md), "
             f"{config.duration:g} s at {1 / config.dt:g} Hz, landmarks at {1 / config.obs_period:g} Hz; K0 = "
             f"diag(({st.prior_std_deg:g} deg)^2 I3, 0, ({config.p0_std:.3g} m)^2 I3)")
    return {"study": {**dataclasses.asdict(st),
                      "initial_estimate": "C_hat0 = C0 exp(alpha n), n a random unit axis per trial (from the trial "
                                          "key); the position error drawn as in the scenario, the velocity exact",
                      "keys": f"trial i uses jax.random.split(jax.random.key({st.seed}), {st.runs})[i] at every "
                              "angle and for every filter"},
            "systems": {SYSTEM: {"description": "extended pose on SE_2(3): IMU input, three landmarks in the body "
                                                "frame", "setup": setup, "samples": int(ts.size), "dof": 9,
                                 "filters": per_filter}},
            "arrays": {"angles_deg": np.asarray(st.angles_deg), "systems": np.array([SYSTEM]),
                       f"{key}_filters": np.array(st.filters), f"{key}_fraction": np.asarray(frac),
                       f"{key}_time_median": np.asarray(t_med)}}


markdown = _attitude_basin.markdown
csv_rows = _attitude_basin.csv_rows
save = functools.partial(_attitude_basin.save, stem="inertial_basin")

__all__ = ["InertialBasin", "compare_inertial_basin", "markdown", "save", "DEFAULT_FILTERS"]
