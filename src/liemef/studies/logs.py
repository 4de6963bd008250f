"""Filtering a recorded log: what ``liemef run`` does, as a function a script calls alike.

>>> from liemef.studies import logs
>>> source = logs.resolve_system("localization")            # or logs.resolve_system(file="my_system.py")
>>> run = logs.filter_log(source, "log.csv", K0=0.1)        # doctest: +SKIP
>>> run.ok, run.message                                     # doctest: +SKIP
>>> run.save("out")                                         # doctest: +SKIP

:func:`resolve_system` gives a :class:`LogSystem` (a ready system of :data:`liemef.studies.experiments.SYSTEMS` or
a user's system file, with its default initial estimate and gain); :func:`filter_log` reads the log, starts the
minimum-energy filter there, runs it over the log in compiled chunks and returns a :class:`LogRun`: the
trajectory, the status report, the innovations and their monitor (:func:`liemef.metrics.innovation_monitor`),
``metrics.json``'s content and the arrays. :meth:`LogRun.save`
writes ``estimates.csv`` (coordinates and K's diagonal), ``innovations.csv``, ``metrics.json``, ``arrays.npz``
and ``estimate.png``, or for a failed run ``failure.json`` alone.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import types
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__, _validate
from ..reports import io

SCHEMA = "liemef.run/1"
"""Version tag of ``liemef run``'s ``metrics.json`` layout (system, log, config, innovation, gain, status, run,
figures)."""
FAILURE_SCHEMA = "liemef.failure/1"
"""Version tag of ``failure.json`` (status, message, last good state, log, filter)."""
OUTLIER_PROB = 1e-6
"""A used sample whose normalized innovation squared exceeds the chi-square quantile ``1 - OUTLIER_PROB`` (of its
sensor's dimension) is reported as an outlier by :meth:`LogRun.warnings` (the filter used it: no gate)."""
CONDITION_WARN = 1e12
"""A failed run whose gain K had a larger condition number than this says that rounding is the likely cause."""
DEFAULT_CHUNK = 65536
"""Samples per compiled chunk of :func:`filter_log` (one compilation per chunk length)."""


@dataclass(frozen=True)
class LogSystem:
    """A system to filter logs with, and where its defaults come from: ``label`` and ``description`` name it,
    ``measured(ys)`` reads state coordinates off measurements (a ready system; None for a user's file),
    ``user`` is the user's :class:`~liemef.systems._file.UserSystem` (its ``x0``, ``K0``, ``initial_guess``) and
    ``params`` the tuning file applied."""

    system: Any
    label: str
    description: str
    measured: Callable[[np.ndarray], np.ndarray] | None = field(default=None, repr=False)
    user: Any = field(default=None, repr=False)
    spec: Any = field(default=None, repr=False)
    params: dict | None = field(default=None, repr=False)
    """The tuning file applied (``--params``): its ``file``, ``sha256``, ``system``, the names it set
    (``from_file``) and every parameter ``values`` the system was built with (``metrics.json``'s
    ``config.params``); None without one."""
    settings: dict | None = field(default=None, repr=False)
    """The ready system's parameters set by ``--set KEY=VALUE`` (:func:`with_settings`), as parsed
    (``metrics.json``'s ``config.system_settings``); None without any."""
    rest: dict | None = field(default=None, repr=False)
    """What :func:`with_log_constants` measured in the log before the run (``metrics.json``'s
    ``config.rest``): the constants ``measured`` and the rest's extent, or ``found`` False and ``why`` when the log
    has no initial rest; None for a system that takes none."""

    def initial_guess(self, ys0) -> np.ndarray:
        """The default initial estimate in coordinates from the first present measurement of each component
        ``ys0`` (p,): the system file's ``x0``, else its ``initial_guess(ys0)``, else zeros; a ready system's
        :meth:`~liemef.studies.experiments.SystemSpec.initial_guess`."""
        if self.user is not None:
            if self.user.x0 is not None:
                return np.asarray(self.user.x0, dtype=np.float64)
            if self.user.initial_guess is not None:
                return self.user.guess(ys0)
            return np.zeros(self.system.group.coords_dim)
        if self.measured is None:  # a ready system whose --set changed its state or outputs
            return np.zeros(self.system.group.coords_dim)
        return self.spec.initial_guess(ys0)

    def default_K0(self) -> np.ndarray:
        """The system file's ``K0``, else the ready system's (:class:`~liemef.studies.experiments.SystemSpec`),
        else the identity."""
        if self.user is not None and self.user.K0 is not None:
            return np.asarray(self.user.K0, dtype=np.float64)
        if self.spec is not None and self.spec.K0 is not None and self.measured is not None:
            return np.asarray(self.spec.K0, dtype=np.float64)
        return np.eye(self.system.group.tangent_dim)

    def run_option(self, key: str, value, default):
        """The filter option ``key``: ``value`` when given, else the ready system's (``SystemSpec.run_options``),
        else ``default``."""
        if value is not None:
            return value
        return (self.spec.run_options if self.spec is not None else {}).get(key, default)


CONSTANTS = ("dip", "gravity", "field")
"""The ready IMU systems' parameters measured in the log before the run (:func:`with_log_constants`)."""


def with_log_constants(source: LogSystem, log) -> LogSystem:
    """``source`` rebuilt with the constants its ready system measures in the ``log`` before the run
    (``SystemSpec.constants``: the IMU systems' dip, gravity and field over the initial rest found from the IMU
    samples, :func:`liemef.systems.imu_rest.log_rest_constants`); those given with ``--set`` are kept. A log
    without an initial rest keeps the factory's defaults, which :attr:`LogSystem.rest` records and
    :meth:`LogRun.warnings` says. Any other system is returned as it is."""
    spec = source.spec
    if spec is None or spec.constants is None or source.rest is not None:
        return source
    given = set(source.settings or ()) & set(CONSTANTS)
    try:
        found = spec.constants(log.ts, log.us, log.ys)
    except ValueError as err:
        return dataclasses.replace(source, rest={"found": False, "why": str(err), "measured": []})
    constants = {k: float(found[k]) for k in CONSTANTS if k not in given}
    rest = {"found": True, "rest_s": float(found["rest_s"]), "rest_samples": int(found["rest_samples"]),
            "measured": sorted(constants), "dip_deg": math.degrees(found["dip"]), "gravity": float(found["gravity"]),
            "field": float(found["field"])}
    params = source.params
    if params is not None:
        from . import tune

        chosen = {k: params["values"][k] for k in params["from_file"]}
        system = tune.system_from(chosen, constants, params["system"])
        params = {**params, "values": tune.parameters(chosen, constants, params["system"])}
    else:
        settings = {k: tuple(v) if isinstance(v, list) else v for k, v in (source.settings or {}).items()}
        system = spec.make(**settings, **constants)
    said = ", ".join(sorted(constants))
    return dataclasses.replace(
        source, system=system, params=params, rest=rest,
        description=f"{source.description}; {said} measured over the initial rest detected from the IMU "
                    f"({rest['rest_s']:.1f} s)" if constants else source.description)


def resolve_system(name: str | None = None, file: str | os.PathLike | None = None, *,
                   timeout: float | None = None) -> LogSystem:
    """A ready system by ``name`` (:data:`liemef.studies.registry.SYSTEMS`) or a user's system ``file``
    (exactly one). ValueError when both or neither are given, the name is unknown or the file fails to load,
    or has not finished loading after ``timeout`` seconds (None or 0: no limit) (naming ``--system-file``)."""
    from ..systems import _file as system_file
    from .experiments import get_system

    if (name is None) == (file is None):
        raise ValueError("expected exactly one of --system NAME (a ready system) or --system-file FILE.py "
                         f"(your own), got {'both' if name else 'neither'}")
    if name is not None:
        spec = get_system(name)
        return LogSystem(spec.make(), spec.name, spec.description, spec.measured, spec=spec)
    path = Path(file)
    user = system_file.load_system_file(path, timeout=timeout)
    return LogSystem(user.system, path.stem, f"user system from {path}", user=user)


def schema_text(name: str | None = None, file: str | os.PathLike | None = None, *,
                timeout: float | None = None) -> str:
    """What ``liemef schema`` prints for a ready system ``name`` or your own ``file`` (:func:`resolve_system`,
    with ``timeout``): its label and description, then its log columns, units, roles and noise levels, and the
    CSV header."""
    from ..systems._file import format_schema

    source = resolve_system(name, file, timeout=timeout)
    return f"{source.label}: {source.description}\n{format_schema(source.system)}"


def system_schema(name: str) -> dict:
    """What ``liemef run`` and ``liemef schema`` need of the ready system ``name`` before JAX loads: its
    description, log columns (inputs, outputs and sensor blocks, :class:`liemef.reports.io.LogLayout`), state
    dimensions (coordinates, tangent) and the schema text of ``liemef schema``. Built from the system itself;
    :data:`liemef.studies._schemas.SCHEMAS` holds it for every ready system (:func:`write_schemas`)."""
    from ..systems._file import format_schema
    from .experiments import get_system

    spec = get_system(name)
    system = spec.make()
    return {"description": spec.description, "inputs": list(system.input_names),
            "outputs": list(system.output_names),
            "blocks": [[b.name, b.start, b.stop] for b in system.blocks()],
            "coords_dim": int(system.group.coords_dim), "tangent_dim": int(system.group.tangent_dim),
            "text": format_schema(system)}


def write_schemas(path: str | os.PathLike | None = None) -> Path:
    """Write :mod:`liemef.studies._schemas` (the schema of every ready system of
    :data:`liemef.studies.registry.SYSTEMS`, read without JAX) anew from the systems; ``tests/test_cli_startup.py``
    checks that it is current. Run ``python -c "from liemef.studies import logs; logs.write_schemas()"`` after a
    ready system's columns change."""
    import pprint

    from . import registry

    p = Path(path) if path is not None else Path(__file__).with_name("_schemas.py")
    table = {name: system_schema(name) for name in sorted(registry.SYSTEMS)}
    text = ('"""The log schemas of liemef\'s ready systems, read by the command line before JAX loads.\n\n'
            "Generated by :func:`liemef.studies.logs.write_schemas` from the systems themselves: do not edit.\n"
            '"""\n\nSCHEMAS = ' + pprint.pformat(table, width=116, sort_dicts=True) + "\n")
    return io.write_text(p, text)


def first_present(ys) -> np.ndarray:
    """Each measurement component's first present (finite) value, NaN where a component never has one."""
    ys = np.asarray(ys)
    ok = np.isfinite(ys)
    first = np.argmax(ok, axis=0)
    return np.where(ok.any(axis=0), ys[first, np.arange(ys.shape[1])], np.nan)


def run_chunked(flt, state, log, gap: float, chunk: int = DEFAULT_CHUNK, progress: bool = False):
    """``flt.run`` over the log in chunks of ``chunk`` intervals (one compilation per chunk length), each
    continuing from the previous chunk's final state, with ``progress`` the samples done after each chunk on
    stderr (:class:`~liemef.reports.progress.ProgressLine`: in place on a terminal, a line at a time when piped);
    stops at the first failure, and the samples after it have NaN estimates."""
    import time

    import jax
    import jax.numpy as jnp

    from ..engines import LogGapWarning
    from ..filters import CAUSES, Trajectory, nan_after_failure
    from ..reports.progress import ProgressLine

    N = log.ts.shape[0]
    line = ProgressLine("filtering") if progress and N - 1 > chunk else None
    t0 = time.perf_counter()
    pieces, start = [], 0
    while start < N - 1:
        stop = min(start + chunk, N - 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LogGapWarning)  # said once, from the final status
            traj = flt.run(state, log.ts[start:stop + 1], log.us[start:stop + 1], log.ys[start:stop + 1],
                           gap=gap)
        pieces.append(traj if start == 0 else jax.tree_util.tree_map(lambda a: a[1:], (traj.g_hat, traj.K)))
        state, start = traj.final, stop
        failed = not traj.status.code == 0
        if line is not None:
            line.show(f"filtering: {stop + 1}/{N} samples", time.perf_counter() - t0,
                      final=failed or stop >= N - 1)
        if failed:
            break
    if len(pieces) == 1:
        return pieces[0]
    first = pieces[0]
    parts = [(first.g_hat, first.K)] + pieces[1:]
    g_hat, K = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)
    n = K.shape[0]
    if n < N:  # stopped at a failure: the rest of the log has no estimate, NaN as the failed rows of a run
        codes = jnp.where(jnp.arange(N) < n, CAUSES.OK.code, traj.status.code)
        g_hat, K = nan_after_failure(codes, jax.tree_util.tree_map(
            lambda a: jnp.concatenate([a, jnp.zeros((N - n,) + a.shape[1:], a.dtype)]), (g_hat, K)),
            first_given=False)
    return Trajectory(ts=jnp.asarray(log.ts), g_hat=g_hat, K=K, status=traj.status, final=traj.final)


