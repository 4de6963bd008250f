"""Closed-form filter terms as PRINTED in the papers, in plain NumPy.

This module is the independent reference the generic (autodiff) engine is tested against. It imports only
NumPy and the standard library (no JAX, no ``liemef``), and every formula is the one printed in the paper,
cited by equation number. Printed misprints are reproduced unless a keyword says otherwise; each one is named
where it is implemented. See ``docs/errata.md`` for the list of known misprints.

Conventions (docs/theorem.md and docs/errata.md):

- Lie algebra coordinates are in the papers' basis order: se(2) = (omega, v_x, v_y), so(3) = (w_x, w_y, w_z),
  product groups concatenate their factors.
- Perturbations are left-trivialized: the direction ``e_j`` at ``g`` is the curve ``g exp(s e_j)``.
- Matrices of maps g -> g* follow ``M[i, j] = M(e_j)(e_i)`` (rows = second argument), so that ``K o E o K``
  is the plain matrix product ``K @ E @ K``. The printed matrices are taken entry by entry in the position in
  which they are printed (row i, column j of the printed array is ``M[i, j]``).
- Maps g -> g (A, W, B R^-1 B^T) are ordinary matrices acting on coordinate column vectors.
- The residual ``r`` is an n-vector (an element of g* in the dual basis).

Each ``*_terms`` function returns a dict of NumPy float arrays with keys ``"r"``, ``"A"``, ``"E"``, ``"W"``
and ``"BRB"`` (= B R^-1 B^T), the terms of the Riccati equation

    K_dot = -alpha K + A K + K A^T - K E K + B R^-1 B^T - W K - K W^T

and of the observer ``g_hat^-1 g_hat_dot = lambda + K r`` (Saccon et al. 2016, Theorem 4.1).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "tse2_output",
    "tso3_output",
    "rigo2022_tse2_terms",
    "saccon2016_tso3_terms",
    "zamani_circle_bias_rhs",
]

_RTOL = 1e-12


# ------------------------------------------------------------------------------------------------------------
# small helpers
# ------------------------------------------------------------------------------------------------------------


def _so3_hat(v):
    """Cross-product matrix ``v^x`` with ``v^x w = v x w``."""
    v = np.asarray(v, dtype=float)
    return np.array(
        [
            [0.0, -v[2], v[1]],
            [v[2], 0.0, -v[0]],
            [-v[1], v[0], 0.0],
        ]
    )


def _se2_ad(v):
    """Matrix of ad_v on se(2) = (omega, v_x, v_y), as printed in Rigo et al. 2022, Sec. III (eq. (10))."""
    w, vx, vy = (float(c) for c in v)
    return np.array(
        [
            [0.0, 0.0, 0.0],
            [vy, 0.0, -w],
            [-vx, w, 0.0],
        ]
    )


def _check_diagonal(M, name, size):
    M = np.asarray(M, dtype=float)
    if M.shape != (size, size):
        raise ValueError(f"{name} must be {size}x{size}, got shape {M.shape}")
    if not np.allclose(M, np.diag(np.diag(M)), rtol=0.0, atol=0.0):
        raise ValueError(f"{name} must be diagonal for the printed closed form to apply")
    return np.diag(M).copy()


def _check_equal(values, name):
    values = np.asarray(values, dtype=float)
    if not np.allclose(values, values[0], rtol=_RTOL, atol=0.0):
        raise ValueError(f"{name}: the printed closed form requires these entries to be equal, got {values}")
    return float(values[0])


# ------------------------------------------------------------------------------------------------------------
# outputs
# ------------------------------------------------------------------------------------------------------------


def tse2_output(state, l):
    """Output map of the planar rigid body, Rigo et al. 2022, eq. (13).

    Parameters
    ----------
    state : array_like, shape (6,)
        ``(theta, x, y, omega, v_x, v_y)``: pose angle, position of the centre of mass in the inertial frame,
        body-frame angular and linear velocities (coordinates of (g, Omega) in TSE(2) = SE(2) x se(2)).
    l : float
        Distance of each GPS antenna from the centre of mass along the body's first axis.

    Returns
    -------
    numpy.ndarray, shape (7,)
        ``(x1, y1, x2, y2, omega, v_x, v_y)`` with ``x1 = x + l cos(theta)``, ``y1 = y + l sin(theta)``,
        ``x2 = x - l cos(theta)``, ``y2 = y - l sin(theta)`` (eq. (13); Sec. VI misprints ``y1 = x + l sin``,
        ``y2 = x - l sin``, which is not used here).
    """
    th, x, y, om, vx, vy = (float(c) for c in np.asarray(state, dtype=float))
    c, s = np.cos(th), np.sin(th)
    return np.array([x + l * c, y + l * s, x - l * c, y - l * s, om, vx, vy])  # eq. (13)


def tso3_output(Rot, a1, a2):
    """Output map of the rigid-body attitude example, Saccon et al. 2016, eq. (57) (noise-free part).

    Parameters
    ----------
    Rot : array_like, shape (3, 3)
        Rotation matrix R in SO(3) (body-to-inertial: columns are the body axes in the inertial frame).
    a1, a2 : array_like, shape (3,)
        Known reference directions (the paper's ring-accented a_1, a_2) in the inertial frame.

    Returns
    -------
    numpy.ndarray, shape (6,)
        ``(R^T a1, R^T a2)``: the two directions expressed in the body frame.
    """
    Rot = np.asarray(Rot, dtype=float)
    return np.concatenate([Rot.T @ np.asarray(a1, dtype=float), Rot.T @ np.asarray(a2, dtype=float)])  # (57)


# ------------------------------------------------------------------------------------------------------------
# Rigo, Segala, Sansonetto, Muradore 2022: TSE(2), Proposition 1
# ------------------------------------------------------------------------------------------------------------


def rigo2022_tse2_terms(state, y, K, u, *, J, m, l, D, Q, B, R, correct_misprint=False):
    """Printed filter terms of Rigo et al. 2022, Proposition 1, eqs. (20)-(27), (0)-connection.

    Paper: D. Rigo, C. Segala, N. Sansonetto, R. Muradore, "Second-Order-Optimal Filter on Lie Groups for
    Planar Rigid Bodies", IEEE TAC 2022 (``rigo2022_mef_tse2_planar_rigid_body.md``). Residual eq. (22) with
    the weighted innovation eq. (23); A eq. (25); E eq. (26), with the weights of eq. (35) (see below);
    B R^-1 B^T and W eq. (27).

    Group and coordinates: TSE(2) = SE(2) x se(2) (product group, Sec. III-A). Algebra coordinates
    ``eta = (eta_theta, eta_x, eta_y, eta_omega, eta_vx, eta_vy)`` = (se(2) part (omega, v_x, v_y) of the
    pose; additive velocity part); perturbation ``(g exp(eta_g^), Omega + eta_Omega)``.

    Parameters
    ----------
    state : array_like, shape (6,)
        Estimate ``(theta, x, y, omega, v_x, v_y)``.
    y : array_like, shape (7,)
        Measurement ``(x1, y1, x2, y2, omega, v_x, v_y)`` (eq. (12)-(13)).
    K : array_like, shape (6, 6)
        Gain (used only in W).
    u : array_like, shape (2,)
        ``(u_omega, u_v)``: torque about the centre of mass and force along the body's first axis (the paper's
        input vector is ``(u_omega/J, u_v/m, 0)``). None of the returned terms depends on u, J or m; they are
        accepted so that the signature mirrors the system.
    J, m : float
        Inertia and mass (unused, see u).
    l : float
        Antenna lever arm (eq. (13)).
    D, Q : array_like, shape (7, 7)
        Diagonal, with the printed pattern ``D = diag(d2, d2, d2, d2, d3, d4, d4)`` (eq. (14)) and
        ``Q = diag(q2, q2, q2, q2, q3, q4, q4)`` (eq. (18)); a ValueError is raised otherwise, since the
        printed forms presuppose it.
    B : array_like, shape (6, 3)
        ``B = [0_{3x3}; B2]`` (Sec. IV); the zero top block is checked.
    R : array_like, shape (3, 3)
        Symmetric positive definite weight of the model error.
    correct_misprint : bool
        False (default): E uses a_{2,1} and a_{3,1} as printed in eq. (26), i.e. with the opposite sign of
        a_{1,2}, a_{1,3} (E is then not symmetric). True: a_{2,1} = a_{1,2} and a_{3,1} = a_{1,3}, which is
        what Theorem 4.1 gives (docs/errata.md).

    Returns
    -------
    dict with keys
        ``"r"`` (6,), ``"A"`` (6, 6), ``"E"`` (6, 6), ``"W"`` (6, 6), ``"BRB"`` (6, 6); matrix convention of
        the module docstring (E[i, j] = E(e_j)(e_i); the printed arrays are used in their printed positions).

    Notes
    -----
    Weights. Eq. (26) prints the constant entries ``2 l^2, 2, 2`` and ``I_3``, which hold only for Q = D^T D
    (the paper's choice). Here the general weighted version is used, eq. (35):
    ``(35) = diag(2 l^2 w_a, 2 w_a, 2 w_a, w_3, w_4, w_4)`` with ``w_a = q2/d2^2``, ``w_3 = q3/d3^2``,
    ``w_4 = q4/d4^2``; for Q = D^T D it reduces to (26).

    Sign. Sec. V-C writes ``E = -T_e L^* [ytilde o Hess h - dh^* D^-* Q D^-1 dh] T_e L``, i.e.
    ``E = (35) - (42)`` with the left translations applied; (26)'s a_{1,1} is indeed 2 l^2 minus the a_{1,1}
    of (42). (42) is written in (theta, x, y) coordinates; with ``L = blockdiag(1, Rot(theta))`` the printed
    E_1 of (26) equals ``(35) - (L^T (42) L)^T`` exactly (checked numerically), i.e. the printed position of
    (42)'s off-diagonal entries is transposed. This function uses (26) in its printed positions:
    ``E_1 = diag(35)_{1:3} + [[a11', a12, a13], [a21, 0, 0], [a31, 0, 0]]``, a11' the ytilde part of (26)'s
    a_{1,1}, the ytilde the weighted innovations of eq. (23).
    """
    state = np.asarray(state, dtype=float)
    y = np.asarray(y, dtype=float)
    K = np.asarray(K, dtype=float)
    B = np.asarray(B, dtype=float)
    R = np.asarray(R, dtype=float)
    th, _x, _y, om, vx, vy = state
    c, s = np.cos(th), np.sin(th)

    d = _check_diagonal(D, "D", 7)
    q = _check_diagonal(Q, "Q", 7)
    d2 = _check_equal(d[0:4], "D[0:4] (d2)")
    d4 = _check_equal(d[5:7], "D[5:7] (d4)")
    q2 = _check_equal(q[0:4], "Q[0:4] (q2)")
    q4 = _check_equal(q[5:7], "Q[5:7] (q4)")
    d3, q3 = d[4], q[4]
    w_a, w_3, w_4 = q2 / d2**2, q3 / d3**2, q4 / d4**2

    # eq. (23): ytilde = diag{q2/d2^2 (x4), q3/d3^2, q4/d4^2 (x2)} (y - y_hat)
    weights = np.array([w_a, w_a, w_a, w_a, w_3, w_4, w_4])
    yt = weights * (y - tse2_output(state, l))
    yt1, yt2, yt3, yt4, yt5, yt6, yt7 = yt

    # eq. (22): residual r = (r^g; r^Omega)
    r = np.array(
        [
            -(yt1 - yt3) * l * s + (yt2 - yt4) * l * c,
            (yt1 + yt3) * c + (yt2 + yt4) * s,
            -(yt1 + yt3) * s + (yt2 + yt4) * c,
            yt5,
            yt6,
            yt7,
        ]
    )

    # eq. (25)
    A = np.array(
        [
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            [-vy, 0.0, om, 0.0, 1.0, 0.0],
            [vx, -om, 0.0, 0.0, 0.0, 1.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, vy, 0.0, om],
            [0.0, 0.0, 0.0, -vx, -om, 0.0],
        ]
    )

    # eq. (26) entries (ytilde parts), with the constants of (26) replaced by the weights of eq. (35)
    a11 = (yt1 - yt3) * l * c + (yt2 - yt4) * l * s + 2.0 * l**2 * w_a  # (26) a_{1,1}; 2 l^2 -> (35)
    a12 = -0.5 * (yt2 + yt4) * c + 0.5 * (yt1 + yt3) * s  # (26) a_{1,2}
    a13 = +0.5 * (yt2 + yt4) * s + 0.5 * (yt1 + yt3) * c  # (26) a_{1,3}
    if correct_misprint:
        a21, a31 = a12, a13  # Theorem 4.1: E symmetric (docs/errata.md)
    else:
        a21 = +0.5 * (yt2 + yt4) * c - 0.5 * (yt1 + yt3) * s  # (26) a_{2,1}, as printed
        a31 = -0.5 * (yt2 + yt4) * s - 0.5 * (yt1 + yt3) * c  # (26) a_{3,1}, as printed
    E1 = np.array(
        [
            [a11, a12, a13],
            [a21, 2.0 * w_a, 0.0],  # (26) "2" -> (35) 2 q2/d2^2
            [a31, 0.0, 2.0 * w_a],
        ]
    )
    E = np.zeros((6, 6))
    E[:3, :3] = E1  # (26)
    E[3:, 3:] = np.diag([w_3, w_4, w_4])  # (26) "I_3" -> (35) diag(q3/d3^2, q4/d4^2, q4/d4^2)

    # Sec. IV / eq. (27): B R^-1 B^T = blockdiag(0, B2 R^-1 B2^T), B = [0; B2]
    if not np.allclose(B[:3], 0.0, rtol=0.0, atol=0.0):
        raise ValueError("B must have a zero top 3x3 block (B delta = (0, B2 delta)) for the printed form")
    B2 = B[3:6]
    BRB = np.zeros((6, 6))
    BRB[3:, 3:] = B2 @ np.linalg.solve(R, B2.T)

    # eq. (27): W = blockdiag(1/2 ad_{(K11 r^g + K12 r^Omega)^}, 0)
    Kr_g = K[:3, :3] @ r[:3] + K[:3, 3:] @ r[3:]
    W = np.zeros((6, 6))
    W[:3, :3] = 0.5 * _se2_ad(Kr_g)

    return {"r": r, "A": A, "E": E, "W": W, "BRB": BRB}


# ------------------------------------------------------------------------------------------------------------
# Saccon, Trumpf, Mahony, Aguiar 2016: TSO(3), Propositions 5.1 and 5.2
# ------------------------------------------------------------------------------------------------------------


def saccon2016_tso3_terms(Rot, Omega, y, K, tau, *, inertia, a1, a2, D, Q, B, R, connection):
    """Printed filter terms of Saccon et al. 2016, Section V, Propositions 5.1 and 5.2.

    Paper: A. Saccon, J. Trumpf, R. Mahony, A. P. Aguiar, "Second-Order-Optimal Minimum-Energy Filters on Lie
    Groups", IEEE TAC 2016 (``saccon2016_second_order_optimal_mef_lie_groups.md``).

    - ``connection="zero"``: Proposition 5.1, Cartan-Schouten (0)-connection (eq. (65)): residual eq. (68),
      A eq. (70), E eq. (71), B R^-1 B^T eq. (72), W eq. (73).
    - ``connection="minus"``: Proposition 5.2, (-)-connection (eq. (74)): residual eq. (68) (the proposition
      reuses (66)-(67)), A eq. (75), E eq. (76) (not symmetric), B R^-1 B^T eq. (77), W = 0 eq. (78).

    Group and coordinates: SO(3) x R^3 with the product structure (eq. (62)); algebra coordinates
    ``(eta_R; eta_Omega)`` in R^3_x x R^3, ad as in eqs. (63)-(64); perturbation
    ``(Rot exp(eta_R^x), Omega + eta_Omega)``.

    Parameters
    ----------
    Rot : array_like, shape (3, 3)
        Estimated attitude R_hat.
    Omega : array_like, shape (3,)
        Estimated body angular velocity Omega_hat.
    y : array_like, shape (6,)
        Measured directions in the body frame ``(a1, a2)`` (eq. (57); plain a_i in eqs. (68), (71), (76)).
    K : array_like, shape (6, 6)
        Gain (used only in W).
    tau : array_like, shape (3,)
        Applied torque (none of the returned terms depends on it; accepted to mirror the system).
    inertia : array_like, shape (3, 3)
        Inertia tensor I (used in A).
    a1, a2 : array_like, shape (3,)
        Known inertial reference directions (ring-accented a_i); the estimated outputs are
        ``a_hat_i = R_hat^T a_i`` (text before eq. (68)).
    D, Q : array_like, shape (6, 6)
        Block diagonal ``D = blockdiag(d1 I3, d2 I3)`` (eq. (58)), ``Q = blockdiag(q1 I3, q2 I3)`` (eq. (61));
        a ValueError is raised otherwise.
    B : array_like, shape (6, 3)
        ``B = [0; B2]`` (text after eq. (60)); the zero top block is checked.
    R : array_like, shape (3, 3)
        Symmetric positive definite weight of the model error.
    connection : {"zero", "minus"}
        Also accepted: "0", "(0)" and "-", "(-)".

    Returns
    -------
    dict with keys ``"r"`` (6,), ``"A"``, ``"E"``, ``"W"``, ``"BRB"`` (6, 6), in the module's matrix
    convention: the printed E of eq. (76) is used as printed, ``E[i, j] = E(e_j)(e_i)``.

    Notes
    -----
    docs/errata.md: Saccon's Sec. V-B eq. (84) prints ``a1 = d2 = sigma_eps``; it reads d1 = d2. That is
    an experiment parameter and does not enter here (d1 and d2 are read from D).
    """
    Rot = np.asarray(Rot, dtype=float)
    Omega = np.asarray(Omega, dtype=float)
    y = np.asarray(y, dtype=float)
    K = np.asarray(K, dtype=float)
    I_ = np.asarray(inertia, dtype=float)
    B = np.asarray(B, dtype=float)
    R = np.asarray(R, dtype=float)

    conn = {"zero": "zero", "0": "zero", "(0)": "zero", "minus": "minus", "-": "minus", "(-)": "minus"}.get(
        connection
    )
    if conn is None:
        raise ValueError(f"connection must be 'zero' or 'minus', got {connection!r}")

    D = np.asarray(D, dtype=float)
    Q = np.asarray(Q, dtype=float)
    for M, name in ((D, "D"), (Q, "Q")):
        dg = _check_diagonal(M, name, 6)
        _check_equal(dg[0:3], f"{name}[0:3]")
        _check_equal(dg[3:6], f"{name}[3:6]")
    d1, d2 = D[0, 0], D[3, 3]  # eq. (58)
    q1, q2 = Q[0, 0], Q[3, 3]  # eq. (61)
    w = (q1 / d1**2, q2 / d2**2)

    a_meas = (y[0:3], y[3:6])  # eq. (57): measured a_1, a_2 (body frame)
    a_hat = (Rot.T @ np.asarray(a1, dtype=float), Rot.T @ np.asarray(a2, dtype=float))  # R_hat^T a_i

    # eq. (68): r^R = -(q1/d1^2)(a_hat_1 x a_1) - (q2/d2^2)(a_hat_2 x a_2), r^Omega = 0
    rR = -w[0] * np.cross(a_hat[0], a_meas[0]) - w[1] * np.cross(a_hat[1], a_meas[1])
    r = np.concatenate([rR, np.zeros(3)])

    # eqs. (70) / (75): lower-right block I^-1 [ (I Omega_hat)^x - Omega_hat^x I ]
    A22 = np.linalg.solve(I_, _so3_hat(I_ @ Omega) - _so3_hat(Omega) @ I_)
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    A[3:, 3:] = A22
    if conn == "zero":
        A[:3, :3] = -_so3_hat(Omega)  # eq. (70)
    # else: eq. (75), top-left block 0

    E = np.zeros((6, 6))
    for wi, ai, ahi in zip(w, a_meas, a_hat, strict=True):
        if conn == "zero":
            # eq. (71): sum_i -(q_i/d_i^2) (a_hat_i^x a_i^x + a_i^x a_hat_i^x) / 2
            E[:3, :3] += -wi * (_so3_hat(ahi) @ _so3_hat(ai) + _so3_hat(ai) @ _so3_hat(ahi)) / 2.0
        else:
            # eq. (76): sum_i -(q_i/d_i^2) a_i^x a_hat_i^x   (not symmetric; used in its printed position)
            E[:3, :3] += -wi * (_so3_hat(ai) @ _so3_hat(ahi))

    # eqs. (72) / (77): B R^-1 B^T = blockdiag(0, B2 R^-1 B2^T)
    if not np.allclose(B[:3], 0.0, rtol=0.0, atol=0.0):
        raise ValueError("B must have a zero top 3x3 block (B delta = (0, B2 delta)) for the printed form")
    B2 = B[3:6]
    BRB = np.zeros((6, 6))
    BRB[3:, 3:] = B2 @ np.linalg.solve(R, B2.T)

    W = np.zeros((6, 6))
    if conn == "zero":
        # eq. (73): W = blockdiag(1/2 (K11 r^R + K12 r^Omega)^x, 0)
        W[:3, :3] = 0.5 * _so3_hat(K[:3, :3] @ r[:3] + K[:3, 3:] @ r[3:])
    # else: eq. (78), W = 0

    return {"r": r, "A": A, "E": E, "W": W, "BRB": BRB}


# ------------------------------------------------------------------------------------------------------------
# Zamani, Hua, Trumpf, Mahony: unit circle with gyro bias, eqs. (37)/(39) and Lemma 2 eq. (40)
# ------------------------------------------------------------------------------------------------------------


def zamani_circle_bias_rhs(
    theta,
    b,
    P,
    u,
    y,
    *,
    Q_w,
    Q_b,
    D,
    correct_misprint=True,
    measurement="vector",
    correct_lemma2_sign=False,
):
    """Right-hand side of the printed filter of Zamani et al., eq. (39) (gains eq. (37)) or Lemma 2, eq. (40).

    Paper: M. Zamani, M.-D. Hua, J. Trumpf, R. Mahony, "Minimum-Energy Filtering on the Unit Circle Using
    Velocity Measurements with Bias and Vectorial State Measurements" (``zamani_mef_unit_circle_bias.md``).

    System (paper): ``X_dot = X omega_x`` (eq. (1)), X = rotation by theta in SO(2) (eq. (2)), equivalently
    ``theta_dot = omega`` (Lemma 1, eq. (4)); gyro ``u = omega + B_omega v_omega + b`` (eq. (7)); bias
    ``b_dot = B_b v_b`` (eq. (8)); vector measurement ``y = X^T (1, 0)^T + D w`` (eq. (9)), or, for Lemma 2,
    the angle ``y'' = theta + w'`` (eq. (11)) with cost ``1 - cos(w')`` (eq. (13)). Cost eq. (12)/(14), with
    the paper's ``R := D D^T`` (a measurement weight, NOT the generic theorem's R), ``Q_w := B_omega^2`` and
    ``Q_b := B_b^2`` (text after eq. (17)).

    Parameters
    ----------
    theta, b : float
        Estimated angle (of X_hat) and bias b_hat.
    P : array_like, shape (2, 2)
        Information matrix ``[[P1, P12], [P12, P2]]`` (eq. (26), (34)); symmetric (checked).
    u : float
        Gyro measurement (eq. (7)).
    y : array_like, shape (2,) for ``measurement="vector"``; float y'' for ``measurement="angle"``.
    Q_w, Q_b : float
        ``B_omega^2`` and ``B_b^2``.
    D : array_like, shape (2, 2)
        Measurement scaling of eq. (9); the weight is ``R^-1 = (D D^T)^-1``. Unused (may be None) for
        ``measurement="angle"``, whose cost (13) has no D.
    correct_misprint : bool
        True (default): ``P12_dot = -Q_w P12 P1 - Q_b P12 P2 + P1`` (the (1,2) entry of ``-P BRB P``;
        docs/errata.md). False: as printed in eqs. (37), (39), (40), ``-Q_w P12 P1 - Q_b P2 P1 + P1``.
    measurement : {"vector", "angle"}
        "vector": eq. (39). "angle": Lemma 2, eq. (40).
    correct_lemma2_sign : bool
        Only for ``measurement="angle"``. False (default): the signs of eq. (40) as printed,
        ``theta_dot = u - b - P2/det sin(y'' - theta)``, ``b_dot = +P12/det sin(y'' - theta)``. These are the
        opposite of eq. (39) with D = I (where ``l = -sin(y'' - theta)``), although the paper states the two
        are equivalent, and the opposite of Theorem 4.1 (the printed correction pushes theta_hat away from
        y''). True: ``theta_dot = u - b + P2/det sin(y'' - theta)``, ``b_dot = -P12/det sin(y'' - theta)``.

    Returns
    -------
    (theta_dot, b_dot, P_dot) : (float, float, numpy.ndarray of shape (2, 2), symmetric)

    Printed equations (39) (vector), with ``y_hat := X_hat^T (1, 0)^T = (cos theta, -sin theta)`` (eq. (34))
    and ``S = [[0, -1], [1, 0]]`` (eq. (38)), ``det = P1 P2 - P12^2``::

        theta_dot = u - b - (P2 / det) l                 (X_hat_dot = X_hat (...)_x, read through Lemma 1)
        b_dot     = (P12 / det) l
        l         = 2 vex P_a(R^-1 (y - y_hat) y_hat^T)   (P_a eq. (32); vex of [[0,-a],[a,0]] is a)
        P1_dot    = -Q_w P1^2 - Q_b P12^2 - y_hat^T S R^-1 S y_hat + (y - y_hat)^T R^-1 y_hat
        P2_dot    = -Q_b P2^2 - Q_w P12^2 + 2 P12
        P12_dot   = -Q_w P12 P1 - Q_b P2 P1 + P1          (printed; see correct_misprint)

    The P1 equation prints ``y_hat_1^T S R^-1 S y_hat``; read literally (first component of y_hat) it is a
    2-vector, not a scalar, so it is read as ``y_hat^T``. With that reading it equals Theorem 4.1 and reduces
    to (40)'s ``cos(y'' - theta)`` for D = I, as the paper states. Both ``y_hat`` in l are the estimated
    output X_hat^T (1, 0)^T (the paper redefines y_hat in eq. (34)).

    Mapping to the generic theorem (docs/theorem.md), for tests that build the generic system:

    - group ``G = SO(2) x R``, algebra coordinates ``(theta; b)``, ``hat(theta) = theta S``; state
      ``g = (X(theta), b)``; abelian, so ad = 0, W = 0 and every connection gives the same filter;
    - dynamics ``lambda(g, u) = (u - b, 0)`` (eqs. (7)-(8) with v = 0);
    - model error ``delta = (v_omega, v_b)`` with ``B = diag(-B_omega, B_b)`` (eq. (7): omega =
      u - b - B_omega v_omega), ``B_omega = sqrt(Q_w)``, ``B_b = sqrt(Q_b)``; generic ``R = I_2`` (cost
      1/2 (v_omega^2 + v_b^2)); so ``B R^-1 B^T = diag(Q_w, Q_b)`` (the sign of B_omega does not matter);
    - output ``h(g) = X^T (1, 0)^T = (cos theta, -sin theta)``, generic ``D = D`` (paper's D), generic
      ``Q = I_2`` (cost 1/2 |w|^2), so ``D^-T Q D^-1 = (D D^T)^-1`` = the paper's R^-1;
    - ``alpha = 0``;
    - gain ``K = P^-1``; then ``theta_dot = u - b + (K r)_theta``, ``b_dot = (K r)_b`` and
      ``P_dot = -P A - A^T P + E - P BRB P`` with ``A = [[0, -1], [0, 0]]``, r = (-l, 0) and
      ``E = [[P1-measurement term, 0], [0, 0]]``;
    - initial cost: the theorem's initial cost is ``1/2 m0``, so ``m0(X0, b0) = 2 trace(I - X0)/K1 + b0^2/K2``
      (eq. (12)). Note: the left-trivialized Hessian at the identity of the paper's initial value function
      V(., ., 0) (eq. (19)), i.e. of ``1/2 m0``, is diag(2/K1, 1/K2) (trace(I - X) = 2 - 2 cos theta), whereas
      the paper states P1(0) = 1/K1, P2(0) = 1/K2 (text after eq. (38)); equivalently P(0) = diag(1/K1, 1/K2)
      is the Hessian of V(., ., 0) for ``trace(I - X0)/(2 K1)``. Simulations use the paper's statement.
    - Lemma 2 (``measurement="angle"``): ``1 - cos(y'' - theta) = 1/2 |(cos y'', -sin y'') - h(g)|^2``
      exactly, so the angle filter is the vector filter with D = I_2 and y = (cos y'', -sin y'') (up to the
      printed sign of eq. (40), see correct_lemma2_sign).
    """
    P = np.asarray(P, dtype=float)
    if P.shape != (2, 2):
        raise ValueError(f"P must be 2x2, got shape {P.shape}")
    if not np.isclose(P[0, 1], P[1, 0], rtol=1e-12, atol=1e-14):
        raise ValueError("P must be symmetric")
    P1, P2, P12 = P[0, 0], P[1, 1], P[0, 1]
    det = P1 * P2 - P12**2
    theta = float(theta)
    b = float(b)
    u = float(u)

    if measurement == "vector":
        y = np.asarray(y, dtype=float)
        D = np.asarray(D, dtype=float)
        Rinv = np.linalg.inv(D @ D.T)  # eq. (14): R := D D^T
        S = np.array([[0.0, -1.0], [1.0, 0.0]])  # eq. (38)
        y_hat = np.array([np.cos(theta), -np.sin(theta)])  # eq. (34): y_hat := X_hat^T (1, 0)^T
        M = Rinv @ np.outer(y - y_hat, y_hat)  # R^-1 (y - y_hat) y_hat^T
        Pa = 0.5 * (M - M.T)  # eq. (32)
        l = 2.0 * Pa[1, 0]  # eq. (39): l = 2 vex P_a(...)
        theta_dot = u - b - P2 / det * l  # eq. (39), first line (through Lemma 1)
        b_dot = P12 / det * l  # eq. (39), second line
        meas_term = -y_hat @ S @ Rinv @ S @ y_hat + (y - y_hat) @ Rinv @ y_hat  # eq. (39) P1 line
    elif measurement == "angle":
        ypp = float(y)
        sn = np.sin(ypp - theta)
        if correct_lemma2_sign:
            theta_dot = u - b + P2 / det * sn  # eq. (40) with the sign of eq. (39) / Theorem 4.1
            b_dot = -P12 / det * sn
        else:
            theta_dot = u - b - P2 / det * sn  # eq. (40), as printed
            b_dot = P12 / det * sn  # eq. (40), as printed
        meas_term = np.cos(ypp - theta)  # eq. (40) p1 line
    else:
        raise ValueError(f"measurement must be 'vector' or 'angle', got {measurement!r}")

    P1_dot = -Q_w * P1**2 - Q_b * P12**2 + meas_term  # eqs. (37)/(39)/(40)
    P2_dot = -Q_b * P2**2 - Q_w * P12**2 + 2.0 * P12  # eqs. (37)/(39)/(40)
    if correct_misprint:
        P12_dot = -Q_w * P12 * P1 - Q_b * P12 * P2 + P1  # docs/errata.md
    else:
        P12_dot = -Q_w * P12 * P1 - Q_b * P2 * P1 + P1  # eqs. (37)/(39)/(40), as printed
    P_dot = np.array([[P1_dot, P12_dot], [P12_dot, P2_dot]])
    return float(theta_dot), float(b_dot), P_dot


# ------------------------------------------------------------------------------------------------------------
# Rigo, Sansonetto, Muradore 2023: Chaplygin sleigh on SE(2) x R^2, Proposition 1 and Section 5
# ------------------------------------------------------------------------------------------------------------


def chaplygin_output(state, l, sensor="gps_ins"):
    """Output map of the Chaplygin sleigh, Rigo et al. 2023, eq. (10) (GPS only: its first four lines, Remark 2).

    Parameters
    ----------
    state : array_like, shape (5,)
        ``(theta, x, y, omega, v)``: blade angle, position of the blade's contact point, angular velocity and
        forward velocity along the blade (eq. (6)).
    l : float
        Distance of each antenna from the contact point along the blade (Fig. 2).
    sensor : {"gps_ins", "gps"}

    Returns
    -------
    numpy.ndarray, shape (6,) or (4,)
        ``(x + l cos, y + l sin, x - l cos, y - l sin[, omega, v])``.
    """
    th, x, y, om, v = (float(c) for c in np.asarray(state, dtype=float))
    c, s = np.cos(th), np.sin(th)
    gps = [x + l * c, y + l * s, x - l * c, y - l * s]  # eq. (10), lines 1-4
    if sensor == "gps":
        return np.array(gps)
    if sensor != "gps_ins":
        raise ValueError(f"sensor must be 'gps_ins' or 'gps', got {sensor!r}")
    return np.array(gps + [om, v])  # eq. (10), lines 5-6


def rigo2023_chaplygin_lambda(state, u, *, J, m, a):
    """Left-trivialized dynamics of the Chaplygin sleigh, Rigo et al. 2023, eqs. (20)-(21):
    ``(lambda_g; lambda_v) = ((omega, v, 0); (-m a/(J + m a^2) omega v + u_omega/(J + m a^2),
    a omega^2 + u_v/m))``."""
    _th, _x, _y, om, v = (float(c) for c in np.asarray(state, dtype=float))
    Ja = J + m * a**2
    return np.array([om, v, 0.0, -m * a / Ja * om * v + u[0] / Ja, a * om**2 + u[1] / m])  # eq. (21)


def rigo2023_chaplygin_terms(state, y, K, u, *, J, m, a, l, D, Q, B, R, sensor="gps_ins", connection="zero",
                             correct_misprint=False, weighted_constants=False):
    """Printed filter terms of Rigo et al. 2023: Proposition 1 ((0)-connection), Remark 2 (GPS only) and
    Section 5 ((-)-connection).

    Paper: D. Rigo, N. Sansonetto, R. Muradore, "Second-order-optimal filtering on SE(2) x R^2 for the
    Chaplygin sleigh", 2023 (``rigo2023_mef_chaplygin_sleigh.md``).

    - ``connection="zero"``: residual eq. (30) (GPS only: eq. (57)) with the weighted innovation eq. (27); A
      eq. (32); E eq. (33) (GPS only: eq. (58)); W eq. (34).
    - ``connection="minus"``: r as above; A eq. (60); W = 0 eq. (61); E eq. (62). The paper prints (62) for
      GPS + INS only; for GPS only the velocity block of (62) is replaced by the zero block of (58), as Remark 2
      does for the (0)-connection.
    - ``B R^-1 B^T = blockdiag(0_3, B2 R^-1 B2^T)`` (Sec. 5: nonzero only on the last 2 x 2 block).

    Group and coordinates: SE(2) x R^2 (eqs. (14)-(15)); algebra coordinates
    ``(eta_theta, eta_x, eta_y; eta_omega, eta_v)``, ad as in eq. (16); perturbation
    ``(g exp(eta_g^), V + eta_V)``.

    Parameters
    ----------
    state : array_like, shape (5,)
        Estimate ``(theta, x, y, omega, v)``.
    y : array_like, shape (6,) (``"gps_ins"``) or (4,) (``"gps"``)
        Measurement (eq. (9)-(10)).
    K : array_like, shape (5, 5)
        Gain (used only in W).
    u : array_like, shape (2,)
        ``(u_omega, u_v)`` (eq. (21)); none of the returned terms depends on it.
    J, m, a : float
        Inertia about the centre of mass, mass, distance of the centre of mass from the blade (A, eqs. (32),
        (60)).
    l : float
        Antenna lever arm (eq. (10)).
    D, Q : array_like, shape (p, p)
        Diagonal (eq. (22), Sec. 4: ``D = diag(d1..d6)``, ``Q = diag(q1..q6)``), with equal antenna weights
        ``q_i/d_i^2``, i = 1..4 (the printed E presupposes it; a ValueError is raised otherwise).
    B : array_like, shape (5, 2)
        ``B = [0_{3x2}; B2]`` (eq. (19)); the zero top block is checked.
    R : array_like, shape (2, 2)
        Symmetric positive definite weight of the model error.
    sensor : {"gps_ins", "gps"}
    connection : {"zero", "minus"}
    correct_misprint : bool
        False (default): E as printed. True: the theorem's E (docs/errata.md):
        for ``"zero"``, eq. (33)/(58)'s a_{2,1}, a_{3,1} are printed with the opposite sign of a_{1,2},
        a_{1,3}; corrected, a_{2,1} = a_{1,2} and a_{3,1} = a_{1,3} (E symmetric). For ``"minus"``, eq. (62)
        prints zeros at (x, theta) and (y, theta); corrected, they are 2 a_{1,2} and 2 a_{1,3} (the a_{i,j} of
        eq. (33)), and the theta row keeps its printed zeros.
    weighted_constants : bool
        False (default): the constant entries of E as printed, ``diag(2 l^2, 2, 2, 1, 1)`` (eqs. (33), (48),
        (62); (58): ``diag(2 l^2, 2, 2, 0, 0)``), which hold only for Q = D^T D (eq. (38) states
        ``D^-* Q D^-1 (y - h) = y - y_hat``) while the residual eq. (27) and the a_{i,j} carry the weights
        q_i/d_i^2. True: eq. (48) computed with the stated weights,
        ``diag(2 l^2 w_a, 2 w_a, 2 w_a, w_5, w_6)``, ``w_a = q_1/d_1^2`` (antennas), ``w_k = q_k/d_k^2``.

    Returns
    -------
    dict with keys ``"r"`` (5,), ``"A"``, ``"E"``, ``"W"``, ``"BRB"`` (5, 5), in the module's matrix
    convention (the printed arrays in their printed positions, ``E[i, j] = E(e_j)(e_i)``).
    """
    state = np.asarray(state, dtype=float)
    y = np.asarray(y, dtype=float)
    K = np.asarray(K, dtype=float)
    B = np.asarray(B, dtype=float)
    R = np.asarray(R, dtype=float)
    th, _x, _y, om, v = state
    c, s = np.cos(th), np.sin(th)
    p = {"gps_ins": 6, "gps": 4}.get(sensor)
    if p is None:
        raise ValueError(f"sensor must be 'gps_ins' or 'gps', got {sensor!r}")
    conn = {"zero": "zero", "0": "zero", "(0)": "zero", "minus": "minus", "-": "minus", "(-)": "minus"}.get(
        connection
    )
    if conn is None:
        raise ValueError(f"connection must be 'zero' or 'minus', got {connection!r}")

    d = _check_diagonal(D, "D", p)
    q = _check_diagonal(Q, "Q", p)
    w = q / d**2  # eq. (27)
    w_a = _check_equal(w[0:4], "q_i/d_i^2 of the antennas (i = 1..4)")

    # eq. (27): ytilde = diag(q_i/d_i^2) (y - y_hat)
    yt = w * (y - chaplygin_output(state, l, sensor))
    yt1, yt2, yt3, yt4 = yt[0:4]

    # eq. (30) (GPS + INS) / eq. (57) (GPS only: r^v = 0)
    r = np.zeros(5)
    r[0] = -(yt1 - yt3) * l * s + (yt2 - yt4) * l * c
    r[1] = (yt1 + yt3) * c + (yt2 + yt4) * s
    r[2] = -(yt1 + yt3) * s + (yt2 + yt4) * c
    if p == 6:
        r[3:5] = yt[4:6]

    # eq. (32) ((0)-connection) / eq. (60) ((-)-connection)
    k = m * a / (J + m * a**2)
    A = np.zeros((5, 5))
    A[0, 3] = A[1, 4] = 1.0
    A[3, 3], A[3, 4] = -k * v, -k * om
    A[4, 3] = 2.0 * a * om
    if conn == "zero":
        A[1, 2] = om  # eq. (32), second row
        A[2, 0], A[2, 1] = v, -om  # eq. (32), third row

    # eq. (33) entries (shared by (58) and (62))
    a11 = (yt1 - yt3) * l * c + (yt2 - yt4) * l * s  # the ytilde part of a_{1,1}
    a12 = -0.5 * (yt2 + yt4) * c + 0.5 * (yt1 + yt3) * s
    a13 = +0.5 * (yt2 + yt4) * s + 0.5 * (yt1 + yt3) * c
    if weighted_constants:  # eq. (48) with the stated weights
        const = [2.0 * l**2 * w_a, 2.0 * w_a, 2.0 * w_a] + ([w[4], w[5]] if p == 6 else [0.0, 0.0])
    else:  # eqs. (33), (48), (62) as printed; (58) for GPS only
        const = [2.0 * l**2, 2.0, 2.0] + ([1.0, 1.0] if p == 6 else [0.0, 0.0])
    E = np.diag(const)
    E[0, 0] += a11
    if conn == "zero":
        if correct_misprint:
            a21, a31 = a12, a13  # Theorem 4.1: E symmetric (docs/errata.md)
        else:
            a21 = +0.5 * (yt2 + yt4) * c - 0.5 * (yt1 + yt3) * s  # eq. (33) a_{2,1}, as printed
            a31 = -0.5 * (yt2 + yt4) * s - 0.5 * (yt1 + yt3) * c  # eq. (33) a_{3,1}, as printed
        E[0, 1], E[0, 2] = a12, a13  # eq. (33), first row
        E[1, 0], E[2, 0] = a21, a31  # eq. (33), first column
    elif correct_misprint:
        E[1, 0], E[2, 0] = 2.0 * a12, 2.0 * a13  # Theorem 4.1; eq. (62) prints 0 (docs/errata.md)
    # else: eq. (62) as printed, first row and column zero apart from a_{1,1}

    # Sec. 5: B R^-1 B^T = blockdiag(0, B2 R^-1 B2^T), B = [0; B2] (eq. (19))
    if not np.allclose(B[:3], 0.0, rtol=0.0, atol=0.0):
        raise ValueError("B must have a zero top 3x2 block (B xi = (0, B2 xi)) for the printed form")
    B2 = B[3:5]
    BRB = np.zeros((5, 5))
    BRB[3:, 3:] = B2 @ np.linalg.solve(R, B2.T)

    W = np.zeros((5, 5))
    if conn == "zero":
        # eq. (34): W = blockdiag(1/2 ad_{(K11 r^g + K12 r^v)^}, 0_2)
        W[:3, :3] = 0.5 * _se2_ad(K[:3, :3] @ r[:3] + K[:3, 3:] @ r[3:])
    # else: eq. (61), W = 0

    return {"r": r, "A": A, "E": E, "W": W, "BRB": BRB}


def rigo2023_embedding(state):
    """The 6 x 6 matrix of an element (g, V) of SE(2) x R^2, Rigo et al. 2023, eqs. (11) and (14)."""
    th, x, y, om, v = (float(c) for c in np.asarray(state, dtype=float))
    c, s = np.cos(th), np.sin(th)
    M = np.eye(6)
    M[:3, :3] = [[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]]  # eq. (11)
    M[3:5, 5] = [om, v]  # eq. (14)
    return M


def rigo2023_m0(state_hat, state0):
    """Initial cost of Rigo et al. 2023, eq. (26): ``m0(g_hat) = 1/2 |I - g_hat^-1 g0|_F^2`` with the matrices
    of eq. (14). Eq. (56) then states that its left-trivialized Hessian at g_hat = g0 is the identity."""
    G_hat, G0 = rigo2023_embedding(state_hat), rigo2023_embedding(state0)
    return 0.5 * float(np.sum((np.eye(6) - np.linalg.solve(G_hat, G0)) ** 2))  # eq. (26)


__all__ += ["chaplygin_output", "rigo2023_chaplygin_lambda", "rigo2023_chaplygin_terms", "rigo2023_embedding",
            "rigo2023_m0"]
