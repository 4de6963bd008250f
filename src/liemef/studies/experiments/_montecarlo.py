r"""Monte Carlo over seeds: N trials of an experiment, batched with ``jax.vmap``, reduced to statistics.

The papers report single noisy runs; a reproduction reports the distribution over seeds and where each
published number falls in it (DESIGN.md §3). :func:`montecarlo` runs ``runs`` trials of an experiment's
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
published value. Results print as a table and save as ``<stem>.npz`` + ``<stem>.json`` (reloadable with
:meth:`MonteCarloResult.load`) + ``<stem>.md`` + ``<stem>.csv``.
"""

from __future__ import annotations

import collections
import functools
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ... import __version__, _validate
from ...filters import CAUSES, Status
from ...metrics import Window, error_stats, window_mask
from ...metrics._stats import format_number, json_number
from ...reports import io
from ._base import EXPERIMENTS, Experiment, TrialSpec, config_dict, get_experiment

STATS = ("mean", "std", "rms")
"""The per-trial statistics over time, in the order of the last axis of :attr:`MonteCarloResult.stats`."""
PERCENTILES = (5, 25, 50, 75, 95)
"""The percentiles across trials that tables report."""
DEFAULT_BATCH_SIZE = 8
"""Trials per compiled batch. On a 2-core CPU, TSE(2) at 1 ms ran 8, 13, 21, 14 and 8 trials/s with batches
of 1, 4, 8, 16 and 32 (larger batches also compile longer)."""
SCHEMA = "liemef.montecarlo/1"
"""Version tag of the ``<stem>.json`` layout."""

ProgressFn = Callable[[int, int, float, "float | None"], None]
"""``progress(done, total, elapsed_s, eta_s)``; ``eta_s`` is None until it can be estimated."""


def trial_keys(seed: int, runs: int) -> jax.Array:
    """The key of every trial: ``jax.random.split(jax.random.key(seed), runs)`` (ValueError naming ``seed`` or
    ``runs`` out of range: a seed in [0, 2**63 - 1], at least one run)."""
    seed = _validate.integer("seed", seed, 0, _validate.SEED_MAX)
    return jax.random.split(jax.random.key(seed), _validate.integer("runs", runs, 1))


# --- progress ----------------------------------------------------------------------------------------------
def format_seconds(s: float) -> str:
    """``12.3 s``, ``4 min 05 s``, ``2 h 07 min``."""
    if s < 60:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def format_progress(label: str, done: int, total: int, elapsed: float, eta: float | None) -> str:
    """``"<label>: 40/100 trials (40%), 12.3 s elapsed, ETA 18.0 s"``."""
    pct = 100.0 * done / total if total else 100.0
    eta_text = "--" if eta is None else format_seconds(eta)
    return f"{label}: {done}/{total} trials ({pct:.0f}%), {format_seconds(elapsed)} elapsed, ETA {eta_text}"


class ProgressLine:
    """A progress display on a text stream (default stderr): on a terminal one line rewritten in place, else
    (logs, pipes) one line at the first report, then at most every ``interval`` seconds, and at the end."""

    def __init__(self, label: str, stream: TextIO | None = None, interval: float = 5.0):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.interval = interval
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty()) if callable(isatty) else False
        self._last: float | None = None
        self._width = 0

    def __call__(self, done: int, total: int, elapsed: float, eta: float | None) -> None:
        self.show(format_progress(self.label, done, total, elapsed, eta), elapsed, done >= total)

    def show(self, line: str, elapsed: float, final: bool = False) -> None:
        """Display ``line`` (rewritten in place on a terminal; elsewhere at most every ``interval`` s, and
        always when ``final``)."""
        if self.tty:
            self.stream.write("\r" + line.ljust(self._width) + ("\n" if final else ""))
            self._width = len(line)
        elif final or self._last is None or elapsed - self._last >= self.interval:
            self.stream.write(line + "\n")
            self._last = elapsed
        self.stream.flush()


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


