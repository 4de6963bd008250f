"""liemef._chi2.quantile is scipy.stats.chi2.ppf, float for float, without importing scipy.stats (about a second
in every process that gates a sensor or bounds a NEES)."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import chi2

from liemef._chi2 import quantile
from liemef.metrics import chi2_bounds
from refusals import raises


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 9, 11, 20, 57, 400, 12000])
def test_it_is_scipy_s_quantile_bit_for_bit(dof):
    for p in (0.0, 1e-12, 0.001, 0.025, 0.05, 0.5, 0.9, 0.95, 0.975, 0.99, 0.999, 0.9999, 1.0 - 1e-12, 1.0):
        assert quantile(p, dof) == float(chi2.ppf(p, dof)), (p, dof)
    assert quantile(1.0, dof) == math.inf and quantile(0.0, dof) == 0.0


def test_bad_arguments_are_refused_by_name():
    raises(lambda: quantile(1.5, 3), "p: expected a probability in [0, 1], got 1.5")
    raises(lambda: quantile(float("nan"), 3), "p: expected a probability in [0, 1], got nan")
    raises(lambda: quantile(0.5, 0), "dof: expected an integer >= 1, got 0")
    raises(lambda: quantile(0.5, 2.5), "dof: expected an integer >= 1, got 2.5")
    raises(lambda: quantile(True, 2), "p: expected a probability in [0, 1], got True")


def test_numpy_numbers_are_numbers():
    """A float32 probability or a NumPy integer (as chi2_bounds may pass on) is taken as its value."""
    assert quantile(np.float32(0.95), np.int64(3)) == float(chi2.ppf(np.float32(0.95), 3))
    p = np.float32(0.95)
    scipy_s = (float(chi2.ppf((1.0 - p) / 2.0, 30)) / 10, float(chi2.ppf((1.0 + p) / 2.0, 30)) / 10)
    assert chi2_bounds(3, 10, p) == scipy_s


def test_a_gated_system_and_its_filter_import_no_scipy_stats():
    code = ("import sys, liemef; from liemef.systems import inertial_navigation; "
            "f = liemef.MinimumEnergyFilter(inertial_navigation(gate=0.999)); "
            "assert f.blocks[0].gate_threshold > 0; "
            "from liemef.metrics import chi2_bounds; chi2_bounds(3, 10); "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"
