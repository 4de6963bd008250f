"""The JAX internals liemef uses, behind one adapter: the only module that reads ``jax._src``.

Three private APIs, each with a public fallback, so that a JAX without one still runs (slower or with a
weaker guarantee), and ``tests/test_jax_adapter.py`` fails loudly on a JAX where an internal has moved:

* :func:`backends_started`: whether XLA's backends have started (``xla_bridge.backends_are_initialized``), so
  that :mod:`liemef._config` sets ``XLA_FLAGS`` only while they still read it (fallback: not started);
* :func:`eager_context`: JAX's own evaluation context, in which JAX computes eagerly even inside an outer trace
  (``core.eval_context``; fallback: the public ``ensure_compile_time_eval``, which also folds constants);
* :func:`dce_jaxpr`: dead-code elimination of a closed jaxpr keeping every input
  (``interpreters.partial_eval.dce_jaxpr``; fallback: the jaxpr as it is, and the C compiler removes the dead
  code);
* :func:`keep_programs`: a persistent compilation cache of liemef's own (``compilation_cache``'s module state,
  which JAX's public configuration can only point at a folder of JAX's own file cache; fallback: no persistent
  cache, every program compiled in each process).

The supported JAX versions are the range of ``pyproject.toml``, the versions these APIs were checked on.
"""

from __future__ import annotations

import importlib

import jax

INTERNALS = {"backends_started": ("xla_bridge", "backends_are_initialized"),
             "eager_context": ("core", "eval_context"),
             "dce_jaxpr": ("interpreters.partial_eval", "dce_jaxpr"),
             "keep_programs": ("compilation_cache", "_initialize_cache")}
"""The one table of the internals: per function of this module, ``jax._src.<module>`` and the name it reads."""


def _internal(module: str, name: str):
    """``jax._src.<module>.<name>``, or None where this JAX has no such thing."""
    try:
        return getattr(importlib.import_module(f"jax._src.{module}"), name)
    except (ImportError, AttributeError):
        return None


def backends_started() -> bool:
    """Whether any XLA backend has started (then ``XLA_FLAGS`` is no longer read)."""
    started = _internal(*INTERNALS["backends_started"])
    return bool(started()) if started is not None else False


def eager_context():
    """A context in which JAX computes eagerly, also when asked from inside an outer trace."""
    context = _internal(*INTERNALS["eager_context"])
    return context() if context is not None else jax.ensure_compile_time_eval()


def dce_jaxpr(closed):
    """``(closed, used)``: the closed jaxpr without the equations no output needs, every input kept (``used``:
    one flag per input, all True), by JAX's own pass; the jaxpr unchanged without it."""
    dce = _internal(*INTERNALS["dce_jaxpr"])
    try:
        jaxpr, used = dce(closed.jaxpr, [True] * len(closed.jaxpr.outvars), instantiate=True)
    except Exception:  # noqa: BLE001 - an internal API (None, or a new signature): the C compiler removes the code
        return closed, [True] * len(closed.jaxpr.invars)
    return jax.extend.core.ClosedJaxpr(jaxpr, closed.consts), used


def keep_programs(cache) -> bool:
    """Make ``cache`` (``get(key) -> bytes | None``, ``put(key, bytes)``: :class:`liemef._cachedirs.ProgramCache`)
    JAX's persistent compilation cache for this process, for every program however quick to compile. True if
    it is; False where this JAX has no such internal, or where this process already has a cache or has already
    compiled a program (JAX decides once whether it uses one)."""
    try:
        module = importlib.import_module("jax._src.compilation_cache")
        lock = module._cache_initialized_mutex
        with lock:
            if module._cache is not None or module._cache_initialized or module._cache_checked:
                return False
            module._cache, module._cache_initialized = cache, True
    except (ImportError, AttributeError):
        return False
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return True

