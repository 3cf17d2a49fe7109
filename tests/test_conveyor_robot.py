"""The robot group on moving frames: the page's Functional Changes 1-11, the IMFS values
("Functionality Changes"), the tracking formula and Q.E.D. of "Theory of operation", the window
and "Item missed" (30238)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.conveyor import (FRAME_LIMITS, ITEM_MISSED_CODE, MOTION_LIMITS, ConveyorCell,
                                 EventKind, FrameBusyError,
                                 LinkState, Location, MovingFrame, NoFrameError,
                                 RobotGroup, SimulatedAxis, TooManyFramesError, Window,
                                 frame_limits)
from controller.conveyor.location import q_axis_angle
from controller.conveyor.telemetry import ItemStatus
from controller.errors import ParameterError, StateError
from controller.limits import CartesianLimits
from controller.tracking import Imfs, Limits, TrackError, TrackerParams

T = 0.002
SPEED = 300.0


def params(**kw) -> TrackerParams:
    base = dict(sample_time_s=T, planner="softmc",
                sync_trans=Limits(2000.0, 20000.0, 400000.0),
                desync_trans=Limits(2000.0, 5000.0, 100000.0))
    base.update(kw)
    return TrackerParams(**base)


def belt(name="cnv", speed=SPEED, direction=(1, 0, 0), window=(50.0, 2000.0), origin=(0, 0, 0),
         limits=FRAME_LIMITS):
    return MovingFrame(name, [SimulatedAxis.constant_speed(speed)], directions=[direction],
                       origin=Location.at(*origin), window=Window.single(*window),
                       limits=limits)


def table(name="rot", speed=20.0, type_=1):
    up = Location((600.0, -400.0, 0.0), q_axis_angle((0, 0, 1), 30.0))
    return MovingFrame(name, [SimulatedAxis.constant_speed(speed)], type=type_, upstream=up,
                       arc_point=(1000.0, 0.0, 0.0), downstream=(600.0, 400.0, 0.0),
                       up_master=0.0, down_master=180.0, window=Window.single(5.0, 175.0))


def make(frames, start=(200.0, 300.0, 100.0), **kw):
    robot = RobotGroup("r", kw.pop("tracker", params()), start=Location.at(*start), **kw)
    cell = ConveyorCell(frames, [robot])
    return cell, robot


def run(cell, n, until=None):
    outs = []
    for _ in range(n):
        o = cell.step()["r"]
        outs.append(o)
        if until is not None and until(o):
            break
    return outs


def kinds(outs):
    return [e.kind for o in outs for e in o.events]


def positions(outs):
    return np.array([o.setpoint.pos for o in outs])


def fd_norms(pos, order):
    d = pos
    for _ in range(order):
        d = np.diff(d, axis=0) / T
    return np.linalg.norm(d, axis=1)


def sync(cell, robot, n=1000):
    outs = run(cell, n, until=lambda o: o.imfs == Imfs.SYNCHRONIZED)
    assert outs[-1].imfs == Imfs.SYNCHRONIZED
    return outs


# -- Theory of operation: the tracking formula and its proof of concept ---------------------
@pytest.mark.parametrize("frame_kind", ["linear", "rotary"])
def test_theory_of_operation_qed_moves_to_mf_zero_ends_on_mf_here(frame_kind):
    """MOVES <robot> <MF>.zero with non-trivial base and tool: setpoint = base:Robot_real:tool
    ends on <MF>.here (position and orientation)."""
    f = belt(speed=150.0, origin=(0, 0, 20)) if frame_kind == "linear" else table()
    base = Location.from_axis_angle((-300.0, 150.0, 50.0), (0.2, 0.1, 1.0), 35.0)
    tool = Location.from_axis_angle((0.0, 10.0, 120.0), (1.0, 0.0, 0.3), -20.0)
    cell, robot = make([f], start=(300.0, -100.0, 200.0), base=base, tool=tool)
    robot.master_frame = f
    item = robot.trigger(f, dr_mm=-40.0 if frame_kind == "rotary" else 0.0)
    cmd = f.zero(item)
    robot.moves(cmd)
    outs = run(cell, 1500, until=lambda o: o.imfs == Imfs.SYNCHRONIZED and not robot.virtual.busy)
    assert outs[-1].imfs == Imfs.SYNCHRONIZED and not robot.virtual.busy
    run(cell, 50)
    here = f.here(item)
    setpoint = base.compound(robot.real).compound(tool)
    assert setpoint.distance_to(here) < 1e-9 and setpoint.angle_to(here) < 1e-7
    # Robot_real = base⁻¹:(base:Robot_virtual:tool ⊕ [MF(t) ⊖ MF(0)]):tool⁻¹
    rv = robot.robot_virtual
    assert rv.isclose(base.inverse().compound(cmd).compound(tool.inverse()), 1e-9, 1e-7)
    formula = base.inverse().compound(
        base.compound(rv).compound(tool).oplus(here.ominus(f.zero(item)))).compound(
        tool.inverse())
    assert robot.real.isclose(formula, 1e-9, 1e-7)


def test_functional_change_1_slave_5_follows_virtual_robot_plus_frame_motion():
    """slave = 5 (the new algorithm): Robot_real = Robot_virtual ⊕ [MF(t) ⊖ MF(0)]: a robot
    that does not move keeps its offset to the item from the item's zero."""
    f = belt()
    cell, robot = make([f])
    robot.set_slave(5, f)
    assert robot.slave == 5 and robot.master_frame is f
    item = robot.trigger(f)
    sync(cell, robot)
    run(cell, 100)
    disp = f.here(item).ominus(f.zero(item))
    assert robot.setpoint.isclose(robot.virtual.location.oplus(disp), 1e-9)
    assert robot.virtual.location.pos == (200.0, 300.0, 100.0)


