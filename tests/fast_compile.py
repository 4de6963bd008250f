"""XLA options for the suite's own compiled test functions: small programs compiled once and run once, whose
results are checked against tolerances, never bit for bit.

Compile time is most of these tests' run time. This option set skips XLA's expensive optimisations and its
fusion emitters and compiles such programs about 3x faster. It enables no fast-math, so every tolerance holds
unchanged; the bits may differ from a default compile in the last place, which is why the library's own
programs (and every bit-for-bit comparison of the suite) keep XLA's defaults.
"""

import jax
import numpy as np

FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True,
                "xla_cpu_use_fusion_emitters": False, "xla_cpu_parallel_codegen_split_count": 1}


def fast_jit(f):
    """``jax.jit(f)``, compiled (once per argument structure and shapes) with :data:`FAST_COMPILE`."""
    jitted, compiled = jax.jit(f), {}

    def call(*args):
        leaves, tree = jax.tree_util.tree_flatten(args)
        key = (tree, tuple((np.shape(x), str(np.asarray(x).dtype)) for x in leaves))
        if key not in compiled:
            compiled[key] = jitted.lower(*args).compile(compiler_options=FAST_COMPILE)
        return compiled[key](*args)

    return call
