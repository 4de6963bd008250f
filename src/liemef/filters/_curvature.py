r"""The safe second-order curvature: the output's residual-weighted Hessian, kept where it only lowers the
Gauss-Newton information without making it negative, else dropped (docs/theorem.md, "When the second-order terms
are unsafe").

The information a sensor adds, in Theorem 4.1's E (continuous) and in the sample update's Hessian (discrete),
is a Gauss-Newton part $G = F^\top W F \succeq 0$ plus a curvature part $C = -\nabla^2(\tilde y\cdot h)$ that has
either sign. Where $G + C$ is indefinite, K can lose positive definiteness or grow without bound; where $C$ adds
to $G$, curvature from a large residual looks like information, and where it acts along a direction that G does
not see, like information about a state the sensor does not observe (a range sensor's Hessian couples the
attitude with the horizontal position it cannot measure).

The rule keeps C exactly where

$$-G \preceq C \preceq 0,$$

and replaces it by 0 (the Gauss-Newton information, the first order's) elsewhere. Within the band, the second
order can only take information away where the cost is flatter than its linearization (K stays larger, the
honest side), and never more than all of it: $0 \preceq G + C \preceq G$. The band excludes curvature along a
direction $v$ that G does not observe: $v^\top C v \le 0 \le v^\top (G + C) v = v^\top C v$ forces $C v = 0$ when
$-C \succeq 0$. G is the expected Hessian of the sensor's cost (its Fisher information: C has zero mean at the
true state, where $\tilde y$ is noise), so a curvature that would add to it is the residual's noise, or the
estimate's error, read as information. This is Newton's method with Hessian modification by fallback (Nocedal
& Wright, Numerical Optimization, ch. 3.4), the modified Hessian being the Gauss-Newton one.

Both conditions are Cholesky tests (:func:`~._status.positive_definite`, an unrolled factorization: the same
arithmetic on both engines, no eigendecomposition) of $-C$ and $G + C$, Jacobi-scaled and shifted by
``BAND_TOL`` so that semidefinite matrices (a sensor that observes some directions only) pass, while a cross term
into a direction that G does not observe does not.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._status import positive_definite

BAND_TOL = 1e-10
"""The Cholesky tests of $-C \\succeq 0$ and $G + C \\succeq 0$, on the matrices scaled by
$d_i = \\sqrt{|G_{ii}| + |C_{ii}|}$ (Jacobi scaling; 1 where both are 0), accept an eigenvalue down to
``-BAND_TOL``."""


def safe_curvature(G: Float[Array, "n n"], C: Float[Array, "n n"]) -> tuple[Float[Array, "n n"], Bool[Array, ""]]:
    r"""$(C_{\text{safe}}, \text{modified})$ for the Gauss-Newton information ``G`` (symmetric positive
    semidefinite) and the curvature ``C`` (module docstring): ``C`` as it came where $-G \preceq C \preceq 0$
    (tested on its symmetric part, the only part a quadratic form sees), else zeros; ``modified`` says which.
    Traceable."""
    n = G.shape[0]
    Gs, Cs = 0.5 * (G + G.T), 0.5 * (C + C.T)
    # Jacobi scaling, so that the tolerance is relative per direction: a direction G does not observe has
    # (nearly) zero scale, and a cross term into it is then large, not lost below the observed ones' rounding
    d = jnp.sqrt(jnp.abs(jnp.diag(Gs)) + jnp.abs(jnp.diag(Cs)))
    d = jnp.where(d > 0, d, 1.0)
    scale = d[:, None] * d[None, :]
    shift = BAND_TOL * jnp.eye(n)
    inside = positive_definite(shift - Cs / scale) & positive_definite((Gs + Cs) / scale + shift)
    return jnp.where(inside, C, jnp.zeros_like(C)), ~inside
