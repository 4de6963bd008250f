r"""The right error of a system: the same system with its state inverted, for filters that work in left coordinates.

Every filter of liemef describes its uncertainty by the left error $\xi$, $g = \hat g\exp\xi$. The invariant EKF
owes its consistency on some systems to the other choice, the right error $\eta$ with $\hat g g^{-1} = \exp\eta$:
for a sensor that sees the world from the body (a landmark's range and bearing, a known field's direction), the
null space of the output's Jacobian in $\eta$, the directions the sensor does not observe, does not depend on the
estimate, so that such a direction gets no information from a linearization at the wrong place
(docs/second-order.md, ``se2-near-rb``).

:func:`right_error` gives a system whose state is $h = g^{-1}$. Its left error is the original's right error,
$\hat h^{-1} h = \hat g g^{-1}$, so any filter of the library run on it works in right coordinates:

* dynamics: $\dot g = g(\lambda + B\delta)$ gives $h^{-1}\dot h = -\mathrm{Ad}_{h^{-1}}(\lambda(h^{-1}, u, t) +
  B\delta)$;
* outputs: $h(h^{-1}, t)$, each sensor with its noise, residual, gate and robust loss unchanged;
* process noise: $B' = -\mathrm{Ad}_{h^{-1}} B$ depends on the state, so its density on the algebra is
  $\mathrm{Ad}_{h^{-1}} B R^{-1} B^\top \mathrm{Ad}_{h^{-1}}^\top$ (:meth:`RightErrorSystem.process_noise_at`), which
  the filters evaluate at their estimate.

:meth:`RightErrorSystem.state_of` turns an initial estimate and its left-error covariance into the inverted
state's, and :meth:`RightErrorSystem.estimates_of` turns the inverted filter's estimates and K back:
$\hat g = \hat h^{-1}$ and, from $\xi = -\mathrm{Ad}_{\hat g^{-1}}\eta$, $K_\xi = \mathrm{Ad}_{\hat h} K_\eta
\mathrm{Ad}_{\hat h}^\top$. The simulator and the batch solvers need a constant process noise and refuse it:
simulate the original system and invert its truth.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..groups import LieGroup
from ._sensors import Sensor, SensorSystem


def _congruence(A, K):
    r"""$A K A^\top$ (any batch shape): a covariance of one error carried to another by the linear map A."""
    return A @ jnp.asarray(K, dtype=jnp.float64) @ jnp.swapaxes(A, -1, -2)


def _inverted_velocity(h, lam):
    r"""$h^{-1}\dot h = -\mathrm{Ad}_{h^{-1}}\lambda$ of an inverted state, from the system's body velocity."""
    return -(h.inverse().Ad() @ jnp.asarray(lam, dtype=jnp.float64))


def _inverted_noise(h, BRB):
    r"""$\mathrm{Ad}_{h^{-1}} B R^{-1} B^\top \mathrm{Ad}_{h^{-1}}^\top$: the process noise of an inverted state."""
    return _congruence(h.inverse().Ad(), BRB)


class _AtInverse(eqx.Module):
    """``fn(h^-1, t)``: a sensor's output at the inverted state (``fn``'s array fields stay leaves)."""

    fn: Callable

    def __call__(self, h, t):
        return self.fn(h.inverse(), t)


class _InverseDynamics(eqx.Module):
    """$h^{-1}\\dot h = -\\mathrm{Ad}_{h^{-1}}\\lambda(h^{-1}, u, t)$."""

    fn: Callable

    def __call__(self, h, u, t):
        return _inverted_velocity(h, self.fn(h.inverse(), u, t))


def _inverted_sensor(s: Sensor) -> Sensor:
    """``s`` with its output read at the inverted state; everything else (noise, gate, residual...) as it was."""
    out = object.__new__(Sensor)
    for f in dataclasses.fields(Sensor):
        object.__setattr__(out, f.name, getattr(s, f.name))
    if not s.covariate:  # a constant output is the same at the inverted state
        object.__setattr__(out, "fn", _AtInverse(s.fn))
    return out


