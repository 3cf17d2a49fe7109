"""Scenario validation: every bad file gives a ConfigError naming the file, line and key."""

from __future__ import annotations

import pytest

from controller.errors import ConfigError
from controller.simulate import load_scenario, run_scenario
from controller.tracking import Mode, SoftMcOptions

# line numbers matter: the cases below replace one line of this text
GOOD = """\
name: test
duration_s: 1.0
engage: 0.02
disengage: 0.8
tracker:
  sample_time_s: 0.002
  planner: softmc
  mode: absolute
  sync_trans: {vel: 2000, acc: 20000, jerk: 400000}
  filter_factor: 1.0
robot:
  position: [-50.0, 40.0, 0.0]
master:
  segments:
    - duration_s: 1.0
      velocity: 300
"""


def write(tmp_path, text, name="s.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def replace_line(lineno: int, new: str) -> str:
    lines = GOOD.splitlines()
    lines[lineno - 1] = new
    return "\n".join(lines) + "\n"


def test_good_file_loads(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    assert sc.params.sample_time_s == 0.002 and sc.params.mode == Mode.ABSOLUTE
    assert sc.engage_samples == (10,) and sc.disengage_samples == (400,)
    assert sc.n_samples == 500


CASES = [
    # (line, new text, expected line, expected key, fragment of the message)
    (6, "  sampel_time_s: 0.002", 6, "tracker.sampel_time_s", "did you mean 'sample_time_s'"),
    (1, "nmae: test", 1, "nmae", "did you mean 'name'"),
    (9, "  sync_trans: {vel: 2000, acc: 20000, jrek: 400000}", 9, "tracker.sync_trans.jrek",
     "did you mean 'jerk'"),
    (16, "      velocty: 300", 16, "master.segments[0].velocty", "did you mean 'velocity'"),
    (10, "  filter_factor: fast", 10, "tracker.filter_factor", "must be a number"),
    (12, "  position: [1, 2]", 12, "robot.position", "list of 3 numbers"),
    (12, "  position: [1, two, 3]", 12, "robot.position", "item 1"),
    (8, "  mode: 4", 8, "tracker.mode", "3 | 5 | absolute | relative"),
    (7, "  planner: softmx", 7, "tracker.planner", "did you mean 'softmc'"),
    # TrackerParams' own range checks, located at the value
    (6, "  sample_time_s: 0.5", 6, "tracker.sample_time_s", "[1e-05...0.1]"),
    (10, "  filter_factor: -1", 10, "tracker.filter_factor", "must be > 0"),
    (9, "  sync_trans: {vel: -5, acc: 20000, jerk: 400000}", 9, "tracker.sync_trans.vel",
     "> 0"),
    # the simulator's own ranges
    (3, "engage: 2.0", 3, "engage", "[0...1) s"),
    (15, "    - duration_s: -1", 15, "master.segments[0].duration_s", "> 0"),
    (4, "disengage: 0.01", 4, "disengage", "alternate"),
    (16, "      velocity: 300\n      acceleration: 5", 17, "master.segments[0].acceleration",
     "at most one of"),
]


@pytest.mark.parametrize("lineno,new,line,key,fragment", CASES)
def test_bad_value_names_file_line_key(tmp_path, lineno, new, line, key, fragment):
    path = write(tmp_path, replace_line(lineno, new))
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    e = info.value
    assert (e.file, e.line, e.key) == (str(path), line, key), str(e)
    assert fragment in str(e)
    assert str(e).startswith(f"{path}:{line}, key '{key}': ")


def test_missing_required_key(tmp_path):
    text = GOOD.replace("  planner: softmc\n", "")
    with pytest.raises(ConfigError) as info:
        load_scenario(write(tmp_path, text))
    assert info.value.key == "tracker.planner" and info.value.line == 5
    assert "required key is missing" in str(info.value)
    text = GOOD.replace("engage: 0.02\n", "")
    with pytest.raises(ConfigError, match="key 'engage': required key is missing"):
        load_scenario(write(tmp_path, text))


def test_yaml_syntax_error_names_line_and_nearest_key(tmp_path):
    path = write(tmp_path, replace_line(9, "  sync_trans: {vel: 2000, acc: 20000"))
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    e = info.value
    assert e.file == str(path) and e.line == 10 and e.key == "sync_trans"
    assert "YAML syntax error" in str(e) and "line 9" in str(e)


def test_duplicate_key(tmp_path):
    path = write(tmp_path, GOOD + "engage: 0.5\n")
    with pytest.raises(ConfigError, match="duplicate key") as info:
        load_scenario(path)
    assert info.value.line == 17 and info.value.key == "engage"


@pytest.mark.parametrize("csv_text,line,key,fragment", [
    ("time_s,x,y,z\n0,0,0,0\n0.002,0.6,0,0\n0.004,abc,0,0\n", 4, "x", "not a number"),
    ("time_s,x,y,z\n0,0,0,0\n0.002,0.6,0\n", 3, "z", "expected 4 values"),
    ("time_s,x,y,z\n0,0,0,0\n0,0.6,0,0\n", 3, "time_s", "must increase"),
    ("time_s,x,y,zz\n0,0,0,0\n", 1, "zz", "did you mean 'z'"),
    ("time_s,x,y,z,vx\n0,0,0,0,1\n", 1, "vy", "give all of vx, vy, vz"),
    ("# recorded\ntime_s,x,y\n0,0,0\n", 2, "z", "required column missing"),
    ("time_s,x,y,z\n0.1,0,0,0\n0.2,0,0,0\n", 2, "time_s", "must be <= 0"),
])
def test_bad_csv_row_names_csv_file_line_column(tmp_path, csv_text, line, key, fragment):
    (tmp_path / "m.csv").write_text(csv_text)
    text = GOOD.replace("  segments:\n    - duration_s: 1.0\n      velocity: 300\n",
                        "  csv: m.csv\n").replace("duration_s: 1.0\n", "duration_s: 0.002\n")
    text = text.replace("engage: 0.02\ndisengage: 0.8\n", "engage: 0.0\n")
    with pytest.raises(ConfigError) as info:
        load_scenario(write(tmp_path, text))
    e = info.value
    assert (e.file, e.line, e.key) == (str(tmp_path / "m.csv"), line, key), str(e)
    assert fragment in str(e)


def test_missing_csv_file_is_located_in_the_scenario(tmp_path):
    text = GOOD.replace("  segments:\n    - duration_s: 1.0\n      velocity: 300\n",
                        "  csv: nowhere.csv\n")
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match="cannot read the master CSV") as info:
        load_scenario(path)
    assert (info.value.file, info.value.line, info.value.key) == (str(path), 14, "master.csv")


def test_speed_change_too_short(tmp_path):
    text = GOOD.replace("      velocity: 300\n", "      velocity: 100\n"
                        "    - speed_change: {to: 500, acc: 1000, jerk: 10000}\n"
                        "      duration_s: 0.1\n")
    with pytest.raises(ConfigError, match="needs 0.5 s") as info:
        load_scenario(write(tmp_path, text))
    assert info.value.line == 18 and info.value.key == "master.segments[1].duration_s"


def test_mapping_errors_name_the_key_without_a_line():
    d = {"engage": 0.0, "tracker": {"sample_time_s": 0.002, "planner": "softmc",
                                    "rates": {"acc": 150}},
         "robot": {"position": [0, 0, 0]},
         "master": {"segments": [{"duration_s": 1, "velocity": 100}]}}
    with pytest.raises(ConfigError) as info:
        run_scenario(d)
    assert info.value.key == "tracker.rates.acc" and info.value.line is None
    assert "(0...100]" in str(info.value)


def test_softmc_literal_shortcut_and_overrides(tmp_path):
    text = GOOD.replace(
        "  filter_factor: 1.0\n",
        "  filter_factor: 1.0\n  softmc: {literal: true, end_of_sample_feedback: true}\n")
    sc = load_scenario(write(tmp_path, text))
    expected = SoftMcOptions.literal()
    assert sc.params.softmc.pred_acc_from_master == expected.pred_acc_from_master is False
    assert sc.params.softmc.end_of_sample_feedback is True


def test_yaml_12_floats_and_partial_limits(tmp_path):
    text = GOOD.replace("  sample_time_s: 0.002", "  sample_time_s: 2e-3").replace(
        "  sync_trans: {vel: 2000, acc: 20000, jerk: 400000}", "  sync_trans: {vel: 1e3}")
    sc = load_scenario(write(tmp_path, text))
    assert sc.params.sample_time_s == 0.002
    assert sc.params.sync_trans.vel == 1000.0
    assert sc.params.sync_trans.acc == 20000.0  # the TrackerParams default


def test_optimal_planner_unavailable_or_runs(tmp_path):
    text = GOOD.replace("  planner: softmc", "  planner: optimal")
    try:
        import controller.tracking.optimal  # noqa: F401
    except ImportError:
        with pytest.raises(ConfigError, match="not available") as info:
            load_scenario(write(tmp_path, text))
        assert info.value.line == 7
    else:
        r = run_scenario(write(tmp_path, text))
        assert r.cycles[0].synced_after_s is not None
