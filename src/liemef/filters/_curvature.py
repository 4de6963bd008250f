r"""The safe second-order curvature: the output's residual-weighted Hessian, kept where the data observe and
where it leaves the information non-negative (docs/theorem.md, "When the second-order terms are unsafe").

The information a sensor adds, in Theorem 4.1's E (continuous) and in the sample update's Hessian (discrete),
is a Gauss-Newton part $G = F^\top W F \succeq 0$ plus a curvature part $C = -\nabla^2(\tilde y\cdot h)$ that has
either sign. Where $C$ is indefinite or large, $G + C$ can be indefinite (K loses positive definiteness, or
grows without bound), and $C$ can act along directions where $G$ is zero: curvature from a large residual then
looks like information about a state the sensor does not see (a range sensor's Hessian couples the attitude
with the horizontal position it cannot measure).

The rule keeps $C$ relative to $G$ on $G$'s range. With $G = V\,\mathrm{diag}(s)\,V^\top$, the observed
directions are those with $s_i > \epsilon \max s$; whitened on them, $M = S^{+1/2} V^\top C\, V S^{+1/2}$ has
the eigenvalues $\mu$ of $C$ relative to $G$ ($C v = \mu\, G v$). The safe curvature is

$$C_{\text{safe}} = V S^{1/2}\, U \max(\mathrm{diag}(\mu), -1)\, U^\top S^{1/2} V^\top, \qquad M = U\,\mathrm{diag}(\mu)
\,U^\top,$$

so that $G + C_{\text{safe}} = V S^{1/2} U \max(1 + \mu, 0) U^\top S^{1/2} V^\top \succeq 0$: along an observed
direction the second order may scale the Gauss-Newton information by any factor $1 + \mu \ge 0$ (it may add
information there, or remove it all, never more), and it adds nothing along a direction the sensor does not
see. It is $C$ itself, to round-off, wherever $G$ is nonsingular and $G + C \succeq 0$; :func:`safe_curvature`
returns $C$'s own bits there, so that a run that never needs the rule is the theorem's, bit for bit.

Eigen-decompositions of these small symmetric matrices (``jnp.linalg.eigh``) are sign-free here: every result is
a product $V\cdot V^\top$, unchanged when a column of V or U changes sign.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._linalg import mm

OBSERVED_TOL = 1e-10
"""A direction is observed where the Gauss-Newton information exceeds ``OBSERVED_TOL`` times its largest
eigenvalue."""
UNCHANGED_TOL = 1e-12
"""The exact curvature is kept (its bits) where the safe one differs from it by at most ``UNCHANGED_TOL`` times
the information's scale."""


def safe_curvature(G: Float[Array, "n n"], C: Float[Array, "n n"]) -> tuple[Float[Array, "n n"], Bool[Array, ""]]:
    r"""$(C_{\text{safe}}, \text{modified})$ for the Gauss-Newton information ``G`` (symmetric positive
    semidefinite) and the curvature ``C`` (module docstring): the rule acts on C's symmetric part, the only part
    a quadratic form sees; an antisymmetric part (a connection with torsion) is kept. ``modified`` says whether
    the rule changed C (beyond ``UNCHANGED_TOL``); where it did not, ``C`` is returned as it came. Traceable."""
    Gs, Cs = 0.5 * (G + G.T), 0.5 * (C + C.T)
    s, V = jnp.linalg.eigh(Gs)
    scale = jnp.maximum(jnp.max(jnp.abs(s)), 1e-300)
    observed = s > OBSERVED_TOL * scale
    root = jnp.where(observed, jnp.sqrt(jnp.where(observed, s, 1.0)), 0.0)
    inv_root = jnp.where(observed, 1.0 / jnp.where(observed, root, 1.0), 0.0)
    Vw = V * inv_root[None, :]                      # whitening on the observed directions
    mu, U = jnp.linalg.eigh(mm(Vw.T, mm(Cs, Vw)))
    B = mm(V * root[None, :], U)                    # V S^{1/2} U
    C_safe = mm(B * jnp.maximum(mu, -1.0)[None, :], B.T)
    big = jnp.maximum(scale, jnp.max(jnp.abs(Cs)))
    modified = jnp.max(jnp.abs(C_safe - Cs)) > UNCHANGED_TOL * big
    return jnp.where(modified, C_safe + (C - Cs), C), modified
