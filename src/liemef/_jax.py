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
* :func:`keep_programs`: a persistent compilation cache of liemef's own (``compilation_cache.get_file_cache``,
  where JAX opens its cache, and two flags of that module; JAX's public configuration can only point its own
  file cache at a folder; fallback: no persistent cache, every program compiled in each process).

The supported JAX versions are the range of ``pyproject.toml``, the versions these APIs were checked on.
"""

from __future__ import annotations

import importlib
import os

import jax

INTERNALS = {"backends_started": ("xla_bridge", "backends_are_initialized"),
             "eager_context": ("core", "eval_context"),
             "dce_jaxpr": ("interpreters.partial_eval", "dce_jaxpr"),
             "keep_programs": ("compilation_cache", "get_file_cache")}
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


def keep_programs(cache, path) -> bool:
    """Make ``cache`` (``get(key) -> bytes | None``, ``put(key, bytes)``: :class:`liemef._cachedirs.ProgramCache`)
    JAX's persistent compilation cache for this process, in the folder ``path``, for every program however quick
    to compile (unless ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` says otherwise). JAX opens its cache at its
    first compile, by ``compilation_cache.get_file_cache(path)``, which gives ``cache`` instead of JAX's own file
    cache. True if done; False where this JAX has no such internal, or where this process has already opened a
    cache or compiled a program (JAX decides once whether it uses one)."""
    opener = _internal(*INTERNALS["keep_programs"])
    if opener is None:
        return False
    module = importlib.import_module("jax._src.compilation_cache")
    if getattr(module, "_cache_initialized", True) or getattr(module, "_cache_checked", True):
        return False
    module.get_file_cache = lambda folder: (cache, folder)
    jax.config.update("jax_compilation_cache_dir", str(path))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return True
