"""Mutated bus.yml, scenario and EDS files: a clear error naming the place, or accepted and
right -- never a traceback (controller.testing.mutants; the larger run is
benchmarks/mutants.py)."""

from __future__ import annotations

import random

import pytest
from hypothesis import HealthCheck, given, settings

from controller.errors import ConfigError
from controller.simulate.scenario import load_scenario
from controller.testing import mutants as mu
from controller.testing.mutant_runs import BusFamily, ScenarioFamily
from controller.yamlmarks import load_marked

SETTINGS = dict(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@pytest.fixture(scope="module")
def bus_family(tmp_path_factory):
    return BusFamily(tmp_path_factory.mktemp("bus"))


@pytest.fixture(scope="module")
def scenario_family(tmp_path_factory):
    return ScenarioFamily(tmp_path_factory.mktemp("scenario"))


@settings(max_examples=40, **SETTINGS)
@given(rng=mu.strategy(lambda r: r))
def test_bus_mutants_are_refused_clearly_or_run(bus_family, rng: random.Random):
    answer = bus_family.judge(bus_family.mutant(rng))
    assert answer.verdict.ok, str(answer)


@settings(max_examples=80, **SETTINGS)
@given(rng=mu.strategy(lambda r: r))
def test_scenario_mutants_are_refused_clearly_or_run(scenario_family, rng: random.Random):
    answer = scenario_family.judge(scenario_family.mutant(rng))
    assert answer.verdict.ok, str(answer)


@pytest.mark.parametrize("text, line, key, words", [
    ("a: 1\nb: x\0y\n", 2, "b", "NUL byte"),
    ("a: 1\nb: " + "[" * 5000 + "]" * 5000 + "\n", 2, "b", "nested more than 50"),
    ("a:\n  b: " + "7" * 5000 + "\n", 2, "b", "5000 digits"),
    ("a: \x07\n", 1, "a", "#x0007"),
])
def test_yaml_that_python_yaml_cannot_take_is_a_placed_error(text, line, key, words):
    with pytest.raises(ConfigError) as e:
        load_marked(text, "f.yml")
    msg = str(e.value)
    assert msg.startswith(f"f.yml:{line}, key '{key}'") and words in msg, msg


def test_the_issues_scenario_mutants(tmp_path):
    base = (tmp_path / "s.yaml")
    text = ("duration_s: 1.0\nengage: 0.1\ntracker: {sample_time_s: 0.002, planner: softmc, mode: absolute}\n"
            "robot: {position: [0, 0, 0]}\n"
            "master: {segments: [{duration_s: 1.0, velocity: 300}]}\n")
    # (the base is right)
    base.write_text(text)
    load_scenario(base)
    cases = [
        (text.replace("duration_s: 1.0\n", "duration_s:\n", 1), 1, "duration_s",
         "has no value"),
        (text + "estimator: {window: .nan}\n", 6, "estimator.window", "finite"),
        (text.replace("position: [0, 0, 0]", "position: [1.0e300, 0, 0]"), 4,
         "robot.position", "out of range"),
        (text.replace("planner: softmc", "planner: softmc, damping_factor: 1e300"),
         3, "tracker", "damping_factor"),
    ]
    for t, line, key, words in cases:
        base.write_text(t)
        with pytest.raises(ConfigError) as e:
            load_scenario(base)
        msg = str(e.value)
        assert f"s.yaml:{line}, key '{key}" in msg and words in msg, msg
