"""The online step's one-call path from Python to a kernel (``_fast_step.c``, a small CPython extension).

A ctypes call converts each argument in Python (about 0.25 us each on a slow core; ``kernel_step`` takes seven)
and the samples must first be copied into C memory by NumPy (1.5-3 us): most of an online step whose kernel
runs in 2-3 us. The extension's ``step(ctl, x, xo, t, u, y, dt, gap)`` reads its arguments through the C-API
and the buffer protocol and calls ``kernel_step`` by its address: the same kernel, the same numbers. Whatever it
does not take as it is (a sample that is not a C-contiguous float64 vector of its length, a non-finite ``t``, a
``dt`` that is not finite and > 0) it leaves alone, returning :data:`FALLBACK`: the caller's checked path then
names the argument in its ValueError, as before.

The extension does not depend on the kernel: it is built once per Python, compiler and generator (with the
Python headers; without them, or without a compiler, :func:`module` is None and the ctypes path serves), kept
in the kernel cache with a manifest and imported from the checked bytes (:func:`._cache.load_module`).
"""

from __future__ import annotations

import ctypes
import hashlib
import sys
import sysconfig
import tempfile
import threading
from pathlib import Path

import numpy as np

from . import _cache, _elf
from ._export import compiler, run_compiler

FALLBACK = -1000
"""What ``step`` returns when it did nothing: the caller takes its checked path."""

_SOURCE = Path(__file__).with_name("_fast_step.c")
_NAME = "_liemef_fast_step"
FLAGS = ("-O2", "-fPIC", "-shared")
"""The extension's compiler flags (with ``-I`` the Python and NumPy headers): it only copies and calls."""

_STATE: dict = {}
_LOCK = threading.Lock()


def module():
    """The loaded extension (built and cached on first use), or None where it cannot be built (``error()``
    says why)."""
    got = _STATE.get("module")
    if got is not None or "error" in _STATE:
        return got
    with _LOCK:
        if "module" not in _STATE and "error" not in _STATE:
            try:
                _STATE["module"] = _cache.load_module(_library(), _NAME)
            except Exception as err:  # noqa: BLE001 - the ctypes path serves
                _STATE["error"] = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
    return _STATE.get("module")


def error() -> str | None:
    """Why :func:`module` is None (None if it loaded or was not asked for)."""
    return _STATE.get("error")


def address(fn) -> int:
    """The address of a ctypes foreign function (``kernel_step``), for ``step``'s ``ctl``."""
    return ctypes.cast(fn, ctypes.c_void_p).value


def _library() -> _cache.Library:
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler found ($CC, cc, gcc or clang)")
    _elf.host()  # as for the kernels: a system whose libraries the cache cannot check is refused by name
    include = sysconfig.get_paths()["include"]
    if not Path(include, "Python.h").is_file():
        raise RuntimeError(f"no Python.h in {include}")
    np_include = np.get_include()
    source = _SOURCE.read_text()
    key = hashlib.sha256("\0".join([source, sys.version, sysconfig.get_config_var("EXT_SUFFIX") or "", cc,
                                    include, np_include, np.__version__, *FLAGS]).encode()).hexdigest()[:24]
    lib = _cache.folder() / f"fast_{key}.so"
    got = _cache.read_verified(lib, key, "fast")
    if got is not None:
        return got
    with tempfile.TemporaryDirectory(dir=lib.parent, prefix=".build.") as tmp:
        Path(tmp, "fast.c").write_text(source)
        run_compiler([*FLAGS, f"-I{include}", f"-I{np_include}", "-o", "fast.so", "fast.c"], cwd=tmp)
        data = Path(tmp, "fast.so").read_bytes()
    return _cache.install(lib, data, key, "fast", {"compiler": cc, "flags": list(FLAGS), "python": sys.version})
