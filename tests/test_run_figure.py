"""`liemef run`'s figure: +-3 sigma bands from K where K is a covariance (none, and a note, where it is not), the
measurements, roll/pitch/yaw for SO(3) (no jump at +-pi), one y axis per panel fitted to its own data, time from
the log's start, and the x-y path of a pose. The tests read the figure's artists and data, not only that a file
exists; and the run's warnings say times from the log's start too."""

import jax.numpy as jnp
import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from liemef.groups import SE23, SO3
from liemef.reports import io
from liemef.reports.figures import NO_BAND_NOTE, run_figure
from liemef.studies.logs import filter_log, state_bands
from liemef.systems import inertial_navigation
from localization_scenario import circle_samples


@pytest.fixture(scope="module")
def spin():
    """SE_2(3) spinning twice about z (the rotation vector jumps at +-pi twice), with a constant body K."""
    N = 81
    yaw = np.linspace(0.0, 4 * np.pi, N)
    R = SO3.exp(jnp.asarray(np.column_stack([np.zeros(N), np.zeros(N), yaw])))
    g = SE23.from_rotation_vectors(R, jnp.asarray(np.stack([np.zeros((N, 3)), np.column_stack([yaw, -yaw, yaw])],
                                                           axis=1)))
    K = np.diag([0.01, 0.04, 0.09, 1.0, 1.0, 1.0, 1.0, 4.0, 9.0])
    return yaw, g, np.broadcast_to(K, (N, 9, 9))


def test_so3_is_plotted_as_unwrapped_roll_pitch_yaw_with_sigma_from_k(spin):
    yaw, g, K = spin
    b = state_bands(inertial_navigation(), g, K)
    assert list(b["names"][:3]) == ["roll", "pitch", "yaw"] and list(b["units"][:3]) == ["rad"] * 3
    np.testing.assert_allclose(b["values"][:, 2], yaw, atol=1e-9)  # through +-pi twice, no jump
    np.testing.assert_allclose(b["values"][:, :2], 0.0, atol=1e-9)
    np.testing.assert_allclose(b["std"][:, :3], np.broadcast_to([0.1, 0.2, 0.3], (len(yaw), 3)), rtol=1e-9)
    # the position error is R rho (rho in the body frame): at yaw 90 deg the world x has the body y's sigma
    k = np.argmin(np.abs(yaw - np.pi / 2))
    np.testing.assert_allclose(b["std"][k, 6:], [2.0, 1.0, 3.0], rtol=1e-9)
    np.testing.assert_allclose(b["path"], np.asarray(g.position())[:, :2])


def test_the_figure_draws_the_bands_the_measurements_and_the_path(spin):
    yaw, g, K = spin
    measured = np.full((len(yaw), 9), np.nan)
    measured[::10, 6:] = np.asarray(g.position())[::10] + 0.5
    b = state_bands(inertial_navigation(), g, K, measured)
    arrays = {"ts": 0.1 * np.arange(len(yaw)), **{f"plot_{k}": v for k, v in b.items()},
              "plot_covariance": np.bool_(True)}
    fig = run_figure(arrays, "spin")
    axes = fig.axes
    assert len(axes) == 10  # nine components and the x-y path
    assert fig.get_suptitle() == "spin" and axes[8].get_xlabel() == "t [s]"  # a log from t = 0: no t0 to state
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["+-3 sigma (K, a covariance)", "filtered",
                                                                  "measured"]
    for k, ax in enumerate(axes[:9]):
        assert ax.get_ylabel().startswith(str(b["names"][k])) and ax.get_legend() is None
        band = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(band) == 1 and band[0].get_label() == "+-3 sigma (K, a covariance)"
        y = band[0].get_paths()[0].vertices[:, 1]
        np.testing.assert_allclose([y.min(), y.max()], [np.min(b["values"][:, k] - 3 * b["std"][:, k]),
                                                        np.max(b["values"][:, k] + 3 * b["std"][:, k])])
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        np.testing.assert_allclose(lines["filtered"].get_ydata(), b["values"][:, k])
        assert ("measured" in lines) == (k >= 6)
        if k >= 6:
            np.testing.assert_allclose(lines["measured"].get_ydata(), measured[::10, k])
    yaw_line = {ln.get_label(): ln for ln in axes[2].get_lines()}["filtered"].get_ydata()
    assert np.max(np.abs(np.diff(yaw_line))) < 0.2  # continuous: no jump of 2 pi
    path = {ln.get_label(): ln for ln in axes[9].get_lines()}
    np.testing.assert_allclose(path["filtered"].get_xydata(), b["path"])
    np.testing.assert_allclose(path["measured"].get_xydata(), measured[::10, 6:8])
    assert axes[9].get_xlabel() == "x [m]" and axes[9].get_ylabel() == "y [m]"


