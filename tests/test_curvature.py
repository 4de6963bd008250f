"""The safe curvature (``curvature="safe"``, docs/theorem.md "When the second-order terms are unsafe"): the
output's residual-weighted Hessian kept on the directions the outputs observe, with E positive semidefinite."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from liemef import MinimumEnergyFilter
from liemef.filters import Weights, information_in_force, safe_curvature, terms
from liemef.studies.experiments import tse2
from tolerances import ROUNDOFF

jax.config.update("jax_enable_x64", True)


def test_safe_curvature_keeps_observed_directions_and_a_semidefinite_information():
    """G observes the first two of three directions; C couples the first with the third (unobserved) and is
    strongly negative on the second: the safe curvature has nothing on the third direction, G + C_safe is
    positive semidefinite, and where G is nonsingular and G + C is definite the exact C comes back bit for bit."""
    G = np.diag([4.0, 1.0, 0.0])
    C = np.array([[0.5, 0.0, 0.7], [0.0, -3.0, 0.0], [0.7, 0.0, 0.2]])
    C_safe, modified = safe_curvature(jnp.asarray(G), jnp.asarray(C))
    C_safe = np.asarray(C_safe)
    assert bool(modified)
    np.testing.assert_allclose(C_safe[2], 0.0, atol=ROUNDOFF)
    np.testing.assert_allclose(C_safe[:, 2], 0.0, atol=ROUNDOFF)
    np.testing.assert_allclose(C_safe[0, 0], 0.5, atol=ROUNDOFF)       # the observed curvature, kept
    np.testing.assert_allclose(C_safe[1, 1], -1.0, atol=ROUNDOFF)      # clipped: the information there is 0
    assert np.linalg.eigvalsh(G + C_safe).min() > -ROUNDOFF
    G2 = np.array([[3.0, 0.4, 0.1], [0.4, 2.0, 0.3], [0.1, 0.3, 1.5]])
    C2 = np.array([[-0.5, 0.2, 0.0], [0.2, 0.3, -0.1], [0.0, -0.1, -0.4]])
    out, modified = safe_curvature(jnp.asarray(G2), jnp.asarray(C2))
    assert not bool(modified)
    assert np.array_equal(np.asarray(out), C2)


def test_the_rule_acts_on_about_half_of_the_papers_tse2_states():
    """On the planar rigid body's paper run (printed weights, 10 s), E is indefinite at about half of the states:
    ``curvature="safe"`` is another filter there, which is why the reproductions use ``"exact"`` (the number is
    docs/theorem.md's). Wherever the rule acts, E_safe is positive semidefinite and has the exact E's
    Gauss-Newton part; ``terms()`` shows it."""
    s = tse2.setup(tse2.TSE2Config(duration=10.0))
    _, log, traj = tse2.trial(s, jax.random.key(0))
    flt = s.filter
    assert flt.curvature == "exact"
    ts = np.asarray(log.ts)
    dt = float(ts[1] - ts[0])
    pick = np.arange(0, len(ts) - 1, 10)
    Wy = information_in_force(flt.weights.Wy, np.asarray(flt.sample, bool), np.ones(7, bool), dt,
                              diagonal=flt.diagonal)
    weights = Weights(Wy=Wy, BRB=flt.weights.BRB)

    def at(k, safe):
        g = jax.tree_util.tree_map(lambda a: a[k], traj.g_hat)
        return terms(flt.system, weights, flt.connection, True, g, traj.K[k], jnp.asarray(log.us)[k],
                     jnp.asarray(log.ys)[k], jnp.asarray(ts)[k], True, safe)

    exact = jax.vmap(lambda k: at(k, False))(jnp.asarray(pick))
    safe = jax.vmap(lambda k: at(k, True))(jnp.asarray(pick))
    modified = np.asarray(safe.modified)
    indefinite = np.linalg.eigvalsh(np.asarray(exact.E)).min(axis=1) < 0
    assert 0.4 < modified.mean() < 0.65, modified.mean()
    assert np.array_equal(modified, indefinite)   # E1 has full rank here: the rule acts where E < 0
    assert np.linalg.eigvalsh(np.asarray(safe.E)).min() > -ROUNDOFF * np.abs(np.asarray(safe.E)).max()
    assert np.array_equal(np.asarray(safe.E)[~modified], np.asarray(exact.E)[~modified])
    flt_safe = MinimumEnergyFilter(flt.system, curvature="safe")
    k = int(pick[np.argmax(modified)])
    g = jax.tree_util.tree_map(lambda a: a[k], traj.g_hat)
    shown = flt_safe.terms(g, np.asarray(traj.K[k]), np.asarray(log.us[k]), np.asarray(log.ys[k]), float(ts[k]))
    assert bool(shown.modified)
