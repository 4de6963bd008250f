"""Integrator convergence slopes on non-abelian groups: the global error at a fixed final time vs the step.

The problem is the filter itself, ``(g_hat, K)`` on TSO(3) = SO(3) x R^3 and on TSE(2) = SE(2) x R^3,
with dynamics lambda(g, u, t) that depend explicitly on t and on g (an attitude-dependent torque, a
position-dependent force, time-varying forcing), and the K Riccati equation with E != 0 and W != 0 from a
constant measurement away from the output. u and y are constant, so the zero-order hold does not limit the
order. The reference is scipy's DOP853 at rtol 1e-13 on the embedded matrix ODE ``G_dot = G hat(xi)`` with K,
using the same vector field (so only the time integration differs). Errors: ``|log(g_ref^-1 g)|`` on the
group and the Frobenius norm of ``K - K_ref``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import liemef
from liemef.groups import R3, SE2, SO3, TSE2, TSO3
from liemef.integrators import RKMK2, RKMK4, LieEuler
from liemef.systems import System
from tolerances import SLOPE

T_END = 1.0
STEPS = {LieEuler: (100, 200, 400, 800), RKMK2: (64, 128, 256, 512), RKMK4: (64, 128, 256, 512)}


def attitude_system() -> System:
    I = jnp.diag(jnp.array([2.0, 5.0, 3.0]))
    arm = jnp.array([0.1, -0.2, 0.3])  # centre of mass offset: gravity torque depends on the attitude

    def dynamics(g, u, t):
        Rot, Omega = g.factors[0].as_matrix(), g.factors[1].x
        w = 2 * jnp.pi * t
        forcing = jnp.stack([jnp.sin(w / 3), jnp.cos(w), jnp.sin(w / 5)])
        gravity = 9.81 * jnp.cross(arm, Rot.T @ jnp.array([0.0, 0.0, -1.0]))
        torque = jnp.cross(I @ Omega, Omega) + u + forcing + gravity
        return jnp.concatenate([Omega, jnp.linalg.solve(I, torque)])

    def output(g, t):
        Rt = g.factors[0].as_matrix().T
        return jnp.concatenate([Rt @ jnp.array([0.0, 0.0, 1.0]), Rt @ jnp.array([0.0, 1.0, 0.0])])

    return System(group_type=TSO3, dynamics_fn=dynamics, output_fn=output,
                  B=np.vstack([np.zeros((3, 3)), np.eye(3)]), D=0.5 * np.eye(6), Q=np.eye(6), R=np.eye(3),
                  n_inputs=3)


def planar_system() -> System:
    J, m, l, k = 6.125, 125.0, 0.2, 40.0

    def dynamics(g, u, t):
        pose, Omega = g.factors[0], g.factors[1].x
        w, vx, vy = Omega[0], Omega[1], Omega[2]
        c, s, p = pose.cos_sin_xy[0], pose.cos_sin_xy[1], pose.cos_sin_xy[2:4]
        spring = -k * jnp.array([c * p[0] + s * p[1], -s * p[0] + c * p[1]])  # R^T (-k p): body-frame force
        u_w = u[0] + 3.0 * jnp.sin(2.0 * t) - 2.0 * s
        u_v = u[1] + 50.0 * jnp.sin(t) + spring[0]
        acc = jnp.stack([u_w / J, w * vy + u_v / m, -w * vx + spring[1] / m])
        return jnp.concatenate([Omega, acc])

    def output(g, t):
        pose, Omega = g.factors[0], g.factors[1].x
        c, s, x, y = pose.cos_sin_xy[0], pose.cos_sin_xy[1], pose.cos_sin_xy[2], pose.cos_sin_xy[3]
        return jnp.concatenate([jnp.stack([x + l * c, y + l * s, x - l * c, y - l * s]), Omega])

    return System(group_type=TSE2, dynamics_fn=dynamics, output_fn=output,
                  B=np.vstack([np.zeros((3, 3)), 0.5 * np.eye(3)]), D=np.diag([1.0] * 4 + [1.5] * 3),
                  Q=np.eye(7), R=np.eye(3), n_inputs=2)


def _problem(name):
    """System, initial state, initial gain, constant input and constant measurement (far from h(g0))."""
    rng = np.random.default_rng(41)
    M = rng.standard_normal((6, 6))
    K0 = M @ M.T / 6 + 0.5 * np.eye(6)
    if name == "TSO3":
        g0 = TSO3((SO3.exp(jnp.array([0.4, -0.7, 0.2])), R3(jnp.array([0.5, 0.6, 0.4]))))
        y = np.concatenate([SO3.exp(jnp.array([0.8, 0.3, -0.5])).as_matrix().T @ np.array([0.0, 0.0, 1.0]),
                            SO3.exp(jnp.array([0.8, 0.3, -0.5])).as_matrix().T @ np.array([0.0, 1.0, 0.0])])
        return attitude_system(), g0, K0, np.array([0.3, -0.2, 0.1]), y
    g0 = TSE2((SE2.from_coords(jnp.array([np.pi / 6, 1.0, 2.0])), R3(jnp.array([0.8, 1.0, -0.3]))))
    y = np.array([1.3, 2.2, 1.0, 2.0, 0.5, 1.2, 0.1])
    return planar_system(), g0, K0, np.array([1.0, 20.0]), y


def _reference(flt, g0, K0, u, y):
    """DOP853 at rtol 1e-13 on the embedded matrix ODE G_dot = G hat(xi), K_dot, with the filter's field."""
    G, n = type(g0), type(g0).tangent_dim
    m = G.matrix_dim

    @jax.jit
    def rhs(t, z):
        Gm, K = z[: m * m].reshape(m, m), z[m * m :].reshape(n, n)
        xi, K_dot = flt.vector_field(G.from_matrix(Gm), K, jnp.asarray(u), jnp.asarray(y), t)
        return jnp.concatenate([(Gm @ G.hat(xi)).ravel(), K_dot.ravel()])

    z0 = np.concatenate([np.asarray(g0.as_matrix()).ravel(), K0.ravel()])
    sol = solve_ivp(lambda t, z: np.asarray(rhs(t, z)), (0.0, T_END), z0, method="DOP853", rtol=1e-13,
                    atol=1e-13)
    assert sol.success
    z = sol.y[:, -1]
    return G.from_matrix(jnp.asarray(z[: m * m].reshape(m, m))), z[m * m :].reshape(n, n)


