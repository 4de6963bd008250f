"""The generic engine (Theorem 4.1 by autodiff) against the closed forms printed in the papers.

Reference: ``paper_forms.py``, plain-NumPy transcriptions of Rigo et al. 2022, Prop. 1 (TSE(2), eqs.
22-27) and Saccon et al. 2016, Props. 5.1-5.2 (TSO(3), eqs. 66-78). Every term r, A, E, W, B R^-1 B^T is
compared entry by entry at random states, measurements, inputs and gains (fixed seeds), with the papers'
weights and with non-trivial ones. The one printed difference (the signs of a21, a31 in Rigo's E) is
pinned by its own test. Beyond the terms: the assembled vector field (observer and eq. (11)) at general,
non-symmetric K, and whole runs on TSO(3) against scipy integrating the printed filter, both connections.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import liemef
import paper_forms as pf
from liemef.groups import R3, SO3, TSO3
from liemef.systems import PlanarRigidBody, RigidBodyAttitude, tse2_state
from tolerances import CLOSED_FORM, ODE_REFERENCE, ROUNDOFF, SYMMETRY

N_STATES = 24
TERMS = ("r", "A", "E", "W", "BRB")


def _engine(flt, g, K, u, y):
    tm = flt.terms(g, K, u, y, 0.0)
    return {k: np.asarray(getattr(tm, k)) for k in (*TERMS, "Dh", "y_tilde")}


def _assert_close(got, want, what):
    scale = 1.0 + np.abs(want).max()
    dev = np.abs(got - want).max()
    assert dev <= CLOSED_FORM * scale, f"{what}: max deviation {dev:.3g} (scale {scale:.3g})\n{got}\n{want}"


def _random_spd(rng, n):
    M = rng.standard_normal((n, n))
    return M @ M.T + 0.5 * np.eye(n)


# ------------------------------------------------------------------------------------------------------------
# TSE(2): Rigo et al. 2022, Proposition 1
# ------------------------------------------------------------------------------------------------------------


def _planar(weights: str) -> PlanarRigidBody:
    if weights == "paper":  # Sec. VI: B2 = 0.1 I3, R = B'B, D = diag(0.5 x4, 0.1 x3), Q = D'D
        return PlanarRigidBody()
    rng = np.random.default_rng(11)
    D = np.diag([0.7] * 4 + [0.3, 0.2, 0.2])
    Q = np.diag([1.3] * 4 + [2.0, 0.5, 0.5])  # q != d^2: D^-T Q D^-1 is not the identity
    B = np.vstack([np.zeros((3, 3)), rng.standard_normal((3, 3))])
    return PlanarRigidBody(J=4.0, m=30.0, l=0.35, B=B, D=D, Q=Q, R=_random_spd(rng, 3))


def _planar_cases(system, seed):
    """Random (coords, y, K, u): y is the output at a nearby state plus O(1) noise, K a general matrix."""
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q = np.concatenate([rng.uniform(-np.pi, np.pi, 1), 3.0 * rng.standard_normal(2),
                            rng.standard_normal(3)])
        y = pf.tse2_output(q + 0.5 * rng.standard_normal(6), system.l) + rng.standard_normal(7)
        yield q, y, rng.standard_normal((6, 6)), rng.standard_normal(2)


def _rigo(system, q, y, K, u, correct_misprint):
    return pf.rigo2022_tse2_terms(q, y, K, u, J=system.J, m=system.m, l=system.l, D=np.asarray(system.D),
                                  Q=np.asarray(system.Q), B=np.asarray(system.B), R=np.asarray(system.R),
                                  correct_misprint=correct_misprint)


@pytest.mark.parametrize("weights", ["paper", "weighted"])
def test_tse2_terms_match_rigo2022_with_corrected_E(weights):
    """r (22), A (25), E (26, with a21 = a12, a31 = a13), W and B R^-1 B' (27) agree entry by entry."""
    system = _planar(weights)
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection="zero")
    for k, (q, y, K, u) in enumerate(_planar_cases(system, seed=1)):
        got = _engine(flt, tse2_state(*q), K, u, y)
        want = _rigo(system, q, y, K, u, correct_misprint=True)
        for key in TERMS:
            _assert_close(got[key], want[key], f"{weights} state {k}: {key}")
        # the theorem's E for the (0)-connection is symmetric
        assert np.abs(got["E"] - got["E"].T).max() <= ROUNDOFF * (1 + np.abs(got["E"]).max())


