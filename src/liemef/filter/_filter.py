from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .. import _validate
from .._linalg import mv
from ..connections import Connection, ConnectionFunction
from ..connections import connection as make_connection
from ..groups import LieGroup
from ..systems import AbstractSystem
from ._integrators import AbstractIntegrator
from ._integrators import integrator as make_integrator
from ._riccati import Terms, Weights, riccati_rhs, terms


class FilterState(eqx.Module):
    """The filter's state: the estimate $\\hat g$ and the gain K (n x n)."""

    g_hat: LieGroup
    K: Float[Array, "n n"]


class Trajectory(eqx.Module):
    """A filter run: ``g_hat[k]`` and ``K[k]`` at ``ts[k]`` (``g_hat`` has batch shape (N,)).

    ``finite`` is False if the run produced a NaN or infinity (a failure is returned as a value, not raised
    inside compiled code).
    """

    ts: Float[Array, " N"]
    g_hat: LieGroup
    K: Float[Array, "N n n"]
    finite: Bool[Array, ""]

    def coords(self) -> Float[Array, "N c"]:
        """The estimate in the group's coordinates (e.g. theta, x, y, omega, vx, vy for TSE(2))."""
        return self.g_hat.coords()


ORDERS = ("second", "first")
"""The filter orders: ``"second"`` (Theorem 4.1, the papers' filter) and ``"first"`` (without the Hessian
term of E and W: the continuous-time left-invariant EKF)."""


