"""One client per campaign folder (issue 19, item 5): a second client is refused with the holder's pid and
host; a lock left by a client that was killed is taken over, and the run says so."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import liemef
from liemef.studies.campaign import LOCK_FILE, CampaignError, CampaignLock, Store, run_campaign
from test_campaign import _fake, small

SRC = str(Path(liemef.__file__).resolve().parents[1])
HOLDER = """
import sys, time
from liemef.studies.campaign import CampaignLock
lock = CampaignLock.acquire(sys.argv[1])
print("locked", flush=True)
time.sleep(600)
"""


def _holder(out: Path) -> subprocess.Popen:
    """Another client (a process of its own) holding the lock of ``out``, once it says so."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([SRC] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def _finished_store(out: Path):
    """A campaign whose every task is recorded (no cluster needed to finish it)."""
    c = small(out)
    store = Store.open(c)
    for i, t in enumerate(c.tasks()):
        _fake(store, t, 1.0 + i)
    return c


def test_a_second_client_is_refused_with_the_holders_pid_and_host(tmp_path):
    c = _finished_store(tmp_path / "out")
    proc = _holder(c.out)
    try:
        before = sorted(p.name for p in c.out.rglob("*"))
        with pytest.raises(CampaignError, match=rf"is in use by another client of this campaign: pid {proc.pid} on "
                                                rf"host {socket.gethostname()}, running since "):
            run_campaign(c, client=object(), progress=False)
        assert sorted(p.name for p in c.out.rglob("*")) == before  # nothing computed or written
        with pytest.raises(CampaignError, match=f"pid {proc.pid}"):  # also from this process's own second try
            CampaignLock.acquire(c.out)
    finally:
        proc.kill()
        proc.wait()


def test_a_killed_clients_lock_is_taken_over_and_the_run_says_so(tmp_path, capsys):
    c = _finished_store(tmp_path / "out")
    proc = _holder(c.out)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert f'"pid": {proc.pid}' in (c.out / LOCK_FILE).read_text()  # the dead client's lock is still there
    res = run_campaign(c, client=object(), progress=False)
    note = [p for p in res.problems if "took over the lock" in p]
    assert len(note) == 1 and f"pid {proc.pid} on host {socket.gethostname()}" in note[0]
    assert "which no longer runs" in note[0] and note[0] in capsys.readouterr().err
    assert res.computed == 0 and np.isfinite(res.results[0].stats).all()
    assert (c.out / LOCK_FILE).read_text() == ""  # released at the end: the next run takes no one's lock
    lock = CampaignLock.acquire(c.out)
    assert lock.note is None
    lock.release()
    lock.release()  # idempotent


CLUSTER = """
import time
from liemef.studies.campaign._run import _client
client, cluster = _client(None, 1)
print("up", flush=True)
time.sleep(600)
"""


def test_a_killed_clients_cluster_says_nothing_on_the_terminal(tmp_path):
    """A client killed by SIGKILL with its local cluster up: its processes end, and the resource tracker that
    removes the semaphores it left prints nothing (it printed a UserWarning with a line of its source, which
    showed up in the middle of the resumed run)."""
    import psutil

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([SRC] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    with open(tmp_path / "stderr.txt", "w") as err:  # the terminal both the client and its tracker write to
        proc = subprocess.Popen([sys.executable, "-c", CLUSTER], stdout=subprocess.PIPE, stderr=err, text=True,
                                env=env)
        assert proc.stdout.readline().strip() == "up"
        children = psutil.Process(proc.pid).children(recursive=True)
        assert any("resource_tracker" in " ".join(c.cmdline()) for c in children)  # the case this test is about
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        gone, alive = psutil.wait_procs(children, timeout=60)  # the workers exit, then the tracker cleans up
        assert not alive, alive
    said = (tmp_path / "stderr.txt").read_text()
    assert said == "", said
