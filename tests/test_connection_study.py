"""The connections studied (docs/connections.md): why the (-)-connection cannot correct heading from position,
and which Theorem 4.1 gain equation propagates the exact Hessian of the value function.

* On the localization system (odometry as the input, state-independent lambda) the engine's A is
  ``-2c ad_lambda``; with c = 0, A = W = 0 and the heading row of E vanishes, so the heading row of K stays
  ``(K00, 0, 0)`` and the heading is dead-reckoned forever, while c = 1/2 corrects it.
* The exact rate of the gain is computed independently of the Riccati formulas: one explicit step of the
  Hamilton-Jacobi-Bellman equation from a value function V0 (minimum at g_hat, Hessian K^{-1}), the new
  minimizer and the new Hessian by autodiff, and d/dh at h = 0 by forward-mode autodiff. At r = 0 it equals
  the (0)-connection's K-dot (and the first-order filter's when y_tilde = 0); c = 0 and c = 1 differ from it by
  exactly ``-(T_lambda K + K T_lambda^T)``. At r != 0 the exact rate has one more term, ``-K V'''(K r) K``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef import MinimumEnergyFilter
from liemef.groups import SE2, TSE2
from liemef.studies.experiments.localization import LocalizationConfig, jax_draws, setup, trial
from liemef.systems import PlanarRigidBody, planar_localization
from tolerances import ROUNDOFF

CONNECTIONS = [("minus", 0.0), ("zero", 0.5), ("plus", 1.0)]
DIFFERENT = 1e-2
"""The smallest relative difference counted as 'different' (the differences checked are 4 % or more)."""


def assert_close(actual, desired, tol, err_msg=""):
    np.testing.assert_allclose(np.asarray(actual), np.asarray(desired), rtol=tol, atol=tol, err_msg=err_msg)


def relative(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.abs(a - b).max() / np.abs(b).max()


def ad_se2(xi):
    """ad of se(2) in the order (omega, vx, vy), written out: [X, Y] = (0, omega J v' - omega' J v)."""
    w, vx, vy = xi
    return np.array([[0.0, 0.0, 0.0], [vy, 0.0, -w], [-vx, w, 0.0]])


def hat_se2(xi):
    w, vx, vy = xi
    return np.array([[0.0, -w, vx], [w, 0.0, vy], [0.0, 0.0, 0.0]])


def test_ad_se2_is_the_commutator():
    rng = np.random.default_rng(1)
    X, Y = rng.standard_normal((2, 3))
    C = hat_se2(X) @ hat_se2(Y) - hat_se2(Y) @ hat_se2(X)
    assert_close(ad_se2(X) @ Y, [C[1, 0], C[0, 2], C[1, 2]], ROUNDOFF)


# --- 1. A = -2c ad_lambda on the localization system, and the structure that freezes the heading ------------

@pytest.fixture(scope="module")
def localization_filters():
    system = planar_localization()
    return _filters(system)


def _filters(system):
    return {name: MinimumEnergyFilter(system, curvature="exact", connection=name) for name, _ in CONNECTIONS} | {
        "first": MinimumEnergyFilter(system, order="first")}


def test_A_is_minus_2c_ad_lambda_and_the_minus_connection_freezes_the_heading_row(localization_filters):
    rng = np.random.default_rng(20260601)
    for _ in range(3):
        g = SE2.exp(rng.standard_normal(3) * [2.0, 5.0, 5.0])
        M = rng.standard_normal((3, 3))
        K = M @ M.T + 0.1 * np.eye(3)
        u = rng.standard_normal(3)  # (vx, vy, omega)
        lam = np.array([u[2], u[0], u[1]])
        y = np.asarray(g.translation()) + rng.standard_normal(2)  # a fix with a residual: r != 0
        for name, c in CONNECTIONS:
            tm = localization_filters[name].terms(g, K, u, y, 0.0, dt=0.01)
            assert_close(tm.lam, lam, ROUNDOFF)
            assert_close(tm.Dlam, np.zeros((3, 3)), 0.0)  # state-independent lambda
            assert_close(tm.A, -2.0 * c * ad_se2(lam), ROUNDOFF, err_msg=name)
            # a position fix sees no heading direction: Dh[:, 0] = 0, so r[0] = 0
            assert_close(tm.Dh[:, 0], np.zeros(2), 0.0)
            assert tm.r[0] == 0.0 and np.abs(tm.r[1:]).max() > 0.1
            if name == "minus":
                assert_close(tm.A, np.zeros((3, 3)), 0.0)
                assert_close(tm.W, np.zeros((3, 3)), 0.0)
                assert_close(tm.BRB, np.diag(np.diag(tm.BRB)), 0.0)  # model error feeds no coupling
                # the (-)-connection E's heading row (second argument e_0: a rotation after the move
                # does not move the position) vanishes; its heading column does not
                assert_close(tm.E[0], np.zeros(3), ROUNDOFF)
                assert np.abs(tm.E[1:, 0]).max() > 1e-2
            if name == "zero":
                assert_close(tm.E, tm.E.T, ROUNDOFF)
                assert np.abs(tm.E[0, 1:]).max() > 1e-2


# --- 2. the scenario: the (-)-connection dead-reckons the heading, the (0)-connection corrects it ----------------

THETA0 = 1.2  # standard normals: 1.2 x 45 deg = 54 deg initial heading error


def _run(connection: str, duration: float = 10.0):
    """The scenario shortened to ``duration`` (the circle is driven once in it), seed 3, 54 deg initial heading
    error, with the scenario's filter (second order, RKMK4, adaptive sub-steps)."""
    config = LocalizationConfig(duration=duration, connection=connection, steady=duration / 2)
    s = setup(config)
    draws = jax_draws(config, jax.random.key(3))._replace(theta0=jnp.asarray(THETA0))
    run = jax.jit(lambda d: trial(s, d)).lower(draws).compile()
    truth, log, traj = run(draws)
    assert bool(traj.ok)
    return config, truth, log, traj


