"""The JAX internals liemef uses sit behind one adapter (``liemef._jax``): no other module imports ``jax._src``,
each internal exists on the JAX installed (so its fallback is not silently taken), the installed JAX is in
the range ``pyproject.toml`` supports, and each fallback works where the internal is gone."""

import tomllib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from packaging.requirements import Requirement
from packaging.version import Version

import liemef._jax as adapter

ROOT = Path(__file__).resolve().parents[1]


def _requirements() -> dict[str, Requirement]:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return {r.name: r for r in map(Requirement, deps)}


def test_the_installed_jax_is_a_supported_one():
    reqs = _requirements()
    import jaxlib

    for name, version in (("jax", jax.__version__), ("jaxlib", jaxlib.__version__)):
        spec = reqs[name].specifier
        assert any(s.operator == "<" for s in spec), f"{name}: expected an upper bound, got {spec}"
        assert Version(version) in spec, f"{name} {version} is outside the supported {spec}"


def test_only_the_adapter_imports_jax_internals():
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "src" / "liemef").rglob("*.py")
             if "jax._src" in p.read_text() and p.name != "_jax.py"]
    assert found == []


def test_every_internal_exists_on_this_jax():
    """Each lookup of the adapter's one table finds its internal here, so no fallback is taken silently."""
    assert set(adapter.INTERNALS) == {"backends_started", "eager_context", "dce_jaxpr", "keep_programs"}
    for function, (module, name) in adapter.INTERNALS.items():
        assert callable(adapter._internal(module, name)), (function, module, name)


def _closed():
    """A jaxpr of (x, y) -> 2 x with a dead y + 1."""
    def f(x, y):
        _ = y + 1.0
        return (x * 2.0,)
    return jax.make_jaxpr(f)(1.0, 2.0)


def test_dead_code_goes_and_every_input_stays():
    closed = _closed()
    out, used = adapter.dce_jaxpr(closed)
    assert len(out.jaxpr.eqns) < len(closed.jaxpr.eqns)
    assert len(out.jaxpr.invars) == 2 and list(used) == [True, True]
    assert float(jax.core.eval_jaxpr(out.jaxpr, out.consts, 3.0, 5.0)[0]) == 6.0


def _computed_inside_a_trace():
    """What ``jnp.ones(2) * 3`` is inside :func:`liemef._jax.eager_context` within a jitted function's trace."""
    seen = []

    @jax.jit
    def f(x):
        with adapter.eager_context():
            seen.append(jnp.ones(2) * 3.0)
        return x

    f(1.0)
    return seen[0]


def test_eager_context_computes_concretely_inside_a_trace():
    value = _computed_inside_a_trace()
    assert isinstance(value, jax.Array) and not isinstance(value, jax.core.Tracer)
    np.testing.assert_array_equal(np.asarray(value), [3.0, 3.0])


def test_backends_started_after_a_computation():
    jnp.ones(1).block_until_ready()
    assert adapter.backends_started() is True


def test_each_fallback_works_without_its_internal(monkeypatch):
    monkeypatch.setattr(adapter, "_internal", lambda module, name: None)
    closed = _closed()
    out, used = adapter.dce_jaxpr(closed)
    assert out is closed and list(used) == [True, True]
    assert adapter.backends_started() is False
    value = _computed_inside_a_trace()  # by the public ensure_compile_time_eval
    assert not isinstance(value, jax.core.Tracer)
    np.testing.assert_array_equal(np.asarray(value), [3.0, 3.0])


def test_the_adapter_finds_what_it_needs():
    assert adapter._internal("core", "eval_context") is not None
    assert adapter._internal("core", "no_such_thing") is None
    assert adapter._internal("no_such_module", "x") is None


def test_the_compilation_cache_state_keep_programs_sets_exists():
    """keep_programs reads two flags of jax._src.compilation_cache and gives JAX its cache where JAX opens one."""
    import importlib
    import inspect

    module = importlib.import_module("jax._src.compilation_cache")
    for name in ("_cache_initialized", "_cache_checked"):
        assert isinstance(getattr(module, name), bool), name
    assert "get_file_cache(path)" in inspect.getsource(module._initialize_cache)  # where JAX opens its cache
