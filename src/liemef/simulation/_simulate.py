from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .. import _validate
from ..groups import LieGroup
from ..integrators import AbstractIntegrator
from ..integrators import integrator as make_integrator
from ..systems import AbstractSystem

InputFn = Callable[[Float[Array, ""]], Float[Array, " m"]]
"""``u(t)``: the nominal input at time t, written with ``jax.numpy`` (traced inside the simulation)."""


class Truth(eqx.Module):
    """The true trajectory: ``g[k]`` at ``ts[k]`` (batch shape (N,)) and the nominal input
    ``u[k] = u(ts[k])``."""

    ts: Float[Array, " N"]
    g: LieGroup
    u: Float[Array, "N m"]

    def coords(self) -> Float[Array, "N c"]:
        """The truth in the group's coordinates (e.g. theta, x, y, omega, vx, vy for TSE(2))."""
        return self.g.coords()


class SensorLog(eqx.Module):
    """What a filter sees: measured inputs ``us[k]`` and measurements ``ys[k]`` at ``ts[k]``.

    The same layout as a recorded log (:func:`liemef.reports.io.read_log`) and as the arguments of
    :meth:`liemef.MinimumEnergyFilter.run`.
    """

    ts: Float[Array, " N"]
    us: Float[Array, "N m"]
    ys: Float[Array, "N p"]


def _no_input(t):
    return jnp.zeros((0,))


def simulate_core(system: AbstractSystem, g0: LieGroup, input_fn: InputFn | None, ts: Float[Array, " N"],
                  key: PRNGKeyArray, model_error_std: float | Float[Array, ""] = 0.0,
                  input_noise: Float[Array, "m q"] | None = None, substeps: int = 1,
                  integrator: str | AbstractIntegrator = "rkmk4") -> tuple[Truth, SensorLog]:
    """Traceable core of :func:`simulate` (no checks): usable under ``jit`` and ``vmap`` over ``key``.

    ``substeps`` and ``integrator`` must be static (Python values); everything else may be traced.
    """
    integ = make_integrator(integrator)
    input_fn = _no_input if input_fn is None else input_fn
    N, d, p = ts.shape[0], system.noise_dim, system.output_dim
    # One split, always the same: changing one noise level never changes the draws of the others.
    k_delta, k_eta, k_eps = jax.random.split(key, 3)
    delta = model_error_std * jax.random.normal(k_delta, (N - 1, substeps, d))
    eps = jax.random.normal(k_eps, (N, p))
    B, D = system.B, system.D

    def truth_step(g, xs):
        t, h, delta_j = xs
        u = input_fn(t)  # the nominal input, held over one truth step
        Bdelta = B @ delta_j

        def f(gg, v, tt):
            return system.dynamics(gg, u, tt) + Bdelta, ()

        g, _ = integ.step(f, g, (), t, h)
        return g, None

    def interval(g, xs):
        t, dt, delta_k = xs
        h = dt / substeps
        tj = t + h * jnp.arange(substeps)
        g, _ = jax.lax.scan(truth_step, g, (tj, jnp.full((substeps,), h), delta_k))
        return g, g

    _, gs = jax.lax.scan(interval, g0, (ts[:-1], jnp.diff(ts), delta))
    g_all = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), g0, gs)

    u_nominal = jax.vmap(input_fn)(ts)
    us = u_nominal
    if input_noise is not None:
        eta = jax.random.normal(k_eta, (N, input_noise.shape[1]))
        us = us + eta @ input_noise.T
    # y_k = h(g(t_k), t_k) + D eps_k
    ys = jax.vmap(system.output)(g_all, ts) + eps @ D.T
    return Truth(ts=ts, g=g_all, u=u_nominal), SensorLog(ts=ts, us=us, ys=ys)


_simulate_jit = eqx.filter_jit(simulate_core)


def input_times(ts: Float[Array, " N"], substeps: int) -> Float[Array, " M"]:
    """Every time at which :func:`simulate_core` evaluates the input function, computed as it does: the start
    of each truth step ``t_k + j dt_k / substeps`` (j < substeps) and each sample time (the nominal input)."""
    h = jnp.diff(ts) / substeps
    steps = ts[:-1, None] + h[:, None] * jnp.arange(substeps)
    return jnp.concatenate([steps.reshape(-1), ts])


@eqx.filter_jit
def _inputs_at(input_fn: InputFn, ts: Float[Array, " N"], substeps: int):
    times = input_times(ts, substeps)
    return times, jax.vmap(input_fn)(times)