def _heading_error_deg(truth, traj):
    e = np.asarray(traj.g_hat.rotation().angle() - truth.g.rotation().angle())
    return np.degrees(np.angle(np.exp(1j * e)))


def test_minus_connection_never_corrects_the_heading():
    config, truth, log, traj = _run("minus")
    K = np.asarray(traj.K)
    # K0 = diag(theta0^2, 0, 0): the heading row of K stays (K00, 0, 0) through every fix ...
    assert np.abs(K[:, 0, 1:]).max() <= ROUNDOFF * np.abs(K).max()
    # ... while its heading column fills (a heading error does enter the position block's model) ...
    assert np.abs(K[-1, 1:, 0]).max() > 1e-6
    # ... and K00 grows by the odometry's yaw-rate density alone: theta0^2 + sigma_w^2 dt t
    sigma_w = config.odometry_std[2]
    assert_close(K[:, 0, 0], config.theta0_std**2 + sigma_w**2 * config.dt * np.asarray(log.ts), 1e-9)
    # so the heading is dead-reckoned: theta_hat_n = theta_hat_0 + sum_{m < n} omega_m dt, through 9 fixes
    theta = np.unwrap(np.asarray(traj.g_hat.rotation().angle()))
    dead = theta[0] + np.concatenate([[0.0], np.cumsum(np.asarray(log.us)[:-1, 2] * config.dt)])
    assert_close(theta, dead, 1e-9)
    e = _heading_error_deg(truth, traj)
    assert abs(e[0]) > 50.0 and np.abs(e - e[0]).max() < 2.0  # the odometry's random walk only


def test_zero_connection_corrects_the_heading():
    _, truth, _, traj = _run("zero")
    K = np.asarray(traj.K)
    assert np.abs(K[1:, 0, 1:]).max() > 1e-2  # the heading-position coupling A creates
    e = _heading_error_deg(truth, traj)
    assert abs(e[0]) > 50.0 and abs(e[-1]) < 5.0


# --- 3. the exact rate of the gain, from the HJB equation, against Theorem 4.1's K-dot ------------------------

def _chart(g_hat, gg):
    """phi(g) = vee(g_hat^{-1} g - I) (matrices): phi(g_hat exp xi) = xi + O(|xi|^2), polynomial in the matrix,
    so V0 = phi^T X0 phi / 2 has its minimum at g_hat with Hessian X0 and a nonzero third derivative."""
    G = type(g_hat)
    M = g_hat.inverse().as_matrix() @ gg.as_matrix()
    return G.vee(M - jnp.eye(G.matrix_dim))


