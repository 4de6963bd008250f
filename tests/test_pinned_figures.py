"""Bit-identity of key figures: the numbers of a few reproductions, Monte Carlo runs and a comparison, pinned
as ``float.hex`` before the restructuring of the package (issue 18), on the same engines.

A restructuring changes where code lives, not what it computes: every figure here must come out with the same
bits. A change that is meant to move numbers writes ``pinned_figures.json`` anew (``python
tests/pinned_figures.py``) and says why in its commit.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import fast_compile

PINNED = json.loads((Path(__file__).with_name("pinned_figures.json")).read_text())


@pytest.fixture(scope="module")
def computed():
    """The figures, computed in a process of their own with XLA's default compile options, a user's: the suite's
    other processes compile with tests/fast_compile.py's, which move last bits (JAX's persistent cache keys its
    programs by XLA_FLAGS, so neither process loads the other's)."""
    env = dict(os.environ, XLA_FLAGS=fast_compile.removed(os.environ.get("XLA_FLAGS", "")))
    res = subprocess.run([sys.executable, str(Path(__file__).with_name("pinned_figures.py"))], capture_output=True,
                         text=True, env=env, timeout=1800)
    assert res.returncode == 0, res.stderr[-4000:]
    return json.loads(res.stdout)


@pytest.mark.parametrize("name", sorted(PINNED))
def test_figure_has_its_pinned_bits(computed, name):
    assert computed[name] == PINNED[name], name


def test_every_computed_figure_is_pinned(computed):
    assert sorted(computed) == sorted(PINNED)
