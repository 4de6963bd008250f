"""`liemef run`'s figure: +-3 sigma bands from K, the measurements, roll/pitch/yaw for SO(3) (no jump at +-pi)
and the x-y path of a pose. The tests read the figure's artists and data, not only that a file exists."""

import jax.numpy as jnp
import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from liemef.groups import SE23, SO3
from liemef.reports.figures import run_figure
from liemef.studies.logs import state_bands
from liemef.systems import inertial_navigation


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
    arrays = {"ts": 0.1 * np.arange(len(yaw)), **{f"plot_{k}": v for k, v in b.items()}}
    fig = run_figure(arrays, "spin")
    axes = fig.axes
    assert len(axes) == 10  # nine components and the x-y path
    for k, ax in enumerate(axes[:9]):
        assert ax.get_ylabel().startswith(str(b["names"][k]))
        band = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(band) == 1
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
