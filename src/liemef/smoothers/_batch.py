r"""The batch minimum-energy smoother: the minimizer of the discretized cost over a whole log, and the marginal
covariance of every state (docs/smoothing.md).

On the sample grid $t_0 < \dots < t_K$ with $\Delta_k = t_{k+1} - t_k$, the states $x_0..x_K \in G$ minimize

$$
J = \tfrac12\|x_0 \ominus g_0\|^2_{P_0^{-1}}
  + \tfrac12\sum_{k<K}\|x_{k+1} \ominus \phi_{\Delta_k}(x_k, u_k, t_k)\|^2_{Q_k^{-1}}
  + \tfrac12\sum_{k \le K}\sum_{b}\rho_b\bigl(|e_{k,b}|^2_{W_{k,b}}\bigr),
\qquad e_k = y_k \ominus h(x_k, t_k),
$$

with $a \ominus b = \log(b^{-1}a)$ (liemef's left error), $\phi_\Delta$ one step of the integrator with the input
held, $Q_k$ the process noise over the interval ($B R^{-1} B^\top \Delta_k$, or the system's
:meth:`~liemef.systems.AbstractSystem.process_noise_at`), $W_k$ the information in force times $\Delta_k$
(:func:`~liemef.filters.information_in_force`: a sample sensor's information once per sample, a density sensor's
over its interval, none for a missing component) and $\rho_b$ each sensor's loss: $\rho(s) = s$, or Huber's /
Cauchy's with the filter's scale, truncated at a gate's threshold. A sample sensor's sample $y_K$ at the log's last
time measures $x_K$; a density sensor's last sample has no interval and does not enter.

The minimizer is found by Levenberg-Marquardt on the whole trajectory (perturbations $x_k\exp\delta_k$,
derivatives by autodiff). A robust sensor enters with the gradient $\rho' J^\top W e$ and the Hessian of its
robust term where that is positive semidefinite (:func:`_measurement`). A trial step is kept only if the cost
does not rise beyond its round-off (:data:`ROUNDOFF`). The normal equations are block-tridiagonal; one forward
elimination and one backward substitution solve them
(a Kalman smoother in information form), so each iteration is linear in the log's length. The marginal
covariances are the diagonal blocks of the inverse Gauss-Newton Hessian at the minimizer, by the backward
recursion $\Sigma_K = S_K^{-1}$, $\Sigma_k = S_k^{-1} + G_k\Sigma_{k+1}G_k^\top$, $G_k = S_k^{-1}C_k$ ($S_k$ the
forward pass's information, $C_k$ the coupling of $x_k$ and $x_{k+1}$): the Rauch-Tung-Striebel covariances.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from ..engines import bucket
from ..filters import AbstractFilter, FilterState, Weights, check_log, information_in_force, sensor_layout
from ..groups import LieGroup
from ..integrators import AbstractIntegrator
from ..integrators import integrator as make_integrator
from ..systems import AbstractSystem

FLOOR_STD = 1e-6
"""The smallest std of the prior and of the process noise per interval (coordinates' units): their eigenvalues
are raised to ``FLOOR_STD**2``, so that a coordinate known exactly (a singular P0, a zero column of B) is a
stiff prior rather than an infinite weight."""

STATUSES = {
    "converged": "a step with little damping was below the tolerance: the estimate is the minimizer to it",
    "max-iterations": "max_iterations steps were taken and none was below the tolerance",
    "stalled": "no step lowered the cost, even with the largest damping (the estimate is the last accepted one)",
    "failed": "the cost or the covariances are not finite (the estimates are NaN)",
}
"""A smoother run's status and what it means: only ``"converged"`` is ok."""

ROUNDOFF = 64 * float(np.finfo(np.float64).eps)
"""The cost's round-off, relative: a trial step is kept if it raises the cost by less than this times 1 + |J|
(at the minimizer a step at the tolerance cannot lower a sum of thousands of terms in float64)."""
BATCH = 256
"""The states whose residuals and Jacobians are computed at once (:func:`_each`): the smoother's memory is this
many states' intermediates, not the whole log's. Vectorized over all states, the Jacobians of a 27-dimensional
inertial model (RKMK4 on SE_2(3) x R^18) took about 1.5 MB per state: 4.4 GB for 10 s of a 286 Hz recording,
beyond 24 GB for 60 s."""
_MAX_DAMPING = 1e12
_CONVERGED_DAMPING = 1.0  # a step counts towards convergence only if its damping was below this


class Smoothed(eqx.Module):
    """A smoothed log: ``g[k]`` (batch (N,)) the estimate of the state at ``ts[k]`` from every sample of the log
    and ``P[k]`` its marginal covariance (the left error $\\log(\\hat g^{-1} g)$, as a filter's K).

    ``cost`` is the cost at the estimate and ``cost_init`` at the starting trajectory (no lower, to round-off),
    ``gradient_norm`` the largest component of its gradient, ``iterations`` the Levenberg-Marquardt steps taken.
    ``status`` (:data:`STATUSES`) says whether it converged; ``message`` says what happened in words.
    """

    ts: Float[Array, " N"]
    g: LieGroup
    P: Float[Array, "N n n"]
    cost: Float[Array, ""]
    cost_init: Float[Array, ""]
    gradient_norm: Float[Array, ""]
    iterations: int = eqx.field(static=True)
    status: str = eqx.field(static=True)
    message: str = eqx.field(static=True)

    @property
    def ok(self) -> bool:
        """True if the smoother converged (:data:`STATUSES`)."""
        return self.status == "converged"

    def coords(self) -> Float[Array, "N c"]:
        """The estimates in the group's coordinates."""
        return self.g.coords()


class Problem(eqx.Module):
    """The cost's data, padded to a length bucket (every array a leaf, so a new log of the same bucket or a new
    weight set reuses the compiled solver): the prior, the times, the held inputs, the samples (zeros where
    missing), the present components, the intervals, the process information per interval and the measurement
    information per state, and which states are the padding's."""

    g0: LieGroup
    P0inv: Float[Array, "n n"]
    ts: Float[Array, " M"]
    us: Float[Array, "M m"]
    ys: Float[Array, "M p"]
    present: Any
    dts: Float[Array, " K"]
    Qinv: Float[Array, "K n n"]
    W: Float[Array, "M p p"]
    padded: Any


# --- the cost -------------------------------------------------------------------------------------------------
def _flow(system, integ, x, u, t, dt):
    """``phi_dt(x, u, t)``: one integrator step with the input held."""
    return integ.step(lambda g, v, s: (system.dynamics(g, u, s), ()), x, (), t, dt)[0]


def _rho(s, screen):
    """A sensor's loss ``rho(s)`` of the squared Mahalanobis distance ``s``, its derivative ``rho'(s)`` (the
    weight) and ``D = 1 + 2 s rho''(s) / rho'(s)``, the curvature along the residual relative to the weight's:
    Huber's or Cauchy's with scale c (the filter's weights ``min(1, c/d)`` and ``1/(1 + d^2/c^2)``),
    truncated at a gate's threshold (weight 0 beyond it)."""
    _, _, gate, robust, c = screen

    def loss(s):
        if robust == "huber":
            root = jnp.sqrt(jnp.maximum(s, 1e-300))
            inlier = s <= c * c
            return (jnp.where(inlier, s, 2.0 * c * root - c * c), jnp.minimum(1.0, c / root),
                    jnp.where(inlier, 1.0, 0.0))
        if robust == "cauchy":
            q = s / (c * c)
            return c * c * jnp.log1p(q), 1.0 / (1.0 + q), (1.0 - q) / (1.0 + q)
        return s, jnp.ones_like(s), jnp.ones_like(s)

    r, w, D = loss(s)
    if gate is not None:
        out = s > gate
        r = jnp.where(out, loss(jnp.asarray(gate, s.dtype))[0], r)
        w = jnp.where(out, 0.0, w)
    return r, w, D


def _measurement(screens, W, rm):
    """Half the measurement cost, the information of its gradient (each screened sensor's weighted by
    ``rho'``) and of its Hessian. The Hessian's is the robust cost's own,
    ``rho' W + 2 rho'' (W r)(W r)^T`` per sensor, where that is positive semidefinite (``D >= 0``: Huber's
    loss, Cauchy's within its scale), so that Newton's convergence is quadratic where iteratively reweighted
    least squares would be linear; where it is not (Cauchy's beyond its scale), its curvature along the
    residual is dropped (``D`` raised to 0), as Newton's method with a modified Hessian does."""
    quad = jnp.einsum("ki,kij,kj->k", rm, W, rm)
    total = jnp.sum(quad)
    scale = jnp.ones(rm.shape)
    extra = jnp.zeros(W.shape)
    for screen in screens:
        a, b = screen[0], screen[1]
        Wb = W[:, a:b, a:b]
        Wr = jnp.einsum("kij,kj->ki", Wb, rm[:, a:b])
        s = jnp.einsum("ki,ki->k", rm[:, a:b], Wr)
        r, w, D = _rho(s, screen)
        total = total + jnp.sum(r - s)
        scale = scale.at[:, a:b].set(jnp.broadcast_to(w[:, None], (w.shape[0], b - a)))
        coef = jnp.where(s > 0.0, w * (jnp.maximum(D, 0.0) - 1.0) / jnp.where(s > 0.0, s, 1.0), 0.0)
        extra = extra.at[:, a:b, a:b].set(coef[:, None, None] * Wr[:, :, None] * Wr[:, None, :])
    root = jnp.sqrt(scale)
    Wg = W * root[:, :, None] * root[:, None, :]
    return 0.5 * total, Wg, Wg + extra


def _quad(r, M):
    return jnp.einsum("...i,...ij,...j->...", r, M, r)


def _each(f, *args):
    """``f`` over the leading axis of ``args``, :data:`BATCH` elements vectorized at a time (``jax.lax.map``)."""
    return jax.lax.map(lambda a: f(*a), args, batch_size=BATCH)


def _cost(system, integ, screens, prob, xs):
    """The cost J at the trajectory ``xs``."""
    r0 = xs[0].rminus(prob.g0)
    rp = _each(lambda x, y, u, t, dt: y.rminus(_flow(system, integ, x, u, t, dt)),
               xs[:-1], xs[1:], prob.us[:-1], prob.ts[:-1], prob.dts)
    rm = _each(lambda x, y, t: system.output_seen_from(y, x, t) - y, xs, prob.ys, prob.ts)
    rm = jnp.where(prob.present, rm, 0.0)
    return 0.5 * (_quad(r0, prob.P0inv) + jnp.sum(_quad(rp, prob.Qinv))) + _measurement(screens, prob.W, rm)[0]


def _linearize(system, integ, screens, prob, xs):
    """The Gauss-Newton normal equations at ``xs``: diagonal blocks D (M, n, n), couplings C (M-1, n, n) of
    ``x_k`` and ``x_{k+1}``, the gradient (M, n) and the cost."""
    n = type(prob.g0).tangent_dim
    z = jnp.zeros(n)

    def prior(x):
        f = lambda d: x.rplus(d).rminus(prob.g0)  # noqa: E731
        return f(z), jax.jacfwd(f)(z)

    def proc(x, y, u, t, dt):
        def f(da, db):
            return y.rplus(db).rminus(_flow(system, integ, x.rplus(da), u, t, dt))
        Ja, Jb = jax.jacfwd(f, argnums=(0, 1))(z, z)
        return f(z, z), Ja, Jb

    def meas(x, y, t, present):
        f = lambda d: jnp.where(present, system.output_seen_from(y, x.rplus(d), t) - y, 0.0)  # noqa: E731
        return f(z), jax.jacfwd(f)(z)

    r0, J0 = prior(xs[0])
    rp, Ja, Jb = _each(proc, xs[:-1], xs[1:], prob.us[:-1], prob.ts[:-1], prob.dts)
    rm, Jm = _each(meas, xs, prob.ys, prob.ts, prob.present)
    fm, Wg, Wh = _measurement(screens, prob.W, rm)
    T = lambda A: jnp.swapaxes(A, -1, -2)  # noqa: E731
    QJa, QJb, WJm = prob.Qinv @ Ja, prob.Qinv @ Jb, Wg @ Jm
    D = T(Jm) @ Wh @ Jm
    D = D + prob.padded[:, None, None] * jnp.eye(n)  # the padding's own curvature: no gradient, no cost (problem)
    D = D.at[0].add(J0.T @ prob.P0inv @ J0)
    D = D.at[:-1].add(T(Ja) @ QJa)
    D = D.at[1:].add(T(Jb) @ QJb)
    C = T(Ja) @ QJb
    gr = jnp.einsum("kji,kj->ki", WJm, rm)
    gr = gr.at[0].add(J0.T @ (prob.P0inv @ r0))
    gr = gr.at[:-1].add(jnp.einsum("kji,kj->ki", QJa, rp))
    gr = gr.at[1:].add(jnp.einsum("kji,kj->ki", QJb, rp))
    cost = 0.5 * (_quad(r0, prob.P0inv) + jnp.sum(_quad(rp, prob.Qinv))) + fm
    return D, C, gr, cost


def _forward(D, C, rhs):
    """Block elimination of the symmetric block-tridiagonal ``H`` (diagonal ``D``, upper blocks ``C``): the
    information ``S_k`` of each state given the terms up to it, and the eliminated right-hand side."""

    def fwd(carry, x):
        S, zeta = carry
        Dk, Ck, bk = x  # C_{k-1} couples k-1 and k
        L = jnp.linalg.solve(S, Ck).T  # C^T S^{-1}
        S1 = Dk - L @ Ck
        z1 = bk - L @ zeta
        return (S1, z1), (S1, z1)

    _, (Ss, zs) = jax.lax.scan(fwd, (D[0], rhs[0]), (D[1:], C, rhs[1:]))
    return jnp.concatenate([D[:1], Ss]), jnp.concatenate([rhs[:1], zs])


def solve_tridiagonal(D, C, rhs):
    """Solve the symmetric block-tridiagonal ``H x = rhs`` by forward elimination and backward substitution
    (linear in the number of blocks)."""
    Ss, zs = _forward(D, C, rhs)
    xK = jnp.linalg.solve(Ss[-1], zs[-1])

    def bwd(x_next, x):
        Sk, zk, Ck = x
        xk = jnp.linalg.solve(Sk, zk - Ck @ x_next)
        return xk, xk

    _, xs = jax.lax.scan(bwd, xK, (Ss[:-1], zs[:-1], C), reverse=True)
    return jnp.concatenate([xs, xK[None]])


def marginal_covariances(D, C):
    """The diagonal blocks of ``H^{-1}`` for the symmetric positive definite block-tridiagonal ``H`` (diagonal
    ``D``, upper blocks ``C``): ``Sigma_K = S_K^{-1}``, ``Sigma_k = S_k^{-1} + G_k Sigma_{k+1} G_k^T`` with
    ``G_k = S_k^{-1} C_k`` (module docstring). NaN where ``H`` is not positive definite."""
    n = D.shape[-1]
    Ss, _ = _forward(D, C, jnp.zeros(D.shape[:-1]))
    chol = jnp.linalg.cholesky(Ss)  # NaN where a pivot block is not positive definite
    eye = jnp.eye(n)
    Sinv = jax.vmap(lambda L: jax.scipy.linalg.cho_solve((L, True), eye))(chol)

    def bwd(Sigma_next, x):
        Si, Ck = x
        G = Si @ Ck
        Sigma = Si + G @ Sigma_next @ G.T
        Sigma = 0.5 * (Sigma + Sigma.T)
        return Sigma, Sigma

    _, Sig = jax.lax.scan(bwd, Sinv[-1], (Sinv[:-1], C), reverse=True)
    return jnp.concatenate([Sig, Sinv[-1:]])


_RUNNING, _CODES = -1, {"converged": 0, "max-iterations": 1, "stalled": 2, "failed": 3}


@eqx.filter_jit
def _solve(system, integ, screens, prob, xs, max_iterations, tol):
    """Levenberg-Marquardt from ``xs`` in one compiled loop (:func:`minimize`): the trajectory, the marginal
    covariances, the cost there and at ``xs``, the largest gradient component, the iterations and the status's
    code (:data:`_CODES`).

    Each pass linearizes at the current trajectory; the pass after the last step only keeps that linearization
    (for the covariances, the cost and the gradient) and takes no step. So the model's Jacobians are traced and
    compiled once, in the loop's body: a second ``_linearize`` after the loop doubled the compile of a smoother's
    first call."""
    n = type(prob.g0).tangent_dim
    M = prob.ts.shape[0]

    def cond(c):
        return ~c[5]

    def step(xs, mu, it, f0, D, C, gr, f):
        Dd = D + mu * jnp.einsum("kii->ki", D)[..., None] * jnp.eye(n)  # Marquardt's damping
        delta = solve_tridiagonal(Dd, C, -gr)
        cand = xs.rplus(delta)
        fc = _cost(system, integ, screens, prob, cand)
        f0 = jnp.where(it == 0, f, f0)
        failed = ~jnp.isfinite(f0)
        lower = jnp.isfinite(fc) & (fc <= f + ROUNDOFF * (1.0 + jnp.abs(f)))
        # a step below the tolerance: xs is the minimizer to it, whether or not the cost, at its round-off, can
        # tell the candidate from xs (a sum of stiff terms rounds far above eps |J|)
        small = (jnp.max(jnp.abs(delta)) < tol) & (mu < _CONVERGED_DAMPING)
        mu1 = jnp.where(lower, mu / 10.0, jnp.maximum(10.0 * mu, 1e-8))
        status = jnp.where(failed, _CODES["failed"], jnp.where(small, _CODES["converged"], jnp.where(
            ~lower & (mu1 > _MAX_DAMPING), _CODES["stalled"], _RUNNING)))
        keep = lower & ~failed
        xs = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), cand, xs)
        return xs, mu1, it + 1, status, f0

    def body(c):
        xs, mu, it, status, f0, _, _ = c
        lin = _linearize(system, integ, screens, prob, xs)
        final = (status != _RUNNING) | (it >= max_iterations)
        xs, mu, it, status, f0 = jax.lax.cond(final, lambda *a: (xs, mu, it, status, f0), step,
                                              xs, mu, it, f0, *lin)
        return xs, mu, it, status, f0, final, lin

    lin0 = (jnp.zeros((M, n, n)), jnp.zeros((M - 1, n, n)), jnp.zeros((M, n)), jnp.asarray(0.0))
    start = (xs, jnp.asarray(0.0), jnp.asarray(0), jnp.asarray(_RUNNING), jnp.asarray(jnp.nan), jnp.asarray(False),
             lin0)
    xs, _, it, status, f0, _, (D, C, gr, f) = jax.lax.while_loop(cond, body, start)
    status = jnp.where(status == _RUNNING, _CODES["max-iterations"], status)
    return xs, marginal_covariances(D, C), f, f0, jnp.max(jnp.abs(gr)), it, status


