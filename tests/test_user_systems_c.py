"""User systems on the C engine (issue 22): eight systems written as a user writes them from the docs, with
everyday JAX in their dynamics and outputs (``jnp.interp`` over t, a table indexed by a traced integer,
``argmax``, ``sort``, ``expm``, a state-dependent ``inv`` that the filter differentiates twice, ``cholesky``,
``fori_loop``). Each runs on the C engine under ``engine="auto"`` without falling back (no ``EngineWarning``)
and equals the XLA engine over a short log to ``USER_SYSTEM_C``. A system the translator cannot read is named
in the warning by the user's own file and line.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef import codegen
from liemef.codegen import _kernel
from liemef.engines import EngineWarning, LogGapWarning
from liemef.groups import SE2, Rn
from liemef.systems import Noise, Sensor, SensorSystem
from tolerances import USER_SYSTEM_C

pytestmark = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")

# --- the users' systems -----------------------------------------------------------------------------------
PUSH_TIMES = jnp.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
PUSH = jnp.array([0.0, 0.5, -0.3, 0.8, 0.1, 0.0])  # a known external force, tabulated over t (N/kg)
GAINS = jnp.array([1.0, 0.8, 1.3, 0.9, 1.1])        # a throttle gain per 0.25 s segment of the run
CELL_BIAS = jnp.array([0.02, -0.01, 0.03, 0.0])     # a range bias per 1 m cell of the track
BEACONS = jnp.array([[0.0, 0.0], [3.0, 0.5], [-1.0, 2.5]])


def cart_interp(g, u, t):
    """A cart (position, velocity) pushed by a tabulated force, read at t by linear interpolation."""
    return jnp.stack([g.x[1], u[0] + jnp.interp(t, PUSH_TIMES, PUSH) - 0.3 * g.x[1]])


def cart_table(g, u, t):
    """A cart whose throttle gain is scheduled by segment: the table indexed by a traced integer from t."""
    k = jnp.clip(jnp.floor(t / 0.25).astype(jnp.int32), 0, GAINS.shape[0] - 1)
    return jnp.stack([g.x[1], GAINS[k] * u[0] - 0.3 * g.x[1]])


def range_with_cell_bias(g, t):
    """A range sensor whose bias depends on the track cell the cart is in (an index from the state)."""
    cell = jnp.clip(jnp.floor(g.x[0] + 2.0).astype(jnp.int32), 0, CELL_BIAS.shape[0] - 1)
    return jnp.sqrt(1.0 + g.x[:1] ** 2) + CELL_BIAS[cell]


def strongest_beacon(g, t):
    """The range to whichever beacon is heard loudest (argmax of the signal strengths)."""
    p = g.coords()[1:3]
    d2 = jnp.sum((BEACONS - p) ** 2, axis=1)
    k = jnp.argmax(jnp.exp(-d2))
    return jnp.sqrt(d2[k] + 0.1)[None]


def sorted_ranges(g, t):
    """Ranges to three unlabeled beacons, reported in increasing order."""
    p = g.coords()[1:3]
    return jnp.sort(jnp.sqrt(jnp.sum((BEACONS - p) ** 2, axis=1) + 0.1))


def unicycle_expm(g, u, t):
    """A unicycle in the plane on R^3 = (x, y, heading): the velocity turned by the heading's rotation,
    written as the exponential of the rotation generator."""
    rot = jax.scipy.linalg.expm(g.x[2] * jnp.array([[0.0, -1.0], [1.0, 0.0]]))
    return jnp.concatenate([rot @ jnp.stack([u[0], 0.0]), u[1:2]])


def compliant_output(g, t):
    """A sensor reading through a state-dependent compliance: h = M(x)^{-1} b (the filter's Hessian of h
    differentiates the inverse twice)."""
    M = jnp.array([[2.0 + g.x[0] ** 2, 0.5 * g.x[1]], [0.5 * g.x[1], 3.0 + jnp.sin(g.x[0])]])
    return jnp.linalg.inv(M) @ jnp.array([1.0, 0.5])


def whitened_output(g, t):
    """A reading whitened by the Cholesky factor of a state-dependent covariance."""
    P = jnp.array([[1.0 + g.x[0] ** 2, 0.3 * g.x[1]], [0.3 * g.x[1], 2.0 + g.x[1] ** 2]])
    return jnp.linalg.cholesky(P) @ jnp.array([1.0, -0.5])


def kepler_output(g, t):
    """An angle from Kepler's equation E - e sin E = M, solved by six Newton steps (a fixed fori_loop)."""
    M, e = g.x[0], 0.3

    def newton(i, E):
        return E - (E - e * jnp.sin(E) - M) / (1.0 - e * jnp.cos(E))

    return jnp.sin(jax.lax.fori_loop(0, 6, newton, M))[None]


