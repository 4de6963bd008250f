r"""How one sample interval is cut into integrator steps: the sub-step controllers.

A controller is an object of its own beside the filter (as diffrax's step-size controllers sit beside its
solvers): given the interval's vector field it integrates ``[t, t + dt]`` and says how many steps it took.

* :class:`AdaptiveSubsteps` (the filter's ``substeps="auto"``): each step's size comes from the stiffness where
  it starts, $h = \min(\text{rest}, 1/\rho)$ with :func:`stiffness_rate` $\rho$, so an impulsive sample with a
  large K takes small steps while K shrinks, then larger ones (a number of steps logarithmic, not linear, in
  $\|K E\| \Delta$). The last allowed step (``max_substeps``) finishes the interval, and says it was forced.
* :class:`FixedSubsteps` (``substeps=N``): N equal steps (1: the papers' scheme).

The field is given as ``f(g, K, tau) -> (xi, K_dot)`` and ``field_and_rate(g, K, tau) -> ((xi, K_dot), rate,
skew)``, ``skew`` the filter's verdict at the interval's start that E is not symmetric where K must stay so.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp

from .._linalg import mm

KE_BUDGET, A_BUDGET, XI_BUDGET = 0.5, 0.5, 0.5
r"""Sub-step budget per unit of stiffness (docs/weights.md): $\|K E\| h$, $\|A\| h$ and the group step $\|\xi\| h$."""


def stiffness_rate(E, A, K, xi):
    r"""The stiffness rate $\rho = \max(\|E K\|/b_{KE}, \|A\|/b_A, \|\xi\|/b_\xi)$ (Frobenius norms, the budgets
    :data:`KE_BUDGET`, ...), so that a step $h = 1/\rho$ keeps each product within its budget. Not finite where
    the terms are not: the caller gives the controller 0 there (the health check then fails the interval).
    $\|K E\|$ is taken as $\|E K\|$: equal for a symmetric K and E, and E K is the Riccati term's own product."""
    fro = lambda M: jnp.sqrt(jnp.sum(M * M))  # noqa: E731
    return jnp.maximum(jnp.maximum(fro(mm(E, K)) / KE_BUDGET, fro(A) / A_BUDGET), jnp.linalg.norm(xi) / XI_BUDGET)


class AbstractSubsteps(eqx.Module):
    """A sub-step controller: :meth:`integrate` one interval."""

    @abc.abstractmethod
    def integrate(self, integrator, f, field_and_rate, g, K, t, dt):
        """``(g1, K1, n_sub, capped, skew)``: the state at ``t + dt`` from ``(g, K)`` at ``t``, by steps of
        ``integrator``; the number of steps (int32), whether the last was forced (the cap), and ``skew`` at the
        interval's start."""


class AdaptiveSubsteps(AbstractSubsteps):
    """Steps sized by the stiffness where each starts, at most ``max_substeps`` (the last one finishes)."""

    max_substeps: int = eqx.field(static=True)

    def integrate(self, integrator, f, field_and_rate, g, K, t, dt):
        """One interval in adaptive steps (module docstring)."""
        def sub(c):
            gg, KK, done, j, _, skew = c
            first, rate, skew_here = field_and_rate(gg, KK, t + done)
            left = dt - done
            forced = (j + 1 >= self.max_substeps) & (rate * left > 1.0)  # the cap: finish, though stiff
            last = forced | (rate * left <= 1.0)
            h = jnp.where(last, left, 1.0 / rate)
            g2, K2 = integrator.step(f, gg, KK, t + done, h, first=first)
            return g2, K2, jnp.where(last, dt, done + h), j + 1, forced, jnp.where(j == 0, skew_here, skew)

        # one integrator step in the program, in the loop (which runs once where the interval is not stiff): half
        # the code of a first step taken outside it, for XLA to compile and in exported C
        g1, K1, _, n_sub, capped, skew = jax.lax.while_loop(
            lambda c: c[2] < dt, sub, (g, K, jnp.zeros_like(dt), jnp.asarray(0, jnp.int32), jnp.asarray(False),
                                       jnp.asarray(False)))
        return g1, K1, n_sub, capped, skew


class FixedSubsteps(AbstractSubsteps):
    """``n`` equal steps per interval."""

    n: int = eqx.field(static=True)

    def integrate(self, integrator, f, field_and_rate, g, K, t, dt):
        """One interval in ``n`` equal steps."""
        h = dt / self.n
        first, _, skew = field_and_rate(g, K, t)
        g1, K1 = integrator.step(f, g, K, t, h, first=first)
        if self.n > 1:
            g1, K1 = jax.lax.fori_loop(1, self.n, lambda j, gK: integrator.step(f, *gK, t + j * h, h), (g1, K1))
        return g1, K1, jnp.asarray(self.n, jnp.int32), jnp.asarray(False), skew


def substep_controller(substeps: str | int, max_substeps: int) -> AbstractSubsteps:
    """The controller of a filter's ``substeps`` option: ``"auto"`` or a number of equal steps."""
    return AdaptiveSubsteps(max_substeps) if substeps == "auto" else FixedSubsteps(substeps)
