"""Conveyor scenarios of ``cantrack simulate``: fixes of the audit.

- the pick program with ``slave: 3`` (absolute) picks at the items on the belt;
- per-item ``left_s`` after the program re-engages an item (and the plot's missed cross);
- the trigger log's robot and frame columns are checked against the scenario.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from controller import cli
from controller.conveyor.replay import (TriggerEvent, check_trigger_log, read_trigger_log,
                                        write_trigger_log)
from controller.errors import ConfigError
from controller.simulate import run_scenario
from controller.simulate.conveyor import ConveyorResult, write_logs
from controller.simulate.plot import marker_points

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

#: Synchronised, the frame's contribution is the core's exact copy of the master and the
#: virtual robot stands still at the end of the relative moves, so the TCP is on the item up
#: to the rounding of a few additions of ~1e3 mm doubles (~1e-13 mm); 1e-6 mm leaves margin
#: for that and is far below anything physical.  A wrong program is off by >= 60 mm.
PICK_TOL_MM = 1e-6


def _linear_doc() -> dict:
    return yaml.safe_load((EXAMPLES / "conveyor_linear.yaml").read_text())


# (the examples' results: the session fixtures `linear` and `rotary` of conftest.py)


@pytest.fixture(scope="module")
def linear_slave3() -> ConveyorResult:
    d = _linear_doc()
    d["conveyor"]["robot"]["slave"] = 3
    return run_scenario(d, base_dir=EXAMPLES)


def _picks_on_items(r: ConveyorResult) -> dict[int, float]:
    """{item: |TCP - item position| at the pick} (the item's <MF>.here at that sample)."""
    T = r.sample_time_s
    out = {}
    for rid, t in r.picks.items():
        k = round(t / T)
        out[rid] = float(np.linalg.norm(r.setpoint_pos[k] - r.item_position(rid, k)))
    return out


# -- 1. slave = 3 (absolute) --------------------------------------------------------------------
def test_slave_3_pick_program_picks_at_the_items_on_the_belt(linear_slave3):
    r = linear_slave3
    assert r.scenario.robot.slave == 3
    assert r.picks, "no item picked"
    T = r.sample_time_s
    for rid, t in r.picks.items():
        k = round(t / T)
        tcp = r.setpoint_pos[k]
        # on the belt (y = 0, z = 0: the belt's line), at the item, synchronised
        assert abs(tcp[1]) < PICK_TOL_MM and abs(tcp[2]) < PICK_TOL_MM, (rid, tcp)
        assert np.linalg.norm(tcp - r.item_position(rid, k)) < PICK_TOL_MM, (rid, tcp)
        assert r.imfs[k] == 1
        # inside the window (150 ... 1100 mm after the sensor)
        assert 150.0 <= r.item_coords(rid, k)[0] <= 1100.0
    assert all(d < PICK_TOL_MM for d in _picks_on_items(r).values())


def test_slave_3_hovers_approach_mm_above_the_item_before_going_down(linear_slave3):
    """As with slave 5: synchronised approach_mm (60 mm) above the item, then down."""
    r = linear_slave3
    T = r.sample_time_s
    for rec in r.records:
        if rec.item_id not in r.picks:
            continue
        ke, ks = rec.engaged_sample, rec.synced_sample
        # the virtual robot: only the relative hover move (60 mm up) between engage and sync
        dv = r.virtual_pos[ks] - r.virtual_pos[ke]
        assert dv == pytest.approx((0.0, 0.0, 60.0), abs=1e-9)
        # synchronised: the TCP is at the item's x/y (the switch sample itself is the last
        # step of the approach) and 60 mm above it (the down move starts at once: 1 sample)
        here = r.item_position(rec.item_id, ks + 1)
        assert np.linalg.norm(r.setpoint_pos[ks + 1, :2] - here[:2]) < PICK_TOL_MM
        assert r.setpoint_pos[ks + 1, 2] == pytest.approx(60.0, abs=0.01)
        k_pick = round(r.picks[rec.item_id] / T)
        assert r.setpoint_pos[k_pick, 2] == pytest.approx(0.0, abs=PICK_TOL_MM)


def test_slave_3_every_caught_item_is_picked_or_has_a_reason(linear_slave3):
    r = linear_slave3
    caught = {rec.item_id for rec in r.records if rec.caught}
    assert set(r.picks) <= caught <= set(r.picks) | set(r.unpicked)
    assert len(r.picks) == r.caught == 5
    for why in r.unpicked.values():
        assert why
    # the item the prediction said no to is skipped with its reason
    assert list(r.skipped) == [5] and "leaves the window" in r.skipped[5]
    # the prediction agrees with the run (the same algorithm, slave 3's reference)
    for rec in r.records:
        if rec.caught:
            assert r.predictions[rec.item_id].time_s == pytest.approx(rec.synced_s, abs=1e-9)


def test_slave_5_examples_unchanged_picks_on_the_items(linear, rotary):
    for r in (linear, rotary):
        assert r.picks and all(d < PICK_TOL_MM for d in _picks_on_items(r).values())
        caught = {rec.item_id for rec in r.records if rec.caught}
        assert set(r.picks) <= caught <= set(r.picks) | set(r.unpicked)


def test_cli_summary_with_slave_3(tmp_path, capsys):
    d = _linear_doc()
    d["conveyor"]["robot"]["slave"] = 3
    p = tmp_path / "cl3.yaml"
    p.write_text(yaml.safe_dump(d))
    assert cli.main(["simulate", str(p), "-o", str(tmp_path / "t.csv")]) == 0
    out = capsys.readouterr().out
    assert "slave 3" in out and "5 caught, 5 picked" in out


# -- 2. left_s after a re-engage -----------------------------------------------------------------
@pytest.mark.parametrize("name", ["linear", "rotary"])
def test_left_s_is_not_before_entered_s(name, linear, rotary):
    r = {"linear": linear, "rotary": rotary}[name]
    for rec in r.records:
        if rec.entered_s is not None and rec.left_s is not None:
            assert rec.left_s >= rec.entered_s, rec.as_dict()
        if rec.caught:
            assert rec.left_s is not None and rec.left_s >= rec.synced_s
        if rec.item_id in r.picks:
            assert rec.left_s >= r.picks[rec.item_id]
    # the item paths of the plot run past the item's leave
    for rec in r.records:
        ts, _ = r.item_paths[rec.item_id]
        if rec.left_s is not None:
            assert ts[-1] >= min(rec.left_s, r.time_s[-1]) - 1e-9


def test_rotary_missed_cross_is_drawn_at_the_window_exit(rotary):
    r = rotary
    rec = next(x for x in r.records if x.item_id == 3)
    assert rec.missed and rec.left_sample == rec.missed_sample
    _, missed = marker_points(r)
    assert list(missed) == [3]
    # the item's arc angle at the cross: the window's downstream limit (45 deg after the
    # sensor), reached within one sample (15 deg/s * 2 ms = 0.03 deg)
    x = r.item_coords(3, rec.missed_sample)[0]
    assert 45.0 <= x < 45.0 + 15.0 * r.sample_time_s + 1e-9
    assert np.linalg.norm(missed[3] - r.item_position(3, rec.missed_sample)) < 1e-9
    # on the item's circle (R = 400 mm + its radius offset dR about the table's center)
    dr = r.triggers[2].dr_mm
    radius = np.linalg.norm(missed[3][:2] - np.array(r.frame.center[:2]))
    assert radius == pytest.approx(400.0 + dr, abs=1e-6)


def test_plot_of_the_rotary_example(rotary, tmp_path):
    pytest.importorskip("matplotlib")
    from controller.simulate.plot import plot_result

    assert plot_result(rotary, tmp_path / "r.png").stat().st_size > 1000


# -- 3. the trigger log's robot and frame columns --------------------------------------------
def _replay_doc(linear, tmp_path) -> tuple[dict, Path]:
    trig, enc = write_logs(linear, tmp_path / "rec")
    d = _linear_doc()
    d["conveyor"]["master"] = {"log": str(enc), "encoder": d["conveyor"]["master"]["encoder"]}
    d["conveyor"]["items"] = {"log": str(trig)}
    return d, trig


def _edit(path: Path, line: int, col: int, value: str) -> None:
    rows = path.read_text().splitlines()
    cells = rows[line - 1].split(",")
    cells[col] = value
    rows[line - 1] = ",".join(cells)
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("col,idx,value", [("robot", 1, "welder"), ("frame", 2, "table")])
def test_trigger_log_with_another_robot_or_frame_is_a_config_error(linear, tmp_path, col, idx,
                                                                    value):
    d, trig = _replay_doc(linear, tmp_path)
    _edit(trig, 3, idx, value)
    with pytest.raises(ConfigError) as ei:
        run_scenario(copy.deepcopy(d))
    e = ei.value
    assert e.file == str(trig) and e.line == 3 and e.key == col
    assert repr(value) in str(e) and f"{trig}:3" in str(e)


def test_trigger_log_renamed_robot_fails_on_the_cli(linear, tmp_path, capsys):
    d, trig = _replay_doc(linear, tmp_path)
    text = trig.read_text().replace(",picker,", ",robot2,")
    trig.write_text(text)
    p = tmp_path / "replay.yaml"
    p.write_text(yaml.safe_dump(d))
    assert cli.main(["simulate", str(p), "-o", str(tmp_path / "t.csv")]) != 0
    err = capsys.readouterr().err
    assert "robot2" in err and "key 'robot'" in err and ":2" in err


@pytest.mark.parametrize("idx,value,key", [(0, "x", "sample"), (3, "1.0;abc", "values"),
                                           (4, "?", "dr_mm"), (5, "2", "inverse"),
                                           (1, "", "robot")])
def test_bad_trigger_log_row_names_file_line_and_column(linear, tmp_path, idx, value, key):
    _, trig = _replay_doc(linear, tmp_path)
    _edit(trig, 4, idx, value)
    with pytest.raises(ConfigError) as ei:
        read_trigger_log(trig)
    assert ei.value.file == str(trig) and ei.value.line == 4 and ei.value.key == key


def test_trigger_log_sample_outside_the_run_and_wrong_value_count(linear, tmp_path):
    d, trig = _replay_doc(linear, tmp_path)
    last = len(trig.read_text().splitlines())
    _edit(trig, last, 0, "5000")          # the run has samples 0 ... 4999
    with pytest.raises(ConfigError) as ei:
        run_scenario(copy.deepcopy(d))
    assert ei.value.key == "sample" and ei.value.line == last
    d, trig = _replay_doc(linear, tmp_path)
    _edit(trig, 2, 3, "1.0;2.0")
    with pytest.raises(ConfigError) as ei:
        run_scenario(copy.deepcopy(d))
    assert ei.value.key == "values" and ei.value.line == 2


def test_trigger_log_round_trip_keeps_lines_and_equality(tmp_path):
    evs = [TriggerEvent(3, "r", "cnv", (1.5,)), TriggerEvent(7, "r", "cnv", None, -2.0, True)]
    p = write_trigger_log(tmp_path / "t.csv", evs)
    back = read_trigger_log(p)
    assert back == evs and [e.line for e in back] == [2, 3]
    with pytest.raises(ConfigError) as ei:
        check_trigger_log(back, ["r"], ["belt"], p)
    assert ei.value.key == "frame" and ei.value.line == 2
