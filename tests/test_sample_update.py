"""The discrete sample update (``updates="discrete"``) against an independent minimizer, and its error orders.

The update minimizes the sample's cost $c(\\xi) = \\tfrac12\\xi^\\top K^{-1}\\xi + \\tfrac12|y \\ominus h(\\hat g
\\exp\\xi)|^2_W$ on the group (docs/theorem.md, "Samples at their own time"). Here scipy's least squares (Levenberg-
Marquardt on the stacked residual, the prior written with K^{-1}), polished by MINPACK's root finder on the
cost's autodiff gradient, finds the minimizer independently; K+ is checked against the inverse of the
Hessian of the new value function in the coordinates at the new estimate,
$\\zeta \\mapsto c(\\log(\\hat g^{-1}\\hat g^+\\exp\\zeta))$, which involves no J of the update.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from liemef.filters import sample_update
from liemef.groups import R1, R3, SE2, SE23, SO2, SO3, TSO3
from tolerances import ROUNDOFF

jax.config.update("jax_enable_x64", True)

MINIMIZER = 1e-10
"""The update's estimate against scipy's minimizer (both to their gradients' rounding: measured <= 2e-15 on the
group)."""
INVERSE_HESSIAN = 1e-10
"""K+ against the inverse Hessian at the minimizer, relative (measured <= 1.4e-14)."""


def _wrap(a):
    return jnp.mod(a + jnp.pi, 2 * jnp.pi) - jnp.pi


def _range_bearing(landmark):
    def h(g, y):
        d = jnp.asarray(landmark) - g.translation()
        R = g.rotation().as_matrix()
        b = R.T @ d
        rng, brg = jnp.sqrt(d @ d), jnp.arctan2(b[1], b[0])
        return jnp.stack([rng, y[1] - _wrap(y[1] - brg)])   # the bearing seen from y: its residual wraps
    return h


def _bearings(landmarks):
    def h(g, y):
        R = g.rotation().as_matrix()
        out = []
        for i, m in enumerate(landmarks):
            b = R.T @ (jnp.asarray(m) - g.translation())
            brg = jnp.arctan2(b[1], b[0])
            out.append(y[i] - _wrap(y[i] - brg))
        return jnp.stack(out)
    return h


def _ranges(landmarks):
    def h(g, y):
        return jnp.stack([jnp.linalg.norm(jnp.asarray(m) - g.translation()) for m in landmarks])
    return h


def _directions(g, y):
    R = g.factors[0].as_matrix() if hasattr(g, "factors") else g.as_matrix()
    return jnp.concatenate([R.T @ jnp.array([0.0, 0.0, 1.0]), R.T @ jnp.array([0.0, 1.0, 0.0])])


def _ins(g, y):
    R = g.rotation().as_matrix() if hasattr(g, "rotation") else g.factors[0].as_matrix()
    return jnp.concatenate([g.position(), R.T @ jnp.array([0.4, 0.0, -0.9])])


def _se2(theta, x, y):
    return SE2.from_rotation_translation(SO2.exp(jnp.array([theta])), jnp.array([x, y]))


def _spd(rng, n, scale):
    L = rng.standard_normal((n, n))
    return scale * (L @ L.T / n + 0.3 * np.eye(n))


def _cases():
    """(name, output(g, y), g_hat, K, y, W): at least one with a large innovation on a strongly curved output."""
    rng = np.random.default_rng(7)
    cases = []
    # 1-D closed form: h(x) = x + x^2/2, K = W = 1
    cases.append(("quadratic 1-D", lambda g, y: g.x + 0.5 * g.x**2, R1(jnp.zeros(1)), np.eye(1), np.array([0.8]),
                  np.eye(1)))
    # SE(2), range and bearing to one landmark, a large innovation (one Newton step from 0 raises the cost 11x)
    g = _se2(-0.8325, -0.7078, 1.7102)
    h = _range_bearing([-0.2738, 3.9547])
    y0 = np.asarray(h(g, jnp.zeros(2)))
    cases.append(("SE(2) range+bearing, large innovation", h, g, np.diag([0.3131, 1.0207, 0.3466]) ** 2,
                  y0 + np.array([-0.3012, 0.2776]), np.diag([1 / 0.4173**2, 1 / 0.04743**2])))
    # SE(2) bearings to three landmarks
    lm = [[5.0, 0.0], [0.0, 6.0], [-4.0, -3.0]]
    g = _se2(-0.7, 0.5, 0.2)
    h = _bearings(lm)
    y0 = np.asarray(h(g, jnp.zeros(3)))
    cases.append(("SE(2) bearings", h, g, np.diag([0.3, 1.0, 1.0]), y0 + np.array([0.3, -0.25, 0.2]),
                  np.eye(3) / 0.05**2))
    # SE(2) ranges to three landmarks
    h = _ranges(lm)
    y0 = np.asarray(h(g, jnp.zeros(3)))
    cases.append(("SE(2) ranges", h, g, np.diag([0.2, 2.0, 2.0]), y0 + np.array([0.8, -0.6, 0.9]),
                  np.eye(3) / 0.1**2))
    # TSO(3), Saccon's two directions, correlated K, 30 deg of innovation
    g = TSO3((SO3.exp(jnp.asarray(rng.standard_normal(3))), R3(jnp.asarray(rng.standard_normal(3)))))
    y0 = np.asarray(_directions(g, None))
    turn = np.asarray(SO3.exp(jnp.array([0.4, -0.3, 0.2])).as_matrix())
    y = np.concatenate([turn @ y0[:3], turn @ y0[3:]])
    cases.append(("TSO(3) two directions", _directions, g, _spd(rng, 6, 0.3), y, np.eye(6) / 0.1**2))
    # SO(3), a direction of gravity and one of the magnetic field, weak and strong weights
    g = SO3.exp(jnp.asarray(rng.standard_normal(3)))
    y0 = np.asarray(_directions(g, None))
    turn = np.asarray(SO3.exp(jnp.array([-0.6, 0.5, 0.3])).as_matrix())
    cases.append(("SO(3) directions", _directions, g, _spd(rng, 3, 0.5),
                  np.concatenate([turn @ y0[:3], turn @ y0[3:]]), np.diag([1 / 0.05**2] * 3 + [1 / 0.2**2] * 3)))
    # SE_2(3), GNSS position and a field direction, correlated K
    g = SE23.from_rotation_velocity_position(SO3.exp(jnp.asarray(rng.standard_normal(3))),
                                             jnp.asarray(rng.standard_normal(3)), jnp.asarray(rng.standard_normal(3)))
    y0 = np.asarray(_ins(g, None))
    cases.append(("SE_2(3) position + direction", _ins, g, _spd(rng, 9, 1.0),
                  y0 + np.concatenate([[1.5, -1.0, 0.7], [0.3, 0.2, -0.1]]),
                  np.diag([1 / 0.3**2] * 3 + [1 / 0.05**2] * 3)))
    return cases


CASES = _cases()


def _cost(output, g_hat, K, y, W):
    K_inv = jnp.asarray(np.linalg.inv(K))
    y, W = jnp.asarray(y), jnp.asarray(W)

    def c(xi):
        e = y - output(g_hat.rplus(xi), y)
        return 0.5 * xi @ K_inv @ xi + 0.5 * e @ W @ e
    return c


def _key(output, g_hat, K, *arrays):
    """What a compiled program of this file depends on: the output map and the sample's arrays, by value."""
    leaves = jax.tree_util.tree_leaves(g_hat)
    return (id(output), type(g_hat), *(np.asarray(a).tobytes() for a in (*leaves, K, *arrays)))