def test_slave_3_absolute_puts_the_tcp_position_onto_mf_here():
    f = belt()
    cell, robot = make([f], start=(100.0, 200.0, 50.0))
    robot.set_slave(3, f)
    item = robot.trigger(f)
    sync(cell, robot)
    run(cell, 20)
    assert robot.setpoint.pos == pytest.approx(f.here(item).pos, abs=1e-9)
    with pytest.raises(StateError, match="slave = 0 first"):
        robot.slave = 5


# -- Functional change 2: sync/de-sync parameters, frame limits ------------------------------
def test_functional_change_2_sync_and_desync_limits_shape_approach_and_stop():
    p = params(sync_trans=Limits(1500.0, 8000.0, 200000.0),
               desync_trans=Limits(1500.0, 3000.0, 60000.0))
    f = belt()
    cell, robot = make([f], tracker=p)
    robot.master_frame = f
    robot.trigger(f)
    # "These values are taken during moving frame assignment": later changes do not count
    robot.tracker_params = params(sync_trans=Limits(10.0, 10.0, 10.0))
    outs = sync(cell, robot)
    pos = positions(outs)
    assert fd_norms(pos, 1).max() <= 1500.0 * 1.01
    assert fd_norms(pos, 2).max() <= 8000.0 * 1.01
    run(cell, 50)
    robot.slave = 0
    outs = run(cell, 600, until=lambda o: o.slave == 0)
    assert outs[-1].slave == 0
    pos = positions(outs)
    assert fd_norms(pos, 2)[2:].max() <= 3000.0 * 1.01     # de-sync acceleration
    assert fd_norms(pos, 3)[3:].max() <= 60000.0 * 1.05   # de-sync jerk (sine profile)
    assert fd_norms(pos, 1)[-1] < 1e-3                      # the last step of the stop
    assert fd_norms(positions(run(cell, 5)), 1).max() == 0.0  # then at rest