@eqx.filter_jit
def dead_reckoning(system, integ, x0, ts, us):
    """The trajectory from ``x0`` at ``ts[0]`` by the process model alone (``integ``'s step over each interval,
    the input ``us[k]`` held over ``[ts[k], ts[k+1])``): batch (N,), ``x0`` first. A start for :func:`solve`
    with no filter to run."""

    def body(g, x):
        t, u, dt = x
        nxt = _flow(system, integ, g, u, t, dt)
        return nxt, nxt

    _, gs = jax.lax.scan(body, x0, (ts[:-1], us[:-1], jnp.diff(ts)))
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), x0, gs)


@eqx.filter_jit
def _process_noise(system, BRB, xs, us, ts):
    return jax.vmap(lambda x, u, t: system.process_noise_at(x, BRB, u, t))(xs, us, ts)


def floor_eigenvalues(P, std: float) -> np.ndarray:
    """``P`` (symmetric, optional leading batch axes) with its eigenvalues raised to ``std**2``."""
    P = np.asarray(P, dtype=np.float64)
    lam, V = np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2)))
    return (V * np.maximum(lam, std**2)[..., None, :]) @ np.swapaxes(V, -1, -2)


# --- the problem's data ---------------------------------------------------------------------------------------
def _held(us: np.ndarray, u0: np.ndarray) -> np.ndarray:
    """The inputs with a missing (NaN) component holding the last present one (``u0`` before the first)."""
    out = us.copy()
    last = u0.copy()
    for k in range(out.shape[0]):
        bad = ~np.isfinite(out[k])
        out[k, bad] = last[bad]
        last = out[k]
    return out


