"""Property tests of the Lie groups, organised by property and parametrised over every group.

Each property is checked on a batch of elements in one vectorised call (fixed numpy seed), against an
independent reference where one exists: matrix products, ``scipy.linalg.expm``, central finite differences.
"""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from liemef.groups import (
    R1,
    R2,
    R3,
    SE2,
    SE2R2,
    SE3,
    SE23,
    SEK3,
    SL3,
    SO2,
    SO2R1,
    SO3,
    TSE2,
    TSO3,
    LieGroup,
    MatrixGroup,
    Product,
    Rn,
    Sim3,
)
from liemef.groups._se2 import _TAYLOR as _SE2_TAYLOR
from liemef.groups._sek3 import _TAYLOR_SQ as _SEK3_TAYLOR_SQ
from liemef.groups._so3 import _TAYLOR_SQ as _SO3_TAYLOR_SQ
from tolerances import FINITE_DIFF, NEAR_PI, ROUNDOFF

GROUPS = [SO2, SO3, SE2, R1, R3, TSE2, TSO3, SE2R2, SO2R1, Product[SO3, SE2, R2],
          SE3, SE23, SEK3[3], Product[SE23, Rn[6]], SL3, Sim3]
PRODUCTS = [G for G in GROUPS if issubclass(G, Product)]
SLOW_GROUPS = (SL3, Sim3)
"""Generic matrix groups: their expm/logm loops take seconds to compile for each function and shape (about 4 min
for the whole property suite of the two on a busy 2-core machine), so their property tests are marked slow. The
fast suite checks the generic group against the closed forms (test_matrix_group_agrees_with_the_closed_forms)."""
BATCH = 16  # elements per vectorised check; one batch size throughout, so eager ops compile once per shape


def _base_factors(G: type[LieGroup]) -> tuple[type[LieGroup], ...]:
    if issubclass(G, Product):
        return tuple(itertools.chain.from_iterable(_base_factors(t) for t in G.factor_types))
    return (G,)


def _has_rotation(G) -> bool:
    return any(not issubclass(T, Rn) and T is not SL3 for T in _base_factors(G))


ROTATION_GROUPS = [G for G in GROUPS if _has_rotation(G)]

# Where the code switches between a Taylor series and the closed form (rotation angle theta).
TAYLOR_ANGLES = sorted({
    float(np.sqrt(_SO3_TAYLOR_SQ)),  # SO3.exp: theta^2 < _TAYLOR_SQ
    float(2 * np.arcsin(np.sqrt(_SO3_TAYLOR_SQ / 4))),  # SO3.log: sin(theta/2)^2 < _TAYLOR_SQ / 4
    _SE2_TAYLOR,  # SE2.exp / SE2.log: |omega| < _TAYLOR
    float(np.sqrt(_SEK3_TAYLOR_SQ)),  # SEK3's Jacobian coefficients: theta^2 < _TAYLOR_SQ
})
AROUND_THRESHOLDS = [a * f for a in TAYLOR_ANGLES for f in (1 - 1e-6, 1 + 1e-6)]
NEAR_IDENTITY = [1e-12, 1e-9, 1e-6, 1e-3, *AROUND_THRESHOLDS, 0.1]
PI_DISTANCES = [1e-3, 1e-6]  # distance of the rotation angle from pi


def sample_xi(G, rng, shape=(), angle=None, scale=1.0) -> np.ndarray:
    """Algebra coordinates of shape ``(*shape, n)``.

    Each rotation factor gets the rotation angle ``angle`` (uniform in [-3, 3] if None, i.e. inside the
    principal domain of log) about a random axis; every other coordinate is normal with standard deviation
    ``scale``, except Sim(3)'s log-scale and all of SL(3)'s coordinates, of standard deviation
    ``0.3 min(scale, 1)`` (exponentials of large non-skew generators are ill-conditioned matrices, and SL(3) has
    no rotation block whose angle could be set: its imaginary eigenvalue parts stay well inside (-pi, pi)).
    """
    blocks = []
    for T in _base_factors(G):
        a = rng.uniform(-3.0, 3.0, shape) if angle is None else np.broadcast_to(angle, shape).astype(float)

        def rotation_vector(a=a):
            u = rng.standard_normal((*shape, 3))
            return a[..., None] * u / np.linalg.norm(u, axis=-1, keepdims=True)

        bounded = 0.3 * np.minimum(scale, 1.0)
        if T is SO2:
            blocks.append(a[..., None])
        elif T is SO3:
            blocks.append(rotation_vector())
        elif issubclass(T, SEK3):
            blocks += [rotation_vector(), scale * rng.standard_normal((*shape, 3 * T.K))]
        elif T is Sim3:
            blocks += [rotation_vector(), scale * rng.standard_normal((*shape, 3)),
                       bounded * rng.standard_normal((*shape, 1))]
        elif T is SL3:
            blocks.append(bounded * rng.standard_normal((*shape, 8)))
        elif T is SE2:
            blocks.append(np.concatenate([a[..., None], scale * rng.standard_normal((*shape, 2))], axis=-1))
        else:
            blocks.append(scale * rng.standard_normal((*shape, T.tangent_dim)))
    return np.concatenate(blocks, axis=-1)


def near_pi_xi(G, rng, eps, shape=(BATCH,)) -> np.ndarray:
    """Rotation angles +-(pi - eps) (both signs), other coordinates random."""
    angle = (np.pi - eps) * np.where(np.arange(np.prod(shape)).reshape(shape) % 2 == 0, 1.0, -1.0)
    return sample_xi(G, rng, shape, angle=angle)


def near_identity_xi(G, rng, size=BATCH) -> np.ndarray:
    """The angles of NEAR_IDENTITY (cycled to ``size`` rows), the other coordinates of the same size."""
    angle = np.resize(NEAR_IDENTITY, size)
    return sample_xi(G, rng, (size,), angle=angle, scale=angle[:, None])


def random_elements(G, rng, shape=(BATCH,)):
    return G.exp(sample_xi(G, rng, shape))