def test_functional_change_2_master_above_frame_limits_is_an_error_that_desyncs():
    f = belt(speed=600.0, limits=frame_limits(VelocityMaxTrans=500.0))
    cell, robot = make([f])
    robot.master_frame = f
    robot.trigger(f)
    outs = run(cell, 300, until=lambda o: o.error != TrackError.NONE)
    assert outs[-1].error == TrackError.MASTER_VELOCITY
    # event kinds are EventKind members (a StrEnum: traces and summaries show the value)
    events = [e for o in outs for e in o.events]
    assert events and all(type(e.kind) is EventKind for e in events)
    assert EventKind.TRACKER_ERROR in kinds(outs) and str(EventKind.TRACKER_ERROR) == \
        f"{EventKind.TRACKER_ERROR}" == "tracker_error"
    assert "tracker_error" in kinds(outs)
    outs = run(cell, 200, until=lambda o: o.slave == 0)
    assert outs[-1].slave == 0 and robot.master_frame is None


# -- Functional changes 3, 4: the trigger ring buffer, TRIGGER and NEXTITEM ------------------
def test_functional_change_3_trigger_ring_buffer_is_per_robot_and_tagged_with_the_frame():
    a, b = belt("a"), belt("b", direction=(0, 1, 0))
    cell, robot = make([a, b])
    other = RobotGroup("q", params())
    robot.master_frame = a
    run(cell, 10)
    e1 = robot.trigger(a)
    e2 = robot.trigger(b)                  # b not linked: kept, marked
    assert [e.frame for e in robot.buffer] == ["a", "b"]
    assert e1.linked and not e2.linked
    assert e1.values == pytest.approx((SPEED * 10 * T,))
    assert len(other.buffer) == 0


def test_functional_change_4_trigger_ndof_value_and_nextitem_skip_other_frames():
    a, b = belt("a"), belt("b", direction=(0, 1, 0))
    xy = MovingFrame("xy", [SimulatedAxis.constant_speed(1.0), SimulatedAxis.constant_speed(2.0)],
                     window=Window((0.0, 0.0), (1e6, 1e6)))
    cell, robot = make([a, b, xy])
    run(cell, 5)
    e = robot.trigger(xy, ndof=2, value=123.0)         # TRIGGER r {NDOF = 2 Value = 123}
    assert e.values == pytest.approx((5 * T * 1.0, 123.0))
    ea1 = robot.trigger(a, values=[1.0])
    eb1 = robot.trigger(b, values=[2.0])
    ea2 = robot.trigger(a, values=[3.0])
    assert robot.nextitem(a) is ea1                    # NEXTITEM r {MasterFrame = a}
    assert [x.id for x in robot.buffer.entries()] == [e.id, eb1.id, ea2.id]   # b skipped
    assert robot.buffer.current("a") is ea2
    assert robot.nextitem(b) is eb1 and robot.nextitem(b) is None


def test_functional_change_4_no_frame_named_error_when_engaged_to_several():
    a, b = belt("a"), belt("b", direction=(0, 1, 0))
    cell, robot = make([a, b])
    with pytest.raises(NoFrameError, match="not engaged"):
        robot.trigger()
    robot.master_frame = a
    robot.trigger(a)
    sync(cell, robot)
    assert robot.trigger().frame == "a"                # one frame: it is the default
    robot.master_frame = b                             # hand-off: engaged to two frames
    with pytest.raises(NoFrameError, match="several"):
        robot.trigger()
    with pytest.raises(NoFrameError, match="several"):
        robot.nextitem()
    assert robot.trigger(b).frame == "b"


def test_functional_change_4_slave_0_deletes_every_item_and_a_full_buffer_is_an_error():
    from controller.conveyor import TriggerBufferFull

    f = belt()
    cell, robot = make([f], buffer_capacity=3)
    robot.master_frame = f
    for _ in range(3):
        robot.trigger(f)
    with pytest.raises(TriggerBufferFull, match="full"):
        robot.trigger(f)
    assert len(robot.buffer) == 3                      # nothing dropped, nothing overwritten
    robot.master_frame = None                          # de-sync only: the items stay
    assert len(robot.buffer) == 3
    robot.slave = 0
    assert len(robot.buffer) == 0
    assert all(r.status == ItemStatus.SKIPPED for r in robot.records.values())


