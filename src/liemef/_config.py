"""Process-wide JAX configuration: liemef computes in float64 throughout, and XLA's CPU runtime keeps to the
memory-frugal (depth-first) schedule.

The schedule is a workaround for a deadlock in jaxlib's CPU LAPACK kernels (seen in jaxlib 0.10.2): a batched
LU, Cholesky or inverse splits its batch into tasks on XLA's intra-op thread pool (one thread per core) and
blocks until they finish. With the concurrency-optimized (breadth-first) schedule, independent batched
factorizations of one program run at once, each on a pool thread; on two cores they take both threads and wait
for tasks that no thread is left to run, forever. ``jax.jit(vmap(...))`` over trials, a filter's batched
factorizations in the Monte Carlo engine, and the UKF baselines' sigma points make such programs. Measured on 2
cores (jaxlib 0.10.2): with the default schedule, 2, 3 and 5 independent batched 12x12 inverses of 4,000
matrices, and 3 and 5 such Choleskys, hung in one program each (2 Choleskys did not), and the program of
``tests/test_config.py`` in 4 runs of 4; with the depth-first schedule none did.
``--xla_cpu_multi_thread_eigen=false`` alone did not help. The schedule orders XLA's buffers, not its
arithmetic: the numbers are the same bits (the pinned figures hold). ``tests/test_config.py`` runs the hanging
program in a subprocess.

XLA reads ``XLA_FLAGS`` once, when the CPU backend starts, so the flag is added only while no backend has
started, and never over a choice of the user's: an ``XLA_FLAGS`` that names
``xla_cpu_enable_concurrency_optimized_scheduler`` is left as it is.
"""

import os

import jax

from ._jax import backends_started

SCHEDULER = "xla_cpu_enable_concurrency_optimized_scheduler"
SCHEDULER_FLAG = f"--{SCHEDULER}=false"


def _keep_xla_cpu_depth_first() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if SCHEDULER in flags or backends_started():
        return
    os.environ["XLA_FLAGS"] = f"{flags} {SCHEDULER_FLAG}".strip()


_keep_xla_cpu_depth_first()
jax.config.update("jax_enable_x64", True)
