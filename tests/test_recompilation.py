"""Parameters are leaves, structure is static: new weights or noise levels reuse the compiled run and
step, and logs of different lengths compile once per length bucket (``liemef.filters.TRACES`` counts traces);
padding a log to its bucket and keeping every M-th state change nothing. These are the XLA engine's
(``engine="xla"``); the C engine's kernel reuse is tests/test_engine.py's."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import liemef
from liemef.engines import bucket
from liemef.filters import TRACES
from liemef.groups import SE2, TSO3, Rn
from liemef.systems import (
    Noise,
    Sensor,
    SensorSystem,
    attitude_field,
    attitude_gyro_bias,
    attitude_imu,
    attitude_velocity,
    inertial_navigation,
    planar_localization,
    ukfm_attitude,
)
from localization_scenario import K0, localization_log


def test_twenty_noise_levels_compile_once():
    """20 noise settings of the localization system by with_noise (GPS std and odometry stds): at most one new
    compilation of run, and the settings do change the estimates."""
    base = planar_localization()
    ts, _, us, ys, th0 = localization_log(0, t_end=5.0)
    g0 = SE2.from_coords(jnp.array([th0, 0.0, 0.0]))
    before = TRACES["run"]
    finals = []
    for i in range(20):
        sys_ = base.with_noise(gps=Noise.sample(0.5 + 0.1 * i),
                               process_noise=Noise.sample((np.radians(1.0 + 0.2 * i), 0.01, 0.01 + 0.002 * i),
                                                          rate=100.0))
        flt = liemef.MinimumEnergyFilter(sys_)
        traj = flt.run(flt.init(g0, K0), ts, us, ys, engine="xla")
        assert traj.status.ok
        finals.append(np.asarray(traj.coords()[-1]))
    print("run traces for 20 noise settings:", TRACES["run"] - before)
    assert TRACES["run"] - before <= 1
    assert np.abs(finals[0] - finals[-1]).max() > 1e-3


def _drift(g, u, t):
    return jnp.array([g.x[1], -0.1 * g.x[1] + u[0]])


def _position(g, t):
    return g.x[:1]


DRIFT = SensorSystem(Rn[2], _drift, (Sensor("p", _position, Noise.sample(0.3)),), Noise.density([0.1, 0.2]),
                     inputs=("a",))


def _drift_log(n):
    ts = 0.05 * np.arange(n)
    ys = (np.cos(ts) + 0.3 * np.random.default_rng(n).standard_normal(n))[:, None]
    ys[::7] = np.nan
    return ts, np.sin(ts)[:, None], ys


def test_log_lengths_compile_once_per_bucket():
    """Six logs of 20 to 300 samples: at most one compilation per distinct length bucket (here 3)."""
    flt = liemef.MinimumEnergyFilter(DRIFT)
    lengths = (20, 64, 65, 100, 129, 300)
    buckets = {bucket(n - 1) for n in lengths}
    before = TRACES["run"]
    for n in lengths:
        traj = flt.run(flt.init(Rn[2](jnp.zeros(2)), np.eye(2)), *_drift_log(n), engine="xla")
        assert traj.status.ok and traj.K.shape == (n, 2, 2)
    print("run traces for 6 lengths:", TRACES["run"] - before, "buckets:", sorted(buckets))
    assert len(buckets) == 3
    assert TRACES["run"] - before <= len(buckets)


def _leaves_equal(a, b) -> bool:
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
                                      for x, y in zip(la, lb, strict=True))


def test_padding_has_no_effect():
    """The first 50 samples of a 300-sample log run alone (bucket 64) equal the same samples inside the whole run
    (bucket 512) and the unpadded scan, exactly; the final state of the short run is the long run's state at
    sample 49."""
    flt = liemef.MinimumEnergyFilter(DRIFT)
    state = flt.init(Rn[2](jnp.array([1.0, -1.0])), np.eye(2))
    ts, us, ys = _drift_log(300)
    n = 50
    short, long = flt.run(state, ts[:n], us[:n], ys[:n], engine="xla"), flt.run(state, ts, us, ys, engine="xla")
    direct = jax.jit(flt.scan)(state, jnp.asarray(ts[:n]), jnp.asarray(us[:n]), jnp.asarray(ys[:n]))
    assert short.status.ok and long.status.ok
    for other in (long, direct):
        np.testing.assert_array_equal(np.asarray(short.g_hat.x), np.asarray(other.g_hat.x)[:n])
        np.testing.assert_array_equal(np.asarray(short.K), np.asarray(other.K)[:n])
    np.testing.assert_array_equal(np.asarray(short.final.g_hat.x), np.asarray(long.g_hat.x)[n - 1])
    assert int(short.final.status.steps) == n - 1 and _leaves_equal(short.final, direct.final)


def test_keep_every_is_a_subsample_of_the_full_run():
    """keep_every=M returns exactly the full run's states at ts[::M] and the same final state (M = 7: the
    299 intervals are not a multiple of M, the last state kept is at ts[294])."""
    flt = liemef.MinimumEnergyFilter(DRIFT)
    state = flt.init(Rn[2](jnp.array([1.0, -1.0])), np.eye(2))
    ts, us, ys = _drift_log(300)
    every = 7
    full, kept = flt.run(state, ts, us, ys, engine="xla"), flt.run(state, ts, us, ys, keep_every=every, engine="xla")
    np.testing.assert_array_equal(np.asarray(kept.ts), ts[::every])
    np.testing.assert_array_equal(np.asarray(kept.g_hat.x), np.asarray(full.g_hat.x)[::every])
    np.testing.assert_array_equal(np.asarray(kept.K), np.asarray(full.K)[::every])
    assert _leaves_equal(kept.final, full.final)


def test_step_compiles_once_for_two_weight_sets():
    """Two systems built separately with different noise levels (not with_noise: new objects, new functions
    nowhere): step compiles once for both (and not again on later steps), and the weights change the estimates."""

    def drift_system(p_std, process_std):
        return SensorSystem(Rn[2], _drift, (Sensor("p", _position, Noise.sample(p_std)),), Noise.density(process_std),
                            inputs=("a",))

    a = liemef.MinimumEnergyFilter(drift_system(0.3, [0.1, 0.2]))
    b = liemef.MinimumEnergyFilter(drift_system(0.05, [1.0, 0.5]))
    before = TRACES["step"]
    states = []
    for flt in (a, b):
        st = flt.init(Rn[2](jnp.array([1.0, 0.0])), np.eye(2))
        for k in range(5):
            st = flt.step(st, 0.05 * k, np.array([0.3]), np.array([0.2 * k]), 0.05, engine="xla")
        assert st.status.ok, st.status.message()
        states.append(np.asarray(st.g_hat.x))
    print("step traces for two weight sets:", TRACES["step"] - before)
    assert TRACES["step"] - before <= 1
    assert np.abs(states[0] - states[1]).max() > 1e-3


def _structure(system):
    """What every compiled program of a filter of ``system`` is keyed by: its static part and its leaves' tree."""
    dyn, static = eqx.partition(liemef.MinimumEnergyFilter(system), eqx.is_array)
    return jax.tree_util.tree_structure(dyn), static