@pytest.mark.parametrize("weights", ["paper", "weighted"])
def test_tse2_printed_E_misprint_is_exactly_a21_a31(weights):
    """Pin of the misprint (docs/errata.md): the printed E of eq. (26) differs from the theorem's only at
    (1, 0) and (2, 0), by 2 a21 and 2 a31 (printed values), i.e. the printed a21 = -a12 and a31 = -a13."""
    system = _planar(weights)
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection="zero")
    mask = np.zeros((6, 6), bool)
    mask[1, 0] = mask[2, 0] = True
    smallest = np.inf
    for q, y, K, u in _planar_cases(system, seed=2):
        E = _engine(flt, tse2_state(*q), K, u, y)["E"]
        printed = _rigo(system, q, y, K, u, correct_misprint=False)["E"]
        diff = printed - E
        _assert_close(np.where(mask, 0.0, diff), np.zeros((6, 6)), "printed E off (1,0), (2,0)")
        a21, a31 = printed[1, 0], printed[2, 0]
        _assert_close(diff[mask], np.array([2 * a21, 2 * a31]), "printed - theorem at (1,0), (2,0)")
        _assert_close(np.array([a21, a31]), -np.array([E[0, 1], E[0, 2]]), "printed a21, a31 vs -a12, -a13")
        smallest = min(smallest, np.abs(diff[mask]).max())
    assert smallest > 1e-3, "the random measurements must exercise the misprinted entries"


# ------------------------------------------------------------------------------------------------------------
# TSO(3): Saccon et al. 2016, Propositions 5.1 (zero) and 5.2 (minus)
# ------------------------------------------------------------------------------------------------------------


def _attitude(weights: str) -> RigidBodyAttitude:
    if weights == "paper":  # eqs. (84)-(85)
        return RigidBodyAttitude()
    rng = np.random.default_rng(12)
    a1, a2 = rng.standard_normal(3), rng.standard_normal(3)
    D = np.diag([0.3] * 3 + [0.6] * 3)
    Q = np.diag([2.0] * 3 + [0.7] * 3)
    B = np.vstack([np.zeros((3, 3)), rng.standard_normal((3, 3))])
    return RigidBodyAttitude(inertia=_random_spd(rng, 3), a1=a1 / np.linalg.norm(a1),
                             a2=a2 / np.linalg.norm(a2), B=B, D=D, Q=Q, R=_random_spd(rng, 3))


def _attitude_cases(system, seed):
    """Random (R, Omega, y, K, tau): y the directions seen from a nearby attitude, plus noise."""
    rng = np.random.default_rng(seed)
    a1, a2 = np.asarray(system.a1), np.asarray(system.a2)
    for _ in range(N_STATES):
        Rot = np.asarray(SO3.exp(jnp.asarray(rng.uniform(-1.8, 1.8, 3))).as_matrix())
        Rtrue = Rot @ np.asarray(SO3.exp(jnp.asarray(0.8 * rng.standard_normal(3))).as_matrix())
        y = pf.tso3_output(Rtrue, a1, a2) + 0.3 * rng.standard_normal(6)
        yield Rot, rng.standard_normal(3), y, rng.standard_normal((6, 6)), rng.standard_normal(3)


def _saccon(system, Rot, Omega, y, K, tau, connection):
    return pf.saccon2016_tso3_terms(Rot, Omega, y, K, tau, inertia=np.asarray(system.inertia),
                                    a1=np.asarray(system.a1), a2=np.asarray(system.a2),
                                    D=np.asarray(system.D), Q=np.asarray(system.Q), B=np.asarray(system.B),
                                    R=np.asarray(system.R), connection=connection)


def _tso3(Rot, Omega):
    return TSO3((SO3.from_matrix(jnp.asarray(Rot)), R3(jnp.asarray(Omega))))


@pytest.mark.parametrize("weights", ["paper", "weighted"])
@pytest.mark.parametrize("connection", ["zero", "minus"])
def test_tso3_terms_match_saccon2016(connection, weights):
    """r (68), A (70/75), E (71/76), B R^-1 B' (72/77), W (73/78) agree entry by entry, both connections."""
    system = _attitude(weights)
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection=connection)
    max_asym = 0.0
    for k, (Rot, Omega, y, K, tau) in enumerate(_attitude_cases(system, seed=3)):
        got = _engine(flt, _tso3(Rot, Omega), K, tau, y)
        want = _saccon(system, Rot, Omega, y, K, tau, connection)
        for key in TERMS:
            _assert_close(got[key], want[key], f"{connection}/{weights} state {k}: {key}")
        max_asym = max(max_asym, np.abs(got["E"] - got["E"].T).max() / np.abs(got["E"]).max())
    if connection == "zero":
        assert max_asym <= ROUNDOFF
    else:  # the (-)-connection E (eq. 76) is not symmetric in general
        assert max_asym > 1e-2


