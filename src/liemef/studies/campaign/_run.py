"""Running a campaign on Dask (``dask.distributed``): tasks out, results streamed into the output folder.

:func:`run_campaign` checks every setting's config in the calling process, skips the tasks the output folder
already holds (:class:`~liemef.studies.campaign.Store`), submits the others to a Dask cluster (a ``LocalCluster`` of
``workers`` single-threaded processes by default, or an existing scheduler), records each result as it
arrives, and when every task is finished assembles one :class:`~liemef.studies.experiments.MonteCarloResult` per
setting and the campaign's table.

Security: the local cluster admits only this run (:func:`_local_cluster`: TLS with credentials made for the
run, every server on 127.0.0.1, no dashboard); an existing scheduler is used as given, and its owner decides
who may connect to it (``docs/campaigns.md``).

Faults: a worker that dies takes its running tasks with it; the scheduler runs them again on another worker
(Dask's ``allowed-failures``, 3 by default, bounds how many worker deaths one task may cause). A task that
raises is tried once more (``retries=1``), then the campaign stops with a :class:`CampaignError` naming the
task, keeping every finished task. Ctrl-C (or SIGTERM through the CLI) stops it the same way; running the
same campaign again resumes.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np

from ... import __version__
from ...reports import io
from ._spec import RESULT_SCHEMA, Campaign, CampaignError, Setting, Task
from ._store import RESULT_FILE, CampaignLock, Entry, Store
from ._task import TaskInput, TaskOutput, config_of, experiment_of, run_task

DEFAULT_WORKERS = 2
"""Local worker processes (one thread each) when no scheduler is given: the cores of this project's machines."""

OnTask = Callable[[Task, Entry, Any], None]
"""``on_task(task, entry, client)``: called in the client after each task is recorded (e.g. a test that
kills a worker after the first one)."""


@dataclass(frozen=True)
class Progress:
    """Where a campaign stands: tasks finished (of ``total``; ``reused`` of them from earlier runs), trials,
    trial-steps computed in this run, and rates measured from the first result of this run on (the first
    result includes start-up and compilation, so no rate comes from it)."""

    done: int
    total: int
    reused: int
    trials_done: int
    trials_total: int
    elapsed: float
    rate: float | None
    eta: float | None

    def format(self, name: str) -> str:
        """``"campaign NAME: 12/40 tasks (30%), 384/1280 trials, 2.1e+05 trial-steps/s, 12.3 s elapsed, ETA
        30.0 s"``."""
        from ..experiments import format_seconds

        pct = 100.0 * self.done / self.total if self.total else 100.0
        rate = "--" if self.rate is None else f"{self.rate:.3g}"
        eta = "--" if self.eta is None else format_seconds(self.eta)
        reused = f", {self.reused} reused" if self.reused else ""
        return (f"campaign {name}: {self.done}/{self.total} tasks ({pct:.0f}%{reused}), {self.trials_done}/"
                f"{self.trials_total} trials, {rate} trial-steps/s, {format_seconds(self.elapsed)} elapsed, "
                f"ETA {eta}")


