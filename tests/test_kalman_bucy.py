"""Reduction test: on R^n with linear dynamics and output the filter is the Kalman-Bucy filter.

On the abelian group R^3, ad = 0, so the torsion, the connection Hessian correction and W vanish, and a
linear output has zero Hessian: every connection and both orders give

    x_hat_dot = F x_hat + G u + K H' D^-T Q D^-1 (y - H x_hat),
    K_dot = -alpha K + F K + K F' - K H' D^-T Q D^-1 H K + B R^-1 B'.

Each is checked against an independent scipy solution (``solve_ivp`` at rtol 1e-12 on the same zero-order-held
samples), and the stationary gain against ``scipy.linalg.solve_continuous_are``.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are

import liemef
from liemef.groups import Rn
from liemef.systems import System
from tolerances import ODE_REFERENCE, ROUNDOFF, STEADY_STATE

R3 = Rn[3]
_rng = np.random.default_rng(31)
F = np.array([[0.0, 1.0, 0.0], [-2.0, -0.3, 0.5], [0.4, 0.0, -0.8]]) + 0.2 * _rng.standard_normal((3, 3))
G = _rng.standard_normal((3, 2))
H = np.array([[1.0, 0.0, 0.0], [0.0, 0.3, 1.0]]) + 0.1 * _rng.standard_normal((2, 3))
B = _rng.standard_normal((3, 2))
D = np.array([[0.5, 0.1], [-0.2, 0.8]])
Q = np.array([[0.6, 0.1], [0.1, 0.25]])
R = np.array([[1.5, -0.4], [-0.4, 0.9]])
WY = np.linalg.inv(D).T @ Q @ np.linalg.inv(D)  # D^-T Q D^-1
BRB = B @ np.linalg.solve(R, B.T)
K0 = np.array([[1.0, 0.2, 0.0], [0.2, 2.0, -0.3], [0.0, -0.3, 0.5]])
ALPHA = 0.3
T_END, TS = 2.0, 0.005
VARIANTS = [(c, o) for c in ("zero", "minus", "plus") for o in ("second", "first")]


def linear_system() -> System:
    return System(group_type=R3, dynamics_fn=lambda g, u, t: jnp.asarray(F) @ g.x + jnp.asarray(G) @ u,
                  output_fn=lambda g, t: jnp.asarray(H) @ g.x, B=B, D=D, Q=Q, R=R, n_inputs=2)


def riccati(K, alpha):
    return -alpha * K + F @ K + K @ F.T - K @ H.T @ WY @ H @ K + BRB


def _samples():
    """Zero-order-held inputs and measurements of a noisy linear truth, every TS."""
    rng = np.random.default_rng(32)
    ts = np.arange(0.0, T_END + TS / 2, TS)
    us = np.column_stack([np.sin(2.0 * ts), np.cos(0.7 * ts)]) + 0.3 * rng.standard_normal((ts.size, 2))
    x, xs = np.array([1.0, -0.5, 0.3]), []
    for u in us:
        xs.append(x)
        x = x + TS * (F @ x + G @ u) + np.sqrt(TS) * B @ rng.standard_normal(2)
    ys = np.array(xs) @ H.T + rng.standard_normal((ts.size, 2)) @ D.T
    return ts, us, ys


def _run(connection, order, ts, us, ys, alpha=ALPHA, x0=(0.0, 0.0, 0.0), K_init=K0):
    flt = liemef.MinimumEnergyFilter(linear_system(), connection=connection, order=order, alpha=alpha)
    traj = flt.run(flt.init(R3(jnp.asarray(x0)), K_init), ts, us, ys)
    assert bool(traj.ok)
    return np.asarray(traj.g_hat.x), np.asarray(traj.K)


@pytest.fixture(scope="module")
def runs():
    ts, us, ys = _samples()
    return (ts, us, ys), {v: _run(*v, ts, us, ys) for v in VARIANTS}


def _reference(ts, us, ys, alpha=ALPHA):
    """Kalman-Bucy estimate and gain by solve_ivp, interval by interval with u_k, y_k held."""

    def rhs(t, z, u, y):
        x, K = z[:3], z[3:].reshape(3, 3)
        return np.concatenate([F @ x + G @ u + K @ H.T @ WY @ (y - H @ x), riccati(K, alpha).ravel()])

    z = np.concatenate([np.zeros(3), K0.ravel()])
    out = [z]
    for k in range(ts.size - 1):
        z = solve_ivp(rhs, (ts[k], ts[k + 1]), z, method="DOP853", rtol=1e-12, atol=1e-12,
                      args=(us[k], ys[k])).y[:, -1]
        out.append(z)
    out = np.array(out)
    return out[:, :3], out[:, 3:].reshape(-1, 3, 3)


def test_gain_matches_riccati_ode(runs):
    """(a) K(t) of every variant equals scipy's solution of the Riccati ODE (with forgetting factor alpha)."""
    (ts, _, _), results = runs
    sol = solve_ivp(lambda t, k: riccati(k.reshape(3, 3), ALPHA).ravel(), (0.0, ts[-1]), K0.ravel(),
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=ts)
    K_ref = sol.y.T.reshape(-1, 3, 3)
    assert np.abs(K_ref[-1] - K0).max() > 0.1  # the gain really moves
    for variant, (_, K) in results.items():
        dev = np.abs(K - K_ref).max()
        assert dev <= ODE_REFERENCE * np.abs(K_ref).max(), f"{variant}: max |K - K_ref| = {dev:.3g}"