def numpy_elements(G, rng, shape):
    """Random elements with numpy leaves of any batch shape, made without compiling for a new shape (the eager
    ``exp`` runs on the usual (BATCH,) batch)."""
    size = int(np.prod(shape))
    assert size <= BATCH
    elements = random_elements(G, rng)
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[:size].reshape(*shape, -1), elements)


def basis_hats(G) -> np.ndarray:
    """``E[k] = hat(e_k)``."""
    return np.asarray(G.hat(jnp.eye(G.tangent_dim)))


def assert_close(actual, desired, tol, err_msg=""):
    np.testing.assert_allclose(np.asarray(actual), np.asarray(desired), rtol=tol, atol=tol, err_msg=err_msg)


def vee(G, X):
    return np.asarray(G.vee(jnp.asarray(X)))


@pytest.fixture
def rng():
    return np.random.default_rng(20160729)


def _params(groups):
    return [pytest.param(G, marks=pytest.mark.slow) if G in SLOW_GROUPS else G for G in groups]


group_param = pytest.mark.parametrize("G", _params(GROUPS), ids=lambda G: G.__name__)


def _xi_cases(G, rng):
    return {
        "random": sample_xi(G, rng, (BATCH,)),
        "near_identity": near_identity_xi(G, rng),
        **{f"pi-{eps:g}": near_pi_xi(G, rng, eps) for eps in PI_DISTANCES},
    }


# --- group axioms and representations -----------------------------------------------------------------------


@group_param
def test_associativity(G, rng):
    a, b, c = (random_elements(G, rng) for _ in range(3))
    assert_close(((a @ b) @ c).as_matrix(), (a @ (b @ c)).as_matrix(), ROUNDOFF)


@group_param
def test_identity(G, rng):
    a = random_elements(G, rng)
    e = G.identity()
    assert_close(e.as_matrix(), np.eye(G.matrix_dim), 0.0)
    assert_close(e.log(), np.zeros(G.tangent_dim), 0.0)
    assert_close((e @ a).as_matrix(), a.as_matrix(), ROUNDOFF)
    assert_close((a @ e).as_matrix(), a.as_matrix(), ROUNDOFF)
    assert_close(G.exp(np.zeros(G.tangent_dim)).as_matrix(), np.eye(G.matrix_dim), 0.0)


@group_param
def test_inverse(G, rng):
    a = random_elements(G, rng)
    eye = np.broadcast_to(np.eye(G.matrix_dim), (BATCH, G.matrix_dim, G.matrix_dim))
    assert_close((a @ a.inverse()).as_matrix(), eye, ROUNDOFF)
    assert_close((a.inverse() @ a).as_matrix(), eye, ROUNDOFF)
    assert_close(a.inverse().as_matrix(), np.linalg.inv(np.asarray(a.as_matrix())), ROUNDOFF)
    assert_close(a.inverse().inverse().as_matrix(), a.as_matrix(), ROUNDOFF)


@group_param
def test_matrix_representation_is_homomorphism(G, rng):
    a, b = random_elements(G, rng), random_elements(G, rng)
    Ma, Mb = np.asarray(a.as_matrix()), np.asarray(b.as_matrix())
    assert_close((a @ b).as_matrix(), Ma @ Mb, ROUNDOFF)
    assert_close(a.between(b).as_matrix(), np.linalg.inv(Ma) @ Mb, ROUNDOFF)


@group_param
def test_from_matrix_round_trip(G, rng):
    for case, xi in _xi_cases(G, rng).items():
        M = np.asarray(G.exp(xi).as_matrix())
        assert_close(G.from_matrix(M).as_matrix(), M, ROUNDOFF, err_msg=case)


@group_param
def test_coords_round_trip(G, rng):
    a = random_elements(G, rng)
    q = np.asarray(a.coords())
    assert q.shape == (BATCH, G.coords_dim)
    assert_close(G.from_coords(q).as_matrix(), a.as_matrix(), ROUNDOFF)
    assert_close(G.from_coords(q).coords(), q, ROUNDOFF)


# --- exp and log --------------------------------------------------------------------------------------------


@group_param
def test_exp_matches_expm(G, rng):
    for case, xi in _xi_cases(G, rng).items():
        want = scipy.linalg.expm(np.asarray(G.hat(xi)))
        assert_close(G.exp(xi).as_matrix(), want, ROUNDOFF, err_msg=case)


@group_param
def test_log_exp_round_trip_random(G, rng):
    xi = sample_xi(G, rng, (BATCH,), scale=3.0)
    assert_close(G.exp(xi).log(), xi, ROUNDOFF)
    assert_close(G.from_matrix(G.exp(xi).as_matrix()).log(), xi, ROUNDOFF)  # exp == expm: tested above


@group_param
def test_log_exp_round_trip_near_identity(G, rng):
    # Relative to |xi|: a Taylor branch that is merely "small" near 0 must still be accurate relative to xi.
    # A MatrixGroup holds the matrix itself, whose diagonal 1 + O(xi) keeps xi only to round-off absolutely
    # (SL(3)'s diagonal generators, Sim(3)'s scale): there the bound is ROUNDOFF relative or 1e-15 absolute.
    xi = near_identity_xi(G, rng)
    err = np.linalg.norm(np.asarray(G.exp(xi).log()) - xi, axis=-1) / np.linalg.norm(xi, axis=-1)
    if issubclass(G, MatrixGroup):
        err = np.minimum(err, np.linalg.norm(np.asarray(G.exp(xi).log()) - xi, axis=-1) / 1e-15 * ROUNDOFF)
    worst = int(np.argmax(err))
    assert err[worst] <= ROUNDOFF, f"relative error {err[worst]:.3g} at xi = {xi[worst]}"


@pytest.mark.parametrize("G", _params(ROTATION_GROUPS), ids=lambda G: G.__name__)
@pytest.mark.parametrize("eps", PI_DISTANCES)
def test_log_exp_round_trip_near_pi(G, eps, rng):
    xi = near_pi_xi(G, rng, eps)
    assert_close(G.exp(xi).log(), xi, NEAR_PI)
    assert_close(G.from_matrix(G.exp(xi).as_matrix()).log(), xi, NEAR_PI)


