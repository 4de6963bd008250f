"""A user's system from a Python file (``liemef run --system-file FILE.py``) and the log schema of a system.

The file is executed as a module. It must define ``system`` (a liemef system, e.g. a
:class:`liemef.systems.SensorSystem`) and may define ``K0`` (n x n initial gain, or a length-n diagonal),
``x0`` (initial estimate in the group's coordinates) and ``initial_guess(y0) -> coords`` (an estimate from the
first row of measurements, NaN where missing).

A file that never finishes (a loop, a wait) is stopped after ``timeout`` seconds: a SIGALRM timer interrupts it
and the ValueError names the file and ``--timeout`` (the command line's default,
:data:`liemef.studies.registry.SYSTEM_FILE_TIMEOUT`). The timer needs the main thread of a POSIX process;
elsewhere (a worker thread, Windows) the file runs without one.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import signal
import sys
import threading
import types
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import _validate


@dataclass(frozen=True)
class UserSystem:
    """What a system file defines."""

    system: Any
    path: Path
    K0: np.ndarray | None = None
    x0: np.ndarray | None = None
    initial_guess: Any = None

    def guess(self, y0) -> np.ndarray:
        """The file's ``initial_guess(y0)`` as coordinates: ValueError naming the file and the function when it
        raises (or exits), or returns anything but the group's coordinates as finite real numbers."""
        c = self.system.group.coords_dim
        where = f"--system-file: initial_guess of {str(self.path)!r}"
        try:
            q = self.initial_guess(y0)
        except (Exception, SystemExit) as err:
            raise ValueError(f"{where} failed: {type(err).__name__}: {err}") from err
        return _validate.array(where, q, (c,))


class _Expired(BaseException):
    """The timer of :func:`_deadline` went off (a BaseException: a user's ``except Exception`` does not hold it)."""


@contextlib.contextmanager
def _deadline(seconds: float | None):
    """Raise :class:`_Expired` in the code of the ``with`` block after ``seconds`` (None or 0: never), by a
    SIGALRM timer, in the main thread of a POSIX process where no other timer runs (else no limit)."""
    usable = (seconds and hasattr(signal, "SIGALRM") and threading.current_thread() is threading.main_thread()
              and signal.getitimer(signal.ITIMER_REAL)[0] == 0)
    if not usable:
        yield
        return

    def expire(signum, frame):
        raise _Expired

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def run_python_file(path: Path, option: str, source: str | None = None, timeout: float | None = None):
    """Execute a user's Python file as a fresh module (``source``: its text, when the file itself is not on
    this machine, e.g. on a Dask worker) and return the module. ValueError naming ``option`` when it cannot be
    loaded or raises, or when it has not finished after ``timeout`` seconds (None: no limit; module
    docstring)."""
    timeout = _validate.timeout("--timeout", timeout)
    name = f"liemef_user_{uuid.uuid4().hex}"
    if source is None:
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise ValueError(f"{option}: cannot load {str(path)!r} as a Python module")
        module = importlib.util.module_from_spec(spec)
    else:
        module = types.ModuleType(name)
        module.__file__ = str(path)
    sys.modules[name] = module
    try:
        with _deadline(timeout):
            if source is None:
                spec.loader.exec_module(module)
            else:
                exec(compile(source, str(path), "exec"), module.__dict__)  # noqa: S102 - the user's own file
    except _Expired as err:
        raise ValueError(f"{option}: running {str(path)!r} did not finish within {timeout:g} s and was stopped (a "
                         "loop that never ends?); give it more time with --timeout SECONDS (0: no limit)") from err
    except (Exception, SystemExit) as err:  # a user's file: whatever it raised, named (exit() included)
        raise ValueError(f"{option}: running {str(path)!r} failed: {type(err).__name__}: {err}") from err
    finally:
        sys.modules.pop(name, None)
    return module


def load_system_file(path: str | os.PathLike, timeout: float | None = None) -> UserSystem:
    """Execute ``path`` and return its ``system`` (and optional ``K0``, ``x0``, ``initial_guess``).

    ValueError naming ``--system-file`` when the file is missing, fails to run, has not finished after
    ``timeout`` seconds (None: no limit; module docstring) or defines no liemef system.
    """
    from . import AbstractSystem

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--system-file: expected a Python file defining `system`, got {str(p)!r} (not found)")
    module = run_python_file(p, "--system-file", timeout=timeout)
    system = getattr(module, "system", None)
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"--system-file: expected {str(p)!r} to define `system`, a liemef system (e.g. "
                         f"liemef.systems.SensorSystem), got {type(system).__name__}")
    n, c = system.group.tangent_dim, system.group.coords_dim
    K0 = getattr(module, "K0", None)
    if K0 is not None:
        K0 = np.asarray(K0, dtype=np.float64)
        K0 = np.diag(K0) if K0.shape == (n,) else K0
        if K0.shape != (n, n):
            raise ValueError(f"--system-file: K0: expected shape ({n}, {n}) or ({n},), got {K0.shape}")
    x0 = getattr(module, "x0", None)
    if x0 is not None:
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (c,):
            raise ValueError(f"--system-file: x0: expected {c} coordinates, got shape {x0.shape}")
    guess = getattr(module, "initial_guess", None)
    if guess is not None and not callable(guess):
        raise ValueError(f"--system-file: initial_guess: expected a function of the first measurement row, got "
                         f"{type(guess).__name__}")
    return UserSystem(system=system, path=p, K0=K0, x0=x0, initial_guess=guess)


def log_schema(system) -> list[dict]:
    """The columns of a log for ``system``: name, unit, role and, for sensors, the noise level and meaning."""
    rows = [{"column": "t", "unit": "s", "role": "time", "noise": ""}]
    units = getattr(system, "input_units", None) or ("",) * system.input_dim
    for name, unit in zip(system.input_names, units, strict=True):
        rows.append({"column": name, "unit": unit, "role": "input", "noise": ""})
    sensors = {s.name: s for s in getattr(system, "sensors", ())}
    names, out_units = system.output_names, system.output_units
    for b in system.blocks():
        s = sensors.get(b.name)
        for j in range(b.start, b.stop):
            noise = ""
            if s is not None:
                std = float(np.asarray(s.noise.std)[j - b.start])
                unit = out_units[j] or "1"
                noise = (f"std {std:g} {unit} per sample" if s.noise.meaning == "sample"
                         else f"density {std:g} {unit}/sqrt(Hz)")
            rows.append({"column": names[j], "unit": out_units[j], "role": f"sensor {b.name}", "noise": noise})
    return rows


def format_schema(system) -> str:
    """:func:`log_schema` as an aligned text table, with the CSV header line."""
    rows = log_schema(system)
    w = [max(len(k), *(len(r[k]) for r in rows)) for k in ("column", "unit", "role")]
    lines = [f"{'column':<{w[0]}}  {'unit':<{w[1]}}  {'role':<{w[2]}}  noise"]
    lines += [f"{r['column']:<{w[0]}}  {r['unit']:<{w[1]}}  {r['role']:<{w[2]}}  {r['noise']}".rstrip() for r in rows]
    lines += ["", "CSV header: " + ",".join(r["column"] for r in rows),
              "An empty field (or nan) is a missing sample; a missing input holds the previous one."]
    return "\n".join(lines)
