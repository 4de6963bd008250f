"""Which engine computes a call: ``engine``, ``$LIEMEF_ENGINE`` or ``"auto"``, and the C kernel it gives."""

from __future__ import annotations

import functools
import os
import warnings

import jax

from .. import _side
from ..codegen import _kernel as kmod
from ..codegen._cache import EngineWarning
from ..codegen._export import compiler

ENGINES = ("auto", "c", "xla")
"""How :meth:`~AbstractFilter.run` and :meth:`~AbstractFilter.step` compute: ``"c"`` (a compiled C kernel of
the interval, :mod:`liemef.codegen`), ``"xla"`` (jitted JAX) or ``"auto"``: C for every filter (the
minimum-energy filter and the baselines alike) where a C compiler is found and the filter's interval
translates, else XLA (with an :class:`EngineWarning` saying why)."""


def engine_of(engine: str | None) -> str:
    """The engine a call uses: ``engine``, else ``$LIEMEF_ENGINE``, else ``"auto"`` (ValueError naming the
    argument if unknown); ``"auto"`` without a C compiler is ``"xla"``."""
    engine = _asked(engine)
    if engine == "auto" and _no_compiler():
        return "xla"
    return engine


def _asked(engine: str | None) -> str:
    """The engine asked for, checked (``"auto"`` kept as it is)."""
    if engine is None:
        engine = os.environ.get("LIEMEF_ENGINE") or "auto"
        where = "LIEMEF_ENGINE"
    else:
        where = "engine"
    if engine not in ENGINES:
        raise ValueError(f"{where}: expected one of {list(ENGINES)}, got {engine!r}")
    return engine


@functools.cache
def _no_compiler() -> bool:
    return compiler() is None


def kernel(flt, engine: str | None):
    """The C kernel the engine choice gives ``flt`` (None: XLA), kept beside the instance (liemef._side): the
    engine's decision alone, the same for every filter (a filter says how its interval advances, not what runs
    it). ``"auto"`` without a C compiler, or with a kernel that cannot be built, warns (:class:`EngineWarning`,
    once per filter) and gives None."""
    engine = _asked(engine)
    if engine == "xla":
        return None
    cached = _side.get(flt, "kernel")
    if cached is not None:
        if cached[0] is None and engine == "c":
            raise cached[3]  # "auto" fell back earlier: "c" says why, as on a first call
        return cached[0]
    error = None
    try:
        if engine == "auto" and _no_compiler():
            raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
        kern = kmod.kernel_for(flt)
    except Exception as err:  # noqa: BLE001 - auto falls back to XLA, saying why; "c" raises
        if engine == "c":
            raise
        warnings.warn(f"the C engine is not available for {type(flt).__name__} ({type(err).__name__}: "
                      f"{str(err).splitlines()[0] if str(err) else ''}); running with XLA", EngineWarning,
                      stacklevel=4)
        kern, error = None, err
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(flt)):
        return kern  # a traced filter (scan under a transformation): its parameters come as data
    theta = kern.theta(flt) if kern is not None else None
    _side.put(flt, "kernel", (kern, theta, theta.ctypes.data if kern is not None else None, error))
    return kern


def theta(flt):
    """The packed parameters of ``flt`` for its C kernel (after :func:`kernel`)."""
    return _side.get(flt, "kernel")[1]


def theta_address(flt) -> int:
    """The address of :func:`theta`'s vector, for the C step."""
    return _side.get(flt, "kernel")[2]