@pytest.mark.parametrize("G", [G for G in ROTATION_GROUPS if not issubclass(G, MatrixGroup)],
                         ids=lambda G: G.__name__)
def test_log_at_exactly_pi(G, rng):
    # MatrixGroup.log is the principal logarithm, undefined on the cut locus: see
    # test_matrix_group_log_on_the_cut_locus.
    # On the cut locus log picks one of the two (or, in SO(3), of the circle of) preimages; exp must return g.
    # For SO(3) also the quaternions with |w| below 1e-12, which take their own branch in SO3.log.
    xi = near_pi_xi(G, rng, 0.0)
    a = G.exp(xi)
    assert_close(G.exp(a.log()).as_matrix(), a.as_matrix(), NEAR_PI)
    if G is SO3:
        u = rng.standard_normal((BATCH, 3))
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        w = np.resize([0.0, 1e-13, -1e-13, -0.0], BATCH)[:, None]
        q = np.concatenate([w, np.sqrt(1 - w**2) * u], axis=-1)
        log = np.asarray(SO3(q).log())
        assert_close(np.linalg.norm(log, axis=-1), np.full(BATCH, np.pi), NEAR_PI)
        assert_close(SO3.exp(log).as_matrix(), SO3(q).as_matrix(), NEAR_PI)


@group_param
def test_exp_log_round_trip(G, rng):
    # Elements far from the principal domain (products of large rotations): log gives some preimage.
    a = random_elements(G, rng) @ random_elements(G, rng) @ random_elements(G, rng)
    assert_close(G.exp(a.log()).as_matrix(), a.as_matrix(), ROUNDOFF)


def test_so3_log_ignores_quaternion_sign(rng):
    # Both quaternions q and -q are the same rotation; compositions produce either sign.
    for case, xi in _xi_cases(SO3, rng).items():
        q = SO3.exp(xi).wxyz
        assert_close(SO3(-q).log(), xi, NEAR_PI, err_msg=case)
    xi = near_identity_xi(SO3, rng)
    err = np.linalg.norm(np.asarray(SO3(-SO3.exp(xi).wxyz).log()) - xi, axis=-1) / np.linalg.norm(xi, axis=-1)
    assert err.max() <= ROUNDOFF


# --- Lie algebra --------------------------------------------------------------------------------------------


@group_param
def test_hat_vee_inverse(G, rng):
    xi = sample_xi(G, rng, (BATCH,))
    # Closed-form vee reads entries (exact); a MatrixGroup's is the dual basis, a sum of products (round-off).
    assert_close(G.vee(G.hat(xi)), xi, ROUNDOFF if issubclass(G, MatrixGroup) else 0.0)
    E = basis_hats(G)
    # The hat matrices of the basis are linearly independent (vee is a left inverse on their span).
    assert np.linalg.matrix_rank(E.reshape(G.tangent_dim, -1)) == G.tangent_dim
    assert_close(G.hat(xi), np.einsum("...k,kab->...ab", xi, E), ROUNDOFF)


@group_param
def test_ad_is_matrix_commutator(G, rng):
    X, Y = sample_xi(G, rng, (BATCH,)), sample_xi(G, rng, (BATCH,))
    hX, hY = np.asarray(G.hat(X)), np.asarray(G.hat(Y))
    adXY = np.einsum("...ij,...j->...i", G.ad(X), Y)
    assert_close(adXY, vee(G, hX @ hY - hY @ hX), ROUNDOFF)
    C = np.asarray(G.structure_constants())  # C[m, j, i] = (ad_{e_j} e_i)_m
    assert_close(np.einsum("mji,...j,...i->...m", C, X, Y), adXY, ROUNDOFF)


@group_param
def test_jacobi_identity(G, rng):
    X, Y, Z = (sample_xi(G, rng, (BATCH,)) for _ in range(3))

    def br(A, B):
        return np.einsum("...ij,...j->...i", G.ad(A), B)

    assert_close(br(X, br(Y, Z)) + br(Y, br(Z, X)) + br(Z, br(X, Y)), np.zeros_like(X), ROUNDOFF)


@group_param
def test_Ad_is_conjugation(G, rng):
    g, xi = random_elements(G, rng), sample_xi(G, rng, (BATCH,))
    M = np.asarray(g.as_matrix())
    want = vee(G, M @ np.asarray(G.hat(xi)) @ np.linalg.inv(M))
    assert_close(np.einsum("...ij,...j->...i", g.Ad(), xi), want, ROUNDOFF)


@group_param
def test_Ad_exp_is_expm_ad(G, rng):
    xi = sample_xi(G, rng, (BATCH,))
    assert_close(G.exp(xi).Ad(), scipy.linalg.expm(np.asarray(G.ad(xi))), ROUNDOFF)


@group_param
def test_Ad_is_homomorphism(G, rng):
    a, b = random_elements(G, rng), random_elements(G, rng)
    assert_close((a @ b).Ad(), np.asarray(a.Ad()) @ np.asarray(b.Ad()), ROUNDOFF)
    assert_close(a.inverse().Ad(), np.linalg.inv(np.asarray(a.Ad())), ROUNDOFF)


@group_param
def test_conjugate_of_exp_is_exp_of_Ad(G, rng):
    g, xi = random_elements(G, rng), sample_xi(G, rng, (BATCH,))
    lhs = (g @ G.exp(xi) @ g.inverse()).as_matrix()
    assert_close(lhs, G.exp(np.einsum("...ij,...j->...i", g.Ad(), xi)).as_matrix(), ROUNDOFF)


# --- derivatives --------------------------------------------------------------------------------------------
# Each group's derivative checks are a few jitted, vmapped functions over a batch (compiled once per group).

FD_STEP = 1e-5
def _central_fd(f, x, h):
    """Central differences of ``f: (n,) -> (...)`` at ``x`` (n,): shape ``(..., n)``."""
    steps = h * jnp.eye(x.shape[-1])
    return jnp.moveaxis((jax.vmap(f)(x + steps) - jax.vmap(f)(x - steps)) / (2 * h), 0, -1)


def _exp_matrix(G):
    return lambda xi: G.exp(xi).as_matrix()


