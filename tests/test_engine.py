"""The C engine (issue 9): ``run``, ``step`` and ``run_batch`` by the compiled C kernel of the filter's interval
(:mod:`liemef.codegen._kernel`) are the XLA engine's computation.

On every ready system (``make test``: one of each group and kind of sensor, FAST_SYSTEMS; ``make test-slow``:
the rest), with held and missing inputs, missing outputs, a gap and a failure, the C engine's trajectory,
final state and status equal the XLA engine's to ``ENGINES`` relative (statuses and counters exactly). A new
weight set with the same zero pattern reuses the kernel (``TRACES["kernel"]``); a new zero pattern builds one
more. Unknown engines, a missing compiler and a kernel that cannot be built are clear.
"""

from __future__ import annotations

import subprocess
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from compilers import COMPILERS, compiler_or_skip, warning_free_flags
from liemef import codegen
from liemef.codegen import _kernel
from liemef.engines import EngineWarning, LogGapWarning
from liemef.filters import CAUSES, TRACES
from liemef.groups import Rn
from liemef.studies.experiments import SYSTEMS
from liemef.systems import Noise, Sensor, SensorSystem, planar_localization
from trees import assert_trees_close

pytestmark = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")


def _log(flt, n=120, seed=0, dt=0.01):
    """A log around a random true state: outputs of the truth plus noise, random bounded inputs, a few missing
    outputs and inputs, and one long interval (a gap at the default threshold)."""
    rng = np.random.default_rng(seed)
    sysm = flt.system
    G = sysm.group
    q = 0.3 * rng.standard_normal(G.coords_dim)
    g = G.from_coords(jnp.asarray(q))
    ts = dt * np.arange(n, dtype=float)
    ts[n // 2:] += 0.5  # one interval of 0.51 s: a gap
    us = 0.2 * rng.standard_normal((n, sysm.input_dim))
    y0 = np.asarray(sysm.output(g, 0.0))
    ys = y0 + 0.05 * rng.standard_normal((n, sysm.output_dim))
    ys[3::11, 0] = np.nan
    ys[5::17] = np.nan
    if sysm.input_dim:
        us[7::13] = np.nan
    g0 = G.from_coords(jnp.asarray(q + 0.1 * rng.standard_normal(G.coords_dim)))
    return flt.init(g0, np.eye(flt.n)), ts, us, ys


def _runs(flt, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        return flt.run(*args, engine="c", **kw), flt.run(*args, engine="xla", **kw)


# The ready systems whose engine comparisons run in `make test`: each group and kind of sensor once (the plane,
# landmarks, a nonholonomic constraint, the circle, SO(3) with directions, SE_2(3) with biases at the scalar
# code's 15 states). The others, which repeat a group or a sensor of these (and cost 5-20 s each cold, mostly
# building their kernels), run in `make test-slow`.
FAST_SYSTEMS = ("tse2", "localization", "chaplygin", "unit-circle", "attitude", "inertial-navigation")


def _systems(fast=FAST_SYSTEMS):
    return [s if s in fast else pytest.param(s, marks=pytest.mark.slow) for s in sorted(SYSTEMS)]


@pytest.mark.parametrize("system", _systems())
def test_run_equals_xla_on_every_ready_system(system):
    """Second order, (0)-connection, RKMK4 with adaptive sub-steps: the whole trajectory, the final state and its
    status, with missing samples and a gap predicted through."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS[system].make())
    c, x = _runs(flt, *_log(flt))
    assert x.status.ok and int(x.status.gaps) == 1
    assert_trees_close(c, x)


@pytest.mark.parametrize("options", [dict(order="first", connection="plus"), dict(connection="minus"),
                                     dict(integrator="lie-euler", interpolation="linear"), dict(integrator="rkmk2"),
                                     dict(substeps=3), dict(alpha=0.5)], ids=str)
def test_run_equals_xla_for_every_option(options):
    """The options that change the kernel: order, a connection with torsion (K not symmetric), Lie-Euler with
    linearly interpolated samples, the explicit-midpoint RKMK2, fixed sub-steps, forgetting."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make(), **options)
    c, x = _runs(flt, *_log(flt, seed=1))
    assert x.status.ok
    assert_trees_close(c, x)


def test_keep_every_and_gap_threshold():
    flt = liemef.MinimumEnergyFilter(planar_localization())
    state, ts, us, ys = _log(flt, n=100, seed=2)
    c, x = _runs(flt, state, ts, us, ys, keep_every=7, gap=np.inf)
    assert c.K.shape == (15, 3, 3) and int(x.status.gaps) == 0
    assert_trees_close(c, x)
    with pytest.warns(LogGapWarning, match="1 sample interval"):
        flt.run(state, ts, us, ys, engine="c")


def test_a_failure_is_the_same_value():
    """A sample of 1e200 makes the state non-finite: both engines stop at the same interval with the same
    cause, the states after it are NaN and the final state is the last good one. (The log has the default 120
    samples: the XLA run is the program ``test_run_equals_xla_on_every_ready_system[tse2]`` compiled.)"""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    state, ts, us, ys = _log(flt, seed=3)
    ys[40] = 1e200
    c, x = _runs(flt, state, ts, us, ys)
    assert not c.status.ok and c.status.cause == "non-finite" and int(c.status.index) == 40
    assert np.isnan(np.asarray(c.K)[41:]).all() and np.isfinite(np.asarray(c.K)[:41]).all()
    assert_trees_close(c, x)
    # a failed state stays failed: running on from it changes nothing
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)  # the counters of the failed state: the gap of the first run
        again = flt.run(c.final, ts[40:], us[40:], ys[40:], engine="c", gap=np.inf)
    assert int(again.status.code) == CAUSES.index("non-finite")
    assert_trees_close(again.final, c.final, tol=0.0)


def test_step_equals_xla_and_chains():
    """Twenty online steps by C (each reading the packed vector of the state before) and by XLA, with missing
    components and held inputs; the C state's leaves are NumPy arrays."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["attitude-bias"].make())
    state, ts, us, ys = _log(flt, n=21, seed=4)
    sc = sx = state
    for k in range(20):
        sc = flt.step(sc, ts[k], us[k], ys[k], ts[k + 1] - ts[k], engine="c")
        sx = flt.step(sx, ts[k], us[k], ys[k], ts[k + 1] - ts[k], engine="xla")
    assert isinstance(sc.K, np.ndarray) and int(sc.status.steps) == 20
    assert_trees_close(sc, sx)
    # a C state fed to XLA and back: the same next state either way
    assert_trees_close(flt.step(sc, ts[20], us[20], ys[20], 0.01, engine="xla"),
                 flt.step(sc, ts[20], us[20], ys[20], 0.01, engine="c"))


@pytest.mark.parametrize("system", ["tse2", pytest.param("attitude-bias", marks=pytest.mark.slow),
                                    pytest.param("attitude", marks=pytest.mark.slow)])
def test_run_batch_equals_single_runs(system):
    """Nine trials (two SIMD groups and a remainder) with their own logs and initial states, one of which fails,
    on two threads: each equals its own run, and the XLA engine's vmap. The attitude's solve with its inertia
    as data is an LU block, which has no lane form: its batch runs one trial at a time, saying why. TSE(2) holds
    the lane form in ``make test``; the attitude with a gyro bias, a second lane form and the heaviest variant
    (about 30 s, mostly compiling), runs in ``make test-slow``."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS[system].make())
    logs = [_log(flt, n=50, seed=10 + b) for b in range(9)]
    logs[5][3][30] = 1e200  # trial 5 fails at interval 30, in the middle of the second lane group
    ts = logs[0][1]
    states = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[lg[0] for lg in logs])
    us, ys = np.stack([lg[2] for lg in logs]), np.stack([lg[3] for lg in logs])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        batch = flt.run_batch(states, ts, us, ys, engine="c", threads=2)
        xla = flt.run_batch(states, ts, us, ys, engine="xla")
        for b, (state, _, u, y) in enumerate(logs):
            one = flt.run(state, ts, u, y, engine="c")
            mine = jax.tree_util.tree_map(lambda a, b=b: a[b], (batch.g_hat, batch.K, batch.status, batch.final))
            assert_trees_close(mine, (one.g_hat, one.K, one.status, one.final))
    assert [int(c) for c in batch.status.code] == [0] * 5 + [CAUSES.index("non-finite")] + [0] * 3
    assert_trees_close(batch, xla)
    kern = _kernel.kernel_for(flt)
    if system == "attitude":
        assert kern.lanes() is None and "no lane form" in kern.lanes_error
    else:
        assert kern.lanes() is not None


