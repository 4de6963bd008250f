r"""Consistency of a filter's gain: the left-invariant error, its NEES under K, and chi-square bounds.

The filter's K approximates the covariance of the left-invariant (body-frame) error
$\xi = \log(\hat g^{-1} g)$, so that $g = \hat g \exp\xi$ (docs/weights.md, with weights set from the noise
levels). The normalized estimation error squared $\epsilon = \xi^\top K^{-1}\xi$ of a consistent filter is
$\chi^2$ with $n$ degrees of freedom; averaged over $N$ independent runs, $N\bar\epsilon \sim \chi^2_{nN}$,
which gives :func:`chi2_bounds` (Bar-Shalom, Li, Kirubarajan 2001, Sec. 5.4.2).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._chi2 import quantile
from ..groups import LieGroup


def left_error(g_true: LieGroup, g_hat: LieGroup) -> Float[Array, "... n"]:
    r"""$\xi = \log(\hat g^{-1} g)$: the left-invariant error whose covariance K approximates
    ($g = \hat g\exp\xi$). Broadcasts over batch axes."""
    return (g_hat.inverse() @ g_true).log()


def nees(e: Float[ArrayLike, "... n"], K: Float[ArrayLike, "... n n"]) -> Float[Array, "..."]:
    r"""$\epsilon = e^\top K^{-1} e$ per sample (batched over the leading axes; by a linear solve, no inverse).

    NaN-safe: a sample with a NaN in ``e`` or ``K`` (a failed run) gives NaN for that sample only, never an
    exception, and a zero error gives 0 whatever ``K`` (the minimum-norm value: an exactly known coordinate,
    ``K = 0`` and ``e = 0``, is consistent, not NaN). Traceable.
    """
    e = jnp.asarray(e, dtype=jnp.float64)
    K = jnp.asarray(K, dtype=jnp.float64)
    x = jnp.linalg.solve(K, e[..., None])[..., 0]
    q = jnp.sum(e * x, axis=-1)
    return jnp.where(jnp.all(e == 0.0, axis=-1), 0.0, q)


def run_nees(g_true: LieGroup, traj) -> Float[Array, " N"]:
    r"""The NEES of a filter's run against its truth, per sample: $e_k^\top K_k^{-1} e_k$ with the left error
    $e_k = \log(\hat g_k^{-1} g_k)$ (:func:`left_error`, :func:`nees`). ``g_true``: the true states (batch shape
    (N,)); ``traj``: the run (a :class:`~liemef.filters.Trajectory`, or anything with ``g_hat`` and ``K`` over the
    same N samples). NaN where the run had failed. For a consistent filter it follows a chi-square law with n
    degrees of freedom (:func:`chi2_bounds`)."""
    return nees(left_error(g_true, traj.g_hat), traj.K)


def chi2_bounds(dof: int, n_runs: int, prob: float = 0.95, *, per_dof: bool = False) -> tuple[float, float]:
    r"""Two-sided ``prob`` bounds for the average NEES of ``n_runs`` independent runs of a consistent filter:
    $(\chi^2_{nN}((1-p)/2),\ \chi^2_{nN}((1+p)/2)) / N$ with $n$ = ``dof``, $N$ = ``n_runs``
    (chi-square quantiles, :func:`liemef._chi2.quantile`). ``per_dof``: divided by ``dof`` as well (bounds around
    1, for a NEES divided by its dimension)."""
    if isinstance(dof, bool) or int(dof) != dof or dof < 1:
        raise ValueError(f"dof: expected an integer >= 1, got {dof!r}")
    if isinstance(n_runs, bool) or int(n_runs) != n_runs or n_runs < 1:
        raise ValueError(f"n_runs: expected an integer >= 1, got {n_runs!r}")
    if not (math.isfinite(prob) and 0.0 < prob < 1.0):
        raise ValueError(f"prob: expected a probability in (0, 1), got {prob!r}")
    k = int(dof) * int(n_runs)
    scale = int(n_runs) * (int(dof) if per_dof else 1)
    return quantile((1.0 - prob) / 2.0, k) / scale, quantile((1.0 + prob) / 2.0, k) / scale


def wilson_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float | None, float | None]:
    """Wilson score interval (95 % by default) of a binomial proportion k/n, e.g. the fraction of trials that
    converge; (None, None) without trials."""
    if n == 0:
        return (None, None)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # at k = 0 (k = n) the bound is 0 (1) exactly; the formula leaves a rounding residue there
    return (0.0 if k == 0 else max(0.0, centre - half), 1.0 if k == n else min(1.0, centre + half))
