r"""Left-trivialized derivatives at the estimate, by autodiff through $\xi \mapsto g\exp(\xi)$ at $\xi = 0$.

For $F(\xi) = f(g \exp \xi)$: the differential is ``jacfwd(F)(0)`` (column j = direction $e_j$) and the autodiff
Hessian of F at 0 is the symmetric (0)-connection Hessian, since by Baker-Campbell-Hausdorff
$\partial_s\partial_t f(g e^{sX} e^{tY}) = D^2F(X, Y) + \tfrac12 DF\,[X, Y]$. The connection Hessian of any other
connection adds a term linear in $DF$ (:meth:`liemef.connections.Connection.hessian_correction`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..groups import LieGroup


def left_jacobian(f: Callable[[LieGroup], Array], g: LieGroup) -> tuple[Array, Array]:
    r"""Value and left-trivialized Jacobian of ``f`` at ``g``: ``J[:, j] = d/ds f(g exp(s e_j))`` at 0."""
    zero = jnp.zeros(type(g).tangent_dim)
    F = lambda xi: f(g.rplus(xi))  # noqa: E731
    return F(zero), jax.jacfwd(F)(zero)


def left_hessian(f: Callable[[LieGroup], Float[Array, ""]], g: LieGroup) -> Float[Array, "n n"]:
    r"""Symmetric Hessian of the scalar $\xi \mapsto f(g\exp\xi)$ at 0 (the (0)-connection Hessian of f)."""
    zero = jnp.zeros(type(g).tangent_dim)
    return jax.hessian(lambda xi: f(g.rplus(xi)))(zero)


_CALLS = ("pjit", "jit", "closed_call", "core_call", "remat", "remat2", "checkpoint")


def _state_while(jaxpr, tainted: set, within: tuple = ()):
    """The first ``while`` equation of ``jaxpr`` whose body or carry depends on the variables ``tainted`` (the
    state's: reverse mode then differentiates through it), with the equations around it, innermost first;
    else None. A ``while`` that the state enters only through its test, through integers or through a
    ``stop_gradient`` (``MatrixGroup.log``'s start) is not differentiated, nor the primal of a custom derivative
    rule (the rule is)."""
    from jax.extend import core as jcore

    def hot(v):
        return not isinstance(v, jcore.Literal) and v in tainted

    for eqn in jaxpr.eqns:
        name, params = eqn.primitive.name, eqn.params
        ins = [hot(v) for v in eqn.invars]
        if name == "while":
            if any(ins[params["cond_nconsts"]:]):
                return eqn, within
            subs = []  # the state enters its test alone: nothing in it is differentiated
        elif name in _CALLS:
            sub = params.get("jaxpr", params.get("call_jaxpr"))
            sub = getattr(sub, "jaxpr", sub)
            subs = [(sub, ins[len(ins) - len(sub.invars):])]
        elif name == "cond":
            subs = [(br.jaxpr, ins[1:]) for br in params["branches"]]
        elif name == "scan":  # a carry may take the state on at any iteration: every input as hot as any
            subs = [(params["jaxpr"].jaxpr, [any(ins)] * len(ins))]
        else:
            subs = []
        for sub, hot_in in subs:
            found = _state_while(sub, {v for v, h in zip(sub.invars, hot_in, strict=True) if h}, (eqn, *within))
            if found is not None:
                return found
        if any(ins) and name != "stop_gradient":  # integers and booleans carry no derivative
            tainted.update(v for v in eqn.outvars if jnp.issubdtype(v.aval.dtype, jnp.inexact))
    return None


def refuse_state_while(what: str, fn: Callable[[LieGroup], Array], g: LieGroup) -> None:
    """ValueError if ``fn(g)`` (an output map, which the second-order filter differentiates twice) loops with
    ``lax.while_loop`` on the state: ``jax.hessian`` is reverse mode over forward mode, and JAX cannot
    differentiate a while loop in reverse mode (it raises from deep inside the filter's trace). ``what`` names
    the map in the message, which gives the line of the user's code that made the loop."""
    from .._frames import eqn_frames, user_frame

    closed = jax.make_jaxpr(fn)(g)
    found = _state_while(closed.jaxpr, set(closed.jaxpr.invars))
    if found is None:
        return
    eqn, within = found
    where = user_frame([f for e in (eqn, *within) for f in eqn_frames(e)])
    raise ValueError(
        f"{what}: expected a map JAX can differentiate twice, got a lax.while_loop on the state"
        + (f" (at {where})" if where else "")
        + ": the second-order filter takes its Hessian (jax.hessian, reverse mode), which JAX cannot take through "
          "a while_loop. Use lax.fori_loop with Python int bounds (a fixed number of iterations: JAX makes it a "
          "scan, which it differentiates) or a closed form; or order=\"first\", which differentiates the output "
          "once")


def refuse_state_while_in_outputs(system) -> None:
    """:func:`refuse_state_while` for each output map of ``system`` the second-order filter differentiates
    twice: each sensor's ``h(g, t)`` with its residual (named by the sensor), else the system's output."""
    from ..systems import SensorSystem

    g = system.group.identity()
    if not isinstance(system, SensorSystem):
        y = jnp.zeros(system.output_dim)
        refuse_state_while("output h(g, t)", lambda gg: system.output_seen_from(y, gg, 0.0), g)
        return
    for s in system.sensors:
        if s.residual is None:
            fn = lambda gg, s=s: s.fn(gg, 0.0)  # noqa: E731
        else:
            fn = lambda gg, s=s: s.residual(jnp.zeros(s.dim), jnp.atleast_1d(s.fn(gg, 0.0)))  # noqa: E731
        refuse_state_while(f"sensor {s.name!r}: h(g, t)", fn, g)
