"""The tutorials and the worked example of the weights page run as written and print what the pages say.

Each ```python block of ``docs/tutorial.md``, ``docs/tutorial-3d.md``, ``docs/tutorial-smoothing.md`` (with the real
recordings) and ``docs/weights.md`` is executed in order
in one namespace, in a temporary folder, except a block titled as a file (```python title="name.py"), which the
reader saves: it is written to that file, importable by the later blocks. A ```text block right after a code block
is the output the page shows; the captured output must match it line by line, words exactly and numbers within 2 %
or one unit of their last printed digit. A page whose code or numbers drift fails here. The tutorial's ``liemef run
--system-file`` command runs too, and its output is compared the same way.

``python tests/test_tutorial.py docs/tutorial.md`` prints each block's actual output (to update a page).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
WEIGHTS = ROOT / "docs" / "weights.md"
TUTORIAL_3D = ROOT / "docs" / "tutorial-3d.md"
TUTORIAL_SMOOTHING = ROOT / "docs" / "tutorial-smoothing.md"

_BLOCK = re.compile(r"^```python([^\n]*)\n(.*?)^```[ \t]*\n(?:[ \t]*\n)*(?:^```text[ \t]*\n(.*?)^```)?", re.S | re.M)
_TITLE = re.compile(r'title="([^"]+)"')
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?%?")
REL_TOL = 0.02
"""Relative tolerance of a printed number (JAX's float64 reductions may differ across machines in the last
digits; a drifted page differs by far more)."""


def blocks(page: Path) -> list[tuple[str | None, str, str | None]]:
    """The page's ```python blocks: (file title or None, code, the ```text block that follows it or None)."""
    text = page.read_text() if page.exists() else ""
    out = []
    for info, code, shown in _BLOCK.findall(text):
        title = _TITLE.search(info)
        out.append((title.group(1) if title else None, code, shown or None))
    return out


def run_blocks(page: Path) -> tuple[dict, list[tuple[str, str | None, str]]]:
    """Execute the page's blocks in order in one namespace, in the current folder (a titled block is written to
    its file instead, importable from there); returns the namespace and (code, shown, printed) per block."""
    # one module, as a reader's script is (a class the page defines is a dataclass of it), compiled without this
    # file's ``from __future__ import annotations``
    module = types.ModuleType("__docs__")
    namespace: dict = module.__dict__
    results, files = [], []
    sys.path.insert(0, os.getcwd())
    sys.modules["__docs__"] = module
    try:
        for title, code, shown in blocks(page):
            buf = io.StringIO()
            if title is not None:
                Path(title).write_text(code)
                files.append(Path(title).stem)
            else:
                with contextlib.redirect_stdout(buf):
                    exec(compile(code, str(page), "exec", dont_inherit=True), namespace)  # noqa: S102
            results.append((code, shown, buf.getvalue()))
    finally:
        sys.modules.pop("__docs__", None)
        sys.path.remove(os.getcwd())
        for name in files:
            sys.modules.pop(name, None)
    return namespace, results


def _same_number(printed: str, shown: str) -> bool:
    pct = shown.endswith("%")
    if pct != printed.endswith("%"):
        return False
    a, b = float(printed.rstrip("%")), float(shown.rstrip("%"))
    digits = shown.rstrip("%").split("e")[0].split("E")[0]
    decimals = len(digits.split(".")[1]) if "." in digits else 0
    exponent = int(re.split("[eE]", shown.rstrip("%"))[1]) if re.search("[eE]", shown) else 0
    last_digit = 10.0 ** (exponent - decimals)
    return math.isclose(a, b, rel_tol=REL_TOL, abs_tol=1.01 * last_digit)


def assert_output_matches(printed: str, shown: str, where: str) -> None:
    """Words equal, numbers within tolerance, line by line (trailing blanks ignored)."""
    got, want = printed.rstrip().splitlines(), shown.rstrip().splitlines()
    assert len(got) == len(want), f"{where}: printed {len(got)} lines, the page shows {len(want)}:\n{printed}"
    for g, w in zip(got, want, strict=True):
        g_words, w_words = _NUMBER.split(g.rstrip()), _NUMBER.split(w.rstrip())
        g_nums, w_nums = _NUMBER.findall(g), _NUMBER.findall(w)
        ok = g_words == w_words and len(g_nums) == len(w_nums) and all(
            _same_number(a, b) for a, b in zip(g_nums, w_nums, strict=True))
        assert ok, f"{where}: printed\n  {g}\nthe page shows\n  {w}"


def check_page(page: Path, tmp_path: Path, monkeypatch) -> dict:
    monkeypatch.chdir(tmp_path)
    namespace, results = run_blocks(page)
    assert results, f"{page.name}: no ```python blocks"
    for i, (_code, shown, printed) in enumerate(results):
        if shown is not None:
            assert_output_matches(printed, shown, f"{page.name}, code block {i + 1}")
    return namespace


# --- the tutorial ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tutorial(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tutorial")
    with pytest.MonkeyPatch.context() as mp:
        ns = check_page(TUTORIAL, tmp, mp)
    return ns, tmp


