"""Statistics windows follow `liemef montecarlo --duration`: a window that would start at or after the shorter
final time T moves in proportion (t -> t T / T0), so every window of a short run holds samples; a window that
starts before T is kept, and without a new duration the config is the study's own."""

import numpy as np
import pytest

from liemef.metrics import window_mask
from liemef.studies.experiments import get_experiment
from liemef.studies.registry import DURATION_RULE
from liemef.studies.settings import experiment_config

WINDOWED = ("tse2", "tse2-velocity", "attitude", "localization")


def follow(exp, **options):
    return experiment_config(exp, options=options, windows_follow=True)


def test_no_duration_leaves_the_config_as_it_is():
    for name in WINDOWED:
        exp = get_experiment(name)
        assert experiment_config(exp, windows_follow=True) == exp.default_config
        assert follow(exp, duration=exp.default_config.duration) == exp.default_config
        assert experiment_config(exp, quick=True, windows_follow=True) == exp.quick()


def test_a_window_past_the_end_moves_in_proportion():
    exp = get_experiment("tse2")
    assert exp.default_config.duration == 50.0 and exp.default_config.steady == (10.0, 50.0)
    assert follow(exp, duration=5.0).steady == (1.0, 5.0)
    assert follow(exp, duration=10.0).steady == (2.0, 10.0)
    assert experiment_config(exp, items=["duration=5"], windows_follow=True).steady == (1.0, 5.0)
    quick = exp.quick()
    assert experiment_config(exp, quick=True, options={"duration": 5.0}, windows_follow=True).steady == \
        pytest.approx(tuple(t * 5.0 / quick.duration for t in quick.steady))
    loc = get_experiment("localization")
    assert follow(loc, duration=10.0).steady == pytest.approx(
        loc.default_config.steady * 10.0 / loc.default_config.duration)


def test_a_window_that_starts_within_the_run_is_kept():
    exp = get_experiment("tse2")
    assert follow(exp, duration=12.0).steady == (10.0, 50.0)
    assert follow(exp, duration=100.0).steady == (10.0, 50.0)


def test_without_windows_follow_the_windows_are_the_studys():
    exp = get_experiment("tse2")
    assert experiment_config(exp, options={"duration": 5.0}).steady == (10.0, 50.0)


def test_the_inertial_benchmark_window_moves_too():
    from liemef.studies.experiments.inertial import InertialConfig

    c = InertialConfig()
    assert c.window_changes(c.duration) == {}
    assert c.window_changes(c.steady / 2.0) == {"steady": pytest.approx(c.steady * c.steady / 2.0 / c.duration)}


def test_a_window_set_by_the_user_wins():
    exp = get_experiment("tse2")
    assert experiment_config(exp, options={"duration": 5.0}, items=["steady=2,4"],
                             windows_follow=True).steady == (2.0, 4.0)


def test_a_bad_duration_is_named_by_the_config():
    with pytest.raises(ValueError, match="duration"):
        follow(get_experiment("tse2"), duration=-1.0)


@pytest.mark.parametrize("name", WINDOWED)
def test_every_window_of_a_short_run_holds_samples(name):
    exp = get_experiment(name)
    config = follow(exp, duration=5.0)
    assert config.duration == 5.0
    spec = exp.trial_fn(config)
    ts = np.asarray(spec.ts)
    for w in spec.windows:
        assert int(np.sum(np.asarray(window_mask(ts, w)))) > 0, (name, w.label)


def test_the_rule_is_in_the_montecarlo_help():
    from click.testing import CliRunner

    from liemef.cli import cli

    out = CliRunner().invoke(cli, ["montecarlo", "--help"], terminal_width=1000).output
    assert DURATION_RULE in " ".join(out.split())
