"""The online step's one-call path (:mod:`liemef.codegen._fast`, issue 22): ``flt.step`` and
``flt.online(state).step`` by the CPython extension are the ctypes path's computation bit for bit, take what they
cannot read as it is to the checked path, and refuse bad input with the same ValueError. The states it reads
back (:func:`liemef.codegen._kernel._state_reader` with the extension's ``leaves``) are the leaves NumPy's
indexing gives: the same types, dtypes, shapes and values.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import liemef
from liemef import codegen
from liemef.codegen import _fast
from liemef.studies.experiments import SYSTEMS
from trees import assert_trees_close

pytestmark = pytest.mark.skipif(codegen.compiler() is None or _fast.module() is None,
                                reason=f"no C compiler or no Python headers ({_fast.error()})")


def _setup(seed=0, n=40):
    flt = liemef.MinimumEnergyFilter(SYSTEMS["tse2"].make())
    rng = np.random.default_rng(seed)
    g0 = flt.system.group.identity()
    state = flt.init(g0, np.eye(flt.n))
    y0 = np.asarray(flt.system.output(g0, 0.0))
    us = 0.3 * rng.standard_normal((n, flt.system.input_dim))
    ys = y0 + 0.05 * rng.standard_normal((n, flt.system.output_dim))
    ys[n // 2, 1] = np.nan  # a missing component
    return flt, state, us, ys


def _chain(flt, state, us, ys, dt=1e-2):
    st, online = state, flt.online(state, engine="c")
    for k in range(len(us)):
        st = flt.step(st, k * dt, us[k], ys[k], dt, engine="c")
        assert online.step(k * dt, us[k], ys[k], dt) == 0
    return st, online.state


def test_the_fast_step_is_the_ctypes_step_bit_for_bit(monkeypatch):
    """The extension unavailable (as without Python headers): the ctypes path serves, with the same numbers."""
    flt, state, us, ys = _setup()
    with monkeypatch.context() as mp:
        mp.setattr(_fast, "_STATE", {"error": "RuntimeError: disabled by the test"})
        slow = liemef.MinimumEnergyFilter(flt.system)
        slow_step, slow_online = _chain(slow, state, us, ys)
        assert liemef.engines._select.fast_ctl(slow) is None
    assert _fast.module() is not None
    fresh = liemef.MinimumEnergyFilter(flt.system)  # a new filter: its fast ctl is made now
    fast_step, fast_online = _chain(fresh, state, us, ys)
    assert liemef.engines._select.fast_ctl(fresh) is not None
    for got in (slow_online, fast_step, fast_online):
        assert_trees_close(got, slow_step, tol=0.0)
    assert int(fast_step.status.steps) == len(us)


def test_what_the_fast_step_cannot_read_takes_the_checked_path():
    """Samples as lists, integers, float32, strided views; times as NumPy scalars, 0-d arrays or integers: the
    same numbers as float64 vectors and Python floats."""
    flt, state, us, ys = _setup(seed=1, n=2)
    ref = flt.step(state, 0.0, us[0], ys[0], 0.01, engine="c")
    wide = np.zeros((2, 2 * ys.shape[1]))
    wide[0, ::2] = ys[0]
    for t, u, y, dt in ((np.float64(0.0), us[0], ys[0], np.float64(0.01)), (np.array(0.0), us[0], ys[0], 0.01),
                        (0, list(us[0]), list(ys[0]), 0.01), (0.0, us[0], wide[0, ::2], np.array(0.01))):
        assert_trees_close(flt.step(state, t, u, y, dt, engine="c"), ref, tol=0.0)
        online = flt.online(state, engine="c")
        assert online.step(t, u, y, dt) == 0
        assert_trees_close(online.state, ref, tol=0.0)
    u32 = us[0].astype(np.float32)
    assert_trees_close(flt.step(state, 0.0, u32, ys[0], 0.01, engine="c"),
                       flt.step(state, 0.0, u32.astype(np.float64), ys[0], 0.01, engine="c"), tol=0.0)


@pytest.mark.parametrize("how", ["step", "online"])
def test_bad_input_is_refused_by_name_and_leaves_the_state(how):
    flt, state, us, ys = _setup(seed=2, n=2)
    online = flt.online(state, engine="c")
    before = online.state

    def call(t, u, y, dt):
        if how == "step":
            return flt.step(state, t, u, y, dt, engine="c")
        return online.step(t, u, y, dt)

    y_inf = ys[0].copy()
    y_inf[2] = np.inf
    for args, match in (((np.inf, us[0], ys[0], 0.01), "t: expected a finite time"),
                        ((np.nan, us[0], ys[0], 0.01), "t: expected a finite time"),
                        ((0.0, us[0], ys[0], 0.0), "dt: expected a finite time step > 0"),
                        ((0.0, us[0], ys[0], -np.inf), "dt: expected a finite time step > 0"),
                        ((0.0, us[0], ys[0], "0.01x"), "dt: expected a finite time step > 0"),
                        ((0.0, us[0], ys[0][:-1], 0.01), r"y: expected shape"),
                        ((0.0, np.array([np.inf, 0.0]), ys[0], 0.01), "u: expected finite values or NaN"),
                        ((0.0, us[0], y_inf, 0.01), "y: expected finite values or NaN")):
        with pytest.raises(ValueError, match=match):
            call(*args)
    assert_trees_close(online.state, before, tol=0.0)
    assert online.step(0.0, us[0], ys[0], 0.01) == 0


def test_the_state_reader_gives_numpy_s_leaves():
    """kernel.state(x): every leaf of the type, dtype, shape and value that indexing the packed vector and
    ``astype`` give, float arrays as views of it."""
    flt, state, us, ys = _setup(seed=3, n=3)
    st = flt.step(state, 0.0, us[0], ys[0], 0.01, engine="c")
    kern = liemef.engines.kernel(flt, "c")
    kern._reader = None  # made again, with the extension
    x = kern.pack(st)
    got = kern.state(x)
    want = jax.tree_util.tree_unflatten(kern.sdef, kern.unpack(x))
    assert jax.tree_util.tree_structure(got) == kern.sdef
    for a, b, s in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want), kern.sslots, strict=True):
        assert np.shape(a) == s.shape and np.asarray(a).dtype == s.dtype
        np.testing.assert_array_equal(a, b)
        if s.shape == ():
            assert type(a) is s.dtype.type  # a NumPy scalar, as x[i] and astype give
        elif s.dtype == np.float64:
            assert np.shares_memory(a, x)