def test_tutorial_runs_and_prints_what_it_shows(tutorial):
    ns, _ = tutorial
    assert ns["traj"].status.ok
    assert ns["system"].group.__name__ == "SE2"
    # the gate caught the outlier and nothing else; without it the run is spoiled
    assert int(ns["gated"].status.rejected[0]) == 1
    assert ns["rms_gated"][1] < 1.2 * ns["rms_ok"][1] < ns["rms_bad"][1]
    assert all(r.status.ok for r in ns["runs"]) and len(ns["runs"]) == 20


def test_tutorial_writes_the_system_file_and_the_csv_log(tutorial):
    _, tmp = tutorial
    assert [t for t, _, _ in blocks(TUTORIAL) if t] == ["tutorial_system.py"]
    assert (tmp / "tutorial_system.py").is_file()
    assert (tmp / "log.csv").read_text().splitlines()[0] == "t,v_x,v_y,omega,gps_x,gps_y"


def _cli_has_system_file() -> bool:
    liemef = Path(sys.executable).parent / "liemef"
    out = subprocess.run([str(liemef), "run", "--help"], capture_output=True, text=True, timeout=120)
    return "--system-file" in out.stdout


@pytest.mark.slow  # a subprocess that imports JAX and compiles the localization filter again: 30 s
def test_tutorial_cli_run_on_the_csv_log(tutorial):
    if not _cli_has_system_file():
        pytest.skip("liemef run --system-file is not available yet")
    _, tmp = tutorial
    cmd = re.search(r"^```sh\n(liemef run --system-file[^\n]*)\n```\s*\n```text\n(.*?)^```", TUTORIAL.read_text(),
                    re.M | re.S)
    assert cmd, "docs/tutorial.md: no ```sh block with the liemef run --system-file command and its output"
    args = cmd.group(1).split()
    proc = subprocess.run([str(Path(sys.executable).parent / "liemef"), *args[1:]], cwd=tmp, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert_output_matches(proc.stdout, cmd.group(2), "docs/tutorial.md, the liemef run block")
    out = tmp / args[args.index("--out") + 1]
    assert (out / "metrics.json").is_file()


# --- the worked example of the weights page -------------------------------------------------------------------
def test_weights_worked_example_runs_and_prints_what_it_shows(tmp_path, monkeypatch):
    ns = check_page(WEIGHTS, tmp_path, monkeypatch)
    assert ns["traj"].status.ok


# --- the 3D tutorial -------------------------------------------------------------------------------------------
@pytest.mark.slow  # simulates 30 s at 100 Hz and builds two 9-dimensional filters: 1-3 min on 2 busy cores
def test_3d_tutorial_runs_and_prints_what_it_shows(tmp_path, monkeypatch):
    """The inertial-navigation page: the ready system converges from 20 deg and 2.3 m off, and the same model
    written as a user system gives the same estimates."""
    ns = check_page(TUTORIAL_3D, tmp_path, monkeypatch)
    assert ns["traj"].status.ok and ns["traj2"].status.ok
    assert ns["system"].group.__name__ == "SE23"
    e = ns["e"]
    import numpy as np

    assert np.degrees(np.linalg.norm(e[0, :3])) > 19.0  # it started far off
    assert np.abs(np.asarray(ns["traj2"].coords()) - np.asarray(ns["traj"].coords())).max() < 1e-9


# --- filter and smoother on a recording ---------------------------------------------------------------------------
@pytest.mark.slow  # a whole BROAD trial, filtered and smoothed: about 2 min on 2 busy cores
def test_smoothing_tutorial_runs_and_prints_what_it_shows(tmp_path, monkeypatch):
    """The smoothing page on BROAD trial 07: the filter runs, the smoother converges and beats it against the
    truth, with a smaller covariance."""
    from liemef.studies import datasets

    if datasets.realdata_dir() is None or "07" not in datasets.broad_trials():
        pytest.skip(f"real data absent: set {datasets.ENV_VAR} or provide ../shared/realdata beside the checkout")
    ns = check_page(TUTORIAL_SMOOTHING, tmp_path, monkeypatch)
    assert ns["traj"].status.ok and ns["sm"].status == "converged"
    import numpy as np

    from liemef.metrics import attitude_rms

    trial = ns["trial"]
    err = [attitude_rms(np.asarray(g.factors[0].wxyz), trial.quat_true, trial.movement)["total"]
           for g in (ns["traj"].g_hat, ns["sm"].g)]
    assert err[1] < 0.8 * err[0]
    # over the motion, the smoother's attitude covariance is the smaller (not at every sample: at the log's end
    # it is the filter's information linearized elsewhere, a few per cent apart)
    std = [np.median(np.trace(np.asarray(P)[trial.movement][:, :3, :3], axis1=1, axis2=2))
           for P in (ns["traj"].K, ns["sm"].P)]
    assert std[1] < 0.6 * std[0]


if __name__ == "__main__":
    import tempfile

    for arg in sys.argv[1:]:
        page = Path(arg).resolve()
        os.chdir(tempfile.mkdtemp())
        for i, (_code, _shown, printed) in enumerate(run_blocks(page)[1]):
            print(f"--- block {i + 1}\n{printed}", end="")
