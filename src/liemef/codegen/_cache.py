r"""The C engine's kernel cache on disk: a private folder, every library checked against its manifest and for its
own structure before it is loaded, and loaded from the very bytes that were checked.

A kernel's file name is a hash of public inputs (the jaxpr, the compiler, its flags), so anyone can predict
it. What keeps a file planted there from running in the user's process:

* **The folder is private.** :func:`folder` creates it 0700, and refuses an existing one that is not a folder,
  is not owned by the user, or is writable by group or others, or one that sits in a folder someone else may
  rename things in (a parent writable by others without the sticky bit, or owned by another user). A refused
  folder is not used at all: the kernels are built into a private temporary folder for this process (removed
  at exit), with an :class:`EngineWarning` saying why, once.
* **Every library has a manifest**, written by the build after the library: its size, its SHA-256 and what
  it was built for (the file name, the filter's key, the build's kind). :func:`read_verified` reads a library
  (a regular file of the user's, opened without following links) and its manifest into memory, and returns
  the bytes only if everything matches. A missing, truncated, zero-byte or foreign file, or another filter's
  kernel at the name, does not match: the caller rebuilds it.
* **Every library is checked as a library.** A manifest can be rewritten to match a damaged file (it is the
  user's own file), and a library cut short with a matching manifest would pass: the dynamic loader maps its
  segments past the end of the file, and the first touch of them kills the process with SIGBUS, without a
  word. So :func:`read_verified` also checks the bytes' ELF structure (:func:`._elf.defect`: the header, this
  machine, every segment, table and section inside the file); a library that fails is not loaded but rebuilt,
  with an :class:`EngineWarning` naming the file and the defect.
* **What is loaded is what was checked.** :func:`load` checks the bytes' ELF structure once more, writes them
  into a fresh private file (0600, in the private folder) and hands *that* to ``dlopen``, then removes it.
  Nobody can change the cache's file between the check and the load, and nothing that fails a check is
  mapped: a library damaged in any way that leaves its segments short of their bytes is refused, not loaded.

The manifest guards integrity (a partial write, a killed build, a disk error, a misplaced file), not
authenticity: whoever can write to the user's cache folder as the user can also write a matching manifest,
and a library that passes every check can still do anything once loaded. The folder check keeps everyone else
out; see ``docs/engines.md`` for the threat model.
"""

from __future__ import annotations

import atexit
import hashlib
import itertools
import json
import os
import shutil
import stat
import tempfile
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

from .._cachedirs import cache_dir, refusal
from . import _elf

MANIFEST_FORMAT = 1
"""The manifest's format number (a manifest of another format does not match: the library is rebuilt)."""

MAX_LIBRARY_BYTES = 1 << 30
"""The largest library read from the cache (1 GiB: a kernel is a few MB at most); a larger file is rebuilt."""


class EngineWarning(UserWarning):
    """The C engine could not serve as asked: ``"auto"`` could not build a kernel (no C compiler, a primitive
    the translator has no C for) and runs with XLA, the kernel cache folder was refused and kernels are
    built, uncached, in a private temporary folder, or a cached library that matches its manifest is not a
    whole library for this machine and is rebuilt."""


@dataclass(frozen=True)
class Library:
    """A built library's checked bytes and where the cache keeps it."""

    path: Path
    data: bytes


_PRIVATE: dict[str, Path] = {}  # refused folder -> this process's private temporary folder
_LOCK = threading.Lock()


def folder() -> Path:
    """The checked folder kernels are built into and loaded from: :func:`cache_dir` if :func:`refusal` accepts
    it, else a private temporary folder of this process's, with an :class:`EngineWarning` naming the refused
    folder and why (once per folder). RuntimeError if no private folder can be made either."""
    want = cache_dir()
    real, why = refusal(want)
    if real is not None:
        return real
    with _LOCK:
        tmp = _PRIVATE.get(str(want))
        if tmp is not None and refusal(tmp)[0] == tmp:
            return tmp
        made = Path(tempfile.mkdtemp(prefix="liemef-kernels-"))
        tmp, why_tmp = refusal(made)
        if tmp is None:
            shutil.rmtree(made, ignore_errors=True)
            raise RuntimeError(f"the kernel cache {want} is refused ({why}), and the temporary folder {made} "
                               f"too ({why_tmp})")
        atexit.register(_remove, tmp, os.getpid())
        _PRIVATE[str(want)] = tmp
    warnings.warn(f"the kernel cache {want} is not used: {why}. Kernels are built uncached in the private "
                  f"folder {tmp} for this process; make the cache folder yours and not writable by group or "
                  f"others (chmod 700), or set LIEMEF_CACHE_DIR, to keep them", EngineWarning, stacklevel=2)
    return tmp


def _remove(tmp: Path, pid: int) -> None:
    if os.getpid() == pid:  # not from a forked child that exits normally: the folder is its parent's
        shutil.rmtree(tmp, ignore_errors=True)


def manifest_path(lib: Path) -> Path:
    """The manifest beside a library: ``kernel_<hash>.so`` -> ``kernel_<hash>.json``."""
    return lib.with_suffix(".json")