# -- Functional change 5: de-sync on the path ------------------------------------------------
@pytest.mark.parametrize("command", ["slave0", "none", "stop"])
def test_functional_change_5_desync_on_the_path_stops_along_the_frame_direction(command):
    d = (0.6, 0.8, 0.0)
    f = belt(direction=d)
    cell, robot = make([f])
    robot.master_frame = f
    robot.trigger(f)
    sync(cell, robot)
    run(cell, 20)
    p0 = np.array(robot.setpoint.pos)
    {"slave0": lambda: setattr(robot, "slave", 0),
     "none": lambda: setattr(robot, "master_frame", None),
     "stop": robot.stop}[command]()
    outs = run(cell, 600, until=lambda o: o.slave == 0)
    assert "desync_started" in kinds(outs) and outs[-1].slave == 0
    pos = positions(outs)
    rel = pos - p0
    along = rel @ np.array(d)
    assert np.abs(rel - np.outer(along, d)).max() < 1e-9      # on the line
    assert np.all(np.diff(along) >= -1e-12)                    # same direction, no reversal
    v = np.diff(along) / T
    assert v[0] == pytest.approx(SPEED, rel=0.02) and abs(v[-1]) < 1e-2
    # "exchanged for a virtual one with the same initial velocity": no velocity step
    assert abs(v[0] - SPEED) < 5000.0 * T * 1.5


# -- Theory of operation: de-sync along the arc ---------------------------------------------
@pytest.mark.parametrize("type_", [1, 2])
def test_theory_of_operation_rotary_desync_stops_along_the_arc(type_):
    f = table(type_=type_)
    cell, robot = make([f], start=(700.0, -300.0, 0.0))
    robot.master_frame = f
    item = robot.trigger(f, dr_mm=-50.0)
    robot.moves(f.zero(item))
    run(cell, 1500, until=lambda o: o.imfs == Imfs.SYNCHRONIZED and not robot.virtual.busy)
    run(cell, 100)
    robot.slave = 0
    outs = run(cell, 1000, until=lambda o: o.slave == 0)
    assert any(e.kind == "desync_started" and "arc" in e.message for o in outs for e in o.events)
    pos = positions(outs)
    r = np.linalg.norm(pos - np.array(f.center), axis=1)
    assert np.abs(r - 350.0).max() < 1e-6                      # stays on the item's circle
    assert np.abs(pos[:, 2]).max() < 1e-9
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=1) / T
    w = math.radians(20.0) * 350.0
    assert speed[0] == pytest.approx(w, rel=0.02) and speed[-1] < 1e-2
    if type_ == 1:   # the orientation stays the frame's orientation at the stop point
        last = robot.setpoint
        x = math.degrees(math.atan2(last.pos[0] - 600.0, -(last.pos[1] - 0.0)))
        expected = q_axis_angle((0, 0, 1), x + 30.0)
        assert last.angle_to(Location((0, 0, 0), expected)) < 1e-6


# -- Functional changes 6, 7, 8: motions across the de-sync ---------------------------------
def synced_with_motion(target_offset=(0.0, 100.0, 0.0)):
    f = belt()
    cell, robot = make([f])
    robot.master_frame = f
    item = robot.trigger(f)
    sync(cell, robot)
    slow = CartesianLimits(Limits(100.0, 500.0, 5000.0), MOTION_LIMITS.rot)
    target = Location.at(*(a + b for a, b in zip(robot.virtual.location.pos, target_offset)))
    m = robot.moves(target, limits=slow)
    run(cell, 5)
    assert m.started and (m.done == (target_offset == (0.0, 0.0, 0.0)))
    return f, cell, robot, item, m, target


def test_functional_change_6_desync_does_not_stop_a_running_motion():
    f, cell, robot, item, m, target = synced_with_motion()
    robot.slave = 0
    run(cell, 2000, until=lambda o: m.done and o.slave == 0)
    assert m.done and robot.slave == 0
    # the motion ran its whole profile: its displacement (100 mm along y) is all there
    assert robot.setpoint.pos[1] - 300.0 == pytest.approx(100.0, abs=1e-9)


