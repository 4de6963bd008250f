"""The user's cache folders: where liemef keeps what it builds (the C engine's kernels), and the check that a
folder is private before anything built there is loaded.

A cache of native code is trusted code: whoever can write to it can make the user's process run anything. So
:func:`refusal` accepts a folder only if it is the user's own, writable by nobody else, and not inside a folder
in which another user may rename or replace it (``docs/engines.md``, the kernel cache's threat model). Standard
library only: the CLI's process reads it before JAX is imported.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path


def cache_dir() -> Path:
    """Where built kernels are kept: ``$LIEMEF_CACHE_DIR``, else ``$XDG_CACHE_HOME/liemef/kernels``, else
    ``~/.cache/liemef/kernels`` (as asked for: :func:`folder` checks it)."""
    if os.environ.get("LIEMEF_CACHE_DIR"):
        return Path(os.environ["LIEMEF_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "liemef" / "kernels"


def refusal(path: Path) -> tuple[Path | None, str | None]:
    """``(the folder's resolved path, None)`` if ``path`` may hold kernels (created 0700 if it does not exist),
    else ``(None, why not)``: not a folder, not the user's, writable by group or others, or inside a folder in
    which another user may rename or replace it."""
    uid = os.geteuid()
    try:
        if not os.path.lexists(path):
            _create(Path(path))
        real = Path(os.path.realpath(path))
        st = os.stat(real)
    except OSError as err:
        return None, f"it cannot be created or read ({err.strerror or err})"
    if not stat.S_ISDIR(st.st_mode):
        return None, "it is not a folder"
    if st.st_uid != uid:
        return None, f"it is owned by uid {st.st_uid}, not by you (uid {uid})"
    if st.st_mode & 0o022:
        return None, f"it is writable by {_who(st.st_mode)} (mode {stat.S_IMODE(st.st_mode):04o})"
    for parent in real.parents:
        try:
            pst = os.stat(parent)
        except OSError as err:
            return None, f"its parent {parent} cannot be read ({err.strerror or err})"
        if pst.st_uid not in (0, uid):
            return None, f"its parent {parent} is owned by uid {pst.st_uid}, who may replace it"
        if pst.st_mode & 0o022 and not pst.st_mode & stat.S_ISVTX:
            return None, (f"its parent {parent} is writable by {_who(pst.st_mode)} without the sticky bit "
                          f"(mode {stat.S_IMODE(pst.st_mode):04o}), so another user may replace it")
    return real, None


def _who(mode: int) -> str:
    return " and ".join(w for w, bit in (("group", 0o020), ("others", 0o002)) if mode & bit)


def _create(path: Path) -> None:
    """``path`` as a new folder, 0700 whatever the umask, and so each missing parent (as ``~/.cache/liemef``)."""
    missing = []
    while not os.path.lexists(path):
        missing.append(path)
        path = path.parent
    for p in reversed(missing):
        try:
            os.mkdir(p, 0o700)
        except FileExistsError:  # made meanwhile by another process: checked as any existing folder
            continue
        os.chmod(p, 0o700)


__all__ = ["cache_dir", "refusal"]
