"""Campaigns on Dask (liemef.studies.campaign): the description, the store, identical numbers whatever the layout, a
killed worker, a stopped and resumed campaign, and a failing task.

The campaign here is the user's experiment in examples/campaign/heading_experiment.py (heading on SO(2)),
shortened: 2 settings (two measurement noise levels: one compiled program, its parameters as data) x 24 seeds
in tasks of 8 trials (3 per setting), 4 trials per compiled batch.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from liemef.studies.campaign import (
    MANIFEST_FILE,
    RESULT_FILE,
    Campaign,
    CampaignError,
    Store,
    Task,
    run_campaign,
)
from liemef.studies.campaign._task import config_of, experiment_of
from liemef.studies.experiments import montecarlo

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "campaign" / "heading_experiment.py"
SMALL = {"name": "test", "experiment_file": str(EXAMPLE), "seeds": 24, "batch_size": 4, "trials_per_task": 8,
         "base": {"duration": 1.0, "dt": 0.05, "substeps": 1, "steady_from": 0.5},
         "grid": {"meas_std": [0.2, 0.4]}}


def small(out: Path, **changes) -> Campaign:
    return Campaign.from_dict({**SMALL, "out": str(out), **changes})


def toml_text(out: Path, seeds: int = 24, trials_per_task: int = 8, duration: float = 1.0, dt: float = 0.05,
              steady_from: float = 0.5) -> str:
    return f"""name = "test"
experiment_file = "{EXAMPLE}"
seeds = {seeds}
batch_size = 4
trials_per_task = {trials_per_task}
out = "{out}"

[base]
duration = {duration}
dt = {dt}
substeps = 1
steady_from = {steady_from}

