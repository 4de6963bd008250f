from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .. import _validate


class Window(NamedTuple):
    """A closed time window ``[start, stop]`` (None: unbounded on that side)."""

    start: float | None = None
    stop: float | None = None

    @property
    def label(self) -> str:
        """``"full"`` for the unbounded window, else e.g. ``"10-50s"`` (the key in tables and JSON)."""
        if self.start is None and self.stop is None:
            return "full"
        lo = "0" if self.start is None else f"{self.start:g}"
        hi = "end" if self.stop is None else f"{self.stop:g}"
        return f"{lo}-{hi}s"


FULL = Window()
"""The whole run."""


def window_mask(ts: Float[ArrayLike, " N"], window: Window) -> Bool[Array, " N"]:
    """Which samples lie in ``window`` (both ends included)."""
    ts = jnp.asarray(ts)
    mask = jnp.ones(ts.shape, dtype=bool)
    if window.start is not None:
        mask = mask & (ts >= window.start)
    if window.stop is not None:
        mask = mask & (ts <= window.stop)
    return mask


def error_stats(ts: Float[ArrayLike, " N"], errors: Float[ArrayLike, "N c"],
                window: Window = FULL) -> dict[str, Float[Array, "..."]]:
    r"""Per-component statistics of ``errors`` over the samples in ``window``: traceable and vmap-able.

    With the $n$ samples $e_k$ in the window: mean $\bar e = \frac1n\sum e_k$, std
    $\sqrt{\frac1n\sum (e_k - \bar e)^2}$ (population, so
    $\mathrm{rms}^2 = \mathrm{mean}^2 + \mathrm{std}^2$), rms $\sqrt{\frac1n\sum e_k^2}$. Returns
    ``{"mean", "std", "rms"}`` (each shape (c,)) and ``"count"`` (n); NaN where the window holds no sample.
    """
    e = jnp.asarray(errors, dtype=jnp.float64)
    w = window_mask(ts, window)[:, None]
    n = jnp.sum(w[:, 0])
    nn = jnp.where(n > 0, n, jnp.nan)
    mean = jnp.sum(jnp.where(w, e, 0.0), axis=0) / nn
    var = jnp.sum(jnp.where(w, (e - mean) ** 2, 0.0), axis=0) / nn
    ms = jnp.sum(jnp.where(w, e * e, 0.0), axis=0) / nn
    return {"mean": mean, "std": jnp.sqrt(var), "rms": jnp.sqrt(ms), "count": n}


STATS = ("mean", "std", "rms")
"""The statistics over time of :func:`error_stats`, in the order statistics arrays stack them."""
PERCENTILES = (5, 25, 50, 75, 95)
"""The percentiles across Monte Carlo trials that statistics and tables report."""


def json_number(x: float) -> float | None:
    """``x`` as a JSON number: a float, or None (JSON null) if it is NaN or infinite."""
    x = float(x)
    return x if math.isfinite(x) else None


def format_number(x: float | None) -> str:
    """``x`` for a printed or Markdown table: ``1.234e-02``, or ``-`` if it is None, NaN or infinite."""
    return f"{x:.3e}" if x is not None and math.isfinite(x) else "-"


@dataclass(frozen=True)
class ErrorTable:
    """Mean, std and rms of each error component over each window, with names and units.

    ``mean[w, c]``, ``std[w, c]``, ``rms[w, c]`` for window ``windows[w]`` and component ``names[c]``;
    ``counts[w]`` samples in each window (NaN statistics where a window is empty).
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    windows: tuple[Window, ...]
    mean: np.ndarray
    std: np.ndarray
    rms: np.ndarray
    counts: tuple[int, ...]

    def to_dict(self) -> dict:
        """``{component: {"unit": ..., <window label>: {"mean", "std", "rms"}}}``, JSON-ready
        (NaN -> None)."""
        out: dict = {}
        for c, (name, unit) in enumerate(zip(self.names, self.units, strict=True)):
            entry: dict = {"unit": unit}
            for w, win in enumerate(self.windows):
                entry[win.label] = {k: json_number(getattr(self, k)[w, c]) for k in ("mean", "std", "rms")}
            out[name] = entry
        return out

    def windows_dict(self) -> dict:
        """``{<window label>: {"start", "stop", "samples"}}``."""
        return {win.label: {"start": win.start, "stop": win.stop, "samples": int(n)}
                for win, n in zip(self.windows, self.counts, strict=True)}

    def format(self) -> str:
        """A plain-text table: one row per component, mean/std/rms per window."""
        stats = ("mean", "std", "rms")
        head = ["component", "unit"] + [f"{k}({win.label})" for win in self.windows for k in stats]
        rows = [head]
        for c, (name, unit) in enumerate(zip(self.names, self.units, strict=True)):
            vals = [getattr(self, k)[w, c] for w in range(len(self.windows)) for k in ("mean", "std", "rms")]
            rows.append([name, unit] + [format_number(v) for v in vals])
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        lines = ["  ".join(s.ljust(wd) if i < 2 else s.rjust(wd)
                           for i, (s, wd) in enumerate(zip(r, widths, strict=True)))
                 for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format()


def error_table(ts: Float[ArrayLike, " N"], errors: Float[ArrayLike, "N c"], names: tuple[str, ...],
                units: tuple[str, ...], windows: tuple[Window, ...] = (FULL,)) -> ErrorTable:
    """:func:`error_stats` of ``errors`` over each of ``windows``, labelled with ``names`` and ``units``.

    Non-finite errors (a diverged run) give NaN statistics, not an exception."""
    ts = _validate.sorted_times("ts", ts)
    errors = np.asarray(errors, dtype=np.float64)  # NaN allowed: a diverged run gives NaN statistics
    if errors.ndim != 2 or errors.shape[0] != ts.shape[0]:
        raise ValueError(f"errors: expected shape ({ts.shape[0]}, c) to match ts, got {errors.shape}")
    c = errors.shape[1]
    if len(names) != c or len(units) != c:
        raise ValueError(f"names/units: expected {c} of each (one per error component), got {len(names)} "
                         f"names and {len(units)} units")
    stats = [error_stats(ts, errors, w) for w in windows]
    stack = lambda k: np.stack([np.asarray(s[k]) for s in stats])  # noqa: E731
    return ErrorTable(names=tuple(names), units=tuple(units), windows=tuple(windows), mean=stack("mean"),
                      std=stack("std"), rms=stack("rms"), counts=tuple(int(s["count"]) for s in stats))