def test_functional_change_8_absolute_target_ends_at_stop_position_combined_with_target():
    f, cell, robot, item, m, target = synced_with_motion()
    robot.slave = 0
    run(cell, 1)
    e = robot.links[0].offset_pos     # the frame's virtual stopping position (displacement)
    run(cell, 2000, until=lambda o: m.done and o.slave == 0)
    assert robot.setpoint.pos == pytest.approx(tuple(a + b for a, b in zip(target.pos, e)),
                                               abs=1e-9)
    assert abs(robot.setpoint.pos[0] - target.pos[0]) > 100.0   # not the target itself


def test_functional_change_7_motion_entered_during_desync_ends_at_the_free_robot_target():
    f, cell, robot, item, m, target = synced_with_motion((0.0, 0.0, 0.0))
    robot.slave = 0
    outs = run(cell, 3)
    assert outs[-1].imfs == Imfs.DESYNCING
    place = Location.at(50.0, 500.0, 80.0)
    robot.moves(place, superpose=True)
    run(cell, 3000, until=lambda o: not robot.virtual.busy and o.slave == 0)
    assert robot.setpoint.isclose(place, 1e-9)


def test_functional_change_7_moves_given_with_masterframe_none_ends_on_its_target():
    f, cell, robot, item, m, target = synced_with_motion((0.0, 0.0, 0.0))
    place = Location.at(50.0, 500.0, 80.0)
    robot.master_frame = None          # the de-sync and the motion start in the same sample
    robot.moves(place)
    run(cell, 3000, until=lambda o: not robot.virtual.busy and o.slave == 0)
    assert robot.setpoint.isclose(place, 1e-9)


def test_functional_change_10_superposition_not_affected_by_sync_or_desync():
    """A relative motion superposed while syncing, synced and de-syncing adds exactly its
    displacement: the setpoint minus the frame's contribution is the free robot's path."""
    f = belt()
    cell, robot = make([f])
    free = RobotGroup("free", params(), start=Location.at(200.0, 300.0, 100.0))
    robot.master_frame = f
    robot.trigger(f)
    for r in (robot, free):
        r.moves_rel((0.0, 0.0, 50.0), superpose=True)
        r.moves_rel((0.0, 80.0, 0.0), superpose=True)
    for k in range(900):
        if k == 300:
            robot.slave = 0
        o = cell.step()["r"]
        fo = free.update()
        contrib = np.zeros(3)
        for link in robot.links:
            contrib += np.array(link.contribution().pos)
        v = np.array(o.setpoint.pos) - contrib
        shift = np.array(robot.virtual.location.pos) - np.array(fo.virtual.pos)
        # V = the free robot's V plus the absorbed stopping position (a constant)
        assert np.allclose(v, np.array(fo.setpoint.pos) + shift, atol=1e-9)
    assert np.allclose(shift[1:], 0.0, atol=1e-9)


# -- Functional change 9: MasterFrame on the fly, hand-off ----------------------------------
def test_functional_change_9_1_masterframe_none_desyncs_then_slave_becomes_0():
    f = belt()
    cell, robot = make([f])
    robot.master_frame = f
    robot.trigger(f)
    sync(cell, robot)
    robot.master_frame = None
    assert robot.slave == 5 and robot.master_frame is None
    outs = run(cell, 600, until=lambda o: o.slave == 0)
    assert outs[0].imfs == Imfs.DESYNCING and outs[0].slave == 5
    assert outs[-1].slave == 0 and outs[-1].imfs == Imfs.NOT_SYNCHRONIZED
    assert f.engaged_by is None and not f.desyncing_by


def test_functional_change_9_2_handoff_desyncs_old_and_syncs_new_at_the_same_time():
    a = belt("a", direction=(1, 0, 0))
    b = belt("b", direction=(0, 1, 0), speed=200.0)
    cell, robot = make([a, b])
    robot.master_frame = a
    robot.trigger(a)
    robot.trigger(b)                       # b's item: kept for later (b not linked yet)
    sync(cell, robot)
    run(cell, 20)
    robot.master_frame = b
    assert robot.master_frame is b and robot.slave == 5
    outs = run(cell, 1500, until=lambda o: o.imfs == Imfs.SYNCHRONIZED)
    states = [dict(o.links) for o in outs]
    both = [s for s in states if s.get("a") == LinkState.DESYNCING and
            s.get("b") in (LinkState.SYNCING, LinkState.SYNCED)]
    assert both, "the de-sync of a and the sync to b must overlap"
    assert all(o.imfs == Imfs.HANDOFF for o, s in zip(outs, states) if len(s) == 2)
    assert outs[-1].imfs == Imfs.SYNCHRONIZED and [n for n, _ in outs[-1].links] == ["b"]
    # no position or velocity step at the hand-off
    pos = positions(outs)
    assert fd_norms(pos, 2).max() < 20000.0 * 1.05
    # following b only: the setpoint moves with b
    v = fd_norms(positions(run(cell, 10)), 1)
    assert v == pytest.approx(200.0, rel=1e-9)