def test_lane_groups_compute_each_trials_bits():
    """The batch kernel's SIMD groups give each trial the bits of the one-at-a-time kernel: TSE(2), whose
    exponential's guarded series (``sin(where(small, 1.0, x))``) the lanes split into a select of the function
    of each arm, with trials of small and of large rotations in one group."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    kern = _kernel.kernel_for(flt).wait()
    assert "? (sin((" in _kernel._translate_lanes(kern.traced)  # the split form is emitted
    logs = [_log(flt, n=40, seed=30 + b) for b in range(8)]
    for b, lg in enumerate(logs):
        lg[2][:] *= (1.0, 40.0)[b % 2]  # rotations of 2e-3 and of 8e-2 rad an interval, within each group
    ts = logs[0][1]
    x = np.stack([kern.pack(lg[0]) for lg in logs])
    us, ys = np.stack([lg[2] for lg in logs]), np.stack([lg[3] for lg in logs])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        lanes = kern.batch(kern.theta(flt), x, ts, us, ys, 0.2, 1, threads=1)
        single = kern.batch(kern.theta(flt), x, ts, us, ys, 0.2, 1, threads=1, lanes=False)
    assert kern.lanes() is not None, kern.lanes_error
    _assert_same_bits(lanes, single)
    assert (lanes[2] == 0).all()


def _inverse_position(g, t):
    """1 / (the position): infinite, and its derivatives too, at 0."""
    return 1.0 / g.x[:1]


def _batch_both_ways(flt, starts, ts, us, ys):
    """The batch kernel's lane groups and the one-at-a-time kernel on the same trials: (lanes, single, kernel)."""
    kern = _kernel.kernel_for(flt).wait()
    x = np.stack([kern.pack(flt.init(Rn[2](jnp.asarray(x0)), np.eye(2))) for x0 in starts])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        lanes = kern.batch(kern.theta(flt), x, ts, us, ys, 0.2, 1, threads=1)
        single = kern.batch(kern.theta(flt), x, ts, us, ys, 0.2, 1, threads=1, lanes=False)
    return lanes, single, kern