_MINIMIZERS: dict = {}
_UPDATES: dict = {}


def _scipy_minimizer(output, g_hat, K, y, W):
    """scipy's least squares on the stacked residual (L^-1 xi, W^(1/2) e(xi)), K = L L^T, whose half
    squared norm is c: a minimizer that shares nothing with the update but the output map. Kept per sample:
    the tests of one case share it (and its four compiled programs)."""
    key = _key(output, g_hat, K, y, W)
    if key not in _MINIMIZERS:
        _MINIMIZERS[key] = _minimize(output, g_hat, K, y, W)
    return _MINIMIZERS[key]


def _minimize(output, g_hat, K, y, W):
    L_inv = jnp.asarray(np.linalg.inv(np.linalg.cholesky(K)))
    W_root = jnp.asarray(np.linalg.cholesky(W).T)
    yj = jnp.asarray(y)
    stacked = lambda xi: jnp.concatenate([L_inv @ xi, W_root @ (yj - output(g_hat.rplus(xi), yj))])  # noqa: E731
    residual, jac = jax.jit(stacked), jax.jit(jax.jacfwd(stacked))
    res = scipy.optimize.least_squares(lambda x: np.asarray(residual(jnp.asarray(x))), np.zeros(K.shape[0]),
                                       jac=lambda x: np.asarray(jac(jnp.asarray(x))), method="lm", xtol=1e-15,
                                       ftol=1e-15, gtol=1e-15, max_nfev=10_000)
    assert res.status > 0, res.message
    # LM stops on the relative decrease of the cost (gradient ~1e-6 here): polish by solving grad c = 0 with
    # MINPACK's hybrid method from there, derivatives by autodiff of the cost itself
    c = _cost(output, g_hat, K, y, W)
    grad, hess = jax.jit(jax.grad(c)), jax.jit(jax.hessian(c))
    root = scipy.optimize.root(lambda x: np.asarray(grad(jnp.asarray(x))), res.x,
                               jac=lambda x: np.asarray(hess(jnp.asarray(x))), method="hybr", tol=1e-15)
    assert np.abs(root.fun).max() < 1e-11, root.message
    return root.x, c