def _screens(system: AbstractSystem) -> tuple:
    """The sensors with a gate or a robust loss, as static tuples ``(start, stop, gate, robust, scale)``. A
    sensor system's noise is block-diagonal by sensor, so each such sensor's distance is of its own block."""
    return tuple((b.start, b.stop, None if b.gate_threshold is None else float(b.gate_threshold), b.robust,
                  float(b.robust_scale)) for b in system.blocks()
                 if b.gate_threshold is not None or b.robust is not None)


def sample_information(system: AbstractSystem, weights: Weights, ts: np.ndarray, ys: np.ndarray, *,
                       gap: float = math.inf, last: int | None = None) -> tuple[np.ndarray, np.ndarray, Array]:
    """Per state k of a log: which components of ``ys[k]`` enter (present, and a density sample only where it
    has an interval that is not a gap), the samples with zeros elsewhere, and W_k, the information in force
    over the interval after t_k times its length, with the sensors' time-varying weights and sample-dependent
    noise (``adaptive``) applied as the filters apply them. At the log's last state ``last`` (default: the last
    row), which has no interval, a sample sensor's per-sample information and no density sample."""
    N = ts.shape[0]
    last = N - 1 if last is None else last
    dts = np.diff(ts)
    _, sample, diagonal = sensor_layout(system, weights.Wy)
    sample = np.asarray(sample, bool)
    present = np.isfinite(ys)
    present[:-1] &= ~((dts > gap)[:, None] & ~sample[None, :])  # density samples are not held across a gap
    present[last] &= sample  # a density sample at the last time has no interval
    yz = np.where(present, np.nan_to_num(ys, nan=0.0), 0.0)
    W = _information(system, jnp.asarray(weights.Wy), jnp.asarray(sample), jnp.asarray(present), jnp.asarray(yz),
                     jnp.asarray(ts), jnp.asarray(np.concatenate([dts, [1.0]])), diagonal)
    return present, yz, W


