from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ClassVar

import jax
import jax.numpy as jnp
import jax.scipy.linalg
import numpy as np

from .. import _validate
from ._base import LieGroup, as_float_array, checked_matrix

# Inverse scaling and squaring (Higham, Functions of Matrices, 2008, Sec. 11.5): square roots until
# |A - I|_1 <= _ISS_RADIUS, then the [8/8] Pade approximant of log(I + X) as 8-node Gauss-Legendre quadrature of
# log(I + X) = int_0^1 X (I + t X)^{-1} dt. Its error at |X| = 0.25 is below 1e-16 (Higham's Table 11.1 bound).
_ISS_RADIUS = 0.25
_MAX_ROOTS = 64
_MAX_DB_ITERATIONS = 60
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(8)
_GL_NODES, _GL_WEIGHTS = (_GL_NODES + 1.0) / 2.0, _GL_WEIGHTS / 2.0  # on [0, 1]
# Newton steps on exp after logm (MatrixGroup.log): quadratic convergence from logm's worst start (1e-4 at a
# rotation angle pi - 1e-6) reaches round-off in two; the third is margin.
_NEWTON_STEPS = 3
_LOG_CHECK = 1e-9
"""Relative |exp(log M) - M|_1 above which log returns NaN (converged on the group: ~1e-15), unless Newton's
iterations converged (:data:`_LOG_OFF_GROUP`)."""
_LOG_OFF_GROUP = 10 * _validate.ON_GROUP
"""A matrix a hair off the group (within ``liemef._validate.ON_GROUP``, which every filter's init accepts)
misses by its distance, up to ~1e-6: its logarithm is kept where Newton's last step was at round-off (the
logarithm of the nearest element along the algebra) and the miss is below this. A start outside Newton's basin
(at the cut locus) does not converge, and stays NaN."""


def _norm1(A):
    return jnp.max(jnp.sum(jnp.abs(A), axis=-2), axis=-1)


# Higham (2005)'s [13/13] Pade approximant with scaling and squaring: the top order of
# jax.scipy.linalg.expm, without its switch over five orders. That switch makes expm slow to compile (3.7 s for
# one 3 x 3 matrix, 52 s for the vmapped Hessian the engine's second order needs; 0.3 s and a few s here) for no
# gain at the filter's small matrices. Accuracy: unit round-off for |A|_1 <= theta_13 (Higham's bound).
_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
           10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0,
           1.0)
_PADE13 = tuple(c / _PADE13[0] for c in _PADE13)  # b0 = 1: expm(0) is exactly I (solve(I, I))
_THETA13 = 5.371920351148152
_MAX_SQUARINGS = 40


def expm(A):
    r"""Matrix exponential of one square matrix: [13/13] Pade approximant of $e^{A/2^s}$, squared $s$ times, with
    $s = \max(0, \lceil\log_2(|A|_1/\theta_{13})\rceil)$ (Higham 2005). $s$ is piecewise constant, so autodiff
    differentiates the approximant and the squarings: at $A = 0$ ($s = 0$) the derivatives of every order are
    exact to round-off."""
    b = _PADE13
    eye = jnp.eye(A.shape[-1], dtype=A.dtype)
    norm = jax.lax.stop_gradient(_norm1(A))
    s = jnp.maximum(0.0, jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / _THETA13)))
    A = A / 2.0**s
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A4 @ A2
    U = A @ (A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2) + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * eye)
    V = A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2) + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * eye
    R = jnp.linalg.solve(V - U, V + U)
    return jax.lax.fori_loop(0, _MAX_SQUARINGS, lambda i, X: jnp.where(i < s, X @ X, X), R)