def _position(g, t):
    return g.x[:1]


def _cart(dynamics, output=_position, p=1):
    return SensorSystem(Rn[2], dynamics, [Sensor("range", output, Noise.sample(0.05 * np.ones(p)))],
                        process_noise=Noise.density([0.05, 0.2]), inputs=("throttle",))


def _planar(output, p):
    return SensorSystem(SE2, lambda g, u, t: jnp.stack([u[2], u[0], u[1]]),
                        [Sensor("radio", output, Noise.sample(0.1 * np.ones(p)))],
                        process_noise=Noise.density([0.05, 0.1, 0.1]), inputs=("v_x", "v_y", "omega"))


USER_SYSTEMS = {
    "interp_over_t": lambda: _cart(cart_interp),
    "table_by_traced_int": lambda: _cart(cart_table, range_with_cell_bias),
    "argmax": lambda: _planar(strongest_beacon, 1),
    "sort": lambda: _planar(sorted_ranges, 3),
    "expm": lambda: SensorSystem(Rn[3], unicycle_expm,
                                 [Sensor("gps", lambda g, t: g.x[:2], Noise.sample([0.5, 0.5]))],
                                 process_noise=Noise.density([0.1, 0.1, 0.05]), inputs=("speed", "turn")),
    "inv_twice": lambda: _cart(cart_interp, compliant_output, 2),
    "cholesky": lambda: _cart(cart_table, whitened_output, 2),
    "fori_loop": lambda: _cart(cart_interp, kepler_output),
}


def _log(system, n=60, dt=0.02, seed=0):
    rng = np.random.default_rng(seed)
    G = system.group
    q = 0.3 * rng.standard_normal(G.coords_dim)
    ts = dt * np.arange(n)
    us = 0.5 + 0.2 * rng.standard_normal((n, system.input_dim))
    ys = np.asarray(system.output(G.from_coords(jnp.asarray(q)), 0.0)) + 0.05 * rng.standard_normal(
        (n, system.output_dim))
    g0 = G.from_coords(jnp.asarray(q + 0.1 * rng.standard_normal(G.coords_dim)))
    return g0, ts, us, ys


def _assert_close(c, x, what):
    for a, b in zip(jax.tree_util.tree_leaves(c), jax.tree_util.tree_leaves(x), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind in "iub":
            np.testing.assert_array_equal(a, b, err_msg=what)
            continue
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=what)
        ok = ~np.isnan(b)
        err = np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(b[ok]))
        assert err.max(initial=0.0) <= USER_SYSTEM_C, f"{what}: relative deviation {err.max():.3g}"


QUICK = ("interp_over_t", "table_by_traced_int")
"""In the default suite; each of the others takes 20-40 s (JAX compiling the XLA run, the kernel's build)."""


@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n in QUICK else [pytest.mark.slow])
                                  for n in sorted(USER_SYSTEMS)])
