r"""Truth and sensor simulation with explicit random keys.

:func:`simulate` integrates a system's truth on its group and samples noisy inputs and measurements; it is
the checked entry point. :func:`simulate_core` is its traceable core (no checks), written so that a batch of
independent trials is ``jax.vmap(lambda k: simulate_core(system, g0, input_fn, ts, k, ...))(keys)``.
"""

from ._simulate import SensorLog, Truth, simulate, simulate_core

__all__ = ["simulate", "simulate_core", "Truth", "SensorLog"]
