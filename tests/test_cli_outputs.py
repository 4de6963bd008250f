"""Outputs complete or absent, and exit codes a script can trust (issue 19, items 3 and 4).

Every command that writes a folder writes it beside ``--out`` and renames it into place with a
``manifest.json``; a folder holding another command's files is refused (exit 2) unless ``--force``; a full disk
is exit 1 with a message and no partial set; Ctrl-C and SIGTERM are exit 130 with no temporary file left; a
Monte Carlo with no usable trial is exit 1 with ``failure.json`` alone. Each test asserts the exact exit code,
that no traceback is printed, and the state of ``--out`` afterwards. Most use a toy experiment (a tiny compile)
in place of ``tse2``.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from liemef.cli import cli
from liemef.metrics import FULL
from liemef.reports import io, outputs
from liemef.studies.compare import failures
from liemef.studies.experiments import EXPERIMENTS, TrialSpec

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class ToyConfig:
    seed: int = 0
    samples: int = 11
    nan_fraction: float = 0.0


def toy_errors(config: ToyConfig, key):
    k1, k2 = jax.random.split(key)
    e = 1.0 + jax.random.normal(k1, (config.samples, 2))
    return e.at[-1, 0].set(jnp.where(jax.random.uniform(k2) < config.nan_fraction, jnp.nan, e[-1, 0]))


def toy_trial(config: ToyConfig) -> TrialSpec:
    return TrialSpec(ts=np.linspace(0.0, 1.0, config.samples), names=("a", "b"), units=("m", "rad"), windows=(FULL,),
                     errors=lambda key: toy_errors(config, key))


def _no_run(config, key=None):
    raise NotImplementedError


@pytest.fixture
def toy(monkeypatch):
    """``tse2`` replaced by the toy experiment (the CLI's choices are the registry's names)."""
    monkeypatch.setitem(EXPERIMENTS, "tse2", dataclasses.replace(
        EXPERIMENTS["tse2"], default_config=ToyConfig(), run_fn=_no_run, trial_fn=toy_trial, quick_config=None))


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def montecarlo(out, *extra):
    return invoke("montecarlo", "tse2", "--runs", 4, "--batch-size", 2, "--out", out, "--no-progress", *extra)


def leftovers(folder: Path) -> list[str]:
    """Temporary files or folders the commands leave beside or inside ``folder``."""
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}.")) + \
        (sorted(p.name for p in folder.rglob(".*")) if folder.is_dir() else [])


def test_a_folder_gets_a_manifest_of_its_files(toy, tmp_path):
    out = tmp_path / "mc"
    res = montecarlo(out)
    assert res.exit_code == 0, res.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["schema"] == outputs.MANIFEST_SCHEMA and manifest["command"] == "montecarlo"
    files = {f["path"]: f for f in manifest["files"]}
    assert sorted(files) == sorted(p.name for p in out.iterdir() if p.name != "manifest.json")
    assert sorted(files) == ["montecarlo.csv", "montecarlo.json", "montecarlo.md", "montecarlo.npz"]
    assert all(files[name]["size"] == (out / name).stat().st_size for name in files)
    assert outputs.verify(out) == [] and leftovers(out) == []
    (out / "montecarlo.md").write_text("edited\n")  # the check can fail
    assert outputs.verify(out) == ["montecarlo.md: altered (size or SHA-256 differs)"]


def test_the_same_command_replaces_its_folder_and_another_is_refused_unless_forced(toy, tmp_path):
    out = tmp_path / "mc"
    assert montecarlo(out).exit_code == 0
    res = montecarlo(out, "--seed", 1)  # the same command: its own folder, replaced whole
    assert res.exit_code == 0, res.output
    assert json.loads((out / "montecarlo.json").read_text())["seed"] == 1
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    res = invoke("compare", "localization", "--out", out, "--runs", 1)
    assert res.exit_code == 2 and "holds the output of `liemef montecarlo`" in res.output and "--force" in res.output
    assert "Traceback" not in res.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # untouched
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    res = montecarlo(mine)
    assert res.exit_code == 2 and "files liemef did not write" in res.output and "notes.txt" in res.output
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    res = montecarlo(mine, "--force")
    assert res.exit_code == 0, res.output
    assert "notes.txt" not in {p.name for p in mine.iterdir()} and outputs.verify(mine) == []


@pytest.mark.parametrize("content", [[], ["x.txt"]])
def test_the_working_folder_is_never_replaced_even_with_force(toy, tmp_path, monkeypatch, content):
    for name in content:
        (tmp_path / name).write_text("")
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    for out in (tmp_path / "sub", tmp_path):  # the working folder and its parent
        res = montecarlo(out, "--force")
        assert res.exit_code == 2 and "give a folder of its own" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*content, "sub"])


@pytest.mark.parametrize("writer", ["write_npz", "write_text"])
def test_a_full_disk_is_exit_1_with_no_partial_set(toy, tmp_path, monkeypatch, writer):
    out = tmp_path / "mc"
    assert montecarlo(out).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(io, writer, full)
    res = montecarlo(out, "--seed", 2)
    assert res.exit_code == 1, res.output
    assert "No space left on device" in res.output and "nothing was written" in res.output
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the earlier set, whole
    assert leftovers(out) == []
    fresh = tmp_path / "fresh"
    assert montecarlo(fresh).exit_code == 1 and not fresh.exists() and leftovers(fresh) == []


def test_an_interrupt_is_exit_130_with_nothing_left(toy, tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "write_json", interrupted)
    out = tmp_path / "mc"
    res = montecarlo(out)
    assert res.exit_code == 130 and "Interrupted" in res.output and "Traceback" not in res.output
    assert not out.exists() and leftovers(out) == []


def test_sigterm_mid_write_is_exit_130_with_no_temporary_file(tmp_path):
    """A real SIGTERM, sent while the files are being written (from inside the writer), in a fresh process."""
    code = textwrap.dedent(f"""
        import dataclasses, os, signal, sys
        sys.path.insert(0, {str(ROOT / 'tests')!r})
        from test_cli_outputs import ToyConfig, _no_run, toy_trial
        from liemef.reports import io
        from liemef.studies.experiments import EXPERIMENTS
        EXPERIMENTS["tse2"] = dataclasses.replace(EXPERIMENTS["tse2"], default_config=ToyConfig(), run_fn=_no_run,
                                                  trial_fn=toy_trial, quick_config=None)
        write = io.write_text
        def killed(path, text):
            write(path, text)
            os.kill(os.getpid(), signal.SIGTERM)
        io.write_text = killed
        from liemef.cli import main
        main(["montecarlo", "tse2", "--runs", "2", "--out", {str(tmp_path / 'mc')!r}, "--no-progress"])
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 130, res.stdout + res.stderr
    assert "Traceback" not in res.stderr and "Interrupted" in res.stderr
    assert not (tmp_path / "mc").exists() and leftovers(tmp_path / "mc") == []