def test_functional_change_9_3_a_third_frame_is_rejected():
    a, b, c = belt("a"), belt("b", direction=(0, 1, 0)), belt("c", direction=(0, 0, 1))
    cell, robot = make([a, b, c])
    robot.master_frame = a
    robot.trigger(a)
    sync(cell, robot)
    robot.master_frame = b
    run(cell, 2)
    assert robot.imfs == Imfs.HANDOFF
    with pytest.raises(TooManyFramesError, match="third"):
        robot.master_frame = c
    assert robot.master_frame is b and c.engaged_by is None


def test_functional_change_9_4_same_frame_ignored_and_desyncing_frame_not_engageable():
    a, b = belt("a"), belt("b", direction=(0, 1, 0))
    cell, robot = make([a, b])
    other = RobotGroup("q", params())
    cell.robots.append(other)
    robot.master_frame = a
    robot.trigger(a)
    sync(cell, robot)
    link = robot.links[0]
    robot.master_frame = a                      # ignored: same link, same tracker
    assert robot.links == [link] and robot.imfs == Imfs.SYNCHRONIZED
    with pytest.raises(FrameBusyError, match="engaged by robot"):
        other.master_frame = a
    robot.master_frame = b                      # a de-syncs
    run(cell, 2)
    for r in (robot, other):
        with pytest.raises(FrameBusyError, match="de-sync"):
            r.master_frame = a
    run(cell, 600, until=lambda o: not a.desyncing_by)
    assert not a.desyncing_by
    other.master_frame = a                      # possible once the de-sync is finished
    assert a.engaged_by == "q"


def test_functional_change_9_5_stop_slave0_and_masterframe_none_are_equivalent():
    results = []
    for command in ("stop", "slave0", "none"):
        f = belt()
        cell, robot = make([f])
        robot.master_frame = f
        robot.trigger(f)
        sync(cell, robot)
        run(cell, 10)
        {"stop": robot.stop, "slave0": lambda r=robot: setattr(r, "slave", 0),
         "none": lambda r=robot: setattr(r, "master_frame", None)}[command]()
        outs = run(cell, 400)
        results.append(positions(outs))
        assert outs[-1].slave == 0
    assert np.array_equal(results[0], results[1]) and np.array_equal(results[0], results[2])


def test_functional_change_9_6_nodal_masterframe_acts_when_the_motion_starts():
    a = belt("a")
    cell, robot = make([a])
    first = robot.moves(Location.at(200.0, 300.0, 0.0))
    second = robot.moves(a.zero(), master_frame=a)   # MOVES r a.zero MasterFrame = a
    robot.trigger(a, values=[0.0])
    outs = run(cell, 2000, until=lambda o: second.started)
    assert robot.master_frame is a
    started = [o.sample for o in outs for e in o.events if e.kind == "motion_started"]
    assert len(started) == 2
    assert all(o.slave == 0 for o in outs[:-1]) and outs[-1].slave == 5
    assert first.done
    # nodal none: the de-sync starts with the motion
    sync(cell, robot)
    third = robot.moves_rel((0.0, 0.0, 10.0), master_frame=None)
    outs = run(cell, 1000, until=lambda o: o.slave == 0)
    assert third.started and outs[-1].slave == 0