@dataclass(frozen=True)
class CampaignResult:
    """A finished campaign: one Monte Carlo result per setting (``results[i]`` of ``settings[i]``), how many
    tasks were computed in this run and how many reused from earlier runs, the wall time of this run, and the
    trial-steps per second of this run (``rate``: from the first result on; ``rate_wall``: over the whole
    run, start-up and compilation included; None when nothing was computed)."""

    campaign: Campaign
    settings: tuple[Setting, ...]
    results: tuple[Any, ...]
    computed: int
    reused: int
    elapsed: float
    rate: float | None
    rate_wall: float | None
    workers: int
    samples: tuple[int, ...]
    steps_computed: int
    problems: tuple[str, ...] = field(default=())

    @property
    def trial_steps(self) -> int:
        """Trial-steps of the whole campaign (trials x samples per trial, over every setting)."""
        return sum(r.runs * n for r, n in zip(self.results, self.samples, strict=True))

    def table_rows(self) -> list[tuple]:
        """One row per (setting, window, component, statistic): the setting's index and label, trials and
        diverged trials, then the Monte Carlo row (:attr:`MonteCarloResult.TABLE_HEADER`)."""
        return [(s.index, s.label, r.runs, r.n_nonfinite, *row)
                for s, r in zip(self.settings, self.results, strict=True) for row in r.table_rows()]

    @property
    def table_header(self) -> tuple[str, ...]:
        """The header of :meth:`table_rows` (``summary.csv``)."""
        from ..experiments import MonteCarloResult

        return ("setting", "label", "trials", "diverged", *MonteCarloResult.TABLE_HEADER)

    error = None

    def messages(self) -> list[tuple[str, bool]]:
        """What ``liemef campaign run`` prints at the end, in order: each line with True where it goes to stderr
        (a setting's diverged trials)."""
        rate = "--" if self.rate is None else f"{self.rate:.3g}"
        return [(self.to_markdown(), False),
                (f"{self.computed} tasks computed, {self.reused} reused from earlier runs; {self.elapsed:.1f} s, "
                 f"{rate} trial-steps/s on {self.workers} worker(s)", False),
                *((f"WARNING: setting {s.index} ({s.label}): {r.divergence_summary()}; left out of its statistics",
                   True) for s, r in zip(self.settings, self.results, strict=True) if r.n_nonfinite),
                (f"Wrote {self.campaign.out}/summary.md, summary.csv, result.json and settings/*/montecarlo.*",
                 False)]

    def to_markdown(self) -> str:
        """Per window, a table with a row per setting: diverged trials, then per error component the mean
        across trials of its rms over time, with the spread (std across trials)."""
        from ...metrics._stats import format_number
        from ..experiments import STATS

        first = self.results[0]
        c = self.campaign
        exp = first.experiment + (f" ({first.title})" if first.title else "")
        out = [f"# Campaign: {c.name}", "", f"Experiment: {exp}." + (f" Paper: {first.paper}." if first.paper
                                                                       else ""), "",
               f"{len(self.settings)} settings x {c.seeds} trials (seed {c.seed}; trial i uses "
               f"jax.random.split(jax.random.key({c.seed}), {c.seeds})[i]), {c.trials_per_task} trials per task, "
               f"{c.batch_size} per compiled batch.", "",
               "Per trial: the rms over time of each error component in the window; across trials: mean "
               "(spread = std, ddof = 1) over the trials that did not diverge.", ""]
        k = STATS.index("rms")
        for w, label in enumerate(first.window_labels):
            head = ["setting", "diverged", *(f"{n} rms ({u})" if u else f"{n} rms" for n, u in
                                             zip(first.names, first.units, strict=True))]
            out += [f"## Window {label}", "", "| " + " | ".join(head) + " |",
                    "|---|---:|" + "---:|" * len(first.names)]
            for s, r in zip(self.settings, self.results, strict=True):
                mean, spread = r.mean, r.spread
                cells = [f"{format_number(mean[w, j, k])} ({format_number(spread[w, j, k])})"
                         for j in range(len(r.names))]
                out.append(f"| {s.label} | {r.n_nonfinite}/{r.runs} | " + " | ".join(cells) + " |")
            out.append("")
        return "\n".join(out)

    def to_dict(self) -> dict:
        """``result.json``: complete, what was computed and reused, throughput, and per setting its folder and
        divergence counts."""
        num = lambda v: None if v is None or not math.isfinite(v) else float(v)  # noqa: E731
        return {"schema": RESULT_SCHEMA, "name": self.campaign.name, "complete": True,
                "fingerprint": self.campaign.fingerprint(),
                "tasks": {"total": self.computed + self.reused, "computed": self.computed, "reused": self.reused},
                "throughput": {"trial_steps": self.trial_steps, "trial_steps_computed": self.steps_computed,
                               "elapsed_s": num(self.elapsed),
                               "trial_steps_per_s": num(self.rate), "trial_steps_per_s_wall": num(self.rate_wall),
                               "workers": self.workers,
                               "definition": "trial-steps = trials x samples per trial; the rates are of the "
                                             "tasks computed in this run: trial_steps_per_s from the first "
                                             "result of the run on, _wall over the whole run with start-up and "
                                             "compilation"},
                "settings": [{"index": s.index, "label": s.label, "folder": f"settings/{s.folder}",
                              "overrides": s.overrides, "runs": r.runs, "diverged": r.diverged()}
                             for s, r in zip(self.settings, self.results, strict=True)],
                "problems": list(self.problems), "liemef_version": __version__}

    def save(self) -> list:
        """Write every setting's ``montecarlo.*``, ``summary.md``, ``summary.csv`` and, last, ``result.json``
        into the campaign's output folder."""
        out = self.campaign.out
        written = []
        for s, r in zip(self.settings, self.results, strict=True):
            written += r.save(out / "settings" / s.folder)
        written += [io.write_text(out / "summary.md", self.to_markdown()),
                    io.write_rows(out / "summary.csv", self.table_header, self.table_rows()),
                    io.write_json(out / RESULT_FILE, self.to_dict())]
        return written


