"""The translator's NumPy versions of data-moving primitives (``codegen._primitives.np_eval``) against XLA's.

The translator moves element ids and folds constants through these instead of an eager JAX call (whose first
call compiles an XLA executable: 0.35 s of a first build for one ``scatter``). Each must give XLA's result
exactly where it answers, and answer None (XLA then decides) where it does not cover the case.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend import core as jcore

from liemef.codegen._primitives import np_eval


def _scatters(f, *args):
    """The scatter equations of ``f``'s jaxpr on ``args``, with their operands' values (all known here)."""
    closed = jax.make_jaxpr(f)(*args)
    env = {v: np.asarray(a) for v, a in zip(closed.jaxpr.invars, args, strict=True)}
    env.update({v: np.asarray(c) for v, c in zip(closed.jaxpr.constvars, closed.consts, strict=True)})
    found = []
    for eqn in closed.jaxpr.eqns:
        xs = [np.asarray(a.val) if isinstance(a, jcore.Literal) else env[a] for a in eqn.invars]
        outs = eqn.primitive.bind(*xs, **eqn.params)
        outs = outs if eqn.primitive.multiple_results else [outs]
        if eqn.primitive.name == "scatter":
            found.append((eqn, xs, np.asarray(outs[0])))
        env.update({v: np.asarray(o) for v, o in zip(eqn.outvars, outs, strict=True)})
    return found


WINDOWS = {
    "block": lambda x, u: x.at[2:5, 1:4].set(u[:3, :3]),
    "row": lambda x, u: x.at[4].set(jnp.tile(u[0], 2)),
    "column_part": lambda x, u: x.at[1:4, 5].set(u[:3, 0]),
    "element": lambda x, u: x.at[3, 2].set(u[1, 1]),
    "corner": lambda x, u: x.at[3:, 3:].set(u),
}


@pytest.mark.parametrize("case", sorted(WINDOWS))
def test_scatter_window_equals_xla(case):
    rng = np.random.default_rng(7)
    x, u = rng.normal(size=(6, 6)), rng.normal(size=(3, 3))
    found = _scatters(WINDOWS[case], x, u)
    assert found, f"{case}: no scatter in the jaxpr"
    for eqn, xs, want in found:
        got = np_eval("scatter", eqn.params, xs, [want.dtype])
        assert got is not None, f"{case}: the NumPy scatter declined a window inside the operand"
        np.testing.assert_array_equal(got[0], want)
        assert got[0].dtype == want.dtype and got[0].shape == want.shape


def test_scatter_window_declines_what_it_does_not_cover():
    x, u = np.zeros((6, 6)), np.ones((3, 3))
    (eqn, xs, _), = _scatters(lambda x, u: x.at[2:5, 1:4].set(u), x, u)
    # the same window at an index where it does not fit (XLA's modes decide: drop or clamp)
    outside = [xs[0], np.array([4, 1], xs[1].dtype), xs[2]]
    assert np_eval("scatter", eqn.params, outside, [np.float64]) is None
    negative = [xs[0], np.array([-1, 1], xs[1].dtype), xs[2]]
    assert np_eval("scatter", eqn.params, negative, [np.float64]) is None
    # several index vectors at once (scatter dims in the updates)
    (eqn, xs, want), = _scatters(lambda x, u: x.at[jnp.array([0, 2, 5])].set(u[:, 0]), np.zeros(6), u)
    assert np_eval("scatter", eqn.params, xs, [np.float64]) is None