@functools.cache
def _exp_first_derivatives(G):
    """Batched (jacfwd, central differences) of ``xi -> exp(xi).as_matrix()`` (reverse mode: see Hessian)."""
    f = _exp_matrix(G)
    return jax.jit(jax.vmap(lambda xi: (jax.jacfwd(f)(xi), _central_fd(f, xi, FD_STEP))))


@functools.cache
def _exp_hessian(G):
    """Batched ``jax.hessian`` (forward over reverse) of ``xi -> exp(xi).as_matrix()``."""
    return jax.jit(jax.vmap(jax.hessian(_exp_matrix(G))))


def _exp_jacobian_fd(G, xi):
    """Central differences of the autodiff Jacobian of ``exp`` at the rows of ``xi`` (BATCH, n)."""
    jac = _exp_first_derivatives(G)
    cols = [(np.asarray(jac(xi + FD_STEP * e)[0]) - np.asarray(jac(xi - FD_STEP * e)[0])) / (2 * FD_STEP)
            for e in np.eye(G.tangent_dim)]
    return np.stack(cols, axis=-1)


@functools.cache
def _log_first_derivatives(G):
    """Batched (jacfwd, central differences with step h) of ``delta -> log(g exp(delta))`` at 0."""

    def one(g, h):
        F = lambda delta: g.rplus(delta).log()  # noqa: E731
        zero = jnp.zeros(G.tangent_dim)
        return jax.jacfwd(F)(zero), _central_fd(F, zero, h)

    return jax.jit(jax.vmap(one, in_axes=(0, None)))


@group_param
@pytest.mark.parametrize("where", ["zero", "near_identity", "random", "pi-1e-3", "pi-1e-6"])
def test_exp_jacobian_matches_finite_differences(G, where, rng):
    if where == "zero":
        xi = np.zeros((BATCH, G.tangent_dim))
    elif where == "near_identity":  # both sides of every Taylor threshold
        xi = near_identity_xi(G, rng)
    elif where == "random":
        xi = sample_xi(G, rng, (BATCH,))
    else:
        xi = near_pi_xi(G, rng, float(where[3:]))
    J, fd = (np.asarray(a) for a in _exp_first_derivatives(G)(jnp.asarray(xi)))
    assert np.isfinite(J).all()
    assert_close(J, fd, FINITE_DIFF)
    if where == "zero":
        assert_close(J[0], np.moveaxis(basis_hats(G), 0, -1), ROUNDOFF)


@group_param
@pytest.mark.parametrize("where", ["identity", "near_identity", "random", "pi-1e-3", "pi-1e-6"])
def test_log_jacobian_matches_finite_differences(G, where, rng):
    # d/d delta log(g exp(delta)) at delta = 0: the inverse right Jacobian at log(g).
    if where == "identity":
        xi, h = np.zeros((BATCH, G.tangent_dim)), FD_STEP
    elif where == "near_identity":  # g on both sides of every Taylor threshold; the steps cross them
        xi, h = near_identity_xi(G, rng), FD_STEP
    elif where == "random":
        xi, h = sample_xi(G, rng, (BATCH,)), FD_STEP
    else:
        eps = float(where[3:])
        xi, h = near_pi_xi(G, rng, eps), min(FD_STEP, eps / 10)  # the step must not cross the cut locus at pi
    J, fd = (np.asarray(a) for a in _log_first_derivatives(G)(G.exp(xi), jnp.asarray(h)))
    assert np.isfinite(J).all()
    assert_close(J, fd, FINITE_DIFF)
    if where == "identity":
        assert_close(J[0], np.eye(G.tangent_dim), ROUNDOFF)


@group_param
def test_exp_second_derivative_at_zero(G):
    # d^2/(ds dt) exp(sX + tY) at 0 = (XY + YX) / 2: the engine differentiates exp twice at exactly 0.
    xi = np.zeros((BATCH, G.tangent_dim))
    H, fd = np.asarray(_exp_hessian(G)(xi))[0], _exp_jacobian_fd(G, xi)[0]
    assert np.isfinite(H).all()
    E = basis_hats(G)
    want = 0.5 * (np.einsum("aij,bjk->ikab", E, E) + np.einsum("bij,ajk->ikab", E, E))  # (m, m, n, n)
    assert_close(H, want, ROUNDOFF)
    assert_close(fd, want, FINITE_DIFF)


