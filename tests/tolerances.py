"""The suite's shared numerical tolerances, each with the reason for its size. A tolerance used by one test
only, for a reason that test states, stays beside it; one that several tests rely on belongs here."""

ROUNDOFF = 1e-12
"""Exact identities evaluated in float64 (group axioms, round trips, block structure)."""
NEAR_PI = 1e-9
"""Round trips near the cut locus (angle within 1e-6 of pi): conditioning of log there."""
FINITE_DIFF = 1e-6
"""Autodiff against central finite differences with step 1e-5 (truncation ~1e-10, cancellation ~1e-11/h)."""
CLOSED_FORM = 1e-9
"""Generic engine against the papers' printed closed forms at random states."""
SYMMETRY = 1e-10
"""Relative asymmetry |K - K^T| / |K| of the (0)-connection gain over a whole run."""
ON_GROUP = 1e-12
"""|R^T R - I| of estimates over a whole run."""
ODE_REFERENCE = 1e-8
"""Filter against an independent ODE solution (scipy solve_ivp at rtol 1e-12) at the step sizes used."""
SLOPE = 0.15
"""Integrator convergence slope against the declared order."""
STEADY_STATE = 1e-9
"""Riccati gain after a long run (transient decayed below 1e-12) against scipy's solve_continuous_are."""
SECOND_FINITE_DIFF = 1e-6
"""Mixed second derivatives by central differences with step 1e-4 (truncation ~1e-8, cancellation ~1e-16/h^2)."""
SUBSTEP_RK4 = 1e-9
"""A Riccati solution integrated by RK4 sub-steps with |K E| h <= 0.02 (local error ~(|K E| h)^5), against its
closed form (information added over an interval)."""
MARGINAL = 1e-10
"""A filter with a missing correlated component against the filter of the marginal: the two form the same
information through different inverses (condition number of D ~10)."""
DISCRETE_KALMAN = 1e-6
"""Sparse samples on a linear system against the exact discrete Kalman filter, with 1000 RK4 sub-steps per
interval and the sample's information spread over 2^-30 s (both errors ~1e-9)."""
EXPORTED_C = 1e-12
"""The exported C99 step (liemef.codegen) against the JAX step at one state, relative to max(1, |value|): the same
operations, with libm's sin/cos/sqrt against XLA's and other summation orders (measured <= 1e-13)."""
EXPORTED_C_RUN = 1e-9
"""A C program's estimates (examples/export_c, its own build and a CSV round trip) against the JAX run over a few
hundred intervals: EXPORTED_C's round-off carried along a trajectory the filter contracts (measured 1e-15)."""
WELL_CONDITIONED = 1e-13
"""A random state counts as well conditioned for the exported-C comparison when a relative change of K by 1e-15
moves the JAX step's result by at most this: round-off then cannot reach EXPORTED_C."""
ENGINES = 1e-10
"""The C engine's run against the XLA engine's over a log of about a hundred intervals, relative to max(1, |value|):
the same operations, libm against XLA's sin/cos/sqrt and other summation orders, carried along a trajectory the
filter contracts (measured <= 1e-13)."""
PRIMITIVE_C = 1e-10
"""A small function's value, Jacobian and Hessian in C (tests/test_jaxpr_c_primitives.py) against XLA's, relative
to max(1, |value|): the same operations in another order (sums, Pade and squaring in expm, pivots in LU); measured
<= 1e-13 on all but expm's Hessian (~1e-12)."""
USER_SYSTEM_C = 1e-10
"""A user's system run by the C engine against the XLA engine over a short log, relative to max(1, |value|)."""