def _inverse_system():
    sensors = (Sensor("p", _position, Noise.sample(0.3)), Sensor("inverse", _inverse_position, Noise.sample(0.1)))
    return SensorSystem(Rn[2], _drift, sensors, Noise.density([0.1, 0.2]), inputs=("a",))


def _inverse_filter_and_log(n=30, trials=8):
    """The filter of :func:`_inverse_system`, and a log of ``trials`` trials of ``n`` samples with their own
    inputs and no measurement yet (each test places its samples)."""
    ts = 0.01 * np.arange(n)
    us = np.stack([0.1 * np.sin(ts + b)[:, None] for b in range(trials)])
    return liemef.MinimumEnergyFilter(_inverse_system()), ts, us, np.full((trials, n, 2), np.nan)


def _assert_same_bits(lanes, single):
    """The batch's outputs (lane groups) equal the one-trial-at-a-time kernel's, bit for bit."""
    for a, b in zip(lanes, single, strict=True):
        assert a.tobytes() == b.tobytes()


def test_lanes_that_take_different_arms_of_a_cond_keep_their_bits():
    """An interval without a sample in force takes the prediction alone (a ``cond``), so trials of one lane group
    with their samples at different times take different arms in one step: each lane gets the one-at-a-time
    kernel's bits. The output 1/x is infinite at the start x = 0: the trials whose first interval has that
    sample fail there as non-finite, and the infinities of the arm they take reach none of the others."""
    flt, ts, us, ys = _inverse_filter_and_log()
    for b in range(8):
        ys[b, 1 + b % 3::3, 0] = 0.05 * b  # positions at times that differ within each group of four
        ys[b, 5::7, 1] = 2.0
        if b % 2:
            ys[b, 0, 1] = 1.0  # the inverse at the start of odd trials only
    lanes, single, kern = _batch_both_ways(flt, [[0.0, 0.5]] * 8, ts, us, ys)
    assert kern.lanes() is not None, kern.lanes_error
    assert "any_act" in _kernel._translate_lanes(kern.traced)  # the cond is in lane form, not one trial at a time
    _assert_same_bits(lanes, single)
    assert [int(c) for c in lanes[2]] == [0, CAUSES.index("non-finite")] * 4


def test_lanes_that_agree_on_a_cond_keep_their_bits():
    """Trials on one sample grid take the same arm of each ``cond`` in every step (the batch kernel then runs
    that arm alone): each lane gets the one-at-a-time kernel's bits, from starts on and off x = 0, where the
    output 1/x is infinite but has no sample until the estimate has left it."""
    flt, ts, us, ys = _inverse_filter_and_log()
    for b in range(8):
        ys[b, 2::4, 0] = 0.05 * b
        ys[b, 9::10, 1] = 2.0
    lanes, single, kern = _batch_both_ways(flt, [[0.0, 0.5], [0.3, -0.2]] * 4, ts, us, ys)
    assert kern.lanes() is not None, kern.lanes_error
    _assert_same_bits(lanes, single)
    assert (lanes[2] == 0).all()


def _drift(g, u, t):
    return jnp.array([g.x[1], -0.1 * g.x[1] + u[0]])


def _position(g, t):
    return g.x[:1]


def _drift_system(p_std, process_std):
    return SensorSystem(Rn[2], _drift, (Sensor("p", _position, Noise.sample(p_std)),), Noise.density(process_std),
                        inputs=("a",))


def test_new_weights_reuse_the_kernel():
    """Ten weight sets of one zero pattern: one kernel build (none if another test built it), and the weights do
    change the estimates; a weight with a new zero pattern builds one more, once."""
    ts = 0.05 * np.arange(40)
    us, ys = np.sin(ts)[:, None], np.cos(ts)[:, None]
    before = TRACES["kernel"]
    finals = []
    for i in range(10):
        flt = liemef.MinimumEnergyFilter(_drift_system(0.1 + 0.05 * i, [0.1 + 0.01 * i, 0.2]))
        traj = flt.run(flt.init(Rn[2](jnp.zeros(2)), np.eye(2)), ts, us, ys, engine="c")
        finals.append(np.asarray(traj.final.g_hat.x))
    assert TRACES["kernel"] - before <= 1
    assert np.abs(finals[0] - finals[-1]).max() > 1e-3
    mid = TRACES["kernel"]
    for _ in range(2):
        flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]), alpha=0.2)  # alpha 0 -> 0.2: a new pattern
        c, x = _runs(flt, flt.init(Rn[2](jnp.zeros(2)), np.eye(2)), ts, us, ys)
        assert_trees_close(c, x)  # alpha is read, not folded to the 0 of the first pattern
    assert TRACES["kernel"] - mid <= 1


