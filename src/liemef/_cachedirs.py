"""The user's cache folders: where liemef keeps what it builds (the C engine's kernels, XLA's compiled programs),
and the check that a folder is private before anything built there is loaded.

A cache of native code is trusted code: whoever can write to it can make the user's process run anything. So
:func:`refusal` accepts a folder only if it is the user's own, writable by nobody else, and not inside a folder
in which another user may rename or replace it (``docs/engines.md``, the kernel cache's threat model). Standard
library only: the CLI's process reads it before JAX is imported.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import stat
import tempfile
import threading
import time
from pathlib import Path

XLA_CACHE = "LIEMEF_XLA_CACHE"
"""The environment variable that asks for the XLA program cache (``1``; the command line sets it, and
:mod:`liemef._config` reads it)."""


def cache_dir() -> Path:
    """Where built kernels are kept: ``$LIEMEF_CACHE_DIR``, else ``$XDG_CACHE_HOME/liemef/kernels``, else
    ``~/.cache/liemef/kernels`` (as asked for: :func:`refusal` checks it before use)."""
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


@functools.cache
def host() -> str:
    """What code built for this machine depends on: the machine and its CPU's features (``/proc/cpuinfo``)."""
    flags = ""
    try:
        with open("/proc/cpuinfo") as fh:
            flags = next((ln for ln in fh if ln.startswith(("flags", "Features"))), "")
    except OSError:
        pass
    return f"{platform.machine()} {flags}"


def xla_dir() -> Path:
    """Where XLA's compiled programs are kept for the command line (:class:`ProgramCache`): ``xla-<host>`` in
    :func:`cache_dir`, one folder per CPU (XLA compiles for the host's features, and JAX's key names only "cpu"),
    so that a home folder shared by several machines never serves one the programs of another."""
    return cache_dir() / f"xla-{hashlib.sha256(host().encode()).hexdigest()[:12]}"


PROGRAM_CACHE_BYTES = 256 << 20
"""The most the XLA program cache holds (256 MiB; a ready system's programs take about 1 MB): past it, the
entries read or written longest ago go until it holds three quarters of it."""


class ProgramCache:
    """XLA's compiled programs on disk, for JAX's persistent compilation cache (:func:`liemef._jax.keep_programs`),
    in a folder :func:`refusal` accepts.

    JAX's own file cache writes an entry in place and never replaces one: a process killed while writing leaves a
    truncated program that every later process fails to read, with a warning, and compiles again. Here an entry
    is the SHA-256 of the program followed by the program, written to a temporary file in the folder and renamed
    into place, so that a reader sees a whole entry or none. An entry whose digest does not match (a disk error)
    is removed and read as absent. JAX writes a program only after compiling it, that is when the entry was
    absent or did not serve (a program this XLA cannot load): the write replaces it. A read marks its entry used
    (its modification time). Past :data:`PROGRAM_CACHE_BYTES` (the folder's size counted once per process, then
    kept up to date by this process's writes), the entries used longest ago are removed, and so are temporary
    files an hour old (a write cut short)."""

    SUFFIX = ".xla"

    def __init__(self, path: Path, max_bytes: int = PROGRAM_CACHE_BYTES):
        self._path = Path(path)
        self.max_bytes = int(max_bytes)
        self.hits = self.misses = self.writes = 0
        self._bytes: int | None = None  # the folder's size as this process knows it (None: not counted yet)
        self._lock = threading.Lock()
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(after_in_child=self._after_fork)

    def _after_fork(self) -> None:
        self._lock = threading.Lock()  # a lock held by another thread at the fork is never released in the child

    def _file(self, key: str) -> Path:
        if not key or "/" in key or key.startswith("."):
            raise ValueError(f"key: expected a file name, got {key!r}")
        return self._path / f"{key}{self.SUFFIX}"

    def get(self, key: str) -> bytes | None:
        """The program kept under ``key``, or None (absent, or damaged and now removed)."""
        f = self._file(key)
        try:
            data = f.read_bytes()
        except OSError:
            self.misses += 1
            return None
        digest, value = data[:32], data[32:]
        if len(data) < 32 or hashlib.sha256(value).digest() != digest:
            f.unlink(missing_ok=True)
            self.misses += 1
            return None
        try:
            os.utime(f)
        except OSError:
            pass
        self.hits += 1
        return value

    def put(self, key: str, value: bytes) -> None:
        """Keep ``value`` under ``key``, whole or not at all, in place of what was there."""
        f = self._file(key)
        fd, tmp = tempfile.mkstemp(dir=self._path, prefix=".tmp-")
        try:
            with os.fdopen(fd, "wb") as out:
                out.write(hashlib.sha256(value).digest())
                out.write(value)
            os.replace(tmp, f)
        except OSError:
            Path(tmp).unlink(missing_ok=True)
            return
        self.writes += 1
        with self._lock:
            if self._bytes is None:
                self._bytes = self._scan(evict=False)
            else:
                self._bytes += 32 + len(value)
            if self._bytes > self.max_bytes:
                self._bytes = self._scan(evict=True)

    def _scan(self, evict: bool) -> int:
        """The entries' total size; with ``evict``, after removing the least recently used down to three
        quarters of the bound, and temporary files an hour old."""
        entries = []
        stale = time.time() - 3600.0
        for e in os.scandir(self._path):
            try:
                st = e.stat(follow_symlinks=False)
            except OSError:
                continue
            if e.name.startswith(".tmp-"):
                if evict and st.st_mtime < stale:  # a write cut short an hour ago or more
                    Path(e.path).unlink(missing_ok=True)
            elif e.name.endswith(self.SUFFIX):
                entries.append((st.st_mtime_ns, st.st_size, e.path))
        total = sum(size for _, size, _ in entries)
        if evict and total > self.max_bytes:
            for _, size, path in sorted(entries):
                if total <= 3 * self.max_bytes // 4:
                    break
                try:
                    os.unlink(path)
                    total -= size
                except OSError:
                    continue
        return total


__all__ = ["PROGRAM_CACHE_BYTES", "XLA_CACHE", "ProgramCache", "cache_dir", "host", "refusal", "xla_dir"]
