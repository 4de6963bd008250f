"""Files in and out: results to an output folder, recorded logs in.

Every file is written completely or not at all: the bytes go to a temporary file in the same folder, which
is flushed, synced and then renamed over the target with :func:`os.replace` (atomic on POSIX), so a crash or
an error mid-write leaves the previous file untouched and no partial file behind.

Output folder of an experiment (``liemef reproduce``): ``metrics.json`` (see
:class:`liemef.studies.experiments.Result`), ``arrays.npz``, the figures (:mod:`liemef.reports.plots`) and the error
table
(``errors.md``, ``errors.csv``); with Monte Carlo trials also ``montecarlo.{npz,json,md,csv}`` (see
:class:`liemef.studies.experiments.MonteCarloResult`). ``liemef reproduce all`` writes one such folder per experiment
and an ``index.md``.

Recorded logs (``liemef run``, :func:`read_log`):

* CSV with a header row ``t,<inputs>,<outputs>``: the system's input names and its sensors' columns
  ``{sensor}_{component}`` (``liemef schema SYSTEM`` prints them), or the generic ``t,u1,...,um,y1,...,yp``;
  any column order, blanks around names ignored; one row per sample time, times strictly increasing. An empty
  field (or ``nan``) is a missing sample: a sensor at 1 Hz in a 100 Hz log has values in one row of 100.
* NPZ with arrays ``ts`` (N,), ``us`` (N, m) and ``ys`` (N, p) (NaN = missing; an experiment's ``arrays.npz``
  is one), or, with a time vector per sensor, ``ts``/``us`` for the inputs and ``NAME`` (N_s, k) with
  ``t_NAME`` (N_s,) for each sensor block NAME, merged onto the union of the times
  (:func:`merge_sensor_times`).
* ROS 1 and ROS 2 bags: :func:`liemef.reports.rosbag.read_bag`.

Trajectories out (and back in): :func:`write_tum` and :func:`read_tum`, the TUM RGB-D format
``timestamp tx ty tz qx qy qz qw`` that evo, the TUM and EuRoC tools and most SLAM benchmarks read.
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

from .. import _validate

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
    float64 precision (``repr``); NaN is written ``nan``; None (no value) is an empty cell, as a missing sample."""
    rows = [list(r) for r in rows]
    bad = [i for i, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        raise ValueError(f"rows: expected {len(header)} values per row (the header), got {len(rows[bad[0]])} "
                         f"in row {bad[0]}")
    cell = lambda v: "" if v is None else repr(float(v)) if isinstance(v, float | np.floating) else str(v)  # noqa: E731
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
ROS2_FILES = (".db3", ".mcap", ".yaml")
"""The files of a ROS 2 bag folder (beside its ``metadata.yaml``): a path to one stands for the folder."""


def is_bag(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a ROS bag: a ROS 1 ``.bag`` file, a ROS 2 bag folder (one holding a ``metadata.yaml``)
    or a file of one (:data:`ROS2_FILES`). Any other folder (of CSV logs, say) is not. ``liemef run`` asks
    before JAX loads; :mod:`liemef.reports.rosbag` reads the bag."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() == ".bag" or (p.suffix.lower() in ROS2_FILES and (p.parent / "metadata.yaml").is_file())


def _existing_file(path: str | os.PathLike, name: str) -> Path:
    """``path`` as an existing file; a ValueError naming ``name`` otherwise."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"{name}: expected a file path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{name}: file not found: {str(p)!r}")
    if not p.is_file():
        raise ValueError(f"{name}: expected a file, got a directory {str(p)!r}")
    return p


def read_arrays(path: str | os.PathLike, name: str = "arrays") -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file (no pickles). ValueError naming ``name`` and the file for anything that
    is not a whole, readable NPZ archive: empty, truncated, corrupted (a bad CRC or compressed stream), a
    single ``.npy`` array, pickled objects."""
    p = _existing_file(path, name)
    try:
        z = np.load(p, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError(f"{name}: expected an .npz archive of named arrays, got a single array of shape "
                             f"{np.shape(z)} in {str(p)!r}")
        with z:
            return {k: z[k] for k in z.files}
    except ValueError as err:
        if str(err).startswith(f"{name}: "):
            raise
        raise ValueError(f"{name}: cannot read {str(p)!r} as an .npz archive (ValueError: {err})") from err
    except Exception as err:  # noqa: BLE001 - zipfile, zlib, EOF and OS errors alike: a bad file
        why = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
        raise ValueError(f"{name}: cannot read {str(p)!r} as an .npz archive ({why})") from err


def read_json(path: str | os.PathLike, name: str = "json") -> Any:
    """A JSON file; a ValueError naming ``name`` if it is missing or not JSON."""
    p = _existing_file(path, name)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise ValueError(f"{name}: cannot read {str(p)!r} as JSON ({err})") from err


def read_metrics(path: str | os.PathLike) -> dict:
    """A ``metrics.json`` file (:func:`read_json`)."""
    return read_json(path, "metrics")


@dataclass(frozen=True)
class RecordedLog:
    """A recorded log: sample times ``ts`` (N,), measured inputs ``us`` (N, m), measurements ``ys`` (N, p).

    NaN in ``ys`` marks a missing sample of that component; NaN in ``us`` a missing input sample (the filter
    holds the last one)."""

    ts: np.ndarray
    us: np.ndarray
    ys: np.ndarray


@dataclass(frozen=True)
class LogLayout:
    """The columns a log must have: input and output names and the output's sensor blocks
    ``(name, start, stop)`` (for per-sensor time vectors in NPZ)."""

    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    blocks: tuple[tuple[str, int, int], ...]

    @staticmethod
    def of(system=None, input_dim: int | None = None, output_dim: int | None = None) -> LogLayout:
        """The layout of a liemef system, or the generic ``u1..um``, ``y1..yp`` of the given sizes."""
        if system is not None:
            return LogLayout(tuple(system.input_names), tuple(system.output_names),
                             tuple((b.name, b.start, b.stop) for b in system.blocks()))
        m, p = int(input_dim), int(output_dim)
        return LogLayout(tuple(f"u{i + 1}" for i in range(m)), tuple(f"y{j + 1}" for j in range(p)), (("y", 0, p),))

    @property
    def header(self) -> list[str]:
        """The CSV header ``t, inputs, outputs``."""
        return ["t", *self.inputs, *self.outputs]

    @property
    def generic(self) -> LogLayout:
        """The generic layout of the same sizes (``u1..um``, ``y1..yp``)."""
        return LogLayout.of(None, len(self.inputs), len(self.outputs))


def log_header(input_dim: int, output_dim: int) -> list[str]:
    """The generic CSV header of a log: ``t, u1..um, y1..yp``."""
    return LogLayout.of(None, input_dim, output_dim).header


def _check_log(ts, us, ys, where: str, layout: LogLayout) -> RecordedLog:
    bad_t = ~np.isfinite(ts)
    if bad_t.any():
        row = int(np.argmax(bad_t))
        raise ValueError(f"log {where}: expected finite time stamps, got {ts[row]} in column t at sample {row}")
    for a, names in ((us, layout.inputs), (ys, layout.outputs)):
        bad = np.isinf(a)
        if bad.any():
            row, col = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"log {where}: expected finite values or an empty field/NaN (missing sample), got "
                             f"{a[row, col]} in column {names[col]} at sample {row} (t = {ts[row]})")
    if ts.shape[0] < 2:
        raise ValueError(f"log {where}: expected at least 2 samples, got {ts.shape[0]}")
    dt = np.diff(ts)
    if not np.all(dt > 0):
        k = int(np.argmax(dt <= 0))
        raise ValueError(f"log {where}: expected strictly increasing time stamps, got t = {ts[k]} at sample "
                         f"{k} followed by t = {ts[k + 1]}")
    return RecordedLog(ts=ts, us=us, ys=ys)


def _cell(c: str) -> float:
    c = c.strip()
    return np.nan if c == "" else float(c)


def _read_csv(p: Path, layout: LogLayout) -> RecordedLog:
    try:  # utf-8-sig: a header with a byte-order mark (as spreadsheets write) is read without it
        with p.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as err:
        raise ValueError(f"log {str(p)!r}: expected UTF-8 text, got the byte {err.object[err.start:err.start + 1]!r} "
                         f"at offset {err.start}, which is not UTF-8 (save the file as UTF-8)") from err
    except csv.Error as err:
        raise ValueError(f"log {str(p)!r}: expected CSV text, got {err}") from err
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"log {str(p)!r}: the file is empty; expected a header row {','.join(layout.header)}")
    header = [c.strip() for c in rows[0]]
    if layout.generic.header != layout.header and set(header) == set(layout.generic.header):
        layout = layout.generic  # the generic names t,u1..,y1.. are always accepted
    want = layout.header
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
        m, pdim = len(layout.inputs), len(layout.outputs)
        raise ValueError(f"log {str(p)!r}: {', '.join(what)}; expected the header {','.join(want)} "
                         f"(m = {m} inputs, p = {pdim} outputs), got {','.join(header)}")
    data = np.empty((len(rows) - 1, len(header)))
    for i, r in enumerate(rows[1:]):
        if len(r) != len(header):
            raise ValueError(f"log {str(p)!r}: expected {len(header)} values on line {i + 2}, got {len(r)}")
        try:
            data[i] = [_cell(c) for c in r]
        except ValueError as err:
            raise ValueError(f"log {str(p)!r}: expected numbers or empty fields (missing samples) on line {i + 2}, "
                             f"got {r} ({err})") from err
    col = {name: data[:, k] for k, name in enumerate(header)}
    ts = col["t"]
    N = ts.shape[0]
    us = np.stack([col[c] for c in layout.inputs], axis=1) if layout.inputs else np.zeros((N, 0))
    ys = np.stack([col[c] for c in layout.outputs], axis=1)
    return _check_log(ts, us, ys, repr(str(p)), layout)


def merge_sensor_times(ts_u, us, streams: Mapping[str, tuple[Any, Any]], layout: LogLayout) -> RecordedLog:
    """One log on the union of the sample times of the inputs (``ts_u``, ``us``) and of each sensor block
    (``streams[name] = (t, values)``, values (N_s, k)): NaN where a stream has no sample at a time (missing
    measurement; a missing input is held). Times present in several streams become one row."""
    ts_u = np.asarray(ts_u, dtype=np.float64)
    us = np.asarray(us, dtype=np.float64).reshape(ts_u.shape[0], len(layout.inputs))
    times = [ts_u] + [np.asarray(t, dtype=np.float64).reshape(-1) for t, _ in streams.values()]
    for t in times:
        if not np.all(np.isfinite(t)):
            raise ValueError("log: expected finite sensor time stamps, got NaN or inf")
    ts = np.unique(np.concatenate(times))
    N = ts.shape[0]
    U = np.full((N, len(layout.inputs)), np.nan)
    U[np.searchsorted(ts, ts_u)] = us
    Y = np.full((N, len(layout.outputs)), np.nan)
    blocks = {name: (a, b) for name, a, b in layout.blocks}
    for name, (t, v) in streams.items():
        if name not in blocks:
            raise ValueError(f"log: unknown sensor {name!r}; expected one of {sorted(blocks)}")
        a, b = blocks[name]
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        v = np.asarray(v, dtype=np.float64).reshape(t.shape[0], b - a)
        if np.unique(t).shape[0] != t.shape[0]:
            raise ValueError(f"log: sensor {name!r} has repeated time stamps")
        Y[np.searchsorted(ts, t), a:b] = v
    return RecordedLog(ts=ts, us=U, ys=Y)


def _read_npz(p: Path, layout: LogLayout) -> RecordedLog:
    z = read_arrays(p, "log")
    names = {"ts", "us", "ys"} | {n for n, _, _ in layout.blocks} | {f"t_{n}" for n, _, _ in layout.blocks}
    for key, a in z.items():  # the log's own arrays; others (an experiment's names, units) are not read
        if key in names:
            _validate.numeric(f"log {str(p)!r}: array {key!r}", a)
    m, pdim = len(layout.inputs), len(layout.outputs)
    per_sensor = "ys" not in z and any(name in z for name, _, _ in layout.blocks)
    need = ["ts"] + (["us"] if m else []) + ([] if per_sensor else ["ys"])
    missing = [k for k in need if k not in z]
    if missing:
        raise ValueError(f"log {str(p)!r}: missing array(s) {missing}; expected ts (N,), us (N, {m}), "
                         f"ys (N, {pdim}) (or, per sensor, arrays NAME and t_NAME for the sensors "
                         f"{[b[0] for b in layout.blocks]}), got {sorted(z)}")
    ts = np.asarray(z["ts"], dtype=np.float64)
    if ts.ndim != 1:
        raise ValueError(f"log {str(p)!r}: expected ts of shape (N,), got {ts.shape}")
    N = ts.shape[0]
    us = np.asarray(z["us"], dtype=np.float64) if "us" in z else np.zeros((N, 0))
    if us.shape != (N, m):
        raise ValueError(f"log {str(p)!r}: expected us of shape {(N, m)} (N = {N} samples), got {us.shape}")
    if per_sensor:
        streams = {}
        for name, a, b in layout.blocks:
            if name not in z:
                continue
            if f"t_{name}" not in z:
                raise ValueError(f"log {str(p)!r}: sensor {name!r} has no time vector; expected an array "
                                 f"t_{name} beside {name}")
            t, v = np.asarray(z[f"t_{name}"], dtype=np.float64), np.asarray(z[name], dtype=np.float64)
            if t.ndim != 1 or v.shape not in ((t.shape[0], b - a), (t.shape[0],) if b - a == 1 else None):
                raise ValueError(f"log {str(p)!r}: expected t_{name} (N_s,) and {name} (N_s, {b - a}), got "
                                 f"{t.shape} and {v.shape}")
            streams[name] = (t, v)
        log = merge_sensor_times(ts, us, streams, layout)
        return _check_log(log.ts, log.us, log.ys, repr(str(p)), layout)
    ys = np.asarray(z["ys"], dtype=np.float64)
    if ys.shape != (N, pdim):
        raise ValueError(f"log {str(p)!r}: expected ys of shape {(N, pdim)} (N = {N} samples), got {ys.shape}")
    return _check_log(ts, us, ys, repr(str(p)), layout)


def read_log(path: str | os.PathLike, system_or_input_dim, output_dim: int | None = None) -> RecordedLog:
    """A recorded log (CSV or NPZ, see the module docstring) for ``system`` (its input and output names are
    the columns), for a :class:`LogLayout` of columns, or for ``input_dim`` inputs and ``output_dim`` outputs
    (columns ``u1..um``, ``y1..yp``).

    Empty fields and NaN are missing samples. ValueError on a missing file, missing columns, non-numbers,
    infinities or unsorted time stamps, naming what was expected and what came."""
    if isinstance(system_or_input_dim, int | np.integer):
        layout = LogLayout.of(None, system_or_input_dim, output_dim)
    elif isinstance(system_or_input_dim, LogLayout):  # the columns alone: read without the system (nor JAX)
        layout = system_or_input_dim
    else:
        layout = LogLayout.of(system_or_input_dim)
    p = _existing_file(path, "log")
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return _read_csv(p, layout)
    if suffix == ".npz":
        return _read_npz(p, layout)
    raise ValueError(f"log: expected a .csv or .npz file, got {str(p)!r}")


def write_log(path: str | os.PathLike, system, ts, us, ys) -> Path:
    """A log in ``system``'s columns, written atomically: CSV with the header ``t,<inputs>,<outputs>`` (full
    float64 precision; NaN, a missing sample, written as an empty field) or NPZ (ts, us, ys), by the suffix.
    ValueError (naming the argument) on wrong shapes, infinities or time stamps not strictly increasing."""
    layout = LogLayout.of(system)
    ts = np.asarray(ts, dtype=np.float64)
    if ts.ndim != 1 or ts.shape[0] < 2:
        raise ValueError(f"ts: expected shape (N,) with N >= 2, got {ts.shape}")
    N = ts.shape[0]
    us = np.zeros((N, 0)) if us is None and not layout.inputs else np.asarray(us, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    for name, a, k in (("us", us, len(layout.inputs)), ("ys", ys, len(layout.outputs))):
        if a.shape != (N, k):
            raise ValueError(f"{name}: expected shape ({N}, {k}), got {a.shape}")
        if np.isinf(a).any():
            raise ValueError(f"{name}: expected finite values or NaN (missing), got an infinity")
    if not (np.all(np.isfinite(ts)) and np.all(np.diff(ts) > 0)):
        raise ValueError("ts: expected finite, strictly increasing time stamps")
    if Path(path).suffix.lower() == ".npz":
        return write_npz(path, {"ts": ts, "us": us, "ys": ys})
    cell = lambda v: "" if np.isnan(v) else repr(float(v))  # noqa: E731
    with atomic_open(path, "w") as f:
        w = csv.writer(f)
        w.writerow(layout.header)
        w.writerows([cell(v) for v in row] for row in np.column_stack([ts, us, ys]))
    return Path(path)


# --- trajectories (TUM) --------------------------------------------------------------------------------------
TUM_FILE = "estimates.tum"
TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"


def write_tum(path: str | os.PathLike, ts, g_hat) -> Path:
    """Estimates ``g_hat`` (batch shape (N,)) at times ``ts`` (N,) in the TUM trajectory format, one line
    ``timestamp tx ty tz qx qy qz qw`` per sample (full float64 precision, a ``#`` header line), written
    atomically. The pose is read off by :func:`liemef.metrics.pose_parts`: SE(3) and SE_2(3) (its position),
    SO(3) attitude states with a zero position, SE(2) and SO(2) lifted to 3D (a rotation about z, z = 0), or
    the first factor of a product. ValueError (naming the argument) for another group, a shape mismatch or
    non-finite values."""
    from ..metrics import pose_parts

    p, q = pose_parts(g_hat)
    ts = np.asarray(ts, dtype=np.float64)
    if ts.shape != (p.shape[0],):
        raise ValueError(f"ts: expected shape ({p.shape[0]},) (one time per estimate), got {ts.shape}")
    if not (np.isfinite(ts).all() and np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError("ts, g_hat: expected finite times and poses, got NaN or inf")
    lines = [TUM_HEADER, *(" ".join(repr(float(v)) for v in row) for row in np.column_stack([ts, p, q]))]
    return write_text(path, "\n".join(lines) + "\n")


def read_tum(path: str | os.PathLike, name: str = "trajectory") -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """A TUM trajectory file: ``(ts (N,), (positions (N, 3), quaternions (N, 4) as x, y, z, w))``, the pair
    :func:`liemef.metrics.ape_rpe` takes. Blank lines and lines starting with ``#`` are skipped; values may be
    separated by spaces or commas. ValueError naming ``name``, the line and what it holds otherwise."""
    p = _existing_file(path, name)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"{name}: cannot read {str(p)!r} as text ({err})") from err
    rows = []
    for i, line in enumerate(text.splitlines()):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        try:
            row = [float(f) for f in fields]
        except ValueError:
            row = []
        if len(row) != 8 or not all(np.isfinite(row)):
            raise ValueError(f"{name}: expected 8 finite numbers 'timestamp tx ty tz qx qy qz qw' on line {i + 1} "
                             f"of {str(p)!r}, got {line!r}")
        rows.append(row)
    if not rows:
        raise ValueError(f"{name}: expected at least one pose line in {str(p)!r}, got none")
    a = np.array(rows)
    return a[:, 0], (a[:, 1:4], a[:, 4:8])
