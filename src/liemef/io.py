"""Files in and out: results to an output folder, recorded logs in.

Every file is written completely or not at all: the bytes go to a temporary file in the same folder, which
is flushed, synced and then renamed over the target with :func:`os.replace` (atomic on POSIX), so a crash or
an error mid-write leaves the previous file untouched and no partial file behind.

Output folder of an experiment (``liemef reproduce``): ``metrics.json`` (see
:class:`liemef.experiments.Result`), ``arrays.npz``, the figures (:mod:`liemef.plots`) and the error table
(``errors.md``, ``errors.csv``); with Monte Carlo trials also ``montecarlo.{npz,json,md,csv}`` (see
:class:`liemef.experiments.MonteCarloResult`). ``liemef reproduce all`` writes one such folder per experiment
and an ``index.md``.

Recorded logs (``liemef run``, :func:`read_log`):

* CSV with a header row ``t,u1,...,um,y1,...,yp`` (any column order, blanks around names ignored), one row
  per sample, times strictly increasing;
* NPZ with arrays ``ts`` (N,), ``us`` (N, m) and ``ys`` (N, p) (an experiment's ``arrays.npz`` is one).
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

METRICS_FILE = "metrics.json"
ARRAYS_FILE = "arrays.npz"


# --- writing -----------------------------------------------------------------------------------------------
def ensure_dir(path: str | os.PathLike, name: str = "out") -> Path:
    """The folder ``path``, created (with its parents) if missing; a ValueError if it cannot be written."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{name}: expected a directory, got an existing file {str(p)!r}")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{name}: cannot create the directory {str(p)!r} ({err.strerror or err})") from err
    if not os.access(p, os.W_OK | os.X_OK):
        raise ValueError(f"{name}: expected a writable directory, got {str(p)!r} (permission denied)")
    return p


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open ``path`` for writing so that it is replaced completely or not at all.

    Writes go to a temporary file next to ``path``; on normal exit it is synced and renamed over ``path``;
    on an exception it is deleted and ``path`` keeps its previous content.
    """
    if "w" not in mode:
        raise ValueError(f"mode: expected a write mode ('w' or 'wb'), got {mode!r}")
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:
        raise ValueError(f"cannot write {str(path)!r}: {err.strerror or err}") from err
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8", "newline": ""})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """``obj`` as indented JSON (strict: NaN and infinity are refused, use None), written atomically."""
    text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    with atomic_open(path, "w") as f:
        f.write(text)
    return Path(path)


def write_npz(path: str | os.PathLike, arrays: Mapping[str, Any]) -> Path:
    """Arrays (numeric or string; no objects) to an uncompressed ``.npz``, written atomically."""
    data = {k: np.asarray(v) for k, v in arrays.items()}
    for k, v in data.items():
        if v.dtype == object:
            raise ValueError(f"arrays[{k!r}]: expected a numeric or string array, got dtype object")
    with atomic_open(path, "wb") as f:
        np.savez(f, **data)
    return Path(path)


def write_csv(path: str | os.PathLike, header: Sequence[str], columns: Sequence[Any]) -> Path:
    """Columns of equal length under ``header`` to a CSV file (full float64 precision), written atomically."""
    cols = [np.asarray(c, dtype=np.float64).reshape(-1) for c in columns]
    if len(cols) != len(header) or len({c.shape[0] for c in cols}) > 1:
        raise ValueError(f"columns: expected {len(header)} columns of one length, got lengths "
                         f"{[c.shape[0] for c in cols]}")
    return write_rows(path, header, list(zip(*cols, strict=True)))


def write_text(path: str | os.PathLike, text: str) -> Path:
    """``text`` (UTF-8) to a file, written atomically (Markdown tables, the index of ``reproduce all``)."""
    with atomic_open(path, "w") as f:
        f.write(text)
    return Path(path)


def write_rows(path: str | os.PathLike, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> Path:
    """Rows of mixed text and numbers under ``header`` to a CSV file, written atomically. Floats keep full
    float64 precision (``repr``); NaN is written ``nan``."""
    rows = [list(r) for r in rows]
    bad = [i for i, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        raise ValueError(f"rows: expected {len(header)} values per row (the header), got {len(rows[bad[0]])} "
                         f"in row {bad[0]}")
    cell = lambda v: repr(float(v)) if isinstance(v, float | np.floating) else str(v)  # noqa: E731
    with atomic_open(path, "w") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([cell(v) for v in r] for r in rows)
    return Path(path)


def write_result(out: str | os.PathLike, metrics: Mapping[str, Any], arrays: Mapping[str, Any]) -> list[Path]:
    """``metrics.json`` and ``arrays.npz`` into the folder ``out`` (created if missing)."""
    d = ensure_dir(out)
    return [write_npz(d / ARRAYS_FILE, arrays), write_json(d / METRICS_FILE, dict(metrics))]


# --- reading -----------------------------------------------------------------------------------------------
def _existing_file(path: str | os.PathLike, name: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{name}: file not found: {str(p)!r}")
    if not p.is_file():
        raise ValueError(f"{name}: expected a file, got a directory {str(p)!r}")
    return p


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file (no pickles)."""
    p = _existing_file(path, "arrays")
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise ValueError(f"arrays: cannot read {str(p)!r} as .npz ({err})") from err


