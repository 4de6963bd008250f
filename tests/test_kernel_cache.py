"""The C engine's kernel cache can be trusted (issue 19, item 1): nothing planted in it runs or is used.

A constructor library, a truncated one, a zero-byte one, random bytes and another filter's kernel (with its
manifest, renamed) are planted at the names the next process will look for. Each planted case runs in a
subprocess (a crash must not take pytest with it), which must exit 0 with the XLA engine's numbers, without
the constructor's marker file, after rebuilding every planted file into the genuine library. A cache folder
that is not the user's or is writable by group or others is refused, with an ``EngineWarning``, and nothing in
it is read. Without a C compiler, ``engine="auto"`` warns and runs XLA.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef import codegen
from liemef.codegen import _cache, _elf, _kernel
from liemef.engines import EngineWarning
from liemef.groups import Rn
from liemef.systems import Noise, Sensor, SensorSystem
from tolerances import ENGINES

pytestmark = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")

SRC = str(Path(liemef.__file__).resolve().parents[1])

def _drift(g, u, t):
    return jnp.array([g.x[1], -0.1 * g.x[1] + u[0]])


def _tiny_filter(which: str = "a"):
    """A small filter ("a": one sensor; "b": two, so another kernel) and a log for it."""
    sensors = (Sensor("p", lambda g, t: g.x[:1], Noise.sample(0.3)),)
    if which == "b":
        sensors += (Sensor("v", lambda g, t: g.x[1:], Noise.sample(0.2)),)
    flt = liemef.MinimumEnergyFilter(SensorSystem(Rn[2], _drift, sensors, Noise.density([0.1, 0.2]), inputs=("a",)))
    ts = 0.01 * np.arange(60)
    ys = np.stack([np.cos(ts), -np.sin(ts)][:len(sensors)], axis=1)
    return flt, (flt.init(Rn[2](jnp.array([0.5, -0.2])), np.eye(2)), ts, np.sin(ts)[:, None], ys)


def _batch(args, B=4):
    """The log's trials for run_batch: B copies of the state, inputs and outputs scaled per trial."""
    state, ts, us, ys = args
    scale = (1.0 + 0.1 * np.arange(B))[:, None, None]
    return jax.tree_util.tree_map(lambda a: np.stack([np.asarray(a)] * B), state), ts, scale * us, scale * ys


# A process that, for each cache folder it is given in turn, builds or finds filter a's kernels there (the
# in-process cache emptied), runs the log and a batch of 4 trials (the batch kernel) by C, and prints what it saw
CHILD = textwrap.dedent("""
    import json, os, sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from test_kernel_cache import _batch, _tiny_filter
    from liemef.codegen import _kernel

    for folder in json.loads(sys.argv[2]):
        os.environ["LIEMEF_CACHE_DIR"] = folder
        _kernel._KERNELS.clear()
        flt, args = _tiny_filter()
        kern = _kernel.kernel_for(flt)
        quick_first = not kern.optimized
        kern.wait()
        c, cb = flt.run(*args, engine="c"), flt.run_batch(*_batch(args), engine="c")
        print(json.dumps({"folder": folder, "quick_first": quick_first, "optimized": kern.optimized,
                          "optimize_error": kern.optimize_error, "lanes": kern.lanes() is not None,
                          "ok": bool(c.status.ok), "x": np.asarray(c.g_hat.x).tolist(), "K": np.asarray(c.K).tolist(),
                          "xb": np.asarray(cb.g_hat.x).tolist(), "Kb": np.asarray(cb.K).tolist()}), flush=True)
""")

CONSTRUCTOR = """
#include <stdio.h>
__attribute__((constructor)) static void planted(void)
{
    FILE *f = fopen("%s", "w");
    if (f != NULL) { fputs("the planted library ran\\n", f); fclose(f); }
}
int kernel_scan(void) { return 0; }
int kernel_step(void) { return 0; }
void kernel_batch(void) {}
void lanes_batch(void) {}
"""