# ------------------------------------------------------------------------------------------------------------
# first-order variant (continuous-time left-invariant EKF)
# ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("connection", ["zero", "minus"])
def test_first_order_is_the_ekf(connection):
    """order="first": E = Dh' D^-T Q D^-1 Dh (no Hessian term), W = 0, r, A, B R^-1 B' unchanged. On both
    paper systems this E equals the printed E at zero innovation (y = h(g_hat)), where the Hessian part
    vanishes (an independent check of the Jacobian part of E)."""
    cases = []
    planar, att = _planar("weighted"), _attitude("weighted")  # the paper weights are a special case
    for q, y, K, u in list(_planar_cases(planar, seed=4))[: N_STATES // 2]:
        zero_innov = _rigo(planar, q, pf.tse2_output(q, planar.l), K, u, correct_misprint=False)["E"]
        cases.append((planar, tse2_state(*q), y, K, u, zero_innov))
    for Rot, Omega, y, K, tau in list(_attitude_cases(att, seed=5))[: N_STATES // 2]:
        y0 = pf.tso3_output(Rot, np.asarray(att.a1), np.asarray(att.a2))
        zero_innov = _saccon(att, Rot, Omega, y0, K, tau, connection)["E"]
        cases.append((att, _tso3(Rot, Omega), y, K, tau, zero_innov))
    filters = {}
    for system, g, y, K, u, zero_innov in cases:
        if id(system) not in filters:
            filters[id(system)] = tuple(liemef.MinimumEnergyFilter(system, curvature="exact",
                                                                   connection=connection, order=o)
                                        for o in ("first", "second"))
        first_flt, second_flt = filters[id(system)]
        first, second = _engine(first_flt, g, K, u, y), _engine(second_flt, g, K, u, y)
        Dinv = np.linalg.inv(np.asarray(system.D))
        Wy = Dinv.T @ np.asarray(system.Q) @ Dinv
        _assert_close(first["E"], first["Dh"].T @ Wy @ first["Dh"], "first-order E vs Dh' W Dh")
        _assert_close(first["E"], zero_innov, "first-order E vs printed E at zero innovation")
        assert np.all(first["W"] == 0.0)
        for key in ("r", "A", "BRB"):
            _assert_close(first[key], second[key], f"first vs second order: {key}")
        # and the second-order E really carries a Hessian term at these measurements
        assert np.abs(second["E"] - first["E"]).max() > 1e-2


# ------------------------------------------------------------------------------------------------------------
# the filter's vector field: observer and perturbed Riccati equation from the printed terms
# ------------------------------------------------------------------------------------------------------------

ALPHA = 0.1


def _printed_vector_field(terms, lam, K, alpha=ALPHA):
    """Theorem 4.1 / eq. (11) in NumPy from printed terms: (lam + K r, K_dot), K a general matrix."""
    A, E, W = terms["A"], terms["E"], terms["W"]
    K_dot = -alpha * K + A @ K + K @ A.T - K @ E @ K + terms["BRB"] - W @ K - K @ W.T
    return lam + K @ terms["r"], K_dot


def _tso3_lambda(system, Omega, tau):  # Saccon et al. 2016, eqs. (55)-(56)
    I_ = np.asarray(system.inertia)
    return np.concatenate([Omega, np.linalg.solve(I_, np.cross(I_ @ Omega, Omega) + tau)])


def _tse2_lambda(system, q, u):  # Rigo et al. 2022, eqs. (8), (11)
    w, vx, vy = q[3:]
    return np.concatenate([q[3:], [u[0] / system.J, w * vy + u[1] / system.m, -w * vx]])


@pytest.mark.parametrize("connection", ["zero", "minus"])
def test_vector_field_matches_printed_filter(connection):
    """flt.vector_field = (lambda + K r, K_dot of eq. (11)) with the printed terms, at general (non-symmetric)
    K: with the (-)-connection K is not symmetric along a run (E of eq. 76 is not), so A K + K A' must not be
    computed as A K + (A K)'."""
    att = _attitude("weighted")  # the paper weights are a special case
    field = jax.jit(liemef.MinimumEnergyFilter(att, curvature="exact", connection=connection, alpha=ALPHA).vector_field)
    for Rot, Omega, y, K, tau in _attitude_cases(att, seed=6):
        xi, K_dot = field(_tso3(Rot, Omega), jnp.asarray(K), jnp.asarray(tau), jnp.asarray(y), 0.0)
        want = _printed_vector_field(_saccon(att, Rot, Omega, y, K, tau, connection),
                                     _tso3_lambda(att, Omega, tau), K)
        _assert_close(np.asarray(xi), want[0], f"TSO(3) {connection}: lambda + K r")
        _assert_close(np.asarray(K_dot), want[1], f"TSO(3) {connection}: K_dot")
    if connection == "zero":  # Rigo et al. 2022 print the (0)-connection filter only
        planar = _planar("weighted")
        field = jax.jit(liemef.MinimumEnergyFilter(planar, curvature="exact", connection="zero",
                                                   alpha=ALPHA).vector_field)
        for q, y, K, u in _planar_cases(planar, seed=7):
            xi, K_dot = field(tse2_state(*q), jnp.asarray(K), jnp.asarray(u), jnp.asarray(y), 0.0)
            want = _printed_vector_field(_rigo(planar, q, y, K, u, correct_misprint=True),
                                         _tse2_lambda(planar, q, u), K)
            _assert_close(np.asarray(xi), want[0], "TSE(2): lambda + K r")
            _assert_close(np.asarray(K_dot), want[1], "TSE(2): K_dot")


@pytest.mark.parametrize("connection", ["zero", "minus"])
def test_tso3_run_matches_printed_filter(connection):
    """flt.run (RKMK4, 2 ms) over 0.5 s of held samples equals Saccon's printed filter (Props. 5.1/5.2,
    observer + eq. 11) integrated by scipy on the embedded matrix ODE R_dot = R hat(xi). With the
    (-)-connection K leaves the symmetric matrices; with the (0)-connection it stays symmetric."""
    system = RigidBodyAttitude()
    a1, a2 = np.asarray(system.a1), np.asarray(system.a2)
    rng = np.random.default_rng(8)
    ts = np.arange(0.0, 0.5 + 0.005, 0.01)
    taus = np.column_stack([np.sin(2 * np.pi * ts / 3), np.cos(2 * np.pi * ts), np.sin(2 * np.pi * ts / 5)])
    truth = np.asarray(SO3.exp(jnp.asarray(np.outer(ts, [0.5, 0.6, 0.4]))).as_matrix())
    ys = np.array([pf.tso3_output(Rt, a1, a2) for Rt in truth]) + 0.05 * rng.standard_normal((ts.size, 6))
    R0 = np.asarray(SO3.exp(jnp.array([0.6, -0.5, 0.4])).as_matrix())
    Omega0, K0 = np.array([0.3, 0.8, 0.1]), np.eye(6)

    def rhs(t, z, tau, y):
        Rot, Omega, K = z[:9].reshape(3, 3), z[9:12], z[12:].reshape(6, 6)
        terms = _saccon(system, Rot, Omega, y, K, tau, connection)
        xi, K_dot = _printed_vector_field(terms, _tso3_lambda(system, Omega, tau), K, alpha=0.01)
        return np.concatenate([(Rot @ pf._so3_hat(xi[:3])).ravel(), xi[3:], K_dot.ravel()])

    z = np.concatenate([R0.ravel(), Omega0, K0.ravel()])
    ref = [z]
    for k in range(ts.size - 1):
        z = solve_ivp(rhs, (ts[k], ts[k + 1]), z, method="DOP853", rtol=1e-12, atol=1e-12,
                      args=(taus[k], ys[k])).y[:, -1]
        ref.append(z)
    ref = np.array(ref)

    sub = 5
    fine = np.linspace(0.0, ts[-1], sub * (ts.size - 1) + 1)
    hold = np.minimum(np.arange(fine.size) // sub, ts.size - 1)
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection=connection, alpha=0.01)
    traj = flt.run(flt.init(_tso3(R0, Omega0), K0), fine, taus[hold], ys[hold])
    R_run = np.asarray(traj.g_hat.factors[0].as_matrix())[::sub]
    Omega_run, K_run = np.asarray(traj.g_hat.factors[1].x)[::sub], np.asarray(traj.K)[::sub]
    R_ref, Omega_ref, K_ref = ref[:, :9].reshape(-1, 3, 3), ref[:, 9:12], ref[:, 12:].reshape(-1, 6, 6)
    between = SO3.from_matrix(jnp.asarray(R_ref.transpose(0, 2, 1) @ R_run))
    err_R = np.linalg.norm(np.asarray(between.log()), axis=-1)
    assert err_R.max() <= ODE_REFERENCE, err_R.max()
    assert np.abs(Omega_run - Omega_ref).max() <= ODE_REFERENCE * (1 + np.abs(Omega_ref).max())
    assert np.abs(K_run - K_ref).max() <= ODE_REFERENCE * np.abs(K_ref).max()
    asym = np.abs(K_ref - K_ref.transpose(0, 2, 1)).max() / np.abs(K_ref).max()
    assert asym > 1e-3 if connection == "minus" else asym < SYMMETRY