# -- Functional change 11: Item missed ------------------------------------------------------
def test_functional_change_11_item_missed_30238_starts_desync_and_keeps_motions():
    f = belt(window=(50.0, 200.0))
    slow = params(sync_trans=Limits(350.0, 300.0, 2000.0))
    cell, robot = make([f], tracker=slow, start=(-800.0, 300.0, 100.0))
    robot.master_frame = f
    item = robot.trigger(f)
    m = robot.moves_rel((0.0, 0.0, 200.0), limits=CartesianLimits(
        Limits(50.0, 200.0, 2000.0), MOTION_LIMITS.rot))
    outs = run(cell, 2000, until=lambda o: o.error != TrackError.NONE)
    o = outs[-1]
    assert o.error == TrackError.ITEM_MISSED
    missed = [e for e in o.events if e.kind == "item_missed"]
    assert missed and missed[0].code == ITEM_MISSED_CODE == 30238
    assert robot.records[item.id].status == ItemStatus.MISSED
    assert item not in list(robot.buffer)
    assert not m.done
    outs = run(cell, 3000, until=lambda o: m.done and o.slave == 0)
    assert m.done and outs[-1].slave == 0                       # the motion ran "as is"


# -- IMFS -------------------------------------------------------------------------------------
def test_functionality_changes_imfs_values_in_each_situation():
    a, b = belt("a", window=(100.0, 5000.0)), belt("b", direction=(0, 1, 0))
    cell, robot = make([a, b])
    seen = []
    assert robot.imfs == Imfs.NOT_SYNCHRONIZED == 0             # slave = 0
    robot.master_frame = a
    robot.trigger(a)
    o = run(cell, 1)[-1]
    assert o.imfs == 0 and dict(o.links)["a"] == LinkState.WAITING       # before the window
    outs = run(cell, 1000, until=lambda o: o.imfs == 1)
    seen += [o.imfs for o in outs]
    assert LinkState.SYNCING in [dict(o.links)["a"] for o in outs]
    assert all(i == 0 for i in seen[:-1]) and seen[-1] == 1            # approach: 0, then 1
    robot.master_frame = b
    robot.trigger(b)
    assert run(cell, 1)[-1].imfs == Imfs.HANDOFF == -2
    outs = run(cell, 1000, until=lambda o: o.imfs == 1)
    assert outs[-1].imfs == 1
    robot.slave = 0
    assert run(cell, 1)[-1].imfs == Imfs.DESYNCING == -1
    outs = run(cell, 1000, until=lambda o: o.slave == 0)
    assert outs[-1].imfs == 0


# -- Window: tracking starts inside, ends outside; the next item -----------------------------
def test_window_tracking_starts_inside_and_goes_on_with_the_next_item():
    f = belt(window=(100.0, 400.0))
    cell, robot = make([f], start=(150.0, 300.0, 100.0))
    robot.master_frame = f
    first = robot.trigger(f)
    run(cell, 250)                                             # 0.5 s: 150 mm
    second = robot.trigger(f)
    outs = run(cell, 3000, until=lambda o: robot.records[second.id].caught)
    ev = [(e.kind, e.item) for o in outs for e in o.events]
    r1 = robot.records[first.id]
    assert r1.entered_s == pytest.approx(100.0 / SPEED, abs=2 * T)
    assert r1.engaged_sample == r1.entered_sample
    assert ("item_left", first.id) in ev and r1.status == ItemStatus.CAUGHT
    assert r1.left_s == pytest.approx(400.0 / SPEED, abs=2 * T)
    assert robot.records[second.id].caught and robot.records[second.id].time_to_sync_s > 0
    assert len(robot.buffer) == 1


