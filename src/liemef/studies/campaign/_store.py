"""The output folder of a campaign, which is also its checkpoint.

::

    OUT/campaign.json           the description and its fingerprint (written first; a rerun must match it)
    OUT/campaign.lock           the running client's pid, host and start (:class:`CampaignLock`; empty when none)
    OUT/manifest.jsonl          one line per finished task: id, file, SHA-256, trials, where and how long
    OUT/tasks/s000/t0000064.npz the per-trial arrays of one task (written atomically, then recorded)
    OUT/settings/s000_.../      montecarlo.{npz,json,md,csv} of each setting        } only when every task
    OUT/summary.md, summary.csv the table across settings                              } is finished, so a
    OUT/result.json             "complete": true, throughput, tasks computed and reused } partial run is never
                                                                                         taken for a whole one

A task counts as finished only when its manifest line exists and its file's SHA-256 matches the line: a
file without a line (killed between the two) or with another checksum (truncated, edited) is computed again.
The manifest is appended one line at a time with ``fsync``; a torn last line (killed mid-write) is ignored
and the next line starts on a new line. The checksums guard integrity (a torn or truncated file), not
authenticity: whoever can write the folder can write a task file and a matching line.

One client at a time: :func:`~liemef.studies.campaign.run_campaign` holds an exclusive lock on the folder
(:class:`CampaignLock`) while it runs.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...reports import io
from ._spec import SCHEMA, TASK_SCHEMA, Campaign, CampaignError, CampaignInputError, Task

CAMPAIGN_FILE = "campaign.json"
MANIFEST_FILE = "manifest.jsonl"
RESULT_FILE = "result.json"
LOCK_FILE = "campaign.lock"


def sha256_file(path: Path) -> str:
    """The SHA-256 of a file's bytes, hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class Entry:
    """A manifest line: a finished task and its file's checksum."""

    task: str
    file: str
    sha256: str
    start: int
    stop: int
    samples: int
    seconds: float
    worker: str

    def to_dict(self) -> dict:
        """The manifest line's JSON data."""
        return {"schema": TASK_SCHEMA, "task": self.task, "file": self.file, "sha256": self.sha256,
                "trials": [self.start, self.stop], "samples": self.samples, "seconds": self.seconds,
                "worker": self.worker, "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}

    @classmethod
    def from_dict(cls, d: dict) -> Entry:
        """A manifest line's entry; KeyError/TypeError/ValueError when it is not one."""
        start, stop = d["trials"]
        return cls(task=str(d["task"]), file=str(d["file"]), sha256=str(d["sha256"]), start=int(start),
                   stop=int(stop), samples=int(d["samples"]), seconds=float(d["seconds"]), worker=str(d["worker"]))


def _differences(old: dict, new: dict) -> list[str]:
    keys = sorted(set(old) | set(new))
    return [f"{k}: {json.dumps(old.get(k))} -> {json.dumps(new.get(k))}" for k in keys if old.get(k) != new.get(k)]


class Store:
    """The output folder of one campaign (see the module docstring). :meth:`open` creates it or checks that
    it belongs to the same campaign; :meth:`finished` reads the manifest; :meth:`record` adds a task."""

    def __init__(self, campaign: Campaign):
        self.campaign = campaign
        self.out = campaign.out
        self.manifest = self.out / MANIFEST_FILE
        self.problems: list[str] = []

    @classmethod
    def open(cls, campaign: Campaign) -> Store:
        """The store of ``campaign``: creates ``out`` and ``campaign.json``, or checks that an existing
        ``campaign.json`` has the same fingerprint (CampaignError listing what changed: a different campaign
        never mixes its tasks with these)."""
        store = cls(campaign)
        try:
            io.ensure_dir(store.out)
        except ValueError as err:
            raise CampaignInputError(str(err)) from None
        path = store.out / CAMPAIGN_FILE
        fp = campaign.fingerprint()
        if path.exists():
            try:
                old = io.read_json(path, "campaign")
            except ValueError as err:
                raise CampaignInputError(f"out: {str(path)!r} is unreadable ({err}); expected the campaign.json "
                                         "of a campaign: use another out folder") from None
            if not isinstance(old, dict) or old.get("schema") != SCHEMA:
                raise CampaignInputError(f"out: {str(store.out)!r} holds a campaign.json of another layout "
                                         f"(schema {old.get('schema') if isinstance(old, dict) else None!r}, "
                                         f"expected {SCHEMA!r}); use another out folder")
            if old.get("fingerprint") != fp:
                changed = _differences(old.get("description", {}), campaign.description())
                raise CampaignInputError(f"out: {str(store.out)!r} holds another campaign "
                                         f"({'; '.join(changed)}); its results are kept: use another out folder, "
                                         "or the description it was run with")
        else:
            io.write_json(path, {"schema": SCHEMA, "name": campaign.name, "fingerprint": fp,
                                 "description": campaign.description(), "campaign": campaign.to_dict(),
                                 "settings": [{"index": s.index, "label": s.label, "folder": s.folder,
                                               "overrides": s.overrides} for s in campaign.points()],
                                 "tasks": len(campaign.tasks()),
                                 "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        store._end_with_newline()
        return store

    def _end_with_newline(self) -> None:
        """After a kill mid-append the manifest may end in a torn line; the next line must start afresh."""
        if self.manifest.exists() and self.manifest.stat().st_size:
            with open(self.manifest, "rb+") as f:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    f.write(b"\n")
                    f.flush()
                    os.fsync(f.fileno())

    def task_path(self, task: Task) -> Path:
        """Where the arrays of ``task`` are kept: ``tasks/s003/t0000064.npz``."""
        return self.out / "tasks" / f"s{task.setting:03d}" / f"t{task.start:07d}.npz"

    def finished(self) -> dict[str, Entry]:
        """The tasks finished in earlier runs, by id: those with a well-formed manifest line whose file exists
        with the recorded SHA-256. Everything else is listed in :attr:`problems` and will be computed again."""
        self.problems = []
        done: dict[str, Entry] = {}
        if not self.manifest.exists():
            return done
        wanted = {t.id: t for t in self.campaign.tasks()}
        lines = self.manifest.read_text(encoding="utf-8", errors="replace").splitlines()
        for n, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                e = Entry.from_dict(json.loads(line))
            except (ValueError, KeyError, TypeError):
                self.problems.append(f"manifest line {n}: not a complete entry (a run killed while writing it); "
                                     "ignored")
                continue
            t = wanted.get(e.task)
            if t is None or (e.start, e.stop) != (t.start, t.stop):
                self.problems.append(f"manifest line {n}: task {e.task!r} is not a task of this campaign; ignored")
                continue
            path = self.out / e.file
            if not path.is_file():
                self.problems.append(f"task {e.task}: {e.file} is missing; it will be computed again")
            elif sha256_file(path) != e.sha256:
                self.problems.append(f"task {e.task}: {e.file} does not match its checksum; it will be "
                                     "computed again")
            else:
                done[e.task] = e
        return done

    def record(self, task: Task, stats, finite, causes, samples: int, seconds: float, worker: str) -> Entry:
        """Write a finished task's arrays (atomically), then append its manifest line (fsync'd)."""
        path = self.task_path(task)
        io.ensure_dir(path.parent)
        io.write_npz(path, {"stats": stats, "finite": finite, "causes": causes,
                            "trials": np.array([task.start, task.stop])})
        entry = Entry(task=task.id, file=path.relative_to(self.out).as_posix(), sha256=sha256_file(path),
                      start=task.start, stop=task.stop, samples=int(samples), seconds=float(seconds),
                      worker=worker)
        line = json.dumps(entry.to_dict(), allow_nan=False) + "\n"
        with open(self.manifest, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        return entry

    def load(self, entry: Entry) -> dict[str, np.ndarray]:
        """The arrays of a finished task."""
        return io.read_arrays(self.out / entry.file)

    def clear_result(self) -> None:
        """Remove ``result.json`` before tasks are added: the summary files then describe an older run until
        the new one rewrites them, and no ``result.json`` says "complete" in between."""
        with contextlib.suppress(FileNotFoundError):
            (self.out / RESULT_FILE).unlink()


class CampaignLock:
    """The exclusive lock of a campaign's output folder, held by the client that runs it.

    ``OUT/campaign.lock`` is locked with ``flock`` (released by the system when the holder exits, however it
    ends) and holds the holder's pid, host and start time. A second client is refused with them. A lock left
    by a client that no longer runs (killed: the file still names it, but nobody holds the ``flock``) is taken
    over, and :attr:`note` says whose it was. :meth:`release` empties the file and unlocks it."""

    def __init__(self, path: Path, fd: int, note: str | None):
        self.path, self._fd, self.note = path, fd, note

    @classmethod
    def acquire(cls, out: Path) -> CampaignLock:
        """Lock ``out`` (CampaignError naming the holder's pid and host if another client holds it)."""
        import fcntl

        path = Path(out) / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as err:
            raise CampaignError(f"out: cannot open the lock {str(path)!r} ({err.strerror or err})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder(fd)
            os.close(fd)
            raise CampaignError(f"out: {str(out)!r} is in use by another client of this campaign: "
                                f"{_describe(holder)} ({str(path)!r}); wait for it to finish or stop it, then run "
                                "again") from None
        holder = _holder(fd)
        note = None
        if holder:
            note = (f"took over the lock of {_describe(holder)}, which no longer runs (a client stopped without "
                    "releasing it)")
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
        os.fsync(fd)
        return cls(path, fd, note)

    def release(self) -> None:
        """Empty the lock file and unlock it (idempotent)."""
        if self._fd is None:
            return
        import fcntl

        with contextlib.suppress(OSError):
            os.ftruncate(self._fd, 0)
        with contextlib.suppress(OSError):
            fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)
        self._fd = None


def _holder(fd: int) -> dict:
    """The holder a lock file names ({} if it is empty or unreadable)."""
    try:
        data = json.loads(os.pread(fd, 4096, 0).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _describe(holder: dict) -> str:
    if not holder:
        return "a client that has not yet written its pid and host"
    return (f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')}, running since "
            f"{holder.get('started', '?')}")


def status_lines(campaign: Campaign) -> list[str]:
    """How far ``campaign`` has come (``liemef campaign status``): finished tasks per setting, verified against
    their checksums, any problem found, and whether its results are complete. Runs nothing; CampaignError when
    the folder is another campaign's."""
    if not (campaign.out / CAMPAIGN_FILE).exists():
        return [f"campaign {campaign.name}: not started ({campaign.out} has no {CAMPAIGN_FILE}); "
                f"{len(campaign.tasks())} tasks to run"]
    store = Store.open(campaign)
    done = store.finished()
    tasks = campaign.tasks()
    lines = list(store.problems)
    for s in campaign.points():
        mine = [t for t in tasks if t.setting == s.index]
        lines.append(f"setting {s.index} ({s.label}): {sum(t.id in done for t in mine)}/{len(mine)} tasks")
    complete = len(done) == len(tasks) and (campaign.out / RESULT_FILE).exists()
    lines.append(f"campaign {campaign.name}: {len(done)}/{len(tasks)} tasks finished; "
                 + ("complete" if complete else "incomplete: `liemef campaign run` resumes it"))
    return lines
