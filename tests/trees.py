"""Comparing two pytrees of results (a trajectory, a final state, a status) leaf by leaf, for the tests that check
one engine or one filter against another."""

import jax
import numpy as np

from tolerances import ENGINES


def assert_trees_close(a, b, tol: float = ENGINES) -> None:
    """Every leaf of ``a`` equal to ``b``'s within ``tol`` relative to max(1, |b|) (``tol=0``: bit for bit), with
    the same shape and dtype; integer and boolean leaves (statuses, counters) exactly, NaNs at the same places."""
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb), (len(la), len(lb))
    for x, y in zip(la, lb, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype, (x.shape, y.shape, x.dtype, y.dtype)
        if x.dtype.kind in "iub":
            np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_array_equal(np.isnan(x), np.isnan(y))
            ok = ~np.isnan(x)
            scale = max(1.0, float(np.abs(y[ok]).max(initial=0)))
            np.testing.assert_allclose(x[ok], y[ok], rtol=0, atol=tol * scale)
