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


def test_safe_curvature_keeps_only_a_curvature_between_minus_G_and_zero():
    """G observes the first two of three directions. A C that only lowers the observed information, never below
    zero, comes back bit for bit; one that couples an observed direction with the unobserved one, adds to G, or
    takes more than all of G's information is dropped (the Gauss-Newton information, zeros)."""
    G = np.diag([4.0, 1.0, 0.0])
    inside = np.array([[-1.0, 0.3, 0.0], [0.3, -0.5, 0.0], [0.0, 0.0, 0.0]])
    out, modified = safe_curvature(jnp.asarray(G), jnp.asarray(inside))
    assert not bool(modified) and np.array_equal(np.asarray(out), inside)
    for C in (np.array([[-1.0, 0.0, 0.2], [0.0, -0.5, 0.0], [0.2, 0.0, 0.0]]),   # onto the unobserved direction
              np.array([[0.5, 0.0, 0.0], [0.0, -0.5, 0.0], [0.0, 0.0, 0.0]]),    # adds information
              np.array([[-1.0, 0.0, 0.0], [0.0, -3.0, 0.0], [0.0, 0.0, 0.0]])):  # takes more than there is
        out, modified = safe_curvature(jnp.asarray(G), jnp.asarray(C))
        assert bool(modified), C
        assert np.array_equal(np.asarray(out), np.zeros((3, 3)))
    G2 = np.array([[3.0, 0.4, 0.1], [0.4, 2.0, 0.3], [0.1, 0.3, 1.5]])
    C2 = -0.5 * G2 - np.array([[0.2, 0.05, 0.0], [0.05, 0.1, 0.02], [0.0, 0.02, 0.1]])
    out, modified = safe_curvature(jnp.asarray(G2), jnp.asarray(C2))
    assert not bool(modified)
    assert np.array_equal(np.asarray(out), C2)


def test_the_rule_acts_on_most_of_the_papers_tse2_states():
    """On the planar rigid body's paper run (printed weights, 10 s), the curvature is outside [-G, 0] at most
    states (E is indefinite at about half of them): ``curvature="safe"`` is another filter there, which is why
    the reproductions use ``"exact"`` (the numbers are docs/theorem.md's). Wherever the rule acts, E_safe lies
    between 0 and the Gauss-Newton part; ``terms()`` shows it."""
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
    assert 0.4 < indefinite.mean() < 0.65, indefinite.mean()
    assert modified.mean() > 0.9, modified.mean()
    assert np.all(modified[indefinite])       # E1 has full rank here: every indefinite E is modified
    E_safe = np.asarray(safe.E)
    G = np.einsum("kpi,pq,kqj->kij", np.asarray(safe.Dh), np.asarray(Wy), np.asarray(safe.Dh))
    scale = np.abs(E_safe).max()
    assert np.linalg.eigvalsh(E_safe).min() > -ROUNDOFF * scale
    assert np.linalg.eigvalsh(G - E_safe).min() > -1e-10 * scale
    assert np.array_equal(np.asarray(safe.E)[~modified], np.asarray(exact.E)[~modified])
    flt_safe = MinimumEnergyFilter(flt.system, curvature="safe")
    k = int(pick[np.argmax(modified)])
    g = jax.tree_util.tree_map(lambda a: a[k], traj.g_hat)
    shown = flt_safe.terms(g, np.asarray(traj.K[k]), np.asarray(log.us[k]), np.asarray(log.ys[k]), float(ts[k]))
    assert bool(shown.modified)
