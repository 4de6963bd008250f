"""The statistics of a Monte Carlo: per-trial statistics over time of each error component in each window, and
across the healthy trials their mean, spread and percentiles (:class:`MonteCarloResult`).

:func:`~liemef.studies.experiments.montecarlo` computes one; its tables, its files and their schema are
:mod:`liemef.reports.montecarlo`, which the methods ``format``, ``to_markdown``, ``save`` and ``load`` call.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ...filters import CAUSES
from ...metrics import Window
from ...metrics._stats import PERCENTILES, STATS
from ...reports import montecarlo as _report
from ...reports.montecarlo import trial_list

SCHEMA = _report.SCHEMA
"""Version tag of the ``<stem>.json`` layout (:data:`liemef.reports.montecarlo.SCHEMA`)."""


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
                                 f"{trial_list(np.flatnonzero((causes == CAUSES.OK.code) != finite))} inconsistent")
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

    # --- tables and files (liemef.reports.montecarlo)
    TABLE_HEADER = _report.TABLE_HEADER

    def table_rows(self) -> list[tuple]:
        """One row per (window, component, statistic): the names, then mean, spread and percentiles across
        trials (:attr:`TABLE_HEADER`; :func:`liemef.reports.montecarlo.table_rows`)."""
        return _report.table_rows(self)

    def format(self) -> str:
        """A plain-text table, one block per window: per component and statistic over time, its mean and
        spread across trials and its percentiles (:func:`liemef.reports.montecarlo.format_text`)."""
        return _report.format_text(self)

    def __str__(self) -> str:
        return self.format()

    def to_markdown(self) -> str:
        """The table as Markdown: a heading, the config, one table per window."""
        return _report.to_markdown(self)

    def write_tables(self, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
        """``<stem>.md`` and ``<stem>.csv`` (full precision, one row per window, component and statistic) into
        the folder ``out``."""
        return _report.write_tables(self, out, stem)

    def to_dict(self) -> dict:
        """Metadata and the statistics across trials, JSON-ready (NaN -> None): the ``<stem>.json`` layout
        (:data:`SCHEMA`)."""
        return _report.to_dict(self)

    def save(self, out: str | os.PathLike, stem: str = "montecarlo") -> list[Path]:
        """``<stem>.npz`` (per-trial arrays), ``<stem>.json`` (:meth:`to_dict`) and the tables
        (:meth:`write_tables`) into the folder ``out`` (created if missing); each written atomically."""
        return _report.save(self, out, stem)

    @classmethod
    def load(cls, out: str | os.PathLike, stem: str = "montecarlo") -> MonteCarloResult:
        """A result saved by :meth:`save` in the folder ``out``."""
        return cls(**_report.read(out, stem))