def exact_rates(system, weights, g_hat, X0, u, y, t):
    r"""The exact $(\hat g^{-1}\dot{\hat g}, \dot X)$ of the minimum-energy filter at one instant, from the
    HJB equation $\partial_t V = \ell - \mu\cdot\lambda - \tfrac12 \mu^\top B R^{-1} B^\top \mu$
    ($\mu$ the left-trivialized differential of V, $\ell = \tfrac12 |y - h|^2_{W_y}$, alpha = 0) with
    $V_0 = \tfrac12 \varphi^\top X_0 \varphi$: $V_h = V_0 + h\,\partial_t V$, its minimizer $\hat g\exp\xi_h$
    (one Newton step with $X_0$: exact to $O(h^2)$) and its Hessian there, differentiated in h at 0.
    Also returns the third derivative of $\xi \mapsto V_0(\hat g \exp \xi)$ at 0 (the term no finite filter
    keeps). Nothing here uses A, E, W, ad or a connection."""
    G = type(g_hat)
    n = G.tangent_dim
    zero = jnp.zeros(n)
    basis = G.hat(jnp.eye(n))  # hat(e_j), (n, m, m)
    Minv = g_hat.inverse().as_matrix()

    def V0(gg):
        phi = _chart(g_hat, gg)
        return 0.5 * phi @ X0 @ phi

    def mu0(gg):  # d/ds V0(gg exp(s e_j)) at 0, in closed form: phi is linear in the matrix
        J = jax.vmap(lambda E: G.vee(Minv @ gg.as_matrix() @ E))(basis).T
        return J.T @ X0 @ _chart(g_hat, gg)

    def Vh(gg, h):
        mu = mu0(gg)
        e = y - system.output(gg, t)
        return V0(gg) + h * (0.5 * e @ weights.Wy @ e - mu @ system.dynamics(gg, u, t) - 0.5 * mu @ weights.BRB @ mu)

    def minimizer_and_hessian(h):
        xi = -jnp.linalg.solve(X0, jax.jacfwd(lambda x: Vh(g_hat.rplus(x), h))(zero))
        gh = g_hat.rplus(xi)
        return xi, jax.jacfwd(jax.jacfwd(lambda eta: Vh(gh.rplus(eta), h)))(zero)

    _, (nu, Xdot) = jax.jvp(minimizer_and_hessian, (0.0,), (1.0,))
    third = jax.jacfwd(jax.jacfwd(jax.jacfwd(lambda xi: V0(g_hat.rplus(xi)))))(zero)
    return nu, Xdot, third


def _compiled(filters, g, K, u, y):
    """One compiled function per system: the exact rates and every filter's vector field at a state."""
    flt = filters["zero"]

    def both(g, X0, u, y):
        theorem = {name: f.vector_field(g, jnp.linalg.inv(X0), u, y, 0.0) for name, f in filters.items()}
        return exact_rates(flt.system, flt.weights, g, X0, u, y, 0.0), theorem

    X0 = jnp.asarray(np.linalg.inv(K))
    fn = jax.jit(both).lower(g, X0, jnp.asarray(u), jnp.asarray(y)).compile()
    return lambda y: jax.tree_util.tree_map(np.asarray, fn(g, X0, jnp.asarray(u), jnp.asarray(y)))


def _check_against_theorem(evaluate, lam, ad, K, y, first_order_equal: bool):
    """At r = 0: the (0)-connection's K-dot is the exact one; c = 0 and c = 1 differ by exactly
    -(T_lam K + K T_lam^T), T_lam = (2c - 1) ad_lam; the first-order one is exact iff y_tilde = 0."""
    (nu, Xdot, _), theorem = evaluate(y)
    Kdot_exact = -K @ Xdot @ K
    scale = np.abs(Kdot_exact).max()
    assert np.abs(ad @ K + K @ ad.T).max() > 2 * DIFFERENT * scale
    for name, c in CONNECTIONS:
        xi, Kdot = theorem[name]
        assert_close(xi, nu, ROUNDOFF * 100, err_msg=name)  # the filter equation: exact for every c
        assert np.abs(xi - lam).max() < ROUNDOFF * 100  # r = 0: no correction
        torsion = (2 * c - 1) * ad
        assert_close(Kdot / scale, (Kdot_exact - torsion @ K - K @ torsion.T) / scale, ROUNDOFF * 100,
                     err_msg=name)
        if c == 0.5:
            assert_close(Kdot / scale, Kdot_exact / scale, ROUNDOFF * 100)
        else:
            assert relative(Kdot, Kdot_exact) > DIFFERENT, name
    Kdot = theorem["first"][1]
    if first_order_equal:
        assert_close(Kdot / scale, Kdot_exact / scale, ROUNDOFF * 100)
    else:
        assert relative(Kdot, Kdot_exact) > DIFFERENT


