r"""Matrix Lie groups, with one set of conventions for the whole library.

Conventions (Saccon et al. 2016 and the papers that follow it; tested in ``tests/test_groups.py``):

* A Lie algebra element is a vector $\xi \in \mathbb R^n$ through :meth:`~LieGroup.hat` /
  :meth:`~LieGroup.vee`, in the papers' basis order: so(2) = $(\omega)$; so(3) = $(w_x, w_y, w_z)$;
  se(2) = $(\omega, v_x, v_y)$ (rotation rate first); se(3) = $(\omega; v)$ (rotation first, then the
  translation rate, 6 entries); se_2(3) = $(\omega; \nu_v; \nu_p)$ (rotation, velocity, position: 9);
  se_K(3) = $(\omega; \nu_1; \ldots; \nu_K)$; $\mathbb R^n$ = $x$; products concatenate their factors, e.g.
  TSE(2) = SE(2) x R^3 has $(\omega, v_x, v_y; \dot\omega, \dot v_x, \dot v_y)$. A
  :class:`MatrixGroup` takes the order of the basis it is given (:data:`SL3`, :data:`Sim3`: see there).
* Perturbations are **left-trivialized** (body frame): the direction $\xi$ at $g$ is the curve $g \exp(s\xi)$
  (:meth:`~LieGroup.rplus`).
* $\mathrm{ad}_X$ is the $n \times n$ matrix with $\mathrm{ad}_X Y = [\hat X, \hat Y]^\vee$;
  $\mathrm{Ad}_g$ the one with $\mathrm{Ad}_g X = (g \hat X g^{-1})^\vee$.
* The dual $\mathfrak g^*$ is $\mathbb R^n$ through the standard pairing.
* Elements are frozen pytrees with optional leading batch axes: they pass through ``jit``, ``vmap`` and
  ``lax.scan``. Every ``exp`` is smooth at 0 with finite first and second derivatives (Taylor branches).
* Membership is checked at the boundaries, with one tolerance, ``liemef._validate.ON_GROUP`` = 1e-6, per
  defect: :meth:`~LieGroup.from_matrix` refuses a non-finite matrix and one whose
  :meth:`~LieGroup.matrix_defects` exceed it (the orthogonality $\max|R^T R - I|$ and the determinant
  $|\det R - 1|$ of a rotation block, the bottom rows against $[0, I]$, a product's blocks off the diagonal, a
  :class:`MatrixGroup`'s rule or exp/log round trip), naming ``M``, the defect and its size; every filter's
  ``init`` refuses a NaN element and one whose :meth:`~LieGroup.defects` exceed it (the norm of a stored unit
  vector: (cos, sin), the quaternion). Under tracing, ``from_matrix`` converts only.
"""

from ._base import LieGroup
from ._matrix import SL3, MatrixGroup, Sim3
from ._product import Product
from ._rn import R1, R2, R3, Rn
from ._se2 import SE2
from ._se3 import SE3
from ._se23 import SE23
from ._sek3 import SEK3
from ._so2 import SO2
from ._so3 import SO3

TSE2 = Product[SE2, R3]
"""TSE(2) = SE(2) x R^3: planar pose and body velocities (Rigo et al. 2022)."""
TSO3 = Product[SO3, R3]
"""TSO(3) = SO(3) x R^3: attitude and body angular velocity (Saccon et al. 2016, Sec. V)."""
SE2R2 = Product[SE2, R2]
"""SE(2) x R^2: pose with (omega, v) of the Chaplygin sleigh (Rigo et al. 2023)."""
SO2R1 = Product[SO2, R1]
"""SO(2) x R: angle and gyro bias (Zamani et al.)."""

__all__ = ["LieGroup", "SO2", "SO3", "SE2", "SE3", "SE23", "SEK3", "MatrixGroup", "SL3", "Sim3", "Rn", "R1", "R2",
           "R3", "Product", "TSE2", "TSO3", "SE2R2", "SO2R1"]