def _client(scheduler: str | None, workers: int):
    """A Dask client: of the scheduler at ``scheduler`` (unchanged; with the credentials of Dask's own
    configuration, ``distributed.comm.tls.*``, for a ``tls://`` address), else of a new :func:`_local_cluster`
    of ``workers`` processes. Returns ``(client, cluster or None)``."""
    from dask.distributed import Client

    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError, ValueError, TypeError) as err:  # TypeError: tls:// without credentials
            why = f"{type(err).__name__}: {err}"
        _finalize_failed_clients()
        raise CampaignError(f"scheduler: cannot connect to {scheduler!r} ({why}); expected the address of a "
                            "running Dask scheduler, e.g. tcp://HOST:8786, or tls://HOST:8786 with the cluster's "
                            "credentials in Dask's configuration (distributed.comm.tls.*)")
    cluster = _local_cluster(workers)
    try:
        return Client(cluster, timeout="20s"), cluster
    except BaseException:
        cluster.close()
        raise


def _finalize_failed_clients() -> None:
    """Finalize, now, a ``Client`` whose constructor raised.

    The half-made client is kept alive by reference cycles (its exception's traceback holds its frames), so
    its ``__del__`` (``close()``, then ``LoopRunner.stop()``) runs in a later garbage collection. If that
    collection happens while another client starts, inside ``LoopRunner.start()``, both take the lock that
    all of Dask's loop runners share (a ``threading.Lock``, not reentrant): the thread waits on itself, forever
    (distributed 2026.8.0: a test of the suite hung so). Collecting here, where no such lock is held, runs that
    ``__del__`` at once."""
    import gc

    gc.collect()


CLOSED_HTTP = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []}
"""The Dask configuration a local cluster starts with: its HTTP servers (which Dask starts even without a
dashboard, serving task lists, logs and metrics to anyone who connects) serve nothing."""


QUIET_TRACKER = "ignore:resource_tracker:UserWarning"
"""A warning filter (``-W``) for the resource tracker, the process multiprocessing starts beside the client
to remove the semaphores of the cluster's nannies if the client cannot. A client killed by SIGKILL leaves
them to it, and it removes them, but would also print ``UserWarning: resource_tracker: There appear to be 12
leaked semaphore objects to clean up at shutdown`` with a line of its source on the terminal, in the middle
of the next run: noise about a kill the resumed run already reports (it takes over the killed client's
lock and says so). multiprocessing gives the tracker the client's ``sys.warnoptions``; this one silences
that warning there and nothing else."""


def _local_cluster(workers: int):
    """A ``LocalCluster`` of ``workers`` single-threaded processes that admits only this run: every server on
    127.0.0.1, speaking TLS with credentials made for the run (``Security.temporary()``: a key and a
    certificate, in memory, that each side must present and that the other checks), no dashboard, and HTTP
    servers that serve nothing (:data:`CLOSED_HTTP`). A client, worker or process without the run's credentials
    cannot connect, and so cannot run code in the workers (``docs/campaigns.md``, the threat model)."""
    import dask
    from dask.distributed import LocalCluster, Security

    try:
        security = Security.temporary()
    except ImportError as err:  # cryptography: a dependency of liemef's, missing from this environment
        raise CampaignError(f"the local cluster's TLS credentials cannot be made: {err}; install the package "
                            "cryptography (pip install cryptography) into this environment") from None
    if QUIET_TRACKER not in sys.warnoptions:  # before the cluster's first semaphore starts the tracker
        sys.warnoptions.append(QUIET_TRACKER)
    with dask.config.set(CLOSED_HTTP):  # read by the scheduler here and by each nanny for its workers
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            security=security, dashboard_address=None,
                            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},  # its HTTP server: no fixed port
                            silence_logs=logging.ERROR)


def _check(campaign: Campaign) -> tuple[Any, list[Setting], list]:
    """The experiment, settings and their configs, checked here before any task leaves: an unknown option,
    a bad value or a setup that fails names the setting."""
    exp = experiment_of(campaign.experiment, campaign.experiment_source(),
                        None if campaign.experiment_file is None else str(campaign.experiment_file))
    points = campaign.points()
    configs = []
    for s in points:
        try:
            config = config_of(exp, campaign.quick, s.overrides)
        except CampaignError as err:
            raise CampaignError(f"setting {s.index} ({s.label}): {err}") from None
        try:
            exp.trial_fn(config)  # builds the setting's system and filter (no tracing)
        except Exception as err:  # the experiment's own code: report whatever it raised
            raise CampaignError(f"setting {s.index} ({s.label}): the experiment's trial_fn failed: "
                                f"{type(err).__name__}: {err}") from None
        configs.append(config)
    return exp, points, configs