@group_param
def test_exp_second_derivative_across_taylor_thresholds(G, rng):
    # Autodiff Hessian of exp against central differences of its autodiff Jacobian on both sides of each
    # threshold (and at random points): a Taylor branch with a wrong second-order term shows here.
    near = sample_xi(G, rng, (BATCH,), angle=np.resize(AROUND_THRESHOLDS, BATCH), scale=0.01)
    xi = np.where(np.arange(BATCH)[:, None] < BATCH // 2, near, sample_xi(G, rng, (BATCH,)))
    H = np.asarray(_exp_hessian(G)(xi))
    assert np.isfinite(H).all()
    fd = _exp_jacobian_fd(G, xi)
    assert_close(H, fd, FINITE_DIFF)


# --- batching, jit, vmap, scan ------------------------------------------------------------------------------


def _ops(G, a, b, xi):
    """Every operation each group implements, as arrays (the derived rplus, rminus, between: tested above)."""
    return {
        "compose": (a @ b).as_matrix(),
        "inverse": a.inverse().as_matrix(),
        "log": a.log(),
        "as_matrix": a.as_matrix(),
        "coords": a.coords(),
        "Ad": a.Ad(),
        "exp": G.exp(xi).as_matrix(),
        "hat": G.hat(xi),
        "vee": G.vee(G.hat(xi)),
        "ad": G.ad(xi),
        "from_matrix": G.from_matrix(a.as_matrix()).as_matrix(),
        "from_coords": G.from_coords(a.coords()).as_matrix(),
    }


@functools.cache
def _jit_ops(G):
    """The operations, compiled: on single elements (the loop reference) and on 2-D batches."""
    return jax.jit(functools.partial(_ops, G))


@functools.cache
def _jit_vmap_ops(G):
    """The operations vmapped over single elements, compiled."""
    return jax.jit(jax.vmap(functools.partial(_ops, G)))


def _assert_ops_close(actual, desired, label):
    assert actual.keys() == desired.keys()
    for name in desired:
        assert_close(actual[name], desired[name], ROUNDOFF, err_msg=f"{label}: {name}")


@group_param
@pytest.mark.parametrize("shape", [(BATCH,), (2, 3)], ids=str)
def test_batched_ops_equal_loop(G, shape, rng):
    # Batched evaluation (eager on the usual 1-D batch, compiled on a 2-D one: eager evaluation on a fresh
    # shape would spend this file's time budget compiling single primitives) against a python loop of
    # compiled single-element (batch shape ()) evaluations.
    a, b = numpy_elements(G, rng, shape), numpy_elements(G, rng, shape)
    xi = sample_xi(G, rng, shape)
    assert a.batch_shape == shape
    if shape == (BATCH,):
        batched = _ops(G, *jax.tree_util.tree_map(jnp.asarray, (a, b, xi)))
    else:
        batched = _jit_ops(G)(a, b, xi)
    for name, value in batched.items():
        assert value.shape[: len(shape)] == shape, name
    batched = jax.tree_util.tree_map(np.asarray, batched)  # numpy: indexing is free
    for idx in np.ndindex(shape):
        single = _jit_ops(G)(a[idx], b[idx], xi[idx])
        assert a[idx].batch_shape == ()
        _assert_ops_close({k: v[idx] for k, v in batched.items()}, single, f"element {idx}")


@group_param
def test_jit_and_vmap_match_eager(G, rng):
    a, b = random_elements(G, rng), random_elements(G, rng)
    xi = jnp.asarray(sample_xi(G, rng, (BATCH,)))
    # jit of single elements against eager: test_batched_ops_equal_loop; here jit(vmap) against eager.
    _assert_ops_close(_jit_vmap_ops(G)(a, b, xi), _ops(G, a, b, xi), "jit(vmap)")


@group_param
def test_batch_broadcasts_against_single_element(G, rng):
    a = random_elements(G, rng)
    Ma = np.asarray(a.as_matrix())
    b, Mb = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[0], a), Ma[0]  # one element, batch shape ()
    assert b.batch_shape == ()
    ab, ba = (a @ b), (b @ a)
    assert ab.batch_shape == ba.batch_shape == (BATCH,)
    assert_close(ab.as_matrix(), Ma @ Mb, ROUNDOFF)
    assert_close(ba.as_matrix(), Mb @ Ma, ROUNDOFF)


@group_param
def test_elements_pass_through_scan(G, rng):
    xs = random_elements(G, rng)

    def step(carry, x):
        carry = carry @ x
        return carry, carry

    final, history = jax.lax.scan(step, G.identity(), xs)
    assert isinstance(final, G) and isinstance(history, G)
    assert history.batch_shape == (BATCH,)
    Ms, got = np.asarray(xs.as_matrix()), np.asarray(history.as_matrix())
    want = np.eye(G.matrix_dim)
    for k in range(BATCH):
        want = want @ Ms[k]
        assert_close(got[k], want, ROUNDOFF)
    assert_close(final.as_matrix(), want, ROUNDOFF)


@group_param
@pytest.mark.parametrize("shape", [(), (5,), (2, 3)], ids=str)
def test_batch_shape(G, shape):
    n, m = G.tangent_dim, G.matrix_dim

    def shapes():  # traced only (jax.eval_shape): the shapes, without compiling anything
        e = G.identity(shape)
        g = G.exp(jnp.zeros((*shape, n)))
        out = {"identity": e.batch_shape, "exp": g.batch_shape, "as_matrix": g.as_matrix().shape,
               "Ad": g.Ad().shape, "log": g.log().shape, "coords": g.coords().shape,
               "ad": G.ad(jnp.zeros((*shape, n))).shape, "hat": G.hat(jnp.zeros((*shape, n))).shape}
        if shape:
            out["index"] = g[0].batch_shape
        return out

    got = {}
    jax.eval_shape(lambda: got.update(shapes()))
    want = {"identity": shape, "exp": shape, "as_matrix": (*shape, m, m), "Ad": (*shape, n, n),
            "log": (*shape, n), "coords": (*shape, G.coords_dim), "ad": (*shape, n, n), "hat": (*shape, m, m)}
    if shape:
        want["index"] = shape[1:]
    assert got == want


# --- conventions (one convention, written once: docs/concepts.md) -----------------------------------------


def _rot2(w):
    return np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])


def test_se2_algebra_order_is_omega_vx_vy():
    w, vx, vy = 0.7, 1.3, -0.4
    M = np.asarray(SE2.exp(np.array([w, 0.0, 0.0])).as_matrix())
    assert_close(M[:2, :2], _rot2(w), ROUNDOFF)
    assert_close(M[:2, 2], np.zeros(2), 0.0)
    M = np.asarray(SE2.exp(np.array([0.0, vx, vy])).as_matrix())
    assert_close(M, np.array([[1.0, 0.0, vx], [0.0, 1.0, vy], [0.0, 0.0, 1.0]]), 0.0)
    assert_close(SE2.hat(np.array([w, vx, vy])), [[0.0, -w, vx], [w, 0.0, vy], [0.0, 0.0, 0.0]], 0.0)
    q = np.array([w, vx, vy])  # coords are (theta, x, y)
    want = np.eye(3)
    want[:2, :2], want[:2, 2] = _rot2(w), [vx, vy]
    assert_close(SE2.from_coords(q).as_matrix(), want, ROUNDOFF)
    assert_close(SE2.from_coords(q).rotation().angle(), w, ROUNDOFF)
    assert_close(SE2.from_coords(q).translation(), [vx, vy], 0.0)
    # Rigo et al. 2022, eq. (33): ad_(omega, v) in this order.
    assert_close(SE2.ad(np.array([w, vx, vy])), [[0.0, 0.0, 0.0], [vy, 0.0, -w], [-vx, w, 0.0]], 0.0)