KINDS = {"quick": _kernel.QUICK_CFLAGS, "kernel": _kernel.KERNEL_CFLAGS, "lanes": _kernel.LANE_CFLAGS}


def _genuine(which: str, cache: Path, monkeypatch) -> None:
    """Build filter ``which``'s three libraries into ``cache``, as an honest process does."""
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(cache))
    tr = _kernel._trace(_tiny_filter(which)[0])
    for kind, flags in KINDS.items():
        _kernel._build(tr, flags, kind)


def _libraries(cache: Path) -> dict[str, Path]:
    """A filter's three libraries in a cache folder, by kind."""
    found = {p.name.split("_", 1)[0]: p for p in cache.glob("*.so")}
    assert sorted(found) == sorted(KINDS), sorted(cache.iterdir())
    return found


def _compile_constructor(root: Path) -> tuple[Path, Path]:
    """A real shared library whose constructor writes a marker file, and the marker's path; loaded directly
    (in a subprocess) it does write the marker, so that its absence below means it never ran."""
    marker = root / "marker.txt"
    src = root / "planted.c"
    src.write_text(CONSTRUCTOR % marker)
    lib = root / "planted.so"
    subprocess.run([codegen.compiler(), "-shared", "-fPIC", "-o", str(lib), str(src)], check=True)
    subprocess.run([sys.executable, "-c", f"import ctypes; ctypes.CDLL({str(lib)!r})"], check=True)
    assert marker.read_text() == "the planted library ran\n"
    marker.unlink()
    return lib, marker


@pytest.fixture(scope="module")
def constructor_library(tmp_path_factory):
    return _compile_constructor(tmp_path_factory.mktemp("constructor"))