def test_a_montecarlo_with_no_usable_trial_fails_and_writes_only_the_failure(toy, tmp_path):
    out = tmp_path / "mc"
    res = montecarlo(out, "--set", "nan_fraction=1.0")
    assert res.exit_code == 1, res.output
    assert "no usable trial: 4 of 4 diverged" in res.output and "Traceback" not in res.output
    assert sorted(p.name for p in out.iterdir()) == ["failure.json"]
    failure = json.loads((out / "failure.json").read_text())
    assert failure["command"] == "montecarlo" and failure["diverged"] == {"non-finite": 4}
    res = montecarlo(out)  # the same command takes its failed folder back
    assert res.exit_code == 0, res.output
    assert "failure.json" not in {p.name for p in out.iterdir()} and outputs.verify(out) == []


def test_bad_input_is_exit_2_without_a_traceback_or_a_folder(toy, tmp_path):
    out = tmp_path / "mc"
    for args in (["--set", "samples=many"], ["--set", "nope=1"], ["--runs", 0], ["--seed", "x"]):
        res = montecarlo(out, *args)
        assert res.exit_code == 2 and "Traceback" not in res.output, (args, res.output)
        assert not out.exists() and leftovers(out) == []


def test_failures_of_a_comparison_count_every_trial():
    ok = {"filters": {"mef": {"runs": 3, "diverged": {"count": 0}}, "ekf": {"runs": 3, "diverged": {
        "count": 3, "trials": [{"trial": 0, "cause": "non-finite", "time": 1.5}]}}}}
    lines, failed, total = failures(ok)
    assert (failed, total) == (3, 6) and lines == ["ekf: 3 of 3 trials failed (first: trial 0, non-finite at t = "
                                                   "1.500 s); left out of the statistics"]
    none = {"recordings": {"1": {"filters": {"mef": {"failed": 2, "runs": 2}}}}}
    assert failures(none)[1:] == (2, 2)
    ins = {"per_trial": {"16": {"variants": {"recorded": {"filters": {"mef": {"ok": True}, "ekf": {
        "ok": False, "status": "non-finite at t = 3 s"}}}, "noisy": {"filters": {"mef": {"ok": True}}}}}}}
    lines, failed, total = failures(ins)
    assert (failed, total) == (1, 3) and lines == ["trial 16 (recorded): ekf failed: non-finite at t = 3 s; no figures"]


def test_python_m_liemef_is_the_command_line():
    res = subprocess.run([sys.executable, "-m", "liemef", "--version"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.startswith("liemef, version ")


@pytest.mark.parametrize(("case", "shown"), [
    ("bad choice", "'tse2'"),
    ("missing log", "file not found"),
    ("empty log", "an empty file"),
    ("text as log", "expected a .csv or .npz file"),
    ("missing system file", "'--system-file'"),
    ("foreign --out", "files liemef did not write"),
])
def test_bad_input_is_reported_before_jax_is_imported(case, shown, tmp_path):
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "log.txt").write_text("t,v\n")
    (tmp_path / "log.csv").write_text("t,v_x,v_y,omega,gps_x,gps_y\n0,1,0,0,,\n")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "mine.txt").write_text("")
    args = {"bad choice": ["--system", "nope", "--log", tmp_path / "log.csv"],
            "missing log": ["--system", "localization", "--log", tmp_path / "no.csv"],
            "empty log": ["--system", "localization", "--log", tmp_path / "empty.csv"],
            "text as log": ["--system", "localization", "--log", tmp_path / "log.txt"],
            "missing system file": ["--system-file", tmp_path / "no.py", "--log", tmp_path / "log.csv"],
            "foreign --out": ["--system", "localization", "--log", tmp_path / "log.csv"]}[case]
    out = tmp_path / ("out" if case == "foreign --out" else "new")
    argv = [str(a) for a in ["run", *args, "--out", out]]
    code = (f"import sys\nfrom liemef.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit as e:\n"
            "    print('exit', e.code, 'jax' in sys.modules)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.stdout.strip() == "exit 2 False", res.stdout + res.stderr
    assert shown in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "new").exists() and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["mine.txt"]