def test_a_recordings_constants_are_data():
    """Dip, gravity, field norm, landmarks and time constants are array leaves of the ready systems: two
    recordings' values are one structure (one XLA program; one C kernel where their exact zeros agree, as a
    dip's always do), and they do change the outputs."""
    pairs = [(attitude_gyro_bias(dip=1.1), attitude_gyro_bias(dip=1.2)),
             (attitude_imu(dip=1.1, gravity=9.80, field=48.0), attitude_imu(dip=1.2, gravity=9.81, field=50.0)),
             (attitude_velocity(dip=1.1, gravity=9.80, field=48.0),
              attitude_velocity(dip=1.2, gravity=9.81, field=50.0)),
             (attitude_field(dip=1.1, gravity=9.80, field=48.0, world_tau=2.0),
              attitude_field(dip=1.2, gravity=9.81, field=50.0, world_tau=3.0)),
             (inertial_navigation(landmarks=[[1.0, 2.0, 3.0]], mag_std=0.05, dip=1.1, gravity=9.80),
              inertial_navigation(landmarks=[[4.0, 5.0, 6.0]], mag_std=0.05, dip=1.2, gravity=9.81)),
             (ukfm_attitude(gravity=9.80, field=(0.3, 0.0, -0.9)), ukfm_attitude(gravity=9.82, field=(0.4, 0.1, -0.9)))]
    for a, b in pairs:
        assert _structure(a) == _structure(b)
        g = a.group.exp(0.1 * jnp.arange(1.0, a.group.tangent_dim + 1.0))
        assert np.abs(np.asarray(a.output(g, 0.0)) - np.asarray(b.output(g, 0.0))).max() > 1e-3
    # the bounded-velocity dynamics read their gravity
    a, b = pairs[2]
    g, u = a.group.identity(), jnp.array([0.0, 0.0, 0.0, 0.0, 0.0, 9.81])
    np.testing.assert_allclose(np.asarray(b.dynamics(g, u, 0.0))[6:], 0.0, atol=1e-15)
    np.testing.assert_allclose(np.asarray(a.dynamics(g, u, 0.0))[6:], [0.0, 0.0, 0.01], atol=1e-12)


def test_two_dips_compile_once():
    """Two recordings' dips through the XLA engine: at most one trace of run, and different estimates."""
    ts = 0.01 * np.arange(50)
    us = 0.1 * np.ones((50, 3))
    ys = np.tile([0.0, 0.1, 0.99, 0.0, 0.4, -0.9], (50, 1))
    before = TRACES["run"]
    finals = []
    for dip in (1.1, 1.2):
        flt = liemef.MinimumEnergyFilter(attitude_gyro_bias(dip=dip))
        traj = flt.run(flt.init(TSO3.identity(), 0.1 * np.eye(6)), ts, us, ys, engine="xla")
        assert traj.status.ok
        finals.append(np.asarray(traj.coords()[-1]))
    assert TRACES["run"] - before <= 1
    assert np.abs(finals[0] - finals[1]).max() > 1e-4


def test_building_a_ready_system_and_its_filter_compiles_few_xla_programs(tmp_path):
    """Outside a trace each jax.numpy operation on a new shape is an XLA compile of its own (tens of ms each):
    a system's constant matrices (B, R, D, Q, the information) and the filter's checks are NumPy there. In a
    fresh process with empty caches, building ``attitude_velocity`` and its filter compiles 21 programs (the
    side Jacobians of the error's choice, the sensors' checks, a few conversions); it compiled 51 when those
    matrices were jax.numpy. JAX's public monitoring counts the compiles."""
    import os
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import jax
        count = [0]
        def seen(name, secs, **kw):
            if name == "/jax/core/compile/backend_compile_duration":
                count[0] += 1
        jax.monitoring.register_event_duration_secs_listener(seen)
        from liemef.filters import MinimumEnergyFilter
        from liemef.systems import attitude_velocity
        before = count[0]
        MinimumEnergyFilter(attitude_velocity(imu_rate=285.7))
        print(count[0] - before)
    """)
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax"), "LIEMEF_CACHE_DIR": str(tmp_path / "k")}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr
    compiles = int(res.stdout.split()[-1])
    assert 0 < compiles <= 25, compiles
