"""``liemef compare broad`` (liemef.studies.compare._broad): which samples every filter's estimate has seen.

On 500 samples of BROAD trial 07 around its first movement (skipped when the real data are absent), every filter
of ``BROAD_FILTERS`` is built as the study builds it (``setup``: the filter, its initial state and its log from
the raw samples) and run with its raw gyro, accelerometer or magnetometer samples offset from some sample on.
The estimate at t_k (the whole state: attitude, bias, velocity) must not move when the samples after the ones
its lag (``lags``) says it has seen are perturbed, and must move when the newest one it has seen is: lag 0 is
"estimate k has seen sample k". An acausal filter's estimate k moves with the samples after k.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from liemef.studies import datasets
from liemef.studies.compare import _broad as B

TRIAL, N, K = "07", 500, 300
"""The trial, the samples of the window (100 at rest, then movement), and the estimate checked."""
OFFSETS = {"gyro": ("gyr", np.array([0.05, -0.03, 0.04])), "acc": ("acc", np.array([0.3, -0.2, 0.25])),
           "mag": ("mag", np.array([1.0, -2.0, 1.5]))}
"""Per sensor, the raw column and the offset added from a sample on (rad/s, m/s^2, uT)."""
SAME, MOVED = 1e-9, 1e-7
"""An estimate that differs by at most SAME has not moved; one that differs by more than MOVED has."""
SLOW = {"mef", "mef-first", "mef-minus", "mef-plus", "mef-robust", "mef-imu", "mef-imu-first", "mef-imu-d", "mef-vel",
        "mef-vel-safe", "mef-vel-first", "mef-pos", "mef-pos-first", "iekf-imu", "ukf-left"}
"""The filters whose lags the fast suite checks through a sibling built the same way (same log, same kind of
update: iekf, mef-imu-d-first, iekf-vel, iekf-pos); each takes several seconds to compile."""


@pytest.fixture(scope="module")
def window() -> datasets.BroadTrial:
    trials = datasets.broad_trials()
    if TRIAL not in trials:
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    tr = datasets.broad(trials[TRIAL])
    s = int(np.argmax(tr.movement)) - 100
    cut = {f: getattr(tr, f)[s:s + N] for f in ("gyr", "acc", "mag", "quat_true", "movement")}
    return dataclasses.replace(tr, ts=tr.ts[:N], **cut)


def perturbed(trial: datasets.BroadTrial, sensors, k: int) -> datasets.BroadTrial:
    """The trial with the raw samples of ``sensors`` offset from sample k on."""
    out = {}
    for s in sensors:
        column, offset = OFFSETS[s]
        v = getattr(trial, column).copy()
        v[k:] += offset
        out[column] = v
    return dataclasses.replace(trial, **out)


def estimates(name: str, ctx: dict, trial: datasets.BroadTrial) -> np.ndarray:
    """The filter's whole state at every t_k (N, all components), run as compare broad runs it."""
    flt, state, log = B.setup(name, ctx, B.trial_logs(trial))
    traj = flt.run(state, log.ts, log.us, log.ys)
    assert int(traj.status.code) == 0, traj.status.message(log.ts)
    return np.concatenate([np.asarray(x).reshape(N, -1) for x in jax.tree_util.tree_leaves(traj.g_hat)], axis=1)


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n
                                  for n in B.BROAD_FILTERS])
def test_estimate_k_has_seen_the_samples_its_lag_says(window, name):
    ctx = B.trial_context(window)  # the initial estimate and the rest calibration: the unperturbed window's
    flt, _, _ = B.setup(name, ctx, B.trial_logs(window))
    lag = B.lags(name, flt)
    base = estimates(name, ctx, window)

    def change(sensors, k):
        return np.abs(estimates(name, ctx, perturbed(window, sensors, k)) - base)

    if any(v is None for v in lag.values()):  # acausal: estimate k has seen the samples after k
        assert set(lag.values()) == {None}
        for s in B.SENSORS:
            assert change((s,), K + 1)[K].max() > MOVED, s
        return
    for s in B.SENSORS:
        newest = K - lag[s]  # the newest sample of s that estimate K has seen
        assert change((s,), newest + 1)[: K + 1].max() <= SAME, (s, lag)
        assert change((s,), newest)[K].max() > MOVED, (s, lag)
    # all sensors at once, from the sample after the newest one seen of any: nothing up to K moves
    assert change(B.SENSORS, K - min(lag.values()) + 1)[: K + 1].max() <= SAME, lag


def test_every_baseline_and_every_filter_at_its_own_time_has_seen_gyro_sample_k():
    """The baselines (VQF, ahrs's Madgwick and Mahony, Fusion) make estimate k from sample k, as BROAD indexes
    them; the filters of OWN_TIME have seen gyro sample k (their accelerometer and magnetometer sample k acts at
    t_k, after the state recorded there). Every row of the study says its lag."""
    from liemef.systems import attitude_gyro_bias

    ctx = {"dip": 1.0, "gravity": 9.81, "field": 50.0, "params": {}, "tuned_system": None,
           "g0": attitude_gyro_bias().group.identity()}
    for name, (_, make) in B.BROAD_FILTERS.items():
        flt = make(ctx)
        lag = B.lags(name, flt)
        assert set(lag) == set(B.SENSORS), name
        if getattr(flt, "offline", False):
            assert lag == dict.fromkeys(B.SENSORS), name
            assert "acausal" in B.BROAD_FILTERS[name][0], name
        elif hasattr(flt, "broad_indexing"):
            assert lag == dict.fromkeys(B.SENSORS, 0), name
        elif name in B.OWN_TIME:
            assert lag["gyro"] == 0 and lag["mag"] == 1, name
        else:
            assert lag == dict.fromkeys(B.SENSORS, 1), name
    assert {n for n, (_, make) in B.BROAD_FILTERS.items() if getattr(make(ctx), "offline", False)} == {
        "vqf-offline", "mef-vel-smooth"}
    assert B.lag_text(dict.fromkeys(B.SENSORS, None)) == "acausal"
    assert B.lag_text({"gyro": 0, "acc": 1, "mag": 1}) == "0 / 1 / 1"