[grid]
meas_std = [0.2, 0.4]
"""


# --- the description ---------------------------------------------------------------------------------------
def test_toml_yaml_and_python_describe_the_same_campaign(tmp_path):
    (tmp_path / "c.toml").write_text(toml_text(tmp_path / "out"))
    yaml_text = "\n".join([
        "name: test", f"experiment_file: {EXAMPLE}", "seeds: 24", "batch_size: 4", "trials_per_task: 8",
        f"out: {tmp_path / 'out'}", "base: {duration: 1.0, dt: 0.05, substeps: 1, steady_from: 0.5}",
        "grid: {meas_std: [0.2, 0.4]}", ""])
    (tmp_path / "c.yaml").write_text(yaml_text)
    a, b, c = Campaign.load(tmp_path / "c.toml"), Campaign.load(tmp_path / "c.yaml"), small(tmp_path / "out")
    assert a.fingerprint() == b.fingerprint() == c.fingerprint()
    assert a.out == b.out == tmp_path / "out"
    # relative paths are taken from the campaign file's folder; the experiment file counts by content
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "exp.py").write_text(EXAMPLE.read_text())
    rel = toml_text(tmp_path / "out").replace(f'"{EXAMPLE}"', '"exp.py"').replace(f'"{tmp_path / "out"}"', '"o"')
    (tmp_path / "sub" / "c.toml").write_text(rel)
    d = Campaign.load(tmp_path / "sub" / "c.toml")
    assert d.out == tmp_path / "sub" / "o" and d.experiment_file == tmp_path / "sub" / "exp.py"
    assert d.fingerprint() == a.fingerprint()
    # the text is read once: what was fingerprinted is what the workers get, whatever happens to the file
    (tmp_path / "sub" / "exp.py").write_text("# edited\n")
    assert d.fingerprint() == a.fingerprint() and d.experiment_source() == EXAMPLE.read_text()
    (tmp_path / "sub" / "exp.py").unlink()
    with pytest.raises(CampaignError, match="experiment_file: cannot read"):
        Campaign.load(tmp_path / "sub" / "c.toml")
    assert small(tmp_path, seeds=25).fingerprint() != a.fingerprint()


def test_grid_settings_and_tasks(tmp_path):
    c = small(tmp_path, grid={"order": ["second", "first"], "alpha": [0.0, 0.5]},
              settings=[{"connection": "zero"}, {"connection": "minus"}], seeds=20)
    pts = c.points()
    assert len(pts) == 8
    assert pts[0].overrides == {"duration": 1.0, "dt": 0.05, "substeps": 1, "steady_from": 0.5,
                                "connection": "zero", "order": "second", "alpha": 0.0}
    assert pts[1].label == "connection=zero, order=second, alpha=0.5"  # the grid's last axis varies fastest
    assert pts[7].label == "connection=minus, order=first, alpha=0.5"
    assert len({p.folder for p in pts}) == 8 and pts[7].folder.startswith("s007_")
    tasks = c.tasks()
    assert [(t.start, t.stop) for t in tasks if t.setting == 3] == [(0, 8), (8, 16), (16, 20)]
    assert len({t.id for t in tasks}) == len(tasks) == 24
    assert all(t.start % c.batch_size == 0 for t in tasks)
    # batch_size is capped at seeds, as in liemef montecarlo
    assert small(tmp_path, seeds=3, trials_per_task=3).batch_size == 3


def test_the_example_campaign_is_the_documented_one_and_is_valid():
    from liemef.studies.campaign._run import _check

    path = ROOT / "examples" / "campaign" / "heading.toml"
    doc = (ROOT / "docs" / "campaigns.md").read_text()
    block = doc.split("```toml\n", 1)[1].split("```", 1)[0]
    assert block == "# examples/campaign/heading.toml\n" + path.read_text().split("\n", 2)[2]
    c = Campaign.load(path)
    assert c.out.resolve() == (ROOT / "out" / "campaign-heading").resolve()
    exp, points, configs = _check(c)  # every setting builds, before anything would run
    assert exp.name == "heading" and len(points) == 6 and configs[5].meas_std == 0.5 and configs[5].order == "first"
    c = Campaign.load(ROOT / "examples" / "campaign" / "tse2_connections.toml")
    exp, points, configs = _check(c)
    assert exp.name == "tse2" and c.seeds * len(points) >= 2000 and configs[3].connection == "minus"


@pytest.mark.parametrize("change, words", [
    ({"colour": 1}, "unknown key(s) ['colour']"),
    ({"experiment": "tse2"}, "exactly one of `experiment`"),
    ({"trials_per_task": 6}, "trials_per_task: expected a multiple of batch_size = 4"),
    ({"seeds": 0}, "seeds: expected an integer >= 1, got 0"),
    ({"grid": {"order": []}}, "grid.order: expected a non-empty list"),
    ({"grid": {"order": ["first", "first"]}}, "grid.order: expected distinct values"),
    ({"settings": [{"meas_std": 0.1}]}, "grid/settings: expected each field in one of them"),
    ({"base": {**SMALL["base"], "meas_std": 0.3}}, "base/grid: expected each field in one of them, got ['meas_std']"),
    ({"base": {"alpha": float("nan")}}, "base.alpha: expected a finite number"),
    ({"quick": "yes"}, "quick: expected true or false"),
])
def test_bad_descriptions_are_named(tmp_path, change, words):
    with pytest.raises(CampaignError) as err:
        small(tmp_path, **change)
    assert words in str(err.value)


def test_bad_files_and_settings_are_named(tmp_path):
    with pytest.raises(CampaignError, match="not found"):
        Campaign.load(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("name = \n")
    with pytest.raises(CampaignError, match="is not valid TOML"):
        Campaign.load(tmp_path / "bad.toml")
    (tmp_path / "c.json").write_text("{}")
    with pytest.raises(CampaignError, match=r"expected a \.toml, \.yaml or \.yml file"):
        Campaign.load(tmp_path / "c.json")
    (tmp_path / "nout.toml").write_text('name = "x"\nexperiment = "tse2"\n')
    with pytest.raises(CampaignError, match="missing key 'out'"):
        Campaign.load(tmp_path / "nout.toml")
    # settings are checked in the caller, before any task leaves (client=None would start a cluster)
    never = object()
    with pytest.raises(CampaignError, match=r"setting 1 \(order=third\): .*order"):
        run_campaign(small(tmp_path / "o", grid={"order": ["second", "third"]}), client=never)
    with pytest.raises(CampaignError, match=r"unknown config option\(s\) \['colour'\]"):
        run_campaign(small(tmp_path / "o", base={"colour": 1}), client=never)
    with pytest.raises(CampaignError, match="experiment: expected one of"):
        run_campaign(Campaign(name="x", out=tmp_path / "o", experiment="no-such"), client=never)
    (tmp_path / "noexp.py").write_text("x = 1\n")
    with pytest.raises(CampaignError, match="to define `experiment`"):
        run_campaign(small(tmp_path / "o", experiment_file=str(tmp_path / "noexp.py")), client=never)
    assert not (tmp_path / "o").exists()  # nothing was written


# --- parameters are data ------------------------------------------------------------------------------------
def test_a_sweep_of_values_compiles_one_batch():
    from liemef.studies.experiments import trial_keys, trial_statistics
    from liemef.studies.experiments._montecarlo import TRACES

    exp = experiment_of(None, EXAMPLE.read_text(), str(EXAMPLE))
    base = {"duration": 0.9, "dt": 0.05, "substeps": 1, "steady_from": 0.5}
    before = TRACES["heading"]
    a = montecarlo(exp, exp.config(**base, meas_std=0.4), runs=4, batch_size=4, progress=False)
    other = exp.config(**{**base, "steady_from": 0.3}, meas_std=0.6, model_std=0.05, alpha=0.2, initial_error=0.5)
    b = montecarlo(exp, other, runs=4, batch_size=4, progress=False)
    assert TRACES["heading"] - before == 1  # noise levels, alpha, initial state and window: values only
    assert np.isfinite(a.stats).all() and not np.allclose(a.stats[:, 0], b.stats[:, 0])
    # the shared batch computes what the trial computes on its own (closed over its config's parameters)
    s, f, c = jax.jit(trial_statistics(exp.trial_fn(other)))(trial_keys(0, 4)[2])  # one program, not op by op
    np.testing.assert_allclose(b.stats[2], np.asarray(s), rtol=1e-12, atol=1e-15)


# --- the store ---------------------------------------------------------------------------------------------
def _fake(store: Store, task: Task, value: float):
    n = task.trials
    return store.record(task, np.full((n, 2, 1, 3), value), np.ones(n, bool), np.zeros(n, np.int32), 21, 0.1,
                        "here")


def test_store_keeps_verified_tasks_only(tmp_path):
    c = small(tmp_path / "out")
    store = Store.open(c)
    tasks = c.tasks()
    for i, t in enumerate(tasks[:4]):
        _fake(store, t, float(i))
    assert set(store.finished()) == {t.id for t in tasks[:4]} and not store.problems
    # a task file changed after it was recorded, one deleted, and a manifest line torn by a kill mid-write
    p1 = store.task_path(tasks[1])
    p1.write_bytes(p1.read_bytes()[:-10])
    store.task_path(tasks[2]).unlink()
    with open(store.manifest, "a") as f:
        f.write('{"schema": "liemef.studies.campaign/1", "task": "s001-t00')
    done = Store.open(c).finished()  # opening again ends the torn line, so the next record starts afresh
    assert set(done) == {tasks[0].id, tasks[3].id}
    store = Store.open(c)
    store.finished()
    assert any("does not match its checksum" in p for p in store.problems)
    assert any("is missing" in p for p in store.problems)
    assert any("not a complete entry" in p for p in store.problems)
    _fake(store, tasks[1], 1.0)
    assert set(Store.open(c).finished()) == {tasks[0].id, tasks[1].id, tasks[3].id}


def test_another_campaign_in_the_same_folder_is_refused(tmp_path):
    a = small(tmp_path / "out")
    _fake(Store.open(a), a.tasks()[0], 1.0)
    before = sorted(p.name for p in (tmp_path / "out").rglob("*"))
    with pytest.raises(CampaignError, match=r"holds another campaign \(seeds: 24 -> 48\)"):
        Store.open(small(tmp_path / "out", seeds=48))
    assert sorted(p.name for p in (tmp_path / "out").rglob("*")) == before
    # on the command line it is bad input (exit 2, as a description that cannot be read), not a failed run (1)
    from click.testing import CliRunner

    from liemef.cli import cli

    (tmp_path / "c.toml").write_text(toml_text(tmp_path / "out", seeds=48))
    res = CliRunner().invoke(cli, ["campaign", "run", str(tmp_path / "c.toml"), "--workers", "1", "--no-progress"])
    assert res.exit_code == 2 and "holds another campaign (seeds: 24 -> 48)" in res.output, res.output
    assert sorted(p.name for p in (tmp_path / "out").rglob("*")) == before


# --- on a cluster ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def reference():
    """liemef montecarlo of each setting, in this process: the numbers every layout must give."""
    c = small(Path("unused"))
    exp = experiment_of(None, c.experiment_source(), str(EXAMPLE))
    return [montecarlo(exp, config_of(exp, False, s.overrides), runs=c.seeds, seed=c.seed,
                       batch_size=c.batch_size, progress=False) for s in c.points()]


@pytest.fixture(scope="module")
def client():
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as cl:
        yield cl


def assert_same(result, reference):
    for r, ref in zip(result.results, reference, strict=True):
        np.testing.assert_array_equal(r.stats, ref.stats)
        np.testing.assert_array_equal(r.causes, ref.causes)
        np.testing.assert_array_equal(r.keys, ref.keys)
        assert r.runs == ref.runs and r.n_nonfinite == ref.n_nonfinite


def manifest_tasks(out: Path) -> list[str]:
    lines = (out / MANIFEST_FILE).read_text().splitlines()
    return [json.loads(line)["task"] for line in lines if line.strip()]


def test_one_worker_two_workers_and_montecarlo_give_identical_statistics(tmp_path, client, reference):
    two = run_campaign(small(tmp_path / "two"), client=client, progress=False)
    one = run_campaign(small(tmp_path / "one"), workers=1, progress=False)  # its own LocalCluster
    assert two.workers == 2 and one.workers == 1 and two.computed == one.computed == 6
    assert_same(two, reference)
    assert_same(one, reference)
    assert sorted(manifest_tasks(tmp_path / "two")) == sorted(t.id for t in small(tmp_path).tasks())
    # what was written: per setting the Monte Carlo files, the table, and result.json saying complete
    meta = json.loads((tmp_path / "two" / RESULT_FILE).read_text())
    assert meta["complete"] and meta["tasks"] == {"total": 6, "computed": 6, "reused": 0}
    assert meta["throughput"]["trial_steps"] == 2 * 24 * 21
    saved = np.load(tmp_path / "two" / "settings" / two.settings[1].folder / "montecarlo.npz")
    np.testing.assert_array_equal(saved["stats"], reference[1].stats)
    table = (tmp_path / "two" / "summary.md").read_text()
    assert "| meas_std=0.4 | 0/24 |" in table
    # run again: nothing is computed, and the same numbers come back
    again = run_campaign(small(tmp_path / "two"), client=client, progress=False)
    assert again.computed == 0 and again.reused == 6
    assert_same(again, reference)


def test_an_existing_scheduler_is_used_unchanged(tmp_path, client, reference):
    address = client.scheduler.address  # as `liemef campaign run FILE --scheduler tcp://HOST:PORT` passes it
    result = run_campaign(small(tmp_path / "out", grid={"meas_std": [0.4]}), scheduler=address, progress=False)
    assert result.workers == 2 and result.computed == 3
    assert_same(result, reference[1:])  # the second setting of the reference, run alone
    assert len(client.scheduler_info()["workers"]) == 2  # the cluster is still there, as it was


def test_a_killed_worker_changes_nothing(tmp_path, client):
    # a setting these workers have not compiled yet, so that tasks are still running after the first result
    c = small(tmp_path / "out", base={**SMALL["base"], "duration": 1.2})
    exp = experiment_of(None, c.experiment_source(), str(EXAMPLE))
    undisturbed = [montecarlo(exp, config_of(exp, False, s.overrides), runs=c.seeds, seed=c.seed,
                              batch_size=c.batch_size, progress=False) for s in c.points()]
    killed, done = [], []

    def kill_a_busy_worker(task, entry, cl):
        # the scheduler hands the next task to a worker shortly after a result comes (under load, later than the
        # client reads it): wait for a busy worker, a few seconds at most, while tasks remain
        deadline = time.monotonic() + 10.0
        while not killed and time.monotonic() < deadline and len(done) + 1 < len(c.tasks()):
            busy = [addr for addr, keys in cl.processing().items() if keys]
            if busy:
                pids = cl.run(os.getpid, workers=busy[:1])
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
            else:
                time.sleep(0.05)
        done.append(task.id)

    result = run_campaign(c, client=client, progress=False, on_task=kill_a_busy_worker)
    assert killed, "no worker was busy after a task: the fault was not injected"
    assert_same(result, undisturbed)
    ids = manifest_tasks(tmp_path / "out")
    assert sorted(ids) == sorted(t.id for t in c.tasks())  # each task recorded exactly once
    client.wait_for_workers(2, timeout=120)  # the nanny restarts it, for the tests after this one


def test_a_failing_task_stops_the_campaign_and_keeps_the_rest(tmp_path, client):
    broken = tmp_path / "broken.py"
    broken.write_text(EXAMPLE.read_text() + (
        "\nimport dataclasses\n_trial_fn = trial_fn\n\n"
        "def trial_fn(config):\n"
        "    spec = _trial_fn(config)\n"
        "    if config.alpha == 0:\n"
        "        return spec\n"
        "    def errors(params, key):\n"
        "        raise RuntimeError('no trial for alpha > 0')\n"
        "    return dataclasses.replace(spec, errors=errors)\n\n"
        "experiment = Experiment(name='heading', title='', paper='', default_config=HeadingConfig(), "
        "run_fn=run_fn, trial_fn=trial_fn)\n"))
    c = small(tmp_path / "out", experiment_file=str(broken), grid={"alpha": [0.0, 0.5]}, seeds=8,
              trials_per_task=4)
    with pytest.raises(CampaignError) as err:
        run_campaign(c, client=client, progress=False)
    msg = str(err.value)
    assert "task s001-t0000" in msg and "RuntimeError: no trial for alpha > 0" in msg and "resume" in msg
    assert not (tmp_path / "out" / RESULT_FILE).exists()
    assert set(manifest_tasks(tmp_path / "out")) <= {"s000-t0000000", "s000-t0000004"}


# --- the command line, stopped and resumed -----------------------------------------------------------------
# pytest-xdist's workers ignore SIGINT, and an ignored signal is inherited: the CLI is started with the handler
# a terminal's Ctrl-C meets (KeyboardInterrupt), set in the child itself (no pre-exec hook in a JAX process).
CLI = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
       "from liemef.cli import main; main(sys.argv[1:])")


def _cli(*args, **kw):
    return subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


def _wait_for_tasks(out: Path, n: int, proc, timeout: float = 300.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if (out / MANIFEST_FILE).exists() and len(manifest_tasks(out)) >= n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the campaign ended before {n} tasks: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError(f"no {n} tasks after {timeout} s")


@pytest.mark.slow  # two CLI processes that compile, 100-160 s on a busy 2-core machine; the fast suite checks the
# reuse of finished tasks in-process (test_one_worker_two_workers_and_montecarlo_give_identical_statistics) and
# the exit code 130 of an interrupt (tests/test_cli_outputs.py)
def test_stopped_campaign_resumes_without_recomputing(tmp_path):
    # tasks long enough (16 trials x 15001 samples, 0.4 s or more once compiled) for Ctrl-C to land between them;
    # 32 seeds: 2 tasks for each of the 2 settings
    out = tmp_path / "out"
    shape = {"seeds": 32, "trials_per_task": 16, "duration": 30.0, "dt": 0.002, "steady_from": 10.0}
    (tmp_path / "c.toml").write_text(toml_text(out, **shape))
    c = Campaign.load(tmp_path / "c.toml")
    n_tasks = len(c.tasks())
    args = ("campaign", "run", str(tmp_path / "c.toml"), "--workers", "1")
    # 1. Ctrl-C after the first task: exit 130, finished tasks kept, nothing says complete
    proc = _cli(*args)
    _wait_for_tasks(out, 1, proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "run the campaign again to resume" in err
    first = manifest_tasks(out)
    assert 1 <= len(first) < n_tasks and not (out / RESULT_FILE).exists() and not (out / "summary.md").exists()
    status = _cli("campaign", "status", str(tmp_path / "c.toml"))
    text, _ = status.communicate(timeout=120)
    assert f"{len(first)}/{n_tasks} tasks finished; incomplete" in text
    # 2. run again to the end: the finished tasks are not computed again, the numbers are montecarlo's
    proc = _cli(*args, "--no-progress")
    text, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    final = manifest_tasks(out)
    assert final[:len(first)] == first and sorted(final) == sorted(t.id for t in c.tasks())
    assert f"{n_tasks - len(first)} tasks computed, {len(first)} reused" in text
    exp = experiment_of(None, c.experiment_source(), str(EXAMPLE))
    for s in c.points():
        ref = montecarlo(exp, config_of(exp, False, s.overrides), runs=c.seeds, seed=c.seed,
                         batch_size=c.batch_size, progress=False)
        np.testing.assert_array_equal(np.load(out / "settings" / s.folder / "montecarlo.npz")["stats"], ref.stats)
    assert json.loads((out / RESULT_FILE).read_text())["complete"]
