"""liemef's process-wide JAX configuration (:mod:`liemef._config`): float64, and XLA's depth-first CPU schedule,
which keeps jaxlib's batched LAPACK kernels from deadlocking on a machine of few cores."""

import os
import subprocess
import sys

import pytest

# Three independent batched 12x12 inverses of 4,000 matrices in one program, called 20 times: with XLA's
# concurrency-optimized schedule each takes a thread of the intra-op pool and waits there for tasks that no free
# thread runs (it hung in 4 runs of 4 on 2 cores); with the depth-first schedule it returns.
_PROGRAM = """
import os, jax, jax.numpy as jnp
{prelude}
print(os.environ.get("XLA_FLAGS", ""), flush=True)
xs = [jax.random.normal(jax.random.key(i), (4000, 12, 12)) + 12.0 * jnp.eye(12) for i in range(3)]
f = jax.jit(lambda *xs: [jnp.linalg.inv(x) for x in xs])
for _ in range(20):
    out = jax.block_until_ready(f(*xs))
print(out[-1].dtype, bool(jnp.all(jnp.isfinite(out[-1]))), flush=True)
"""


def _run(prelude, env_flags):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if env_flags is not None:
        env["XLA_FLAGS"] = env_flags
    # the timeout turns a deadlock into a failure; the program takes a few seconds
    return subprocess.run([sys.executable, "-c", _PROGRAM.format(prelude=prelude)], capture_output=True,
                          text=True, env=env, timeout=300)


def test_importing_liemef_keeps_batched_factorizations_from_deadlocking():
    out = _run("import liemef.groups", None)
    assert out.returncode == 0, out.stderr
    flags, result = out.stdout.splitlines()
    assert flags == "--xla_cpu_enable_concurrency_optimized_scheduler=false"
    assert result == "float64 True"


def test_a_users_xla_flags_are_kept_and_extended():
    out = _run("import liemef.groups", "--xla_cpu_multi_thread_eigen=false")
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0] == ("--xla_cpu_multi_thread_eigen=false "
                                          "--xla_cpu_enable_concurrency_optimized_scheduler=false")


@pytest.mark.parametrize("choice", ["true", "false"])
def test_a_users_own_schedule_is_left_alone(choice):
    """A user who names the scheduler flag keeps it (with "true", at the deadlock's risk: not run here)."""
    flag = f"--xla_cpu_enable_concurrency_optimized_scheduler={choice}"
    code = f"import os; os.environ['XLA_FLAGS'] = '{flag}'; import liemef.groups; print(os.environ['XLA_FLAGS'])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == flag


def test_a_backend_started_before_liemef_is_not_told_a_flag_it_would_ignore():
    """XLA reads its flags once: after JAX has computed anything, adding the flag would say what is not so."""
    code = ("import os, jax, jax.numpy as jnp; jnp.ones(2).sum(); import liemef.groups;"
            "print(repr(os.environ.get('XLA_FLAGS', '')))")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "''"