def read_json(path: str | os.PathLike, name: str = "json") -> Any:
    """A JSON file; a ValueError naming ``name`` if it is missing or not JSON."""
    p = _existing_file(path, name)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise ValueError(f"{name}: cannot read {str(p)!r} as JSON ({err})") from err


def read_metrics(path: str | os.PathLike) -> dict:
    return read_json(path, "metrics")


@dataclass(frozen=True)
class RecordedLog:
    """A recorded log: sample times ``ts`` (N,), measured inputs ``us`` (N, m), measurements ``ys`` (N, p)."""

    ts: np.ndarray
    us: np.ndarray
    ys: np.ndarray


def log_header(input_dim: int, output_dim: int) -> list[str]:
    """The CSV header of a log: ``t, u1..um, y1..yp``."""
    return ["t"] + [f"u{i + 1}" for i in range(input_dim)] + [f"y{j + 1}" for j in range(output_dim)]


def _check_log(ts, us, ys, where: str) -> RecordedLog:
    for name, a in (("t", ts), ("u", us), ("y", ys)):
        bad = ~np.isfinite(a)
        if bad.any():
            idx = np.argwhere(bad)[0]
            row = int(idx[0])
            col = name if a.ndim == 1 else f"{name}{int(idx[1]) + 1}"
            raise ValueError(f"log {where}: expected finite values, got {a[tuple(idx)]} in column {col} "
                             f"at sample {row}" + (f" (t = {ts[row]})" if name != "t" else ""))
    if ts.shape[0] < 2:
        raise ValueError(f"log {where}: expected at least 2 samples, got {ts.shape[0]}")
    dt = np.diff(ts)
    if not np.all(dt > 0):
        k = int(np.argmax(dt <= 0))
        raise ValueError(f"log {where}: expected strictly increasing time stamps, got t = {ts[k]} at sample "
                         f"{k} followed by t = {ts[k + 1]}")
    return RecordedLog(ts=ts, us=us, ys=ys)


def _read_csv(p: Path, m: int, pdim: int) -> RecordedLog:
    want = log_header(m, pdim)
    with p.open(newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"log {str(p)!r}: the file is empty; expected a header row {','.join(want)}")
    header = [c.strip() for c in rows[0]]
    missing = [c for c in want if c not in header]
    extra = [c for c in header if c not in want]
    if missing or extra or len(set(header)) != len(header):
        what = []
        if missing:
            what.append(f"missing column(s) {missing}")
        if extra:
            what.append(f"unexpected column(s) {extra}")
        if len(set(header)) != len(header):
            what.append("duplicate columns")
        raise ValueError(f"log {str(p)!r}: {', '.join(what)}; expected the header {','.join(want)} "
                         f"(m = {m} inputs, p = {pdim} outputs), got {','.join(header)}")
    data = np.empty((len(rows) - 1, len(header)))
    for i, r in enumerate(rows[1:]):
        if len(r) != len(header):
            raise ValueError(f"log {str(p)!r}: expected {len(header)} values on line {i + 2}, got {len(r)}")
        try:
            data[i] = [float(c) for c in r]
        except ValueError as err:
            raise ValueError(f"log {str(p)!r}: expected numbers on line {i + 2}, got {r} ({err})") from err
    col = {name: data[:, k] for k, name in enumerate(header)}
    ts = col["t"]
    us = np.stack([col[f"u{i + 1}"] for i in range(m)], axis=1) if m else np.zeros((ts.shape[0], 0))
    ys = np.stack([col[f"y{j + 1}"] for j in range(pdim)], axis=1)
    return _check_log(ts, us, ys, repr(str(p)))


def _read_npz(p: Path, m: int, pdim: int) -> RecordedLog:
    z = read_arrays(p)
    missing = [k for k in ("ts", "us", "ys") if k not in z and not (k == "us" and m == 0)]
    if missing:
        raise ValueError(f"log {str(p)!r}: missing array(s) {missing}; expected ts (N,), us (N, {m}), "
                         f"ys (N, {pdim}), got {sorted(z)}")
    ts = np.asarray(z["ts"], dtype=np.float64)
    if ts.ndim != 1:
        raise ValueError(f"log {str(p)!r}: expected ts of shape (N,), got {ts.shape}")
    N = ts.shape[0]
    us = np.asarray(z["us"], dtype=np.float64) if "us" in z else np.zeros((N, 0))
    ys = np.asarray(z["ys"], dtype=np.float64)
    for name, a, shape in (("us", us, (N, m)), ("ys", ys, (N, pdim))):
        if a.shape != shape:
            raise ValueError(f"log {str(p)!r}: expected {name} of shape {shape} (N = {N} samples), "
                             f"got {a.shape}")
    return _check_log(ts, us, ys, repr(str(p)))


def read_log(path: str | os.PathLike, input_dim: int, output_dim: int) -> RecordedLog:
    """A recorded log (CSV or NPZ, see the module docstring) for a system with ``input_dim`` inputs and
    ``output_dim`` outputs. ValueError on a missing file, missing columns, non-numbers, NaN/inf or unsorted
    time stamps, naming what was expected and what came."""
    p = _existing_file(path, "log")
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return _read_csv(p, input_dim, output_dim)
    if suffix == ".npz":
        return _read_npz(p, input_dim, output_dim)
    raise ValueError(f"log: expected a .csv or .npz file, got {str(p)!r}")