def test_tracking_process_trigger_delay_correction_takes_the_latch_back_to_the_edge():
    """Overview page, "Tracking Process": "a correction term is added to correct a delay of 1-2
    samples between the trigger from the sensor to the start of the operation ... this delay
    causes a gap in the position".  TRIGGER with the edge's age (or the frame's
    trigger_delay_s) latches where the item was at the edge: exact for a constant-acceleration
    belt; without the correction the gap is vel*delay."""
    def accelerating(t):  # 100 mm/s + 200 mm/s^2
        return 100.0 * t + 100.0 * t * t, 100.0 + 200.0 * t, 200.0

    def at(t):
        return accelerating(t)[0]

    delayed = MovingFrame("late", [SimulatedAxis(accelerating)], trigger_delay_s=2 * T,
                          window=Window.single(0.0, 1e6))
    plain = MovingFrame("plain", [SimulatedAxis(accelerating)], window=Window.single(0.0, 1e6))
    cell, robot = make([delayed, plain])
    run(cell, 50)
    k = delayed.sample
    e_frame = robot.trigger(delayed)                  # the frame's delay: 2 samples
    e_call = robot.trigger(plain, age_s=3 * T)        # the edge's age given by the caller
    e_none = robot.trigger(plain)                     # no correction
    assert e_frame.values[0] == pytest.approx(at((k - 2) * T), abs=1e-9)
    assert e_call.values[0] == pytest.approx(at((k - 3) * T), abs=1e-9)
    assert e_none.values[0] == pytest.approx(at(k * T), abs=1e-9)
    gap = e_none.values[0] - at((k - 2) * T)          # what the correction removes
    assert gap == pytest.approx((100.0 + 200.0 * k * T) * 2 * T, rel=0.05) and gap > 0.4
    with pytest.raises(ParameterError, match=r"age \(=-0\.001\) must be >= 0 s"):
        robot.trigger(plain, age_s=-0.001)
    with pytest.raises(ParameterError, match="trigger delay"):
        MovingFrame("bad", [SimulatedAxis(accelerating)], trigger_delay_s=math.nan)


def test_phase2_frame_max_values_reduce_the_superimposed_motion():
    """Overview page, Moving Frame parameters: "Increasing these values will effectively
    decrease the velocity of the superimposed robot motion while it is synchronized" (PHASE2):
    with the robot's maxima given, a motion started while synced gets robot max - frame max;
    the combined (frame + motion) speed stays within the robot's maximum; without robot
    maxima, or when not synced, the motion's own limits apply; nothing left is an error."""
    robot_max = Limits(800.0, 20000.0, 400000.0)
    own = CartesianLimits(Limits(700.0, 15000.0, 300000.0), MOTION_LIMITS.rot)

    def peak_motion_speed(frame_vmax, *, synced=True, tracker=None):
        f = belt(window=(0.0, 5000.0), limits=frame_limits(VelocityMaxTrans=frame_vmax))
        cell, robot = make([f], tracker=tracker or params(robot_max_trans=robot_max),
                           motion_limits=own)
        if synced:
            robot.master_frame = f
            run(cell, 5)
            robot.trigger(f)
            sync(cell, robot)
        m = robot.moves_rel(Location.at(0.0, 300.0, 0.0), name="pick")   # across the belt
        outs = run(cell, 3000, until=lambda o: m.done)
        vy = np.abs(np.diff(positions(outs)[:, 1])) / T
        return m, float(vy.max()), outs, robot

    m, v, _, _ = peak_motion_speed(300.0)
    assert m.limits.trans.vel == pytest.approx(800.0 - 300.0) and v == pytest.approx(500.0, rel=1e-3)
    assert m.limits.trans.acc == 15000.0                    # own limit lower than 20000 - 1000
    m, v, _, _ = peak_motion_speed(600.0)             # a faster frame: a slower motion
    assert m.limits.trans.vel == pytest.approx(200.0) and v == pytest.approx(200.0, rel=1e-3)
    assert SPEED + v <= robot_max.vel                 # combined speed within the robot's max
    m, v, _, _ = peak_motion_speed(300.0, synced=False)   # not synchronised: own limits
    assert m.limits is None and v == pytest.approx(700.0, rel=1e-3)
    m, v, _, _ = peak_motion_speed(300.0, tracker=params())   # no robot maxima: own limits
    assert m.limits is None and v == pytest.approx(700.0, rel=1e-3)
    m, v, outs, robot = peak_motion_speed(800.0)      # nothing left for the motion
    errors = [e for o in outs for e in o.events if e.kind == "command_error"]
    assert errors and "leaves nothing of the robot's maximum (800)" in errors[0].message
    assert not m.done and m not in robot.virtual.queue and not robot.virtual.busy