def test_engine_argument_is_checked(monkeypatch):
    flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    state = flt.init(Rn[2](jnp.zeros(2)), np.eye(2))
    with pytest.raises(ValueError, match=r"engine: expected one of \['auto', 'c', 'xla'\], got 'gpu'"):
        flt.run(state, [0.0, 0.1], [[0.0], [0.0]], [[1.0], [1.0]], engine="gpu")
    monkeypatch.setenv("LIEMEF_ENGINE", "fast")
    with pytest.raises(ValueError, match="LIEMEF_ENGINE: expected one of"):
        flt.step(state, 0.0, [0.0], [1.0], 0.1)


@pytest.fixture
def no_kernel(monkeypatch):
    """A kernel that cannot be built (the translator meets a primitive it has no C for): a filter and a state."""
    def broken(flt):
        raise codegen.UnsupportedPrimitive("primitive 'fft' has no C here")

    from liemef.engines import _select

    monkeypatch.setattr(_select, "kernel_for", broken)  # where the engines look it up
    flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    return flt, flt.init(Rn[2](jnp.zeros(2)), np.eye(2))


def test_auto_falls_back_to_xla_saying_why(no_kernel):
    """A kernel that cannot be built: "auto" warns and runs with XLA (the same result), "c" raises."""
    flt, state = no_kernel
    args = (state, [0.0, 0.1, 0.2], [[0.0], [0.1], [0.2]], [[1.0], [1.0], [0.9]])
    with pytest.raises(codegen.UnsupportedPrimitive, match="fft"):
        flt.run(*args, engine="c")
    flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    with pytest.warns(EngineWarning, match="UnsupportedPrimitive: primitive 'fft'.*running with XLA"):
        auto = flt.run(*args, engine="auto")
    assert_trees_close(auto, flt.run(*args, engine="xla"), tol=0.0)


def test_without_a_compiler_auto_is_xla(monkeypatch):
    from liemef.engines import _select

    monkeypatch.setattr(_select, "_no_compiler", lambda: True)
    assert liemef.engines.engine_of("auto") == "xla" and liemef.engines.engine_of("c") == "c"


def test_kernel_disk_cache(tmp_path, monkeypatch):
    """The first build is quick (-O0); the -O2 one starts once the quick one has served OPTIMIZE_AFTER_S of
    calls, and replaces it when done, with the same numbers bit for bit; a second process finds the -O2 kernel
    on disk (here: the in-process cache emptied): no new build."""
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    k1 = _kernel.kernel_for(flt)
    assert len(list(tmp_path.glob("quick_*.so"))) == 1  # the first build serves
    state, ts, us, ys = _log(flt, n=200, seed=5)
    theta, x = k1.theta(flt), k1.pack(state)
    quick = k1.scan(theta, x, ts, us, ys, 0.2, 3)  # a short call: far below the rent, no -O2 build
    assert not k1.optimized and k1._optimizer is None and 0.0 < k1._served < _kernel.OPTIMIZE_AFTER_S
    assert not list(tmp_path.glob("kernel_*.so"))
    monkeypatch.setattr(_kernel, "OPTIMIZE_AFTER_S", k1._served)  # the rent is paid by any further call
    again = k1.scan(theta, x, ts, us, ys, 0.2, 3)
    assert k1._optimizer is not None  # the -O2 build started, beside the quick one
    for a, b in zip(quick, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert k1.wait().optimized and k1.optimize_error is None
    files = sorted(tmp_path.glob("kernel_*.so"))
    assert len(files) == 1 and k1.path == files[0]
    for a, b in zip(quick, k1.scan(theta, x, ts, us, ys, 0.2, 3), strict=True):  # -O0 and -O2: bit for bit
        np.testing.assert_array_equal(a, b)
    stamp = files[0].stat().st_mtime_ns
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    k2 = _kernel.kernel_for(liemef.MinimumEnergyFilter(_drift_system(0.7, [0.3, 0.2])))
    assert k2.optimized and k2.path == files[0] and files[0].stat().st_mtime_ns == stamp


def test_a_quick_build_on_disk_serves_a_new_process_untranslated(tmp_path, monkeypatch):
    """A process that finds only the quick build on disk (the one before it never paid for -O2) loads it
    without translating the jaxpr again, with the same bits; the -O2 build translates when it starts."""
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    flt = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    k1 = _kernel.kernel_for(flt)
    state, ts, us, ys = _log(flt, n=200, seed=5)
    theta, x = k1.theta(flt), k1.pack(state)
    first = k1.scan(theta, x, ts, us, ys, 0.2, 3)
    assert not list(tmp_path.glob("kernel_*.so"))
    monkeypatch.setattr(_kernel, "_KERNELS", {})  # as in a new process
    translated, translate = [], _kernel._translate
    monkeypatch.setattr(_kernel, "_translate", lambda tr: translated.append(tr) or translate(tr))
    k2 = _kernel.kernel_for(flt)
    assert k2 is not k1 and not k2.optimized and k2.path == k1.path and not translated
    for a, b in zip(first, k2.scan(theta, x, ts, us, ys, 0.2, 3), strict=True):
        np.testing.assert_array_equal(a, b)
    assert k2.wait().optimized and k2.optimize_error is None and len(translated) == 1


def _two_weight_sets(flt):
    """The localization filter's parameters and those of one with a 2 m GPS std, stacked on a leading axis (to
    vmap over), and the static part to combine them with."""
    other = liemef.MinimumEnergyFilter(planar_localization(gps_std=2.0))
    both = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), eqx.filter(flt, eqx.is_array),
                                  eqx.filter(other, eqx.is_array))
    return both, eqx.filter(flt, eqx.is_array, inverse=True)


