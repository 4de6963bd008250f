"""The campaign description: what to run (an experiment and a grid of its settings, seeds per setting) and
where the results go. Read from a TOML or YAML file or built in Python; expanded into settings and tasks.

A task is a range of trials ``[start, stop)`` of one setting, aligned to ``batch_size``: its trials run as
compiled ``vmap`` batches identical to those of :func:`liemef.studies.experiments.montecarlo`, so the statistics do
not depend on how the trials are split into tasks or spread over workers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SCHEMA = "liemef.studies.campaign/1"
"""Version tag of ``campaign.json`` (the campaign an output folder holds; checked on resume)."""
TASK_SCHEMA = "liemef.studies.campaign.task/1"
"""Version tag of a line of ``manifest.jsonl`` (one finished task: file, SHA-256, trials, time)."""
RESULT_SCHEMA = "liemef.studies.campaign.result/1"
"""Version tag of ``result.json`` (a finished campaign: tasks, throughput, settings)."""
KEYS = ("name", "experiment", "experiment_file", "quick", "base", "grid", "settings", "seeds", "seed",
        "batch_size", "trials_per_task", "out")
"""The keys of a campaign file, in the order of :class:`Campaign`'s fields."""


class CampaignError(ValueError):
    """A campaign that cannot run as described, or a task that failed; the message names the key or task."""


class CampaignInputError(CampaignError):
    """A campaign that cannot start as given (its out folder holds another campaign or cannot be made): bad input,
    which the command line reports with exit status 2, not a failure of its run."""