def test_a_group_without_a_position_has_no_path():
    from liemef.groups import SO2, Product
    from liemef.studies.experiments import get_system

    system = get_system("unit-circle").make()
    assert issubclass(system.group, Product) and system.group.factor_types[0] is SO2
    g = system.group.from_coords(jnp.asarray(np.column_stack([np.linspace(0, 7, 5), np.zeros(5)])))
    b = state_bands(system, g, np.broadcast_to(np.eye(2), (5, 2, 2)))
    assert "path" not in b and np.max(np.diff(b["values"][:, 0])) < 2  # the angle is unwrapped
    fig = run_figure({"ts": np.arange(5.0), **{f"plot_{k}": v for k, v in b.items()}})
    assert len(fig.axes) == 2


def test_without_a_covariance_there_is_no_band_and_the_figure_says_why(spin):
    yaw, g, K = spin
    b = state_bands(inertial_navigation(), g, K)
    for covariance in (np.bool_(False), None):  # said so, or not saved (an older folder): no band either way
        arrays = {"ts": 0.1 * np.arange(len(yaw)), **{f"plot_{k}": v for k, v in b.items()}}
        if covariance is not None:
            arrays["plot_covariance"] = covariance
        fig = run_figure(arrays, "spin")
        assert not any(isinstance(c, PolyCollection) for ax in fig.axes for c in ax.collections)
        assert fig.get_suptitle() == "spin\n" + NO_BAND_NOTE and "not a covariance" in NO_BAND_NOTE
        assert [t.get_text() for t in fig.legends[0].get_texts()] == ["filtered"]
        for k, ax in enumerate(fig.axes[:9]):  # the limits fit the estimate, not the 3 sigma of a gain
            lo, hi = ax.get_ylim()
            v = b["values"][:, k]
            if np.ptp(v) > 0:  # (matplotlib widens a constant's limits its own way)
                assert lo <= v.min() and v.max() <= hi and hi - lo <= 1.2 * np.ptp(v)


def epoch_bias_arrays(N=600):
    """A roll in rad swinging by +-2 and a gyro bias in rad/s near 0.003, at 100 Hz from an epoch-scale t0 (a ROS
    bag's stamps); the bias's K starts at the prior 1 (rad/s)^2 and settles to (1e-4 rad/s)^2 within 0.5 s."""
    t = 0.01 * np.arange(N)
    values = np.column_stack([2.0 * np.sin(t), 0.003 + 0.001 * np.sin(3 * t)])
    std = np.column_stack([np.full(N, 0.05), 1e-4 + np.exp(-t / 0.05)])
    measured = np.column_stack([values[:, 0] + 0.1 * np.cos(7 * t), np.full(N, np.nan)])
    return {"ts": 1_700_000_000.0 + t, "plot_names": np.array(["roll", "bx"]), "plot_units": np.array(["rad", "rad/s"]),
            "plot_values": values, "plot_std": std, "plot_measured": measured, "plot_covariance": np.bool_(True)}


