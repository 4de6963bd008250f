"""Truth and sensor simulation: noise statistics with fixed seeds, reproducibility, the noise-free truth
against an independent ODE solution in coordinates, and vmap over keys."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from liemef.simulation import SensorLog, Truth, simulate, simulate_core
from liemef.systems import PlanarRigidBody, tse2_state
from tolerances import ODE_REFERENCE, ROUNDOFF

MC_SIGMAS = 5.0
"""Monte Carlo band: a sample statistic must lie within 5 standard errors of its exact value (a false alarm
has probability below 1e-6 per check, and the seeds are fixed)."""

SYSTEM = PlanarRigidBody()
G0 = tse2_state(np.pi / 6, 1.0, 2.0, 0.0, 0.0, 0.0)


def paper_input(t):
    return jnp.stack([jnp.sin(t), 50.0 * jnp.sin(t / 50.0)])


def fast_input(t):
    """A livelier input than the paper's, so that the ODE comparison exercises every term."""
    return jnp.stack([3.0 * jnp.sin(2.0 * t), 200.0 * jnp.cos(1.5 * t)])


def grid(T, dt):
    return np.arange(int(round(T / dt)) + 1) * dt


# --- noise statistics
def test_measurement_noise_has_the_std_of_D():
    ts = grid(20.0, 1e-3)
    truth, log = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(7))
    res = np.asarray(log.ys - jax.vmap(SYSTEM.output)(truth.g, truth.ts))
    d = np.diag(np.asarray(SYSTEM.D))  # (0.5 x4, 0.1 x3)
    N = res.shape[0]
    # std of a sample std is sigma / sqrt(2N); of a sample mean sigma / sqrt(N)
    np.testing.assert_array_less(np.abs(res.std(axis=0) / d - 1.0), MC_SIGMAS / np.sqrt(2 * N))
    np.testing.assert_array_less(np.abs(res.mean(axis=0)) / d, MC_SIGMAS / np.sqrt(N))
    # independent channels: correlation coefficients have std 1/sqrt(N)
    corr = np.corrcoef(res.T) - np.eye(7)
    assert np.abs(corr).max() < MC_SIGMAS / np.sqrt(N)


def test_input_noise_statistics_and_truth_uses_the_nominal_input():
    ts = grid(20.0, 1e-3)
    Nu = np.array([[0.2, 0.0], [0.0, 3.0]])
    truth, log = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(3), input_noise=Nu)
    np.testing.assert_allclose(truth.u, jax.vmap(paper_input)(jnp.asarray(ts)), rtol=0, atol=ROUNDOFF)
    noise = np.asarray(log.us - truth.u)
    N = noise.shape[0]
    np.testing.assert_array_less(np.abs(noise.std(axis=0) / np.diag(Nu) - 1.0), MC_SIGMAS / np.sqrt(2 * N))
    # the truth does not see the input noise
    truth0, _ = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(3))
    np.testing.assert_array_equal(truth.coords(), truth0.coords())


def test_model_error_is_a_per_step_draw_of_the_stated_std():
    # omega_dot = u_w / J + b delta_1 (B2 = 0.1 I): RKMK4 integrates the held right-hand side exactly, so the
    # difference of omega with and without model error (same key) has increments h b delta_1.
    ts, sigma, b = grid(20.0, 1e-3), 2.0, 0.1
    t1, _ = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(5), model_error_std=sigma)
    t0, _ = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(5))
    delta1 = np.diff(np.asarray(t1.coords()[:, 3] - t0.coords()[:, 3])) / (1e-3 * b)
    N = delta1.shape[0]
    assert abs(delta1.std() / sigma - 1.0) < MC_SIGMAS / np.sqrt(2 * N)
    assert abs(delta1.mean()) / sigma < MC_SIGMAS / np.sqrt(N)


def test_model_error_does_not_change_the_measurement_noise_draws():
    ts = grid(1.0, 1e-2)
    t1, l1 = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(4), model_error_std=1.0)
    t0, l0 = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(4))
    e1 = l1.ys - jax.vmap(SYSTEM.output)(t1.g, t1.ts)
    e0 = l0.ys - jax.vmap(SYSTEM.output)(t0.g, t0.ts)
    np.testing.assert_allclose(e1, e0, rtol=0, atol=ROUNDOFF * 100)


# --- reproducibility
def test_same_key_same_result_different_key_different_result():
    ts = grid(2.0, 1e-3)
    kw = dict(model_error_std=0.5, input_noise=0.1 * np.eye(2))
    ta, la = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(11), **kw)
    tb, lb = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(11), **kw)
    tc, lc = simulate(SYSTEM, G0, paper_input, ts, jax.random.key(12), **kw)
    for x, y in ((ta.coords(), tb.coords()), (la.ys, lb.ys), (la.us, lb.us)):
        np.testing.assert_array_equal(x, y)
    assert np.abs(np.asarray(la.ys - lc.ys)).min() > 0  # every sample differs
    assert np.abs(np.asarray(la.us - lc.us)).min() > 0
    assert np.abs(np.asarray(ta.coords()[-1] - tc.coords()[-1])).min() > 0


