"""Campaigns: Monte Carlo studies over a grid of settings, run on Dask, resumable and fault-tolerant.

A :class:`Campaign` (a TOML/YAML file or a Python object) names an experiment (registered, or a user's file
that defines one), a grid of its config fields, the seeds per setting and an output folder.
:func:`run_campaign` (``liemef campaign run FILE``) splits every setting's trials into tasks of whole compiled
``vmap`` batches, runs them on a ``dask.distributed`` cluster (a local one by default, or ``--scheduler
tcp://HOST:PORT``), streams each result into the output folder with a checksummed manifest entry, and when
all are finished writes one Monte Carlo result per setting and a table across settings
(:class:`CampaignResult`).

Trial ``i`` of a setting uses ``jax.random.split(jax.random.key(seed), seeds)[i]``, and the tasks run the same
compiled batches as :func:`liemef.studies.experiments.montecarlo`: the statistics are identical on one worker, on
many, and through ``liemef montecarlo``. A killed worker's tasks are run again elsewhere; a stopped campaign
resumes without recomputing its finished tasks (:class:`Store`).
"""

from ._run import DEFAULT_WORKERS, CampaignResult, Progress, run_campaign
from ._spec import (
    KEYS,
    RESULT_SCHEMA,
    SCHEMA,
    TASK_SCHEMA,
    Campaign,
    CampaignError,
    CampaignInputError,
    Setting,
    Task,
)
from ._store import (
    CAMPAIGN_FILE,
    LOCK_FILE,
    MANIFEST_FILE,
    RESULT_FILE,
    CampaignLock,
    Entry,
    Store,
    sha256_file,
    status_lines,
)
from ._task import TaskInput, TaskOutput, run_task

__all__ = ["Campaign", "CampaignError", "CampaignInputError", "CampaignResult", "Setting", "Task", "Progress",
           "run_campaign", "Store", "Entry", "CampaignLock", "TaskInput", "TaskOutput", "run_task", "sha256_file",
           "KEYS", "SCHEMA", "TASK_SCHEMA", "RESULT_SCHEMA", "DEFAULT_WORKERS", "status_lines", "CAMPAIGN_FILE",
           "LOCK_FILE", "MANIFEST_FILE", "RESULT_FILE"]
