"""slave = 3 (absolute) brings the full location - position and orientation - onto <MF>.here
(issue 16, point 1): a rotary table with an UpStream orientation, a tilted table, a linear
frame whose MF.zero has a non-identity orientation, a robot whose orientation offset to the
frame is not a rotation about the frame's axis (the swing channel), within the sync rotation
limits; slave = 5 keeps its reading (the robot turns *with* the frame only)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.conveyor import (ConveyorCell, LinkState, Location, MovingFrame,
                                 RobotGroup, SimulatedAxis, Window)
from controller.conveyor.location import q_axis_angle
from controller.tracking import Imfs, Limits, TrackerParams

T = 0.002
SYNC_ROT = Limits(120.0, 1200.0, 24000.0)


def params() -> TrackerParams:
    return TrackerParams(sample_time_s=T, planner="softmc",
                         sync_trans=Limits(2000.0, 20000.0, 400000.0),
                         desync_trans=Limits(2000.0, 5000.0, 100000.0),
                         sync_rot=SYNC_ROT, desync_rot=Limits(120.0, 600.0, 12000.0))


def table(up_ori, axis=(0.0, 0.0, 1.0), speed=10.0):
    """A rotary table (type 1) about ``axis`` through (600, 0, 0), radius 400 mm."""
    # points of the arc in the plane perpendicular to axis
    a = np.array(axis, float) / np.linalg.norm(axis)
    u = np.cross(a, [0.0, 1.0, 0.0] if abs(a[1]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(a, u)
    c = np.array([600.0, 0.0, 0.0])
    p1, p2, p3 = (tuple(c + 400.0 * (np.cos(t) * u + np.sin(t) * w)) for t in (0.0, 1.2, 2.4))
    up = Location(p1, up_ori)
    return MovingFrame("rot", [SimulatedAxis.constant_speed(speed)], type=1, upstream=up,
                       arc_point=p2, downstream=p3, deg_per_unit=1.0,
                       window=Window.single(2.0, 170.0))


def belt(origin: Location, speed=100.0):
    return MovingFrame("cnv", [SimulatedAxis.constant_speed(speed)], directions=[(1, 0, 0)],
                       origin=origin, window=Window.single(20.0, 3000.0))


def run_synced(frame, start: Location, slave=3, extra=200):
    robot = RobotGroup("r", params(), start=start)
    cell = ConveyorCell([frame], [robot])
    robot.set_slave(slave, frame)
    item = robot.trigger(frame)
    outs = []
    for _ in range(4000):
        outs.append(cell.step()["r"])
        if outs[-1].imfs == Imfs.SYNCHRONIZED:
            break
    assert outs[-1].imfs == Imfs.SYNCHRONIZED, "not synchronised"
    for _ in range(extra):
        outs.append(cell.step()["r"])
    return robot, item, outs


def step(robot, frame):
    """One sample (what ConveyorCell.step does for one frame and one robot)."""
    k = robot.k + 1
    frame.update(k, k * T)
    return robot.update()


def angle_rates(outs):
    """|rotation rate| [deg/s] between consecutive setpoints."""
    qs = [o.setpoint for o in outs]
    return np.array([a.angle_to(b) / T for a, b in zip(qs, qs[1:])])


def test_slave_3_rotary_table_orientation_ends_on_mf_here():
    """The issue's case: UpStream orientation Q(30 deg, z), the robot starts at identity:
    synchronised, the orientation error is 0 (it was exactly 30 deg)."""
    f = table(q_axis_angle((0, 0, 1), 30.0))
    robot, item, outs = run_synced(f, Location.at(500.0, 100.0, 50.0))
    here = f.here(item)
    assert robot.setpoint.distance_to(here) < 1e-6
    assert robot.setpoint.angle_to(here) < 1e-6
    # the approach of the orientation stays within the sync rotation limit (+1 % sampling)
    assert angle_rates(outs).max() <= SYNC_ROT.vel * 1.01


def test_slave_3_tilted_rotary_table_position_and_orientation():
    axis = (0.0, 0.5, 0.8)
    a = np.array(axis) / np.linalg.norm(axis)
    up_ori = q_axis_angle(tuple(a), 40.0)          # the page's UpStream[1].ori = Q(Δ, v)
    f = table(up_ori, axis)
    robot, item, outs = run_synced(f, Location.at(500.0, 100.0, 50.0))
    assert f.geometry().ori_about_axis
    for _ in range(3):   # stays on it while the table turns
        here = f.here(item)
        assert robot.setpoint.distance_to(here) < 1e-6
        assert robot.setpoint.angle_to(here) < 1e-6
        for _ in range(100):
            step(robot, f)
    assert angle_rates(outs).max() <= SYNC_ROT.vel * 1.01


def test_slave_3_swing_channel_when_the_offset_is_not_about_the_frame_axis():
    """A robot tool tilted 25 deg about x on a table turning about z: the offset has a swing
    part; the second channel brings it on, and the link reports SYNCED only then."""
    f = table(q_axis_angle((0, 0, 1), 30.0))
    start = Location.from_axis_angle((500.0, 100.0, 50.0), (1, 0, 0), 25.0)
    robot, item, outs = run_synced(f, start)
    link = robot.link_for(f)
    assert link.swing is not None and abs(link.swing_deg) > 1.0
    here = f.here(item)
    assert robot.setpoint.distance_to(here) < 1e-6
    assert robot.setpoint.angle_to(here) < 1e-6
    # follows afterwards, and a de-sync stops without a jump
    robot.slave = 0
    stop = []
    for _ in range(3000):
        stop.append(step(robot, f))
        if robot.slave == 0:
            break
    assert robot.slave == 0
    assert angle_rates(outs[-5:] + stop).max() <= 2 * SYNC_ROT.vel * 1.01


def test_slave_3_linear_frame_with_a_non_identity_orientation():
    origin = Location.from_axis_angle((0.0, 0.0, 20.0), (0.3, -0.2, 1.0), 50.0)
    f = belt(origin)
    robot, item, outs = run_synced(f, Location.from_axis_angle((100, 200, 80), (0, 1, 0), 10))
    here = f.here(item)
    assert robot.setpoint.distance_to(here) < 1e-6
    assert robot.setpoint.angle_to(here) < 1e-6
    assert robot.link_for(f).swing is None      # one channel about the offset's own axis
    assert angle_rates(outs).max() <= SYNC_ROT.vel * 1.01


def test_slave_5_keeps_its_reading_the_robot_turns_with_the_frame_only():
    f = table(q_axis_angle((0, 0, 1), 30.0))
    start = Location.at(500.0, 100.0, 50.0)
    robot, item, outs = run_synced(f, start, slave=5)
    disp = f.here(item).ominus(f.zero(item))
    assert robot.setpoint.isclose(robot.virtual.location.oplus(disp), 1e-6, 1e-6)
    assert robot.setpoint.angle_to(f.here(item)) == pytest.approx(30.0, abs=1e-6)
    assert robot.link_for(f).state == LinkState.SYNCED
