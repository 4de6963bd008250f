r"""Lie-group time integrators for $\dot g = g\,\xi(g, v, t)$ coupled with a vector-space state $\dot v = L(g, v, t)$.

The filter integrates $(\hat g, K)$; the truth simulation integrates $g$ alone (``v = ()``). Each integrator
declares its ``order``, which ``tests/test_integrators.py`` checks by the convergence slope.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar

import equinox as eqx
import jax

from . import _names
from ._linalg import mv
from .groups import LieGroup

VectorField = Callable[[LieGroup, Any, Any], tuple[Any, Any]]
"""``f(g, v, t) -> (xi, v_dot)``: left-trivialized velocity of g and time derivative of the pytree v."""


def _axpy(a, x, y):
    return jax.tree_util.tree_map(lambda xi, yi: yi + a * xi, x, y)


class AbstractIntegrator(eqx.Module):
    """One step ``(g, v) -> (g', v')`` of size ``dt`` from time ``t``; ``order`` is the global order."""

    order: eqx.AbstractClassVar[int]
    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def step(self, f: VectorField, g: LieGroup, v: Any, t, dt, first=None) -> tuple[LieGroup, Any]:
        """Advance one step; ``first`` is ``f(g, v, t)`` when the caller has it already."""


class LieEuler(AbstractIntegrator):
    r"""Lie-Euler: $g \leftarrow g \exp(h\,\xi)$, $v \leftarrow v + h L$."""

    order: ClassVar[int] = 1
    name: ClassVar[str] = "lie-euler"

    def step(self, f, g, v, t, dt, first=None):
        """One Lie-Euler step."""
        xi, L = f(g, v, t) if first is None else first
        return g.rplus(dt * xi), _axpy(dt, L, v)


class RKMK2(AbstractIntegrator):
    r"""The explicit midpoint rule of Runge-Kutta-Munthe-Kaas, order 2 (Iserles et al. 2000, Sec. 4): a half
    step $g_{1/2} = g \exp(\tfrac h2 \xi_1)$, $v_{1/2} = v + \tfrac h2 L_1$, then
    $g \leftarrow g \exp(h\,\xi_{1/2})$, $v \leftarrow v + h L_{1/2}$ with $(\xi_{1/2}, L_{1/2})$ the field
    there. At order 2 the $\mathrm{dexp}^{-1}$ series contributes nothing beyond $\xi$ itself. Two evaluations of
    the field a step against RKMK4's four: on a high-rate IMU, whose step is a sample interval of a few
    milliseconds, its estimate is RKMK4's to well below the sensors' noise, at less cost (docs/performance.md)."""

    order: ClassVar[int] = 2
    name: ClassVar[str] = "rkmk2"

    def step(self, f, g, v, t, dt, first=None):
        """One explicit-midpoint RKMK step."""
        xi1, L1 = f(g, v, t) if first is None else first
        xi2, L2 = f(g.rplus(0.5 * dt * xi1), _axpy(0.5 * dt, L1, v), t + 0.5 * dt)
        return g.rplus(dt * xi2), _axpy(dt, L2, v)


class RKMK4(AbstractIntegrator):
    r"""Classical 4th-order Runge-Kutta-Munthe-Kaas (Munthe-Kaas 1999; Iserles et al. 2000, Sec. 4).

    With $g = g_0 \exp\theta$ the body-frame velocity satisfies $\dot\theta = \mathrm{dexp}^{-1}_{-\theta}\xi =
    \xi + \tfrac12 [\theta, \xi] + \tfrac1{12} [\theta, [\theta, \xi]] + O(\theta^4)$; RK4 is applied to
    $(\theta, v)$ from $\theta = 0$, with that series truncated as order 4 allows.
    """

    order: ClassVar[int] = 4
    name: ClassVar[str] = "rkmk4"

    def step(self, f, g, v, t, dt, first=None):
        """One RKMK4 step."""
        G = type(g)

        def dexpinv(theta, xi):
            ad = G.ad(theta)
            a1 = mv(ad, xi)
            return xi + 0.5 * a1 + mv(ad, a1) / 12.0

        xi1, L1 = f(g, v, t) if first is None else first
        k1 = dt * xi1
        xi2, L2 = f(g.rplus(0.5 * k1), _axpy(0.5 * dt, L1, v), t + 0.5 * dt)
        k2 = dt * dexpinv(0.5 * k1, xi2)
        xi3, L3 = f(g.rplus(0.5 * k2), _axpy(0.5 * dt, L2, v), t + 0.5 * dt)
        k3 = dt * dexpinv(0.5 * k2, xi3)
        xi4, L4 = f(g.rplus(k3), _axpy(dt, L3, v), t + dt)
        k4 = dt * dexpinv(k3, xi4)
        theta = (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        L = jax.tree_util.tree_map(lambda a, b, c, d: (a + 2.0 * b + 2.0 * c + d) / 6.0, L1, L2, L3, L4)
        return g.rplus(theta), _axpy(dt, L, v)


_OWN = {cls.name: cls for cls in (LieEuler, RKMK2, RKMK4)}
INTEGRATORS: dict[str, type[AbstractIntegrator]] = {**{name: _OWN[name] for name in _names.INTEGRATORS},
                                                    "euler": LieEuler, "midpoint": RKMK2, "rk4": RKMK4}
"""Every integrator by its own name (:data:`liemef._names.INTEGRATORS`, the command line's choices), then by its
alias."""


def integrator(spec: str | AbstractIntegrator) -> AbstractIntegrator:
    """An integrator from its name (``"rkmk4"``/``"rk4"``, ``"rkmk2"``/``"midpoint"``, ``"lie-euler"``/``"euler"``)
    or itself."""
    if isinstance(spec, AbstractIntegrator):
        return spec
    if spec not in INTEGRATORS:
        raise ValueError(f"integrator: expected one of {sorted(INTEGRATORS)}, got {spec!r}")
    return INTEGRATORS[spec]()


