"""Figures from saved results (never recomputed): state panels as in Rigo et al. 2022, Figs. 3-4.

Each figure has one row per state component: on the left the truth (black), the measurement (blue) and the
estimate (green); on the right the error truth - estimate (red). A component that was not measured has no
blue curve; a result without truth (``liemef run`` on a recorded log) has the left column only.

Matplotlib is used through :class:`matplotlib.figure.Figure` with the Agg canvas, without pyplot, so no
global backend state is touched and no display is needed.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from . import io

TRUTH, MEASURED, FILTERED, ERROR = "black", "tab:blue", "tab:green", "tab:red"
_SYMBOL = {"theta": r"\theta", "omega": r"\omega", "vx": r"v^x", "vy": r"v^y", "x": "x", "y": "y"}


def _label(name: str, unit: str, error: bool = False) -> str:
    sym = _SYMBOL.get(name, name)
    sym = rf"$\delta {sym}$" if error else rf"${sym}$"
    return f"{sym} [{unit}]" if unit else sym


def state_figure(arrays: Mapping[str, np.ndarray], components: Sequence[str], title: str = "") -> Figure:
    """A figure of state panels for ``components`` (names in ``arrays["names"]``) from saved arrays.

    Uses ``ts``, ``names``, ``units``, ``filtered`` and, when present, ``truth``, ``measured``, ``error``
    (all (N, c); see :class:`liemef.studies.experiments.Result`).
    """
    names = [str(s) for s in arrays["names"]]
    units = [str(s) for s in arrays["units"]] if "units" in arrays else [""] * len(names)
    unknown = [c for c in components if c not in names]
    if unknown:
        raise ValueError(f"components: expected names among {names}, got {unknown}")
    ts = np.asarray(arrays["ts"])
    has_error = "error" in arrays
    ncols = 2 if has_error else 1
    fig = Figure(figsize=(11 if has_error else 6.5, 2.4 * len(components) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(len(components), ncols, sharex=True, squeeze=False))
    for row, comp in enumerate(components):
        k = names.index(comp)
        ax = axes[row, 0]
        if "measured" in arrays and np.isfinite(arrays["measured"][:, k]).any():
            ax.plot(ts, arrays["measured"][:, k], color=MEASURED, lw=0.3, alpha=0.6, label="measured",
                    zorder=1)
        if "truth" in arrays:
            ax.plot(ts, arrays["truth"][:, k], color=TRUTH, lw=1.4, label="truth", zorder=2)
        ax.plot(ts, arrays["filtered"][:, k], color=FILTERED, lw=1.0, ls="--" if "truth" in arrays else "-",
                label="filtered", zorder=3)
        ax.set_ylabel(_label(comp, units[k]))
        if "truth" in arrays:
            # Keep the axes on the truth and estimate: raw measured headings span the whole circle.
            ref = np.concatenate([arrays["truth"][:, k], arrays["filtered"][:, k]])
            ref = ref[np.isfinite(ref)]
            if ref.size:
                lo, hi = float(ref.min()), float(ref.max())
                pad = 0.25 * max(hi - lo, 1e-3)
                meas = arrays["measured"][:, k] if "measured" in arrays else np.array([])
                meas = meas[np.isfinite(meas)]
                if meas.size:
                    lo, hi = min(lo, np.percentile(meas, 0.5)), max(hi, np.percentile(meas, 99.5))
                ax.set_ylim(lo - pad, hi + pad)
        ax.grid(True, lw=0.3, alpha=0.5)
        if has_error:
            ax = axes[row, 1]
            ax.plot(ts, arrays["error"][:, k], color=ERROR, lw=0.8)
            ax.axhline(0.0, color="0.5", lw=0.5)
            ax.set_ylabel(_label(comp, units[k], error=True))
            ax.grid(True, lw=0.3, alpha=0.5)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    axes[0, 0].legend(loc="upper left", fontsize="small", ncols=3)
    if title:
        fig.suptitle(title, fontsize="medium")
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, dpi: int = 130) -> Path:
    """A figure to PNG, written atomically (see :func:`liemef.reports.io.atomic_open`)."""
    with io.atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=dpi)
    return Path(path)


def write_figures(out: str | os.PathLike, figures: Sequence[Mapping] | None = None) -> list[Path]:
    """Draw the figures of the result saved in the folder ``out`` from its ``arrays.npz``.

    ``figures`` are dicts with ``file``, ``components`` and ``title`` (and ``kind`` ``"run"`` for
    :func:`liemef.reports.figures.run_figure`); by default the ``figures`` listed in the folder's
    ``metrics.json``.
    """
    d = Path(out)
    arrays = io.read_arrays(d / io.ARRAYS_FILE)
    if figures is None:
        figures = io.read_metrics(d / io.METRICS_FILE).get("figures", [])
    written = []
    for spec in figures:
        if spec.get("kind") == "run":  # liemef run's figure: bands from K, roll/pitch/yaw, the x-y path
            from .figures import run_figure

            fig = run_figure(arrays, spec.get("title", ""))
        else:
            fig = state_figure(arrays, spec["components"], spec.get("title", ""))
        written.append(save_figure(fig, d / spec["file"]))
    return written