@eqx.filter_jit
def _information(system, Wy, sample, present, yz, ts, dt_ext, diagonal: bool):
    """:func:`sample_information`'s W in one compiled program (a fixed-lag window calls it at every step)."""
    W = jax.vmap(lambda m, dt: information_in_force(Wy, sample, m, dt, diagonal=diagonal) * dt)(present, dt_ext)
    blocks = system.blocks()
    if any(b.adaptive for b in blocks):
        T = jax.vmap(system.sample_transform)(yz)
        W = jnp.swapaxes(T, -1, -2) @ W @ T
    factor = jnp.ones((ts.shape[0], system.output_dim))
    for b in blocks:
        if b.weight_fn is not None:
            w = jax.vmap(lambda t, fn=b.weight_fn: jnp.asarray(fn(t), jnp.float64))(ts)
            factor = factor.at[:, b.start:b.stop].set(jnp.broadcast_to(w[:, None], (ts.shape[0], b.dim)))
    root = jnp.sqrt(factor)
    return W * root[:, :, None] * root[:, None, :]


def problem(system: AbstractSystem, weights: Weights, ts, us, ys, g0: LieGroup, P0, *,
            init: LieGroup, integ: AbstractIntegrator, gap: float = math.inf, last_sample: bool = True,
            floor_std: float = FLOOR_STD) -> tuple[Problem, LieGroup]:
    """The cost's data for a checked log (``us`` with missing inputs already held), padded to a length bucket,
    and ``init`` extended over the padding by dead reckoning. The padded states carry no sample and no link to
    the log's: a chain of their own, of unit information, whose terms vanish, and which leaves the log's states
    and their marginals as without it.
    ``last_sample=False``: the last row's samples do not enter (the filter's information set at ``ts[-1]``).
    The process noise is evaluated on ``init``."""
    N = ts.shape[0]
    pad = bucket(N - 1) + 1 - N
    dt_last = ts[-1] - ts[-2]
    tsp = np.concatenate([ts, ts[-1] + dt_last * np.arange(1, pad + 1)])
    usp = np.concatenate([us, np.repeat(us[-1:], pad, axis=0)])
    ysp = np.concatenate([ys, np.full((pad, ys.shape[1]), np.nan)])
    if not last_sample:
        ysp[N - 1] = np.nan
    present, yz, W = sample_information(system, weights, tsp, ysp, gap=gap, last=N - 1)
    dts = np.diff(tsp)
    tsj, usj = jnp.asarray(tsp), jnp.asarray(usp)
    if pad:
        tail = dead_reckoning(system, integ, init[-1], tsj[N - 1:], usj[N - 1:])
        init = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b[1:]]), init, tail)
    BRB = jnp.asarray(weights.BRB)
    if system.constant_process_noise:
        Qd = np.asarray(BRB)[None] * dts[:, None, None]
    else:
        Qd = np.asarray(_process_noise(system, BRB, init[:-1], usj[:-1], tsj[:-1])) * dts[:, None, None]
    Qinv = np.linalg.inv(floor_eigenvalues(Qd, floor_std))
    # The padding is cut from the log: no weight on the link from the last state into it, unit information
    # between padded states, and a unit curvature on each (``padded``, :func:`_linearize`), so that the log's
    # states are solved as if there were no padding and the padded chain stays positive definite. With the
    # model's weights on the padding, the last padded state's information was the difference of terms of
    # 1/floor_std^2 (a constant coordinate, a position without noise), which round-off made indefinite after a
    # long extrapolation (the 27-state inertial model of compare broad-ins over 30 s of padding: an eigenvalue
    # of -0.08 beside 1e12, and NaN covariances).
    Qinv[N - 1:] = np.eye(Qinv.shape[-1])
    if pad:
        Qinv[N - 1] = 0.0
    prob = Problem(g0=g0, P0inv=jnp.asarray(np.linalg.inv(floor_eigenvalues(P0, floor_std))), ts=tsj, us=usj,
                   ys=jnp.asarray(yz), present=jnp.asarray(present), dts=jnp.asarray(dts), Qinv=jnp.asarray(Qinv),
                   W=W, padded=jnp.asarray(np.arange(tsp.shape[0]) >= N))
    return prob, init


