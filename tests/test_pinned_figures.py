"""Bit-identity of key figures: the numbers of a few reproductions, Monte Carlo runs and a comparison, pinned
as ``float.hex`` before the restructuring of the package (issue 18), on the same engines.

A restructuring changes where code lives, not what it computes: every figure here must come out with the same
bits. A change that is meant to move numbers writes ``pinned_figures.json`` anew (``python
tests/pinned_figures.py``) and says why in its commit.
"""

import json
from pathlib import Path

import pytest

from pinned_figures import figures

PINNED = json.loads((Path(__file__).with_name("pinned_figures.json")).read_text())


@pytest.fixture(scope="module")
def computed():
    return figures()


@pytest.mark.parametrize("name", sorted(PINNED))
def test_figure_has_its_pinned_bits(computed, name):
    assert computed[name] == PINNED[name], name


def test_every_computed_figure_is_pinned(computed):
    assert sorted(computed) == sorted(PINNED)