@pytest.mark.parametrize("keep_every", [1, pytest.param(4, marks=pytest.mark.slow)])
def test_scan_by_c_under_jit_and_vmap(keep_every):
    """``scan(engine="c")`` inside ``jit(vmap(...))`` over the trials' states and logs (the Monte Carlo engine's
    form): one callback for the batch, equal to the XLA scan's vmap, padding (``n_valid``) included; over the
    weights: ``test_scan_by_c_vmaps_over_weights``. Three trials, fewer than a SIMD group (:data:`_kernel.LANES`):
    the batch runs one trial at a time, with no batch kernel to build; the lane groups' bits are
    ``test_lane_groups_compute_each_trials_bits``'s and ``test_run_batch_equals_single_runs``'s."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["localization"].make())
    logs = [_log(flt, n=41, seed=20 + b) for b in range(3)]
    ts = jnp.asarray(logs[0][1])
    states = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[lg[0] for lg in logs])
    us, ys = jnp.asarray(np.stack([lg[2] for lg in logs])), jnp.asarray(np.stack([lg[3] for lg in logs]))

    def batch(engine, n_valid):
        fn = jax.jit(jax.vmap(lambda st, u, y: flt.scan(st, ts, u, y, keep_every=keep_every, n_valid=n_valid,
                                                       engine=engine)))
        return fn(states, us, ys)

    for n_valid in (None, 30):
        c, x = batch("c", n_valid), batch("xla", n_valid)
        assert np.asarray(c.K).shape[:2] == (3, 1 + -(-40 // keep_every))
        assert_trees_close(c, x)


def test_scan_by_c_vmaps_over_weights():
    """Weights as traced data (the Monte Carlo engine's form over filters): ``jit(vmap(...))`` over two filters'
    parameters through the same kernel equals the XLA scan's vmap. Apart from
    ``test_scan_by_c_under_jit_and_vmap``, whose ``keep_every`` it does not depend on: one run, not one per
    parameter."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["localization"].make())
    logs = [_log(flt, n=41, seed=20 + b) for b in range(6)]
    ts = jnp.asarray(logs[0][1])
    states = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[lg[0] for lg in logs])
    us, ys = jnp.asarray(np.stack([lg[2] for lg in logs])), jnp.asarray(np.stack([lg[3] for lg in logs]))
    both, static = _two_weight_sets(flt)

    def run_with(params, engine):
        f = eqx.combine(params, static)
        return f.scan(jax.tree_util.tree_map(lambda a: a[0], states), ts, us[0], ys[0], engine=engine).K

    per = [jax.jit(jax.vmap(lambda p_, e=e: run_with(p_, e)))(both) for e in ("c", "xla")]
    assert_trees_close(per[0], per[1])
    assert np.abs(np.asarray(per[0][0] - per[0][1])).max() > 1e-6


def test_gates_and_robust_losses_are_the_same_in_c():
    """Gated GPS (a 1e4 m outlier rejected and counted), a Huber loss, and three rejections in a row failing the
    run with cause "gate": the same rejections, counters and failure in both engines."""
    for kw, cause in ((dict(gate=0.999, robust="huber"), "ok"), (dict(gate=0.999, max_rejections=2), "gate")):
        flt = liemef.MinimumEnergyFilter(planar_localization(**kw))
        state, ts, us, ys = _log(flt, n=80, seed=30)
        ys[:, :] = np.where(np.arange(80)[:, None] % 10 == 0, ys, np.nan)  # a fix every 10 samples
        ys[40] += 1e4
        if cause == "gate":
            ys[50] += 1e4
            ys[60] += 1e4
        c, x = _runs(flt, state, ts, us, ys)
        assert c.status.cause == cause and int(np.asarray(c.status.rejected).sum()) >= 1
        assert_trees_close(c, x)