def failed(ts, element: LieGroup, message: str, iterations: int = 0) -> Smoothed:
    """A smoother's failure as a value: status ``"failed"``, NaN estimates (of ``element``'s group) and
    covariances at every time of ``ts``, NaN costs, and ``message`` saying why."""
    N, n = len(ts), type(element).tangent_dim
    g = jax.tree_util.tree_map(lambda a: jnp.full((N, *jnp.shape(a)), jnp.nan), element)
    nan = jnp.asarray(jnp.nan)
    return Smoothed(ts=jnp.asarray(ts), g=g, P=jnp.full((N, n, n), jnp.nan), cost=nan, cost_init=nan,
                    gradient_norm=nan, iterations=iterations, status="failed", message=message)


def minimize(system: AbstractSystem, integ: AbstractIntegrator, screens: tuple, prob: Problem, xs: LieGroup, N: int,
             *, max_iterations: int, tol: float) -> tuple[LieGroup, Array, Array, Array, Array, int, str, str]:
    """Levenberg-Marquardt from ``xs`` (module docstring), compiled as one loop (``max_iterations`` and ``tol``
    are traced: new values do not recompile). Returns the trajectory and the marginal covariances of the first
    ``N`` states, the cost there and at ``xs``, the largest gradient component, the iterations, the status and
    its message."""
    xs, P, f, f0, gn, it, code = _solve(system, integ, screens, prob, xs, jnp.asarray(max_iterations),
                                        jnp.asarray(float(tol)))
    it = int(it)
    status = {v: k for k, v in _CODES.items()}[int(code)]
    g, P = xs[:N], P[:N]
    finite = bool(jnp.isfinite(f)) and bool(jnp.all(jnp.isfinite(P)))
    if status == "failed" or not finite:
        g = jax.tree_util.tree_map(lambda a: jnp.full_like(a, jnp.nan), g)
        P = jnp.full_like(P, jnp.nan)
        why = ("the cost is not finite at the starting trajectory" if status == "failed" else
               "the cost or the Hessian at the estimate is not finite, or the Hessian is not positive definite")
        status, message = "failed", f"failed after {it} iteration(s): {why}"
    else:
        message = {"converged": f"converged in {it} iteration(s): the last step was below {tol:g}",
                   "max-iterations": f"not converged: {it} iteration(s) taken, no step below {tol:g}",
                   "stalled": f"stalled after {it} iteration(s): no step lowered the cost"}[status]
    return g, P, f, f0, gn, it, status, message