class RightErrorSystem(SensorSystem):
    """A :class:`SensorSystem` on the inverted state $h = g^{-1}$ of ``base`` (module docstring): its left error
    is the right error of ``base``. Build it with :func:`right_error`."""

    base: SensorSystem

    def __init__(self, base: SensorSystem):
        if not isinstance(base, SensorSystem) or isinstance(base, RightErrorSystem):
            raise ValueError(f"system: expected a SensorSystem (not already inverted), got {type(base).__name__}")
        super().__init__(base.group, _InverseDynamics(base.dynamics_fn), [_inverted_sensor(s) for s in base.sensors],
                         base.process_noise, base.noise_map, inputs=base.inputs, input_units=base.input_units)
        self.base = base

    def with_noise(self, **levels) -> RightErrorSystem:
        """The right error of ``base.with_noise(**levels)``: the base system stays the one inverted."""
        return RightErrorSystem(self.base.with_noise(**levels))

    def with_scale_params(self, **params) -> RightErrorSystem:
        """The right error of ``base.with_scale_params(**params)``."""
        return RightErrorSystem(self.base.with_scale_params(**params))

    def process_noise_at(self, g: LieGroup, BRB, u, t):
        """$\\mathrm{Ad}_{h^{-1}} B R^{-1} B^\\top \\mathrm{Ad}_{h^{-1}}^\\top$ at the inverted state ``g`` = h, with
        ``base``'s own noise at $h^{-1}$ as $B R^{-1} B^\\top$ (its nominal where it is constant)."""
        return _inverted_noise(g, self.base.process_noise_at(g.inverse(), BRB, u, t))

    def state_of(self, g0: LieGroup, K0):
        r"""The inverted state of the estimate ``g0`` with left-error covariance ``K0``: $(g_0^{-1},
        \mathrm{Ad}_{g_0} K_0 \mathrm{Ad}_{g_0}^\top)$, to start a filter of this system with."""
        return g0.inverse(), _congruence(g0.Ad(), K0)

    def estimates_of(self, h_hat: LieGroup, K):
        r"""The estimates of ``base`` from this system's (any batch shape): $(\hat h^{-1}, \mathrm{Ad}_{\hat h} K
        \mathrm{Ad}_{\hat h}^\top)$, K the covariance of the left error of ``base``."""
        return h_hat.inverse(), _congruence(h_hat.Ad(), K)


class RightErrorAbout(eqx.Module):
    r"""The right error of ``base`` about an ``anchor`` T: the state $h = g^{-1}T$, the inverted state of the
    system whose world is translated by $T^{-1}$, $g' = T^{-1}g$. Its left error is $\mathrm{Ad}_{T^{-1}}\eta$, a
    constant linear map of the right error $\eta$ ($\hat g g^{-1} = \exp\eta$), so that a filter of it keeps the
    right error; with T the estimate, $\hat h = I$ and its quantities stay of the size of the left error's, where
    those of :class:`RightErrorSystem` grow with the distance from the world's origin ($\mathrm{Ad}_{\hat g}$
    holds the position). What :class:`~liemef.MinimumEnergyFilter` with ``error="right"`` runs each interval on,
    anchored at the interval's first estimate: the dynamics, the outputs and the process noise (the methods its
    terms and its sample update read), with ``base``'s sensors, residuals and weights. A plain module, built inside
    a trace (``anchor`` a traced element)."""

    base: SensorSystem
    anchor: LieGroup

    @property
    def group(self) -> type[LieGroup]:
        return self.base.group

    def _g(self, h):
        return self.anchor @ h.inverse()

    def dynamics(self, h, u, t):
        r"""$h^{-1}\dot h = -\mathrm{Ad}_{h^{-1}}\lambda(T h^{-1}, u, t)$."""
        return _inverted_velocity(h, self.base.dynamics(self._g(h), u, t))

    def output_seen_from(self, y, h, t):
        """``base``'s output, as seen from ``y``, at $g = T h^{-1}$."""
        return self.base.output_seen_from(y, self._g(h), t)

    def process_noise_at(self, h, BRB, u, t):
        r"""$\mathrm{Ad}_{h^{-1}} B R^{-1} B^\top \mathrm{Ad}_{h^{-1}}^\top$, with ``base``'s own noise at
        $g = T h^{-1}$ as $B R^{-1} B^\top$."""
        return _inverted_noise(h, self.base.process_noise_at(self._g(h), BRB, u, t))

    def estimates_of(self, h_hat, K):
        r"""The system's estimate and left-error covariance: $(T\hat h^{-1}, \mathrm{Ad}_{\hat h} K
        \mathrm{Ad}_{\hat h}^\top)$ (with $h = \hat h\exp\zeta$: $g = \hat g\exp(-\mathrm{Ad}_{\hat h}\zeta)$)."""
        return self._g(h_hat), _congruence(h_hat.Ad(), K)


