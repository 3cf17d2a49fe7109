"""Kinematic compatibility of a robot and a moving frame (docs/spec/conveyor.md#3.1).

softMC: "Robots must be of the same type as the world frame of the object in the tracking
process (dimension and robot type)"; "It is impossible to track a different kinematics
system".

A :class:`Kinematics` names a robot type and the dimension of its world frame: the Cartesian
coordinates its TCP has (2: X Y; 3: X Y Z; 4: X Y Z and a rotation about Z, e.g. a SCARA or
a gantry with a C axis; 6: the full location).  A robot group has one (default: a general
6-dimensional robot); a moving frame has the kinematics of the world frame its object is
given in (default: that of the robot it is assigned to, i.e. unchecked - the usual cell where
every frame is given in the robots' common world frame).

:func:`check_compatible` is called at ``<robot>.MasterFrame = <frame>`` (with the frame's
circle pre-calculation) and raises :class:`KinematicsError` when

- the frame declares a world frame of another type or dimension than the robot's;
- the frame's motion needs coordinates the robot does not have: a translation with a Z
  component on a 2-dimensional robot; a rotation on a robot of dimension 2 or 3; a rotation
  about an axis other than Z on a robot of dimension 4.

Spec: docs/spec/conveyor-extensions.md#2.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

from ..errors import ParameterError
from ..tracking.values import python_class

if TYPE_CHECKING:
    from .frame import MovingFrame

#: a direction or axis component below this counts as 0
AXIS_TOLERANCE = 1e-9


class RobotType(Enum):
    """The robot types of a cell (the value is the name used in files)."""

    GENERAL = "general"          #: any 6-axis (articulated) arm
    CARTESIAN = "cartesian"      #: XY table, XYZ gantry (optionally with a C axis)
    SCARA = "scara"
    DELTA = "delta"


DIMENSIONS = (2, 3, 4, 6)


class KinematicsError(ParameterError):
    """A robot cannot track a moving frame of another kinematics system."""


@python_class
@dataclass(frozen=True, slots=True)
class Kinematics:
    """A robot type and the dimension of its world frame (2, 3, 4 or 6 coordinates)."""

    type: RobotType = RobotType.GENERAL
    dimension: int = 6

    def __post_init__(self) -> None:
        if not isinstance(self.type, RobotType):
            try:
                object.__setattr__(self, "type", RobotType(self.type))
            except ValueError:
                raise ParameterError(
                    f"robot type (={self.type!r}) must be one of "
                    f"{', '.join(t.value for t in RobotType)}") from None
        if isinstance(self.dimension, bool) or self.dimension not in DIMENSIONS:
            raise ParameterError(f"kinematics dimension (={self.dimension!r}) must be one of "
                                 f"{', '.join(map(str, DIMENSIONS))} (X Y | X Y Z | X Y Z C | "
                                 "full location)")

    def __str__(self) -> str:
        return f"{self.type.value}, dimension {self.dimension}"


def _frame_needs(frame: "MovingFrame") -> tuple[bool, tuple[float, float, float] | None]:
    """(translation with a Z component, the rotation axis (world) or None) of a frame."""
    from .frames import GroupGeometry, RotaryGeometry

    geo = frame.geometry()
    if isinstance(geo, GroupGeometry):   # as the master robot moves
        return geo.master_dimension >= 3, (geo.axis if geo.master_dimension >= 4 else None)
    if isinstance(geo, RotaryGeometry):
        z = abs(geo.axis[0]) > AXIS_TOLERANCE or abs(geo.axis[1]) > AXIS_TOLERANCE
        return z, (geo.axis if geo.rotates else None)
    z = any(abs(d[2]) > AXIS_TOLERANCE for d in geo.directions)
    return z, None


def check_compatible(robot_name: str, robot: Kinematics, frame: "MovingFrame") -> None:
    """Raise :class:`KinematicsError` if ``robot`` cannot track ``frame`` (module doc)."""
    world = frame.world
    # (the fields compared: compiled code compares two instances of a class without its own
    # __eq__ by identity, docs/architecture.md "Compiled core")
    if world is not None and (world.type, world.dimension) != (robot.type, robot.dimension):
        raise KinematicsError(
            f"robot {robot_name!r} ({robot}) cannot track moving frame {frame.name!r}: its "
            f"world frame is of another kinematics system ({world}); the robot type and the "
            "dimension must match")
    needs_z, rot_axis = _frame_needs(frame)
    dim = robot.dimension
    if needs_z and dim < 3:
        raise KinematicsError(
            f"robot {robot_name!r} ({robot}) cannot track moving frame {frame.name!r}: the "
            "frame moves out of the X-Y plane and the robot has no Z coordinate")
    if rot_axis is not None:
        if dim < 4:
            raise KinematicsError(
                f"robot {robot_name!r} ({robot}) cannot track moving frame {frame.name!r}: "
                "the frame's orientation turns (rotary, type 1) and the robot has no "
                "rotation coordinate (use type 2, rotary decoupled, or a robot of dimension "
                ">= 4)")
        if dim == 4 and (abs(rot_axis[0]) > AXIS_TOLERANCE or abs(rot_axis[1]) > AXIS_TOLERANCE):
            raise KinematicsError(
                f"robot {robot_name!r} ({robot}) cannot track moving frame {frame.name!r}: "
                f"the frame turns about {tuple(round(a, 6) for a in rot_axis)}, the robot "
                "only about Z")
