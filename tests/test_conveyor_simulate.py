"""``cantrack simulate`` with conveyor scenarios: the examples, summary, trace, plot, CLI,
replay of recorded logs, and scenario errors with file/line/key."""

from __future__ import annotations

import copy
import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from controller import cli
from controller.conveyor import ITEM_MISSED_CODE
from controller.errors import ConfigError
from controller.simulate import format_summary, load_scenario, run_scenario, write_trace
from controller.simulate.conveyor import (CONVEYOR_TRACE_COLUMNS, ConveyorScenario, write_logs)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


# (the examples' results: the session fixtures `linear` and `rotary` of conftest.py)


def small(**changes) -> dict:
    """A small valid conveyor scenario (mapping)."""
    d = {
        "duration_s": 3.0,
        "tracker": {"sample_time_s": 0.002, "planner": "softmc"},
        "conveyor": {
            "frame": {"type": "linear", "window": {"upstream": 50, "downstream": 900}},
            "master": {"speed": 200.0},
            "items": {"trigger_times": [0.1]},
            "robot": {"start": [300.0, 300.0, 100.0]},
            "program": {"place": [300.0, 300.0, 100.0]},
        },
    }
    for k, v in changes.items():
        cur = d
        *head, last = k.split(".")
        for h in head:
            cur = cur[h]
        if v is None:
            del cur[last]
        else:
            cur[last] = v
    return d


# -- the examples ----------------------------------------------------------------------------
def test_example_conveyor_linear_items_caught_and_one_skipped_by_the_prediction(linear):
    r = linear
    assert isinstance(r.scenario, ConveyorScenario)
    assert len(r.records) == 6 and len(r.picks) == 5 and r.caught == 5 and r.missed == 0
    assert list(r.skipped) == [5] and "leaves the window" in r.skipped[5]
    for rec in r.records:
        if rec.caught:
            assert 0.3 < rec.time_to_sync_s < 1.2
            assert rec.peak_error_synced_mm < 1e-6
            p = r.predictions[rec.item_id]
            assert p.can_catch and p.time_s == pytest.approx(rec.synced_s, abs=1e-9)
    # the robot is back at the place position at the end, de-synchronised
    assert r.setpoint_pos[-1] == pytest.approx((450.0, 400.0, 120.0), abs=1e-9)
    assert r.imfs[-1] == 0 and r.slave[-1] == 0


def test_example_conveyor_rotary_item_missed_30238_and_picks_on_the_arc(rotary):
    r = rotary
    assert r.missed == 1 and len(r.picks) == 5
    missed = [e for e in r.events if e.kind == "item_missed"]
    assert len(missed) == 1 and missed[0].code == ITEM_MISSED_CODE and missed[0].item == 3
    T = r.sample_time_s
    f = r.frame
    # at each pick the TCP is on the item: position and orientation (Q(x + Delta, v))
    for rec, trig in zip(r.records, r.triggers):
        if rec.item_id not in r.picks:
            continue
        k = round(r.picks[rec.item_id] / T)
        geo = f.geometry()
        c = geo.coords([r.master_value[k]], trig.values)
        here = geo.point(c, (0.0,), (0.0,), trig.dr_mm).here
        assert np.linalg.norm(r.setpoint_pos[k] - np.array(here.pos)) < 1e-6
        q = r.setpoint_ori[k]
        assert abs(abs(float(np.dot(q, here.ori))) - 1.0) < 1e-9
        radius = np.linalg.norm(r.setpoint_pos[k, :2] - np.array(f.center[:2]))
        assert radius == pytest.approx(400.0 + trig.dr_mm, abs=1e-6)


def test_conveyor_summary_lists_items_times_errors(linear, rotary):
    s = format_summary(linear)
    assert "6 triggered: 5 caught, 5 picked, 0 missed (30238), 1 skipped" in s
    assert "to sync" in s and "peak err" in s and "prediction" in s
    assert "item 5 skipped: not synchronised before the item leaves the window" in s
    s = format_summary(rotary)
    assert "item_missed [30238]  item 3" in s and "R 400.0 mm, alpha 180.0 deg" in s