def _sqrtm(A):
    """Principal square root by the product-form Denman-Beavers iteration (Higham 2008, eq. (6.17))."""
    eye = jnp.eye(A.shape[-1], dtype=A.dtype)

    def cond(state):
        k, _, M, M_prev = state
        return (k < _MAX_DB_ITERATIONS) & (_norm1(M - M_prev) > 0.0) & (_norm1(M - eye) > 1e-15)

    def body(state):
        k, Y, M, _ = state
        M_inv = jnp.linalg.inv(M)
        return k + 1, 0.5 * Y @ (eye + M_inv), 0.5 * eye + 0.25 * (M + M_inv), M

    _, Y, _, _ = jax.lax.while_loop(cond, body, (0, A, A, A + 1.0))
    return Y


def logm(A):
    r"""Principal matrix logarithm of one square matrix by inverse scaling and squaring: $\log A = 2^k \log
    A^{1/2^k}$ with $k$ square roots (Denman-Beavers) taking $A^{1/2^k}$ within 0.25 of $I$, then an [8/8] Pade
    approximant. Defined where no eigenvalue lies on the closed negative real axis; NaN on it."""
    eye = jnp.eye(A.shape[-1], dtype=A.dtype)

    def cond(state):
        k, Y = state
        return (k < _MAX_ROOTS) & (_norm1(Y - eye) > _ISS_RADIUS)

    def body(state):
        k, Y = state
        return k + 1, _sqrtm(Y)

    k, Y = jax.lax.while_loop(cond, body, (0, A))
    X = Y - eye
    L = sum(w * jnp.linalg.solve(eye + t * X, X) for t, w in zip(_GL_NODES, _GL_WEIGHTS, strict=True))
    ok = _norm1(X) <= _ISS_RADIUS
    return jnp.where(ok, 2.0 ** k.astype(A.dtype) * L, jnp.nan)