class MinimumEnergyFilter:
    r"""Second-order-optimal minimum-energy filter on a matrix Lie group (Saccon et al. 2016, Theorem 4.1).

    Args:
        system: the model (group, dynamics, output, B, D, Q, R), e.g. :class:`liemef.systems.PlanarRigidBody`.
        connection: ``"zero"`` (c = 1/2, torsion-free, the papers' default), ``"minus"`` (c = 0), ``"plus"``
            (c = 1), a Cartan-Schouten coefficient c, or a bilinear function ``omega(X, Y)``.
        order: ``"second"`` (the paper filter) or ``"first"`` (no Hessian term in E, W = 0: the continuous-time
            left-invariant EKF on the group).
        integrator: ``"rkmk4"`` (4th-order Runge-Kutta-Munthe-Kaas) or ``"lie-euler"``.
        alpha: forgetting factor, >= 0.

    Inputs and measurements are samples held between sample times (zero-order hold). The filter is
    immutable: :meth:`init`, :meth:`step` and :meth:`run` return new states. ``step`` and ``run`` are compiled
    on first use (``run`` as one ``lax.scan``); :meth:`scan` is the traceable, unchecked core of ``run`` for use
    inside your own ``jit``/``vmap``.
    """

    def __init__(self, system: AbstractSystem, connection: str | float | ConnectionFunction | Connection = "zero",
                 order: Literal["second", "first"] = "second",
                 integrator: str | AbstractIntegrator = "rkmk4", alpha: float = 0.0):
        if not isinstance(system, AbstractSystem):
            raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
        _validate.choice("order", order, set(ORDERS))
        set_ = object.__setattr__
        set_(self, "system", system)
        set_(self, "connection", make_connection(connection, system.group))
        set_(self, "order", order)
        set_(self, "integrator", make_integrator(integrator))
        set_(self, "alpha", _validate.nonnegative("alpha", alpha))
        set_(self, "weights", Weights.of(system))
        treedef = jax.tree_util.tree_structure(FilterState(system.group.identity(), jnp.zeros((self.n, self.n))))
        set_(self, "_treedef", treedef)
        set_(self, "_step_jit", jax.jit(self._step_leaves))
        set_(self, "_run_jit", jax.jit(self.scan))
        set_(self, "_terms_jit", jax.jit(self._terms))

    def __setattr__(self, name, value):
        raise AttributeError(f"MinimumEnergyFilter is immutable: cannot set {name!r}")

    def __repr__(self) -> str:
        return (f"MinimumEnergyFilter({type(self.system).__name__}, connection={self.connection.name!r}, "
                f"order={self.order!r}, integrator={self.integrator.name!r}, alpha={self.alpha})")

    @property
    def n(self) -> int:
        return self.system.group.tangent_dim

    # --- initialisation -----------------------------------------------------------------------------------
    def init(self, g0: LieGroup, K0: ArrayLike | None = None, *, X0: ArrayLike | None = None) -> FilterState:
        """Initial state: ``g_hat = g0`` (argmin of m0) and ``K = K0``, or ``K = X0^{-1}`` with X0 the
        left-trivialized Hessian of m0. K0 may be singular (positive semidefinite), as in Rigo et al. 2023,
        eq. (63)."""
        self._check_element("g0", g0)
        n = self.n
        if (K0 is None) == (X0 is None):
            raise ValueError("init: expected exactly one of K0 (initial gain) or X0 (Hessian of m0), got "
                             f"{'both' if K0 is not None else 'neither'}")
        if K0 is not None:
            K = _validate.symmetric_psd("K0", K0, n, definite=False)
        else:
            K = np.linalg.inv(_validate.symmetric_psd("X0", X0, n))
        return FilterState(g_hat=g0, K=jnp.asarray(K))

    # --- the mathematics ----------------------------------------------------------------------------------
    def _terms(self, g_hat, K, u, y, t) -> Terms:
        return terms(self.system, self.weights, self.connection, self.order == "second", g_hat, K, u, y, t)

    def terms(self, g_hat: LieGroup, K: ArrayLike, u: ArrayLike, y: ArrayLike, t: float = 0.0) -> Terms:
        """r, A, E, W and B R^{-1} B^T of Theorem 4.1 at a state, to compare with the papers' printed forms."""
        self._check_element("g_hat", g_hat)
        K = _validate.square("K", K, self.n)
        u, y = self._check_sample("u", u, self.system.input_dim), self._check_sample("y", y, self.system.output_dim)
        return self._terms_jit(g_hat, jnp.asarray(K), u, y, jnp.asarray(float(t)))

    def vector_field(self, g_hat: LieGroup, K, u, y, t):
        r"""$(\hat g^{-1}\dot{\hat g}, \dot K)$ at a state (traceable)."""
        tm = self._terms(g_hat, K, u, y, t)
        return tm.lam + mv(K, tm.r), riccati_rhs(tm, K, self.alpha)

    def _step(self, state: FilterState, t, u, y, dt) -> FilterState:
        f = lambda g, K, tt: self.vector_field(g, K, u, y, tt)  # noqa: E731  (u, y held over the step)
        g, K = self.integrator.step(f, state.g_hat, state.K, t, dt)
        return FilterState(g_hat=g, K=K)

    def _step_leaves(self, leaves, z):
        # Online step on flat arrays: jit dispatch flattens nested modules in Python (~20 us); a list of arrays
        # and one packed sample vector z = (t, dt, u, y) take the C++ fast path.
        m = self.system.input_dim
        state = jax.tree_util.tree_unflatten(self._treedef, leaves)
        return jax.tree_util.tree_leaves(self._step(state, z[0], z[2 : 2 + m], z[2 + m :], z[1]))

    # --- public drivers -----------------------------------------------------------------------------------
    def step(self, state: FilterState, t: float, u: ArrayLike, y: ArrayLike, dt: float) -> FilterState:
        """Advance one sample interval ``[t, t + dt]`` with ``u`` and ``y`` held (online use)."""
        self._check_state(state)
        u, y = self._check_sample("u", u, self.system.input_dim), self._check_sample("y", y, self.system.output_dim)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: expected a finite time step > 0, got {dt}")
        if not np.isfinite(t):
            raise ValueError(f"t: expected a finite time, got {t}")
        leaves = jax.tree_util.tree_leaves(state)
        out = self._step_jit(leaves, np.concatenate([[float(t), float(dt)], u, y]))
        return jax.tree_util.tree_unflatten(self._treedef, out)

    def scan(self, state: FilterState, ts, us, ys) -> Trajectory:
        """Traceable core of :meth:`run` (no checks): one ``lax.scan`` over the sample intervals."""

        def body(st, k):
            t, dt, u, y = k
            nxt = self._step(st, t, u, y, dt)
            return nxt, nxt

        xs = (ts[:-1], jnp.diff(ts), us[:-1], ys[:-1])
        _, traj = jax.lax.scan(body, state, xs)
        g_all = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), state.g_hat, traj.g_hat)
        K_all = jnp.concatenate([state.K[None], traj.K])
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves((g_all, K_all))]))
        return Trajectory(ts=ts, g_hat=g_all, K=K_all, finite=finite)

    def run(self, state: FilterState, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike) -> Trajectory:
        """Filter a whole log: ``ts`` (N,) strictly increasing, ``us`` (N, m), ``ys`` (N, p).

        Sample k is held over ``[ts[k], ts[k+1])``; the result holds the state at every ``ts[k]``, the first
        being ``state``. Compiled once per log length.
        """
        self._check_state(state)
        self._check_element("state.g_hat", state.g_hat)
        _validate.square("state.K", state.K, self.n)
        ts = _validate.sorted_times("ts", ts)
        N = ts.shape[0]
        if N < 2:
            raise ValueError(f"ts: expected at least 2 time stamps, got {N}")
        m, p = self.system.input_dim, self.system.output_dim
        us = np.zeros((N, 0)) if us is None and m == 0 else _validate.array("us", us, (N, m))
        ys = _validate.array("ys", ys, (N, p))
        return self._run_jit(state, jnp.asarray(ts), jnp.asarray(us), jnp.asarray(ys))

    # --- checks -------------------------------------------------------------------------------------------
    def _check_state(self, state):
        # cheap structural checks only: step() is the online hot path
        if not isinstance(state, FilterState):
            raise ValueError(f"state: expected a FilterState (from init or step), got {type(state).__name__}")
        G, n = self.system.group, self.n
        if type(state.g_hat) is not G or getattr(state.K, "shape", None) != (n, n):
            raise ValueError(f"state: expected g_hat in {G.__name__} and K of shape ({n}, {n}), got "
                             f"{type(state.g_hat).__name__} and {getattr(state.K, 'shape', None)}")

    def _check_element(self, name, g):
        G = self.system.group
        if not isinstance(g, G):
            raise ValueError(f"{name}: expected an element of {G.__name__}, got {type(g).__name__}")
        if g.batch_shape != ():
            raise ValueError(f"{name}: expected a single element (no batch axes), got batch shape {g.batch_shape}")
        for leaf in jax.tree_util.tree_leaves(g):
            _validate.array(name, leaf)

    @staticmethod
    def _check_sample(name, v, n) -> np.ndarray:
        return _validate.array(name, np.zeros(0) if v is None and n == 0 else v, (n,))