def test_user_system_runs_on_c_and_equals_xla(name):
    system = USER_SYSTEMS[name]()
    # Theorem 4.1's filter: these systems test the engines. On table_by_traced_int the held range's Jacobian
    # grows 20x within the first interval, where the adaptive sub-steps fail the first order and the safe
    # curvature alike (K not positive definite at t = 0), and the exact curvature runs.
    flt = liemef.MinimumEnergyFilter(system, curvature="exact")
    g0, ts, us, ys = _log(system)
    state = flt.init(g0, np.eye(flt.n))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        warnings.simplefilter("error", EngineWarning)  # no fallback to XLA
        auto = flt.run(state, ts, us, ys)
        c = flt.run(state, ts, us, ys, engine="c")
        x = flt.run(state, ts, us, ys, engine="xla")
    assert int(x.final.status.code) == 0, f"{name}: the XLA run itself failed"
    _assert_close(auto, c, f"{name} auto vs c")
    _assert_close(c, x, f"{name} c vs xla")


@pytest.mark.slow  # 40 s on a busy 2-core machine: the XLA run's compilation and the kernel's build
def test_a_matrix_group_from_its_basis_runs_on_c_and_equals_xla():
    # MatrixGroup.exp is a Pade expm with a loop of squarings (and log a while loop): the C engine translates
    # both, so a group made from a basis needs no closed form to run in C (docs/adding-a-group.md).
    from liemef.groups import SO3, MatrixGroup
    from liemef.systems import System

    G = MatrixGroup.from_basis("SO3FromBasis", np.asarray(SO3.hat(jnp.eye(3))))
    system = System(group_type=G, dynamics_fn=lambda g, u, t: u,
                    output_fn=lambda g, t: g.as_matrix().T @ jnp.array([0.0, 0.0, 1.0]),
                    B=0.1 * np.eye(3), D=0.1 * np.eye(3), Q=np.eye(3), R=np.eye(3), n_inputs=3)
    flt = liemef.MinimumEnergyFilter(system)
    g0, ts, us, ys = _log(system)
    state = flt.init(g0, np.eye(flt.n))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        warnings.simplefilter("error", EngineWarning)
        c = flt.run(state, ts, us, ys, engine="c")
        x = flt.run(state, ts, us, ys, engine="xla")
    assert int(x.final.status.code) == 0
    _assert_close(c, x, "SO(3) from its basis, c vs xla")


# --- a system the translator cannot read ------------------------------------------------------------------
def svd_output(g, t):
    s = jnp.linalg.svd(jnp.diag(g.x), compute_uv=False)  # unsupported: named in the warning
    return g.x[:1] + 0.0 * s[:1]


def test_an_unsupported_primitive_is_named_with_the_users_file_and_line():
    system = _cart(cart_interp, svd_output)
    flt = liemef.MinimumEnergyFilter(system)
    g0, ts, us, ys = _log(system, n=5)
    source = Path(__file__).read_text().splitlines()
    line = next(i + 1 for i, ln in enumerate(source) if "# unsupported: named in the warning" in ln)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        with pytest.warns(EngineWarning) as record:
            flt.run(flt.init(g0, np.eye(2)), ts, us, ys)
    text = str(record[0].message)
    assert "svd" in text and f"{Path(__file__).name}:{line} (svd_output)" in text, text
    assert "running with XLA" in text
    with pytest.raises(codegen.UnsupportedPrimitive, match=rf"test_user_systems_c\.py:{line} "):
        flt.run(flt.init(g0, np.eye(2)), ts, us, ys, engine="c")


@pytest.mark.parametrize("call", ["run", "step", "online"])
def test_the_fallback_warning_points_at_the_users_call(call):
    """Python prints a warning under the file and line it is attributed to: the user's own ``run``, ``step`` or
    ``online`` call (each reaches the engine's choice by another path), not a line inside liemef."""
    system = _cart(cart_interp, svd_output)
    flt = liemef.MinimumEnergyFilter(system)
    g0, ts, us, ys = _log(system, n=5)
    state = flt.init(g0, np.eye(2))
    calls = {"run": lambda: flt.run(state, ts, us, ys),  # the user's call
             "step": lambda: flt.step(state, ts[0], us[0], ys[0], 0.02),  # the user's call
             "online": lambda: flt.online(state)}  # the user's call
    line = next(i + 1 for i, ln in enumerate(Path(__file__).read_text().splitlines())
                if f'"{call}": lambda: flt.' in ln)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        with pytest.warns(EngineWarning) as record:
            calls[call]()
    assert (Path(record[0].filename).name, record[0].lineno) == (Path(__file__).name, line), \
        f"{record[0].filename}:{record[0].lineno}"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["interp_over_t", "sort"])