def _update(output, g_hat, K, y, W, **kw):
    """sample_update of the sample y, compiled once per output map, prior, weights and options (y an argument:
    the samples of one case share the program)."""
    kw = {"iterations": 30, "newton": True, "safe": False} | kw
    key = (_key(output, g_hat, K, W), tuple(sorted(kw.items())))
    if key not in _UPDATES:
        _UPDATES[key] = jax.jit(lambda yy: sample_update(lambda gg: output(gg, yy), g_hat, jnp.asarray(K), yy,
                                                         jnp.asarray(W), **kw))
    return _UPDATES[key](jnp.asarray(y))


@pytest.mark.parametrize(("name", "output", "g_hat", "K", "y", "W"), CASES, ids=[c[0] for c in CASES])
def test_update_is_the_minimizer_and_K_the_inverse_hessian_there(name, output, g_hat, K, y, W):
    xi_ref, c = _scipy_minimizer(output, g_hat, K, y, W)
    g_ref = g_hat.rplus(jnp.asarray(xi_ref))
    # the Hessian of the new value function in the coordinates at the new estimate (no J of the update enters),
    # compiled once for both updates
    value_hessian = jax.jit(jax.hessian(lambda z, shift: c(shift.rplus(z).log())))
    for safe in (False, True):
        g_plus, K_plus, info = _update(output, g_hat, K, y, W, safe=safe)
        assert bool(info.converged), (name, safe, info)
        assert float(info.cost) <= float(info.cost0)
        np.testing.assert_allclose(np.asarray(g_plus.rminus(g_ref)), 0.0, atol=MINIMIZER, err_msg=name)
        H = np.asarray(value_hessian(jnp.zeros(K.shape[0]), g_hat.inverse() @ g_plus))
        assert np.all(np.linalg.eigvalsh(0.5 * (H + H.T)) > 0), name  # a strict minimum: Newton's Hessian is used
        if not bool(info.modified):
            np.testing.assert_allclose(np.asarray(K_plus), np.linalg.inv(H), rtol=INVERSE_HESSIAN,
                                       atol=INVERSE_HESSIAN * np.abs(np.linalg.inv(H)).max(), err_msg=name)