class MatrixGroup(LieGroup):
    r"""A matrix Lie group given by a basis $E_1, \ldots, E_n$ of its Lie algebra: any matrix Lie group.

    Build a group with :meth:`from_basis`; :data:`SL3` and :data:`Sim3` are two. An element stores its
    $m \times m$ matrix (flattened to one trailing axis). The algebra coordinates are those of the basis,
    $\hat\xi = \sum_k \xi_k E_k$, in the basis order; :meth:`vee` is the least-squares inverse (the dual basis:
    the pseudo-inverse of the basis as an $n \times m^2$ matrix), so it projects a matrix onto the algebra.

    * :meth:`exp` is :func:`expm` of $\hat\xi$: the [13/13] Pade approximant with scaling and squaring of
      ``jax.scipy.linalg.expm``, without its switch between orders, which is slow to compile. Its first and
      second derivatives at 0 are those of the approximant, exact there (the number of squarings is piecewise
      constant).
    * :meth:`log` is the principal matrix logarithm by inverse scaling and squaring (:func:`logm`), then
      :meth:`vee`, polished by Newton's method on :meth:`exp` (accurate to round-off up to a rotation angle of
      about pi - 1e-7; see :meth:`log`), with derivatives in both autodiff modes.
    * $\mathrm{ad}$ comes from the structure constants of the basis, $\mathrm{Ad}_g$ from $g E_k g^{-1}$.
    * Membership (:meth:`matrix_defects`, checked by :meth:`from_matrix` and by every filter's ``init``): the
      group's own rule when :meth:`from_basis` was given one (:data:`SL3`: the determinant; :data:`Sim3`: the
      bottom row, then the orthogonality and the determinant of the 3 x 3 block divided by its scale), else the
      round trip $|\exp(\log M) - M|_1 / (1 + |M|_1)$, which also refuses an element that is not the
      exponential of its principal logarithm (a rotation by exactly pi; give such a group a rule).

    The closed-form groups (:class:`SO3`, :class:`SE3`, :class:`SE23`) are faster, to run and to build for the C
    engine (which translates a :class:`MatrixGroup` too: ``tests/test_user_systems_c.py``); a :class:`MatrixGroup`
    with their basis agrees with them to round-off (``tests/test_groups.py``).
    """

    matrix_flat: jnp.ndarray

    basis: ClassVar[np.ndarray]
    """The basis ``(n, m, m)``: ``basis[k] = hat(e_k)``."""
    dual: ClassVar[np.ndarray]
    """The dual basis ``(n, m * m)``: ``vee(X) = dual @ X.ravel()``."""
    constants: ClassVar[np.ndarray]
    """The structure constants ``C[m, j, i] = vee([E_j, E_i])[m]``."""
    rule: ClassVar[Callable[[np.ndarray], dict[str, float]] | None]
    """The membership rule given to :meth:`from_basis` (None: the exp/log round trip; see :meth:`matrix_defects`)."""
    tangent_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    coords_dim: ClassVar[int]

    def __init__(self, matrix_flat):
        matrix_flat = as_float_array(matrix_flat)
        m = self.matrix_dim
        if matrix_flat.shape[-1:] != (m * m,):
            raise ValueError(f"{type(self).__name__}: expected matrix_flat of shape (..., {m * m}) (a {m} x {m} "
                             f"matrix, flattened), got {matrix_flat.shape}")
        self.matrix_flat = matrix_flat

    @staticmethod
    def from_basis(name: str, basis, doc: str | None = None,
                   rule: Callable[[np.ndarray], dict[str, float]] | None = None) -> type[MatrixGroup]:
        """A new group class named ``name`` from a basis ``(n, m, m)`` of its Lie algebra.

        The basis must be linearly independent and closed under the commutator (a Lie algebra): a
        ``ValueError`` says which check failed. ``rule`` says how far one finite ``m x m`` NumPy matrix is from the
        group, as ``{defect: size}`` (e.g. ``{"determinant |det M - 1|": abs(det(M) - 1)}`` for SL(3)); a matrix
        with a size above ``liemef._validate.ON_GROUP`` is refused by :meth:`from_matrix` and by every filter's
        ``init``. Without one, membership is the exp/log round trip (:meth:`matrix_defects`).
        """
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"name: expected a class name (letters, digits, _), got {name!r}")
        if rule is not None and not callable(rule):
            raise ValueError(f"rule: expected a function of one matrix returning {{defect: size}}, or None, got "
                             f"{type(rule).__name__}")
        E = np.asarray(basis, dtype=np.float64)
        if E.ndim != 3 or E.shape[1] != E.shape[2] or E.shape[0] < 1 or not np.all(np.isfinite(E)):
            raise ValueError(f"basis: expected finite matrices of shape (n, m, m) with n >= 1, got shape "
                             f"{E.shape}")
        n, m = E.shape[0], E.shape[1]
        flat = E.reshape(n, m * m)
        if np.linalg.matrix_rank(flat) < n:
            raise ValueError(f"basis: expected {n} linearly independent matrices, got rank "
                             f"{np.linalg.matrix_rank(flat)}")
        dual = np.linalg.pinv(flat.T)  # (n, m*m): dual @ flat.T = I
        brackets = np.einsum("jab,ibc->jiac", E, E) - np.einsum("iab,jbc->jiac", E, E)  # [E_j, E_i]
        C = np.einsum("mk,jik->mji", dual, brackets.reshape(n, n, m * m))
        residual = brackets - np.einsum("mji,mab->jiab", C, E)
        scale = max(1.0, float(np.abs(E).max()) ** 2)
        if np.abs(residual).max() > 1e-10 * scale:
            raise ValueError(f"basis: expected a Lie algebra (commutators of the basis in its span), got a "
                             f"commutator {np.abs(residual).max():.3g} away from the span")
        return type(MatrixGroup)(name, (MatrixGroup,), {
            "basis": E, "dual": dual, "constants": C, "rule": staticmethod(rule) if rule is not None else None,
            "tangent_dim": n, "matrix_dim": m, "coords_dim": n,
            "__module__": MatrixGroup.__module__, "__qualname__": name,
            "__doc__": doc or f"The matrix Lie group {name} from a basis of {n} {m} x {m} matrices.",
        })

    @classmethod
    def identity(cls, batch_shape=()):
        """The identity matrix."""
        m = cls.matrix_dim
        return cls(jnp.broadcast_to(jnp.eye(m).reshape(m * m), (*batch_shape, m * m)))

    @classmethod
    def exp(cls, xi):
        r""":func:`expm` of $\hat\xi$."""
        M = jnp.vectorize(expm, signature="(m,m)->(m,m)")(cls.hat(xi))
        return cls._of_matrix(M)

    @classmethod
    def _of_matrix(cls, M):
        """From the ``m x m`` matrix, unchecked (the group's own operations)."""
        return cls(M.reshape(*M.shape[:-2], cls.matrix_dim**2))

    @classmethod
    def from_matrix(cls, M):
        """From the ``m x m`` matrix, checked (:func:`~liemef.groups._base.checked_matrix`): within
        ``liemef._validate.ON_GROUP`` of the group by :meth:`matrix_defects`."""
        return cls._of_matrix(checked_matrix(cls, M))

    @classmethod
    def matrix_defects(cls, M):
        r"""The group's rule (:meth:`from_basis`), matrix by matrix; without one, the round trip
        $|\exp(\log M) - M|_1 / (1 + |M|_1)$ with :meth:`log` before its NaN check, infinite where the principal
        logarithm does not exist or Newton's method does not converge (an element that is not the exponential of
        its principal logarithm, such as a rotation by exactly pi, is refused: give such a group a rule)."""
        M = np.asarray(M, dtype=np.float64)
        batch = M.shape[:-2]
        if cls.rule is None:
            miss = np.asarray(jnp.vectorize(functools.partial(_log_miss, cls), signature="(m,m)->()")(M))
            finite = np.all(np.isfinite(M), axis=(-2, -1))
            return {"round trip |exp(log M) - M|_1 / (1 + |M|_1)": np.where(finite & np.isnan(miss), np.inf, miss)}
        out: dict[str, np.ndarray] = {}
        for index in np.ndindex(*batch):
            for what, size in cls.rule(M[index]).items():
                out.setdefault(what, np.full(batch, np.nan))[index] = float(size)
        return out

    def defects(self) -> dict[str, float]:
        """The largest over the batch of each of :meth:`matrix_defects` of the matrix."""
        return {what: float(np.max(size, initial=0.0))
                for what, size in type(self).matrix_defects(np.asarray(self.as_matrix())).items()}

    @classmethod
    def from_coords(cls, q):
        """The same as :meth:`exp`."""
        return cls.exp(q)

    def compose(self, other):
        """Matrix product."""
        return type(self)._of_matrix(self.as_matrix() @ other.as_matrix())

    def inverse(self):
        """Matrix inverse."""
        return type(self)._of_matrix(jnp.linalg.inv(self.as_matrix()))

    def log(self):
        r"""The principal logarithm: :meth:`vee` of :func:`logm`, polished by Newton's method on :meth:`exp`.

        :func:`logm`'s square roots lose accuracy when an eigenvalue nears the negative real axis (a rotation
        angle near $\pi$: relative error ~1e-16 / (pi - angle)^2), so its result only starts
        ``_NEWTON_STEPS`` Newton iterations $\xi \leftarrow \xi + J_r(\xi)^{-1} \log(\exp(-\xi)\, g)^\vee$
        ($J_r = \int_0^1 e^{-s\,\mathrm{ad}_\xi} ds$ the right Jacobian of exp, from one ``expm`` of a
        $2n \times 2n$ block matrix; the small logarithm by its cubic series),
        which converge quadratically to round-off. The start is a constant for autodiff, so derivatives are those
        of the Newton map at its fixed point (the implicit-function derivative $J_r^{-1}$), in forward and
        reverse mode. NaN where the principal logarithm is undefined (an eigenvalue on the closed negative real
        axis, e.g. a rotation by exactly pi): use a closed-form group there.
        """
        cls = type(self)
        return jnp.vectorize(functools.partial(_log, cls), signature="(m,m)->(n)")(self.as_matrix())

    def coords(self):
        """The same as :meth:`log`."""
        return self.log()

    def as_matrix(self):
        """The ``m x m`` matrix."""
        m = self.matrix_dim
        return self.matrix_flat.reshape(*self.matrix_flat.shape[:-1], m, m)

    def Ad(self):
        r"""Column k is $(g E_k g^{-1})^\vee$."""
        M = self.as_matrix()
        conj = M[..., None, :, :] @ jnp.asarray(self.basis) @ jnp.linalg.inv(M)[..., None, :, :]
        return jnp.swapaxes(type(self).vee(conj), -1, -2)

    @classmethod
    def hat(cls, xi):
        r"""$\sum_k \xi_k E_k$."""
        return jnp.einsum("...k,kab->...ab", as_float_array(xi), jnp.asarray(cls.basis))

    @classmethod
    def vee(cls, X):
        """Coordinates of the least-squares projection of ``X`` onto the algebra (the dual basis)."""
        X = as_float_array(X)
        m = cls.matrix_dim
        return jnp.einsum("kc,...c->...k", jnp.asarray(cls.dual), X.reshape(*X.shape[:-2], m * m))

    @classmethod
    def ad(cls, xi):
        r"""$\mathrm{ad}_\xi[m, i] = \sum_j \xi_j C[m, j, i]$ (structure constants of the basis)."""
        return jnp.einsum("mji,...j->...mi", jnp.asarray(cls.constants), as_float_array(xi))


