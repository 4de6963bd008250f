from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ..groups import SE2, SO2, SO3, LieGroup, Product
from ..systems._residuals import wrap_angle


def angle_mask(G: type[LieGroup]) -> tuple[bool, ...]:
    """Which entries of ``G``'s coordinates (:meth:`~liemef.groups.LieGroup.coords`) are angles to wrap.

    SO(2) and the heading of SE(2) are angles; R^n entries are not. SO(3) coordinates are a rotation vector,
    not wrapped entry by entry (:func:`state_error` uses the rotation error for them).
    """
    if issubclass(G, Product):
        return tuple(b for F in G.factor_types for b in angle_mask(F))
    if issubclass(G, SO2):
        return (True,)
    if issubclass(G, SE2):
        return (True, False, False)
    return (False,) * G.coords_dim  # R^n, SO(3) and anything else


def continuous_angles(coords: Float[ArrayLike, "N c"], angles: Bool[ArrayLike, " c"] | tuple[bool, ...],
                      reference: Float[ArrayLike, "N c"] | None = None) -> np.ndarray:
    """Time series of coordinates with continuous angles, for plotting (NumPy, not traced).

    Without ``reference`` each angle component is unwrapped along time; with it, each angle sample is put on
    the branch nearest the reference sample (for noisy measured angles, whose unwrapping means nothing).
    NaN stays NaN.
    """
    out = np.array(coords, dtype=np.float64)
    for k in np.flatnonzero(np.asarray(angles, dtype=bool)):
        if reference is None:
            ok = np.isfinite(out[:, k])
            out[ok, k] = np.unwrap(out[ok, k])
        else:
            ref = np.asarray(reference, dtype=np.float64)[:, k]
            out[:, k] = ref + np.asarray(wrap_angle(out[:, k] - ref))
    return out


def coordinate_error(truth: Float[ArrayLike, "... c"], estimate: Float[ArrayLike, "... c"],
                     angles: Bool[ArrayLike, " c"] | tuple[bool, ...]) -> Float[Array, "... c"]:
    r"""$\delta = q - \hat q$ entry by entry, the entries flagged in ``angles`` wrapped to $(-\pi, \pi]$."""
    diff = jnp.asarray(truth, dtype=jnp.float64) - jnp.asarray(estimate, dtype=jnp.float64)
    return jnp.where(jnp.asarray(angles, dtype=bool), wrap_angle(diff), diff)


def state_error(truth: LieGroup, estimate: LieGroup) -> Float[Array, "... c"]:
    r"""Truth minus estimate in the group's coordinates (Rigo et al. 2022, Sec. VI: $\delta\theta = \theta_n -
    \hat\theta$, $\delta x = x_n - \hat x$, ...), angles wrapped. Broadcasts over batch axes.

    An SO(3) factor has no meaningful coordinate difference (two rotation vectors); its entries are the
    body-frame rotation error $\log(\hat R^\top R)$, whose norm is the attitude error angle.
    """
    if isinstance(truth, Product):
        return jnp.concatenate([state_error(a, b) for a, b in zip(truth.factors, estimate.factors, strict=True)],
                               axis=-1)
    if isinstance(truth, SO3):
        return truth.rminus(estimate)
    return coordinate_error(truth.coords(), estimate.coords(), angle_mask(type(truth)))


def group_error(truth: LieGroup, estimate: LieGroup) -> Float[Array, "... n"]:
    r"""$\log(\hat g^{-1} g)$: the truth seen from the estimate, in the body frame (left-trivialized)."""
    return truth.rminus(estimate)