def test_so3_algebra_order_is_wx_wy_wz():
    w = 0.9
    c, s = np.cos(w), np.sin(w)
    Rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    for k, R in enumerate([Rx, Ry, Rz]):
        xi = np.zeros(3)
        xi[k] = w
        assert_close(SO3.exp(xi).as_matrix(), R, ROUNDOFF)
    a, b = np.array([0.3, -1.2, 0.5]), np.array([2.0, 0.1, -0.7])
    assert_close(SO3.hat(a) @ b, np.cross(a, b), ROUNDOFF)
    assert_close(SO3.ad(a) @ b, np.cross(a, b), ROUNDOFF)


def test_so2_and_rn_matrices():
    assert_close(SO2.exp(np.array([0.4])).as_matrix(), _rot2(0.4), ROUNDOFF)
    assert_close(SO2.from_angle(0.4).angle(), 0.4, ROUNDOFF)
    x = np.array([1.0, -2.0, 3.0])
    want = np.eye(4)
    want[:3, 3] = x
    assert_close(R3(x).as_matrix(), want, 0.0)
    assert_close(R3(x).rplus(x).log(), 2 * x, 0.0)


def test_act_is_matrix_action(rng):
    p2, p3 = rng.standard_normal((BATCH, 2)), rng.standard_normal((BATCH, 3))
    for G, p in [(SO2, p2), (SO3, p3)]:
        g = random_elements(G, rng)
        assert_close(g.act(p), np.einsum("...ij,...j->...i", g.as_matrix(), p), ROUNDOFF)
    g = random_elements(SE2, rng)
    M = np.asarray(g.as_matrix())
    assert_close(g.act(p2), np.einsum("...ij,...j->...i", M[..., :2, :2], p2) + M[..., :2, 2], ROUNDOFF)


@pytest.mark.parametrize("G", PRODUCTS, ids=lambda G: G.__name__)
def test_product_concatenates_factors_in_order(G, rng):
    types = G.factor_types
    parts = [random_elements(T, rng) for T in types]
    xis = [sample_xi(T, rng, (BATCH,)) for T in types]
    g = G(tuple(parts))
    assert G.tangent_dim == sum(T.tangent_dim for T in types)
    assert_close(g.log(), np.concatenate([p.log() for p in parts], -1), 0.0)
    assert_close(g.coords(), np.concatenate([p.coords() for p in parts], -1), 0.0)

    def block_diag(blocks):  # per batch element
        blocks = [np.asarray(b) for b in blocks]
        return np.stack([scipy.linalg.block_diag(*(b[k] for b in blocks)) for k in range(BATCH)])

    assert_close(g.as_matrix(), block_diag(p.as_matrix() for p in parts), 0.0)
    xi = np.concatenate(xis, -1)
    for T, factor, x in zip(types, G.exp(xi).factors, xis, strict=True):
        assert type(factor) is T
        assert_close(factor.as_matrix(), T.exp(x).as_matrix(), 0.0)
    assert_close(G.ad(xi), block_diag(T.ad(x) for T, x in zip(types, xis, strict=True)), 0.0)
    assert_close(G.hat(xi), block_diag(T.hat(x) for T, x in zip(types, xis, strict=True)), 0.0)


@group_param
def test_rplus_is_body_frame_and_rminus_inverts_it(G, rng):
    g, h = random_elements(G, rng), random_elements(G, rng)
    xi = sample_xi(G, rng, (BATCH,))
    Mg = np.asarray(g.as_matrix())
    assert_close(g.rplus(xi).as_matrix(), Mg @ np.asarray(G.exp(xi).as_matrix()), ROUNDOFF)
    assert_close(g.rplus(xi).rminus(g), xi, ROUNDOFF)
    assert_close(g.rplus(h.rminus(g)).as_matrix(), h.as_matrix(), ROUNDOFF)


# --- errors -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [0, -1, "a", 2.0, True, None], ids=repr)
def test_rn_rejects_non_positive_integer_dimension(n):
    with pytest.raises(ValueError, match=r"expected a positive integer dimension"):
        Rn[n]


def test_rn_accepts_numpy_integers_and_caches():
    assert Rn[np.int64(3)] is R3 is Rn[3]
    assert R3[1] is R1


def test_rn_rejects_wrong_length():
    with pytest.raises(ValueError, match=r"R3: expected x of shape \(\.\.\., 3\), got \(2,\)"):
        R3(np.zeros(2))


@pytest.mark.parametrize("factors", [(), (int,), (SO3, "SE2"), (Rn,), (LieGroup,), (Product,), (SO3, 1.0)],
                         ids=repr)
def test_product_rejects_non_group_types(factors):
    with pytest.raises(ValueError, match=r"expected one or more concrete LieGroup types"):
        Product[factors]


def test_product_rejects_factor_type_mismatch():
    with pytest.raises(ValueError, match=r"expected factors of types \('SE2', 'R3'\), got \('SO3', 'R3'\)"):
        TSE2((SO3.identity(), R3.identity()))
    with pytest.raises(ValueError, match=r"expected factors of types \('SO3', 'R3'\), got \('SO3',\)"):
        TSO3((SO3.identity(),))
    assert Product[SE2, R3] is TSE2
    assert Product[SO2, R1] is SO2R1
    assert Product[SE2, R2] is SE2R2


# --- SE(3), SE_2(3), SE_K(3) --------------------------------------------------------------------------------


def test_se3_algebra_order_is_omega_v():
    w, v = np.array([0.0, 0.0, 0.7]), np.array([1.3, -0.4, 2.0])
    c, s = np.cos(0.7), np.sin(0.7)
    M = np.asarray(SE3.exp(np.concatenate([w, np.zeros(3)])).as_matrix())
    assert_close(M[:3, :3], [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], ROUNDOFF)
    assert_close(M[:3, 3], np.zeros(3), 0.0)
    want = np.eye(4)
    want[:3, 3] = v
    assert_close(SE3.exp(np.concatenate([np.zeros(3), v])).as_matrix(), want, 0.0)
    X = np.asarray(SE3.hat(np.concatenate([w, v])))
    assert_close(X[:3, :3], SO3.hat(w), 0.0)
    assert_close(X[:3, 3], v, 0.0)
    g = SE3.from_rotation_translation(SO3.exp(w), v)
    assert_close(g.translation(), v, 0.0)
    assert_close(g.coords(), np.concatenate([w, v]), ROUNDOFF)
    p = np.array([0.5, -1.0, 2.0])
    assert_close(g.act(p), np.asarray(SO3.exp(w).as_matrix()) @ p + v, ROUNDOFF)


