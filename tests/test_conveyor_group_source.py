"""A robot group's TCP as the master of a moving frame (issue 16, point 3; the page's "group
as a master source (phase 3)": "the offset must be taken into consideration in TRIGGER"):
a full location offset taken at TRIGGER, the transformation between the two robots' worlds,
the kinematic check against the master robot's system."""

from __future__ import annotations

import pytest

from controller.conveyor import (ConveyorCell, Kinematics, KinematicsError, Location,
                                 MovingFrame, RobotGroup, RobotType, SimulatedAxis, Window)
from controller.conveyor.location import q_axis_angle
from controller.errors import ParameterError
from controller.tracking import Imfs, Limits, TrackerParams

T = 0.002


def params():
    return TrackerParams(sample_time_s=T, planner="softmc",
                         sync_trans=Limits(2000.0, 20000.0, 400000.0),
                         sync_rot=Limits(360.0, 3600.0, 72000.0))


def carrier_on_table(speed_deg_s=15.0):
    """Robot A follows a rotary table (turning about z): its TCP moves on an arc and turns."""
    table = MovingFrame("table", [SimulatedAxis.constant_speed(speed_deg_s)], type=1,
                        upstream=Location((600.0, -400.0, 0.0), q_axis_angle((0, 0, 1), 20.0)),
                        arc_point=(1000.0, 0.0, 0.0), downstream=(600.0, 400.0, 0.0),
                        deg_per_unit=1.0, window=Window.single(-1000.0, 1000.0))
    a = RobotGroup("A", params(), start=Location.at(650.0, -380.0, 30.0))
    return table, a


def synced(cell, robot, n=3000):
    for _ in range(n):
        out = cell.step()[robot.name]
        if out.imfs == Imfs.SYNCHRONIZED:
            return out
    raise AssertionError(f"{robot.name} not synchronised")


@pytest.mark.parametrize("slave", [3, 5])
def test_a_frame_whose_source_is_another_robots_tcp(slave):
    table, a = carrier_on_table()
    transform = Location.from_axis_angle((-50.0, 20.0, 5.0), (0, 0, 1), 10.0)
    b = RobotGroup("B", params(), start=Location.at(400.0, 300.0, 200.0))
    grp = MovingFrame.group("onA", a, transform=transform)
    cell = ConveyorCell([table, grp], [b, a])     # B listed first: the cell orders A first
    a.master_frame = table
    a.trigger(table)
    synced(cell, a)
    for _ in range(100):
        cell.step()
    # the item sits 80 mm along A's tool x, turned 30 deg about its z: the offset P
    P = Location.from_axis_angle((80.0, 0.0, 10.0), (0, 0, 1), 30.0)
    b.set_slave(slave, grp)
    item = b.trigger(grp, offset=P)
    w0 = transform.compound(a.setpoint).compound(P)
    assert item.zero.isclose(w0, 1e-9, 1e-9)       # the full offset, taken at TRIGGER
    synced(cell, b)
    for _ in range(200):
        cell.step()
    expected = transform.compound(a.setpoint).compound(P)   # the item, now: T : TCP_A : P
    assert grp.here(item).isclose(expected, 1e-6, 1e-6)
    if slave == 3:
        assert b.setpoint.distance_to(expected) < 1e-6
        assert b.setpoint.angle_to(expected) < 1e-6
    else:   # V ⊕ [MF(t) ⊖ MF(0)]
        disp = expected.ominus(w0)
        assert b.setpoint.isclose(b.virtual.location.oplus(disp), 1e-6, 1e-6)
    # B moves as A's item does: rigid-body velocity of the offset point
    p0 = b.setpoint.pos
    cell.step()
    item_vel = [(x - y) / T for x, y in zip(transform.compound(a.setpoint).compound(P).pos,
                                             expected.pos)]
    b_vel = [(x - y) / T for x, y in zip(b.setpoint.pos, p0)]
    assert b_vel == pytest.approx(item_vel, abs=1e-6)
    assert max(abs(v) for v in b_vel) > 10.0   # it really moves


def test_trigger_location_given_and_offset_errors():
    table, a = carrier_on_table()
    b = RobotGroup("B", params(), start=Location.at(0, 0, 0))
    grp = MovingFrame.group("onA", a)
    ConveyorCell([table, grp], [a, b])
    w = Location.from_axis_angle((700.0, -300.0, 40.0), (1, 0, 0), 5.0)
    e = b.trigger(grp, location=w)
    assert e.zero == w and grp.zero(e) == w
    with pytest.raises(ParameterError, match="offset or location, not both"):
        b.trigger(grp, location=w, offset=Location())
    with pytest.raises(ParameterError, match="for group frames"):
        b.trigger(table, offset=Location())
    assert len(e.values) == 4 and grp.nof == 4


def test_the_master_robots_kinematics_system_is_the_frames_world():
    """'It is impossible to track a different kinematics system': a group frame's world is
    its master robot's kinematics."""
    master = RobotGroup("M", params(), kinematics=Kinematics(RobotType.SCARA, 4))
    grp = MovingFrame.group("onM", master)
    other = RobotGroup("B", params(), kinematics=Kinematics(RobotType.GENERAL, 6))
    ConveyorCell([grp], [master, other])
    with pytest.raises(KinematicsError, match="scara, dimension 4"):
        other.master_frame = grp
    same = RobotGroup("C", params(), kinematics=Kinematics(RobotType.SCARA, 4))
    same.master_frame = grp
    assert same.master_frame is grp
