"""XLA's compiled programs kept on disk for the command line (``liemef._cachedirs.ProgramCache``, installed by
``liemef._config`` through ``liemef._jax.keep_programs``): whole entries or none, damaged ones recompiled, a
bounded folder, a second process that loads what the first compiled, and never over the user's own cache."""

import json
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import liemef._jax as adapter
from liemef import cli
from liemef._cachedirs import ProgramCache


def test_an_entry_is_read_back_whole_and_a_new_write_replaces_it(tmp_path):
    """JAX writes a program after compiling it: the entry was absent, or it did not serve (a program this XLA
    cannot load), and the new one takes its place."""
    cache = ProgramCache(tmp_path)
    assert cache.get("k1") is None
    cache.put("k1", b"program one")
    assert cache.get("k1") == b"program one"
    cache.put("k1", b"another program")
    assert cache.get("k1") == b"another program"
    assert (cache.hits, cache.misses, cache.writes) == (2, 1, 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k1.xla"]  # no temporary file left


@pytest.mark.parametrize("damage", ["truncated", "flipped", "empty"])
def test_a_damaged_entry_is_removed_and_read_as_absent(tmp_path, damage):
    cache = ProgramCache(tmp_path)
    cache.put("k", b"x" * 100)
    f = tmp_path / "k.xla"
    data = f.read_bytes()
    f.write_bytes({"truncated": data[:-10], "flipped": data[:-1] + b"y", "empty": b""}[damage])
    assert cache.get("k") is None
    assert not f.exists()
    cache.put("k", b"x" * 100)  # compiled again, written again
    assert cache.get("k") == b"x" * 100


def test_the_folder_keeps_its_bound_by_dropping_the_least_recently_used(tmp_path):
    cache = ProgramCache(tmp_path, max_bytes=1000)
    for i in range(4):
        cache.put(f"k{i}", bytes(200))  # 232 bytes each with the digest
        os.utime(tmp_path / f"k{i}.xla", ns=(i * 10**9, i * 10**9))
    cache.get("k0")  # read now: the most recently used
    stale = tmp_path / ".tmp-cut"
    stale.write_bytes(b"partial")
    os.utime(stale, (time.time() - 7200, time.time() - 7200))
    fresh = tmp_path / ".tmp-writing"
    fresh.write_bytes(b"partial")
    cache.put("k4", bytes(200))  # 5 x 232 > 1000: down to 750, the least recently used first
    assert sorted(p.name for p in tmp_path.iterdir()) == [".tmp-writing", "k0.xla", "k3.xla", "k4.xla"]


def test_keys_are_file_names(tmp_path):
    cache = ProgramCache(tmp_path)
    for key in ("", "../k", "a/b", ".hidden"):
        with pytest.raises(ValueError, match="key: expected a file name"):
            cache.get(key)


def _python(code: str, env: dict) -> dict:
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                         timeout=300, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


PROGRAM = """
import json
import jax, jax.numpy as jnp
import liemef._config as c
y = [float(v) for v in jax.jit(lambda x: jnp.sin(x) * 2.0)(jnp.arange(3.0))]
p = c.PROGRAMS
print(json.dumps({"cache": None if p is None else [p.hits, p.writes], "y": y}))
"""


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "LIEMEF_XLA_CACHE")}
    env["LIEMEF_CACHE_DIR"] = str(tmp_path / "kernels")
    first = _python(PROGRAM, {**env, "LIEMEF_XLA_CACHE": "1"})
    second = _python(PROGRAM, {**env, "LIEMEF_XLA_CACHE": "1"})
    (_, writes1), (hits2, writes2) = first["cache"], second["cache"]
    assert writes1 >= 1 and hits2 >= writes1 and writes2 == 0, (first, second)
    assert first["y"] == second["y"]
    (folder,) = (tmp_path / "kernels").glob("xla-*")  # one per CPU
    assert oct(os.stat(folder).st_mode & 0o777) == "0o700" and len(list(folder.glob("*.xla"))) == writes1
    # not asked for, or the user's own cache: none of ours
    assert _python(PROGRAM, env)["cache"] is None
    assert _python(PROGRAM, {**env, "LIEMEF_XLA_CACHE": "1",
                             "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "theirs")})["cache"] is None
    assert _python(PROGRAM, {**env, "LIEMEF_XLA_CACHE": "1", "JAX_ENABLE_COMPILATION_CACHE": "false"})["cache"] is None


def test_a_process_that_has_compiled_keeps_its_choice(tmp_path):
    """JAX decides once whether a process has a persistent cache: after a compile, nothing is installed."""
    import jax

    jax.jit(lambda x: x + 1.0)(np.float64(1.0))
    assert adapter.keep_programs(ProgramCache(tmp_path), tmp_path) is False
    assert jax.config.jax_compilation_cache_dir != str(tmp_path)


def test_the_command_line_asks_for_it_unless_told_otherwise(monkeypatch):
    for preset, expected in ((None, "1"), ("0", "0")):
        if preset is None:
            monkeypatch.delenv("LIEMEF_XLA_CACHE", raising=False)
        else:
            monkeypatch.setenv("LIEMEF_XLA_CACHE", preset)
        with pytest.raises(SystemExit):
            cli.main(["--version"])
        assert os.environ["LIEMEF_XLA_CACHE"] == expected
