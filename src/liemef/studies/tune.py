r"""``liemef tune``: fit a system's noise levels (and its noise model's parameters) to recorded data, across
several recordings, with leave-one-recording-out cross-validation.

Objectives (:data:`OBJECTIVES`):

* ``"truth"``: the attitude error against a truth (BROAD's total rms over its movement mask, deg);
* ``"nll"``: the innovations' negative log-likelihood, which needs no truth. Before sample $k$ is used, the
  filter predicts it: $\nu_k = y_k - h(\hat g_k)$ with covariance $S_k = Dh\,K_k\,Dh^\top + \Sigma(y_k)$ (K is
  the covariance of the left error, $\Sigma(y)$ the sample's own noise under the system's noise model). The cost is
  $\frac{1}{N}\sum_k \tfrac12 (\nu_k^\top S_k^{-1}\nu_k + \log\det S_k)$. A direction sensor (a unit vector) has
  two degrees of freedom: its innovation and covariance are taken in the tangent plane at $h(\hat g_k)$.

Search: derivative-free (scipy's Nelder-Mead) over the logarithms of the parameters. The filter's adaptive
sub-steps (a ``while_loop``) have no reverse-mode derivative, and the noise model's weights move the sub-step
count, so the objective is piecewise smooth at best: a gradient through the compiled filter does not exist
where it would be needed. Every evaluation reuses the compiled filter (the parameters are array leaves).

Cross-validation, nested: the outer loop holds recording $i$ out; the inner search, a Nelder-Mead from the
common start (``start`` or the system's defaults) on the mean over the other recordings, never asks for
recording $i$, so its path does not depend on it. Once the fold's point is fixed, recording $i$ is run there
once: its *held-out* error, which the report puts beside the fold's training error. The final set is the same
search on every recording (:data:`PARAMS_FROM`); its errors on those recordings are training errors, and the
folds' held-out mean is the estimate of its error on a recording it has not seen. The cost is $R + 1$ searches
for $R$ recordings, about $R$ times one search's filter runs; runs are cached per (point, recording), so the
searches share the points where they coincide (the initial simplex, the same for every search), and a cached
value is what a fresh run would give. Objectives may be computed on each recording's first ``seconds``
(windowed, for speed); the held-out evaluation of :func:`liemef.studies.compare.compare_broad` then runs whole
recordings.

The result is saved as JSON (:func:`save`, :func:`load`): the system's name, the parameters, and per fold the
parameters tuned without that recording, which ``liemef run``, ``liemef compare broad`` and
:func:`system_from` accept. A file is data with a schema (:func:`read`, :data:`FILE_KEYS`): a file for another
system, an unknown key, a value of the wrong type or a negative std is refused by name.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _names, _validate
from ..reports import io
from . import registry

OBJECTIVES = tuple(registry.TUNE_OBJECTIVES)
"""The objectives :func:`tune` minimizes, declared with their descriptions in
:data:`liemef.studies.registry.TUNE_OBJECTIVES`."""
PARAMETERS = {
    "acc_std": (1e-3, 1.0),
    "mag_std": (1e-3, 1.0),
    "acc_adapt": (1e-2, 100.0),
    "acc_norm_tol": (1e-3, 10.0),
    "mag_adapt": (1e-2, 100.0),
    "dip_std": (1e-3, 3.0),
    "bias_walk": (1e-7, 1e-2),
    "gyro_std": (1e-4, 0.1),
    "acc_density": (1e-4, 1.0),
    "velocity_std": (1e-2, 10.0),
    "position_std": (1e-3, 10.0),
    "position_walk": (1e-5, 1.0),
    "gyro_scale_std": (1e-4, 0.3),
}
"""The tunable parameters of the IMU systems and their bounds (the search is in log space)."""
ZERO_ALLOWED = ("acc_adapt", "mag_adapt", "dip_std", "gyro_scale_std")
"""The parameters that may be 0 in a tuning file (0 turns a noise model's term off); the others, standard
deviations and ``acc_norm_tol``, must be > 0."""
SYSTEM = "attitude-imu"
"""The default system of a tuning file."""
SYSTEMS = {name: registry.SYSTEMS[name].tunable for name in registry.tune_systems()}
"""The systems a tuning file may be for (:func:`liemef.systems.attitude_imu`,
:func:`liemef.systems.attitude_velocity`, :func:`liemef.systems.attitude_position`) and the parameters each
takes: a view of :data:`liemef.studies.registry.SYSTEMS` (``tunable``), the command line's choices."""
DEFAULT_NAMES = {name: registry.SYSTEMS[name].tune_defaults for name in registry.tune_systems()}
"""The parameters :func:`tune` fits by default, per system (``tune_defaults`` of the registry)."""
FORMAT = "liemef-tune-1"
CROSS_VALIDATION = "nested"
"""A tuning file's ``cross_validation``: each fold's search ran on its training recordings only and never saw its
held-out recording (a file without the key was written by the earlier shared search, whose held-out errors are
partly in-sample)."""
UNSAID_INTEGRATOR = "rkmk4"
"""The integrator of a tuning file without the key ``integrator``: RKMK4, the only one :func:`tune` ran before its
files named it."""
PARAMS_FROM = "search-on-all-recordings"
"""A tuning file's ``params_from``: its final set ``params`` is a search, from the same start with the same
budget as each fold's, over every recording. Its own errors (``per_recording``, ``train``) are training errors;
the folds' held-out mean is the estimate of its error on recordings it has not seen."""


@dataclass(frozen=True)
class Recording:
    """One recording to tune on: its log, the structural constants of its system (``dip``, ``gravity``,
    ``field``, measured at rest), the initial state, and optionally its truth (quaternions (w, x, y, z) body
    -> world) with the mask of samples the error counts."""

    name: str
    ts: np.ndarray
    us: np.ndarray
    ys: np.ndarray
    constants: dict
    g0: object
    K0: np.ndarray
    quat_true: np.ndarray | None = None
    mask: np.ndarray | None = None
    system: str = SYSTEM
    rest_s: float | None = None
    """The initial rest (s) the constants were measured over, found from the IMU samples
    (:func:`~liemef.systems.imu_rest.initial_rest`); None when they come from elsewhere."""


def broad_recordings(trials: Sequence[str] | None = None, seconds: float | None = None,
                     realdata: str | None = None, *, lead: float = 5.0, gyro: str = "forward",
                     system: str = SYSTEM) -> list[Recording]:
    """The BROAD trials present (:func:`liemef.studies.datasets.broad_trials`) as recordings for
    :func:`liemef.systems.attitude_imu`, with the dip and the norms measured over the initial rest, which is found
    from the IMU samples alone (:func:`~liemef.systems.imu_rest.rest_constants`; BROAD's movement annotation
    only scores, as the mask of the ``"truth"`` objective).

    Whole trials (``seconds`` None) start as ``liemef compare broad`` does: TRIAD of the first 50 samples, zero
    bias and its ``K0``. A window (``seconds``) starts ``lead`` s before the end of the detected rest and lasts
    ``lead + seconds`` s: TRIAD of its first 50 samples (at rest) and the mean gyro over the rest before it as
    the bias, with ``K0 = diag((0.05 rad)^2 I3, (0.002 rad/s)^2 I3)`` (what any user can measure at rest). ``gyro``:
    the gyro's sample convention (:func:`liemef.studies.datasets.broad_to_log`; ``"backward"`` for
    ``updates="discrete"``, as ``liemef compare broad``'s ``mef-imu-d``). ``system``: a key of :data:`SYSTEMS`;
    the bounded-motion models (``"attitude-velocity"``, ``"attitude-position"``) take their own log
    (:func:`~liemef.systems.bounded_velocity.imu_velocity_log`, ``imu_position_log``), the state at rest at the
    origin and their K0 (``K0_VELOCITY``, ``K0_POSITION``; in a window, their blocks beyond the bias)."""
    from ..reports import io as _io
    from ..systems import bounded_velocity as bv
    from ..systems.attitude_bias import K0_GYRO_BIAS
    from ..systems.imu_rest import initial_estimate, rest_constants
    from . import datasets

    if system not in SYSTEMS:
        raise ValueError(f"system: expected one of {list(SYSTEMS)}, got {system!r}")
    moving = {"attitude-velocity": (bv.imu_velocity_log, bv.attitude_velocity_state, bv.K0_VELOCITY),
              "attitude-position": (bv.imu_position_log, bv.attitude_position_state, bv.K0_POSITION)}.get(system)
    K0 = K0_GYRO_BIAS if moving is None else moving[2]
    state = (lambda g: g) if moving is None else moving[1]

    folder = None if realdata is None else Path(realdata) / datasets.BROAD_DIR
    found = datasets.broad_trials(folder)
    ids = list(found) if trials is None else [f"{int(t):02d}" if str(t).isdigit() else str(t) for t in trials]
    missing = [t for t in ids if t not in found]
    if not ids or missing:
        raise ValueError(f"trials: expected BROAD trials present from {list(found)}, got {ids}")
    if len(set(ids)) != len(ids):  # a fold "without" a trial given twice would train on it
        raise ValueError(f"trials: expected each trial once, got {ids}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds: expected a window > 0 s, or None for whole trials (liemef tune's --seconds 0), "
                         f"got {seconds!r}")
    out = []
    for tid in ids:
        tr = datasets.broad(found[tid])
        rest = rest_constants(tr.gyr, tr.acc, tr.mag, tr.rate)  # from the IMU alone
        constants = {k: rest[k] for k in ("dip", "gravity", "field")}
        if moving is not None:
            log = _io.RecordedLog(*moving[0](tr.gyr, tr.acc, tr.mag, tr.rate, float(tr.ts[0]), gyro=gyro))
        else:
            log = datasets.broad_to_log(tr, norms=True, gyro=gyro)
        if seconds is None:
            g0 = initial_estimate(tr.acc[:50], tr.mag[:50])
            out.append(Recording(tid, log.ts, log.us, log.ys, constants, state(g0), K0, tr.quat_true, tr.movement,
                                 system, rest["rest_s"]))
            continue
        k_move = rest["rest_samples"]
        a = max(0, k_move - int(lead * tr.rate))
        b = min(len(tr.ts), k_move + int(seconds * tr.rate))
        bias = tr.gyr[:a].mean(axis=0) if a > 0 else np.zeros(3)
        w = slice(a, b)
        g0 = initial_estimate(tr.acc[a:a + 50], tr.mag[a:a + 50], bias)
        k0 = np.diag([0.05**2] * 3 + [0.002**2] * 3 + list(np.diag(K0)[6:]))
        out.append(Recording(tid, log.ts[w], log.us[w], log.ys[w], constants, state(g0), k0, tr.quat_true[w],
                             tr.movement[w], system, rest["rest_s"]))
    return out


def _factory(system: str):
    from ..systems import attitude_imu, attitude_position, attitude_velocity

    if system not in SYSTEMS:
        raise ValueError(f"system: expected one of {list(SYSTEMS)}, got {system!r}")
    return {"attitude-imu": attitude_imu, "attitude-velocity": attitude_velocity,
            "attitude-position": attitude_position}[system]


def check_params(params, system: str = SYSTEM, where: str = "params") -> dict:
    """``params`` as ``{name: float}``: a mapping from names of the system's tunable parameters
    (:data:`SYSTEMS`) to finite real numbers, > 0 (>= 0 for :data:`ZERO_ALLOWED`). A ValueError naming ``where``
    and the key otherwise: an unknown name, a boolean, a string, ``null``, NaN or a negative std."""
    if system not in SYSTEMS:
        raise ValueError(f"system: expected one of {list(SYSTEMS)}, got {system!r}")
    if not isinstance(params, dict):
        raise ValueError(f"{where}: expected a mapping from parameter names to numbers, got "
                         f"{type(params).__name__} {params!r}")
    allowed = SYSTEMS[system]
    out = {}
    for name, v in params.items():
        if name not in allowed:
            raise ValueError(f"{where}.{name}: unknown parameter of {system}; expected names from {sorted(allowed)}")
        floor = ">= 0" if name in ZERO_ALLOWED else "> 0"
        if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
            what = "a boolean" if isinstance(v, bool) else type(v).__name__
            raise ValueError(f"{where}.{name}: expected a number {floor}, got {_json(v)} ({what})")
        x = float(v)
        if not (math.isfinite(x) and (x >= 0 if name in ZERO_ALLOWED else x > 0)):
            raise ValueError(f"{where}.{name}: expected a finite number {floor}, got {v!r}")
        out[name] = x
    return out


def parameters(params: dict, constants: dict, system: str = SYSTEM) -> dict:
    """Every keyword argument the system ``system`` is built with by :func:`system_from`: the factory's
    defaults (:func:`liemef.systems.attitude_imu`, ``attitude_velocity`` or ``attitude_position``), the recording's
    ``constants`` and the tuned ``params`` (checked, :func:`check_params`) over them, as JSON values."""
    values = _defaults(system)
    values.update(constants)
    values.update(check_params(params, system))
    return {k: _plain(v) for k, v in values.items()}


def start_set(system: str, start: dict | None = None) -> dict:
    """The values every search of :func:`tune` starts from, for the tunable parameters of ``system``: its
    factory's defaults (:func:`system_from`'s factory), then ``start`` (checked, :func:`check_params`)."""
    defaults = {k: v for k, v in _defaults(system).items() if k in SYSTEMS[system]}
    return {**defaults, **check_params(start or {}, system, "start")}


def _defaults(system: str) -> dict:
    """The keyword arguments of ``system``'s factory (:func:`_factory`) that have a default, with it."""
    import inspect

    return {k: p.default for k, p in inspect.signature(_factory(system)).parameters.items()
            if p.default is not inspect.Parameter.empty}


def _plain(v):
    """A parameter's value as JSON: a float, a list of floats, a string or None."""
    if v is None or isinstance(v, str | bool):
        return v
    a = np.asarray(v, dtype=np.float64)
    return float(a) if a.ndim == 0 else a.tolist()


def system_from(params: dict, constants: dict, system: str = SYSTEM):
    """The system ``system`` (a key of :data:`SYSTEMS`: :func:`liemef.systems.attitude_imu`,
    ``attitude_velocity`` or ``attitude_position``) with the recording's ``constants`` and the tuned ``params``
    (:func:`check_params`)."""
    factory = _factory(system)
    return factory(**constants, **check_params(params, system))


# --- objectives -------------------------------------------------------------------------------------------------
def truth_error(rec: Recording, quat: np.ndarray) -> float:
    """BROAD's total rms (deg) of the estimate against the recording's truth over its mask."""
    from ..metrics import attitude_rms

    if rec.quat_true is None:
        raise ValueError(f"objective: 'truth' needs a truth; recording {rec.name!r} has none")
    e = attitude_rms(quat, rec.quat_true, rec.mask if rec.mask is not None else np.ones(len(rec.ts), bool))
    return float("inf") if e["total"] is None else e["total"]


def innovation_nll(system, traj, ys: np.ndarray) -> float:
    """The innovations' mean negative log-likelihood (module docstring) of the direction sensors ``acc`` and
    ``mag`` over the samples where they are present (``inf`` if it is not finite)."""
    import jax.numpy as jnp

    vals = np.asarray(_nll_terms(system, traj.g_hat, traj.K, jnp.asarray(ys)))
    return float(np.mean(vals)) if np.all(np.isfinite(vals)) else float("inf")


def _nll_one(system, g, K, y):
    import jax.numpy as jnp

    from ..filters import left_jacobian

    h, Dh = left_jacobian(lambda gg: system.output(gg, 0.0), g)
    T = system.sample_transform(jnp.where(jnp.isfinite(y), y, 0.0))
    Wy = T.T @ system.information() @ T
    total = 0.0
    for b in system.blocks():
        if b.name not in ("acc", "mag") or _constant(system, b.name):
            continue
        sl = slice(b.start, b.stop)
        hb = h[sl]
        # an orthonormal basis of the tangent plane at h (a unit vector): the sample's two degrees of freedom
        a = jnp.where(jnp.abs(hb[0]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
        e1 = jnp.cross(hb, a)
        e1 = e1 / jnp.linalg.norm(e1)
        P = jnp.stack([e1, jnp.cross(hb, e1)])
        ok = jnp.all(jnp.isfinite(y[sl]))
        nu = P @ (jnp.where(ok, y[sl], hb) - hb)
        S = P @ (Dh[sl] @ K @ Dh[sl].T + jnp.linalg.inv(Wy[sl, sl])) @ P.T
        val = 0.5 * (nu @ jnp.linalg.solve(S, nu) + jnp.linalg.slogdet(S)[1])
        total = total + jnp.where(ok, val, 0.0)
    return total


def _constant(system, name: str) -> bool:
    """Whether the sensor ``name``'s output does not depend on the state (a covariate, not a measurement)."""
    return any(s.name == name and s.covariate for s in system.sensors)


def _nll_terms_impl(system, g, K, ys):
    import jax

    return jax.vmap(lambda gg, KK, y: _nll_one(system, gg, KK, y))(g, K, ys)


def _lazy_jit():
    import equinox as eqx

    return eqx.filter_jit(_nll_terms_impl)


_NLL_JIT = []


def _nll_terms(system, g, K, ys):
    """Per sample, the NLL terms; compiled once per system structure (the noise levels are leaves)."""
    if not _NLL_JIT:
        _NLL_JIT.append(_lazy_jit())
    return _NLL_JIT[0](system, g, K, ys)


def evaluate(rec: Recording, params: dict, objective: str = "truth", *, order: str = "second",
             engine: str | None = None, updates: str = "hold", integrator: str = "rkmk4") -> float:
    """One recording's loss under ``params``: run the minimum-energy filter (``order``, ``updates``,
    ``integrator``) and score it; a failed run scores ``inf``."""
    from ..filters import MinimumEnergyFilter

    if objective not in OBJECTIVES:
        raise ValueError(f"objective: expected one of {list(OBJECTIVES)}, got {objective!r}")
    system = system_from(params, rec.constants, rec.system)
    # compare broad's mef-vel
    flt = MinimumEnergyFilter(system, order=order, updates=updates, curvature="exact", error="left",
                              integrator=integrator)
    traj = flt.run(flt.init(rec.g0, rec.K0), rec.ts, rec.us, rec.ys, engine=engine)
    if int(traj.status.code) != 0:
        return float("inf")
    if objective == "truth":
        return truth_error(rec, np.asarray(traj.g_hat.factors[0].wxyz))
    return innovation_nll(system, traj, rec.ys)


# --- the search -------------------------------------------------------------------------------------------------
def _to_params(names, x) -> dict:
    out = {}
    for n, v in zip(names, x, strict=True):
        lo, hi = PARAMETERS[n]
        out[n] = float(10.0 ** np.clip(v, math.log10(lo), math.log10(hi)))
    return out


def _search(loss_of: Callable[[np.ndarray, np.ndarray], np.ndarray], train: np.ndarray, x0: np.ndarray,
            maxfev: int, step: float) -> np.ndarray:
    """Nelder-Mead on the mean loss over the recordings ``train`` (a bool mask), from ``x0``: ``loss_of(x, train)``
    is asked for those recordings only, so the path depends on nothing else."""
    from scipy.optimize import minimize

    def f(x):
        m = float(np.mean(loss_of(x, train)))
        return m if math.isfinite(m) else 1e300

    simplex = np.vstack([x0] + [x0 + step * e for e in np.eye(len(x0))])
    res = minimize(f, x0, method="Nelder-Mead", options={"maxfev": maxfev, "initial_simplex": simplex,
                                                         "xatol": 0.02, "fatol": 1e-4})
    return np.asarray(res.x)


def tune(recordings: Sequence[Recording], names: Sequence[str] | None = None, objective: str = "truth", *,
         start: dict | None = None, maxfev: int = 40, fold_maxfev: int | None = None, step: float = 0.5,
         order: str = "second", updates: str = "hold", integrator: str = "rkmk4", progress: bool = True,
         workers: int | None = None) -> dict:
    """Tune ``names`` on ``recordings`` with nested leave-one-recording-out cross-validation (module docstring).

    Args:
        recordings: two or more :class:`Recording` (e.g. :func:`broad_recordings`).
        names: the parameters to tune (of the recordings' system, :data:`SYSTEMS`; default
            :data:`DEFAULT_NAMES`); the others stay at ``start`` or the system's defaults.
        objective: ``"truth"`` or ``"nll"``.
        start: the starting values of every search (default: the system's defaults).
        maxfev: points of the final search (each point runs every recording).
        fold_maxfev: points of each fold's own search (each runs the fold's training recordings); default
            ``maxfev``, the final search's procedure, whose held-out error it then estimates.
        step: the initial simplex's size, in decades.
        order: the filter's order.
        integrator: the filter's integrator (:data:`liemef._names.INTEGRATORS`): ``"rkmk2"`` evaluates the
            filter's field half as often as the default ``"rkmk4"``, a faster tune whose file says so
            (``liemef run`` warns when a run's integrator is not the file's).
        updates: the filter's sample updates (``"discrete"``: samples at their own time; give it recordings with
            ``gyro="backward"``).
        progress: a tqdm progress bar (on stderr), counting the searches' points.
        workers: threads that run a point's recordings side by side (default: the CPUs this process may use).
            The compiled filter runs outside Python's lock (ctypes), so on 2 cores a point costs about half; each
            loss is one recording's own run at one point, the same value whichever thread computes it.

    Returns ``{"format", "system", "objective", "names", "order", "updates", "integrator", "cross_validation",
    "params_from",
    "params", "train", "per_recording", "folds": {name: {"params", "train", "held_out"}}, "held_out_mean",
    "train_mean", "evaluations", "elapsed_s"}``: ``params`` is the final set (the search on every recording;
    ``per_recording`` and ``train`` are its training errors), ``folds[name]`` the search without ``name``, its
    training error and its error on ``name`` (held out); ``evaluations`` counts the filter runs (one recording at
    one point; a run shared by several searches counts once).
    """
    from ..integrators import integrator as make_integrator

    integrator = make_integrator(integrator).name  # checked before any run; the file keeps its own name
    recs = list(recordings)
    if len(recs) < 2 or not all(isinstance(r, Recording) for r in recs):
        raise ValueError(f"recordings: expected two or more Recording objects, got {len(recs)}")
    systems = {r.system for r in recs}
    if len(systems) != 1:
        raise ValueError(f"recordings: expected recordings of one system, got {sorted(systems)}")
    sysname = systems.pop()
    allowed = SYSTEMS[sysname]
    names = DEFAULT_NAMES[sysname] if names is None else tuple(names)
    bad = [n for n in names if n not in allowed]
    if not names or bad or len(set(names)) != len(names):
        why = f"unknown {bad}" if bad else "a name twice" if names else "none"
        raise ValueError(f"names: expected distinct parameter names from {sorted(allowed)}, got {list(names)} "
                         f"({why})")
    if objective not in OBJECTIVES:
        raise ValueError(f"objective: expected one of {list(OBJECTIVES)}, got {objective!r}")
    maxfev = _validate.integer("maxfev", maxfev, 1)
    workers = _validate.integer("workers", _validate.cpus() if workers is None else workers, 1)
    fold_maxfev = maxfev if fold_maxfev is None else _validate.integer("fold_maxfev", fold_maxfev, 1)
    base = start_set(sysname, start)
    first = {n: float(np.atleast_1d(base[n])[0]) for n in names}
    zero = [n for n in names if not first[n] > 0]
    if zero:  # the search is in log space
        raise ValueError(f"start: expected a value > 0 to start the search in log space for {zero} (their default "
                         f"0 turns the term off), got {[first[n] for n in zero]}")
    outside = {n: first[n] for n in names if not PARAMETERS[n][0] <= first[n] <= PARAMETERS[n][1]}
    if outside:  # the search keeps to its bounds: a start beyond them would be moved without a word
        raise ValueError("start: expected each searched parameter within its bounds, "
                         + ", ".join(f"{n} in [{PARAMETERS[n][0]:g}, {PARAMETERS[n][1]:g}]" for n in outside)
                         + f", got {outside}")
    x0 = np.array([math.log10(first[n]) for n in names])
    fixed = {k: float(np.atleast_1d(v)[0]) for k, v in base.items() if k not in names}
    R = len(recs)
    cache: dict[tuple, float] = {}  # (point, recording index) -> loss: a value, never a search's history
    t0 = time.perf_counter()
    bar = _progress(maxfev + R * fold_maxfev, progress)

    def key(x, i):
        return tuple(np.round(x, 12)), i

    def run(x, i):
        return evaluate(recs[i], {**fixed, **_to_params(names, x)}, objective, order=order, updates=updates,
                        integrator=integrator)

    def loss(x, i):
        if key(x, i) not in cache:
            cache[key(x, i)] = run(x, i)
        return cache[key(x, i)]

    def losses(x, which):
        """The losses of the recordings ``which`` (a bool mask) at x, and of no other: those not yet cached run
        side by side (the first run of all alone, so that the filter is compiled once)."""
        bar.update(1)
        todo = [i for i in np.flatnonzero(which) if key(x, i) not in cache]
        if todo and not cache:
            loss(x, todo.pop(0))
        for i, v in zip(todo, pool.map(lambda i: run(x, i), todo), strict=True):
            cache[key(x, i)] = v
        return np.array([loss(x, i) for i in np.flatnonzero(which)])

    everyone = np.ones(R, bool)
    folds = {}
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for i, rec in enumerate(recs):
            train = everyone.copy()
            train[i] = False
            bar.set_postfix_str(f"fold without {rec.name}")
            x_i = _search(losses, train, x0, fold_maxfev, step)  # recording i is not asked for until x_i is fixed
            folds[rec.name] = {"params": {**fixed, **_to_params(names, x_i)},
                               "train": _mean([loss(x_i, j) for j in np.flatnonzero(train)]),
                               "held_out": _loss(loss(x_i, i))}
        bar.set_postfix_str("final set (all recordings)")
        x_all = _search(losses, everyone, x0, maxfev, step)
        final = [loss(x_all, i) for i in range(R)]
    bar.close()
    return {"format": FORMAT, "system": sysname, "objective": objective, "names": list(names), "order": order,
            "updates": updates, "integrator": integrator, "cross_validation": CROSS_VALIDATION,
            "params_from": PARAMS_FROM,
            "params": {**fixed, **_to_params(names, x_all)}, "train": _mean(final),
            "per_recording": {r.name: _loss(v) for r, v in zip(recs, final, strict=True)},
            "folds": folds, "held_out_mean": _mean([f["held_out"] for f in folds.values()]),
            "rest_s": {r.name: float(r.rest_s) for r in recs if r.rest_s is not None},
            "train_mean": _mean([f["train"] for f in folds.values()]),
            "evaluations": len(cache), "elapsed_s": time.perf_counter() - t0}


def _loss(v) -> float | None:
    """A loss as the file keeps it: None for a failed run (an infinite loss), which JSON cannot hold."""
    return float(v) if v is not None and math.isfinite(v) else None


def _mean(values) -> float | None:
    """The mean of losses, None (failed) if one of them is."""
    values = [_loss(v) for v in values]
    return None if any(v is None for v in values) else float(np.mean(values))


def _progress(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="tune", unit="point", disable=not enabled, leave=True)


# --- the tuned set as a file --------------------------------------------------------------------------------------
def save(result: dict, path: str | Path) -> Path:
    """Write a tuning result (:func:`tune`) as JSON."""
    return io.write_json(Path(path), result)


FILE_KEYS = {"format": "text", "system": "text", "objective": "text", "names": "names", "order": "text",
             "updates": "text", "integrator": "text", "cross_validation": "text", "params_from": "text",
             "params": "params",
             "train": "loss", "per_recording": "losses",
             "folds": "folds", "held_out_mean": "loss", "train_mean": "loss", "evaluations": "count",
             "elapsed_s": "number", "rest_s": "numbers"}
"""The keys of a tuning file (every key :func:`tune` writes) and the kind of each value; ``format``, ``system``
and ``params`` are required, every other key is optional, and a key not listed is refused."""
FOLD_KEYS = {"params": "params", "train": "loss", "held_out": "loss"}
"""The keys of one fold of a tuning file's ``folds`` (``params`` required)."""
TEXT_CHOICES = {"format": (FORMAT,), "system": tuple(SYSTEMS), "objective": OBJECTIVES, "order": _names.ORDERS,
                "updates": _names.UPDATES, "integrator": _names.INTEGRATORS, "cross_validation": (CROSS_VALIDATION,),
                "params_from": (PARAMS_FROM,)}
"""The values a tuning file's text entries may take."""


@dataclass(frozen=True)
class TuningFile:
    """A tuning file read and checked (:func:`read`): its ``path``, the SHA-256 of its bytes and its ``data``
    (the JSON object :func:`save` wrote)."""

    path: Path
    sha256: str
    data: dict = field(repr=False)

    @property
    def system(self) -> str:
        """The system the file was tuned for (a key of :data:`SYSTEMS`)."""
        return self.data["system"]


def read(path: str | Path, system: str | None = None) -> TuningFile:
    """Read a tuning file (:func:`save`) and check it against its schema (:data:`FILE_KEYS`): an object with
    ``format`` :data:`FORMAT`, ``system`` (a key of :data:`SYSTEMS`; when ``system`` is given, that one) and
    ``params``, each parameter set a mapping from the system's names to finite numbers > 0 (>= 0 for
    :data:`ZERO_ALLOWED`), no key that :func:`tune` does not write. A ValueError starting ``params:`` and naming
    the file and the key otherwise. A file without ``system`` (written before ``liemef tune`` fitted two models)
    is refused: it was tuned for attitude-imu, and adding ``"system": "attitude-imu"`` makes it current."""
    import hashlib

    p = io._existing_file(path, "params")
    where = f"params: {str(p)!r}"
    try:
        raw = p.read_bytes()
        data = json.loads(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{where}: cannot read it as a liemef tuning file (JSON): {err}") from err
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a liemef tuning file (a JSON object with format {FORMAT!r}), got a "
                         f"JSON {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise ValueError(f"{where}: format: expected a liemef tuning file (format {FORMAT!r}), got "
                         f"{data.get('format')!r}")
    if "system" not in data:
        raise ValueError(f"{where}: system: missing; expected the model the file was tuned for, one of "
                         f"{list(SYSTEMS)} (a file written before liemef tune named it was tuned for attitude-imu: "
                         "add \"system\": \"attitude-imu\")")
    if data["system"] not in SYSTEMS:
        raise ValueError(f"{where}: system: expected one of {list(SYSTEMS)}, got {_json(data['system'])}")
    if "params" not in data:
        raise ValueError(f"{where}: params: missing; expected the tuned parameter set")
    if system is not None and data["system"] != system:
        raise ValueError(f"{where}: system: expected a file tuned for {system}, got one tuned for "
                         f"{data['system']!r} (its parameters are another model's)")
    for key, value in data.items():
        _check_entry(where, key, value, FILE_KEYS, data["system"])
    return TuningFile(p, hashlib.sha256(raw).hexdigest(), data)


def _number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _check_entry(where: str, path: str, value, keys: dict, system: str) -> None:
    """The entry ``path`` (its last part a key of ``keys``: :data:`FILE_KEYS` or :data:`FOLD_KEYS`) of a tuning
    file against its kind; a ValueError naming the file ``where`` and ``path`` otherwise."""
    key = path.rsplit(".", 1)[-1]
    if key not in keys:
        raise ValueError(f"{where}: {path}: unknown key; expected keys from {sorted(keys)}")
    kind, at = keys[key], f"{where}: {path}"
    if kind == "params":
        check_params(value, system, at)
        return
    if kind == "folds":
        if not isinstance(value, dict):
            raise ValueError(f"{at}: expected a mapping from recording names to folds, got {_json(value)}")
        for name, fold in value.items():
            if not isinstance(fold, dict) or "params" not in fold:
                raise ValueError(f"{at}.{name}: expected a fold with its params, got {_json(fold)}")
            for k, v in fold.items():
                _check_entry(where, f"{path}.{name}.{k}", v, FOLD_KEYS, system)
        return
    if kind == "text":
        ok, expected = value in TEXT_CHOICES[key], f"one of {list(TEXT_CHOICES[key])}"
    elif kind == "names":
        ok = isinstance(value, list) and all(isinstance(v, str) and v in SYSTEMS[system] for v in value)
        expected = f"a list of names from {sorted(SYSTEMS[system])}"
    elif kind == "number":
        ok, expected = _number(value), "a finite number"
    elif kind == "loss":
        ok, expected = value is None or _number(value), "a finite number, or null for a failed run"
    elif kind == "count":
        ok = isinstance(value, int) and not isinstance(value, bool) and value >= 0
        expected = "an integer >= 0"
    elif kind == "losses":
        ok = isinstance(value, dict) and all(v is None or _number(v) for v in value.values())
        expected = "a mapping from recording names to finite numbers, or null for a failed run"
    else:  # numbers
        ok = isinstance(value, dict) and all(_number(v) for v in value.values())
        expected = "a mapping from recording names to finite numbers"
    if not ok:
        raise ValueError(f"{at}: expected {expected}, got {_json(value)}")


def _json(value) -> str:
    text = json.dumps(value, default=repr)
    return text if len(text) <= 200 else text[:200] + "..."


def load(path: str | Path, system: str | None = None) -> dict:
    """A tuning file's content, read and checked by :func:`read`."""
    return read(path, system).data


def params_for(tuned: dict, recording: str | None = None) -> dict:
    """The parameters to use on ``recording``: its fold's (tuned without it) if the file has one, else the
    file's final set."""
    folds = tuned.get("folds") or {}
    if recording is not None and recording in folds:
        return dict(folds[recording]["params"])
    return dict(tuned["params"])


def _cell(loss: float | None) -> str:
    return "failed" if loss is None else f"{loss:.3f}"


def markdown(result: dict) -> str:
    """The tuning report: per recording, side by side, the held-out error (the fold tuned without it), the
    fold's training error (its mean over the other recordings) and the final set's error on it (in-sample), their
    means, and the parameters."""
    unit = "deg (BROAD total rms)" if result["objective"] == "truth" else "(mean NLL per sample)"
    nested = result.get("cross_validation") == CROSS_VALIDATION
    how = ("Nested leave-one-recording-out: each fold's search ran without its recording, which was then run once "
           "at the fold's point (held-out)." if nested else
           "Leave-one-recording-out with a shared search (a file without cross_validation): the folds started "
           "from a search that saw every recording, so their held-out errors are partly in-sample.")
    per = result.get("per_recording") or {}
    names = result["names"]
    lines = [f"# liemef tune: {result['system']}, objective {result['objective']} {unit}", "",
             f"{result['evaluations']} filter runs, {result['elapsed_s']:.0f} s. {how}"
             + ("" if not result.get("rest_s") else " Dip, gravity and field measured over the initial rest detected "
                "from the IMU (" + ", ".join(f"{k} {v:.1f} s" for k, v in result["rest_s"].items()) + ")."), "",
             "| recording | held-out (fold without it) | fold's training (the other recordings) "
             "| final set, in-sample | " + " | ".join(f"fold's {n}" for n in names) + " |",
             "|---|---:|---:|---:|" + "---:|" * len(names)]
    for name, f in result["folds"].items():
        final = _cell(per[name]) if name in per else "-"
        lines.append(f"| {name} | {_cell(f['held_out'])} | {_cell(f['train'])} | {final} | "
                     + " | ".join(f"{f['params'][n]:.4g}" for n in names) + " |")
    final = _cell(result["train"]) if "train" in result else "-"
    lines.append(f"| mean | {_cell(result['held_out_mean'])} | {_cell(result['train_mean'])} | {final} |"
                 + " |" * len(names))
    lines += ["", "Final set (a search on all recordings; its column above is a training error, the held-out mean "
              "estimates its error on an unseen recording): "
              + ", ".join(f"{k} = {v:.4g}" for k, v in result["params"].items()), ""]
    return "\n".join(lines)
