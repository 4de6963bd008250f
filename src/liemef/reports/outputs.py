"""Output folders that are complete or absent.

A command's output folder (``--out``) is written as a whole: its files go to a fresh temporary folder beside
it (``.NAME.XXXX.partial``), which, once every file is written, gets a ``manifest.json`` (each file with its
size and SHA-256) and is renamed into place. A failure, a full disk, Ctrl-C or SIGTERM removes the temporary
folder and leaves ``--out`` as it was; a failed run that explains itself (``failure.json``) replaces the folder
like any other result, so it never sits beside the estimates of an earlier run.

A command owns its folder: :func:`claim` accepts a missing or empty folder or one that holds the same command's
earlier output (its manifest says so), and refuses one that holds anything else unless ``force`` (then it is
replaced). This module needs only the standard library, so the check runs before JAX is imported.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

MANIFEST_FILE = "manifest.json"
MANIFEST_SCHEMA = "liemef.manifest/1"
"""Version tag of ``manifest.json``: ``{"schema", "command", "created", "liemef_version", "files": [{"path",
"size", "sha256"}]}``, paths relative to the folder, sorted."""
FAILURE_FILE = "failure.json"
"""What a failed run writes, alone: it has no manifest (there is no result to list)."""
_STAGE_SUFFIX = ".partial"


class OutputRefused(ValueError):
    """The output folder cannot be used (a file, another command's folder without ``force``, unwritable)."""


@dataclass(frozen=True)
class Target:
    """A claimed output folder: where the result goes, for which command, and whether an earlier folder there
    (``replace``) is to be replaced."""

    path: Path
    command: str
    replace: bool


def read_manifest(folder: str | os.PathLike) -> dict | None:
    """The folder's ``manifest.json`` if it is a liemef manifest, else None."""
    p = Path(folder) / MANIFEST_FILE
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("schema") == MANIFEST_SCHEMA else None


def _owner(folder: Path) -> str | None:
    """The command whose output the folder holds: its manifest's, or for a failed run's folder (``failure.json``
    alone, with no manifest) the failure's; None for anything else."""
    manifest = read_manifest(folder)
    if manifest is not None:
        return manifest.get("command")
    if sorted(e.name for e in folder.iterdir()) == [FAILURE_FILE]:
        try:
            data = json.loads((folder / FAILURE_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if isinstance(data, dict) and str(data.get("schema", "")).startswith("liemef.failure/"):
            return data.get("command")
    return None


def _protected(p: Path) -> bool:
    """Folders never cleared, even with ``force``: the file system's root, the home folder, the working folder
    and its ancestors."""
    r = p.resolve()
    cwd = Path.cwd().resolve()
    return r == Path(r.anchor) or r == Path.home().resolve() or r == cwd or r in cwd.parents


def claim(out: str | os.PathLike, command: str, force: bool = False, name: str = "--out") -> Target:
    """Check that ``command`` may write its output to the folder ``out``: missing, empty, holding the output of
    the same ``command`` (by its manifest), or anything else with ``force``. :class:`OutputRefused` otherwise,
    naming ``name``, the folder and what it holds. Nothing is written."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise OutputRefused(f"{name}: expected a directory, got an existing file {str(p)!r}")
    if not p.exists():
        return Target(p, command, replace=False)
    if _protected(p):  # replaced by a rename: never the folder a shell or the user's files live in
        raise OutputRefused(f"{name}: {str(p)!r} is the root, home or working folder (or one of its parents), which a "
                            "command does not replace; give a folder of its own")
    entries = sorted(e.name for e in p.iterdir())
    if not entries:
        return Target(p, command, replace=True)
    owner = _owner(p)
    if owner == command:
        return Target(p, command, replace=True)
    if force:
        return Target(p, command, replace=True)
    what = f"the output of `liemef {owner}`" if owner else \
        f"files liemef did not write for `{command}` ({', '.join(entries[:5])}{', ...' if len(entries) > 5 else ''})"
    raise OutputRefused(f"{name}: {str(p)!r} holds {what}; give --force to replace them, or another folder")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(folder: str | os.PathLike, command: str) -> Path:
    """``folder/manifest.json``: every file below ``folder`` with its size and SHA-256 (written atomically)."""
    from .. import __version__

    d = Path(folder)
    files = [{"path": p.relative_to(d).as_posix(), "size": p.stat().st_size, "sha256": _sha256(p)}
             for p in sorted(d.rglob("*")) if p.is_file() and p.name != MANIFEST_FILE]
    data = {"schema": MANIFEST_SCHEMA, "command": command,
            "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "liemef_version": __version__, "files": files}
    fd, tmp = tempfile.mkstemp(dir=d, prefix=f".{MANIFEST_FILE}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(data, indent=2) + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, d / MANIFEST_FILE)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return d / MANIFEST_FILE


def verify(folder: str | os.PathLike) -> list[str]:
    """What in ``folder`` disagrees with its manifest: missing, resized or altered files, files not listed
    (an empty list: the folder is what its command wrote)."""
    d = Path(folder)
    manifest = read_manifest(d)
    if manifest is None:
        return [f"{str(d / MANIFEST_FILE)!r}: missing or not a liemef manifest"]
    problems, listed = [], set()
    for entry in manifest["files"]:
        p = d / entry["path"]
        listed.add(entry["path"])
        if not p.is_file():
            problems.append(f"{entry['path']}: missing")
        elif p.stat().st_size != entry["size"] or _sha256(p) != entry["sha256"]:
            problems.append(f"{entry['path']}: altered (size or SHA-256 differs)")
    for p in sorted(d.rglob("*")):
        rel = p.relative_to(d).as_posix()
        if p.is_file() and p.name != MANIFEST_FILE and rel not in listed:
            problems.append(f"{rel}: not in the manifest")
    return problems


@contextlib.contextmanager
def staged(target: Target, manifest: bool = True) -> Iterator[Path]:
    """A fresh temporary folder beside ``target.path`` to write the output into. On normal exit it gets its
    manifest (unless not ``manifest``: a failed run's ``failure.json`` stands alone) and replaces
    ``target.path`` (renamed into place); on any exception (KeyboardInterrupt, a full disk) it is removed and
    ``target.path`` is left as it was."""
    out = target.path
    parent = out.parent if str(out.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{out.name}.", suffix=_STAGE_SUFFIX))
    except OSError as err:
        raise OutputRefused(f"--out: cannot create a folder beside {str(out)!r} ({err.strerror or err})") from err
    try:
        os.chmod(tmp, 0o755)
        yield tmp
        if manifest:
            write_manifest(tmp, target.command)
        _replace(tmp, out, target.replace)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace(tmp: Path, out: Path, replace: bool) -> None:
    """Rename ``tmp`` to ``out``, the earlier ``out`` (if any, and ``replace``) moved aside first and then
    removed."""
    if out.exists():
        if not replace:
            raise OutputRefused(f"--out: {str(out)!r} appeared while the command ran; its result is not written")
        old = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".old"))
        os.rmdir(old)
        os.rename(out, old)
        try:
            os.rename(tmp, out)
        except BaseException:
            os.rename(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, out)
