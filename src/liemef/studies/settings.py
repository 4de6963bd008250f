"""A study's config from text: the ``--set KEY=VALUE`` options of ``liemef reproduce``, ``montecarlo`` and
``compare``, each value parsed as the type of the field it replaces, checked by the config itself.

Errors are :class:`OptionError` (a ValueError that names the option it came from), so that a command line
reports them as bad input against the right option.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from typing import Any


class OptionError(ValueError):
    """A ValueError about one option (``option``, e.g. ``"--set"``)."""

    def __init__(self, message: str, option: str):
        super().__init__(message)
        self.option = option


def parse_value(text: str, current: Any, key: str) -> Any:
    """``text`` as a value of the type of the config field's ``current`` value (bool, int, float, str, a tuple
    of those separated by commas, else JSON or the text itself)."""
    try:
        if isinstance(current, bool):
            low = text.lower()
            if low not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError("expected true or false")
            return low in ("true", "1", "yes", "on")
        if isinstance(current, int):
            return int(text)
        if isinstance(current, float):
            return float(text)
        if isinstance(current, str):
            return text
        if isinstance(current, tuple | list):
            item = current[0] if len(current) else 0.0
            return tuple(parse_value(part, item, key) for part in text.replace(",", " ").split())
        try:
            return json.loads(text)
        except ValueError:
            return text
    except ValueError as err:
        raise OptionError(f"{key}: expected a value like {current!r}, got {text!r} ({err})", "--set") from err


def parse_settings(items: Sequence[str], base: Any) -> dict:
    """``KEY=VALUE`` items as overrides of the config dataclass ``base``, each parsed as the type of its field."""
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise OptionError(f"expected KEY=VALUE, got {item!r}", "--set")
        if key not in fields:
            raise OptionError(f"unknown config option {key!r}; expected one of {sorted(fields)}", "--set")
        if key in out:  # the later would silently win
            raise OptionError(f"{key}: expected each key once, got it twice", "--set")
        out[key] = parse_value(text.strip(), fields[key], key)
    return out


def experiment_config(experiment, quick: bool = False, options: dict | None = None, items: Sequence[str] = (),
                      windows_follow: bool = False, own: dict[str, str] | None = None):
    """The config of ``experiment`` (its reduced one when ``quick``) with ``options`` (None values left out) and
    the ``KEY=VALUE`` ``items`` replaced; ValueError from the config's own checks. A key both given by an option
    and set in ``items``, or set in ``items`` where the command takes it from an option of its own (``own``: key
    -> why), is refused naming ``--set``: one would silently win.

    With ``windows_follow`` (``liemef montecarlo``), a new ``duration`` T moves the statistics windows that would
    start at or after it (:data:`liemef.studies.registry.DURATION_RULE`, ``RunConfig.window_changes``): their
    times scale by T / T0, T0 the base config's duration, unless the window is set itself. Without a new
    duration nothing changes."""
    base = experiment.quick() if quick else experiment.default_config
    overrides = {k: v for k, v in (options or {}).items() if v is not None}
    settings = parse_settings(items, base)
    for key in settings:
        if key in overrides:
            raise OptionError(f"{key}: given both by --{key} and by --set; expected it once", "--set")
        if key in (own or {}):
            raise OptionError(f"{key}: expected no --set {key}: {own[key]}", "--set")
    overrides.update(settings)
    if windows_follow and "duration" in overrides and hasattr(base, "window_changes"):
        changes = base.window_changes(overrides["duration"])
        overrides = {**{k: v for k, v in changes.items() if k not in overrides}, **overrides}
    return experiment.quick(**overrides) if quick else experiment.config(**overrides)


TRIAL_OPTIONS = ("runs", "seed", "filters")
"""The settings of a comparison that have their own option (``--runs``, ``--seed``, ``--filters``)."""


def comparison_settings(study: str, settings: type, runs: int | None = None, seed: int = 0,
                        filters: str | None = None, items: Sequence[str] = ()) -> Any:
    """The ``settings`` dataclass of the comparison ``study`` from its options and ``KEY=VALUE`` ``items``
    (numbers, JSON, comma-separated lists for ``angles_deg``, names as text; the study checks them)."""
    fields = {f.name: f for f in dataclasses.fields(settings)}
    kwargs = {}
    for key, value in (("runs", runs), ("seed", seed), ("filters", filters)):
        if value is not None and not (key == "seed" and value == 0):
            if key not in fields:
                raise OptionError(f"{study} has no {key} (a recording, not trials)", f"--{key}")
            kwargs[key] = value
    given = set()
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in fields or key in TRIAL_OPTIONS:
            allowed = sorted(k for k in fields if k not in TRIAL_OPTIONS)
            raise OptionError(f"expected KEY=VALUE with KEY one of {allowed}, got {item!r}", "--set")
        if key in given:  # the later would silently win
            raise OptionError(f"{key}: expected each key once, got it twice", "--set")
        given.add(key)
        try:
            parsed = json.loads(f"[{value}]") if key == "angles_deg" else json.loads(value)
        except json.JSONDecodeError:
            parsed = value  # a name or a list of names (trials=01,07; realdata=PATH): the study checks it
        default = fields[key].default
        number = isinstance(parsed, int | float) and not isinstance(parsed, bool)
        if isinstance(default, int | float) and not isinstance(default, bool) and not number:
            raise OptionError(f"{key}: expected a number, got {value!r}", "--set")
        kwargs[key] = value if isinstance(parsed, bool) else parsed  # true/false is no number: left as text
    try:
        return settings(**kwargs)
    except TypeError as err:
        raise ValueError(str(err)) from err