def test_each_panel_has_its_own_y_axis_fitted_to_its_own_data():
    a = epoch_bias_arrays()
    fig = run_figure(a, "bias")
    roll, bx = fig.axes
    assert roll.get_ylabel() == "roll [rad]" and bx.get_ylabel() == "bx [rad/s]"
    for ax in (roll, bx):  # never one y axis across panels (and units)
        assert ax.get_shared_y_axes().get_siblings(ax) == [ax]
    v, std, m = a["plot_values"], a["plot_std"], a["plot_measured"]
    lo, hi = roll.get_ylim()
    assert lo <= np.min(m[:, 0]) and np.max(m[:, 0]) <= hi and hi - lo < 1.2 * np.ptp(m[:, 0])
    # the bias panel fits the bias and its settled band: a span of about 5 mrad/s, not the prior's +-3 rad/s
    lo, hi = bx.get_ylim()
    settled = std[:, 1] <= 10 * np.median(std[:, 1])
    band = np.concatenate([v[settled, 1] - 3 * std[settled, 1], v[settled, 1] + 3 * std[settled, 1]])
    assert lo <= band.min() and band.max() <= hi and hi - lo < 1.2 * np.ptp(band) < 0.01
    band_drawn = [c for c in bx.collections if isinstance(c, PolyCollection)][0].get_paths()[0].vertices[:, 1]
    assert band_drawn.max() > 2.9  # the prior is drawn, off scale, and the panel says so
    assert [t.get_text() for t in bx.texts] == [f"off scale before {0.01 * np.argmax(settled):.3g} s: K settling "
                                                "from K0"]
    assert len(roll.texts) == 0


def test_time_runs_from_the_log_start_and_the_title_states_t0():
    a = epoch_bias_arrays()
    fig = run_figure(a, "bias")
    assert fig.get_suptitle() == "bias\nt0 = 1700000000 s, the log's first sample"
    assert fig.axes[-1].get_xlabel() == "t - t0 [s]"
    for ax in fig.axes:
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        np.testing.assert_allclose(lines["filtered"].get_xdata(), a["ts"] - a["ts"][0])
        assert lines["filtered"].get_xdata()[0] == 0.0
        band = [c for c in ax.collections if isinstance(c, PolyCollection)][0].get_paths()[0].vertices[:, 0]
        assert band.min() == 0.0 and band.max() == pytest.approx(5.99)
    assert {ln.get_label(): ln for ln in fig.axes[0].get_lines()}["measured"].get_xdata()[0] == 0.0


def test_a_run_says_whether_k_is_a_covariance_and_times_from_the_log_start():
    """A SensorSystem's K is a covariance: band and title say so; a paper system's (tse2) is a gain: neither.
    The outlier warning of a log with epoch time stamps says the time from its start, with the absolute one."""
    ts, _, _, us, ys = circle_samples(600, np.arange(100, 600, 100), 1.0)
    ys[300] = [40.0, 0.0]  # an outlier with no gate, at t0 + 3 s
    run = filter_log("localization", io.RecordedLog(1_700_000_000.0 + ts, us, ys), log_file="bag")
    assert run.arrays["plot_covariance"] and "with +-3 sigma from K" in run.metrics["figures"][0]["title"]
    said = [w for w in run.warnings() if w.startswith("gps:")]
    assert len(said) == 1 and "at t = t0 + 3 s (1700000003 s)" in said[0], said
    assert run.monitor.t0 == 1_700_000_000.0  # its message says its times from there too
    import jax

    import liemef
    from liemef.studies.experiments import SYSTEMS
    from liemef.systems import tse2_state

    system = SYSTEMS["tse2"].make()
    ts = 0.01 * np.arange(60)
    _, log = liemef.simulate(system, tse2_state(0.5, 1.0, 2.0, 0.0, 0.0, 0.0),
                             lambda t: jax.numpy.stack([jax.numpy.sin(t), 1.0 + 0 * t]), ts, jax.random.key(0))
    run = filter_log("tse2", io.RecordedLog(ts, np.asarray(log.us), np.asarray(log.ys)), monitor=False)
    assert not run.arrays["plot_covariance"] and "sigma" not in run.metrics["figures"][0]["title"]
    fig = run_figure(run.arrays, run.metrics["figures"][0]["title"])
    assert NO_BAND_NOTE in fig.get_suptitle()
    assert not any(isinstance(c, PolyCollection) for ax in fig.axes for c in ax.collections)