def test_online_filter_is_the_step():
    """flt.online(state): thirty steps equal the step chain by C exactly and by XLA to ENGINES; its gain, code and
    state read back; bad samples are named; a failure returns its code and freezes the state."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    state, ts, us, ys = _log(flt, n=31, seed=40)
    for engine in ("c", "xla"):
        online, st = flt.online(state, engine=engine), state
        for k in range(30):
            code = online.step(ts[k], us[k], ys[k], ts[k + 1] - ts[k])
            st = flt.step(st, ts[k], us[k], ys[k], ts[k + 1] - ts[k], engine=engine)
            assert code == 0
        assert_trees_close(online.state, st, tol=0.0)
        np.testing.assert_array_equal(online.K, np.asarray(st.K))
    assert_trees_close(flt.online(state).state, jax.tree_util.tree_map(np.asarray, state), tol=0.0)
    online = flt.online(state, engine="c")
    with pytest.raises(ValueError, match=r"y: expected shape \(7,\), got \(6,\)"):
        online.step(0.0, us[0], ys[0][:6], 0.01)
    with pytest.raises(ValueError, match="u_next: expected finite values or NaN"):
        online.step(0.0, us[0], ys[0], 0.01, u_next=[np.inf, 0.0])
    with pytest.raises(ValueError, match="dt: expected a finite time step > 0, got 0"):
        online.step(0.0, us[0], ys[0], 0)
    before = online.state
    assert online.step(0.0, us[0], np.full(7, 1e200), 0.01) == CAUSES.index("non-finite") == online.code
    assert_trees_close(online.state.g_hat, before.g_hat, tol=0.0)
    assert online.step(0.01, us[1], ys[1], 0.01) == online.code != 0


def test_a_state_of_another_filter_is_refused():
    """Two filters on one group with other inputs and sensors: a state of one given to the other is an error
    naming the state (the C code reads and writes a fixed number of numbers)."""
    a = liemef.MinimumEnergyFilter(_drift_system(0.3, [0.1, 0.2]))
    b = liemef.MinimumEnergyFilter(SensorSystem(Rn[2], lambda g, u, t: jnp.array([g.x[1], -0.1 * g.x[1]]),
                                                (Sensor("p", _position, Noise.sample(0.3)),
                                                 Sensor("q", _position, Noise.sample(0.5))), Noise.density([0.1, 0.2])))
    state_a = a.init(Rn[2](jnp.zeros(2)), np.eye(2))
    with pytest.raises(ValueError, match="state: expected a state of this filter"):
        b.step(state_a, 0.0, None, [1.0, 1.0], 0.1, engine="c")
    with pytest.raises(ValueError, match="state: expected a state of this filter"):
        b.online(state_a, engine="c")
    with pytest.raises(ValueError, match="states: expected a state of this filter"):
        b.run_batch(jax.tree_util.tree_map(lambda x: x[None], state_a), [0.0, 0.1], None, np.ones((1, 2, 2)),
                    engine="c")
    # b has no inputs: u may be None, in step, online and run alike
    state_b = b.init(Rn[2](jnp.zeros(2)), np.eye(2))
    assert_trees_close(b.step(state_b, 0.0, None, [1.0, 1.0], 0.1, engine="c"),
                 b.step(state_b, 0.0, None, [1.0, 1.0], 0.1, engine="xla"))
    online = b.online(state_b)
    assert online.step(0.0, None, [1.0, 1.0], 0.1) == 0
    with pytest.raises(ValueError, match="threads: expected an integer >= 1"):
        b.run_batch(jax.tree_util.tree_map(lambda x: x[None], state_b), [0.0, 0.1], None, np.ones((1, 2, 2)),
                    threads=0)


def test_c_after_a_fallback_still_raises(no_kernel):
    """An "auto" run that fell back to XLA does not make a later engine="c" on the same filter run XLA."""
    flt, state = no_kernel
    with pytest.warns(EngineWarning):
        flt.step(state, 0.0, [0.0], [1.0], 0.1)
    with pytest.raises(codegen.UnsupportedPrimitive, match="fft"):
        flt.step(state, 0.0, [0.0], [1.0], 0.1, engine="c")


def test_scan_by_c_alone_nested_and_per_trial():
    """scan(engine="c") outside vmap (with a gap threshold and padding), under two nested vmaps (weights x
    trials), and with n_valid differing between trials (one trial at a time): each equals the XLA scan."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["localization"].make())
    logs = [_log(flt, n=41, seed=50 + b) for b in range(3)]
    ts = jnp.asarray(logs[0][1])
    state = logs[0][0]
    u0, y0 = jnp.asarray(logs[0][2]), jnp.asarray(logs[0][3])
    for kw in (dict(gap=0.1, n_valid=35, keep_every=3), dict()):
        assert_trees_close(jax.jit(lambda u, y, kw=kw: flt.scan(state, ts, u, y, engine="c", **kw))(u0, y0),
                     jax.jit(lambda u, y, kw=kw: flt.scan(state, ts, u, y, engine="xla", **kw))(u0, y0))
    us, ys = jnp.asarray(np.stack([lg[2] for lg in logs])), jnp.asarray(np.stack([lg[3] for lg in logs]))
    nvs = jnp.asarray([41, 30, 12])

    def per_trial(engine):
        return jax.jit(jax.vmap(lambda u, y, n: flt.scan(state, ts, u, y, n_valid=n, engine=engine)))(us, ys, nvs)

    assert_trees_close(per_trial("c"), per_trial("xla"))
    both, static = _two_weight_sets(flt)

    def nested(engine):
        def one(params, u, y):
            return eqx.combine(params, static).scan(state, ts, u, y, engine=engine).K
        return jax.jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, 0)), in_axes=(0, None, None)))(both, us, ys)

    got = nested("c")
    assert got.shape[:2] == (2, 3)
    assert_trees_close(got, nested("xla"))