def _row_space(J: np.ndarray, rtol: float = 1e-9) -> np.ndarray | None:
    """An orthonormal basis (r x n) of the row space of ``J``; None where ``J`` is not finite."""
    if not np.all(np.isfinite(J)):
        return None
    _, s, Vt = np.linalg.svd(J)
    return Vt[: int(np.sum(s > rtol * max(s.max(initial=0.0), 1e-300)))]


def _same_space(bases: list[np.ndarray], tol: float) -> bool:
    """Whether the row spaces ``bases`` are one space: equal ranks, and each inside the first to ``tol`` (the
    largest sine of their principal angles)."""
    V0 = bases[0]
    P0 = V0.T @ V0
    for V in bases[1:]:
        if V.shape != V0.shape:
            return False
        if V.size and np.linalg.norm(V - V @ P0, 2) > tol:
            return False
    return True


@eqx.filter_jit
def _side_jacobians(system: SensorSystem, zetas, times) -> dict:
    """The Jacobians of the outputs as the filter linearizes them (a sensor's own residual included: the output
    as seen from the sample y = h(g)), on each side, at every state and its time, compiled as one program, once
    per system's structure (its arrays are traced: a new weight set reuses it): run eagerly, JAX compiled each of
    its hundreds of operations alone (22 s for ukfm's inertial system on a loaded machine, 1.7 s compiled)."""
    G = system.group
    zero = jnp.zeros(G.tangent_dim)
    moves = {"left": lambda g, e: g.rplus(e), "right": lambda g, e: G.exp(e) @ g}

    def one(zeta, t):
        g = G.exp(zeta)
        y = system.output(g, t)
        return {side: jax.jacfwd(lambda e, move=move: system.output_seen_from(y, move(g, e), t))(zero)
                for side, move in moves.items()}
    return jax.vmap(one)(zetas, times)