def failure_context(flt, log, k: int, g, K, gap: float, report: dict) -> dict:
    """What a failed run's interval ``k`` held, to say why it failed: its length (a gap?), whether its sub-steps
    hit their cap, and each sensor's sample at its start against the last good estimate ``g`` (gain ``K``): the
    residual ``y (-) h(g)`` of its present components and its size in standard deviations of the innovation,
    ``sqrt(r^T S^-1 r)`` with ``S = H K H^T + Sigma`` (``Sigma`` a sample's noise covariance; for a density sensor
    its average over the interval). The JSON-ready dict of ``failure.json``'s ``interval``, with ``"said"``: the
    clause that the failure message ends with."""
    import jax.numpy as jnp

    from ..filters import left_jacobian

    system, ts = flt.system, log.ts
    t0 = float(ts[k])
    dt = float(ts[k + 1] - ts[k]) if k + 1 < len(ts) else math.nan
    y = np.asarray(log.ys[k], dtype=np.float64)
    out = {"start": t0, "length": dt, "gap": bool(dt > gap), "substeps_capped": bool(report["substeps_capped"]),
           "samples": {}}
    said = []
    if out["gap"]:
        said.append(f"the interval is a gap of {dt:.4g} s, predicted through on held inputs")
    if out["substeps_capped"]:
        said.append("its integration hit the sub-step cap (max_substeps)")
    if report["cause"] == "non-finite":
        said += _nonfinite_functions(system, g, log, k, t0)
    Ks = 0.5 * (np.asarray(K) + np.asarray(K).T)
    with np.errstate(all="ignore"):
        cond = float(np.linalg.cond(Ks)) if np.all(np.isfinite(Ks)) else math.inf
    out["K_condition"] = cond if math.isfinite(cond) else None
    if cond > CONDITION_WARN:
        said.append(f"K at its start has a condition number of {cond:.2g}, at which float64 rounding (1/eps = "
                    f"{1 / np.finfo(np.float64).eps:.2g}) can break its positive definiteness: a K0 of a realistic "
                    "size (your prior's covariance) avoids this")
    present = np.isfinite(y)
    if present.any():
        y0 = jnp.asarray(np.where(present, y, 0.0))
        h, H = left_jacobian(lambda gg: system.output_seen_from(y0, gg, t0), g)
        r = np.asarray(y0 - h)
        H, K = np.asarray(H), np.asarray(K)
        Sigma = np.linalg.inv(np.asarray(flt.weights.Wy))
        sizes = []
        for b in flt.blocks:
            idx = np.arange(b.start, b.stop)[present[b.start:b.stop]]
            if idx.size == 0:
                continue
            S = H[idx] @ K @ H[idx].T + Sigma[np.ix_(idx, idx)] / (1.0 if b.sample or not dt > 0 else dt)
            with np.errstate(all="ignore"):
                try:
                    sigmas = float(np.sqrt(r[idx] @ np.linalg.solve(S, r[idx])))
                except np.linalg.LinAlgError:
                    sigmas = math.nan
            names = [system.output_names[i] for i in idx]
            out["samples"][b.name] = {"components": names,
                                      "residual": [float(v) if math.isfinite(v) else None for v in r[idx]],
                                      "sigmas": sigmas if math.isfinite(sigmas) else None}
            sizes.append((sigmas, b.name))
        shown = ", ".join(f"{name} {s:.3g}" for s, name in sorted(sizes, key=lambda x: -np.nan_to_num(x[0]))
                          if math.isfinite(s))
        if shown:
            said.append(f"its samples, in innovation standard deviations from the last good estimate: {shown}")
    out["said"] = "".join(f"; {s}" for s in said)
    return out