def solve(system: AbstractSystem, weights: Weights, ts, us, ys, g0: LieGroup, P0, init: LieGroup, *,
          integ: AbstractIntegrator, screens: tuple = (), gap: float = math.inf, last_sample: bool = True,
          floor_std: float = FLOOR_STD, max_iterations: int = 50, tol: float = 1e-9) -> Smoothed:
    """The minimizer of the cost (module docstring) over one log, from the start ``init``: the one solve behind
    :func:`~liemef.smoothers.smooth` (a whole log, or each window of ``chunk=``), the fixed-lag windows and
    :func:`liemef.studies.optimum.batch_map`.

    ``ts`` (N,), ``us`` (N, m) with missing inputs already held, ``ys`` (N, p) with NaN where missing; the prior
    ``g0`` and its covariance ``P0`` (left error); ``init`` (batch (N,)) the start (a filter's run, or
    :func:`dead_reckoning`); ``weights`` the system's (:class:`~liemef.filters.Weights`); ``integ`` the process
    model's step; ``screens`` the gated or robust sensors as ``(start, stop, gate, robust, scale)`` (none: every
    loss Gaussian); ``gap``: an interval longer than this holds no density sample; ``last_sample=False``: the
    last row's samples do not enter; ``floor_std``: the floor of the prior's and the process noise's stds.
    Returns the :class:`Smoothed` of the N states (a failure as a value: status ``"failed"``, NaN estimates and
    covariances)."""
    prob, xs = problem(system, weights, ts, us, ys, g0, P0, init=init, integ=integ, gap=gap,
                       last_sample=last_sample, floor_std=floor_std)
    g, P, f, f0, gn, it, status, message = minimize(system, integ, screens, prob, xs, ts.shape[0],
                                                    max_iterations=max_iterations, tol=tol)
    return Smoothed(ts=jnp.asarray(ts), g=g, P=P, cost=f, cost_init=f0, gradient_norm=gn, iterations=it,
                    status=status, message=message)