@functools.partial(jax.jit, static_argnums=0)  # jitted: eager calls compile the loops once per shape
def _log(cls: type[MatrixGroup], M):
    """:meth:`MatrixGroup.log` of one matrix ``M`` (m, m)."""
    xi, miss, step = _newton_log(cls, M)
    converged = step <= 1e-12 * (1.0 + jnp.sum(jnp.abs(jax.lax.stop_gradient(xi))))
    return jnp.where((miss <= _LOG_CHECK) | (converged & (miss <= _LOG_OFF_GROUP)), xi, jnp.nan)


@functools.partial(jax.jit, static_argnums=0)
def _log_miss(cls: type[MatrixGroup], M):
    """The relative 1-norm miss ``|exp(log M) - M|_1 / (1 + |M|_1)`` of :meth:`MatrixGroup.log` of one matrix
    ``M`` (m, m), before its NaN check: how far ``M`` is from the group (NaN without a principal logarithm)."""
    return _newton_log(cls, M)[1]


def _newton_log(cls: type[MatrixGroup], M):
    """``(xi, miss, step)``: the Newton-polished logarithm of one matrix ``M``, ``|exp(xi) - M|_1 / (1 + |M|_1)``
    and the 1-norm of Newton's last step."""
    n, m = cls.tangent_dim, cls.matrix_dim
    eye = jnp.eye(m)

    def small_log(E):  # log(I + E)^vee to third order: E ~ 1e-4 at the first step, then ~1e-8
        return cls.vee(E - 0.5 * E @ E + (E @ E @ E) / 3.0)

    def newton(_, xi):
        # Right Jacobian J_r(xi) = int_0^1 exp(-s ad_xi) ds: the top-right block of expm([[-ad_xi, I], [0, 0]]).
        block = jnp.zeros((2 * n, 2 * n)).at[:n, :n].set(-cls.ad(xi)).at[:n, n:].set(jnp.eye(n))
        J = expm(block)[:n, n:]
        exp_inv = jnp.linalg.inv(expm(cls.hat(xi)))
        return xi + jnp.linalg.solve(J, small_log(exp_inv @ M - eye))

    xi = cls.vee(logm(jax.lax.stop_gradient(M)))
    xi = jax.lax.fori_loop(0, _NEWTON_STEPS - 1, newton, xi)
    last = newton(0, xi)
    step = jnp.sum(jnp.abs(jax.lax.stop_gradient(last - xi)))
    xi = last
    # A start outside Newton's basin (at the cut locus) may end anywhere: a value that is not a logarithm is NaN.
    miss = _norm1(jax.lax.stop_gradient(expm(cls.hat(xi)) - M)) / (1.0 + _norm1(jax.lax.stop_gradient(M)))
    return xi, miss, step


