"""From one run's truth, sensor log and filter trajectory to a :class:`~liemef.studies.experiments.Result`.

Shared by every experiment: the errors (coordinates and group), their statistics over the windows, the gain
summary and the arrays the figures are drawn from.
"""

from __future__ import annotations

import numpy as np

from ... import __version__
from ...filters import MinimumEnergyFilter, Trajectory
from ...metrics import (
    Window,
    angle_mask,
    continuous_angles,
    error_table,
    gain_stats,
    group_error,
    group_error_labels,
    state_error,
    state_labels,
)
from ...simulation import SensorLog, Truth
from ._base import SCHEMA, Experiment, Result, TrialSpec, config_dict

ERROR_DEFINITION = "truth - estimate in coordinates, angles wrapped to (-pi, pi] (Rigo et al. 2022, Sec. VI)"


def evaluate(experiment: Experiment, config, flt: MinimumEnergyFilter, truth: Truth, log: SensorLog,
             traj: Trajectory, measured: np.ndarray, windows: tuple[Window, ...], assumptions: dict,
             extra_metrics: dict | None = None, extra_arrays: dict | None = None) -> Result:
    """Errors, statistics and arrays of one run.

    ``measured`` (N, c) are the state coordinates read off the measurements (NaN where not measured), for
    the figures only. ``extra_metrics``/``extra_arrays`` are merged into ``metrics.json``/``arrays.npz``.
    """
    system = flt.system
    ts = np.asarray(truth.ts)
    names, units = state_labels(system)
    err = np.asarray(state_error(truth.g, traj.g_hat))
    gerr = np.asarray(group_error(truth.g, traj.g_hat))
    angles = angle_mask(system.group)
    filt_c = continuous_angles(traj.coords(), angles)
    K = np.asarray(traj.K)

    table = error_table(ts, err, names, units, windows)
    gnames, gunits = group_error_labels(system)
    gtable = error_table(ts, gerr, gnames, gunits, windows)
    metrics = {
        "schema": SCHEMA,
        "experiment": {"name": experiment.name, "title": experiment.title, "paper": experiment.paper},
        "config": config_dict(config),
        "assumptions": assumptions,
        "windows": table.windows_dict(),
        "errors": {"definition": ERROR_DEFINITION, "components": table.to_dict()},
        "group_errors": {"definition": "log(g_hat^-1 g), body frame", "components": gtable.to_dict()},
        "gain": gain_stats(K),
        "run": {"finite": bool(traj.ok), "samples": int(ts.shape[0]), "liemef_version": __version__,
                "filter": repr(flt)},
        "figures": [f.to_dict() for f in experiment.figures],
        **(extra_metrics or {}),
    }
    arrays = {
        "ts": ts, "names": np.array(names), "units": np.array(units),
        "truth": continuous_angles(truth.coords(), angles),
        "measured": continuous_angles(measured, angles, reference=filt_c),
        "filtered": filt_c, "error": err,
        "group_error": gerr, "group_error_names": np.array(gnames),
        "K_diag": np.diagonal(K, axis1=1, axis2=2),
        "u_nominal": np.asarray(truth.u), "us": np.asarray(log.us), "ys": np.asarray(log.ys),
        "output_names": np.array(system.output_names),
        **(extra_arrays or {}),
    }
    return Result(experiment=experiment.name, config=config, arrays=arrays, metrics=metrics, table=table,
                  figures=experiment.figures, raw={"truth": truth, "log": log, "trajectory": traj})


def state_error_trial(setup, trial, windows: tuple[Window, ...]) -> TrialSpec:
    """The Monte Carlo trial of an experiment whose errors are the state errors truth - estimate
    (:func:`~liemef.metrics.state_error`, the columns of its tables): ``trial(setup, key) -> (truth, log,
    trajectory)`` is its traceable run, ``setup`` has the ``system`` and the time grid ``ts``."""

    def errors(key):
        truth, _, traj = trial(setup, key)
        return state_error(truth.g, traj.g_hat)

    names, units = state_labels(setup.system)
    return TrialSpec(ts=setup.ts, names=names, units=units, windows=tuple(windows), errors=errors)
