"""Kinematic compatibility at MasterFrame assignment (issue 16, point 4): "Robots must be of
the same type as the world frame of the object in the tracking process (dimension and robot
type)"; "It is impossible to track a different kinematics system"."""

from __future__ import annotations

import pytest

from controller.conveyor import (ConveyorCell, Kinematics, KinematicsError, Location,
                                 MovingFrame, RobotGroup, RobotType, SimulatedAxis, Window)
from controller.conveyor.location import q_axis_angle
from controller.errors import ParameterError
from controller.tracking import Imfs, TrackerParams

P = TrackerParams(sample_time_s=0.002, planner="softmc")


def belt(direction=(1, 0, 0), world=None):
    return MovingFrame("cnv", [SimulatedAxis.constant_speed(100.0)], directions=[direction],
                       window=Window.single(10.0, 2000.0), world=world)


def table(type_=1, axis_tilt=0.0):
    z = 0.0 if not axis_tilt else 100.0
    return MovingFrame("rot", [SimulatedAxis.constant_speed(10.0)], type=type_,
                       upstream=Location((600.0, -400.0, 0.0), q_axis_angle((0, 0, 1), 0.0)),
                       arc_point=(1000.0, 0.0, z), downstream=(600.0, 400.0, 0.0),
                       deg_per_unit=1.0, window=Window.single(2.0, 170.0))


def robot(kin=Kinematics()):
    return RobotGroup("r", P, start=Location.at(0, 0, 0), kinematics=kin)


def test_a_frame_of_another_robot_type_or_dimension_is_rejected_and_nothing_changes():
    f = belt(world=Kinematics(RobotType.SCARA, 4))
    r = robot(Kinematics(RobotType.GENERAL, 6))
    with pytest.raises(KinematicsError, match=r"robot 'r' \(general, dimension 6\) cannot "
                                              r"track moving frame 'cnv'.*scara, dimension 4"):
        r.master_frame = f
    assert r.master_frame is None and r.slave == 0 and not f.linked
    r2 = robot(Kinematics(RobotType.SCARA, 6))
    with pytest.raises(KinematicsError, match="dimension must match"):
        r2.set_slave(5, f)
    r3 = robot(Kinematics(RobotType.SCARA, 4))
    r3.master_frame = f
    assert r3.master_frame is f


@pytest.mark.parametrize("kin, frame, match", [
    (Kinematics(RobotType.CARTESIAN, 2), lambda: belt((1, 0, 0.2)), "out of the X-Y plane"),
    (Kinematics(RobotType.CARTESIAN, 3), lambda: table(1), "no rotation coordinate"),
    (Kinematics(RobotType.SCARA, 4), lambda: table(1, axis_tilt=1.0), "only about Z"),
    (Kinematics(RobotType.CARTESIAN, 2), lambda: table(2, axis_tilt=1.0), "X-Y plane"),
])
def test_a_frame_whose_motion_needs_coordinates_the_robot_lacks_is_rejected(kin, frame, match):
    with pytest.raises(KinematicsError, match=match):
        robot(kin).master_frame = frame()


@pytest.mark.parametrize("kin, frame", [
    (Kinematics(RobotType.CARTESIAN, 2), lambda: belt((0.6, 0.8, 0))),
    (Kinematics(RobotType.CARTESIAN, 3), lambda: table(2)),      # decoupled: no rotation
    (Kinematics(RobotType.SCARA, 4), lambda: table(1)),          # turns about Z
    (Kinematics(), lambda: table(1, axis_tilt=1.0)),
])
def test_compatible_pairs_track(kin, frame):
    f = frame()
    r = robot(kin)
    cell = ConveyorCell([f], [r])
    r.master_frame = f
    r.trigger(f)
    outs = cell.run(2000)
    assert any(o["r"].imfs == Imfs.SYNCHRONIZED for o in outs)


def test_bad_kinematics_values_name_what_is_allowed():
    with pytest.raises(ParameterError, match="dimension.*2, 3, 4, 6"):
        Kinematics(RobotType.SCARA, 5)
    with pytest.raises(ParameterError, match="robot type.*general, cartesian, scara, delta"):
        Kinematics("puma", 6)
    assert Kinematics("scara", 4).type is RobotType.SCARA