def _nonfinite_functions(system, g, log, k: int, t0: float) -> list[str]:
    """The system's functions that return NaN or infinities at the last good state ``g`` of a run that became
    non-finite over interval ``k``: the dynamics with the input in force (the last present one), the outputs
    and the residuals (:meth:`~liemef.systems.AbstractSystem.check_finite_at`), each named."""
    from ..systems._traced import at_state, check_finite

    us = np.asarray(log.us, dtype=np.float64)
    rows = np.flatnonzero(np.all(np.isfinite(us[:k + 1]), axis=1))
    u = us[rows[-1]] if rows.size else np.zeros(us.shape[1])
    out = []
    at = at_state("the last good state", t0) + f" with the input {u}"
    for check in (lambda: check_finite("dynamics", getattr(system, "dynamics_fn", system.dynamics),
                                       system.dynamics(g, u, t0), at),
                  lambda: system.check_finite_at(g, t0, state="the last good state", singular=False)):
        try:
            check()
        except ValueError as err:
            out.append(str(err).split("; expected")[0])
    return out


def _rotation_blocks(G, offset: int = 0) -> list[tuple[int, tuple[int, ...]]]:
    """Where the coordinates of ``G`` hold an SO(3) rotation vector: ``(coordinate offset, factor path)`` per
    SO(3) part (SO(3) itself, the rotation of SE(3), SE_2(3), SE_K(3), and of those in a product)."""
    from ..groups import SEK3, SO3, Product

    if isinstance(G, type) and issubclass(G, Product):
        out, o = [], offset
        for i, F in enumerate(G.factor_types):
            out += [(off, (i, *path)) for off, path in _rotation_blocks(F, o)]
            o += F.coords_dim
        return out
    if issubclass(G, SO3 | SEK3):
        return [(offset, ())]
    return []