def _filled(system, integ, g: LieGroup, ts, us) -> LieGroup:
    """``g`` with any states from the first non-finite one on replaced by dead reckoning from the state before
    it (a filter's trajectory is NaN after a failure)."""
    bad = np.zeros(ts.shape[0], bool)
    for leaf in jax.tree_util.tree_leaves(g):
        a = np.asarray(leaf)
        bad |= ~np.all(np.isfinite(a.reshape(a.shape[0], -1)), axis=1)
    if not bad.any():
        return g
    k = int(np.argmax(bad))
    k = max(k, 1)
    tail = dead_reckoning(system, integ, g[k - 1], jnp.asarray(ts[k - 1:]), jnp.asarray(us[k - 1:]))
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[:k - 1], b]), g, tail)


def _check_options(max_iterations, tol, floor_std) -> float:
    """The solver's options, checked (ValueError naming each); returns ``tol`` as a float."""
    _validate.integer("max_iterations", max_iterations, low=1)
    _validate.positive("floor_std", floor_std)
    return _validate.positive("tol", tol)  # converged when a step is below it: 0 never is


@dataclasses.dataclass(frozen=True)
class Setup:
    """A smoother's checked arguments (:func:`setup`): the system, the integrator, the robust sensors, the
    prior's covariance, the log (``us`` as given, ``held`` with missing inputs held), the gap and the options."""

    system: AbstractSystem
    integ: AbstractIntegrator
    screens: tuple
    P0: np.ndarray
    ts: np.ndarray
    us: np.ndarray
    held: np.ndarray
    ys: np.ndarray
    gap: float
    max_iterations: int
    tol: float
    floor_std: float


