"""The ukfm 2D localization scenario (../shared/scenarios/ukfm_localization.md) as a liemef log, for the tests
of sparse GPS fixes: a circle of 5 m radius in 40 s, odometry at 100 Hz with stds (0.01 m/s, 0.01 m/s, 1 deg/s),
GPS at 1 Hz with 1 m std from t = 1 s, an initial heading error drawn with 45 deg std, the position known."""

import numpy as np

F_ODO, RADIUS, PERIOD = 100.0, 5.0, 40.0
K0 = np.diag([np.radians(45.0) ** 2, 1e-6, 1e-6])
"""Initial gain: the heading's variance (45 deg std), the position (nearly) known."""


def localization_log(seed: int, t_end: float = 40.0):
    """ts (N,), true (theta, x, y) (N, 3), us = (v_x, v_y, omega) (N, 3), ys (N, 2) with NaN between fixes, and the
    initial heading estimate (the true heading is 0)."""
    rng = np.random.default_rng(seed)
    ts = np.arange(int(round(t_end * F_ODO))) / F_ODO
    v, w = 2 * np.pi * RADIUS / PERIOD, 2 * np.pi / PERIOD
    th = w * ts
    truth = np.column_stack([th, RADIUS * np.sin(th), RADIUS * (1 - np.cos(th))])
    us = np.column_stack([v + 0.01 * rng.standard_normal(ts.size), 0.01 * rng.standard_normal(ts.size),
                          w + np.radians(1.0) * rng.standard_normal(ts.size)])
    ys = np.full((ts.size, 2), np.nan)
    fix = np.arange(100, ts.size, 100)
    ys[fix] = truth[fix, 1:] + rng.standard_normal((fix.size, 2))
    return ts, truth, us, ys, np.radians(45.0) * rng.standard_normal()


def circle_samples(N: int, fixes, gps_std: float):
    """The circle above from (0, 0) heading east, N samples at 100 Hz from t = 0, drawn with numpy's
    ``RandomState(0)`` (the logs of `liemef run`'s tests): ts (N,), the true positions p (N, 2), the headings th
    (N,), the odometry us (N, 3) with stds (0.01 m/s, 0.01 m/s, 1 deg/s) and ys (N, 2), GPS fixes at the sample
    indices ``fixes`` with std ``gps_std`` and NaN elsewhere."""
    rng = np.random.RandomState(0)
    dt, v, w = 1 / F_ODO, 2 * np.pi * RADIUS / PERIOD, 2 * np.pi / PERIOD
    th = np.arange(N) * w * dt
    p = np.concatenate([[[0.0, 0.0]], np.cumsum(v * dt * np.column_stack([np.cos(th), np.sin(th)]), axis=0)[:-1]])
    us = np.column_stack([v + 0.01 * rng.randn(N), 0.01 * rng.randn(N), w + np.pi / 180 * rng.randn(N)])
    ys = np.full((N, 2), np.nan)
    ys[fixes] = p[fixes] + gps_std * rng.randn(len(ys[fixes]), 2)
    return np.arange(N) * dt, p, th, us, ys
