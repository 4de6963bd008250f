"""The studies' figures, drawn from saved arrays: the reports layer is the only one that imports matplotlib.

Each function takes what a study saved (its ``arrays.npz`` as a dict, or a file) and, where a figure labels
what the study defines (connections, paper figures, published values), those as arguments; it returns a
matplotlib :class:`~matplotlib.figure.Figure` that :func:`liemef.reports.plots.save_figure` writes. matplotlib
loads on the first figure drawn, so that importing a study stays light.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._times import seconds
from . import io

if TYPE_CHECKING:
    from matplotlib.figure import Figure


NO_BAND_NOTE = ("no sigma band: K is not a covariance here (the system's weights are not noise levels in its "
                "sensors' units), so sqrt(K) is no standard deviation")
"""What ``liemef run``'s figure says in place of the +-3 sigma band when K is not a covariance."""


def run_figure(arrays: Mapping, title: str = "") -> Figure:
    """``liemef run``'s figure, from its saved arrays (:func:`liemef.studies.logs.state_bands`, saved with the
    prefix ``plot_``): per state component the estimate (green) and the measurements (blue points) where the
    sensors read that component; roll, pitch and yaw in place of an SO(3) rotation vector, angles unwrapped. For
    a pose, a panel on the right with the x-y path (and the measured positions).

    The +-3 sigma band from K is drawn only where ``plot_covariance`` is true
    (:func:`liemef.metrics.gain_is_covariance`: the system's weights are noise levels in its sensors' units);
    otherwise the figure says why there is none (:data:`NO_BAND_NOTE`). Time runs from the log's first sample
    t0, stated in the title when it is not 0 (a ROS bag's stamps are epoch seconds). Each panel has its own y
    axis, in its component's unit, fitted to its own data: the measurements, and the estimate and its band from
    the sample where K has settled from the prior K0 (:func:`settled`); what lies off scale before is said in the
    panel."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts = np.asarray(arrays["ts"], dtype=np.float64)
    t0 = float(ts[0])
    t = ts - t0
    names, units = [str(v) for v in arrays["plot_names"]], [str(v) for v in arrays["plot_units"]]
    values, std = np.asarray(arrays["plot_values"]), np.asarray(arrays["plot_std"])
    measured = arrays.get("plot_measured")
    covariance = bool(np.asarray(arrays.get("plot_covariance", False)))
    path = "plot_path" in arrays
    rows = len(names)
    fig = Figure(figsize=(12 if path else 7, 1.9 * rows + 1.2), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(rows, 2 if path else 1, width_ratios=(3, 2) if path else None)
    axes = []
    for k, (name, unit) in enumerate(zip(names, units, strict=True)):
        ax = fig.add_subplot(grid[k, 0], sharex=axes[0] if axes else None)
        lower, upper = values[:, k] - 3 * std[:, k], values[:, k] + 3 * std[:, k]
        if covariance:
            ax.fill_between(t, lower, upper, color="tab:green", alpha=0.2, lw=0, label="+-3 sigma (K, a covariance)")
        seen = np.zeros(0)
        if measured is not None and np.isfinite(measured[:, k]).any():
            ok = np.isfinite(measured[:, k])
            seen = np.asarray(measured)[ok, k]
            ax.plot(t[ok], seen, ".", color="tab:blue", ms=2.5, label="measured")
        ax.plot(t, values[:, k], color="tab:green", lw=1.0, label="filtered")
        drawn = (values[:, k], lower, upper) if covariance else (values[:, k],)
        s = settled(std[:, k])
        fitted = np.concatenate([seen, *(d[s:] for d in drawn)])
        fitted = fitted[np.isfinite(fitted)]
        if fitted.size and fitted.max() > fitted.min():
            lo, hi = float(fitted.min()), float(fitted.max())
            pad = 0.05 * (hi - lo)
            ax.set_ylim(lo - pad, hi + pad)
            early = np.concatenate([d[:s] for d in drawn])
            if np.any((early < lo - pad) | (early > hi + pad)):
                ax.text(0.99, 0.96, f"off scale before {t[s]:.3g} s: K settling from K0", transform=ax.transAxes,
                        ha="right", va="top", fontsize="x-small", color="0.35")
        ax.set_ylabel(f"{name} [{unit}]" if unit else name)
        ax.grid(True, lw=0.3, alpha=0.5)
        if k < rows - 1:
            ax.tick_params(labelbottom=False)
        axes.append(ax)
    axes[-1].set_xlabel("t [s]" if t0 == 0.0 else "t - t0 [s]")
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[1:]:  # "measured" may be on a later panel only
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", fontsize="small", ncols=len(labels))
    if path:
        ax = fig.add_subplot(grid[:, 1])
        xy = np.asarray(arrays["plot_path"])
        if "plot_path_measured" in arrays:
            m = np.asarray(arrays["plot_path_measured"])
            ok = np.isfinite(m).all(axis=1)
            ax.plot(m[ok, 0], m[ok, 1], ".", color="tab:blue", ms=3, label="measured")
        ax.plot(xy[:, 0], xy[:, 1], color="tab:green", lw=1.0, label="filtered")
        ax.plot(xy[:1, 0], xy[:1, 1], "o", color="tab:green", ms=4, label="start")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("x-y path", fontsize="small")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(loc="best", fontsize="small")
    notes = ([] if covariance else [NO_BAND_NOTE]) + ([] if t0 == 0.0 else [f"t0 = {seconds(t0)} s, the log's "
                                                                              "first sample"])
    if title or notes:
        fig.suptitle("\n".join([title] * bool(title) + notes), fontsize="medium")
    return fig


def settled(std) -> int:
    """The first sample whose standard deviation from K (a component's, over a run) is at most ten times its
    median over the run: before it the prior K0 still dominates K, and its band (and the estimate's first
    response to the data) would flatten the panel. 0 where the first sample already is."""
    std = np.asarray(std, dtype=np.float64)
    ok = np.isfinite(std)
    if not ok.any():
        return 0
    return int(np.argmax(ok & (std <= 10 * np.median(std[ok]))))


def optimum_figure(arrays: dict):
    """Mean distance of each filter's estimate from the exact minimum-energy estimate over time (log scale),
    from saved arrays."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts, names = arrays["ts"], [str(n) for n in arrays["optimum_filters"]]
    fig = Figure(figsize=(9, 6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 1, sharex=True)
    for ax, key, label in zip(axes, ("optimum_heading_deg", "optimum_position_m"),
                              ("heading distance to the MAP [deg]", "position distance to the MAP [m]"), strict=True):
        for i, name in enumerate(names):
            ax.plot(ts, np.maximum(arrays[key][i], 1e-12), color=f"C{i}", lw=1.0, label=name)
        ax.set_yscale("log")
        ax.set_ylabel(label)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0].legend(fontsize="small", ncol=2)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("distance to the exact minimum-energy estimate (mean over the trials)", fontsize="medium")
    return fig


def basin_figure(arrays: dict, title: str = ""):
    """Fraction converged and median time to converge against the initial heading error, per filter."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    a, names = arrays["angles_deg"], [str(n) for n in arrays["filters"]]
    fig = Figure(figsize=(8, 6), layout="constrained")
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for i, name in enumerate(names):
        ax1.plot(a, arrays["fraction"][i], marker="o", lw=1.1, color=f"C{i}", label=name)
        ax2.plot(a, arrays["time_median"][i], marker="o", lw=1.1, color=f"C{i}")
    ax1.set_ylabel("fraction converged")
    ax1.set_ylim(-0.03, 1.03)
    ax2.set_ylabel("median time to converge [s]")
    ax2.set_xlabel("initial heading error [deg]")
    for ax in (ax1, ax2):
        ax.grid(True, lw=0.3, alpha=0.5)
    ax1.legend(fontsize="small", ncol=2)
    fig.suptitle(title or "convergence basin in the initial heading error", fontsize="medium")
    return fig


def distinct_colors(n: int) -> list:
    """``n`` colours, no two alike and none grey (grey is for references): matplotlib's tab10 without its grey
    while it suffices, else ``n`` evenly spaced samples of the turbo colormap."""
    import matplotlib

    if n <= 9:
        return [matplotlib.colormaps["tab10"](i) for i in (0, 1, 2, 3, 4, 5, 6, 8, 9)[:n]]
    return [matplotlib.colormaps["turbo"](x) for x in np.linspace(0.05, 0.95, n)]


def broad_error_figure(arrays: dict, trial: str, names: list[str], title: str = ""):
    """The total attitude error over time (rms over each second, log scale) of the filters ``names`` (the ones
    the study ran) on one BROAD trial, from saved arrays: small multiples, one panel per filter in its own colour
    (:func:`distinct_colors`), titled with its name and its total rms, and on every other panel the filter with
    the lowest total rms in grey for reference (named in the figure's title); the panels share their axes, and
    no legend covers them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(names)
    ncols = min(4, n)
    nrows = -(-n // ncols)
    fig = Figure(figsize=(3.3 * ncols + 0.8, 1.9 * nrows + 1.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False))
    totals = {name: float(np.asarray(arrays[f"{trial}/{name}"])[0]) for name in names}
    ranked = sorted((v, name) for name, v in totals.items() if np.isfinite(v))
    best = ranked[0][1] if ranked else None
    for i, (name, color) in enumerate(zip(names, distinct_colors(n), strict=True)):
        ax = axes.flat[i]
        if best is not None and name != best:
            e = np.asarray(arrays[f"{trial}/{best}/error_1s"])
            ax.plot(np.arange(e.size), e, color="0.65", lw=0.9, label=f"{best} (reference)")
        e = np.asarray(arrays[f"{trial}/{name}/error_1s"])
        ax.plot(np.arange(e.size), e, color=color, lw=1.3, label=name)
        total = totals[name]
        ax.set_title(f"{name}: " + (f"{total:.3g} deg total rms" if np.isfinite(total) else "failed")
                     + (" (lowest)" if name == best else ""), fontsize="small")
        ax.set_yscale("log")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    for i in range(n, nrows * ncols):  # the empty slots of the last row: the panel above shows the time axis
        fig.delaxes(axes.flat[i])
        axes.flat[i - ncols].tick_params(labelbottom=True)
    fig.supxlabel("t [s]", fontsize="medium")
    fig.supylabel("total attitude error, rms per second [deg]", fontsize="medium")
    fig.suptitle((title or f"BROAD trial {trial}") + ("" if best is None else f"\nin grey on every other panel: "
                                                      f"{best}, the lowest total rms"), fontsize="medium")
    return fig


def comparison_band_figure(arrays: dict, title: str = ""):
    """|heading error| and position error over time: per filter the median and the 5-95 % band across the
    healthy trials (log scale), from saved arrays."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts, names, b = arrays["ts"], [str(n) for n in arrays["filters"]], arrays["bands"]
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 1, sharex=True)
    colors = [f"C{i}" for i in range(len(names))]
    for ax, k, label in zip(axes, (0, 1), ("|heading error| [deg]", "position error [m]"), strict=True):
        for i, name in enumerate(names):
            ax.fill_between(ts, b[i, 0, :, k], b[i, 2, :, k], color=colors[i], alpha=0.12, lw=0)
            ax.plot(ts, b[i, 1, :, k], color=colors[i], lw=1.1, label=name)
        ax.set_yscale("log")
        ax.set_ylabel(label)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0].legend(loc="upper right", fontsize="small", ncol=2)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or "median and 5-95 % band across trials", fontsize="medium")
    return fig


def attitude_figure3(arrays: dict, steady: tuple[float, float] | None = None, *, connection_labels: Mapping[str, str]):
    """Saccon et al. 2016, Fig. 3 from saved arrays: e_R [deg] and |e_Omega| of both connections on the same
    axes, (0) black and (-) dashed red as in the paper; with ``steady`` a second column zooms on that window."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts = np.asarray(arrays["ts"])
    conns = [str(s) for s in arrays["connections"]]
    styles = [dict(color="black", lw=0.9), dict(color="tab:red", lw=0.9, ls="--")]
    ncols = 1 if steady is None else 2
    fig = Figure(figsize=(6.5 * ncols, 5.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(2, ncols, squeeze=False))
    labels = (r"$e^R$ [deg]", r"$|e^\Omega|$ [rad/s]")
    for col in range(ncols):
        sel = np.ones(ts.shape, bool) if col == 0 else (ts >= steady[0]) & (ts <= steady[1])
        for row in range(2):
            ax = axes[row, col]
            for conn, st in zip(conns, styles, strict=False):
                ax.plot(ts[sel], np.asarray(arrays[f"attitude_error_{conn}"])[sel, row],
                        label=f"{connection_labels.get(conn, conn)}-connection", **st)
            ax.set_ylabel(labels[row])
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.set_ylim(bottom=0.0)
        axes[-1, col].set_xlabel("t [s]")
        axes[0, col].set_title("whole run" if col == 0 else f"after the transient ({steady[0]:g}-{steady[1]:g} s)",
                               fontsize="medium")
    axes[0, 0].legend(loc="upper right", fontsize="small")
    fig.suptitle("Attitude filter errors, both connections on the same data (Saccon et al. 2016, Fig. 3)",
                 fontsize="medium")
    return fig


def chaplygin_figure(arrays, *, connections: Sequence[str], label: Mapping[str, str], paper_figures: Mapping,
                     ms: Callable[[float], str]) -> Figure:
    """Figs. 3-6 of Rigo et al. 2023 from saved arrays
    (:func:`liemef.studies.experiments.chaplygin.figure_arrays`): for each of theta, x, y, omega,
    v the nominal (black), measured (blue), (0)-filtered (green) and (-)-filtered (red) trajectories on the left,
    their errors on the right; the x-y path in the last row."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ts = np.asarray(arrays["ts"])
    names = [str(s) for s in arrays["names"]]
    units = [str(s) for s in arrays["units"]]
    colors = {"zero": "tab:green", "minus": "tab:red"}
    sym = {"theta": r"\theta", "omega": r"\omega", "x": "x", "y": "y", "v": "v"}
    fig = Figure(figsize=(11, 2.0 * (len(names) + 1) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(len(names) + 1, 2, squeeze=False))
    truth, meas = np.asarray(arrays["truth"]), np.asarray(arrays["measured"])
    for k, name in enumerate(names):
        ax = axes[k, 0]
        if np.isfinite(meas[:, k]).any():
            ax.plot(ts, meas[:, k], color="tab:blue", lw=0.3, alpha=0.5, label="measured", zorder=1)
        ax.plot(ts, truth[:, k], color="black", lw=1.3, label="nominal", zorder=2)
        for conn in connections:
            ax.plot(ts, np.asarray(arrays[f"filtered_{conn}"])[:, k], color=colors[conn], lw=0.9, ls="--",
                    label=f"filtered {label[conn]}", zorder=3)
        ref = np.concatenate([truth[:, k]] + [np.asarray(arrays[f"filtered_{c}"])[:, k] for c in connections])
        lo, hi = float(np.nanmin(ref)), float(np.nanmax(ref))
        pad = 0.25 * max(hi - lo, 1e-3)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"${sym.get(name, name)}$ [{units[k]}]")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax = axes[k, 1]
        for conn in connections:
            ax.plot(ts, np.asarray(arrays[f"error_{conn}"])[:, k], color=colors[conn], lw=0.7,
                    label=f"{label[conn]}")
        ax.axhline(0.0, color="0.5", lw=0.5)
        ax.set_ylabel(rf"$\delta {sym.get(name, name)}$ [{units[k]}]")
        ax.grid(True, lw=0.3, alpha=0.5)
    for k in (0, 1):
        axes[-2, k].set_xlabel("t [s]")
    ax = axes[-1, 0]
    ax.plot(truth[:, 1], truth[:, 2], color="black", lw=1.3, label="nominal")
    for conn in connections:
        f = np.asarray(arrays[f"filtered_{conn}"])
        ax.plot(f[:, 1], f[:, 2], color=colors[conn], lw=0.9, ls="--", label=f"filtered {label[conn]}")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax = axes[-1, 1]
    for conn in connections:
        ax.plot(ts, np.asarray(arrays[f"lateral_velocity_{conn}"]), color=colors[conn], lw=0.7, label=label[conn])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("lateral velocity\nof the estimate [m/s]")
    ax.grid(True, lw=0.3, alpha=0.5)
    axes[0, 0].legend(loc="upper left", fontsize="small", ncols=2)
    axes[0, 1].legend(loc="upper right", fontsize="small", ncols=2)
    dt, sensor = float(arrays["dt"]), str(arrays["sensor"])
    trial_note = "" if int(arrays["trial"]) < 0 else f", Monte Carlo trial {int(arrays['trial'])}"
    fig.suptitle(f"Chaplygin sleigh, {label[sensor]}, Ts = {ms(dt)} (Rigo et al. 2023, "
                 f"{paper_figures.get((round(dt, 9), sensor), 'cf. Figs. 3-6')}){trial_note}", fontsize="medium")
    return fig


def localization_band_figure(bands_npz: str | Path, *, published: Mapping[str, Mapping[str, float]]):
    """Heading and position error over time from a saved ``bands.npz``: median and 5-95 % band across the
    healthy trials (absolute values, log scale)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    a = io.read_arrays(bands_npz)
    ts, b = a["ts"], a["bands"]  # (3, times, 2): p5, p50, p95 of |heading| [deg], position [m]
    fig = Figure(figsize=(8.5, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 1, sharex=True)
    for k, (ax, label, ref) in enumerate(zip(axes, ("|heading error| [deg]", "position error [m]"),
                                             (published["iekf"]["heading_deg"], published["iekf"]["position_m"]),
                                             strict=True)):
        ax.fill_between(ts, b[0, :, k], b[2, :, k], color="tab:green", alpha=0.25, lw=0, label="5-95 %")
        ax.plot(ts, b[1, :, k], color="tab:green", lw=1.2, label="median")
        ax.axhline(ref, color="0.3", ls="--", lw=0.8, label="published IEKF rms (t >= 20 s)")
        ax.set_yscale("log")
        ax.set_ylabel(label)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0].legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"ukfm 2D localization: {int(a['healthy'])} of {int(a['runs'])} trials, {a['filter']}",
                 fontsize="medium")
    return fig
