"""Reduction test: sparse samples on a linear system are the discrete Kalman filter (docs/weights.md).

System on R^2 (a damped oscillator driven by an input): ``x_dot = A x + G u + w``, w white of density
``diag(q^2)`` (``Noise.density(q)``), and a position sensor ``y_k = x_1(t_k) + v_k``, ``v_k ~ N(0, sigma^2)``,
one sample per measurement time (``Noise.sample(sigma)``). The reference is filterpy's ``KalmanFilter`` with the
exact discretization over the measurement period T: ``F = expm(A T)``, ``Q_d = int_0^T e^{A s} diag(q^2) e^{A' s} ds``
(Van Loan), ``B_d = int_0^T e^{A s} ds G`` (the input is held over the period).

Where the information goes. The engine spreads a sample's information ``1/sigma^2`` over the interval that follows
its time stamp, as a continuous measurement of weight ``1/(sigma^2 Delta)``; for a linear system the Riccati and
estimate equations over that interval, in the limit ``Delta -> 0``, are exactly the information-form Kalman update
(``K^-1 += H' H / sigma^2``, ``K^-1 x += H' y / sigma^2``). So the log has, at each measurement time t_k, the
sample at ``t_k`` and a time stamp without a sample at ``t_k + eps`` (eps = 2^-30 s), then M - 1 prediction steps
to ``t_{k+1} = t_k + T``. Then:

* the engine's state at ``t_k + eps`` is the Kalman posterior at t_k (``update``), and
* its state at ``t_{k+1}`` the Kalman prior there (``predict``),

up to O(eps) (dynamics over the update interval) plus the integration error of the sub-steps; with 10, 100 and
1000 RK4 sub-steps per interval the difference falls and reaches 1e-6.

On a uniform grid (the next time stamp ``t_k + dt``), the engine's state at ``t_k + dt`` is instead the Kalman
"update at t_k, then predict dt" up to O(dt): the measurement and the dynamics act over the same interval.
``test_uniform_grid_is_first_order_in_dt`` measures that.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.linalg import expm

import liemef
from liemef.groups import Rn
from liemef.systems import Noise, Sensor, SensorSystem
from tolerances import DISCRETE_KALMAN

R2 = Rn[2]
A = np.array([[0.0, 1.0], [-0.5, -0.2]])
G = np.array([[0.0], [1.0]])
H = np.array([[1.0, 0.0]])
Q_DENSITY = np.array([0.3, 0.5])
SIGMA = 0.5
X0, P0 = np.array([0.5, -0.3]), np.diag([1.0, 2.0])
T, M, N_MEAS = 0.5, 5, 20
EPS = 2.0**-30  # a power of two: t_k + eps and the difference back to eps are exact


def _dynamics(g, u, t):
    return jnp.asarray(A) @ g.x + jnp.asarray(G) @ u


def _position(g, t):
    return g.x[:1]


SYSTEM = SensorSystem(R2, _dynamics, (Sensor("pos", _position, Noise.sample(SIGMA)),), Noise.density(Q_DENSITY),
                      inputs=("a",))


def discretize(dt):
    """Exact discretization of (A, G, diag(q^2)) over dt (Van Loan for Q_d)."""
    n = 2
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n], V[:n, n:], V[n:, n:] = -A, np.diag(Q_DENSITY**2), A.T
    E = expm(V * dt)
    F = E[n:, n:].T
    Qd = F @ E[:n, n:]
    C = np.zeros((n + 1, n + 1))
    C[:n, :n], C[:n, n:] = A, G
    return F, 0.5 * (Qd + Qd.T), expm(C * dt)[:n, n:]


def data(seed=0, n_meas=N_MEAS):
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n_meas + 1), rng.standard_normal(n_meas + 1)  # u_k (held over period k), y_k


def kalman(uk, yk):
    """filterpy: at each t_k update with y_k, predict over the period T with u_k. Returns the posteriors (after
    the update at t_k) and the priors at t_{k+1}."""
    kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=1)
    kf.x, kf.P, kf.H, kf.R = X0.copy(), P0.copy(), H, np.array([[SIGMA**2]])
    posts, priors = [], []
    for k in range(len(yk) - 1):
        kf.update(np.array([yk[k]]))
        posts.append((kf.x.copy(), kf.P.copy()))
        kf.F, kf.Q, kf.B = discretize(T)
        kf.predict(u=np.array([uk[k]]))
        priors.append((kf.x.copy(), kf.P.copy()))
    return posts, priors


def impulsive_log(uk, yk):
    """Per period: t_k (sample), t_k + eps (none), t_k + j T/M for j = 1..M-1 (none); the input u_k throughout."""
    n_meas = len(yk) - 1
    ts = [np.concatenate([[k * T, k * T + EPS], k * T + T / M * np.arange(1, M)]) for k in range(n_meas)]
    ts = np.concatenate(ts + [[n_meas * T]])
    per = M + 1
    us = np.repeat(uk[:n_meas], per)
    us = np.append(us, uk[n_meas])[:, None]
    ys = np.full((ts.size, 1), np.nan)
    ys[::per, 0] = yk
    return ts, us, ys, per


def engine(substeps, ts, us, ys):
    flt = liemef.MinimumEnergyFilter(SYSTEM, order="first", substeps=substeps)
    traj = flt.run(flt.init(R2(jnp.asarray(X0)), P0), ts, us, ys, gap=1e9)
    assert traj.status.ok
    return np.asarray(traj.g_hat.x), np.asarray(traj.K)


def _err(x, K, ref, idx):
    return max(max(np.abs(x[i] - r[0]).max(), np.abs(K[i] - r[1]).max()) for i, r in zip(idx, ref, strict=True))


@pytest.fixture(scope="module")
def impulsive():
    uk, yk = data()
    ts, us, ys, per = impulsive_log(uk, yk)
    posts, priors = kalman(uk, yk)
    errors = {}
    for substeps in (10, 100, 1000):
        x, K = engine(substeps, ts, us, ys)
        errors[substeps] = (_err(x, K, posts, range(1, ts.size, per)), _err(x, K, priors, range(per, ts.size, per)))
    return errors, posts


def test_sparse_samples_are_the_discrete_kalman_filter(impulsive):
    """Estimate and K at every measurement time (posterior) and just before the next (prior) against filterpy:
    the error falls with the sub-steps and is below 1e-6 with 1000. Measured (max over 20 periods, x and K):
    10 sub-steps 3e-5, 100 5e-9, 1000 2e-9 (the O(eps) floor)."""
    errors, posts = impulsive
    print({n: f"posterior {a:.2g}, prior {b:.2g}" for n, (a, b) in errors.items()})
    assert posts[-1][1][0, 0] < 0.5 * P0[0, 0]  # the samples really inform the filter
    e = [max(errors[n]) for n in (10, 100, 1000)]
    assert e[0] > e[1] > e[2]
    assert e[1] < 1e-2 * e[0]
    assert e[2] <= DISCRETE_KALMAN


def test_auto_substeps_are_close_to_the_discrete_kalman_filter():
    """With substeps="auto" (the default: |K E| h <= 0.5 per sub-step) the same comparison is good to ~1e-4
    (measured 7.8e-5)."""
    uk, yk = data()
    ts, us, ys, per = impulsive_log(uk, yk)
    posts, priors = kalman(uk, yk)
    x, K = engine("auto", ts, us, ys)
    e = max(_err(x, K, posts, range(1, ts.size, per)), _err(x, K, priors, range(per, ts.size, per)))
    print(f"auto: {e:.3g}")
    assert e < 1e-3


def test_uniform_grid_is_first_order_in_dt():
    """Uniform grid of step dt = T/M, a sample every M steps: the engine at t_k + dt against "update at t_k, then
    predict dt" differs by O(dt) (measured 0.040 at dt = T/10 and 0.020 at dt = T/20), while the impulsive
    grid above is exact: the sample's information and the dynamics act over the same interval."""
    errs = []
    for m, n_meas in ((10, 12), (20, 6)):  # 121 samples each: the bucket and filter of substeps=100 above
        uk, yk = data(1, n_meas)
        dt = T / m
        ts = dt * np.arange(n_meas * m + 1)
        us = np.append(np.repeat(uk[:n_meas], m), uk[n_meas])[:, None]
        ys = np.full((ts.size, 1), np.nan)
        ys[::m, 0] = yk
        x, K = engine(100, ts, us, ys)
        posts, _ = kalman(uk, yk)
        # KF posterior at t_k predicted over dt
        F, Qd, Bd = discretize(dt)
        after = [(F @ p[0] + Bd[:, 0] * uk[k], F @ p[1] @ F.T + Qd) for k, p in enumerate(posts)]
        errs.append(_err(x, K, after, range(1, ts.size, m)))
    print(f"uniform grid: dt = T/10: {errs[0]:.3g}, dt = T/20: {errs[1]:.3g}")
    assert errs[0] > 1e-2  # not the Kalman filter at this dt ...
    assert 1.7 < errs[0] / errs[1] < 2.3  # ... but first order in dt