def test_online_states_are_values():
    """States from flt.step by C are values: a state kept across more steps than a block of rows holds is
    unchanged by the steps after it; samples as lists, integers or with explicit next samples are the same
    numbers as float arrays; the generated state reader gives what ``unflatten`` gives."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    state, ts, us, ys = _log(flt, n=2, seed=41)
    kept, copies = [], []
    st = state
    for _ in range(3 * _kernel.ROWS_PER_BLOCK + 5):
        st = flt.step(st, 0.0, us[0], ys[0], 1e-3, engine="c")
        kept.append(st)
        copies.append(jax.tree_util.tree_map(np.copy, st))
    for a, b in zip(kept, copies, strict=True):
        assert_trees_close(a, b, tol=0.0)
    assert int(kept[-1].status.steps) == 3 * _kernel.ROWS_PER_BLOCK + 5
    u_int = np.array([1, 2])
    ref = flt.step(state, 0.0, u_int.astype(float), ys[0], 1e-3, engine="c")
    for u, y, kw in ((u_int, ys[0], {}), (list(u_int), list(ys[0]), {}),
                     (u_int, ys[0], dict(u_next=u_int, y_next=ys[0]))):
        assert_trees_close(flt.step(state, 0.0, u, y, 1e-3, engine="c", **kw), ref, tol=0.0)
    with pytest.raises(ValueError, match="y: expected a numeric array, got str"):
        flt.step(state, 0.0, u_int, "seven", 1e-3, engine="c")
    with pytest.raises(ValueError, match=r"y_next: expected finite values or NaN \(missing\), got -inf at index \(2,"):
        flt.step(state, 0.0, u_int, ys[0], 1e-3, engine="c", y_next=np.where(np.arange(7) == 2, -np.inf, 0.0))
    kern = liemef.engines.kernel(flt, "c")
    x = kern.packed(ref)
    assert kern._reader.__name__ == "read"  # the generated reader, not the fallback
    assert_trees_close(kern._reader(x), kern.sdef.unflatten(jax.tree_util.tree_leaves(ref)), tol=0.0)


def test_state_reader_falls_back_on_static_fields():
    """A state node with a static field is built by ``unflatten`` (the generated reader covers Modules without
    static fields and tuples), with the same result."""

    class Node(eqx.Module):
        a: np.ndarray
        tag: int = eqx.field(static=True)

    template = (Node(np.zeros(2), 3), np.zeros((2, 2)), np.int32(4))
    leaves, sdef = jax.tree_util.tree_flatten(template)
    slots, _ = _kernel._slots(leaves)
    read = _kernel._state_reader(slots, sdef, template)
    assert read.__name__ == "<lambda>"
    got = read(np.arange(7.0))
    assert jax.tree_util.tree_structure(got) == sdef and got[0].tag == 3
    np.testing.assert_array_equal(got[1], [[2.0, 3.0], [4.0, 5.0]])
    assert got[2] == 6 and got[2].dtype == np.int32
    plain = (np.zeros(2), (np.zeros(3), np.int32(0)))
    leaves, sdef = jax.tree_util.tree_flatten(plain)
    read = _kernel._state_reader(_kernel._slots(leaves)[0], sdef, plain)
    assert read.__name__ == "read" and jax.tree_util.tree_structure(read(np.arange(6.0))) == sdef


def test_side_values_die_with_their_object():
    """liemef._side: a value is found while its object lives, not for another object that reuses its identity,
    and sweeps drop the entries of collected objects."""
    from liemef import _side

    class Obj:
        pass

    live = [Obj() for _ in range(3)]
    for i, o in enumerate(live):
        _side.put(o, "v", i)
    assert [_side.get(o, "v") for o in live] == [0, 1, 2]
    dead = Obj()
    _side.put(dead, "v", "gone")
    key = (id(dead), "v")
    del dead
    assert key in _side._SIDE
    _side.sweep()
    assert key not in _side._SIDE and [_side.get(o, "v") for o in live] == [0, 1, 2]
    before = len(_side._SIDE)
    for _ in range(3 * max(_side._SWEEP_AT[0], before)):  # many short-lived objects: the table stays bounded
        _side.put(Obj(), "v", 0)
    assert len(_side._SIDE) <= 2 * max(1024, before) + 1


def test_folded_constants_are_xlas_bits():
    """Constant folding in NumPy (no XLA compile during a translation) gives XLA's bits: integer powers by
    XLA's products (overflow and 0 ** -1 quietly, as XLA), and sums only where every order gives the same
    bits; float32 sums and sums with -0 are left to XLA."""
    from liemef.codegen._primitives import exact_sum, np_eval

    rng = np.random.default_rng(7)
    x = np.concatenate([rng.standard_normal(2000) * 10.0 ** rng.uniform(-8, 8, 2000), [0.0, -0.0, 1e200, 1e-200]])
    for y in (-7, -3, -2, -1, 0, 1, 2, 3, 5, 6, 13):
        want = np.asarray(jax.jit(lambda a, y=y: jax.lax.integer_pow(a, y))(x))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got = np_eval("integer_pow", {"y": y}, [x], [np.float64])[0]
        assert got.tobytes() == want.tobytes(), y
    ints = rng.integers(-9, 9, (4, 5)).astype(np.int32)
    want = np.asarray(jax.jit(lambda a: jnp.sum(a, axis=1))(ints))
    got = np_eval("reduce_sum", {"axes": (1,)}, [ints], [want.dtype])[0]
    assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    whole = np.array([[1.0, -3.0], [2.0**40, 5.0]])
    got = np_eval("reduce_sum", {"axes": (0, 1)}, [whole], [np.float64])[0]
    assert got.tobytes() == np.asarray(jax.jit(jnp.sum)(whole)).tobytes()
    assert exact_sum(whole)
    for bad in (np.array([0.1, 0.2]), np.array([np.inf, 1.0]), np.array([-0.0]), whole.astype(np.float32)):
        assert not exact_sum(bad)
    assert np_eval("reduce_sum", {"axes": (0,)}, [np.array([-0.0, -0.0])], [np.float64]) is None


@pytest.mark.parametrize("system", _systems(("tse2", "localization", "chaplygin", "unit-circle", "attitude-bias")))
def test_quick_and_optimized_builds_agree_bit_for_bit(system):
    """The quick first build (-O0) and the -O2 build for the host that replaces it compute the same bits on a
    log of every ready system (five in ``make test``, the rest in ``make test-slow``; no fused multiply-add in
    either: GCC's vectorizer made some at -march=native); a kernel whose build thread was lost in a fork builds
    it when waited for."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS[system].make())
    state, ts, us, ys = _log(flt, n=150, seed=6)
    kern = _kernel.kernel_for(flt).wait()
    assert kern.optimized and kern.optimize_error is None
    quick = _kernel.Kernel(_kernel._build(kern.traced, _kernel.QUICK_CFLAGS, "quick"), kern.traced)
    assert not quick.optimized
    theta, x = kern.theta(flt), kern.pack(state)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogGapWarning)
        for a, b in zip(quick.scan(theta, x, ts, us, ys, 0.2, 1), kern.scan(theta, x, ts, us, ys, 0.2, 1),
                        strict=True):
            assert a.tobytes() == b.tobytes()
    if system == "tse2":  # as after a fork: no build thread of this process's, the source kept
        quick._source = _kernel._translate(kern.traced)
        _kernel._PENDING.add(quick)
        _kernel._after_fork()
        assert quick.wait().optimized and quick.path == kern.path


