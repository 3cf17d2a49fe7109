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

SETTINGS = {"deadline": None, "derandomize": True, "database": None,
            "suppress_health_check": [HealthCheck.function_scoped_fixture,
                                      HealthCheck.too_slow]}


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


@pytest.fixture(scope="module")
def eds_family(tmp_path_factory):
    from controller.testing.mutant_runs import EdsFamily
    return EdsFamily(tmp_path_factory.mktemp("eds"))


@settings(max_examples=40, **SETTINGS)
@given(rng=mu.strategy(lambda r: r))
def test_eds_mutants_are_refused_clearly_or_run(eds_family, rng: random.Random):
    answer = eds_family.judge(eds_family.mutant(rng))
    assert answer.verdict.ok, str(answer)


SERVO = """[1A00sub0]
ParameterName=Number of mapped objects
ObjectType=0x7
DataType=0x0005
AccessType=rw
DefaultValue=2
PDOMapping=0
"""


@pytest.mark.parametrize("old, new, key, words", [
    ("AccessType=rw\nDefaultValue=2", "AccessType=xx\nDefaultValue=2", "AccessType", "must be one of"),
    ("ObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=2",
     "ObjectType=0x99\nDataType=0x0005\nAccessType=rw\nDefaultValue=2", "ObjectType", "0x7 VAR"),
    ("DataType=0x0005\nAccessType=rw\nDefaultValue=2",
     "DataType=0xFFFF\nAccessType=rw\nDefaultValue=2", "DataType", "not a CiA 301 data type"),
    ("DefaultValue=2\nPDOMapping=0", "DefaultValue=2\nPDOMapping=7", "PDOMapping", "0 or 1"),
    ("DefaultValue=2\nPDOMapping=0", "DefaultValue=256\nPDOMapping=0", "DefaultValue",
     "outside UNSIGNED8"),
])
def test_the_issues_eds_mutants_name_file_section_and_key(tmp_path, old, new, key, words):
    from controller.canopen.protocol.eds_check import check_eds
    from controller.testing.mutant_runs import EDS_DIR
    text = (EDS_DIR / "cantrack-servo.eds").read_text()
    assert SERVO in text
    bad = tmp_path / "servo.eds"
    bad.write_text(text.replace(SERVO, SERVO.replace(old, new)))
    with pytest.raises(ConfigError) as e:
        check_eds(bad)
    msg = str(e.value)
    line = text[:text.index(SERVO)].count("\n") + 1 + SERVO[:SERVO.index(old)].count("\n")
    assert f"servo.eds:{line}" in msg or f"servo.eds:{line + 1}" in msg, msg
    assert f"key '[1A00sub0] {key}'" in msg and words in msg, msg


def test_a_deleted_sub_index_or_mandatory_object_is_named(tmp_path):
    from controller.canopen.protocol.eds_check import check_eds
    from controller.testing.mutant_runs import EDS_DIR
    text = (EDS_DIR / "cantrack-servo.eds").read_text()
    bad = tmp_path / "servo.eds"
    bad.write_text(text.replace(SERVO, ""))  # the KeyError of the issue
    with pytest.raises(ConfigError, match=r"\[1A00\] SubNumber.*\(=\d+\) but the file has"):
        check_eds(bad)
    i = text.index("[6041]")
    j = text.index("\n[", i + 1)
    bad.write_text(text[:i] + text[j + 1:])  # the statusword, mandatory for CiA 402
    with pytest.raises(ConfigError, match=r"6041"):
        check_eds(bad)