def _manifest(lib: Path, data: bytes, key: str, kind: str, about: dict) -> dict:
    return {"format": MANIFEST_FORMAT, "file": lib.name, "kind": kind, "key": key, "size": len(data),
            "sha256": hashlib.sha256(data).hexdigest(), **about}


def _read_private(path: Path, limit: int) -> bytes | None:
    """The bytes of ``path`` if it is a regular file of the user's (not a link: opened without following one;
    not a FIFO: opened without blocking), not writable by group or others and at most ``limit`` bytes."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if (not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_mode & 0o022
                or st.st_size > limit):
            return None
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        return b"".join(chunks) if size <= limit else None
    except OSError:
        return None
    finally:
        os.close(fd)


def read_verified(lib: Path, key: str, kind: str) -> Library | None:
    """The library at ``lib`` with its bytes, if its manifest vouches for them and they are a whole library for
    this machine: the manifest names this file, this filter's ``key`` and this ``kind``, the bytes have its size
    and SHA-256, and their ELF structure is sound (:func:`._elf.defect`). None otherwise (missing, truncated,
    zero bytes, changed, another filter's, not the user's, or a damaged library with a manifest to match, which
    an :class:`EngineWarning` names with its defect, once per file and content): never loaded, to be rebuilt."""
    raw = _read_private(manifest_path(lib), 1 << 16)
    if raw is None:
        return None
    try:
        man = json.loads(raw)
    except ValueError:  # UnicodeDecodeError included
        return None
    if not isinstance(man, dict) or any(man.get(k) != v for k, v in
                                        (("format", MANIFEST_FORMAT), ("file", lib.name), ("key", key),
                                         ("kind", kind))):
        return None
    size = man.get("size")
    if type(size) is not int or not 0 < size <= MAX_LIBRARY_BYTES:
        return None
    data = _read_private(lib, size)
    if data is None or len(data) != size or hashlib.sha256(data).hexdigest() != man.get("sha256"):
        return None
    why = _elf.defect(data)
    if why is not None:
        with _LOCK:
            seen = (str(lib), man.get("sha256")) in _DAMAGED
            _DAMAGED.add((str(lib), man.get("sha256")))
        if not seen:
            warnings.warn(f"the cached library {lib} matches its manifest but cannot be loaded: {why}. It is "
                          "rebuilt", EngineWarning, stacklevel=2)
        return None
    return Library(lib, data)


_DAMAGED: set[tuple[str, str]] = set()  # (library, SHA-256) already named by read_verified's warning


def install(lib: Path, data: bytes, key: str, kind: str, about: dict) -> Library:
    """Put a built library and then its manifest in the cache (each written 0600 beside its name and renamed
    into place, so that a reader sees a whole file or none): a reader between the two renames finds a mismatch
    and rebuilds."""
    _write_private(lib, data)
    _write_private(manifest_path(lib), (json.dumps(_manifest(lib, data, key, kind, about), indent=1) + "\n").encode())
    return Library(lib, data)


def _write_private(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")  # 0600
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_LOADS = itertools.count()


def dlopen(path: str | os.PathLike):
    """The shared library at ``path``, loaded with ctypes: the one ctypes loader of :mod:`liemef.codegen` (the
    engine's checked copies by :func:`load`, an export's library by :class:`~liemef.codegen.CFilter`)."""
    import ctypes

    return ctypes.CDLL(os.fspath(path))


def _private_copy(lib: Library) -> str:
    """A fresh private file (0600, a name used once, in the library's checked folder) holding the checked bytes
    of ``lib``, after a last check of their ELF structure (RuntimeError naming the file and the defect)."""
    why = _elf.defect(lib.data)
    if why is not None:
        raise RuntimeError(f"{lib.path}: not loaded: {why}")
    fd, tmp = tempfile.mkstemp(dir=lib.path.parent, prefix=f".load.{os.getpid()}.{next(_LOADS)}.", suffix=".so")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(lib.data)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return tmp


def load(lib: Library):
    """``dlopen`` the checked bytes of ``lib``: a fresh private copy of them (:func:`_private_copy`, which checks
    their ELF structure once more) is loaded and removed, so that what is mapped is what was checked. (Not a
    Linux memory file: ``/proc/self/fd/N`` names are reused, and the dynamic loader takes a library whose name
    it has loaded before for that one.)"""
    tmp = _private_copy(lib)
    try:
        return dlopen(tmp)
    finally:
        Path(tmp).unlink(missing_ok=True)


def load_module(lib: Library, name: str):
    """Import the checked bytes of ``lib`` as the CPython extension module ``name`` (its ``PyInit_<name>``), by
    the same private copy as :func:`load`: what is imported is what was checked."""
    import importlib.machinery
    import importlib.util

    tmp = _private_copy(lib)
    try:
        loader = importlib.machinery.ExtensionFileLoader(name, tmp)
        module = importlib.util.module_from_spec(importlib.util.spec_from_file_location(name, tmp, loader=loader))
        loader.exec_module(module)
        return module
    finally:
        Path(tmp).unlink(missing_ok=True)


def _after_fork() -> None:
    global _LOCK
    _LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


__all__ = ["EngineWarning", "Library", "cache_dir", "dlopen", "folder", "install", "load", "load_module",
           "read_verified", "refusal"]
