"""The hand-written C99 reference step of the TSE(2) filter (``c/tse2_reference.c``): build, run, time.

The reference reproduces ``liemef.MinimumEnergyFilter(PlanarRigidBody(), connection="zero", order="second",
integrator=..., alpha=0.0, substeps=1)`` from the closed forms of Rigo et al. 2022 (see the C file's header).
It is the yardstick of ``bench_tse2.py`` (issue 9): every speed figure is also printed as a ratio to it.

    lib = build(tmpdir)                       # compiles with $CC or cc: -O2 -std=c99 -fPIC -shared
    g_traj, K_traj = run(lib, "rkmk4", ts, us, ys, g0_leaves, K0)
    us_per_step = time_per_step(lib, "rkmk4", ts, us, ys, g0_leaves, K0)

States are liemef's TSE2 leaves concatenated: ``(cos theta, sin theta, x, y, omega, vx, vy)``.
Only NumPy and the standard library are needed (an element of ``liemef.groups.TSE2`` is also accepted as g0).
"""

from __future__ import annotations

import ctypes
import os
import shlex
import shutil
import subprocess
import time

import numpy as np

SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "c", "tse2_reference.c")
"""The C source."""
INTEGRATORS = {"lie-euler": 0, "euler": 0, "rkmk4": 1, "rk4": 1}
"""liemef's integrator names to the C codes (TSE2_REF_LIE_EULER, TSE2_REF_RKMK4)."""
FLAGS = ("-O2", "-std=c99", "-fPIC", "-shared")
"""The compiler flags of :func:`build`."""

_P = ctypes.POINTER(ctypes.c_double)


def compiler() -> list[str] | None:
    """The C compiler command: ``$CC`` if set (may carry flags), else ``cc``; None if it is not found."""
    cmd = shlex.split(os.environ.get("CC", "") or "cc")
    return cmd if cmd and shutil.which(cmd[0]) else None


def build(tmpdir, extra: tuple[str, ...] = ()) -> str:
    """Compile the reference into ``tmpdir`` (with ``extra`` flags after :data:`FLAGS`, e.g. ``-march=native``)
    and return the path of the shared library.

    Raises RuntimeError if no C compiler is found or the compilation fails (with the compiler's output)."""
    cmd = compiler()
    if cmd is None:
        raise RuntimeError("no C compiler: set $CC or install cc")
    out = os.path.join(os.fspath(tmpdir), f"libtse2_reference{''.join(extra).replace('=', '_')}.so")
    proc = subprocess.run([*cmd, *FLAGS, *extra, SOURCE, "-o", out, "-lm"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling {SOURCE} failed:\n{proc.stdout}{proc.stderr}")
    return out


def load(path) -> ctypes.CDLL:
    """The library at ``path`` with the argument types of ``tse2_ref_run`` set."""
    lib = ctypes.CDLL(os.fspath(path))
    lib.tse2_ref_run.argtypes = [ctypes.c_int, ctypes.c_int, _P, _P, _P, _P, _P, _P, _P]
    lib.tse2_ref_run.restype = ctypes.c_int
    return lib


def _lib(lib) -> ctypes.CDLL:
    return lib if isinstance(lib, ctypes.CDLL) else load(lib)


def g_leaves(g0) -> np.ndarray:
    """The 7 state numbers: an array (7,), a sequence of leaves (4,) + (3,), or a ``TSE2`` element."""
    if hasattr(g0, "factors"):  # a liemef TSE2 element: its pytree leaves, in order
        import jax

        g0 = jax.tree_util.tree_leaves(g0)
    if isinstance(g0, list | tuple):
        g0 = np.concatenate([np.ravel(np.asarray(a, dtype=np.float64)) for a in g0])
    g0 = np.array(g0, dtype=np.float64).ravel()
    if g0.shape != (7,):
        raise ValueError(f"g0: expected 7 numbers (cos, sin, x, y, omega, vx, vy), got shape {g0.shape}")
    return g0


def _arrays(integrator, ts, us, ys, g0, K0):
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator: expected one of {sorted(INTEGRATORS)}, got {integrator!r}")
    ts = np.ascontiguousarray(ts, dtype=np.float64)
    N = ts.shape[0]
    us = np.ascontiguousarray(us, dtype=np.float64)
    ys = np.ascontiguousarray(ys, dtype=np.float64)
    if ts.ndim != 1 or N < 2 or us.shape != (N, 2) or ys.shape != (N, 7):
        raise ValueError(f"ts, us, ys: expected shapes (N,), (N, 2), (N, 7) with N >= 2, got {ts.shape}, "
                         f"{us.shape}, {ys.shape}")
    K0 = np.array(K0, dtype=np.float64)
    if K0.shape != (6, 6):
        raise ValueError(f"K0: expected a 6 x 6 matrix, got shape {K0.shape}")
    return INTEGRATORS[integrator], ts, us, ys, g_leaves(g0), K0


def _call(lib, code, ts, us, ys, g, K, g_out, K_out):
    ptr = lambda a: None if a is None else a.ctypes.data_as(_P)  # noqa: E731
    rc = lib.tse2_ref_run(code, ts.shape[0] - 1, ptr(ts), ptr(us), ptr(ys), ptr(g), ptr(K), ptr(g_out), ptr(K_out))
    if rc != 0:
        raise RuntimeError(f"tse2_ref_run returned {rc}")


def run(lib, integrator, ts, us, ys, g0_leaves, K0) -> tuple[np.ndarray, np.ndarray]:
    """Filter the log ``(ts, us, ys)`` (shapes (N,), (N, 2), (N, 7)) in C from ``(g0, K0)``.

    ``lib``: the path from :func:`build` or a loaded library; ``integrator``: ``"rkmk4"`` or ``"lie-euler"``.
    Returns the trajectory ``g_traj`` (N, 7) and ``K_traj`` (N, 6, 6), the initial state first, as liemef's
    ``run`` (sample k is held over ``[ts[k], ts[k+1])``)."""
    code, ts, us, ys, g, K = _arrays(integrator, ts, us, ys, g0_leaves, K0)
    N = ts.shape[0]
    g_out, K_out = np.empty((N, 7)), np.empty((N, 6, 6))
    _call(_lib(lib), code, ts, us, ys, g, K, g_out, K_out)
    return g_out, K_out


def time_per_step(lib, integrator, ts, us, ys, g0, K0, repeats=5) -> float:
    """Median wall time per step, in microseconds, of the C run over the whole log (trajectory stored, as
    liemef's ``run`` does), over ``repeats`` runs after one warm-up run."""
    code, ts, us, ys, g, K = _arrays(integrator, ts, us, ys, g0, K0)
    lib = _lib(lib)
    N = ts.shape[0]
    g_out, K_out = np.empty((N, 7)), np.empty((N, 6, 6))
    times = []
    for k in range(repeats + 1):
        gk, Kk = g.copy(), K.copy()
        t0 = time.perf_counter()
        _call(lib, code, ts, us, ys, gk, Kk, g_out, K_out)
        if k:
            times.append(time.perf_counter() - t0)
    return float(np.median(times)) / (N - 1) * 1e6