def check_inputs(input_fn: InputFn, ts: Float[Array, " N"], substeps: int) -> None:
    """``input_fn`` returns finite values at every time the simulation evaluates it (:func:`input_times`): a
    ValueError naming it, the first such time and the values otherwise (a NaN input would give a NaN log)."""
    times, us = (np.asarray(a) for a in _inputs_at(input_fn, jnp.asarray(ts), substeps))
    bad = ~np.all(np.isfinite(us), axis=-1)
    if np.any(bad):
        k = int(np.argmin(np.where(bad, times, np.inf)))
        raise ValueError(f"input_fn: expected finite inputs u(t), got u(t) = {us[k].tolist()} at t = "
                         f"{float(times[k])!r}, the first time it returned non-finite values")


def simulate(system: AbstractSystem, g0: LieGroup, input_fn: InputFn | None, ts: ArrayLike,
             key: PRNGKeyArray, *, model_error_std: float = 0.0, input_noise: ArrayLike | None = None,
             substeps: int = 1, integrator: str | AbstractIntegrator = "rkmk4") -> tuple[Truth, SensorLog]:
    r"""Simulate a system's truth and its sensors on the time grid ``ts``.

    The truth solves $\dot g = g\,(\lambda(g, u(t), t) + B\delta)$ from ``g0`` with a Lie-group integrator
    (``"rkmk4"``, ``"rkmk2"`` or ``"lie-euler"``), ``substeps`` equal steps per sample interval. Over each truth
    step the nominal input $u(t)$ is held at its value at the start of the step, and so is the model error $\delta$,
    drawn per truth step as $\delta \sim N(0, \sigma_\delta^2 I_d)$ with $\sigma_\delta$ = ``model_error_std``
    (a per-step draw, not a continuous white-noise density: the step size does not rescale it).

    At every sample time $t_k$ (including ``ts[0]``):

    * measured input $u^{meas}_k = u(t_k) + N_u \eta_k$, $\eta_k \sim N(0, I_q)$, with $N_u$ = ``input_noise``
      (m x q; None for none);
    * measurement $y_k = h(g(t_k), t_k) + D\varepsilon_k$, $\varepsilon_k \sim N(0, I_p)$, D the system's.

    Args:
        system: the model, e.g. :class:`liemef.systems.PlanarRigidBody`.
        g0: initial truth, an element of ``system.group`` (no batch axes).
        input_fn: ``u(t)`` as a JAX function of a scalar time returning shape (m,); None when m = 0. It must
            return finite values at every time the simulation evaluates it (the sample times and the start of
            every truth step): a ValueError names the first time it does not. Pass the same function object
            across calls to reuse the compiled simulation.
        ts: sample times (N,), strictly increasing, N >= 2.
        key: a ``jax.random`` key, the only source of randomness (split inside; never global state).

    Returns:
        ``(truth, log)``: :class:`Truth` (ts, g with batch shape (N,), nominal u) and :class:`SensorLog`
        (ts, measured us, ys). Compiled once per system, input function, grid length and static options.
    """
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a liemef system (AbstractSystem), got {type(system).__name__}")
    if not system.constant_process_noise:
        raise ValueError(f"system: expected a system with a constant noise map B, got {type(system).__name__}, whose "
                         "process noise depends on the state (simulate the system it was made from)")
    G = system.group
    _validate.element("g0", g0, G)
    ts = _validate.sorted_times("ts", ts)
    if ts.shape[0] < 2:
        raise ValueError(f"ts: expected at least 2 sample times, got {ts.shape[0]}")
    if not (isinstance(key, jax.Array) and (jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
                                            or (key.dtype == jnp.uint32 and key.shape == (2,)))):
        raise ValueError(f"key: expected a jax.random key (e.g. jax.random.key(0)), got {key!r}")
    model_error_std = _validate.nonnegative("model_error_std", model_error_std)
    m = system.input_dim
    if input_fn is None and m > 0:
        raise ValueError(f"input_fn: expected a function u(t) returning shape ({m},), got None")
    if input_fn is not None:
        if not callable(input_fn):
            raise ValueError(f"input_fn: expected a function u(t), got {type(input_fn).__name__}")
        out = jax.eval_shape(input_fn, jnp.zeros(()))
        if getattr(out, "shape", None) != (m,):
            raise ValueError(f"input_fn: expected u(t) of shape ({m},), got {getattr(out, 'shape', out)}")
    if input_noise is not None:
        input_noise = _validate.array("input_noise", input_noise, (m, None))
        input_noise = jnp.asarray(input_noise)
    substeps = _validate.integer("substeps", substeps, 1)
    if input_fn is not None:
        check_inputs(input_fn, ts, int(substeps))
    integ = make_integrator(integrator)
    return _simulate_jit(system, g0, input_fn, jnp.asarray(ts), key, jnp.asarray(model_error_std),
                         input_noise, int(substeps), integ)