def test_the_quick_build_takes_clang_unless_cc_says_otherwise(monkeypatch):
    """The quick (-O0) kernels are Clang's where it is on the PATH (faster at -O0 than GCC), ``$CC``'s where it
    is set, else the system compiler's; the -O2 kernels are always the system compiler's. That the two builds
    give the same bits is ``test_quick_and_optimized_builds_agree_bit_for_bit``."""
    from liemef.codegen import _export

    monkeypatch.delenv("CC", raising=False)
    real_which = _export.shutil.which
    monkeypatch.setattr(_export.shutil, "which", lambda name: f"/usr/bin/{name}" if name == "clang" else
                        real_which(name))
    assert _export.quick_compiler() == "clang" and _kernel._compiler_for("quick") == "clang"
    assert _kernel._compiler_for("kernel") == _export.compiler()
    monkeypatch.setenv("CC", "gcc")
    assert _export.quick_compiler() == "gcc" == _kernel._compiler_for("kernel")
    monkeypatch.delenv("CC")
    monkeypatch.setattr(_export.shutil, "which", lambda name: None if name == "clang" else f"/usr/bin/{name}")
    assert _export.quick_compiler() == _export.compiler() == "cc"


@pytest.mark.parametrize("cc", COMPILERS)
def test_the_kernel_source_builds_warning_free(cc, tmp_path):
    """The engine's C (TSE(2)'s kernel, built without warnings flags) is ISO C99 that GCC and Clang build with
    the export's -Wall -Wextra -Werror -pedantic too: it carries only the helper functions it calls (an unused
    static function is a warning in Clang)."""
    compiler_or_skip(cc)
    source = tmp_path / "kernel.c"
    source.write_text(_kernel._translate(_kernel.kernel_for(liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make()))
                                         .traced))
    proc = subprocess.run([cc, *warning_free_flags(cc, tmp_path / "kernel.o"), str(source)], capture_output=True,
                          text=True)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[:4000]


def test_bad_samples_are_named_alike_by_both_engines():
    """The same bad samples, the same error from the C and the XLA engines: checked in one order (u, y, then
    the next samples), each for its shape and then its infinities."""
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    state, ts, us, ys = _log(flt, n=2, seed=8)
    y_inf = ys[0].copy()
    y_inf[1] = -np.inf
    cases = [dict(u=us[0], y=y_inf, u_next=np.array([np.inf, 0.0])),
             dict(u=us[0], y=np.zeros(8), u_next=np.zeros(4)),
             dict(u=np.array([np.inf, 0.0]), y=np.zeros(6)),
             dict(u=list(us[0]), y=list(y_inf)),
             dict(u=us[0], y=y_inf)]
    for kw in cases:
        messages = []
        for engine in ("c", "xla"):
            with pytest.raises(ValueError) as err:
                flt.step(state, 0.0, dt=0.01, engine=engine, **kw)
            messages.append(str(err.value))
        assert messages[0] == messages[1], (kw, messages)
