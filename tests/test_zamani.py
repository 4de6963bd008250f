"""SO(2) x R with gyro bias (Zamani, Hua, Trumpf, Mahony): the generic engine against the printed filter.

The generic :class:`liemef.systems.System` is built from the mapping in
``paper_forms.zamani_circle_bias_rhs``: lambda = (u - b, 0), B = diag(-B_omega, B_b), R = I,
h(X, b) = X^T (1, 0), Q = I, D = D (so D^-T Q D^-1 is the paper's R^-1 = (D D^T)^-1), alpha = 0, and the
paper's information matrix P = K^-1, P_dot = -P K_dot P.
The printed filter (eq. 39) is reproduced once its P12 equation is corrected; the misprint and the flipped
signs of Lemma 2 (eq. 40) are pinned by their own tests.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import liemef
import paper_forms as pf
from liemef.groups import R1, SO2, SO2R1
from liemef.systems import System
from tolerances import CLOSED_FORM, ODE_REFERENCE

DEG = np.pi / 180.0
B_OMEGA, B_B = 17.0 * DEG, 52.0 * DEG  # Sec. V: standard deviations of v_omega and v_b
N_STATES, N_PARAMS = 24, 4


def dynamics(g, u, t):
    """Eqs. (7)-(8) without noise: theta_dot = u - b, b_dot = 0."""
    return jnp.stack([u[0] - g.factors[1].x[0], jnp.zeros(())])


def output(g, t):
    """Eq. (9) without noise: X^T (1, 0)."""
    return g.factors[0].as_matrix().T @ jnp.array([1.0, 0.0])


def circle_system(D, Q_w, Q_b) -> System:
    """The unit circle with gyro bias as a generic system (mapping of paper_forms' docstring)."""
    return System(group_type=SO2R1, dynamics_fn=dynamics, output_fn=output,
                  B=np.diag([-np.sqrt(Q_w), np.sqrt(Q_b)]), D=D, Q=np.eye(2), R=np.eye(2), n_inputs=1)


def state(theta, b) -> SO2R1:
    return SO2R1((SO2.from_angle(theta), R1(jnp.array([b]))))


def _engine_rhs(flt):
    """(theta_dot, b_dot, P_dot) of the engine at (theta, b, P), with K = P^-1 and P_dot = -P K_dot P."""

    @jax.jit
    def rhs(theta, b, P, u, y):
        xi, K_dot = flt.vector_field(state(theta, b), jnp.linalg.inv(P), jnp.atleast_1d(u), y, 0.0)
        return xi[0], xi[1], -P @ K_dot @ P

    return lambda *a: tuple(np.asarray(v) for v in rhs(*(jnp.asarray(x, dtype=float) for x in a)))


def _cases(seed):
    """Random (theta, b, P, u, y, D, Q_w, Q_b): P symmetric positive definite, D a general invertible matrix
    (N_PARAMS parameter sets (D, Q_w, Q_b), each at N_STATES / N_PARAMS states: one compilation per set)."""
    rng = np.random.default_rng(seed)
    for k in range(N_STATES):
        if k % (N_STATES // N_PARAMS) == 0:
            D = rng.standard_normal((2, 2)) + 1.5 * np.eye(2)
            Q_w, Q_b = rng.uniform(0.05, 2.0, 2)
        M = rng.standard_normal((2, 2))
        P = M @ M.T + 0.3 * np.eye(2)
        theta = rng.uniform(-np.pi, np.pi)
        phi = theta + rng.normal(0.0, 1.0)
        y = np.array([np.cos(phi), -np.sin(phi)]) + 0.3 * rng.standard_normal(2)
        yield theta, rng.normal(), P, rng.normal(), y, D, Q_w, Q_b


def _paper(theta, b, P, u, y, D, Q_w, Q_b, **kw):
    return pf.zamani_circle_bias_rhs(theta, b, P, u, y, Q_w=Q_w, Q_b=Q_b, D=D, **kw)


def _close(got, want):
    return np.abs(np.asarray(got) - np.asarray(want)).max() <= CLOSED_FORM * (1 + np.abs(want).max())


def test_engine_reproduces_corrected_eq39_and_not_the_printed_P12():
    """theta_dot, b_dot, P_dot of Theorem 4.1 equal eq. (39) with P12_dot = -Q_w P12 P1 - Q_b P12 P2 + P1.
    The printed P12_dot (-Q_b P2 P1 instead of -Q_b P12 P2) differs by exactly Q_b P2 (P12 - P1)."""
    min_misprint, engines = np.inf, {}
    for theta, b, P, u, y, D, Q_w, Q_b in _cases(seed=21):
        if (key := (D.tobytes(), Q_w, Q_b)) not in engines:
            engines[key] = _engine_rhs(liemef.MinimumEnergyFilter(circle_system(D, Q_w, Q_b), curvature="exact"))
        got = engines[key](theta, b, P, u, y)
        want = _paper(theta, b, P, u, y, D, Q_w, Q_b, correct_misprint=True)
        for name, g, w in zip(("theta_dot", "b_dot", "P_dot"), got, want, strict=True):
            assert _close(g, w), f"{name}: engine {g} vs corrected eq. (39) {w}"
        printed = _paper(theta, b, P, u, y, D, Q_w, Q_b, correct_misprint=False)
        assert _close(printed[:2], want[:2])  # only the P12 equation is misprinted
        diff = printed[2] - got[2]
        P1, P12, P2 = P[0, 0], P[0, 1], P[1, 1]
        expected = Q_b * P2 * (P12 - P1)
        assert _close(diff, np.array([[0.0, expected], [expected, 0.0]])), diff
        min_misprint = min(min_misprint, abs(expected))
    assert min_misprint > 1e-3


@pytest.fixture(scope="module")
def unit_filter():
    """Engine filter with D = I (Lemma 2's setting), paper noise levels."""
    return _engine_rhs(liemef.MinimumEnergyFilter(circle_system(np.eye(2), B_OMEGA**2, B_B**2), curvature="exact"))


def test_lemma2_angle_filter_equals_vector_filter_with_corrected_sign(unit_filter):
    """Lemma 2: 1 - cos(y'' - theta) = 1/2 |(cos y'', -sin y'') - h(g)|^2, so the angle filter (40) is the
    vector filter with D = I and y = (cos y'', -sin y''), with the signs of the correction as in (39)."""
    rng = np.random.default_rng(22)
    for theta, b, P, u, _y, _D, _qw, _qb in _cases(seed=23):
        ypp = theta + rng.uniform(-3.0, 3.0)
        y = np.array([np.cos(ypp), -np.sin(ypp)])
        angle = pf.zamani_circle_bias_rhs(theta, b, P, u, ypp, Q_w=B_OMEGA**2, Q_b=B_B**2, D=None,
                                          measurement="angle", correct_lemma2_sign=True)
        vector = _paper(theta, b, P, u, y, np.eye(2), B_OMEGA**2, B_B**2)
        engine = unit_filter(theta, b, P, u, y)
        for a, v, e in zip(angle, vector, engine, strict=True):
            assert _close(a, e) and _close(v, e), (a, v, e)


def test_lemma2_printed_signs_are_flipped(unit_filter):
    """Pin of the printed eq. (40): its correction terms of theta_dot and b_dot are the negatives of the
    theorem's (and of eq. 39 with D = I), and the printed correction drives theta_hat away from y''."""
    rng = np.random.default_rng(24)
    for theta, b, P, u, _y, _D, _qw, _qb in _cases(seed=25):
        ypp = theta + rng.uniform(-3.0, 3.0)
        printed = pf.zamani_circle_bias_rhs(theta, b, P, u, ypp, Q_w=B_OMEGA**2, Q_b=B_B**2, D=None,
                                            measurement="angle", correct_lemma2_sign=False)
        engine = unit_filter(theta, b, P, u, np.array([np.cos(ypp), -np.sin(ypp)]))
        assert _close(printed[0] - (u - b), -(engine[0] - (u - b)))
        assert _close(printed[1], -engine[1])
        assert _close(printed[2], engine[2])
        # the theorem's correction moves theta_hat towards y'', the printed one away from it
        assert (engine[0] - (u - b)) * np.sin(ypp - theta) > 0 > (printed[0] - (u - b)) * np.sin(ypp - theta)


# ------------------------------------------------------------------------------------------------------------
# trajectories: flt.run against scipy on the printed (corrected) filter, same zero-order-held samples
# ------------------------------------------------------------------------------------------------------------

T_END, TS, SUBSTEPS = 2.0, 0.02, 10  # samples every 20 ms, RKMK4 step 2 ms
K1, K2 = 2.0, 4.0  # P(0) = diag(1/K1, 1/K2), i.e. K(0) = diag(K1, K2)


def _samples(rng):
    """Truth (theta0 = 45 deg, bias 45 deg/s, omega = sin(t/4)) and noisy gyro and vector samples."""
    ts = np.arange(0.0, T_END + TS / 2, TS)
    bias = 45.0 * DEG
    theta = 45.0 * DEG + (1.0 - np.cos(0.25 * ts)) / 0.25
    us = np.sin(0.25 * ts) + bias + B_OMEGA * rng.standard_normal(ts.size)
    ys = np.stack([np.cos(theta), -np.sin(theta)], axis=1) + 0.4 * rng.standard_normal((ts.size, 2))
    return ts, us, ys


def _scipy_printed(ts, us, ys, correct_misprint):
    """The printed filter (39) integrated interval by interval with u, y held, DOP853 at rtol 1e-12."""

    def rhs(t, x, u, y):
        P = np.array([[x[2], x[3]], [x[3], x[4]]])
        th_dot, b_dot, P_dot = _paper(x[0], x[1], P, u, y, 0.4 * np.eye(2), B_OMEGA**2, B_B**2,
                                      correct_misprint=correct_misprint)
        return [th_dot, b_dot, P_dot[0, 0], P_dot[0, 1], P_dot[1, 1]]

    x = np.array([0.0, 0.0, 1.0 / K1, 0.0, 1.0 / K2])  # theta_hat(0) = 0, b_hat(0) = 0 (eq. 39)
    out = [x]
    for k in range(ts.size - 1):
        sol = solve_ivp(rhs, (ts[k], ts[k + 1]), x, method="DOP853", rtol=1e-12, atol=1e-12,
                        args=(us[k], ys[k]))
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)


def test_run_matches_printed_filter_trajectory():
    """flt.run (RKMK4, 2 ms) reproduces the corrected eq. (39) integrated by scipy over 2 s of held samples,
    and the printed (misprinted) P12 equation gives a visibly different trajectory."""
    ts, us, ys = _samples(np.random.default_rng(26))
    flt = liemef.MinimumEnergyFilter(circle_system(0.4 * np.eye(2), B_OMEGA**2, B_B**2), curvature="exact")
    fine = np.linspace(0.0, ts[-1], SUBSTEPS * (ts.size - 1) + 1)
    hold = np.minimum(np.arange(fine.size) // SUBSTEPS, ts.size - 1)
    traj = flt.run(flt.init(state(0.0, 0.0), np.diag([K1, K2])), fine, us[hold, None], ys[hold])
    assert bool(traj.ok)
    coords = np.asarray(traj.coords())[::SUBSTEPS]
    P = np.linalg.inv(np.asarray(traj.K)[::SUBSTEPS])
    engine = np.column_stack([coords, P[:, 0, 0], P[:, 0, 1], P[:, 1, 1]])
    ref = _scipy_printed(ts, us, ys, correct_misprint=True)
    dev = engine - ref
    dev[:, 0] = np.angle(np.exp(1j * dev[:, 0]))  # angle difference on the circle
    assert np.abs(dev).max() <= ODE_REFERENCE * (1 + np.abs(ref).max()), np.abs(dev).max(axis=0)
    assert np.abs(np.asarray(traj.K) - np.swapaxes(np.asarray(traj.K), 1, 2)).max() <= 1e-12 * np.abs(P).max()
    misprinted = _scipy_printed(ts, us, ys, correct_misprint=False)
    assert np.abs(misprinted - ref)[:, 2:].max() > 1e-2  # the misprint changes the gains by far more