def _slope(dts, errs):
    return np.polyfit(np.log(dts), np.log(errs), 1)[0]


# TSO(3) (about 2 min of compile and reference solve) runs under `make test-slow`; TSE(2), also non-abelian with E and
# W acting, keeps both slopes in the default suite.
@pytest.fixture(scope="module", params=[pytest.param("TSO3", marks=pytest.mark.slow), "TSE2"])
def problem(request):
    system, g0, K0, u, y = _problem(request.param)
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection="zero")
    tm = flt.terms(g0, K0, u, y, 0.0)
    assert np.abs(np.asarray(tm.W)).max() > 0.1 and np.abs(np.asarray(tm.r)).max() > 0.1  # E, W really act
    return request.param, system, g0, K0, u, y, _reference(flt, g0, K0, u, y)


@pytest.mark.parametrize("method", [LieEuler, RKMK2, RKMK4])
def test_convergence_slope(problem, method):
    """Global error at T = 1 s on the group and in K over 4 step sizes: log-log slope = declared order.
    The steps are the public driver's ``flt.step`` (time passed to the integrator, u and y held)."""
    name, system, g0, K0, u, y, (g_ref, K_ref) = problem
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection="zero", integrator=method())
    dts, err_g, err_K = [], [], []
    for N in STEPS[method]:
        dt = T_END / N
        state = flt.init(g0, K0)
        for k in range(N):
            state = flt.step(state, k * dt, u, y, dt)
        dts.append(dt)
        err_g.append(float(np.linalg.norm(np.asarray(state.g_hat.rminus(g_ref)))))
        err_K.append(float(np.linalg.norm(np.asarray(state.K) - K_ref)))
    slope_g, slope_K = _slope(dts, err_g), _slope(dts, err_K)
    info = f"{name} {method.__name__}: dt {dts}, group errors {err_g}, K errors {err_K}"
    # the reference is good to ~1e-13 here (DOP853 at rtol 1e-13 differs from rtol 3e-14 by < 1e-13)
    assert min(err_g + err_K) > 1e-12, "errors must stay above the reference's accuracy: " + info
    assert abs(slope_g - method.order) <= SLOPE, f"group slope {slope_g:.3f}; " + info
    assert abs(slope_K - method.order) <= SLOPE, f"K slope {slope_K:.3f}; " + info


def test_declared_orders():
    assert (LieEuler.order, RKMK2.order, RKMK4.order) == (1, 2, 4)


def test_the_command_line_offers_every_integrator_by_its_own_name():
    """`liemef run --integrator` takes its choices from liemef._names (known before JAX loads): they are the
    integrators' own names, every one of them, and each name gives its integrator."""
    from liemef import _names
    from liemef.integrators import INTEGRATORS, integrator

    assert set(_names.INTEGRATORS) == {cls.name for cls in INTEGRATORS.values()}
    for name in _names.INTEGRATORS:
        assert integrator(name).name == name
