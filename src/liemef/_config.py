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

With ``LIEMEF_XLA_CACHE=1`` (the command line sets it for its process and those it starts), XLA's compiled
programs are kept on disk in :func:`liemef._cachedirs.xla_dir`, every one however quick to compile, and a later
process loads them instead of compiling again (:class:`liemef._cachedirs.ProgramCache`). Building a system and
its filter runs some seventy small eager operations, each an XLA compile of its own on its first shapes: kept,
a second ``liemef run`` on a recording takes about 40 % less time. Never over the user's own choice (a
persistent cache of theirs, or JAX's cache turned off), and not where the folder is not private
(:func:`liemef._cachedirs.refusal`).
"""

import os

import jax

from ._cachedirs import XLA_CACHE, ProgramCache, refusal, xla_dir
from ._jax import backends_started, keep_programs

SCHEDULER = "xla_cpu_enable_concurrency_optimized_scheduler"
SCHEDULER_FLAG = f"--{SCHEDULER}=false"


def _keep_xla_cpu_depth_first() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if SCHEDULER in flags or backends_started():
        return
    os.environ["XLA_FLAGS"] = f"{flags} {SCHEDULER_FLAG}".strip()


_keep_xla_cpu_depth_first()
jax.config.update("jax_enable_x64", True)


def _keep_xla_programs() -> ProgramCache | None:
    if os.environ.get(XLA_CACHE) != "1":
        return None
    if jax.config.jax_compilation_cache_dir or not jax.config.jax_enable_compilation_cache:
        return None  # the user's own persistent cache, or none by the user's choice
    path, _ = refusal(xla_dir())
    if path is None:  # a folder others could write to: no cache (the kernel cache's warning names the folder)
        return None
    cache = ProgramCache(path)
    return cache if keep_programs(cache, path) else None


PROGRAMS = _keep_xla_programs()
"""This process's XLA program cache (None: none)."""