def invariant_sides(system: SensorSystem, *, states: int = 8, seed: int = 0, tol: float = 1e-6) -> dict[str, str]:
    r"""Per sensor of ``system`` (by name): ``"left"``, ``"right"``, ``"both"`` or ``"neither"``, the error
    coordinates in which the directions the sensor observes (the row space of its output's Jacobian) are the same
    at every state.

    A sensor of the world seen from the body (a landmark's range and bearing, a known field's direction,
    $y = g^{-1}b$) observes fixed directions of the right error $\eta$ ($\hat g g^{-1} = \exp\eta$): its Jacobian
    there is an invertible map of the output times a constant matrix, so a linearization at a wrong estimate
    gives no information along what it does not observe. A sensor of the body seen from the world (a position
    fix, $y = g b$) does the same in the left error $\xi$ ($g = \hat g\exp\xi$) (Barrau and Bonnabel 2017).
    A sensor that observes every direction, or none, is ``"both"``; one that is curved in both (an altimeter's
    $p_z$ on $SE_2(3)$, whose rows turn with the attitude in one and with the position in the other),
    ``"neither"``.

    Measured, not declared: the Jacobians of the outputs as the filter linearizes them (a sensor's own residual
    included), at the identity at t = 0 and at ``states`` random states $\exp\zeta$, $\zeta \sim N(0, I)$, at
    random times in [0, 10] s (``seed``), their row spaces compared to ``tol`` (the largest sine of the
    principal angles). States where a sensor's output is not finite, or where it observes nothing, are skipped;
    a sensor with fewer than two such states is ``"neither"``, one that observes nothing anywhere ``"both"``, and
    every sensor of a system whose outputs raise at one of the states ``"neither"``."""
    if not isinstance(system, SensorSystem):
        raise ValueError(f"system: expected a SensorSystem, got {type(system).__name__}")
    G = system.group
    n = G.tangent_dim
    rng = np.random.default_rng(seed)
    zetas = np.vstack([np.zeros(n), rng.standard_normal((states, n))])
    times = np.concatenate([[0.0], rng.uniform(0.0, 10.0, states)])  # an output may vary with t

    out = {}
    try:
        J = {side: np.asarray(a, np.float64)
             for side, a in _side_jacobians(system, jnp.asarray(zetas), jnp.asarray(times)).items()}
    except Exception:  # noqa: BLE001 (a user's output that fails at a random state: nothing measured)
        return {s.name: "neither" for s in system.sensors}
    for b in system.blocks():
        verdict = {}
        for side in J:  # the two sides _side_jacobians measured
            bases = [v for v in map(_row_space, J[side][:, b.start:b.stop]) if v is not None]
            seen = [v for v in bases if v.shape[0] > 0]  # a state where it observes nothing says nothing
            verdict[side] = (len(seen) >= 2 and _same_space(seen, tol)) or (len(bases) >= 2 and not seen)
        out[b.name] = ("both" if verdict["left"] and verdict["right"] else "left" if verdict["left"]
                       else "right" if verdict["right"] else "neither")
    return out


def natural_error(system) -> str:
    """``"right"`` where some sensor of ``system`` observes fixed directions of the right error only and none
    observes fixed directions of the left error only (:func:`invariant_sides`); ``"left"`` otherwise, and for a
    system that is not a :class:`SensorSystem` (the papers' systems, whose filters the papers write in the left
    error). The side a filter's ``error="auto"`` takes."""
    if not isinstance(system, SensorSystem) or isinstance(system, RightErrorSystem):
        return "left"
    # the verdict depends on the group and the output functions only: kept per (group, functions), as a new
    # weight set of the same system must not measure again
    key = (system.group, tuple((s.name, _hashable(s.fn), s.residual) for s in system.sensors))
    try:
        cached = _NATURAL.get(key)
    except TypeError:  # an output function that cannot be hashed: measured each time
        key = cached = None
    if cached is None:
        sides = set(invariant_sides(system).values())
        cached = "right" if "right" in sides and "left" not in sides else "left"
        if key is not None:
            if len(_NATURAL) >= _NATURAL_MAX:  # the oldest verdict goes (the keys hold the output functions)
                _NATURAL.pop(next(iter(_NATURAL)))
            _NATURAL[key] = cached
    return cached


def _hashable(fn):
    """A key of an output function: the function itself, or for a parameterized one (an ``eqx.Module`` with array
    fields) its structure and its arrays' bytes (the verdict may depend on a direction's value)."""
    arrays, rest = eqx.partition(fn, eqx.is_array)
    leaves = jax.tree_util.tree_leaves(arrays)
    if not leaves:
        return fn
    return rest, tuple((np.asarray(x).tobytes(), np.shape(x)) for x in leaves)


_NATURAL: dict = {}
_NATURAL_MAX = 256


def right_error(system: SensorSystem) -> RightErrorSystem:
    """``system`` with its state inverted, so that a filter of it keeps the right error of ``system`` (module
    docstring). ValueError for anything but a :class:`SensorSystem`."""
    return RightErrorSystem(system)


__all__ = ["RightErrorSystem", "right_error", "invariant_sides", "natural_error"]