def run_campaign(campaign: Campaign, scheduler: str | None = None, workers: int = DEFAULT_WORKERS,
                 progress: bool | Callable[[Progress], None] = True, client: Any = None,
                 on_task: OnTask | None = None, stream: TextIO | None = None) -> CampaignResult:
    """Run ``campaign`` (or finish it: tasks its output folder already holds are not run again) and return
    its result, written to its output folder (:meth:`CampaignResult.save`).

    Args:
        scheduler: the address of an existing Dask scheduler (``tcp://HOST:PORT``, or ``tls://HOST:PORT`` with
            the cluster's credentials in Dask's configuration), used as it is.
        workers: without ``scheduler`` or ``client``, the worker processes of the ``LocalCluster`` started
            for this run (and closed after it), which admits only this run (TLS with credentials made for it).
        progress: True shows tasks done, trial-steps/s and the time left on ``stream`` (stderr), False
            nothing; a function receives a :class:`Progress` after every task.
        client: an existing ``dask.distributed.Client`` to use (not closed).
        on_task: called after each task is recorded (:data:`OnTask`).

    Raises:
        CampaignError: a bad description or setting (before anything runs), another campaign in ``out``,
            another client running this one (naming its pid and host; a lock left by a client that no longer
            runs is taken over, and the result's ``problems`` say so), or a task that failed twice (naming it;
            finished tasks are kept).
        KeyboardInterrupt: on Ctrl-C, after the cluster is closed; finished tasks are kept.
    """
    if not isinstance(campaign, Campaign):
        raise CampaignError(f"campaign: expected a liemef.studies.campaign.Campaign, got {type(campaign).__name__}")
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise CampaignError(f"workers: expected an integer >= 1, got {workers!r}")
    exp, points, configs = _check(campaign)
    store = Store.open(campaign)
    lock = CampaignLock.acquire(campaign.out)  # one client at a time
    try:
        return _run_locked(campaign, store, lock.note, exp, points, configs, scheduler, workers, progress, client,
                           on_task, stream)
    finally:
        lock.release()


