"""The hand-written C99 reference of the benchmark (``benchmarks/c/tse2_reference.c``, issue 9) against liemef.

The C step is built from the closed forms of Rigo et al. 2022 (with Theorem 4.1's symmetric E); liemef's filter
differentiates the model by autodiff. On the benchmark scenario (Rigo et al. 2022, Sec. VI: 2 s at 1 ms) the two
trajectories must agree to round-off for both integrators, so that the benchmark's ratios compare the same
computation.
"""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef.simulation import simulate
from liemef.systems import PlanarRigidBody, tse2_state

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import c_reference  # noqa: E402

C_REFERENCE = 1e-10
"""Relative deviation, per sample, of the C trajectory from liemef's over 2000 steps: the same arithmetic in a
different order (measured 2e-15 for both integrators; the filter contracts errors, so round-off does not grow)."""
STEPS = 2000

pytestmark = pytest.mark.skipif(c_reference.compiler() is None, reason="no C compiler ($CC or cc)")


def _tse2_input(t):
    # Rigo et al. 2022, Sec. VI: u = (u_omega, u_v) = (sin t, 50 sin(t / 50)), as benchmarks/bench_tse2.py
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    system = PlanarRigidBody()
    ts = np.arange(STEPS + 1) * 1e-3
    _, log = simulate(system, tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0), _tse2_input, ts, jax.random.PRNGKey(0))
    lib = c_reference.build(tmp_path_factory.mktemp("c_reference"))
    return system, lib, np.asarray(log.ts), np.asarray(log.us), np.asarray(log.ys)


def _rel_dev(got, want):
    """Largest deviation per sample over the sample's largest entry."""
    got, want = got.reshape(len(got), -1), want.reshape(len(want), -1)
    return float((np.abs(got - want).max(axis=1) / np.abs(want).max(axis=1)).max())


@pytest.mark.parametrize("integrator", ["rkmk4", "lie-euler"])
def test_c_reference_reproduces_the_filter_run(scenario, integrator):
    system, lib, ts, us, ys = scenario
    flt = liemef.MinimumEnergyFilter(system, curvature="exact", connection="zero", order="second",
                                     integrator=integrator, alpha=0.0, substeps=1)
    g0 = tse2_state(np.pi / 8, 1.1, 2.1, 0.1, -0.1, -0.1)
    traj = flt.run(flt.init(g0, np.eye(6)), ts, us, ys)
    assert bool(traj.ok)
    g_want = np.concatenate([np.asarray(traj.g_hat.factors[0].cos_sin_xy), np.asarray(traj.g_hat.factors[1].x)],
                            axis=1)
    K_want = np.asarray(traj.K)

    g_got, K_got = c_reference.run(lib, integrator, ts, us, ys, g0, np.eye(6))

    assert g_got.shape == (STEPS + 1, 7) and K_got.shape == (STEPS + 1, 6, 6)
    np.testing.assert_array_equal(g_got[0], g_want[0])
    dev_g, dev_K = _rel_dev(g_got, g_want), _rel_dev(K_got, K_want)
    assert dev_g <= C_REFERENCE, f"{integrator}: estimate deviates by {dev_g:.3g}"
    assert dev_K <= C_REFERENCE, f"{integrator}: gain deviates by {dev_K:.3g}"
    # the run moved: the comparison is not of two copies of the initial state
    assert np.abs(K_want[-1] - np.eye(6)).max() > 0.1


def test_c_reference_rejects_an_unknown_integrator(scenario):
    _, lib, ts, us, ys = scenario
    with pytest.raises(ValueError, match="integrator"):
        c_reference.run(lib, "rk45", ts, us, ys, np.zeros(7), np.eye(6))
