"""Where the test suite's time goes: a pytest plugin that times every XLA compile and every C compiler call,
by test file, and a summary of what it wrote.

Run the suite with it (both xdist workers load it; each writes its own JSON into the folder named by
``LIEMEF_SUITE_PROFILE``, default ``out/suite-profile``), then summarize::

    JAX_COMPILATION_CACHE_DIR=$PWD/.cache/jax LIEMEF_CACHE_DIR=$PWD/.cache/liemef PYTHONPATH=tools \\
        .venv/bin/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder -q -p suite_profile
    .venv/bin/python tools/suite_profile.py out/suite-profile

What it counts:

- XLA: each call of JAX's ``backend_compile_and_load`` (a program compiled, not loaded from a cache), by the
  program's name and by the innermost frame of liemef or of the tests that asked for it;
- C: the time C compiler subprocesses (cc, gcc, clang) took to answer, from any thread. The kernels' -O2
  builds run in a background thread beside the tests, so a file's C time can exceed its own run time;
- C translation: the time liemef's kernels took to translate their traced interval into C (Python), in any
  thread, and how many kernels did.

It wraps a private function of JAX (``jax._src.compiler.backend_compile_and_load``, as in the JAX this project
installs): where another JAX lacks it, the plugin says so and times the C compilers only.
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
import time
import traceback
from pathlib import Path

OUT_ENV = "LIEMEF_SUITE_PROFILE"
COMPILERS = ("cc", "gcc", "clang")
_STATS = {key: collections.Counter() for key in ("xla_s", "xla_n", "site_s", "site_n", "file_xla_s",
                                                  "file_xla_n", "file_c_s", "file_tr_s", "file_tr_n", "file_s")}
_CURRENT = {"file": "(collection)"}


def _site() -> str:
    """The innermost frame of liemef or of the tests in the current stack, as ``path:line:function``."""
    for frame in reversed(traceback.extract_stack()[:-3]):
        name = frame.filename.replace(os.sep, "/")
        for marker in ("/src/liemef/", "/site-packages/liemef/", "/tests/"):
            if marker in name:
                return f"{marker.strip('/').split('/')[-1]}/{name.split(marker)[-1]}:{frame.lineno}:{frame.name}"
    return "(elsewhere)"


def _timed_xla(original):
    def backend_compile_and_load(backend, module, *args, **kwargs):
        start = time.perf_counter()
        try:
            return original(backend, module, *args, **kwargs)
        finally:
            seconds = time.perf_counter() - start
            try:
                name = str(module.operation.attributes["sym_name"]).strip('"')
            except Exception:  # noqa: BLE001 (a module of another shape: counted, unnamed)
                name = "(unnamed)"
            site, file = _site(), _CURRENT["file"]
            for key, label in (("xla", name), ("site", site), ("file_xla", file)):
                _STATS[f"{key}_s"][label] += seconds
                _STATS[f"{key}_n"][label] += 1
    return backend_compile_and_load


def _timed_communicate(original):
    def communicate(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            argv = self.args if isinstance(self.args, list | tuple) else str(self.args).split()
            if argv and Path(str(argv[0])).name in COMPILERS:
                _STATS["file_c_s"][_CURRENT["file"]] += time.perf_counter() - start
    return communicate


def _timed_translate(original):
    def _translate(*args, **kwargs):
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            _STATS["file_tr_s"][_CURRENT["file"]] += time.perf_counter() - start
            _STATS["file_tr_n"][_CURRENT["file"]] += 1
    return _translate


def pytest_configure(config):
    try:
        from jax._src import compiler
        compiler.backend_compile_and_load = _timed_xla(compiler.backend_compile_and_load)
    except (ImportError, AttributeError) as exc:
        print(f"suite_profile: XLA compiles not timed ({exc})", file=sys.stderr)
    subprocess.Popen.communicate = _timed_communicate(subprocess.Popen.communicate)
    from liemef.codegen import _kernel
    _kernel._translate = _timed_translate(_kernel._translate)


def pytest_runtest_protocol(item, nextitem):
    _CURRENT["file"] = item.path.name


def pytest_runtest_logreport(report):
    _STATS["file_s"][Path(report.fspath).name] += report.duration


def pytest_sessionfinish(session):
    out = Path(os.environ.get(OUT_ENV, "out/suite-profile"))
    out.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    tmp = out / f".{worker}.json.tmp"
    tmp.write_text(json.dumps({key: dict(c.most_common()) for key, c in _STATS.items()}))
    tmp.replace(out / f"{worker}.json")


def summary(folder: Path, top: int = 30) -> str:
    """The workers' files of ``folder`` added up: totals, then the programs, sites and files that cost most."""
    files = sorted(folder.glob("*.json"))
    if not files:
        raise SystemExit(f"folder: expected the JSON files suite_profile writes, found none in {folder}")
    total = {key: collections.Counter() for key in _STATS}
    for path in files:
        for key, values in json.loads(path.read_text()).items():
            total[key].update(values)
    test_s, xla_s = sum(total["file_s"].values()), sum(total["xla_s"].values())
    lines = [f"{len(files)} worker(s): tests {test_s:.0f} s; XLA compiles {xla_s:.0f} s "
             f"({100 * xla_s / max(test_s, 1e-9):.0f} %, {sum(total['xla_n'].values())} programs); "
             f"C compilers {sum(total['file_c_s'].values()):.0f} s (any thread); kernels translated to C "
             f"{sum(total['file_tr_s'].values()):.0f} s ({sum(total['file_tr_n'].values())} kernels)"]
    for title, s_key, n_key in (("program", "xla_s", "xla_n"), ("asked from", "site_s", "site_n")):
        lines += ["", f"XLA compile s, count, {title}"]
        lines += [f"{s:8.1f} {total[n_key][k]:6d}  {k}" for k, s in total[s_key].most_common(top)]
    lines += ["", "file: test s, XLA compile s (count), C compiler s, C translation s (count)"]
    lines += [f"{s:8.1f} {total['file_xla_s'][k]:8.1f} ({total['file_xla_n'][k]:5d}) {total['file_c_s'][k]:8.1f} "
              f"{total['file_tr_s'][k]:8.1f} ({total['file_tr_n'][k]:4d})  {k}"
              for k, s in total["file_s"].most_common(top)]
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        raise SystemExit("usage: python tools/suite_profile.py FOLDER [TOP]")
    print(summary(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) == 3 else 30))