# --- the result --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """The statistics of ``runs`` seeded trials of one experiment config.

    ``stats[i, w, c, k]`` is trial ``i``'s statistic ``STATS[k]`` (mean, std, rms over time) of error
    component ``names[c]`` over window ``windows[w]`` (``counts[w]`` samples); ``finite[i]`` says whether
    trial ``i`` is healthy: all its errors finite and its filter status (if the trial returns one) ok.
    Diverged trials are left out of :attr:`mean`, :attr:`spread`, :attr:`percentiles` and
    :meth:`percentile_of`; ``causes[i]`` is the cause code of trial ``i`` (an index in
    :data:`~liemef.filters.CAUSES`, 0 for a healthy trial; default: ``"non-finite"`` for every trial not
    ``finite``). ``keys[i]`` is the key data of trial ``i``
    (:meth:`trial_key`), ``config`` the experiment config as JSON-ready data, ``elapsed`` the wall time in s
    (with compilation) and ``batch_size`` the trials per compiled batch. ``series[i]`` (optional,
    ``montecarlo(..., keep_every=M)``) are trial ``i``'s errors at the times ``series_ts``.
    """

    experiment: str
    config: dict
    seed: int
    names: tuple[str, ...]
    units: tuple[str, ...]
    windows: tuple[Window, ...]
    counts: tuple[int, ...]
    stats: np.ndarray
    finite: np.ndarray
    keys: np.ndarray | None = None
    elapsed: float = math.nan
    batch_size: int = 0
    title: str = ""
    paper: str = ""
    causes: np.ndarray | None = None
    series: np.ndarray | None = None
    series_ts: np.ndarray | None = None

    def __post_init__(self):
        stats = np.asarray(self.stats, dtype=np.float64)
        shape = (len(self.windows), len(self.names), len(STATS))
        if stats.ndim != 4 or stats.shape[1:] != shape:
            raise ValueError(f"stats: expected shape (runs, {shape[0]}, {shape[1]}, {shape[2]}) (runs, windows, "
                             f"components, {'/'.join(STATS)}), got {stats.shape}")
        finite = np.asarray(self.finite, dtype=bool)
        if finite.shape != stats.shape[:1]:
            raise ValueError(f"finite: expected shape ({stats.shape[0]},) (one flag per trial), got {finite.shape}")
        if len(self.units) != len(self.names) or len(self.counts) != len(self.windows):
            raise ValueError(f"units/counts: expected one unit per component ({len(self.names)}) and one count "
                             f"per window ({len(self.windows)}), got {len(self.units)} and {len(self.counts)}")
        if self.causes is None:
            causes = np.where(finite, CAUSES.OK.code, CAUSES.NONFINITE.code).astype(np.int32)
        else:
            causes = np.asarray(self.causes)
            if causes.shape != finite.shape or not np.issubdtype(causes.dtype, np.integer) \
                    or np.any((causes < 0) | (causes >= len(CAUSES))):
                raise ValueError(f"causes: expected shape ({finite.shape[0]},) of integer cause codes in "
                                 f"[0, {len(CAUSES)}) (liemef.filters.CAUSES), got {causes.shape} {causes.dtype}")
            if np.any((causes == CAUSES.OK.code) != finite):
                raise ValueError("causes: expected code 0 (ok) exactly for the finite trials, got "
                                 f"{_list(np.flatnonzero((causes == CAUSES.OK.code) != finite))} inconsistent")
        set_ = object.__setattr__
        set_(self, "stats", stats)
        set_(self, "finite", finite)
        set_(self, "causes", causes.astype(np.int32))
        set_(self, "names", tuple(str(s) for s in self.names))
        set_(self, "units", tuple(str(s) for s in self.units))
        set_(self, "windows", tuple(Window(*w) for w in self.windows))
        set_(self, "counts", tuple(int(n) for n in self.counts))
        if self.keys is not None:
            set_(self, "keys", np.asarray(self.keys))
        if (self.series is None) != (self.series_ts is None):
            raise ValueError("series, series_ts: expected both or neither, got one")
        if self.series is not None:
            series, series_ts = np.asarray(self.series, np.float64), np.asarray(self.series_ts, np.float64)
            if series.shape != (stats.shape[0], series_ts.shape[0], len(self.names)):
                raise ValueError(f"series: expected shape ({stats.shape[0]}, {series_ts.shape[0]}, "
                                 f"{len(self.names)}) (runs, times, components), got {series.shape}")
            set_(self, "series", series)
            set_(self, "series_ts", series_ts)

    # --- sizes and selection
    @property
    def runs(self) -> int:
        """The number of trials, finite or not."""
        return int(self.stats.shape[0])

    @property
    def n_finite(self) -> int:
        """The number of trials with finite errors, those the statistics are taken over."""
        return int(self.finite.sum())

    @property
    def n_nonfinite(self) -> int:
        """The number of diverged trials (non-finite errors or a failed status), left out of the statistics."""
        return self.runs - self.n_finite

    @property
    def nonfinite_trials(self) -> np.ndarray:
        """Indices of the diverged trials."""
        return np.flatnonzero(~self.finite)

    def diverged(self) -> dict[str, int]:
        """The number of diverged trials by cause, ``{cause: count}`` over the causes that occurred, in the
        order of :data:`~liemef.filters.CAUSES` (e.g. ``{"non-finite": 1, "K not positive definite": 1}``)."""
        counts = np.bincount(self.causes, minlength=len(CAUSES))
        return {CAUSES[i].value: int(n) for i, n in enumerate(counts) if i != CAUSES.OK.code and n}

    def divergence_summary(self) -> str:
        """One line: ``"2 of 100 diverged: non-finite 1, K not positive definite 1"`` or
        ``"none of 100 diverged"`` (what the CLI prints beside the table)."""
        if not self.n_nonfinite:
            return f"none of {self.runs} diverged"
        by = ", ".join(f"{cause} {n}" for cause, n in self.diverged().items())
        return f"{self.n_nonfinite} of {self.runs} diverged: {by}"

    @property
    def window_labels(self) -> tuple[str, ...]:
        """The labels of the time windows, in the order of the window axis of the statistics."""
        return tuple(w.label for w in self.windows)

    def trial_key(self, i: int) -> jax.Array:
        """The ``jax.random`` key of trial ``i`` (to rerun one trial, e.g. an outlier, with ``run``)."""
        if self.keys is None:
            raise ValueError("keys: this result has no trial keys")
        return jax.random.wrap_key_data(jnp.asarray(self.keys[i]))

    def index(self, component: str | int, window: str | int | Window, stat: str | int) -> tuple[int, int, int]:
        """``(w, c, k)`` of a component (name or index), window (label, :class:`Window` or index) and
        statistic (``"mean"``, ``"std"``, ``"rms"`` or index)."""
        def pick(what, value, options):
            if isinstance(value, int | np.integer) and not isinstance(value, bool):
                if not 0 <= value < len(options):
                    raise ValueError(f"{what}: expected an index in [0, {len(options)}), got {value}")
                return int(value)
            if value not in options:
                raise ValueError(f"{what}: expected one of {list(options)}, got {value!r}")
            return options.index(value)

        w = window.label if isinstance(window, Window) else window
        return (pick("window", w, self.window_labels), pick("component", component, self.names),
                pick("stat", stat, STATS))

    def values(self, component: str | int, window: str | int | Window, stat: str | int) -> np.ndarray:
        """The per-trial values of one statistic over the finite trials, in trial order."""
        w, c, k = self.index(component, window, stat)
        return self.stats[self.finite, w, c, k]

    # --- across trials
    @property
    def mean(self) -> np.ndarray:
        """(windows, components, 3): the mean across finite trials of each per-trial statistic."""
        x = self.stats[self.finite]
        return np.full(self.stats.shape[1:], np.nan) if x.shape[0] == 0 else x.mean(axis=0)

    @property
    def spread(self) -> np.ndarray:
        """(windows, components, 3): the seed-to-seed spread, std across finite trials (ddof = 1)."""
        x = self.stats[self.finite]
        return np.full(self.stats.shape[1:], np.nan) if x.shape[0] < 2 else x.std(axis=0, ddof=1)

    @property
    def percentiles(self) -> np.ndarray:
        """(len(PERCENTILES), windows, components, 3): percentiles 5, 25, 50, 75, 95 across finite trials."""
        x = self.stats[self.finite]
        if x.shape[0] == 0:
            return np.full((len(PERCENTILES), *self.stats.shape[1:]), np.nan)
        return np.percentile(x, PERCENTILES, axis=0)

    def percentile_of(self, value: float, component: str | int, window: str | int | Window,
                      stat: str | int) -> float:
        """Where ``value`` (e.g. a published number) falls in the Monte Carlo distribution of one statistic:
        the percentage of finite trials whose statistic is at most ``value`` (0-100; NaN without trials)."""
        x = self.values(component, window, stat)
        x = x[~np.isnan(x)]
        if x.size == 0:
            return math.nan
        return 100.0 * float(np.count_nonzero(x <= float(value))) / x.size

    def bands(self, percentiles=(5, 50, 95), absolute: bool = False) -> np.ndarray:
        """``(len(percentiles), times, components)``: at each time of :attr:`series_ts`, the percentiles
        across the healthy trials of each error (of its absolute value with ``absolute``); needs
        ``montecarlo(..., keep_every=M)``."""
        if self.series is None:
            raise ValueError("series: this result kept no errors over time; expected montecarlo(..., "
                             "keep_every=M)")
        x = self.series[self.finite]
        x = np.abs(x) if absolute else x
        if x.shape[0] == 0:
            return np.full((len(percentiles), *self.series.shape[1:]), np.nan)
        return np.percentile(x, list(percentiles), axis=0)

    # --- tables
    TABLE_HEADER = ("window", "component", "unit", "stat", "mean", "spread",
                    *(f"p{p}" for p in PERCENTILES))

    def table_rows(self) -> list[tuple]:
        """One row per (window, component, statistic): the names, then mean, spread and percentiles across
        trials (:attr:`TABLE_HEADER`)."""
        mean, spread, pct = self.mean, self.spread, self.percentiles
        rows = []
        for w, label in enumerate(self.window_labels):
            for c, (name, unit) in enumerate(zip(self.names, self.units, strict=True)):
                for k, stat in enumerate(STATS):
                    rows.append((label, name, unit, stat, float(mean[w, c, k]), float(spread[w, c, k]),
                                 *(float(v) for v in pct[:, w, c, k])))
        return rows

    def _heading(self) -> str:
        word = "non-finite" if set(self.diverged()) <= {CAUSES.NONFINITE.value} else "diverged"
        bad = f", {self.n_nonfinite} {word} (left out: trials {_list(self.nonfinite_trials)})" \
            if self.n_nonfinite else ", all finite"
        return f"Monte Carlo of {self.experiment}: {self.runs} trials (seed {self.seed}){bad}"

    def _window_heading(self, w: int) -> str:
        return f"window {self.window_labels[w]} ({self.counts[w]} samples)"

    def format(self) -> str:
        """A plain-text table, one block per window: per component and statistic over time, its mean and
        spread across trials and its percentiles."""
        head = ["component", "unit", "stat", "mean", "spread", *(f"p{p}" for p in PERCENTILES)]
        lines = [self._heading(), *([self.divergence_summary()] if self.n_nonfinite else []),
                 "Per trial over time: mean, std, rms of each error; across trials: mean, spread (std), "
                 "percentiles."]
        by_window = collections.defaultdict(list)
        for r in self.table_rows():
            by_window[r[0]].append(r)
        for w, label in enumerate(self.window_labels):
            if self.counts[w] == 0:
                lines += ["", f"{self._window_heading(w)}: no statistics"]
                continue
            rows = [head]
            for i, r in enumerate(by_window[label]):
                first = i % len(STATS) == 0
                rows.append([r[1] if first else "", r[2] if first else "", r[3], *map(format_number, r[4:])])
            widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
            table = ["  ".join(s.ljust(wd) if i < 3 else s.rjust(wd)
                               for i, (s, wd) in enumerate(zip(r, widths, strict=True))) for r in rows]
            table.insert(1, "-" * len(table[0]))
            lines += ["", self._window_heading(w), *table]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format()

    def to_markdown(self) -> str:
        """The table as Markdown: a heading, the config, one table per window."""
        title = f"# Monte Carlo: {self.experiment}" + (f" ({self.title})" if self.title else "")
        cfg = ", ".join(f"{k} = {v}" for k, v in self.config.items() if k != "seed")  # trials: self.seed
        out = [title, ""]
        if self.paper:
            out += [f"Paper: {self.paper}.", ""]
        out += [f"{self._heading()}; {self.batch_size} trials per compiled batch, {self.elapsed:.1f} s.", "",
                *([f"{self.divergence_summary().capitalize()}.", ""] if self.n_nonfinite else []),
                f"Config: {cfg}.", "",
                "Per trial, over time: mean, std and rms of each error component; across trials: their mean, "
                "spread (std, ddof = 1) and percentiles.", ""]
        head = ["component", "unit", "stat", "mean", "spread", *(f"p{p}" for p in PERCENTILES)]
        for w, label in enumerate(self.window_labels):
            if self.counts[w] == 0:
                out += [f"## {self._window_heading(w).capitalize()}", "", "No statistics.", ""]
                continue
            out += [f"## {self._window_heading(w).capitalize()}", "",
                    "| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 3 + ["---:"] * (len(head) - 3)) + "|"]
            out += ["| " + " | ".join([*r[1:4], *map(format_number, r[4:])]) + " |"
                    for r in self.table_rows() if r[0] == label]
            out.append("")
        return "\n".join(out)

    def write_tables(self, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
        """``<stem>.md`` and ``<stem>.csv`` (full precision, one row per window, component and statistic) into
        the folder ``out``."""
        d = io.ensure_dir(out)
        return [io.write_text(d / f"{stem}.md", self.to_markdown()),
                io.write_rows(d / f"{stem}.csv", self.TABLE_HEADER, self.table_rows())]

    # --- saving
    def to_dict(self) -> dict:
        """Metadata and the statistics across trials, JSON-ready (NaN -> None): the ``<stem>.json`` layout."""
        mean, spread, pct = self.mean, self.spread, self.percentiles
        summary: dict = {}
        for w, label in enumerate(self.window_labels):
            comps = {}
            for c, (name, unit) in enumerate(zip(self.names, self.units, strict=True)):
                entry: dict = {"unit": unit}
                for k, stat in enumerate(STATS):
                    entry[stat] = {"mean": json_number(mean[w, c, k]), "spread": json_number(spread[w, c, k]),
                                   **{f"p{p}": json_number(pct[i, w, c, k]) for i, p in enumerate(PERCENTILES)}}
                comps[name] = entry
            summary[label] = comps
        return {
            "schema": SCHEMA,
            "experiment": {"name": self.experiment, "title": self.title, "paper": self.paper},
            "config": self.config,
            "seed": self.seed,
            "runs": self.runs,
            "keys": f"trial i uses jax.random.split(jax.random.key({self.seed}), {self.runs})[i]",
            "nonfinite": {"count": self.n_nonfinite, "trials": [int(i) for i in self.nonfinite_trials]},
            "diverged": {"count": self.n_nonfinite, "by_cause": self.diverged(),
                         "trials": {CAUSES[c].value: [int(i) for i in np.flatnonzero(self.causes == c)]
                                    for c in sorted(set(self.causes.tolist()) - {CAUSES.OK.code})},
                         "definition": "a trial diverged when its filter status failed (its cause) or its "
                                       "errors are not all finite (non-finite); diverged trials are left out "
                                       "of the statistics"},
            "windows": {w.label: {"start": w.start, "stop": w.stop, "samples": n}
                        for w, n in zip(self.windows, self.counts, strict=True)},
            "definition": {"per_trial": "mean, std (population) and rms over the samples of the window of each "
                                        "error component (liemef.metrics.error_stats)",
                           "across_trials": "over the finite trials: mean, spread = std with ddof = 1, "
                                            "percentiles with linear interpolation (numpy.percentile)"},
            "statistics": summary,
            "run": {"elapsed_s": json_number(self.elapsed), "batch_size": self.batch_size,
                    "liemef_version": __version__},
        }

    def save(self, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
        """``<stem>.npz`` (per-trial arrays), ``<stem>.json`` (:meth:`to_dict`) and the tables
        (:meth:`write_tables`) into the folder ``out`` (created if missing); each written atomically."""
        d = io.ensure_dir(out)
        nan = lambda v: np.nan if v is None else v  # noqa: E731
        arrays = {"stats": self.stats, "finite": self.finite, "causes": self.causes,
                  "names": np.array(self.names, dtype=str),
                  "units": np.array(self.units, dtype=str), "stat_names": np.array(STATS),
                  "window_start": np.array([nan(w.start) for w in self.windows], dtype=np.float64),
                  "window_stop": np.array([nan(w.stop) for w in self.windows], dtype=np.float64),
                  "counts": np.array(self.counts, dtype=np.int64)}
        if self.keys is not None:
            arrays["keys"] = self.keys
        if self.series is not None:
            arrays["series"], arrays["series_ts"] = self.series, self.series_ts
        return [io.write_npz(d / f"{stem}.npz", arrays), io.write_json(d / f"{stem}.json", self.to_dict()),
                *self.write_tables(d, stem)]

    @classmethod
    def load(cls, out: str | os.PathLike, stem: str = "montecarlo") -> MonteCarloResult:
        """A result saved by :meth:`save` in the folder ``out``."""
        d = Path(out)
        a = io.read_arrays(d / f"{stem}.npz")
        meta = io.read_json(d / f"{stem}.json", "montecarlo")
        if meta.get("schema") != SCHEMA:
            raise ValueError(f"montecarlo: expected schema {SCHEMA!r} in {str(d / f'{stem}.json')!r}, "
                             f"got {meta.get('schema')!r}")
        opt = lambda v: None if math.isnan(v) else float(v)  # noqa: E731
        windows = tuple(Window(opt(s), opt(e)) for s, e in zip(a["window_start"], a["window_stop"], strict=True))
        run = meta.get("run", {})
        return cls(experiment=meta["experiment"]["name"], title=meta["experiment"].get("title", ""),
                   paper=meta["experiment"].get("paper", ""), config=meta["config"], seed=int(meta["seed"]),
                   names=tuple(a["names"]), units=tuple(a["units"]), windows=windows, counts=tuple(a["counts"]),
                   stats=a["stats"], finite=a["finite"], keys=a.get("keys"), causes=a.get("causes"),
                   series=a.get("series"), series_ts=a.get("series_ts"),
                   elapsed=math.nan if run.get("elapsed_s") is None else run["elapsed_s"],
                   batch_size=int(run.get("batch_size", 0)))


def _list(idx: np.ndarray, limit: int = 10) -> str:
    items = [str(int(i)) for i in idx[:limit]]
    return ", ".join(items) + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")