def _one_newton_step(output, g_hat, K, y, W):
    """The update liemef had before: one undamped Newton step from 0, nothing checked."""
    y, W, K = jnp.asarray(y), jnp.asarray(W), jnp.asarray(K)
    F_of = lambda z: output(g_hat.rplus(z), y)  # noqa: E731
    z0 = jnp.zeros(K.shape[0])
    F, h = jax.jacfwd(F_of)(z0), F_of(z0)
    yt = W @ (y - h)
    Hf = F.T @ W @ F - jax.hessian(lambda z: yt @ F_of(z))(z0)
    return jnp.linalg.solve(jnp.eye(K.shape[0]) + K @ Hf, K @ F.T @ yt)


def test_one_unchecked_newton_step_raises_the_cost_the_update_lowers_it():
    """The SE(2) range-and-bearing sample with a large innovation: one Newton step from 0 (the former update)
    ends at a higher cost than no update at all; the safeguarded update never does, and one Gauss-Newton step is
    already far better than the Newton step."""
    name, output, g_hat, K, y, W = CASES[1]
    c = jax.jit(_cost(output, g_hat, K, y, W))
    c0 = float(c(jnp.zeros(3)))
    c_newton = float(c(jax.jit(lambda: _one_newton_step(output, g_hat, K, y, W))()))  # one program, not eager
    assert c_newton > c0, (c0, c_newton)
    for kw in ({"iterations": 1}, {"iterations": 1, "newton": False}, {}, {"safe": True}):
        _, _, info = _update(output, g_hat, K, y, W, **kw)
        assert float(info.cost) < c0, kw
    xi_ref, _ = _scipy_minimizer(output, g_hat, K, y, W)
    c_min = float(c(jnp.asarray(xi_ref)))
    _, _, gn = _update(output, g_hat, K, y, W, iterations=1, newton=False)
    assert float(gn.cost) - c_min < 0.1 * (c_newton - c_min)


def test_error_of_one_step_is_second_order_in_the_innovation():
    """h(x) = x + x^2/2, K = W = 1, innovation d: the minimizer is d/2 + d^2/16 + O(d^3). One Newton step gives
    d/(2 - d) = d/2 + d^2/4 + ...: error 3/16 d^2; one Gauss-Newton step d/2: error 1/16 d^2. Both are of
    second order (slope 2), not third; iterated to the tolerance, the update is the minimizer to round-off."""
    output = CASES[0][1]
    g0 = R1(jnp.zeros(1))

    def solve(d, **kw):
        return float(_update(output, g0, np.eye(1), np.array([d]), np.eye(1), **kw)[0].x[0])

    def exact(d):  # c'(x) = x - (d - x - x^2/2)(1 + x), by Newton to convergence from d/2
        x = d / 2
        for _ in range(50):
            f = x - (d - x - x * x / 2) * (1 + x)
            df = 1 + (1 + x) ** 2 - (d - x - x * x / 2)
            x -= f / df
        return x

    ds = np.array([1e-2, 2e-3])
    for kw, coefficient in (({"iterations": 1}, 3 / 16), ({"iterations": 1, "newton": False}, 1 / 16)):
        err = np.array([abs(solve(d, **kw) - exact(d)) for d in ds])
        slope = np.log(err[0] / err[1]) / np.log(ds[0] / ds[1])
        assert abs(slope - 2.0) < 0.02, (kw, slope)
        np.testing.assert_allclose(err / ds**2, coefficient, rtol=0.05)
    for d in (0.5, 1.0):
        assert abs(solve(d) - exact(d)) < ROUNDOFF