def _unit(m, i, j):
    E = np.zeros((m, m))
    E[i, j] = 1.0
    return E


@functools.cache
def _sl3_basis():
    # Rotation generators first (as in so(3)), then the symmetric traceless part, ordered as a homography acts:
    # shears/scalings of the image, then the projective row.
    u = functools.partial(_unit, 3)
    rot = [u(2, 1) - u(1, 2), u(0, 2) - u(2, 0), u(1, 0) - u(0, 1)]
    sym = [u(0, 1) + u(1, 0), u(0, 2) + u(2, 0), u(1, 2) + u(2, 1), u(0, 0) - u(1, 1),
           u(0, 0) + u(1, 1) - 2.0 * u(2, 2)]
    return np.stack(rot + sym)


@functools.cache
def _sim3_basis():
    u = functools.partial(_unit, 4)
    rot = [u(2, 1) - u(1, 2), u(0, 2) - u(2, 0), u(1, 0) - u(0, 1)]
    trans = [u(0, 3), u(1, 3), u(2, 3)]
    scale = [u(0, 0) + u(1, 1) + u(2, 2)]
    return np.stack(rot + trans + scale)


def _sl3_rule(M):
    """SL(3): the determinant."""
    return {"determinant |det M - 1|": abs(np.linalg.det(M) - 1.0)}


