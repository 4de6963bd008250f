"""Where a traced equation came from: the Python frames that made it and which of them is the user's own code,
for error messages that point at the user's line. Used by the filters (a map the second-order filter cannot
differentiate) and by the C translator (a primitive it refuses)."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

_LIEMEF_DIR = str(Path(__file__).resolve().parent)
_JAX_DIRS = tuple(str(Path(m.__file__).resolve().parent) for m in (jax, np))


def eqn_frames(eqn) -> list[tuple[str, int, str]]:
    """The Python frames (file, line, function), innermost first, that traced ``eqn`` (within its own trace:
    a call's frames continue in the equation that calls it)."""
    tb = eqn.source_info.traceback if eqn.source_info is not None else None
    if tb is None:
        return []
    return [(f.file_name, int(f.line_num), f.function_name) for f in tb.frames]


def _inside(path: str, dirs) -> bool:
    try:
        real = str(Path(path).resolve())
    except (OSError, ValueError):
        return False
    return any(real == d or real.startswith(d + "/") for d in dirs)


def _library(path: str) -> bool:
    """Whether ``path`` is JAX's, NumPy's, an installed package's or the interpreter's own code."""
    return _inside(path, _JAX_DIRS) or "site-packages" in path or path.startswith("<frozen")


def is_users(path: str) -> bool:
    """Whether the file ``path`` is the user's own code: outside liemef, JAX, NumPy and installed packages."""
    return not _library(path) and not _inside(path, (_LIEMEF_DIR,))


def user_frame(frames) -> str:
    """``file:line (function)`` of the innermost frame outside liemef, JAX and NumPy (the user's own code);
    else the innermost liemef frame; else ""."""
    outside = [f for f in frames if not _library(f[0])]
    user = [f for f in outside if is_users(f[0])]
    pick = (user or outside or [None])[0]
    return "" if pick is None else f"{pick[0]}:{pick[1]} ({pick[2]})"


def liemefs_own(frames) -> bool:
    """Whether the frames (innermost first) of an equation and the calls around it were traced by liemef's
    own code: the innermost frame outside JAX and NumPy is in liemef (a user's file, an installed package or
    no frame at all: not)."""
    for f in frames:
        if _inside(f[0], _JAX_DIRS) or f[0].startswith("<frozen"):
            continue
        return _inside(f[0], (_LIEMEF_DIR,))
    return False