def test_se23_algebra_order_is_omega_velocity_position():
    nu_v, nu_p = np.array([1.0, 2.0, 3.0]), np.array([-4.0, 5.0, -6.0])
    M = np.asarray(SE23.exp(np.concatenate([np.zeros(3), nu_v, nu_p])).as_matrix())
    want = np.eye(5)
    want[:3, 3], want[:3, 4] = nu_v, nu_p
    assert_close(M, want, 0.0)
    R = SO3.exp(np.array([0.3, -0.2, 0.1]))
    g = SE23.from_rotation_velocity_position(R, nu_v, nu_p)
    assert_close(g.velocity(), nu_v, 0.0)
    assert_close(g.position(), nu_p, 0.0)
    assert_close(g.as_matrix()[:3, :3], R.as_matrix(), 0.0)
    # extended-pose kinematics: (R, v, p) exp(dt (w, a, v_b)) with zero rotation moves v by R a dt
    a = np.array([0.2, 0.0, -0.1])
    moved = g.rplus(0.5 * np.concatenate([np.zeros(3), a, np.zeros(3)]))
    assert_close(moved.velocity(), nu_v + np.asarray(R.act(a)) * 0.5, ROUNDOFF)


def test_sek3_is_indexed_by_the_number_of_vectors():
    assert SEK3[1] is SE3 and SEK3[2] is SE23 and SEK3[np.int64(3)] is SEK3[3]
    assert SEK3[3].tangent_dim == 12 and SEK3[3].matrix_dim == 6
    for K in (0, -1, 1.0, True, "2"):
        with pytest.raises(ValueError, match=r"SEK3\[K\]: expected a positive integer"):
            SEK3[K]
    with pytest.raises(ValueError, match=r"SE3: expected wxyz_p of shape \(\.\.\., 7\)"):
        SE3(np.zeros(4))


@functools.cache
def _so3_exp_autodiff_left_jacobian():
    # J_l(w)[:, j] = vee(d/ds exp(w + s e_j) exp(w)^T) at s = 0: the definition, by forward-mode autodiff.
    def J(w):
        R = lambda x: SO3.exp(x).as_matrix()  # noqa: E731
        dR = jax.jacfwd(R)(w)  # (3, 3, 3)
        return jnp.stack([SO3.vee(dR[..., j] @ R(w).T) for j in range(3)], axis=-1)

    return jax.jit(jax.vmap(J))


@functools.cache
def _sek3_coefficient_hessians():
    """Batched Hessians of SE_K(3)'s Jacobian coefficients (a, b, c of theta^2), compiled once for the five cases."""
    from liemef.groups import _sek3

    coeffs = lambda x: jnp.stack([*_sek3.left_jacobian_coefficients(x),  # noqa: E731
                                  _sek3.inverse_left_jacobian_coefficient(x)])
    return jax.jit(jax.vmap(jax.hessian(coeffs)))


@pytest.mark.parametrize("where", ["zero", "near_identity", "random", "pi-1e-3", "pi-1e-6"])
def test_sek3_left_jacobian_closed_forms_equal_autodiff(where, rng):
    # SE_K(3)'s exp and log use J_l(w) and J_l(w)^{-1} in closed form (Taylor branches): pinned to autodiff of
    # SO3.exp, on both sides of the Taylor threshold and near pi; and their own derivatives are finite at 0.
    from liemef.groups import _sek3

    if where == "zero":
        w = np.zeros((BATCH, 3))
    elif where == "near_identity":
        w = sample_xi(SO3, rng, (BATCH,), angle=np.resize(NEAR_IDENTITY, BATCH))
    elif where == "random":
        w = sample_xi(SO3, rng, (BATCH,))
    else:
        w = near_pi_xi(SO3, rng, float(where[3:]))
    J = np.asarray(_so3_exp_autodiff_left_jacobian()(jnp.asarray(w)))
    eye = np.broadcast_to(np.eye(3), (BATCH, 3, 3))
    Jl = np.swapaxes(np.asarray(_sek3.left_jacobian_apply(w, np.swapaxes(eye, -1, -2))), -1, -2)
    Jl_inv = np.swapaxes(np.asarray(_sek3.inverse_left_jacobian_apply(w, np.swapaxes(eye, -1, -2))), -1, -2)
    assert_close(Jl, J, ROUNDOFF)
    assert_close(Jl_inv @ J, eye, ROUNDOFF if where[:2] != "pi" else NEAR_PI)
    H = np.asarray(_sek3_coefficient_hessians()(jnp.asarray(w)))
    assert np.isfinite(H).all()
    if where == "zero":  # d^2/dw^2 of a(theta^2) at 0 = 2 a'(0) I: a' = -1/24, b' = -1/120, c' = 1/720
        assert_close(H[0], 2 * np.array([-1 / 24, -1 / 120, 1 / 720])[:, None, None] * np.eye(3), ROUNDOFF)


# --- the generic matrix group -------------------------------------------------------------------------------


@functools.cache
def _generic(G):
    return MatrixGroup.from_basis(f"{G.__name__}_generic", basis_hats(G))


def _agreement_ops(G, M, xi, a, b):
    """The operations of the closed-form group G and of the MatrixGroup M with its basis, side by side."""
    g, m = G.exp(xi), M.exp(xi)
    ma, mb = M.from_matrix(a.as_matrix()), M.from_matrix(b.as_matrix())

    def d_log(T, e):
        return jax.vmap(lambda x: jax.jacfwd(lambda d: x.rplus(d).log())(jnp.zeros(T.tangent_dim)))(e)

    return {
        "exp": (m.as_matrix(), g.as_matrix()), "log": (m.log(), g.log()), "Ad": (m.Ad(), g.Ad()),
        "ad": (M.ad(xi), G.ad(xi)), "vee": (M.vee(G.hat(xi)), xi),
        "compose": ((ma @ mb.inverse()).as_matrix(), (a @ b.inverse()).as_matrix()),
        "rminus": (ma.rminus(mb), a.rminus(b)), "d_log": (d_log(M, m), d_log(G, g)),
    }