def _run_locked(campaign: Campaign, store: Store, note: str | None, exp, points: list[Setting], configs: list,
                scheduler: str | None, workers: int, progress, client: Any, on_task: OnTask | None,
                stream: TextIO | None) -> CampaignResult:
    """:func:`run_campaign` once its folder is open and locked (``note``: a stale lock taken over)."""
    tasks = campaign.tasks()
    done = store.finished()
    problems = list(store.problems) + ([note] if note else [])
    stream = sys.stderr if stream is None else stream
    for p in problems:
        print(f"campaign {campaign.name}: {p}", file=stream)
    line = None
    if progress is True:
        from ..experiments import ProgressLine

        line = ProgressLine(f"campaign {campaign.name}", stream)
    report = progress if callable(progress) else None

    todo = [t for t in tasks if t.id not in done]
    reused = len(tasks) - len(todo)
    t0 = time.perf_counter()
    stamps: list[tuple[float, int]] = []  # (time, trial-steps) of each result of this run
    trials_done = sum(t.trials for t in tasks if t.id in done)
    n_workers = 0

    def show(final: bool = False) -> None:
        elapsed = time.perf_counter() - t0
        rate = eta = None
        if len(stamps) >= 2 and stamps[-1][0] > stamps[0][0]:
            span = stamps[-1][0] - stamps[0][0]
            rate = sum(s for _, s in stamps[1:]) / span
            eta = (len(todo) - len(stamps)) * span / (len(stamps) - 1)
        elif not todo or len(stamps) == len(todo):
            eta = 0.0
        pr = Progress(done=reused + len(stamps), total=len(tasks), reused=reused, trials_done=trials_done,
                      trials_total=campaign.seeds * len(points), elapsed=elapsed, rate=rate, eta=eta)
        if line is not None:
            line.show(pr.format(campaign.name), elapsed, final)
        if report is not None:
            report(pr)

    if todo:
        store.clear_result()
        own = client is None
        cluster = None
        if own:
            client, cluster = _client(scheduler, workers)
        source = campaign.experiment_source()
        filename = "<registered>" if campaign.experiment_file is None else str(campaign.experiment_file)
        futures = {}
        try:
            n_workers = len(client.scheduler_info().get("workers", {}))
            show()
            for t in todo:
                s = points[t.setting]
                inp = TaskInput(task_id=t.id, experiment=campaign.experiment, source=source, filename=filename,
                                quick=campaign.quick, overrides=tuple(s.overrides.items()), seed=campaign.seed,
                                runs=campaign.seeds, start=t.start, stop=t.stop, batch_size=campaign.batch_size)
                fut = client.submit(run_task, inp, key=f"liemef-{t.id}-{uuid.uuid4().hex[:8]}", pure=False,
                                    retries=1)
                futures[fut] = t
            from dask.distributed import as_completed

            for fut in as_completed(list(futures)):
                t = futures[fut]
                try:
                    res: TaskOutput = fut.result()
                except Exception as err:  # a task that raised twice, or killed too many workers
                    raise CampaignError(
                        f"task {t.id} (setting {t.setting}: {points[t.setting].label}, trials [{t.start}, "
                        f"{t.stop})) failed: {type(err).__name__}: {err}; {reused + len(stamps)} of {len(tasks)} "
                        f"tasks are finished and kept in {str(campaign.out)!r}: run the campaign again to "
                        "resume") from err
                entry = store.record(t, res.stats, res.finite, res.causes, res.samples, res.seconds, res.worker)
                stamps.append((time.perf_counter(), t.trials * res.samples))
                trials_done += t.trials
                fut.release()
                show(final=len(stamps) == len(todo))
                if on_task is not None:
                    on_task(t, entry, client)
        except KeyboardInterrupt:
            print(f"\ncampaign {campaign.name}: interrupted; {reused + len(stamps)} of {len(tasks)} tasks are "
                  f"finished and kept in {str(campaign.out)!r}: run the campaign again to resume", file=stream)
            raise
        finally:
            with contextlib.suppress(Exception):
                client.cancel(list(futures))
            if own:
                with contextlib.suppress(Exception):
                    client.close()
                if cluster is not None:
                    with contextlib.suppress(Exception):
                        cluster.close()
    elif line is not None or report is not None:
        show(final=True)

    elapsed = time.perf_counter() - t0
    rate = rate_wall = None
    if stamps:
        rate_wall = sum(s for _, s in stamps) / elapsed
        if len(stamps) >= 2 and stamps[-1][0] > stamps[0][0]:
            rate = sum(s for _, s in stamps[1:]) / (stamps[-1][0] - stamps[0][0])
    results, samples = _assemble(campaign, store, exp, points, configs, tasks, elapsed)
    out = CampaignResult(campaign=campaign, settings=tuple(points), results=tuple(results), computed=len(stamps),
                         reused=reused, elapsed=elapsed, rate=rate, rate_wall=rate_wall, workers=n_workers,
                         samples=tuple(samples), steps_computed=sum(s for _, s in stamps), problems=tuple(problems))
    out.save()
    return out


def _assemble(campaign: Campaign, store: Store, exp, points: list[Setting], configs: list, tasks: list[Task],
              elapsed: float) -> tuple[list, list[int]]:
    """Every setting's :class:`~liemef.studies.experiments.MonteCarloResult` from its tasks' files, checked again
    against the manifest: a campaign's result is built from recorded, verified tasks only."""
    from ..experiments import TrialArrays, result_of

    done = store.finished()
    missing = [t.id for t in tasks if t.id not in done]
    if missing:
        raise CampaignError(f"campaign {campaign.name}: tasks {missing[:5]} are not finished (or their files "
                            f"changed: {'; '.join(store.problems[:3])}); run the campaign again")
    results, samples = [], []
    for s, config in zip(points, configs, strict=True):
        mine = [done[t.id] for t in tasks if t.setting == s.index]
        parts = [store.load(e) for e in mine]
        arrays = TrialArrays(start=0, stop=campaign.seeds,
                             stats=np.concatenate([p["stats"] for p in parts]),
                             finite=np.concatenate([p["finite"] for p in parts]),
                             causes=np.concatenate([p["causes"] for p in parts]),
                             samples=mine[0].samples)
        results.append(result_of(exp, config, campaign.seed, campaign.seeds, arrays, elapsed, campaign.batch_size))
        samples.append(mine[0].samples)
    return results, samples
