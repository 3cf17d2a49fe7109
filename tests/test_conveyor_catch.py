"""Beyond the page: "can it catch this item?", per-item telemetry, deterministic replay."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.conveyor import (ConveyorCell, EncoderSource, Location,
                                 MovingFrame, RobotGroup, SimulatedAxis, Window,
                                 frame_limits)
from controller.conveyor.catch import min_time_double_integrator
from controller.conveyor.location import q_axis_angle
from controller.conveyor.replay import (TriggerEvent, read_encoder_log, read_trigger_log,
                                        replay, write_encoder_log, write_trigger_log)
from controller.conveyor.sources import quantise_counts
from controller.conveyor.telemetry import ItemStatus
from controller.tracking import Imfs, Limits, TrackerParams

T = 0.002


def params(acc=20000.0, vel=2000.0, jerk=400000.0):
    return TrackerParams(sample_time_s=T, planner="softmc", sync_trans=Limits(vel, acc, jerk),
                         desync_trans=Limits(2000.0, 5000.0, 100000.0))


def belt(speed=300.0, window=(100.0, 800.0)):
    return MovingFrame("cnv", [SimulatedAxis.constant_speed(speed)], directions=[(1, 0, 0)],
                       window=Window.single(*window))


def table():
    up = Location((600.0, -400.0, 0.0), q_axis_angle((0, 0, 1), 30.0))
    return MovingFrame("rot", [SimulatedAxis.constant_speed(20.0)], type=1, upstream=up,
                       arc_point=(1000.0, 0.0, 0.0), downstream=(600.0, 400.0, 0.0),
                       up_master=0.0, down_master=180.0, window=Window.single(10.0, 170.0))


def make(frame, tracker=None, start=(100.0, 300.0, 50.0)):
    robot = RobotGroup("r", tracker or params(), start=Location.at(*start))
    return ConveyorCell([frame], [robot]), robot


def run_until_synced(cell, robot, item, n=5000):
    for _ in range(n):
        cell.step()
        if robot.records[item.id].synced_sample is not None or \
                robot.records[item.id].status == ItemStatus.MISSED:
            break
    return robot.records[item.id]


# -- can it catch this item? -----------------------------------------------------------------
@pytest.mark.parametrize("engaged", [True, False])
@pytest.mark.parametrize("frame_factory", [belt, table])
def test_can_catch_predicts_the_rendezvous_time_and_point_exactly(engaged, frame_factory):
    f = frame_factory()
    cell, robot = make(f)
    if engaged:
        robot.master_frame = f
    cell.step()
    item = robot.trigger(f)
    p = robot.can_catch(f, item)
    assert p.can_catch and not p.early, p.reason
    assert p.lower_bound_s <= p.in_s
    if not engaged:
        robot.master_frame = f          # engaged now; the approach starts at window entry
    rec = run_until_synced(cell, robot, item)
    assert rec.caught
    assert rec.synced_s == pytest.approx(p.time_s, abs=1e-12)
    assert f.here(item).isclose(p.item_location, 1e-9)
    assert robot.setpoint.isclose(p.robot_location, 1e-9)


def test_can_catch_is_pure():
    f = belt()
    ref_cell, ref = make(belt())
    cell, robot = make(f)
    for _c, r, fr in ((ref_cell, ref, ref_cell.frames[0]), (cell, robot, f)):
        r.master_frame = fr
        r.trigger(fr)
    a, b = [], []
    for k in range(400):
        if k % 50 == 0:
            robot.can_catch(f)
        a.append(ref_cell.step()["r"].setpoint.pos)
        b.append(cell.step()["r"].setpoint.pos)
    assert a == b


def test_can_catch_says_no_early_with_the_reason():
    f = belt(speed=300.0, window=(100.0, 300.0))
    cell, robot = make(f, tracker=params(acc=500.0, jerk=5000.0), start=(-2000.0, 0.0, 0.0))
    robot.master_frame = f
    item = robot.trigger(f)
    robot.moves(f.zero(item))
    p = robot.can_catch(f, item)
    assert not p.can_catch and p.early and "at least" in p.reason
    assert p.lower_bound_s > p.leave_in_s
    # the prediction was right: the item is missed
    rec = run_until_synced(cell, robot, item)
    assert rec.status == ItemStatus.MISSED

    fast = belt(speed=900.0)
    cell, robot = make(fast, tracker=params(vel=800.0))
    item = robot.trigger(fast)
    p = robot.can_catch(fast, item)
    assert not p.can_catch and p.early and "sync velocity" in p.reason

    over = MovingFrame("cnv", [SimulatedAxis.constant_speed(700.0)],
                       limits=frame_limits(VelocityMaxTrans=600.0))
    cell, robot = make(over)
    p = robot.can_catch(over, robot.trigger(over))
    assert not p.can_catch and "VelocityMax" in p.reason

    gone = belt(window=(10.0, 20.0))
    cell, robot = make(gone)
    item = robot.trigger(gone)
    for _ in range(100):
        cell.step()
    p = robot.can_catch(gone, item)
    assert not p.can_catch and p.early and "already left" in p.reason

    still = belt(speed=0.0)
    cell, robot = make(still)
    p = robot.can_catch(still, robot.trigger(still))
    assert not p.can_catch and "does not move" in p.reason
    cell, robot = make(belt())
    p = robot.can_catch(cell.frames[0])
    assert not p.can_catch and "no item" in p.reason


def test_can_catch_lower_bound_is_a_lower_bound():
    rng = np.random.default_rng(5)
    for _ in range(25):
        speed = rng.uniform(50, 600)
        start = (rng.uniform(-600, 600), rng.uniform(-300, 300), 0.0)
        f = belt(speed=speed, window=(rng.uniform(0, 100), 5000.0))
        cell, robot = make(f, tracker=params(acc=rng.uniform(2000, 20000)), start=start)
        robot.master_frame = f
        item = robot.trigger(f)
        p = robot.can_catch(f, item)
        if p.can_catch:
            assert p.lower_bound_s <= p.in_s + 1e-12


def test_min_time_double_integrator():
    assert min_time_double_integrator(0.0, 0.0, 1.0) == 0.0
    assert min_time_double_integrator(4.0, 0.0, 1.0) == pytest.approx(4.0)    # 2*sqrt(x/A)
    assert min_time_double_integrator(-4.0, 0.0, 1.0) == pytest.approx(4.0)
    assert min_time_double_integrator(0.0, 2.0, 1.0) == pytest.approx(2.0 + 2 * math.sqrt(2))
    # on the switching curve: brake only
    assert min_time_double_integrator(-2.0, 2.0, 1.0) == pytest.approx(2.0)


# -- telemetry -------------------------------------------------------------------------------
def test_item_telemetry_time_to_sync_peak_error_oscillations_status():
    f = belt()
    cell, robot = make(f)
    robot.master_frame = f
    item = robot.trigger(f)
    rec = run_until_synced(cell, robot, item)
    assert rec.status == ItemStatus.CAUGHT and rec.caught and not rec.missed
    assert rec.entered_s == pytest.approx(100.0 / 300.0, abs=T)
    assert rec.time_to_sync_s == pytest.approx(rec.synced_s - rec.engaged_s)
    # the contribution starts at zero: the error starts at the displacement since the
    # trigger and grows while the robot speeds up
    assert 100.0 < rec.peak_error_approach_mm < 150.0
    assert rec.oscillations >= 0
    for _ in range(200):
        cell.step()
    assert rec.peak_error_synced_mm < 1e-9
    d = rec.as_dict()
    assert d["status"] == "caught" and d["item"] == item.id


# -- replay ----------------------------------------------------------------------------------
def _cell_with_encoder(counts, modulus):
    enc = EncoderSource(T, modulus=modulus, counts=counts, window=24, name="enc")
    f = MovingFrame("cnv", [enc], scales=[0.02], window=Window.single(50.0, 700.0))
    robot = RobotGroup("r", params(), start=Location.at(100.0, 300.0, 50.0))
    return ConveyorCell([f], [robot]), robot, f, enc


def _program(cell, outs):
    robot = cell.robots[0]
    f = cell.frames[0]
    if robot.master_frame is None and robot.slave == 0 and len(robot.buffer):
        robot.master_frame = f
        robot.moves(f.zero(robot.current_item(f)))
    if robot.imfs == Imfs.SYNCHRONIZED and not robot.virtual.busy:
        robot.nextitem(f)


def test_deterministic_replay_of_a_recorded_encoder_and_trigger_log(tmp_path):
    modulus = 1 << 14

    def live(k):  # a master with a speed ripple, 50 counts per mm
        t = k * T
        return quantise_counts(300.0 * t + 5.0 * math.sin(7.0 * t), 50.0, modulus)

    cell, robot, f, enc = _cell_with_encoder(live, modulus)
    events = []
    outs = []
    for k in range(1200):
        if k % 300 == 10:
            e = robot.trigger(f)
            events.append(TriggerEvent(cell.k, "r", "cnv", e.values))
        o = cell.step()
        outs.append(o)
        _program(cell, o)
    enc_path = write_encoder_log(tmp_path / "enc.csv", T, {"enc": enc.log})
    trig_path = write_trigger_log(tmp_path / "trig.csv", events)

    log = read_encoder_log(enc_path)
    trig = read_trigger_log(trig_path)
    assert log["enc"] == enc.log and trig == events
    cell2, robot2, f2, _ = _cell_with_encoder(log["enc"], modulus)
    outs2 = replay(cell2, trig, 1200, on_sample=_program)
    assert [o["r"] for o in outs] == [o["r"] for o in outs2]     # bit-identical outputs
    assert {k: r.as_dict() for k, r in robot.records.items()} == \
        {k: r.as_dict() for k, r in robot2.records.items()}
    assert sum(r.caught for r in robot.records.values()) >= 3


def test_can_catch_the_next_item_while_following_another():
    f = belt(window=(50.0, 3000.0))
    cell, robot = make(f)
    robot.master_frame = f
    first = robot.trigger(f)
    run_until_synced(cell, robot, first)
    for _ in range(100):
        cell.step()
    second = robot.trigger(f)
    p = robot.can_catch(f, second)
    assert p.can_catch and p.in_s > 0
    robot.nextitem(f)                        # go on with the second item now
    rec = run_until_synced(cell, robot, second)
    assert rec.caught and rec.synced_s == pytest.approx(p.time_s, abs=1e-12)
