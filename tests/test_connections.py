"""Property tests of the connections: the Cartan-Schouten family, user connection functions, and the
connection Hessian formula of docs/theorem.md against finite differences on the group (which pins the matrix
convention)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from liemef.connections import CARTAN_SCHOUTEN, Connection, connection
from liemef.groups import R1, R2, R3, SE2, SE2R2, SO2, SO2R1, SO3, TSE2, TSO3, Product
from tolerances import ROUNDOFF, SECOND_FINITE_DIFF

GROUPS = [SO2, SO3, SE2, R1, R3, TSE2, TSO3, SE2R2, SO2R1, Product[SO3, SE2, R2]]
NAMED = [("minus", 0.0), ("zero", 0.5), ("plus", 1.0)]

group_param = pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
named_param = pytest.mark.parametrize(("name", "c"), NAMED, ids=[n for n, _ in NAMED])


@pytest.fixture
def rng():
    return np.random.default_rng(20220613)


def assert_close(actual, desired, tol, err_msg=""):
    np.testing.assert_allclose(np.asarray(actual), np.asarray(desired), rtol=tol, atol=tol, err_msg=err_msg)


@functools.cache
def _hat_basis(G):
    """``hat(e_k)`` for every k, shape (n, m, m)."""
    return np.asarray(G.hat(jnp.eye(G.tangent_dim)))


def bracket(G, X, Y):
    """``[X, Y]`` from the matrix commutator of the hats, independent of ``G.ad`` and ``G.vee`` (numpy,
    broadcasts over leading axes): the coordinates of the commutator in the basis ``hat(e_k)``."""
    E = _hat_basis(G)
    hX, hY = np.einsum("...k,kab->...ab", X, E), np.einsum("...k,kab->...ab", Y, E)
    comm = hX @ hY - hY @ hX
    return comm.reshape(*comm.shape[:-2], -1) @ np.linalg.pinv(E.reshape(len(E), -1))


def basis_brackets(G):
    """``B[m, j, i] = [e_j, e_i]_m`` from matrix commutators."""
    E = np.eye(G.tangent_dim)
    return np.moveaxis(bracket(G, E[:, None, :], E[None, :, :]), -1, 0)


def test_named_coefficients():
    assert CARTAN_SCHOUTEN == dict(NAMED)


@group_param
def test_structure_constants(G):
    C = np.asarray(connection("zero", G).C)
    n = G.tangent_dim
    assert C.shape == (n, n, n)
    assert_close(C, basis_brackets(G), ROUNDOFF)
    assert_close(G.structure_constants(), C, 0.0)


@group_param
@named_param
def test_named_connection_is_c_times_ad(G, name, c, rng):
    conn = connection(name, G)
    assert conn.name == name
    assert_close(conn.Gamma, c * np.asarray(conn.C), 0.0)
    X, Y = rng.standard_normal((2, G.tangent_dim))
    assert_close(conn.omega(X, Y), c * bracket(G, X, Y), ROUNDOFF)
    assert_close(conn.omega_matrix(X) @ Y, conn.omega(X, Y), ROUNDOFF)
    assert_close(conn.omega_matrix(X), c * np.asarray(G.ad(X)), ROUNDOFF)
    # A number c gives the same connection as its name.
    assert_close(connection(c, G).Gamma, conn.Gamma, 0.0)


@group_param
@named_param
def test_torsion_is_2c_minus_1_times_ad(G, name, c, rng):
    conn = connection(name, G)
    X, Y = rng.standard_normal((2, G.tangent_dim))
    T = np.asarray(conn.torsion_matrix(X))
    assert_close(T, (2 * c - 1) * np.asarray(G.ad(X)), ROUNDOFF)
    # The definition T(X, Y) = omega(X, Y) - omega(Y, X) - [X, Y].
    assert_close(T @ Y, conn.omega(X, Y) - conn.omega(Y, X) - bracket(G, X, Y), ROUNDOFF)
    if name == "zero":
        assert_close(T, np.zeros_like(T), 0.0)


@group_param
def test_user_function_of_half_ad_is_the_zero_connection(G, rng):
    conn = connection(lambda X, Y: 0.5 * (G.ad(X) @ Y), G)
    zero = connection("zero", G)
    assert isinstance(conn, Connection)
    assert_close(conn.Gamma, zero.Gamma, ROUNDOFF)
    assert_close(conn.C, zero.C, 0.0)
    X, r = rng.standard_normal((2, G.tangent_dim))
    assert_close(conn.torsion_matrix(X), np.zeros((G.tangent_dim, G.tangent_dim)), ROUNDOFF)
    assert_close(conn.hessian_correction(r), zero.hessian_correction(r), ROUNDOFF)


@pytest.mark.parametrize("G", [SO3, TSE2], ids=lambda G: G.__name__)
def test_user_function_tensor_index_order(G, rng):
    # Gamma[m, j, i] = omega(e_j, e_i)[m]: the first argument is the middle index.
    n = G.tangent_dim
    T = rng.standard_normal((n, n, n))
    conn = connection(lambda X, Y: jnp.einsum("mji,j,i->m", T, X, Y), G)
    assert_close(conn.Gamma, T, ROUNDOFF)
    conn = connection(lambda X, Y: X[0] * Y, G)  # omega(e_j, e_i) = [j == 0] e_i
    want = np.zeros((n, n, n))
    want[:, 0, :] = np.eye(n)
    assert_close(conn.Gamma, want, 0.0)
    X, Y = rng.standard_normal((2, n))
    assert_close(conn.omega(X, Y), X[0] * Y, ROUNDOFF)
    assert_close(conn.omega_matrix(X), X[0] * np.eye(n), ROUNDOFF)


@pytest.mark.parametrize(
    "fn",
    [
        lambda X, Y: X * jnp.linalg.norm(Y),
        lambda X, Y: X * jnp.abs(Y),
        lambda X, Y: X + Y,
        lambda X, Y: X * (Y @ Y),
        lambda X, Y: jnp.sin(X) * Y[0],
    ],
    ids=["X|Y|", "X*abs(Y)", "X+Y", "X(Y.Y)", "sin(X)Y0"],
)
def test_non_bilinear_function_is_rejected(fn):
    with pytest.raises(ValueError, match=r"expected a bilinear function omega\(X, Y\)"):
        connection(fn, TSE2)


def test_function_of_wrong_output_shape_is_rejected():
    with pytest.raises(ValueError, match=r"return a vector of shape \(6,\), got shape \(\)"):
        connection(lambda X, Y: X @ Y, TSE2)
    with pytest.raises(ValueError, match=r"failed on basis vectors of length 6"):
        connection(lambda X, Y: X @ jnp.ones((3, 3)), TSE2)


def test_unknown_name_is_rejected_with_the_valid_names():
    with pytest.raises(ValueError, match=r"expected one of \['minus', 'plus', 'zero'\].*got 'torsionfree'"):
        connection("torsionfree", TSO3)


@pytest.mark.parametrize("spec", [None, True, float("nan"), float("inf"), [0.5]], ids=repr)
def test_invalid_spec_is_rejected(spec):
    with pytest.raises(ValueError, match=r"connection: expected"):
        connection(spec, TSO3)


def test_connection_passes_through_and_under_jit(rng):
    conn = connection("minus", TSO3)
    assert connection(conn, TSO3) is conn
    X = rng.standard_normal(6)
    assert_close(jax.jit(lambda cn, x: cn.omega_matrix(x))(conn, X), conn.omega_matrix(X), ROUNDOFF)


@group_param
@named_param
def test_hessian_correction(G, name, c, rng):
    # M[i, j] = (1/2 - c) r . ad_{e_j} e_i: zero for c = 1/2, 0.5 r . ad_{e_j} e_i for c = 0.
    conn = connection(name, G)
    n = G.tangent_dim
    r = rng.standard_normal(n)
    want = (0.5 - c) * np.einsum("m,mji->ij", r, basis_brackets(G))
    M = np.asarray(conn.hessian_correction(r))
    assert_close(M, want, ROUNDOFF)
    if name == "zero":
        assert_close(M, np.zeros((n, n)), 0.0)


# --- the connection Hessian of docs/theorem.md against finite differences on the group ----------------------

FD_STEP_2 = 1e-4


def _nonlinear_output(G, rng):
    """A scalar nonlinear function of the element, through its matrix (every coordinate enters)."""
    m = G.matrix_dim
    W1, W2, W3 = rng.standard_normal((3, m, m))

    def h(g):
        M = g.as_matrix()
        return jnp.tanh(jnp.sum(W1 * M)) + jnp.sum(W2 * M) ** 2 + jnp.sin(jnp.sum(W3 * M))

    return h


@pytest.mark.parametrize("G", [TSO3, TSE2, SE2R2], ids=lambda G: G.__name__)
def test_connection_hessian_formula_matches_finite_differences(G, rng):
    # docs/theorem.md: H[i, j] = Hess_c h(e_j, e_i)
    #                            = d2/(ds dt) h(g exp(s e_j) exp(t e_i)) - c Dh . ad_{e_j} e_i,
    # computed by the engine as hessian(F)(0)[i, j] + hessian_correction(Dh), F(xi) = h(g exp(xi)).
    n = G.tangent_dim
    h = _nonlinear_output(G, rng)
    g = G.exp(rng.standard_normal(n))
    E = np.eye(n)

    def derivatives(g):
        F = lambda xi: h(g.rplus(xi))  # noqa: E731
        zero = jnp.zeros(n)

        def f(ej, ei, s, t):  # h(g exp(s e_j) exp(t e_i))
            return h(g.rplus(s * ej).rplus(t * ei))

        ej, ei = np.repeat(E, n, axis=0), np.tile(E, (n, 1))  # row j * n + i: the pair (e_j, e_i)
        d = FD_STEP_2
        vf = jax.vmap(f, in_axes=(0, 0, None, None))
        mixed = (vf(ej, ei, d, d) - vf(ej, ei, d, -d) - vf(ej, ei, -d, d) + vf(ej, ei, -d, -d)) / (4 * d * d)
        return jax.grad(F)(zero), jax.hessian(F)(zero), mixed.reshape(n, n)

    compiled = jax.jit(derivatives).lower(g).compile()
    Dh, hess, mixed = (np.asarray(a) for a in compiled(g))
    ad_term = np.einsum("m,mji->ji", Dh, basis_brackets(G))  # [j, i] = Dh . [e_j, e_i] = Dh . ad_{e_j} e_i
    assert np.abs(ad_term).max() > 1e-2, "the test function must see the non-commutativity"
    for name, c in NAMED:
        H = hess + np.asarray(connection(name, G).hessian_correction(Dh))
        H_fd = (mixed - c * ad_term).T  # rows are the second argument: H[i, j] = Hess_c h(e_j, e_i)
        assert_close(H, H_fd, SECOND_FINITE_DIFF, err_msg=name)
        # docs/theorem.md's closed form of the same matrix.
        assert_close(H, hess + (0.5 - c) * ad_term.T, ROUNDOFF, err_msg=name)
        if c != 0.5:  # non-symmetric: a transposed convention would fail above
            assert np.abs(H - H.T).max() > 1e-2