def _sim3_rule(M):
    """Sim(3) = ``[[s R, p], [0, 1]]`` with s > 0: the bottom row, and the 3 x 3 block A divided by its scale
    s = |det A|^(1/3) as a rotation (orthogonality and determinant; infinitely far when A is singular)."""
    A = M[:3, :3]
    s = abs(np.linalg.det(A)) ** (1.0 / 3.0)
    R = A / s if s > 0 else None
    return {"bottom row max|M[3] - [0, 1]|": float(np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max()),
            "orthogonality max|R^T R - I| of R = A / |det A|^(1/3)":
                np.inf if R is None else float(np.abs(R.T @ R - np.eye(3)).max()),
            "determinant |det R - 1| of R = A / |det A|^(1/3)": np.inf if R is None else abs(np.linalg.det(R) - 1.0)}


SL3 = MatrixGroup.from_basis("SL3", _sl3_basis(), rule=_sl3_rule, doc=r"""SL(3), the homographies (3 x 3 matrices of
determinant 1), as a :class:`MatrixGroup`. sl(3) coordinates: the rotation generators $(w_x, w_y, w_z)$ as in
so(3), then the symmetric traceless generators $E_{01} + E_{10}$, $E_{02} + E_{20}$, $E_{12} + E_{21}$,
$E_{00} - E_{11}$, $E_{00} + E_{11} - 2 E_{22}$. Membership: $|\det M - 1|$.""")

Sim3 = MatrixGroup.from_basis("Sim3", _sim3_basis(), rule=_sim3_rule, doc=r"""Sim(3), similarities
``[[s R, p], [0, 1]]`` with s > 0, as a :class:`MatrixGroup`. sim(3) coordinates $(\omega; v; \sigma)$: the
rotation first as in se(3), the translation rate, then the log-scale rate
($\hat\xi = [[[\omega]_\times + \sigma I, v], [0, 0]]$). Membership: the bottom row, then the 3 x 3 block divided
by its scale $|\det|^{1/3}$ as a rotation (orthogonality, determinant).""")
