"""Process-wide JAX configuration: liemef computes in float64 throughout."""

import jax

jax.config.update("jax_enable_x64", True)