def test_estimate_matches_kalman_bucy(runs):
    """(c) The estimate and gain equal the Kalman-Bucy filter integrated by scipy on the same held samples,
    at the RKMK4 step used (one step per sample interval, TS = 5 ms)."""
    (ts, us, ys), results = runs
    x_ref, K_ref = _reference(ts, us, ys)
    assert np.abs(x_ref[-1]).max() > 0.1  # the estimate really moves
    for variant, (x, K) in results.items():
        dev_x, dev_K = np.abs(x - x_ref).max(), np.abs(K - K_ref).max()
        assert dev_x <= ODE_REFERENCE * (1 + np.abs(x_ref).max()), f"{variant}: max |x - x_ref| = {dev_x:.3g}"
        assert dev_K <= ODE_REFERENCE * np.abs(K_ref).max(), f"{variant}: max |K - K_ref| = {dev_K:.3g}"


def test_all_connections_and_orders_coincide(runs):
    """On R^n the connection and the order do not matter: all variants give the same run to round-off."""
    _, results = runs
    x0, K0_ = results[VARIANTS[0]]
    for variant, (x, K) in results.items():
        assert np.abs(x - x0).max() <= ROUNDOFF * (1 + np.abs(x0).max()), variant
        assert np.abs(K - K0_).max() <= ROUNDOFF * np.abs(K0_).max(), variant


def test_terms_are_kalman_bucy():
    """The terms at a random state: A = F, E = H' D^-T Q D^-1 H, W = 0, r = H' D^-T Q D^-1 (y - H x)."""
    rng = np.random.default_rng(33)
    for connection, order in VARIANTS:
        flt = liemef.MinimumEnergyFilter(linear_system(), connection=connection, order=order)
        x, y, u = rng.standard_normal(3), rng.standard_normal(2), rng.standard_normal(2)
        K = rng.standard_normal((3, 3))
        tm = flt.terms(R3(jnp.asarray(x)), K, u, y, 0.0)
        for got, want in ((tm.A, F), (tm.E, H.T @ WY @ H), (tm.W, np.zeros((3, 3))), (tm.BRB, BRB),
                          (tm.r, H.T @ WY @ (y - H @ x)), (tm.lam, F @ x + G @ u)):
            assert np.abs(np.asarray(got) - want).max() <= ROUNDOFF * (1 + np.abs(want).max())


@pytest.mark.parametrize("connection", ["zero", "minus"])
def test_steady_state_gain_is_care(connection):
    """(b) With alpha = 0, K converges to the stabilizing solution of the filter algebraic Riccati equation
    F K + K F' - K H' W H K + B R^-1 B' = 0 (``solve_continuous_are(F', H', B R^-1 B', W^-1)``)."""
    K_care = solve_continuous_are(F.T, H.T, BRB, np.linalg.inv(WY))
    ts = np.arange(0.0, 40.0 + 0.025, 0.05)
    zeros_u, zeros_y = np.zeros((ts.size, 2)), np.zeros((ts.size, 2))
    _, K = _run(connection, "second", ts, zeros_u, zeros_y, alpha=0.0)
    assert np.abs(K[0] - K_care).max() > 0.1
    assert np.abs(riccati(K_care, 0.0)).max() <= ROUNDOFF * np.abs(K_care).max()  # a solution of the ARE
    dev = np.abs(K[-1] - K_care).max()
    assert dev <= STEADY_STATE * np.abs(K_care).max(), f"max |K(40 s) - K_care| = {dev:.3g}"