def setup(flt: AbstractFilter, state: FilterState, ts, us, ys, *, gap: float | None, init: LieGroup | None,
          integrator: str | AbstractIntegrator | None, max_iterations: int, tol: float, floor_std: float) -> Setup:
    """:func:`~liemef.smoothers.smooth`'s arguments checked (ValueError naming each), before anything runs."""
    if not isinstance(flt, AbstractFilter):
        raise ValueError(f"flt: expected a liemef filter (MinimumEnergyFilter or a baseline), got {type(flt).__name__}")
    flt.check_state(state)
    flt.check_element("state.g_hat", state.g_hat)
    system = flt.system
    n = system.group.tangent_dim
    P0 = _validate.symmetric_psd("state.K", state.K, n, definite=False)
    tol = _check_options(max_iterations, tol, floor_std)
    ts, us, ys, gap = check_log(flt, ts, us, ys, (), gap)
    N = ts.shape[0]
    if init is not None and (not isinstance(init, system.group) or init.batch_shape != (N,)):
        raise ValueError(f"init: expected a {system.group.__name__} of batch shape ({N},), got "
                         f"{type(init).__name__} {getattr(init, 'batch_shape', None)}")
    if integrator is None:
        integrator = getattr(flt, "integrator", None) or "rkmk4"
    return Setup(system=system, integ=make_integrator(integrator), screens=_screens(system), P0=P0, ts=ts, us=us,
                 held=_held(us, np.asarray(state.u_last, dtype=np.float64)), ys=ys, gap=gap,
                 max_iterations=max_iterations, tol=tol, floor_std=floor_std)


def smooth_whole(flt: AbstractFilter, state: FilterState, su: Setup, init: LieGroup | None) -> Smoothed:
    """The whole log as one problem (:func:`~liemef.smoothers.smooth` without chunks)."""
    system, integ, ts = su.system, su.integ, su.ts
    if init is None:
        init = flt.run(state, ts, su.us, su.ys, gap=su.gap).g_hat
    init = _filled(system, integ, init, ts, su.held)
    return solve(system, flt.weights, ts, su.held, su.ys, state.g_hat, su.P0, init, integ=integ,
                 screens=su.screens, gap=su.gap, floor_std=su.floor_std, max_iterations=su.max_iterations,
                 tol=su.tol)
