r"""Monte Carlo over seeds: N trials of an experiment, batched with ``jax.vmap``, reduced to statistics.

The papers report single noisy runs; a reproduction reports the distribution over seeds and where each
published number falls in it (docs/errata.md). :func:`montecarlo` runs ``runs`` trials of an experiment's
:class:`~liemef.studies.experiments.TrialSpec`:

* trial ``i`` uses the key ``jax.random.split(jax.random.key(seed), runs)[i]``, whatever the batch size
  (:func:`trial_keys`; the keys do depend on ``runs``);
* trials are evaluated ``batch_size`` at a time by one compiled ``jit(vmap(trial))``, the last batch padded
  to the same size so nothing recompiles; each trial is reduced inside the compiled function to its
  statistics over time in each window (:func:`liemef.metrics.error_stats`: mean, std, rms per component), so
  memory grows with ``runs`` x windows x components, not with the number of samples;
* a trial may return, besides its errors, its filter's status (``errors(key) -> (errors, status)``, a
  :class:`~liemef.filters.Status` or its ``code``); a trial diverged when its status failed or, without a
  status or beside it, when its errors are not all finite. A diverged trial is flagged in ``finite``, its
  cause recorded in ``causes`` (an index in :data:`~liemef.filters.CAUSES`: ``"non-finite"``, ``"K not
  positive definite"``, ...), and it is left out of every statistic across trials; the counts by cause are
  reported (:meth:`MonteCarloResult.divergence_summary`).

Across the finite trials, :class:`MonteCarloResult` gives for every (window, component, per-trial statistic)
the mean, the spread (sample std across trials, ddof = 1) and the percentiles 5, 25, 50, 75, 95 (linear
interpolation, as :func:`numpy.percentile`), and :meth:`MonteCarloResult.percentile_of` the percentile of a
published value (module ``_mcresult``). Results print as a table and save as ``<stem>.npz`` + ``<stem>.json``
(reloadable with :meth:`MonteCarloResult.load`) + ``<stem>.md`` + ``<stem>.csv``, written by
:mod:`liemef.reports.montecarlo`; the progress line is :mod:`liemef.reports.progress`'s.
"""

from __future__ import annotations

import collections
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ... import _validate
from ...filters import CAUSES, Status
from ...metrics import Window, error_stats, window_mask
from ...metrics._stats import PERCENTILES, STATS
from ...reports.progress import ProgressLine, format_progress, format_seconds
from ..registry import DEFAULT_BATCH_SIZE
from ._base import EXPERIMENTS, Experiment, TrialSpec, config_dict, get_experiment
from ._mcresult import SCHEMA, MonteCarloResult

__all__ = ["STATS", "PERCENTILES", "SCHEMA", "ProgressLine", "format_progress", "format_seconds", "trial_keys",
           "trial_cause", "trial_statistics", "TRACES", "resolve_experiment", "TrialArrays", "run_trials",
           "montecarlo", "result_of", "MonteCarloResult", "DEFAULT_BATCH_SIZE"]
# STATS (mean, std, rms: the last axis of MonteCarloResult.stats) and PERCENTILES come from liemef.metrics;
# SCHEMA (the <stem>.json layout), the tables and the files from liemef.reports.montecarlo; the progress line
# from liemef.reports.progress. They are re-exported here, where users have always imported them.

ProgressFn = Callable[[int, int, float, "float | None"], None]
"""``progress(done, total, elapsed_s, eta_s)``; ``eta_s`` is None until it can be estimated."""


def trial_keys(seed: int, runs: int) -> jax.Array:
    """The key of every trial: ``jax.random.split(jax.random.key(seed), runs)`` (ValueError naming ``seed`` or
    ``runs`` out of range: a seed in [0, 2**63 - 1], at least one run)."""
    seed = _validate.integer("seed", seed, 0, _validate.SEED_MAX)
    return jax.random.split(jax.random.key(seed), _validate.integer("runs", runs, 1))