def _int(where: str, value: Any, minimum: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise CampaignError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def _plain(where: str, value: Any) -> Any:
    """A setting value as plain JSON data (lists for sequences); a CampaignError for anything else."""
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise CampaignError(f"{where}: expected a finite number, got {value!r}")
        return value
    if isinstance(value, list | tuple):
        return [_plain(f"{where}[{i}]", v) for i, v in enumerate(value)]
    raise CampaignError(f"{where}: expected a number, string, boolean or list, got {type(value).__name__}")


def _table(where: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise CampaignError(f"{where}: expected a table of config fields (name = value), got "
                            f"{type(value).__name__}")
    out = {}
    for k, v in value.items():
        if not isinstance(k, str) or not k:
            raise CampaignError(f"{where}: expected config field names, got {k!r}")
        out[k] = _plain(f"{where}.{k}", v)
    return out


@dataclass(frozen=True)
class Setting:
    """One point of the campaign's grid: ``index`` in :meth:`Campaign.points`, the config ``overrides`` (base,
    then the listed setting, then the grid values) and a ``label`` of the values that vary."""

    index: int
    overrides: dict[str, Any]
    varying: dict[str, Any]

    @property
    def label(self) -> str:
        """``"connection=minus, order=first"`` (the values that vary across settings), or ``"default"``."""
        if not self.varying:
            return "default"
        return ", ".join(f"{k}={_text(v)}" for k, v in self.varying.items())

    @property
    def folder(self) -> str:
        """The output subfolder of this setting: ``s003_connection-minus_order-first`` (file-system safe)."""
        slug = "_".join(f"{k}-{_text(v)}" for k, v in self.varying.items())
        slug = re.sub(r"[^A-Za-z0-9._-]+", "-", slug).strip("-")[:80]
        return f"s{self.index:03d}" + (f"_{slug}" if slug else "")


def _text(v: Any) -> str:
    return ",".join(map(_text, v)) if isinstance(v, list) else str(v)


@dataclass(frozen=True)
class Task:
    """Trials ``[start, stop)`` of setting ``setting``: one compiled-batch job on a worker."""

    setting: int
    start: int
    stop: int

    @property
    def id(self) -> str:
        """``s003-t0000064``: stable across runs of the same campaign (the manifest's key)."""
        return f"s{self.setting:03d}-t{self.start:07d}"

    @property
    def trials(self) -> int:
        """The number of trials of the task."""
        return self.stop - self.start


@dataclass(frozen=True)
class Campaign:
    """A Monte Carlo campaign: ``seeds`` trials of every setting of an experiment.

    Fields (the keys of a campaign file):
        name: a name for the progress display and the tables.
        experiment: a registered experiment (``liemef reproduce --list``), or
        experiment_file: a Python file that defines ``experiment``, a :class:`liemef.studies.experiments.Experiment`
            with a ``trial_fn`` (a user's system, simulation and filter); its text is sent to the workers, so
            it need not exist on their machines. Exactly one of the two.
        quick: start every setting from the experiment's reduced config (``reproduce --quick``) instead of its
            default config.
        base: config overrides shared by every setting (e.g. ``duration``).
        grid: config field -> list of values; every combination is a setting (Cartesian product).
        settings: a list of override tables, each combined with every grid point (default: one, empty).
        seeds: trials per setting; trial i of a setting uses ``jax.random.split(jax.random.key(seed),
            seeds)[i]``, the keys of ``liemef montecarlo --runs seeds --seed seed``.
        seed: the root seed.
        batch_size: trials per compiled ``vmap`` batch (as ``liemef montecarlo --batch-size``).
        trials_per_task: trials per Dask task, a multiple of ``batch_size``: each task runs
            ``trials_per_task / batch_size`` compiled batches.
        out: the output folder.

    Relative paths in a campaign file (``out``, ``experiment_file``) are relative to the file's folder.
    """

    name: str
    out: Path
    experiment: str | None = None
    experiment_file: Path | None = None
    quick: bool = False
    base: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)
    settings: tuple[dict[str, Any], ...] = ({},)
    seeds: int = 100
    seed: int = 0
    batch_size: int = 8
    trials_per_task: int = 64
    _source: str | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        if not isinstance(self.name, str) or not self.name.strip():
            raise CampaignError(f"name: expected a non-empty string, got {self.name!r}")
        if (self.experiment is None) == (self.experiment_file is None):
            raise CampaignError("experiment: expected exactly one of `experiment` (a registered name) and "
                                f"`experiment_file` (a Python file), got experiment={self.experiment!r}, "
                                f"experiment_file={self.experiment_file!r}")
        if self.experiment is not None and not isinstance(self.experiment, str):
            raise CampaignError(f"experiment: expected a registered experiment name, got {self.experiment!r}")
        if self.experiment_file is not None:
            set_("experiment_file", Path(self.experiment_file))
            # read once: the text fingerprinted is the text the workers run, whatever happens to the file later
            try:
                set_("_source", self.experiment_file.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError) as err:
                raise CampaignError(f"experiment_file: cannot read {str(self.experiment_file)!r} ({err})") from None
        if not isinstance(self.quick, bool):
            raise CampaignError(f"quick: expected true or false, got {self.quick!r}")
        set_("out", Path(self.out))
        set_("base", _table("base", self.base))
        grid = _table("grid", self.grid)
        for k, values in grid.items():
            if not isinstance(values, list) or not values:
                raise CampaignError(f"grid.{k}: expected a non-empty list of values, got {values!r}")
            if len({json.dumps(v) for v in values}) != len(values):
                raise CampaignError(f"grid.{k}: expected distinct values, got {values!r}")
        set_("grid", grid)
        settings = self.settings
        if isinstance(settings, Mapping) or not isinstance(settings, Sequence) or not settings:
            raise CampaignError(f"settings: expected a non-empty list of tables, got {settings!r}")
        set_("settings", tuple(_table(f"settings[{i}]", s) for i, s in enumerate(settings)))
        both = sorted(set(grid) & {k for s in self.settings for k in s})
        if both:
            raise CampaignError(f"grid/settings: expected each field in one of them, got {both} in both")
        dead = sorted(set(grid) & set(self.base))
        if dead:  # the grid's values replace it at every point: base's value would be recorded, never run
            raise CampaignError(f"base/grid: expected each field in one of them, got {dead} in both")
        set_("seeds", _int("seeds", self.seeds, 1))
        _int("seed", self.seed, -(2**63))
        set_("batch_size", min(_int("batch_size", self.batch_size, 1), self.seeds))
        tpt = _int("trials_per_task", self.trials_per_task, 1)
        if tpt % self.batch_size:
            raise CampaignError(f"trials_per_task: expected a multiple of batch_size = {self.batch_size} (tasks "
                                f"run whole compiled batches), got {tpt}")

    # --- reading
    @classmethod
    def load(cls, path: str | os.PathLike, **overrides) -> Campaign:
        """A campaign file (``.toml``, or ``.yaml``/``.yml``); ``overrides`` replace its keys (e.g. ``out``).
        CampaignError naming the file and the key for anything missing, unknown or malformed."""
        p = Path(path)
        if not p.is_file():
            raise CampaignError(f"campaign: expected a campaign file (.toml, .yaml), got {str(p)!r} (not found)")
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise CampaignError(f"campaign: cannot read {str(p)!r} ({err})") from err
        suffix = p.suffix.lower()
        try:
            if suffix == ".toml":
                data = tomllib.loads(text)
            elif suffix in (".yaml", ".yml"):
                import yaml

                data = yaml.safe_load(text)
            else:
                raise CampaignError(f"campaign: expected a .toml, .yaml or .yml file, got {str(p)!r}")
        except CampaignError:
            raise
        except Exception as err:  # the parsers' own errors (tomllib.TOMLDecodeError, yaml.YAMLError)
            raise CampaignError(f"campaign: {str(p)!r} is not valid {suffix[1:].upper()}: {err}") from err
        if not isinstance(data, dict):
            raise CampaignError(f"campaign: expected a table of keys in {str(p)!r}, got {type(data).__name__}")
        data = {**data, **{k: v for k, v in overrides.items() if v is not None}}
        return cls.from_dict(data, root=p.parent, where=str(p))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], root: str | os.PathLike = ".", where: str = "campaign"
                  ) -> Campaign:
        """A campaign from its keys (:data:`KEYS`); relative paths are taken from ``root``."""
        unknown = sorted(set(data) - set(KEYS))
        if unknown:
            raise CampaignError(f"{where}: unknown key(s) {unknown}; expected some of {list(KEYS)}")
        for k in ("name", "out"):
            if k not in data:
                raise CampaignError(f"{where}: missing key {k!r}")
        root = Path(root)
        d = dict(data)
        d["out"] = root / Path(d["out"])
        if d.get("experiment_file") is not None:
            d["experiment_file"] = root / Path(d["experiment_file"])
        if "settings" in d and isinstance(d["settings"], list):
            d["settings"] = tuple(d["settings"])
        try:
            return cls(**d)
        except CampaignError as err:
            raise CampaignError(f"{where}: {err}") from None

    # --- expansion
    def points(self) -> list[Setting]:
        """Every setting: each listed setting combined with every grid point, in order (grid fastest)."""
        keys = list(self.grid)
        combos = list(itertools.product(*(self.grid[k] for k in keys)))
        raw = [{**s, **dict(zip(keys, c, strict=True))} for s in self.settings for c in combos]
        varying = [k for k in dict.fromkeys(k for r in raw for k in r)
                   if len({json.dumps(r.get(k)) for r in raw}) > 1]
        return [Setting(index=i, overrides={**self.base, **r}, varying={k: r.get(k) for k in varying if k in r})
                for i, r in enumerate(raw)]

    def tasks(self) -> list[Task]:
        """Every task: for each setting, the trials ``[0, seeds)`` in ranges of ``trials_per_task``."""
        return [Task(s.index, lo, min(lo + self.trials_per_task, self.seeds))
                for s in self.points() for lo in range(0, self.seeds, self.trials_per_task)]

    def experiment_source(self) -> str | None:
        """The text of ``experiment_file``, as read when the campaign was made (None for a registered
        experiment)."""
        return self._source

    # --- identity
    def description(self) -> dict:
        """What determines the results, as JSON data: the experiment (name, or the file and its SHA-256), the
        settings, seeds, seed, batch sizes. Two campaigns with the same description compute the same tasks."""
        src = self.experiment_source()
        exp = ({"registered": self.experiment} if src is None else
               {"file": str(self.experiment_file), "sha256": hashlib.sha256(src.encode()).hexdigest()})
        return {"experiment": exp, "quick": self.quick, "base": self.base, "grid": self.grid,
                "settings": list(self.settings), "seeds": self.seeds, "seed": self.seed,
                "batch_size": self.batch_size, "trials_per_task": self.trials_per_task}

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of :meth:`description` (the experiment file by content, not path)."""
        d = self.description()
        d["experiment"] = {k: v for k, v in d["experiment"].items() if k != "file"}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def to_dict(self) -> dict:
        """The campaign's keys as JSON data (paths as strings)."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}
        d["out"] = str(self.out)
        d["experiment_file"] = None if self.experiment_file is None else str(self.experiment_file)
        d["settings"] = list(self.settings)
        return d
