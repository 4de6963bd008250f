"""Which engine computes a call: ``engine``, ``$LIEMEF_ENGINE`` or ``"auto"``, and the C kernel it gives."""

from __future__ import annotations

import functools
import os
import sys
import warnings

from .. import _side
from .._frames import is_users
from ..codegen import EngineWarning, compiler, kernel_for
from ..systems._traced import is_traced

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
        engine = _environment() or "auto"
        where = "LIEMEF_ENGINE"
    else:
        where = "engine"
    if engine not in ENGINES:
        raise ValueError(f"{where}: expected one of {list(ENGINES)}, got {engine!r}")
    return engine


try:  # os.environ's own table (CPython's, on every platform): a read in 0.1 us, not 1-2 us through the Mapping
    _ENVIRON, _KEY = os.environ._data, os.environ.encodekey("LIEMEF_ENGINE")
except AttributeError:  # pragma: no cover - another Python
    _ENVIRON = None


def _environment() -> str | None:
    """``$LIEMEF_ENGINE`` as ``os.environ`` holds it now (the online step reads it at each call)."""
    if _ENVIRON is None:  # pragma: no cover
        return os.environ.get("LIEMEF_ENGINE")
    value = _ENVIRON.get(_KEY)
    return None if value is None else os.environ.decodevalue(value)


@functools.cache
def _no_compiler() -> bool:
    return compiler() is None


def kernel(flt, engine: str | None):
    """The C kernel the engine choice gives ``flt`` (None: XLA), kept beside the instance (liemef._side): the
    engine's decision alone, the same for every filter (a filter says how its interval advances, not what runs
    it). ``"auto"`` without a C compiler, or with a kernel that cannot be built, warns (:class:`EngineWarning`,
    once per filter) and gives None."""
    return _entry(flt, engine)[0]


_XLA = (None, None, None, None, None)
LAZY = object()
"""The fast step's ``ctl`` in a new entry: made on the first online step (:func:`fast_ctl`), so that a filter
that only runs logs never builds the extension."""


def _entry(flt, engine: str | None, check=None, args=()) -> tuple:
    """:func:`kernel`'s decision as kept beside ``flt``: (kernel, theta, theta's address, the error of a fallback,
    the fast step's ``ctl``); all None for XLA. ``check(*args)`` runs before a kernel is built (a first call's
    boundary check)."""
    engine = _asked(engine)
    if engine == "xla":
        return _XLA
    cached = _side.get(flt, "kernel")
    if cached is not None:
        if cached[0] is None and engine == "c":
            raise cached[3]  # "auto" fell back earlier: "c" says why, as on a first call
        return cached
    if check is not None:
        check(*args)
    error = None
    try:
        if engine == "auto" and _no_compiler():
            raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
        kern = kernel_for(flt)
    except Exception as err:  # noqa: BLE001 - auto falls back to XLA, saying why; "c" raises
        if engine == "c":
            raise
        warnings.warn(f"the C engine is not available for {type(flt).__name__} ({type(err).__name__}: "
                      f"{str(err).splitlines()[0] if str(err) else ''}); running with XLA", EngineWarning,
                      stacklevel=_users_level())
        kern, error = None, err
    if is_traced(flt):
        return (kern, None, None, None, None)  # a traced filter (scan under a transformation): parameters as data
    if kern is None:
        entry = (None, None, None, error, None)
    else:
        theta = kern.theta(flt)
        entry = (kern, theta, theta.ctypes.data, None, LAZY)
    _side.put(flt, "kernel", entry)
    return entry


def _users_level() -> int:
    """``warnings.warn``'s stacklevel, for its caller, of the innermost frame in the user's code (the user's
    ``run``, ``step``, ``online`` or ``scan`` call: each reaches the warning by another path); 1 if none."""
    frame, level = sys._getframe(1), 1
    while frame is not None and not is_users(frame.f_code.co_filename):
        frame, level = frame.f_back, level + 1
    return level if frame is not None else 1


def theta(flt):
    """The packed parameters of ``flt`` for its C kernel (after :func:`kernel`)."""
    return _side.get(flt, "kernel")[1]


def theta_address(flt) -> int:
    """The address of :func:`theta`'s vector, for the C step."""
    return _side.get(flt, "kernel")[2]


def fast_ctl(flt):
    """The fast step's ``ctl`` for ``flt``'s kernel (:meth:`~liemef.codegen._kernel.Kernel.fast_ctl`; None:
    the ctypes path), made on first use and kept in its entry."""
    entry = _side.get(flt, "kernel")
    if entry[4] is not LAZY:
        return entry[4]
    ctl = entry[0].fast_ctl(entry[2])
    _side.put(flt, "kernel", entry[:4] + (ctl,))
    return ctl