def _reporter(progress: bool | ProgressFn, label: str) -> ProgressFn | None:
    if progress is True:
        return ProgressLine(label)
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    raise ValueError(f"progress: expected True, False or a function (done, total, elapsed, eta), got {progress!r}")


# --- the compiled batch ------------------------------------------------------------------------------------
_SHAPES: dict = {}


def _output_shape(spec: TrialSpec):
    """The shapes ``errors`` returns (``jax.eval_shape``: a trace). For a spec with ``params`` the trace is
    kept per ``errors`` function and structure of the params (their shapes, dtypes and static parts), so a
    sweep of values traces it once, as it compiles once."""
    key = jax.random.key(0)
    if spec.params is None:
        return jax.eval_shape(spec.errors, key)
    dynamic, static = eqx.partition(spec.params, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(dynamic)
    try:
        cache_key = (spec.errors, treedef, tuple((x.shape, str(x.dtype)) for x in leaves),
                     jax.tree_util.tree_structure(static), tuple(jax.tree_util.tree_leaves(static)))
        hash(cache_key)
    except TypeError:
        return eqx.filter_eval_shape(spec.errors, spec.params, key)
    if cache_key not in _SHAPES:
        _SHAPES[cache_key] = eqx.filter_eval_shape(spec.errors, spec.params, key)
    return _SHAPES[cache_key]


def _check_spec(name: str, spec: TrialSpec) -> np.ndarray:
    if not isinstance(spec, TrialSpec):
        raise ValueError(f"trial_fn of {name!r}: expected a TrialSpec, got {type(spec).__name__}")
    ts = np.asarray(spec.ts, dtype=np.float64)
    if ts.ndim != 1 or ts.shape[0] < 1:
        raise ValueError(f"trial_fn of {name!r}: expected ts of shape (N,), got {ts.shape}")
    c = len(spec.names)
    if len(spec.units) != c:
        raise ValueError(f"trial_fn of {name!r}: expected one unit per name ({c}), got {len(spec.units)}")
    if not spec.windows:
        raise ValueError(f"trial_fn of {name!r}: expected at least one window, got none")
    out = _output_shape(spec)
    if isinstance(out, tuple):
        if len(out) != 2:
            raise ValueError(f"trial_fn of {name!r}: expected errors(key) to return the errors or (errors, "
                             f"status), got a tuple of {len(out)}")
        out, status = out
        code = status.code if isinstance(status, Status) else status
        if getattr(code, "shape", None) != () or not jnp.issubdtype(code.dtype, jnp.integer):
            raise ValueError(f"trial_fn of {name!r}: expected the status of errors(key) to be a Status or its "
                             f"integer code (shape ()), got {getattr(code, 'shape', None)} "
                             f"{getattr(code, 'dtype', type(code).__name__)}")
    if tuple(out.shape) != (ts.shape[0], c):
        raise ValueError(f"trial_fn of {name!r}: expected errors(key) of shape ({ts.shape[0]}, {c}) "
                         f"(samples, components {list(spec.names)}), got {tuple(out.shape)}")
    return ts


def trial_cause(errors: Float[Array, "N c"], status: Status | Int[Array, ""] | None = None) -> Int[Array, ""]:
    """The cause code of a trial (an index in :data:`~liemef.filters.CAUSES`): its status code when the status
    failed, else ``"non-finite"`` when its errors are not all finite, else 0 (``"ok"``). Traceable."""
    finite = jnp.all(jnp.isfinite(errors))
    cause = jnp.where(finite, CAUSES.OK.code, CAUSES.NONFINITE.code).astype(jnp.int32)
    if status is None:
        return cause
    code = jnp.asarray(status.code if isinstance(status, Status) else status).astype(jnp.int32)
    return jnp.where(code != CAUSES.OK.code, code, cause)


TRACES = collections.Counter()
"""How many times a trial batch was traced (= compiled), by experiment name: a test that a sweep of weights
over a ``params`` trial (:class:`~liemef.studies.experiments.TrialSpec`) compiles once reads it."""


def _statistics_fn(name: str, errors: Callable, windows: tuple[Window, ...] | int, keep_every: int | None,
                   with_params: bool) -> Callable:
    """``one(params, ts, bounds, key)``: a trial's statistics. ``windows`` are the spec's (static) windows, or
    their number when the bounds come traced in ``bounds`` ((W, 2), +-inf for an open side)."""

    def one(params, ts, bounds, key):
        TRACES[name] += 1  # Python runs here only while tracing
        out = errors(params, key) if with_params else errors(key)
        e, status = out if isinstance(out, tuple) else (out, None)
        wins = windows if bounds is None else [Window(bounds[i, 0], bounds[i, 1]) for i in range(windows)]
        per_window = [error_stats(ts, e, w) for w in wins]
        stats = jnp.stack([jnp.stack([s[k] for k in STATS], axis=-1) for s in per_window])
        cause = trial_cause(e, status)
        if keep_every is None:
            return stats, cause == CAUSES.OK.code, cause
        return stats, cause == CAUSES.OK.code, cause, e[::keep_every]

    return one


def trial_statistics(spec: TrialSpec, keep_every: int | None = None) -> Callable[[Any], tuple]:
    """``one(key) -> (stats, finite, cause)``: the trial's per-window statistics ``stats[w, c, k]`` (``k`` in
    :data:`STATS`), whether it is healthy (errors all finite and, if ``spec.errors`` returns a status too,
    the status ok) and its cause code (:func:`trial_cause`). With ``keep_every = M`` also the errors at every
    M-th sample, ``errors[::M]``. Traceable; :func:`montecarlo` vmaps it (for a spec with ``params``, over the
    key only, with the params as a traced argument shared by the batch)."""
    ts = jnp.asarray(spec.ts, dtype=jnp.float64)
    one = _statistics_fn("", spec.errors, tuple(spec.windows), keep_every, spec.params is not None)
    return lambda key: one(spec.params, ts, None, key)


@functools.lru_cache(maxsize=16)
def _shared_batch(name: str, errors: Callable, n_windows: int, keep_every: int | None) -> Callable:
    """``batch(params, ts, bounds, keys)``: one compiled function per ``errors`` function, reused (through
    equinox's cache on the static structure of its arguments) by every config whose params, time grid and
    window bounds differ only in values."""
    one = _statistics_fn(name, errors, n_windows, keep_every, True)
    return eqx.filter_jit(eqx.filter_vmap(one, in_axes=(None, None, None, 0)))


def _bounds(windows: tuple[Window, ...]) -> jax.Array:
    return jnp.asarray([[-jnp.inf if w.start is None else w.start, jnp.inf if w.stop is None else w.stop]
                        for w in windows], dtype=jnp.float64)


_CACHE: collections.OrderedDict = collections.OrderedDict()
_CACHE_SIZE = 8


def _compiled(experiment: Experiment, config: Any, keep_every: int | None = None
              ) -> tuple[TrialSpec, np.ndarray, Callable]:
    """The trial spec, its time grid and the batch ``keys -> statistics`` (``jit(vmap(trial_statistics))``),
    cached per (trial_fn, config, keep_every) so repeated Monte Carlos of one config (other seeds, runs or
    batch sizes) reuse it; a spec with ``params`` uses the batch compiled for its ``errors`` function
    (:func:`_shared_batch`), whatever the config's values."""
    try:
        cache_key = (experiment.trial_fn, config, keep_every)
        hash(cache_key)
    except TypeError:
        cache_key = None
    if cache_key is not None and cache_key in _CACHE:
        _CACHE.move_to_end(cache_key)
        return _CACHE[cache_key]
    spec = experiment.trial_fn(config)
    ts = _check_spec(experiment.name, spec)
    if spec.params is None:
        one = _statistics_fn(experiment.name, spec.errors, tuple(spec.windows), keep_every, False)
        ts_j = jnp.asarray(ts)
        batched = jax.jit(jax.vmap(lambda key: one(None, ts_j, None, key)))
    else:
        shared = _shared_batch(experiment.name, spec.errors, len(spec.windows), keep_every)
        args = (spec.params, jnp.asarray(ts), _bounds(tuple(spec.windows)))
        batched = functools.partial(shared, *args)
    entry = (spec, ts, batched)
    if cache_key is not None:
        _CACHE[cache_key] = entry
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return entry


def _spec_of(experiment: Experiment, config: Any, keep_every: int | None = None) -> tuple[TrialSpec, np.ndarray]:
    """The trial spec and time grid of a config: from the compiled cache when this process ran it, else from
    ``trial_fn`` alone (no tracing; e.g. a campaign's client, whose trials ran on workers)."""
    try:
        entry = _CACHE.get((experiment.trial_fn, config, keep_every))
    except TypeError:
        entry = None
    if entry is not None:
        return entry[0], entry[1]
    spec = experiment.trial_fn(config)
    return spec, np.asarray(spec.ts, dtype=np.float64)


def _count(name: str, value, minimum: int) -> int:
    if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def resolve_experiment(experiment: Experiment | str) -> Experiment:
    """``experiment`` itself or the registered experiment of that name; a ValueError unless it has a
    ``trial_fn`` (a Monte Carlo trial)."""
    exp = get_experiment(experiment) if isinstance(experiment, str) else experiment
    if not isinstance(exp, Experiment):
        raise ValueError(f"experiment: expected an Experiment or a registered name, got {type(exp).__name__}")
    if exp.trial_fn is None:
        raise ValueError(f"experiment: {exp.name!r} has no trial_fn, so no Monte Carlo; expected one of "
                         f"{sorted(e.name for e in EXPERIMENTS.values() if e.trial_fn is not None)}")
    return exp


@dataclass(frozen=True)
class TrialArrays:
    """The per-trial outputs of trials ``start <= i < stop`` (:func:`run_trials`): ``stats[i - start]``
    (windows, components, :data:`STATS`), ``finite``, ``causes`` and, with ``keep_every``, ``series``;
    ``samples`` is the number of time samples of one trial (the trial-steps of a trial)."""

    start: int
    stop: int
    stats: np.ndarray
    finite: np.ndarray
    causes: np.ndarray
    samples: int
    series: np.ndarray | None = None


def run_trials(experiment: Experiment, config: Any, seed: int, runs: int, start: int, stop: int,
               batch_size: int, keep_every: int | None = None,
               on_batch: Callable[[int], None] | None = None) -> TrialArrays:
    """Trials ``start <= i < stop`` of ``runs`` seeded trials, ``batch_size`` at a time through one compiled
    ``jit(vmap(trial))`` (cached per experiment and config), the last batch padded with copies of its last
    key. Trial ``i`` uses ``trial_keys(seed, runs)[i]``; with ``start`` a multiple of ``batch_size`` the
    compiled batches are exactly those of :func:`montecarlo`, so any split of ``[0, runs)`` into such ranges
    gives bit-identical arrays. ``on_batch(done)`` is called after every batch with the trials done so far."""
    spec, ts, batched = _compiled(experiment, config, keep_every)
    keys = trial_keys(seed, runs)
    n_trials = stop - start
    series = None if keep_every is None else np.empty((n_trials, ts[::keep_every].shape[0], len(spec.names)))
    stats = np.empty((n_trials, len(spec.windows), len(spec.names), len(STATS)))
    finite = np.empty(n_trials, dtype=bool)
    causes = np.empty(n_trials, dtype=np.int32)
    for lo in range(start, stop, batch_size):
        n = min(batch_size, stop - lo)
        # Pad the last batch with copies of the last key: one shape, one compilation.
        idx = np.minimum(np.arange(lo, lo + batch_size), stop - 1)
        s, f, c, *e = batched(keys[idx])
        at = slice(lo - start, lo - start + n)
        if series is not None:
            series[at] = np.asarray(e[0])[:n]
        stats[at] = np.asarray(s)[:n]
        finite[at] = np.asarray(f)[:n]
        causes[at] = np.asarray(c)[:n]
        if on_batch is not None:
            on_batch(lo - start + n)
    return TrialArrays(start=start, stop=stop, stats=stats, finite=finite, causes=causes, samples=int(ts.shape[0]),
                       series=series)


def montecarlo(experiment: Experiment | str, config: Any | None = None, runs: int = 100, seed: int = 0,
               batch_size: int = DEFAULT_BATCH_SIZE, progress: bool | ProgressFn = True,
               keep_every: int | None = None) -> MonteCarloResult:
    """``runs`` seeded trials of ``experiment`` (an :class:`~liemef.studies.experiments.Experiment` with a
    ``trial_fn``, or its registered name) at ``config`` (None: its default config), batched with ``vmap``.

    Trial ``i`` uses ``trial_keys(seed, runs)[i]`` (the config's own ``seed`` field is not used). Trials run
    ``batch_size`` at a time through one compiled function; the result does not depend on ``batch_size``.
    ``progress``: True shows trials done, elapsed time and ETA on stderr (:class:`ProgressLine`), False
    nothing, a function ``progress(done, total, elapsed, eta)`` is called after every batch.
    ``keep_every = M`` also keeps every trial's errors at every M-th sample (:attr:`MonteCarloResult.series`,
    memory runs x N/M x components), e.g. for bands across trials over time (:meth:`MonteCarloResult.bands`).
    A campaign (:mod:`liemef.studies.campaign`) runs the same trials split into tasks on a Dask cluster, with
    identical results.
    """
    exp = resolve_experiment(experiment)
    runs = _count("runs", runs, 1)
    seed = _count("seed", seed, -(2**63))
    batch = min(_count("batch_size", batch_size, 1), runs)
    keep_every = None if keep_every is None else _count("keep_every", keep_every, 1)
    config = exp.default_config if config is None else config
    report = _reporter(progress, f"montecarlo {exp.name}")

    t0 = time.perf_counter()
    first: list[tuple[int, float]] = []

    def on_batch(done: int) -> None:
        elapsed = time.perf_counter() - t0
        if not first:
            first.append((done, elapsed))  # includes compilation: no rate from it
            eta = 0.0 if done == runs else None
        else:
            eta = (runs - done) * (elapsed - first[0][1]) / (done - first[0][0])
        if report is not None:
            report(done, runs, elapsed, eta)

    arrays = run_trials(exp, config, seed, runs, 0, runs, batch, keep_every, on_batch)
    return result_of(exp, config, seed, runs, arrays, time.perf_counter() - t0, batch, keep_every)


def result_of(experiment: Experiment, config: Any, seed: int, runs: int, arrays: TrialArrays, elapsed: float,
              batch_size: int, keep_every: int | None = None) -> MonteCarloResult:
    """The :class:`MonteCarloResult` of all ``runs`` trials from their arrays (``arrays.start == 0`` and
    ``arrays.stop == runs``: :func:`run_trials` over the whole range, or the concatenation of its ranges)."""
    if (arrays.start, arrays.stop) != (0, runs):
        raise ValueError(f"arrays: expected the trials [0, {runs}), got [{arrays.start}, {arrays.stop})")
    spec, ts = _spec_of(experiment, config, keep_every)
    counts = tuple(int(np.sum(np.asarray(window_mask(ts, w)))) for w in spec.windows)
    return MonteCarloResult(
        experiment=experiment.name, title=experiment.title, paper=experiment.paper, config=_config_data(config),
        seed=seed, names=tuple(spec.names), units=tuple(spec.units), windows=tuple(spec.windows), counts=counts,
        stats=arrays.stats, finite=arrays.finite, keys=np.asarray(jax.random.key_data(trial_keys(seed, runs))),
        elapsed=elapsed, batch_size=batch_size, causes=arrays.causes, series=arrays.series,
        series_ts=None if keep_every is None else ts[::keep_every])


def _config_data(config: Any) -> dict:
    if isinstance(config, dict):
        return dict(config)
    try:
        return config_dict(config)
    except TypeError:
        return {"repr": repr(config)}