def test_exact_gain_rate_localization(localization_filters):
    rng = np.random.default_rng(7)
    g = SE2.exp(rng.standard_normal(3) * [1.0, 3.0, 3.0])
    M = rng.standard_normal((3, 3))
    K = M @ M.T + 0.3 * np.eye(3)
    u = np.array([0.8, 0.1, 0.3])
    lam = np.array([u[2], u[0], u[1]])
    evaluate = _compiled(localization_filters, g, K, u, np.zeros(2))
    y = np.asarray(g.translation())  # r = 0 (and y_tilde = 0: Dh has full row rank)
    _check_against_theorem(evaluate, lam, ad_se2(lam), K, y, first_order_equal=True)

    # r != 0: the exact rate has one more term, -K V0'''(K r) K, that no finite filter carries; with it the
    # (0)-connection's K-dot is exact again (Theorem 4.1 neglects the third derivative of V)
    y = y + rng.standard_normal(2)
    (nu, Xdot, third), theorem = evaluate(y)
    Kdot_exact = -K @ Xdot @ K
    xi, Kdot = theorem["zero"]
    Kr = xi - lam
    assert np.abs(Kr).max() > 0.1
    assert_close(xi, nu, ROUNDOFF * 100)
    T_Kr = np.einsum("ijk,k->ij", third, Kr)
    scale = np.abs(Kdot_exact).max()
    assert_close((Kdot - K @ T_Kr @ K) / scale, Kdot_exact / scale, ROUNDOFF * 100)
    assert relative(Kdot, Kdot_exact) > DIFFERENT


def test_exact_gain_rate_planar_rigid_body():
    # TSE(2): lambda depends on the state (the velocities), D lambda != 0; p = 7 > rank Dh = 6
    system = PlanarRigidBody()
    filters = _filters(system)
    rng = np.random.default_rng(11)
    g = TSE2.exp(rng.standard_normal(6) * [1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
    M = rng.standard_normal((6, 6))
    K = M @ M.T + 0.3 * np.eye(6)
    u = np.array([0.7, 20.0])
    h0 = np.asarray(system.output(g, 0.0))
    lam = np.asarray(system.dynamics(g, jnp.asarray(u), 0.0))
    zero = jnp.zeros(6)
    Dlam = np.asarray(jax.jacfwd(lambda xi: system.dynamics(g.rplus(xi), jnp.asarray(u), 0.0))(zero))
    Dh = np.asarray(jax.jacfwd(lambda xi: system.output(g.rplus(xi), 0.0))(zero))
    assert np.abs(Dlam).max() > 0.1 and np.linalg.matrix_rank(Dh) == 6
    ad = np.asarray(TSE2.ad(lam))
    evaluate = _compiled(filters, g, K, u, h0)
    _check_against_theorem(evaluate, lam, ad, K, h0, first_order_equal=True)  # y_tilde = 0
    # r = 0 with y_tilde != 0: a residual in the null space of Dh^T (the filter equation's xi = lambda checks
    # the engine's r = 0). The connections still agree with each other on E (their Hessian terms differ by
    # c r . ad = 0); the first-order E lacks the Hessian term.
    z = np.linalg.svd(Dh.T)[2][-1]  # Dh^T z = 0
    y = h0 + np.linalg.solve(np.asarray(filters["zero"].weights.Wy), z)
    _check_against_theorem(evaluate, lam, ad, K, y, first_order_equal=False)


def test_first_order_switch_keeps_the_connection_torsion():
    # order="first" drops E's Hessian term and W, not the torsion term of A: with c = 0 it freezes the heading too
    g = SE2.exp(np.array([0.3, 1.0, 2.0]))
    tm = MinimumEnergyFilter(planar_localization(), connection="minus", order="first").terms(
        g, np.eye(3), np.array([1.0, 0.0, 0.2]), np.array([1.0, -1.0]), dt=0.01)
    assert_close(tm.A, np.zeros((3, 3)), 0.0)
    assert_close(tm.W, np.zeros((3, 3)), 0.0)
    assert_close(tm.E[0], np.zeros(3), 0.0)
    assert tm.r[0] == 0.0