def test_vmap_over_keys_matches_single_runs():
    ts = jnp.asarray(grid(0.5, 1e-3))
    keys = jax.random.split(jax.random.key(0), 3)
    batch = jax.jit(jax.vmap(lambda k: simulate_core(SYSTEM, G0, paper_input, ts, k, 0.3)))(keys)
    truth, log = batch
    assert isinstance(truth, Truth) and isinstance(log, SensorLog)
    assert truth.g.batch_shape == (3, ts.shape[0]) and log.ys.shape == (3, ts.shape[0], 7)
    for i in range(3):
        t1, l1 = simulate(SYSTEM, G0, paper_input, ts, keys[i], model_error_std=0.3)
        np.testing.assert_allclose(truth.coords()[i], t1.coords(), rtol=0, atol=ROUNDOFF)
        np.testing.assert_allclose(log.ys[i], l1.ys, rtol=0, atol=ROUNDOFF)


# --- the noise-free truth against scipy
def tse2_ode(t, q, u, J, m):
    """TSE(2) in coordinates (Rigo et al. 2022, componentwise form of eq. (4)), written independently."""
    th, x, y, w, vx, vy = q
    c, s = np.cos(th), np.sin(th)
    return [w, vx * c - vy * s, vx * s + vy * c, u[0] / J, w * vy + u[1] / m, -w * vx]


def reference_solution(q0, ts, substeps, input_fn):
    """solve_ivp (rtol 1e-12) over each truth step with the input held at its value at the step start."""
    q, out = np.asarray(q0, dtype=float), [np.asarray(q0, dtype=float)]
    for t0, t1 in zip(ts[:-1], ts[1:], strict=True):
        steps = np.linspace(t0, t1, substeps + 1)
        for tj, tk in zip(steps[:-1], steps[1:], strict=True):
            u = np.asarray(input_fn(tj))
            sol = solve_ivp(tse2_ode, (tj, tk), q, method="DOP853", rtol=1e-12, atol=1e-12,
                            args=(u, SYSTEM.J, SYSTEM.m))
            q = sol.y[:, -1]
        out.append(q)
    return np.array(out)


@pytest.mark.parametrize(("dt", "substeps"), [(1e-2, 1), (2e-2, 4)])
def test_noise_free_truth_integrates_the_nominal_dynamics(dt, substeps):
    q0 = np.array([np.pi / 6, 1.0, 2.0, 0.2, 0.5, -0.3])
    ts = grid(2.0, dt)
    truth, log = simulate(SYSTEM, tse2_state(*q0), fast_input, ts, jax.random.key(0), substeps=substeps)
    ref = reference_solution(q0, ts, substeps, fast_input)
    q = np.array(truth.coords())
    q[:, 0] = np.unwrap(q[:, 0])
    scale = np.maximum(1.0, np.abs(ref))
    assert np.max(np.abs(q - ref) / scale) < ODE_REFERENCE


def test_lie_euler_truth_takes_group_euler_steps():
    # g_{k+1} = g_k exp(h lambda(g_k, u(t_k), t_k)), written out by hand.
    ts = grid(0.05, 1e-2)
    truth, _ = simulate(SYSTEM, G0, fast_input, ts, jax.random.key(0), integrator="lie-euler")
    g = G0
    for k, t in enumerate(ts[:-1]):
        g = g.rplus(1e-2 * SYSTEM.dynamics(g, fast_input(t), t))
        np.testing.assert_allclose(truth.coords()[k + 1], g.coords(), rtol=0, atol=ROUNDOFF)


# --- checks at the boundary
@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(key=0), "key: expected a jax.random key"),
    (dict(ts=[0.0, 0.2, 0.1]), "ts: expected strictly increasing"),
    (dict(ts=[0.0]), "ts: expected at least 2"),
    (dict(g0=tse2_state(0, 0, 0, 0, 0, 0).factors[0]), "g0: expected an element of SE2xR3"),
    (dict(model_error_std=-1.0), "model_error_std: expected a number >= 0"),
    (dict(input_fn=lambda t: jnp.zeros(3)), r"input_fn: expected u\(t\) of shape \(2,\)"),
    (dict(input_fn=None), "input_fn: expected a function"),
    (dict(input_noise=np.eye(3)), r"input_noise: expected shape \(2, N\)"),
    (dict(substeps=0), "substeps: expected an integer >= 1"),
    (dict(integrator="rk45"), "integrator: expected one of"),
])
def test_bad_arguments_raise_a_named_value_error(kwargs, match):
    args = dict(system=SYSTEM, g0=G0, input_fn=paper_input, ts=grid(0.1, 1e-2), key=jax.random.key(0))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        system, g0, input_fn, ts, key = (args.pop(k) for k in ("system", "g0", "input_fn", "ts", "key"))
        simulate(system, g0, input_fn, ts, key, **args)