@functools.cache
def _programs():
    """The compiled programs of a run's reports, made once per process. Each is ``eqx.filter_jit``: one program
    per system structure and log shape (the system's arrays, a recording's constants among them, are traced), so
    that a second run in the process, a test's or a notebook's, compiles nothing."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from ..filters import left_jacobian
    from ..groups import SO3

    @eqx.filter_jit
    def innovations(system, ys, g, ts):
        return jax.vmap(system.residual)(ys, jax.vmap(system.output)(g, ts), ts)

    @eqx.filter_jit
    def output_jacobians(system, g, ys, ts):
        return jax.vmap(lambda gg, y, t: left_jacobian(lambda x: system.output_seen_from(y, x, t), gg)[1])(g, ys, ts)

    @eqx.filter_jit
    def bands(G, blocks, g_hat, K):
        """The plotted components of each state (rotations as roll, pitch, yaw) and their stds from K."""
        def rotation(g, path):
            for i in path:
                g = g.factors[i]
            return g if isinstance(g, SO3) else g.rotation()

        def plotted(g):
            c = g.coords()
            for off, path in blocks:
                c = c.at[off:off + 3].set(rotation(g, path).as_rpy())
            return c

        def one(g, KK):
            J = jax.jacfwd(lambda xi: plotted(g.rplus(xi)))(jnp.zeros(G.tangent_dim))
            return plotted(g), jnp.sqrt(jnp.clip(jnp.einsum("ij,jk,ik->i", J, 0.5 * (KK + KK.T), J), 0.0))

        # one compiled program: an eager vmap of jacfwd dispatches (and compiles) each primitive on its own
        return jax.vmap(one)(g_hat, K)

    return types.SimpleNamespace(innovations=innovations, output_jacobians=output_jacobians, bands=bands)


def state_bands(system, g_hat, K, measured=None) -> dict[str, np.ndarray]:
    """The state components that ``liemef run``'s figure plots, with their standard deviations from K.

    The components are the coordinates of ``g_hat`` (batch (N,)), except that each SO(3) rotation vector (which
    jumps at +-pi) is replaced by roll, pitch and yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``); angles are unwrapped
    along time. A component ``f(g)`` has the standard deviation ``sqrt(J K J^T)`` with ``J`` the derivative of
    ``f(g_hat exp xi)`` at ``xi = 0`` (a standard deviation where K is the covariance of the left error xi, which
    only a system whose weights are noise levels makes it: the figure draws its band only then, from the flag
    ``plot_covariance`` that :func:`filter_log` saves beside these). ``measured`` (N, c) coordinates
    read off the measurements (NaN where not measured) are mapped alike and put on the estimate's branch.
    Returns ``names``, ``units``, ``values`` (N, c), ``std`` (N, c), ``measured`` (N, c, when given) and, for a
    pose group, ``path`` (N, 2): the estimate's x-y position (``path_measured`` from ``measured`` when it has x
    and y)."""
    import jax.numpy as jnp

    from ..groups import SE2, SEK3, SO3, Product
    from ..metrics import angle_mask, continuous_angles, pose_parts

    G = system.group
    names, units = list(system.state_names), list(system.state_units)
    angles = list(angle_mask(G))
    blocks = _rotation_blocks(G)
    for j, (off, _) in enumerate(blocks):
        names[off:off + 3] = [n + (f"_{j + 1}" if j else "") for n in ("roll", "pitch", "yaw")]
        units[off:off + 3] = ["rad"] * 3
        angles[off:off + 3] = [True, False, True]
    values, std = (np.asarray(a) for a in _programs().bands(G, tuple(blocks), g_hat, jnp.asarray(K)))
    values = continuous_angles(values, angles)
    out = {"names": np.array(names), "units": np.array(units), "values": values, "std": std}
    if measured is not None:
        m = np.array(measured, dtype=np.float64)
        for off, _ in blocks:
            rows = np.isfinite(m[:, off:off + 3]).all(axis=1)
            rv = np.where(rows[:, None], m[:, off:off + 3], 0.0)
            m[:, off:off + 3] = np.where(rows[:, None], np.asarray(SO3.exp(jnp.asarray(rv)).as_rpy()),
                                         np.nan)
        out["measured"] = continuous_angles(m, angles, reference=values)
    first = G.factor_types[0] if issubclass(G, Product) else G
    if not issubclass(first, SE2 | SEK3):  # no position (SO(2), SO(3), R^n)
        return out
    out["path"] = np.asarray(pose_parts(g_hat)[0])[:, :2]
    if measured is not None and {"x", "y"} <= set(names):
        out["path_measured"] = out["measured"][:, [names.index("x"), names.index("y")]]
    return out


def innovation_outliers(flt, log, traj, innov) -> dict[str, dict]:
    """Per sensor, the present samples whose innovation (``innov``, before their update) lies beyond the
    chi-square ``1 - OUTLIER_PROB`` quantile of its dimension, measured by ``r^T S^-1 r`` with ``S = H K H^T +
    Sigma`` (``Sigma`` one sample's noise covariance; for a density sensor its average over the interval): their
    count, and the largest in standard deviations (``sqrt(r^T S^-1 r)``) with its time. A JSON-ready dict."""
    import jax

    from .._chi2 import quantile


    system, ts = flt.system, log.ts
    ys = np.asarray(log.ys, dtype=np.float64)
    present = np.isfinite(ys)
    rows = np.flatnonzero(present.any(axis=1))
    Sigma = np.linalg.inv(np.asarray(flt.weights.Wy))
    out = {}
    if rows.size == 0:
        return out
    y0 = np.where(present[rows], ys[rows], 0.0)
    g = jax.tree_util.tree_map(lambda a: a[rows], traj.g_hat)
    H = np.asarray(_programs().output_jacobians(system, g, y0, ts[rows]))
    K = np.asarray(traj.K)[rows]
    dt = np.diff(ts, append=np.nan)[rows]
    finite_K = np.isfinite(K).all(axis=(1, 2))
    for b in flt.blocks:
        sl = slice(b.start, b.stop)
        scale = np.where(b.sample | ~(dt > 0), 1.0, dt)
        nis = np.full(rows.size, np.nan)
        # rows alike in which of the block's components are present share one batched solve
        patterns = present[rows, sl] & finite_K[:, None]
        for pattern in np.unique(patterns[patterns.any(axis=1)], axis=0):
            i = np.flatnonzero((patterns == pattern).all(axis=1))
            idx = np.arange(b.start, b.stop)[pattern]
            Hi = H[i][:, idx]
            S = Hi @ K[i] @ np.swapaxes(Hi, 1, 2) + Sigma[np.ix_(idx, idx)] / scale[i, None, None]
            r = innov[rows[i]][:, idx]
            with np.errstate(all="ignore"):
                try:
                    nis[i] = np.einsum("ij,ij->i", r, np.linalg.solve(S, r[..., None])[..., 0])
                except np.linalg.LinAlgError:  # a singular S somewhere: row by row, skipping those
                    for j, Sj, rj in zip(i, S, r, strict=True):
                        try:
                            nis[j] = rj @ np.linalg.solve(Sj, rj)
                        except np.linalg.LinAlgError:
                            pass
            nis[i] = np.where(nis[i] > quantile(1.0 - OUTLIER_PROB, int(idx.size)), nis[i], np.nan)
        sizes = np.sqrt(nis)
        hit = np.flatnonzero(np.isfinite(sizes))
        worst = hit[np.argmax(sizes[hit])] if hit.size else None
        out[b.name] = {"count": int(hit.size), "probability": OUTLIER_PROB,
                       "largest_sigmas": None if worst is None else float(sizes[worst]),
                       "largest_t": None if worst is None else float(ts[rows[worst]])}
    return out


def innovation_table(innov, names, units) -> tuple[str, dict]:
    """Mean, std and rms of each innovation component over its present samples (NaN = no sample): the text
    table and its JSON-ready form."""
    from ..metrics._stats import format_number, json_number

    rows, out = [], {}
    for j, name in enumerate(names):
        v = innov[:, j][np.isfinite(innov[:, j])]
        stats = {"count": int(v.size), "mean": float(v.mean()) if v.size else math.nan,
                 "std": float(v.std(ddof=1)) if v.size > 1 else math.nan,
                 "rms": float(np.sqrt(np.mean(v ** 2))) if v.size else math.nan}
        out[name] = {"unit": units[j], **{k: json_number(x) for k, x in stats.items()}}
        rows.append(f"  {name:<12} {units[j]:<7} {stats['count']:>8d} " + " ".join(
            f"{format_number(stats[k]):>12}" for k in ("mean", "std", "rms")))
    head = f"  {'component':<12} {'unit':<7} {'samples':>8} {'mean':>12} {'std':>12} {'rms':>12}"
    return "\n".join([head, *rows]), out


@dataclass(frozen=True)
class LogRun:
    """A filtered log: ``trajectory`` (the filter's :class:`~liemef.filters.Trajectory`), ``report`` (the
    status as a dict), ``filter`` (its repr), ``gap`` (the threshold used, s), ``x0`` and ``K0`` (the start), and
    either ``metrics``/``arrays``/``innovation_text``/``monitor`` (a good run; ``monitor`` the
    :class:`~liemef.metrics.InnovationReport` of its innovations) or ``failure`` (what ``failure.json`` holds)."""

    source: LogSystem
    log_file: str
    log: Any = field(repr=False)
    trajectory: Any = field(repr=False)
    filter: str
    report: dict
    gap: float
    x0: np.ndarray = field(repr=False)
    K0: np.ndarray = field(repr=False)
    message: str = ""
    failure: dict | None = None
    metrics: dict = field(default_factory=dict, repr=False)
    arrays: dict = field(default_factory=dict, repr=False)
    innovation_text: str = field(default="", repr=False)
    monitor: Any = field(default=None, repr=False)
    smoothed: dict | None = None

    @property
    def not_converged(self) -> bool:
        """The run was smoothed and the smoother did not converge (``liemef smooth`` writes its outputs and exits
        with status 5)."""
        return self.smoothed is not None and self.smoothed["status"] != "converged"

    @property
    def inconsistent(self) -> bool:
        """The run did not fail, but its innovations are inconsistent with its K (``liemef run`` exits with
        status 3)."""
        return self.monitor is not None and self.monitor.status == "inconsistent"

    @property
    def nonlinear(self) -> bool:
        """The run did not fail and its innovations are consistent, but the monitor found an output so curved over
        K's spread that K may understate the errors where no sensor looks (``liemef run`` exits with status 4)."""
        return self.monitor is not None and self.monitor.status == "nonlinear"

    @property
    def ok(self) -> bool:
        """The filter ran over the whole log with status ok."""
        return self.failure is None

    def warnings(self) -> list[str]:
        """What the run did that a user should know: gaps predicted through, inputs held, intervals integrated
        past the sub-step cap, outliers used (their times relative to the log's start,
        :func:`liemef._times.time_said`)."""
        from .._times import time_said

        out = []
        rest = self.source.rest
        if rest is not None and not rest["found"]:
            out.append(f"no initial rest found in the log ({rest['why']}); dip, gravity and field are "
                       f"{self.source.label}'s defaults: give them with --set dip=RAD --set gravity=M/S2 --set "
                       "field=UT")
        if self.report["gaps"]:
            out.append(f"{self.report['gaps']} interval(s) longer than the gap threshold {self.gap:.4g} s (longest "
                       f"{self.report['longest_gap']:.4g} s) were predicted through")
        if self.report["inputs_held"]:
            out.append(f"{self.report['inputs_held']} input sample(s) were missing; the previous input was held")
        from .tune import UNSAID_INTEGRATOR

        tuned = self.source.params or {}
        config = self.metrics.get("config", {})
        for key, unsaid, what in (("updates", None, "sample updates"),
                                  ("integrator", UNSAID_INTEGRATOR, "integrator")):
            was, used = tuned.get(key) or (unsaid if tuned else None), config.get(key)
            if was and used and was != used:
                out.append(f"the tuning file {tuned['file']} was tuned with {key}={was!r} and this run used "
                           f"{used!r}: its noise levels were fitted for the other {what} (--{key} {was} runs as it "
                           "was tuned)")
        if self.report.get("substeps_capped"):
            after = ("the estimate after them may be far off though the run is ok" if self.ok
                     else "the run failed")  # a failed run's status is not ok: its warning must not say it is
            out.append(f"{self.report['substeps_capped']} interval(s) hit the sub-step cap "
                       f"({self.report['substeps_max']} steps): their last step was forced past the integrator's "
                       f"stability budget, and {after} (a sample far outside its noise, held over the interval, "
                       "does this: a gate rejects it, and --updates discrete takes each sample as one safeguarded "
                       "update)")
        for name, o in self.metrics.get("innovation", {}).get("outliers", {}).items():
            if o["count"]:
                out.append(f"{name}: {o['count']} sample(s) lay beyond the chi-square {1 - OUTLIER_PROB:g} bound of "
                           f"their innovation (largest {o['largest_sigmas']:.3g} standard deviations, at "
                           f"{time_said(o['largest_t'], self.metrics['log']['t0'])}) and were used; a gate "
                           "(Sensor(gate=...) in a --system-file, or --set gate=P for a ready system whose "
                           "factory takes one) would reject them")
        return out

    def rejected(self) -> dict[str, int]:
        """Samples each gated sensor rejected (only sensors that rejected some)."""
        return {k: v for k, v in self.report["rejected"].items() if v}

    def save(self, out: str | os.PathLike) -> list[Path]:
        """Write the run into the folder ``out`` (created if missing): ``failure.json`` alone for a failed run,
        else ``estimates.csv``, ``innovations.csv``, ``metrics.json``, ``arrays.npz`` and ``estimate.png``."""
        from ..reports import plots

        d = io.ensure_dir(out)
        if self.failure is not None:
            return [io.write_json(d / "failure.json", self.failure)]
        a = self.arrays
        n = self.K0.shape[0]
        comps = [f"e{k}" for k in range(n)]
        names = [str(v) for v in a["names"]]
        coords = np.asarray(self.trajectory.coords())
        written = [io.write_csv(d / "estimates.csv", ["t", *names, *(f"K_{e}{e}" for e in comps)],
                                [a["ts"], *coords.T, *a["K_diag"].T]),
                   io.write_rows(d / "innovations.csv", ["t", *(str(v) for v in a["output_names"])],
                                 # an empty field: no sample, hence no innovation
                                 [[float(t), *("" if math.isnan(v) else float(v) for v in row)]
                                  for t, row in zip(a["ts"], a["innovation"], strict=True)])]
        written += io.write_result(d, self.metrics, a)
        written += plots.write_figures(d)
        return written


def filter_log(source: LogSystem | str, log, *, x0=None, K0=None, connection: str = "zero", order: str = "second",
               alpha: float = 0.0, interpolation: str = "hold", updates: str | None = None,
               substeps: int | str = "auto", curvature: str | None = None, error: str | None = None,
               integrator: str = "rkmk4", gap: float | None = None, chunk: int = DEFAULT_CHUNK,
               progress: bool = False, log_file: str | os.PathLike | None = None, monitor: bool = True,
               smooth: dict | None = None) -> LogRun:
    """Filter the recorded ``log`` (a path to a CSV or NPZ log, :func:`liemef.reports.io.read_log`, or a read
    log) with the minimum-energy filter of ``source`` (a :class:`LogSystem` or a ready system's name).

    ``x0``: the initial estimate in coordinates (default: :meth:`LogSystem.initial_guess` of the first present
    measurements); ``K0``: the initial gain, a number (times I), a diagonal or a matrix (default:
    :meth:`LogSystem.default_K0`); ``gap``: an interval longer than this is predicted through (default: 10 x the
    median interval); ``log_file``: the file named in the outputs when ``log`` is already read; ``monitor``: run
    the innovation monitor on a good run (:func:`liemef.metrics.innovation_monitor`: ``metrics["innovations"]``,
    :attr:`LogRun.monitor`); the other options are those of :class:`~liemef.filters.MinimumEnergyFilter`, where
    ``updates``, ``curvature`` and ``error`` None are the ready system's (``attitude-velocity``,
    ``attitude-position`` and ``attitude-field``: discrete, exact, left, as ``liemef compare broad``'s
    ``mef-vel``), else ``"hold"``, ``"safe"`` and ``"auto"``. ``smooth``: the options of :func:`liemef.smooth`
    (:func:`smoother_options`) to smooth the log after a good filter run (``liemef smooth``): the estimates,
    covariances and residuals written are then the smoother's, the innovation monitor stays the filter's, and a
    smoother that fails makes the run a failure. A ready IMU
    system is first built with the dip, gravity and field measured over the log's initial rest
    (:func:`with_log_constants`). ValueError for bad input, before any compile. A failure inside the filter is no
    exception: see :attr:`LogRun.ok`.
    """
    from ..filters import MinimumEnergyFilter
    from ..metrics import angle_mask, continuous_angles, gain_stats, innovation_monitor, state_labels
    from ..systems import RightErrorSystem

    if isinstance(source, str):
        source = resolve_system(source)
    system = source.system
    if isinstance(system, RightErrorSystem):
        raise ValueError("system: expected a system whose state is the one to estimate, got the right error of "
                         f"a {type(system.base).__name__} (liemef.systems.right_error): its state is the inverse, and "
                         "the run's x0, K0 and outputs would be of the inverse; filter it from Python, with "
                         "state_of and estimates_of")
    n, c = system.group.tangent_dim, system.group.coords_dim
    if log_file is None:
        log_file = str(log) if isinstance(log, str | os.PathLike) else "<log>"
    log_file = str(log_file)
    if isinstance(log, str | os.PathLike):
        log = io.read_log(log, system)
    source = with_log_constants(source, log)
    system = source.system
    updates = source.run_option("updates", updates, "hold")
    curvature = source.run_option("curvature", curvature, "safe")
    error = source.run_option("error", error, "auto")
    q0 = source.initial_guess(first_present(log.ys)) if x0 is None else np.asarray(x0, dtype=np.float64)
    if q0.shape != (c,):
        raise ValueError(f"x0: expected {c} coordinates, got shape {q0.shape}")
    K0 = source.default_K0() if K0 is None else np.asarray(K0, dtype=np.float64)
    K0 = K0 * np.eye(n) if K0.ndim == 0 else np.diag(K0) if K0.shape == (n,) else K0
    if K0.shape != (n, n):
        raise ValueError(f"K0: expected a number, {n} diagonal entries or an {n} x {n} matrix, got shape {K0.shape}")
    g0, problem = initial_element(system.group, q0)
    if problem is not None:
        what = "x0" if x0 is not None else "x0 (the system's initial guess)"
        raise ValueError(f"{what}: expected the coordinates of an element of {system.group.__name__}, got "
                         f"{q0.tolist()}; {problem}")
    flt = MinimumEnergyFilter(system, connection=connection, order=order, alpha=alpha, interpolation=interpolation,
                              substeps=substeps, updates=updates, curvature=curvature, error=error,
                              integrator=integrator)
    state = flt.init(g0, K0)
    if gap is None:
        gap = 10.0 * float(np.median(np.diff(log.ts)))
    traj = run_chunked(flt, state, log, gap, chunk, progress)
    status = traj.status
    report = status.as_dict([b.name for b in system.blocks()])
    common = {"source": source, "log_file": log_file, "log": log, "trajectory": traj, "filter": repr(flt),
              "report": report, "gap": gap, "x0": q0, "K0": K0, "message": status.message(log.ts)}
    names, units = state_labels(system)
    if not status.ok:
        k = int(status.index)
        last = np.asarray(traj.final.g_hat.coords())
        context = failure_context(flt, log, k, traj.final.g_hat, traj.final.K, gap, report)
        common["message"] = status.message(log.ts) + context.pop("said")
        failure = {"schema": FAILURE_SCHEMA, "status": report, "message": common["message"],
                   "last_good_state": {"sample": k, "t": float(log.ts[k]),
                                       "coords": dict(zip(names, map(float, last), strict=True)),
                                       "K_diag": [float(v) for v in np.diagonal(np.asarray(traj.final.K))]},
                   "interval": context, "log": log_file, "filter": repr(flt), "command": "run",
                   "liemef_version": __version__}
        return LogRun(**common, failure=failure)
    extra, report = {}, None
    if monitor:
        report = innovation_monitor(flt, traj, log.ts, log.us, log.ys)
        extra["innovations"] = report.as_dict()
    smoothed = None
    if smooth is not None:
        traj, smoothed = _smoothed(flt, state, log, traj, gap, smooth)
        if smoothed["status"] == "failed":
            common["message"] = f"smoother {smoothed['message']}"
            failure = {"schema": FAILURE_SCHEMA, "status": report_failed(common["report"], "smoother"),
                       "message": common["message"], "smoother": smoothed, "log": log_file, "filter": repr(flt),
                       "command": "smooth", "liemef_version": __version__}
            return LogRun(**common, failure=failure, smoothed=smoothed)
        common["trajectory"] = traj
        extra["smoother"] = smoothed
    run = _good_run(common, flt, system, source, log, traj, names, units, connection, order, alpha, interpolation,
                    updates, substeps, angle_mask, continuous_angles, gain_stats, smoothed=smoothed is not None)
    return dataclasses.replace(run, metrics={**run.metrics, **extra}, monitor=report, smoothed=smoothed)


def smoother_options(max_iterations: int = 200, tol: float = 1e-9, chunk: int | None = None,
                     overlap: int | None = None) -> dict:
    """``liemef smooth``'s options of :func:`liemef.smooth`, checked before JAX loads (ValueError naming
    ``--max-iterations``, ``--tol``, ``--smooth-chunk`` or ``--smooth-overlap``)."""
    out = {}
    for option, check, value in (("--max-iterations", lambda n, v: _validate.integer(n, v, low=1), max_iterations),
                                 ("--tol", _validate.nonnegative, tol),
                                 ("--smooth-chunk", lambda n, v: v if v is None else _validate.integer(n, v, low=1),
                                  chunk),
                                 ("--smooth-overlap", lambda n, v: v if v is None else _validate.integer(n, v),
                                  overlap)):
        try:
            out[option[2:].removeprefix("smooth-").replace("-", "_")] = check(option, value)
        except ValueError as err:
            raise _bad(option, str(err).removeprefix(f"{option}: ")) from err
    if overlap is not None and chunk is None:
        raise _bad("--smooth-overlap", f"only with --smooth-chunk (the states per window), got {overlap}")
    return out


def report_failed(report: dict, cause: str) -> dict:
    """A run's status dict with ``cause`` in place of ok (the filter ran; what came after it failed)."""
    return {**report, "ok": False, "cause": cause}


def _smoothed(flt, state, log, traj, gap: float, options: dict):
    """The smoother over the log from the filter's trajectory (:func:`liemef.smooth`), as a trajectory with its
    estimates and covariances, and what it did (status, message, iterations, costs)."""
    from ..filters import Trajectory
    from ..smoothers import smooth

    sm = smooth(flt, state, log.ts, log.us, log.ys, gap=gap, init=traj.g_hat, **options)
    said = {"status": sm.status, "message": sm.message, "iterations": sm.iterations, "cost": float(sm.cost),
            "cost_init": float(sm.cost_init), "gradient_norm": float(sm.gradient_norm),
            "options": dict(options)}
    return Trajectory(ts=traj.ts, g_hat=sm.g, K=sm.P, status=traj.status, final=traj.final), said


def _good_run(common, flt, system, source, log, traj, names, units, connection, order, alpha, interpolation,
              updates, substeps, angle_mask, continuous_angles, gain_stats, smoothed: bool = False) -> LogRun:

    from ..metrics import gain_is_covariance

    angles = angle_mask(system.group)
    filt = continuous_angles(np.asarray(traj.coords()), angles)
    K = np.asarray(traj.K)
    K_diag = np.diagonal(K, axis1=1, axis2=2)
    innov = np.asarray(_programs().innovations(system, log.ys, traj.g_hat, log.ts))
    onames, ounits = system.output_names, system.output_units
    text, table = innovation_table(innov, onames, ounits)
    # the outlier test is of innovations against K; a smoother's residuals have another covariance (the filter's
    # innovations stay judged by the monitor)
    outliers = {} if smoothed else innovation_outliers(flt, log, traj, innov)
    label, measured = source.label, source.measured
    bands = state_bands(system, traj.g_hat, K, None if measured is None else measured(log.ys))
    # the figure draws a sigma band only from a covariance: K where it is one, the smoother's P always
    bands["covariance"] = np.bool_(smoothed or gain_is_covariance(flt))
    figures = [{"file": "estimate.png", "kind": "run", "components": [str(v) for v in bands["names"]],
                "title": f"{label}: " + ("measured (blue), " if measured else "")
                         + ("smoothed (green) with +-3 sigma from its covariance" if smoothed else "filtered (green)"
                            + (" with +-3 sigma from K" if bands["covariance"] else ""))
                         + f", from {Path(common['log_file']).name}"}]
    metrics = {
        "schema": SCHEMA,
        "system": {"name": label, "description": source.description, "filter": common["filter"]},
        "log": {"file": common["log_file"], "samples": int(log.ts.shape[0]), "t0": float(log.ts[0]),
                "t1": float(log.ts[-1])},
        "config": {"x0": [float(v) for v in common["x0"]], "K0_diag": [float(v) for v in np.diagonal(common["K0"])],
                   "connection": connection, "order": order, "alpha": alpha, "interpolation": interpolation,
                   "updates": updates, "substeps": substeps, "integrator": flt.integrator.name,
                   "curvature": flt.curvature,
                   "error": flt.error, "iterations": flt.iterations, "gap": common["gap"], "params": source.params,
                  "system_settings": source.settings, "rest": source.rest},
        "innovation": {"definition": ("y (-) h(g_smoothed) (the sensors' residual, y - h unless declared) at each "
                                      "present sample, at the smoother's estimate (which has used every sample)")
                       if smoothed else "y (-) h(g_hat) (the sensors' residual, y - h unless declared) at each present "
                       "sample (before the update of that sample)",
                       "components": table,
                       "outliers": outliers},
        "gain": gain_stats(K),
        "status": common["report"],
        "run": {"finite": True, "liemef_version": __version__},
        "figures": figures,
    }
    arrays = {"ts": log.ts, "names": np.array(names), "units": np.array(units), "filtered": filt,
              "K_diag": K_diag, "us": log.us, "ys": log.ys, "innovation": innov, "output_names": np.array(onames)}
    if measured is not None:
        arrays["measured"] = continuous_angles(measured(log.ys), angles, reference=filt)
    arrays.update({f"plot_{k}": v for k, v in bands.items()})
    return LogRun(**common, metrics=metrics, arrays=arrays, innovation_text=text)


def initial_element(G, q0) -> tuple[Any, str | None]:
    """``(G.from_coords(q0), problem)``: the element of the coordinates ``q0`` and, when it is not finite and on
    the group (coordinates too large for ``exp``, NaN), what is wrong with it (else None)."""
    import jax.numpy as jnp

    from .. import _validate

    g0 = G.from_coords(jnp.asarray(q0, dtype=jnp.float64))
    try:
        _validate.element("from_coords(x0)", g0, G)
    except ValueError as err:
        return g0, str(err)
    return g0, None


def _bad(option: str, message: str) -> ValueError:
    """A ValueError naming the command-line ``option`` it is about
    (:class:`liemef.studies.settings.OptionError`, for the CLI's hint)."""
    from .settings import OptionError

    return OptionError(message, option)


def check_log_file(path: str | os.PathLike) -> None:
    """What can be said of a log file before it is read (and before JAX loads): an existing, non-empty .csv or
    .npz file. ValueError naming ``--log`` otherwise."""
    p = Path(path)
    if not p.exists():
        raise _bad("--log", f"log: file not found: {str(p)!r}")
    if p.is_dir():
        csv = sorted(q.name for q in p.glob("*.csv"))
        held = f"; it holds {len(csv)} .csv file(s), e.g. {csv[0]!r}: give one of them" if csv else ""
        raise _bad("--log", f"log: expected a .csv or .npz log file, or a ROS bag (a .bag file, or a ROS 2 bag "
                            f"folder with a metadata.yaml), got the folder {str(p)!r} without a metadata.yaml{held}")
    if not p.is_file():
        raise _bad("--log", f"log: expected a file, got {str(p)!r}")
    if p.suffix.lower() not in (".csv", ".npz"):
        raise _bad("--log", f"log: expected a .csv or .npz file, got {str(p)!r}")
    if p.stat().st_size == 0:
        raise _bad("--log", f"log: expected a CSV or NPZ log, got an empty file {str(p)!r}")


@dataclass(frozen=True)
class SavedRun:
    """What :func:`filter_log_to` did: the filtered ``run`` (:class:`LogRun`), the ``log`` read, the folder
    ``out`` and the files ``written`` there (``failure.json`` alone for a failed run)."""

    run: LogRun
    log: Any = field(repr=False)
    out: Path
    written: list[Path]

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef run`` prints, in order: each line with True where it goes to stderr (a warning)."""
        run = self.run
        verb = "Filtered" if run.ok else "Failed to filter"  # a failed run's message says where it stopped
        lines = [(f"{verb} {self.log.ts.shape[0]} samples of {run.log_file} with {run.source.label} "
                  f"({run.filter})", False)]
        rest = run.source.rest
        if rest is not None and rest["found"] and rest["measured"]:
            lines.append((f"Measured over the initial rest detected from the IMU ({rest['rest_s']:.1f} s): dip "
                          f"{rest['dip_deg']:.2f} deg, gravity {rest['gravity']:.4g} m/s^2, field {rest['field']:.4g} "
                          f"(the log's unit); used: {', '.join(rest['measured'])}", False))
        if run.rejected():
            lines.append(("Gate rejected samples: " + ", ".join(f"{k} {v}" for k, v in run.rejected().items()),
                          False))
        lines += [(f"WARNING: {w}", True) for w in run.warnings()]
        if not run.ok:
            return lines + ([(f"Smoothed: {run.smoothed['message']}", True)] if run.smoothed else [])
        if run.monitor is not None:
            lines.append((("The filter's innovations: " if run.smoothed else "") + run.monitor.message(),
                          run.inconsistent or run.nonlinear))
        if run.smoothed is not None:
            lines.append((f"Smoothed: {run.smoothed['message']}" if not run.not_converged else
                          f"WARNING: the smoother {run.smoothed['message']}; the estimates written are its last "
                          "accepted ones, not the minimizer", run.not_converged))
        residual = "Residual y - h(g_smoothed)" if run.smoothed else "Innovation y - h(g_hat)"
        return lines + [(f"{residual} over the present samples:", False), (run.innovation_text, False),
                        (f"Sub-steps: {run.report['substeps_total']} over {run.report['steps']} intervals (at most "
                         f"{run.report['substeps_max']} in one)", False),
                        ("Wrote estimates.csv (coordinates and K's diagonal), innovations.csv, metrics.json, "
                         f"arrays.npz, {', '.join(p.name for p in self.written[4:])} to {self.out}", False)]

    @property
    def error(self) -> str | None:
        """Why the run failed (``liemef run`` exits with status 1), or None. An inconsistent run is no error
        (its outputs are written whole): see :attr:`LogRun.inconsistent`."""
        if self.run.ok:
            return None
        return (f"{self.run.message} (cause: {self.run.report['cause']}). No estimates were written; see "
                f"{self.out / 'failure.json'}")


def filter_log_to(out: str | os.PathLike, log: str | os.PathLike, *, system: str | None = None,
                  system_file: str | os.PathLike | None = None, topics: str | os.PathLike | None = None,
                  params: str | os.PathLike | None = None, x0=None, K0=None, tum: bool = False, force: bool = False,
                  timeout: float | None = None, settings: Sequence[str] = (), **options) -> SavedRun:
    """Filter the recorded ``log`` and write its outputs to the folder ``out``, whole or not at all: what
    ``liemef run`` does, for a script as well.

    ``system`` (a ready system's name) or ``system_file`` (your own), exactly one; ``log`` a CSV or NPZ file, or
    a ROS bag with ``topics`` (the mapping file, :mod:`liemef.reports.rosbag`); ``params`` a `liemef tune` file
    (attitude-imu only); ``settings`` the ready system's parameters as ``KEY=VALUE`` texts (``--set``,
    :func:`with_settings`); ``x0``, ``K0`` and ``options`` as :func:`filter_log`; ``tum`` also writes
    ``estimates.tum``; ``force`` replaces a folder of another command (:func:`liemef.reports.outputs.claim`);
    ``timeout``: the seconds ``system_file`` may take to load (None or 0: no limit; the command line's
    ``--timeout``, :data:`liemef.studies.registry.SYSTEM_FILE_TIMEOUT` by default).
    Bad input is a ValueError naming the option (``err.option``), raised before anything is written and, for a
    ready system and a CSV or NPZ log, before JAX is imported. A failure inside the filter is no exception:
    ``out`` then holds ``failure.json`` alone and :attr:`LogRun.ok` is False."""
    from ..reports import outputs
    from . import registry

    try:
        _validate.timeout("--timeout", timeout)
    except ValueError as err:
        raise _bad("--timeout", str(err).removeprefix("--timeout: ")) from err
    K0 = None if K0 is None else np.asarray(K0, dtype=np.float64)
    if K0 is not None and K0.ndim == 0 and not (math.isfinite(K0) and K0 >= 0):
        raise _bad("--k0", f"expected a number >= 0, got {float(K0)}")
    if K0 is not None and K0.ndim == 1 and not np.all(np.isfinite(K0) & (K0 >= 0)):
        raise _bad("--k0-diag", f"expected finite numbers >= 0 separated by commas, got {K0.tolist()}")
    for flag, key, ok, bound in (("--alpha", "alpha", lambda v: v >= 0, ">= 0"),
                                 ("--gap", "gap", lambda v: v > 0, "> 0 (s)")):
        v = options.get(key)  # checked again by the filter, which would name the keyword, not the option
        if v is not None and not (math.isfinite(v) and ok(v)):
            raise _bad(flag, f"expected a finite number {bound}, got {v}")
    if (system is None) == (system_file is None):
        raise ValueError("expected exactly one of --system NAME (a ready system) or --system-file FILE.py (your "
                         f"own), got {'both' if system else 'neither'}")
    if params is not None and system not in registry.tune_systems():
        raise _bad("--params", f"expected --system {' or '.join(registry.tune_systems())} with a tuning file, got "
                               f"{system!r}")
    settings = tuple(settings or ())
    if settings and params is not None:
        raise _bad("--set", "expected either a tuning file (--params) or --set KEY=VALUE, got both")
    if settings and system is None:
        raise _bad("--set", "expected a ready system (--system); a system file sets its own parameters")
    log = Path(log)
    bag = io.is_bag(log)
    if bag and topics is None:
        raise _bad("--topics", f"{log} is a ROS bag: give --topics MAPPING.json")
    if not bag:
        check_log_file(log)
    if system_file is not None and not Path(system_file).is_file():
        raise _bad("--system-file", f"expected a Python file defining `system`, got {str(system_file)!r} "
                                    "(not found)")
    smooth = options.get("smooth")
    if smooth is not None:
        options["smooth"] = smoother_options(**smooth)
    target = outputs.claim(out, "run" if smooth is None else "smooth", force)
    recorded = None
    if system is not None and not settings:  # a ready system: its columns and sizes are known without JAX
        known = registry.system_schema(system)
        for name, value, n in (("--x0", x0, known["coords_dim"]), ("--k0-diag", K0, known["tangent_dim"])):
            if value is not None and np.ndim(value) == 1 and np.shape(value) != (n,):
                raise _bad(name, f"expected {n} finite numbers separated by commas, got {len(value)}")
        if topics is None:
            layout = io.LogLayout(tuple(known["inputs"]), tuple(known["outputs"]),
                                  tuple(tuple(b) for b in known["blocks"]))
            recorded = _read(lambda: io.read_log(log, layout), "--log")
    source = resolve_system(system, system_file, timeout=timeout)
    if params is not None:
        source = _tuned(source, params)
    if settings:
        source = with_settings(source, settings)
    n, c = source.system.group.tangent_dim, source.system.group.coords_dim
    for name, value, size in (("--x0", x0, c), ("--k0-diag", K0, n)):
        if value is not None and np.ndim(value) == 1 and np.shape(value) != (size,):
            raise _bad(name, f"expected {size} finite numbers separated by commas, got {len(value)}")
    if x0 is not None:
        _, problem = initial_element(source.system.group, np.asarray(x0, dtype=np.float64))
        if problem is not None:
            raise _bad("--x0", f"expected the coordinates of an element of {source.system.group.__name__}, got "
                               f"{np.asarray(x0, dtype=np.float64).tolist()}; {problem}")
    if tum:
        from ..metrics import pose_parts

        _read(lambda: pose_parts(source.system.group.identity((1,))), "--tum")
    if recorded is None:
        recorded = _read(lambda: io.read_log(log, source.system), "--log") if topics is None else \
            _read_bag(log, topics, source.system)
    run = filter_log(source, recorded, x0=x0, K0=K0, log_file=log, **options)
    with outputs.staged(target, manifest=run.ok) as d:
        written = run.save(d)
        if tum and run.ok:
            written.append(io.write_tum(d / io.TUM_FILE, recorded.ts, run.trajectory.g_hat))
    return SavedRun(run=run, log=recorded, out=target.path, written=[target.path / p.name for p in written])


def _read(fn, option: str):
    try:
        return fn()
    except ValueError as err:
        raise _bad(option, str(err)) from err


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _system_value(key: str, text: str, default):
    """``text`` (``--set KEY=VALUE``) as a value of the ready system's parameter ``key`` whose default is
    ``default``: true/false for a bool, a finite number for a number, null or a number or comma-separated
    numbers for a parameter that may be None (a name otherwise: robust=huber), one number or comma-separated numbers
    for a number or a sequence (the factory checks how many), the text for a string."""
    def number(t):
        try:
            v = float(t)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise _bad("--set", f"{key}: expected a finite number, got {t!r}")
        return v

    t = text.strip()
    if isinstance(default, bool):
        if t.lower() not in ("true", "false"):
            raise _bad("--set", f"{key}: expected true or false, got {text!r}")
        return t.lower() == "true"
    if isinstance(default, str):
        return t
    if default is None and t.lower() in ("null", "none"):
        return None
    parts = [p for p in t.replace(",", " ").split()]
    if not parts:
        raise _bad("--set", f"{key}: expected a value, got {text!r}")
    if default is None and not all(_is_number(p) for p in parts):
        return t  # a name (robust=huber): the factory checks it
    values = [number(p) for p in parts]  # one number, or one per axis (gnss_std=0.5,0.5,1): the factory checks
    return values[0] if len(values) == 1 and not isinstance(default, tuple | list) else tuple(values)


def with_settings(source: LogSystem, items) -> LogSystem:
    """``source`` (a ready system) rebuilt with its factory's parameters set by ``--set KEY=VALUE`` ``items``
    (for example ``gnss_std=0.5``, ``biases=true``, ``mag_std=0.02``; ``liemef schema`` names the factory). A key
    that is not a parameter, a value of the wrong type, and a value the factory refuses (a negative std) are
    ValueErrors naming ``--set``. Where the settings change the state or the outputs, the initial estimate is
    no longer read off the measurements: it is ``--x0`` (default: the identity's coordinates)."""
    import inspect

    if source.spec is None:
        raise _bad("--set", "expected a ready system (--system); a system file sets its own parameters")
    make = source.spec.make
    params = {k: p.default for k, p in inspect.signature(make).parameters.items()
              if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.default is not p.empty}
    if not params:
        raise _bad("--set", f"the ready system {source.label!r} has no parameters to set (its paper's weights); "
                            "write a system file (--system-file) for others")
    kwargs = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise _bad("--set", f"expected KEY=VALUE, got {item!r}")
        if key not in params:
            raise _bad("--set", f"{source.label} has no parameter {key!r}; expected one of {sorted(params)}")
        if key in kwargs:
            raise _bad("--set", f"{key} is set twice")
        kwargs[key] = _system_value(key, text, params[key])
    shown = ", ".join(f"{k}={v}" for k, v in kwargs.items())
    try:
        system = make(**kwargs)
    except (ValueError, TypeError) as err:
        raise _bad("--set", f"{source.label} with {shown}: {err}") from err
    default = source.system
    same = (system.group is default.group and tuple(b.name for b in system.blocks())
            == tuple(b.name for b in default.blocks()) and system.output_dim == default.output_dim)
    base = source.description.split("; defaults of ")[0].split("; the default noise levels")[0]
    return dataclasses.replace(source, system=system, measured=source.measured if same else None,
                               settings={k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items()},
                               description=f"{base}; built with {shown} (--set)")


def _tuned(source: LogSystem, params) -> LogSystem:
    """``source`` (a ready system that ``liemef tune`` fits) built with the final parameter set of the tuning file
    ``params`` (``--params``, read and checked by :func:`liemef.studies.tune.read`: a file for another system is
    refused), its description and :attr:`LogSystem.params` saying which file (SHA-256) and every value used."""
    from . import tune

    tuned = _read(lambda: tune.read(params, system=source.label), "--params")
    chosen = tune.params_for(tuned.data)
    values = tune.parameters(chosen, {}, tuned.system)
    system = _read(lambda: tune.system_from(chosen, {}, tuned.system), "--params")
    base = source.description.split("; defaults of ")[0]
    return dataclasses.replace(
        source, system=system, params={"file": str(params), "sha256": tuned.sha256, "system": tuned.system,
                                       "from_file": sorted(chosen), "values": values,
                                       "updates": tuned.data.get("updates"),
                                       "integrator": tuned.data.get("integrator")},
        description=f"{base}; the final parameter set of the tuning file {params} (sha256 {tuned.sha256[:12]}; "
                    "every value in metrics.json's config.params)")


def _read_bag(path, topics, system):
    from ..reports.rosbag import read_bag

    try:
        return read_bag(path, topics, system)
    except ValueError as err:
        if err.args[0].startswith("mapping"):
            raise _bad("--topics", str(err)) from err
        raise