def test_conveyor_trace_and_plot(rotary, tmp_path):
    out = write_trace(rotary, tmp_path / "t.csv")
    rows = list(csv.reader(out.read_text().splitlines()))
    assert tuple(rows[0]) == CONVEYOR_TRACE_COLUMNS
    assert len(rows) == rotary.scenario.n_samples + 2
    assert any("item_missed(3)[30238]" in r[-1] for r in rows[1:])
    assert float(rows[-1][2]) == rotary.setpoint_pos[-1, 0]    # exact (repr)
    from controller.simulate import plot_result

    png = plot_result(rotary, tmp_path / "t.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000


def test_cli_simulate_conveyor_with_plot_and_record(tmp_path, capsys):
    code = cli.main(["simulate", str(EXAMPLES / "conveyor_linear.yaml"), "-o",
                     str(tmp_path / "run.csv"), "--plot", "--record", str(tmp_path / "rec")])
    assert code == 0
    out = capsys.readouterr().out
    assert "5 picked" in out and "rec_triggers.csv" in out and "rec_encoder.csv" in out
    assert (tmp_path / "run.png").is_file()
    code = cli.main(["simulate", str(EXAMPLES / "linear_absolute.yaml"), "-o",
                     str(tmp_path / "x.csv"), "-q", "--record", str(tmp_path / "r")])
    assert code == 2
    assert "--record applies to conveyor scenarios" in capsys.readouterr().err


# -- replay through the simulator ------------------------------------------------------------
def test_replay_of_recorded_logs_reproduces_the_run_exactly(linear, tmp_path):
    trig, enc = write_logs(linear, tmp_path / "rec")
    d = yaml.safe_load((EXAMPLES / "conveyor_linear.yaml").read_text())
    d["conveyor"]["master"] = {"log": str(enc), "encoder": d["conveyor"]["master"]["encoder"]}
    d["conveyor"]["items"] = {"log": str(trig)}
    r = run_scenario(d)
    assert np.array_equal(r.setpoint_pos, linear.setpoint_pos)
    assert np.array_equal(r.imfs, linear.imfs)
    assert [x.as_dict() for x in r.records] == [x.as_dict() for x in linear.records]


def test_scenario_with_segment_profile_master_and_items_csv(tmp_path):
    (tmp_path / "items.csv").write_text("# sensor\ntime_s,dr_mm\n0.1,0\n0.4,0\n")
    d = small(**{"conveyor.master": {"profile": {"initial_speed": 100.0, "segments": [
        {"speed_change": {"to": 250.0, "acc": 400.0, "jerk": 4000.0}},
        {"duration_s": 2.0}]}},
        "conveyor.items": {"csv": "items.csv"}, "duration_s": 4.0})
    r = run_scenario(d, base_dir=tmp_path)
    assert len(r.records) == 2 and r.caught >= 1
    assert r.master_value[-1] > r.master_value[0]


def test_old_scenario_format_still_loads_as_a_tracking_scenario():
    from controller.simulate.scenario import Scenario

    assert isinstance(load_scenario(EXAMPLES / "linear_absolute.yaml"), Scenario)


# -- scenario errors -------------------------------------------------------------------------
def _yaml_error(tmp_path, d) -> ConfigError:
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    with pytest.raises(ConfigError) as exc:
        load_scenario(p)
    return exc.value


def test_conveyor_scenario_errors_name_file_line_and_key(tmp_path):
    e = _yaml_error(tmp_path, small(**{"conveyor.frame.windw": {"upstream": 1}}))
    assert e.key == "conveyor.frame.windw" and "did you mean 'window'" in str(e)
    assert e.file.endswith("s.yaml") and e.line is not None
    e = _yaml_error(tmp_path, small(**{"conveyor.frame.window": {"upstream": 500,
                                                                 "downstream": 100}}))
    assert e.key == "conveyor.frame.window.downstream" and "> upstream" in str(e)
    e = _yaml_error(tmp_path, small(**{"conveyor.frame.type": "spiral"}))
    assert e.key == "conveyor.frame.type"
    e = _yaml_error(tmp_path, small(**{"conveyor.frame.arc_point": [1, 2, 3]}))
    assert e.key == "conveyor.frame.arc_point" and "rotary" in str(e)
    rot = small(**{"conveyor.frame": {
        "type": "rotary", "upstream": {"position": [0, 0, 0]}, "arc_point": [100, 0, 0],
        "downstream": [200, 0, 0], "down_master": 90, "window": {"upstream": 1,
                                                                 "downstream": 80}}})
    e = _yaml_error(tmp_path, rot)
    assert e.key == "conveyor.frame.arc_point" and "collinear" in str(e)
    e = _yaml_error(tmp_path, small(**{"conveyor.master": {"speed": 1, "log": "x.csv"}}))
    assert "exactly one of" in str(e)
    e = _yaml_error(tmp_path, small(**{"conveyor.items.trigger_times": [0.5, 0.1]}))
    assert e.key == "conveyor.items.trigger_times" and "increasing" in str(e)
    e = _yaml_error(tmp_path, small(**{"conveyor.robot.slave": 4}))
    assert e.key == "conveyor.robot.slave"
    e = _yaml_error(tmp_path, small(**{"duration_s": None}))
    assert e.key == "duration_s"
    (tmp_path / "bad.csv").write_text("time_s,dr_mm\n0.1,abc\n")
    e = _yaml_error(tmp_path, small(**{"conveyor.items": {"csv": "bad.csv"}}))
    assert e.file.endswith("bad.csv") and e.line == 2 and e.key == "dr_mm"


def test_full_trigger_buffer_is_reported_not_dropped_silently():
    d = small(**{"conveyor.robot.buffer_capacity": 2,
                 "conveyor.items.trigger_times": [0.1, 0.15, 0.2, 0.25]})
    r = run_scenario(copy.deepcopy(d))
    rejected = [e for e in r.events if e.kind == "trigger_rejected"]
    assert len(rejected) == 2 and "full" in rejected[0].message
    assert len(r.records) == 2