@pytest.mark.parametrize("G", [SO3, SE3, pytest.param(SE23, marks=pytest.mark.slow)], ids=lambda G: G.__name__)
def test_matrix_group_agrees_with_the_closed_forms(G, rng):
    # Random, near the identity and near pi (1e-3, 1e-6), in one compiled function per group.
    M = _generic(G)
    assert (M.tangent_dim, M.matrix_dim) == (G.tangent_dim, G.matrix_dim)
    xi = np.concatenate(list(_xi_cases(G, rng).values()))
    a, b = random_elements(G, rng, (xi.shape[0],)), random_elements(G, rng, (xi.shape[0],))
    out = jax.jit(functools.partial(_agreement_ops, G, M))(xi, a, b)
    for name, (got, want) in out.items():
        assert_close(got, want, ROUNDOFF, err_msg=name)


def test_sl3_and_sim3_are_their_groups(rng):
    g = random_elements(SL3, rng)
    assert_close(np.linalg.det(np.asarray(g.as_matrix())), np.ones(BATCH), ROUNDOFF)
    assert_close(np.trace(np.asarray(SL3.hat(sample_xi(SL3, rng, (BATCH,)))), axis1=-2, axis2=-1),
                 np.zeros(BATCH), ROUNDOFF)
    w, v, sigma = np.array([0.0, 0.0, 0.4]), np.array([1.0, 2.0, 3.0]), 0.3
    M = np.asarray(Sim3.exp(np.concatenate([w, np.zeros(3), [sigma]])).as_matrix())
    assert_close(M[:3, :3], np.exp(sigma) * np.asarray(SO3.exp(w).as_matrix()), ROUNDOFF)
    assert_close(Sim3.exp(np.concatenate([np.zeros(3), v, [0.0]])).as_matrix()[:3, 3], v, ROUNDOFF)
    assert SL3.tangent_dim == 8 and Sim3.tangent_dim == 7


@pytest.mark.parametrize("G", [Sim3, _generic(SO3)], ids=lambda G: G.__name__)
def test_matrix_group_log_on_the_cut_locus(G, rng):
    # The principal logarithm is undefined for a rotation by exactly pi (eigenvalues -1). Round-off may still
    # lead the square roots to a preimage; otherwise the result is NaN, never a wrong finite value.
    xi = near_pi_xi(G, rng, 0.0)
    exp = jax.jit(G.exp)  # compiled once, for both calls (eager: an expm op by op)
    g = exp(xi)
    log = np.asarray(jax.jit(lambda e: e.log())(g))
    finite = np.isfinite(log).all(axis=-1)
    assert (finite | np.isnan(log).any(axis=-1)).all()
    back = np.asarray(exp(np.where(finite[:, None], log, 0.0)).as_matrix())[finite]
    assert_close(back, np.asarray(g.as_matrix())[finite], NEAR_PI)


@pytest.mark.parametrize(("basis", "match"), [
    (np.zeros((2, 3)), r"basis: expected finite matrices of shape \(n, m, m\)"),
    (np.stack([np.eye(2), 2 * np.eye(2)]), r"basis: expected 2 linearly independent matrices, got rank 1"),
    (np.stack([[[0.0, 1.0], [0.0, 0.0]], [[0.0, 0.0], [1.0, 0.0]]]), r"basis: expected a Lie algebra"),
], ids=["shape", "dependent", "not-closed"])
def test_matrix_group_rejects_bad_bases(basis, match):
    with pytest.raises(ValueError, match=match):
        MatrixGroup.from_basis("Bad", basis)
    with pytest.raises(ValueError, match=r"name: expected a class name"):
        MatrixGroup.from_basis("no name", np.eye(2)[None])


@pytest.mark.slow  # 65 s on a busy 2-core machine: compiling a filter on SL(3)
def test_adding_a_group_page_runs_and_prints_what_it_shows(tmp_path, monkeypatch):
    # The worked example of docs/adding-a-group.md: a MatrixGroup from a basis, used as the group of a filter.
    from pathlib import Path

    from test_tutorial import check_page

    ns = check_page(Path(__file__).resolve().parents[1] / "docs" / "adding-a-group.md", tmp_path, monkeypatch)
    assert bool(ns["traj"].ok)


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def test_roll_pitch_yaw_build_rz_ry_rx_and_come_back():
    """SO3.from_rpy(roll, pitch, yaw) is Rz(yaw) Ry(pitch) Rx(roll), batched, and as_rpy inverts it away from
    gimbal lock; a rotation about one axis has that angle alone."""
    rng = np.random.default_rng(7)
    rpy = np.column_stack([rng.uniform(-np.pi, np.pi, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(-np.pi, np.pi, 50)])
    R = SO3.from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    want = np.stack([_rot(2, y) @ _rot(1, p) @ _rot(0, r) for r, p, y in rpy])
    np.testing.assert_allclose(np.asarray(R.as_matrix()), want, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(R.wxyz), axis=-1), 1.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose(np.asarray(R.as_rpy()), rpy, rtol=0, atol=1e-10)
    for axis in range(3):
        angles = [0.0, 0.0, 0.0]
        angles[axis] = 0.3
        np.testing.assert_allclose(np.asarray(SO3.from_rpy(*angles).log()), np.eye(3)[axis] * 0.3, atol=ROUNDOFF)
    # a scalar and a batch broadcast; the derivative is finite at the identity
    assert SO3.from_rpy(0.1, np.zeros(4), 0.2).wxyz.shape == (4, 4)
    J = jax.jacfwd(lambda a: SO3.from_rpy(a[0], a[1], a[2]).log())(jnp.zeros(3))
    np.testing.assert_allclose(np.asarray(J), np.eye(3), atol=ROUNDOFF)