def test_user_system_batch_in_simd_equals_single_runs(name):
    """Five trials on the batch kernel (one SIMD group of 4 and a remainder): its lane code has the selects,
    comparisons and unsigned indices of interp's and sort's derivatives, and each trial equals its own run
    (slow: 40 s, the -O3 batch build on top of the kernel)."""
    system = USER_SYSTEMS[name]()
    flt = liemef.MinimumEnergyFilter(system)
    logs = [_log(system, n=30, seed=s) for s in range(5)]
    ts = logs[0][1]
    states = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[flt.init(lg[0], np.eye(flt.n)) for lg in logs])
    us, ys = np.stack([lg[2] for lg in logs]), np.stack([lg[3] for lg in logs])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        warnings.simplefilter("error", EngineWarning)
        batch = flt.run_batch(states, ts, us, ys, engine="c", threads=1)
        assert _kernel.kernel_for(flt).lanes() is not None, _kernel.kernel_for(flt).lanes_error
        for b, (g0, _, u, y) in enumerate(logs):
            one = flt.run(flt.init(g0, np.eye(flt.n)), ts, u, y, engine="c")
            mine = jax.tree_util.tree_map(lambda a, b=b: a[b], (batch.g_hat, batch.K, batch.final))
            _assert_close(mine, (one.g_hat, one.K, one.final), f"{name} trial {b}")


def _landmark_system(landmark):
    """SE(2) with odometry and the range and bearing of a landmark that the output function closes over."""
    point = jnp.asarray(landmark, dtype=jnp.float64)

    def rb(g, t):
        b = (point - g.translation()) @ g.rotation().as_matrix()
        return jnp.array([jnp.linalg.norm(b), jnp.arctan2(b[1], b[0])])

    return SensorSystem(SE2, lambda g, u, t: u, [Sensor("rb", rb, Noise.sample([0.5, 0.1]), ["r", "b"],
                                                        angles=["b"])],
                        Noise.sample([0.01, 0.01, 0.01], rate=10.0), inputs=("w", "vx", "vy"))


def test_a_kernel_is_not_shared_by_systems_that_close_over_other_arrays():
    """Two systems alike but for the landmark their output closes over (the jaxprs print the same: the landmark
    is a constant of the jit inside the filter's terms): their kernels' keys differ, and each C run is its own
    system's, as XLA's. A key that missed the constants inside served the first landmark's kernel for the second
    from the disk cache: a run 'ok' with the wrong answer."""
    keys, runs = [], []
    ts = np.arange(40) * 0.1
    us = np.tile([0.1, 0.5, 0.0], (40, 1))
    for landmark in ((1.0, 1.0), (101.0, 101.0)):
        system = _landmark_system(landmark)
        flt = liemef.MinimumEnergyFilter(system, error="left")
        keys.append(_kernel._trace(flt).key)
        g0 = SE2.from_coords(jnp.array([0.1, landmark[0] - 3.0, landmark[1] - 1.0]))
        ys = np.asarray(jax.vmap(lambda t, g0=g0, system=system: system.output(g0, t))(ts))  # a parked robot's
        state = flt.init(SE2.from_coords(jnp.array([0.0, landmark[0] - 2.8, landmark[1] - 1.1])), 0.1 * np.eye(3))
        with warnings.catch_warnings():
            warnings.simplefilter("error", EngineWarning)  # no fallback to XLA
            c = flt.run(state, ts, us * 0.0, ys, engine="c")
        x = flt.run(state, ts, us * 0.0, ys, engine="xla")
        _assert_close(c, x, f"landmark {landmark}: c vs xla")
        runs.append(np.asarray(c.g_hat.coords()[-1]) - np.array([0.0, *landmark]))
    assert keys[0] != keys[1]
    np.testing.assert_allclose(runs[0], runs[1], atol=1e-6)  # the same relative run, wherever the landmark is