def _plant(case: str, cache: Path, other: Path, constructor: Path) -> list[str]:
    """Plant ``case`` in ``cache`` (a copy of filter a's genuine cache; ``other``: filter b's); the kinds
    planted."""
    libs = _libraries(cache)
    if case == "constructor":  # the genuine manifests left beside: their hashes do not match
        for lib in libs.values():
            shutil.copyfile(constructor, lib)
        return list(libs)
    if case == "constructor without manifests":  # as a cache of a liemef before manifests
        for lib in libs.values():
            shutil.copyfile(constructor, lib)
            _cache.manifest_path(lib).unlink()
        return list(libs)
    if case == "truncated":  # the genuine library cut in half, its genuine manifest beside
        for kind in ("kernel", "lanes"):
            data = libs[kind].read_bytes()
            libs[kind].write_bytes(data[:len(data) // 2])
        return ["kernel", "lanes"]
    if case == "truncated with a matching manifest":  # cut to 4 KiB, the manifest rewritten to match (SIGBUS before)
        for lib in libs.values():
            _cut_and_vouch(lib, 4096)
        return list(libs)
    if case == "zero bytes":
        for kind in ("kernel", "lanes"):
            libs[kind].write_bytes(b"")
        return ["kernel", "lanes"]
    if case == "random bytes":
        rng = np.random.default_rng(19)
        for kind in ("kernel", "lanes"):
            libs[kind].write_bytes(rng.integers(0, 256, 30000, dtype=np.uint8).tobytes())
        return ["kernel", "lanes"]
    if case == "another filter's kernel":  # b's libraries, with b's manifests edited to name a's files
        theirs = _libraries(other)
        for kind in ("kernel", "lanes"):
            shutil.copyfile(theirs[kind], libs[kind])
            man = json.loads(_cache.manifest_path(theirs[kind]).read_text())
            man["file"] = libs[kind].name
            _cache.manifest_path(libs[kind]).write_text(json.dumps(man))
        return ["kernel", "lanes"]
    raise AssertionError(case)


def _cut_and_vouch(lib: Path, size: int) -> None:
    """Cut the library at ``lib`` to ``size`` bytes and rewrite its manifest to match (the user's own files)."""
    data = lib.read_bytes()[:size]
    lib.write_bytes(data)
    man = json.loads(_cache.manifest_path(lib).read_text())
    man.update(size=len(data), sha256=hashlib.sha256(data).hexdigest())
    _cache.manifest_path(lib).write_text(json.dumps(man))


CASES = ["constructor", "constructor without manifests", "truncated", "truncated with a matching manifest",
         "zero bytes", "random bytes", "another filter's kernel"]


@pytest.fixture(scope="module")
def planted(tmp_path_factory, constructor_library):
    """Every case planted in its own copy of a genuine cache, then one child process run over them all (a
    crash, as a truncated library's SIGBUS, kills the child, not pytest): per case, the child's report, the
    folder, the genuine bytes and the kinds planted."""
    constructor, _ = constructor_library
    root = tmp_path_factory.mktemp("planted")
    with pytest.MonkeyPatch.context() as mp:
        for which in ("a", "b"):
            _genuine(which, root / which, mp)
    want = {kind: lib.read_bytes() for kind, lib in _libraries(root / "a").items()}
    out = {}
    for i, case in enumerate(CASES):
        cache = root / f"case{i}"
        shutil.copytree(root / "a", cache)
        kinds = _plant(case, cache, root / "b", constructor)
        assert all(_libraries(cache)[kind].read_bytes() != want[kind] for kind in kinds)
        out[case] = [cache, kinds]
    env = dict(os.environ, LIEMEF_ENGINE="auto",
               PYTHONPATH=os.pathsep.join([SRC] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    res = subprocess.run([sys.executable, "-c", CHILD, str(Path(__file__).parent),
                          json.dumps([str(out[c][0]) for c in CASES])],
                         capture_output=True, text=True, env=env, timeout=900)
    reports = {json.loads(line)["folder"]: json.loads(line) for line in res.stdout.splitlines()
               if line.startswith("{")}
    return {case: (reports.get(str(cache)), cache, want, kinds, res) for case, (cache, kinds) in out.items()}


@pytest.mark.parametrize("case", CASES)
def test_a_planted_library_is_never_run_or_used_and_is_rebuilt(case, planted, constructor_library):
    got, cache, want, kinds, res = planted[case]
    _, marker = constructor_library
    assert got is not None, f"the child died ({res.returncode}):\n{res.stderr[-3000:]}"
    assert "Traceback" not in res.stderr and res.returncode == 0, res.stderr[-3000:]
    assert not marker.exists()
    assert got["ok"] and got["optimized"] and got["optimize_error"] is None and got["lanes"]
    flt, args = _tiny_filter()  # the numbers of the filter's own kernel: the XLA engine's
    x, xb = flt.run(*args, engine="xla"), flt.run_batch(*_batch(args), engine="xla")
    for key, ref in (("x", x.g_hat.x), ("K", x.K), ("xb", xb.g_hat.x), ("Kb", xb.K)):
        np.testing.assert_allclose(np.array(got[key]), np.asarray(ref), rtol=0, atol=ENGINES)
    assert got["quick_first"] == ("kernel" in kinds)  # a refused -O2 kernel: built again, a quick one serving
    if case == "truncated with a matching manifest":  # each named, with its defect, and rebuilt
        for lib in _libraries(cache).values():
            assert re.search(rf"EngineWarning: the cached library {re.escape(str(lib))} matches its manifest but "
                             r"cannot be loaded: segment \d+ \(PT_LOAD\) ends at byte \d+, past the end of the "
                             r"file \(4096 bytes\)\. It is rebuilt", res.stderr), res.stderr[-3000:]
    for kind, lib in _libraries(cache).items():  # each planted file rebuilt: it passes its check again
        assert _cache.read_verified(lib, json.loads(_cache.manifest_path(lib).read_text())["key"], kind) is not None
        assert lib.read_bytes() == want[kind]  # the very bytes of the genuine build (builds are reproducible)
        assert stat.S_IMODE(lib.stat().st_mode) == 0o600
    assert not [p for p in cache.iterdir() if p.name.startswith(".")]  # no build folder or loaded copy left


def test_every_cut_of_a_genuine_library_is_refused_before_it_is_mapped(planted):
    """The ELF check passes the three libraries a build makes and refuses each of them cut at every length
    (a library cut short would raise SIGBUS once mapped), naming the defect."""
    want = planted[CASES[0]][2]
    for kind, data in want.items():
        assert _elf.defect(data) is None, kind
        cuts = [_elf.defect(data[:n]) for n in range(len(data))]
        assert all(cuts), (kind, cuts.index(None))
        assert any("past the end of the file" in why for why in cuts)


def test_a_new_cache_folder_is_private(tmp_path, monkeypatch):
    """Created 0700 whatever the umask; libraries and manifests written 0600."""
    cache = tmp_path / "deep" / "kernels"
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(cache))
    old = os.umask(0)
    try:
        assert _cache.folder() == cache.resolve()
    finally:
        os.umask(old)
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    flt, _ = _tiny_filter()
    tr = _kernel._trace(flt)
    lib = _kernel._build(tr, _kernel.QUICK_CFLAGS, "quick")
    assert lib.path.parent == cache.resolve()
    for p in (lib.path, _cache.manifest_path(lib.path)):
        assert stat.S_IMODE(p.stat().st_mode) == 0o600
    man = json.loads(_cache.manifest_path(lib.path).read_text())
    assert man["key"] == tr.key and man["kind"] == "quick" and man["size"] == len(lib.data)


def _foreign(path: Path, monkeypatch) -> int:
    """Make ``path`` another user's: chown where allowed (root), else pretend to be another user."""
    if os.geteuid() == 0:
        os.chown(path, 65534, 65534)
        return 65534
    owner = path.stat().st_uid
    monkeypatch.setattr(_cache.os, "geteuid", lambda: owner + 1)
    return owner


@pytest.mark.parametrize("how", ["group-writable", "world-writable", "foreign", "a file", "loose parent"])
def test_an_unsafe_cache_folder_is_refused_and_never_read(how, tmp_path, monkeypatch, constructor_library):
    """An existing cache folder that is another user's, writable by group or others, not a folder, or in a
    parent writable by others without the sticky bit, is not used: an EngineWarning names it and why, the
    kernels are built into a private temporary folder, and nothing in the refused one is read, even a library
    with a forged manifest that would pass the check."""
    constructor, marker = constructor_library
    flt, args = _tiny_filter()
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(tmp_path / "name"))
    tr = _kernel._trace(flt)
    names = {kind: _kernel._library(tr, flags, kind).name
             for kind, flags in (("quick", _kernel.QUICK_CFLAGS), ("kernel", _kernel.KERNEL_CFLAGS))}
    cache = tmp_path / "shared" / "kernels"
    cache.mkdir(parents=True)
    for kind, name in names.items():  # the planted library, with a manifest forged to pass the check
        data = constructor.read_bytes()
        _cache.install(cache / name, data, tr.key, kind, {})
    expect = {"group-writable": r"writable by group \(mode 0770\)",
              "world-writable": r"writable by group and others \(mode 0777\)",
              "foreign": "owned by uid", "a file": "not a folder",
              "loose parent": r"its parent .*shared is writable by others without the sticky bit \(mode 0703\)"}[how]
    target = cache
    if how == "group-writable":
        os.chmod(cache, 0o770)
    elif how == "world-writable":
        os.chmod(cache, 0o777)
    elif how == "foreign":
        _foreign(cache, monkeypatch)
    elif how == "a file":
        target = tmp_path / "shared" / "a-file"
        target.write_bytes(b"")
    else:
        os.chmod(cache.parent, 0o703)
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(target))
    real, why = _cache.refusal(target)
    assert real is None and why is not None
    with pytest.warns(EngineWarning, match=f"the kernel cache {re.escape(str(target))} is not used: .*{expect}"):
        c = flt.run(*args, engine="c")
    kern = _kernel.kernel_for(flt).wait()
    assert kern.path.parent != target and kern.path.parent.name.startswith("liemef-kernels-")
    assert stat.S_IMODE(kern.path.parent.stat().st_mode) == 0o700
    assert not marker.exists()
    x = flt.run(*args, engine="xla")
    np.testing.assert_allclose(np.asarray(c.g_hat.x), np.asarray(x.g_hat.x), rtol=0, atol=ENGINES)
    if how != "a file":
        assert sorted(p.name for p in cache.glob("*.so")) == sorted(names.values())  # untouched
    os.chmod(cache.parent, 0o755)


def test_a_safe_parent_with_the_sticky_bit_is_accepted(tmp_path):
    """A folder of the user's in a parent writable by all but sticky (as /tmp): no one else can replace it."""
    parent = tmp_path / "tmp-like"
    parent.mkdir()
    os.chmod(parent, 0o1777)
    real, why = _cache.refusal(parent / "kernels")
    assert why is None and real == (parent / "kernels").resolve()


@pytest.fixture(scope="module")
def small_library(tmp_path_factory) -> bytes:
    """The bytes of a small genuine shared library (one function), as the compiler makes it."""
    root = tmp_path_factory.mktemp("small")
    (root / "small.c").write_text("int small(int x) { return x + 1; }\n")
    subprocess.run([codegen.compiler(), "-shared", "-fPIC", "-o", str(root / "small.so"), str(root / "small.c")],
                   check=True)
    return (root / "small.so").read_bytes()


def test_links_fifos_and_foreign_files_fail_the_check(tmp_path, monkeypatch, small_library):
    """read_verified opens without following a link and without blocking on a FIFO, and takes only the
    user's regular files: each of these makes a library that is rebuilt, never read."""
    cache = tmp_path / "c"
    cache.mkdir(mode=0o700)
    good = _cache.install(cache / "kernel_x.so", small_library, "k", "kernel", {})
    assert _cache.read_verified(good.path, "k", "kernel") == good
    assert _cache.read_verified(good.path, "other key", "kernel") is None
    assert _cache.read_verified(good.path, "k", "lanes") is None
    link = cache / "kernel_y.so"
    link.symlink_to(good.path)
    shutil.copyfile(_cache.manifest_path(good.path), _cache.manifest_path(link))
    man = json.loads(_cache.manifest_path(link).read_text())
    man["file"] = link.name
    _cache.manifest_path(link).write_text(json.dumps(man))
    os.chmod(_cache.manifest_path(link), 0o600)
    assert _cache.read_verified(link, "k", "kernel") is None
    fifo = cache / "kernel_z.so"
    os.mkfifo(fifo)
    shutil.copyfile(_cache.manifest_path(link), _cache.manifest_path(fifo))
    assert _cache.read_verified(fifo, "k", "kernel") is None  # and it returned: no blocking open
    os.chmod(good.path, 0o666)
    assert _cache.read_verified(good.path, "k", "kernel") is None
    os.chmod(good.path, 0o600)
    _foreign(good.path, monkeypatch)
    assert _cache.read_verified(good.path, "k", "kernel") is None


def test_auto_without_a_compiler_warns_and_runs_xla(monkeypatch):
    """engine="auto" with no C compiler: an EngineWarning saying so, and XLA's numbers; "c" raises."""
    from liemef.engines import _select

    monkeypatch.setattr(_select, "_no_compiler", lambda: True)
    flt, args = _tiny_filter()
    with pytest.warns(EngineWarning, match=r"no C compiler found.*running with XLA"):
        auto = flt.run(*args, engine="auto")
    x = flt.run(*args, engine="xla")
    np.testing.assert_array_equal(np.asarray(auto.g_hat.x), np.asarray(x.g_hat.x))
    with pytest.raises(RuntimeError, match="no C compiler"):
        flt.run(*args, engine="c")
