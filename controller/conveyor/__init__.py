"""The softMC conveyor model: moving frames, items, windows, triggers, hand-off.

Spec: docs/spec/conveyor.md (softMC's conveyor model) on top of the tracking core
(:mod:`controller.tracking`).  Functional core: deterministic, sample-stepped, no clocks.

Public API::

    from controller.conveyor import (Location, MovingFrame, Window, RobotGroup, ConveyorCell,
                                     SimulatedAxis, EncoderSource, frame_limits)
    cnv = MovingFrame("cnv", [SimulatedAxis.constant_speed(300.0)], directions=[(1, 0, 0)],
                      window=Window.single(100.0, 800.0))
    robot = RobotGroup("scara", TrackerParams(sample_time_s=0.002, planner="softmc"),
                       start=Location.at(0, 400, 50))
    cell = ConveyorCell([cnv], [robot])
    robot.master_frame = cnv            # slave = 5
    robot.trigger(cnv)                  # TRIGGER scara {MasterFrame = cnv}
    robot.moves(cnv.zero())             # MOVES scara cnv.zero
    out = cell.step()["scara"]          # once per sample: out.setpoint, out.imfs, out.events

Modules: ``location`` (⊕, ⊖, ':', quaternions), ``frames`` (linear and rotary geometry),
``frame`` (MovingFrame; its limits: ``FRAME_LIMITS``, ``frame_limits`` by softMC's names, a
:class:`controller.limits.CartesianLimits`), ``kinematics`` (robot type and dimension, checked at
MasterFrame assignment), ``sources``, ``window``, ``triggers``, ``motion``
(virtual robot), ``tracker`` (the core tracker with the arc de-sync), ``robot`` (RobotGroup:
MasterFrame, slave, IMFS, hand-off), ``catch`` (can it catch this item?), ``telemetry``
(per-item figures), ``cell`` (stepping), ``replay`` (record/replay of encoder counts and
triggers), ``errors``.
"""

# first: controller.tracking chooses compiled or pure for this package's modules too
# (docs/architecture.md "Compiled core"), before one of them is loaded
from .. import tracking as _tracking  # noqa: F401
from .catch import CatchPrediction, predict_catch
from .cell import ConveyorCell
from .errors import (ITEM_MISSED_CODE, ArcGeometryError, FrameBusyError, NoFrameError,
                     TooManyFramesError, TriggerBufferFull)
from .frame import (FRAME_LIMITS, LINEAR, ROTARY, ROTARY_DECOUPLED, SOFTMC_LIMIT_NAMES,
                    FrameType, MovingFrame, frame_limits)
from .frames import ArcGeometry, FramePoint, LinearGeometry, RotaryGeometry, arc_from_points
from .kinematics import Kinematics, KinematicsError, RobotType
from .location import Location, compound, oplus, ominus, q_axis_angle
from .motion import KEEP, MOTION_LIMITS, Motion, SCurve, VirtualRobot
from .robot import Event, EventKind, FrameLink, LinkState, RobotGroup, RobotOutput
from .sources import EncoderSource, FrameSource, SimulatedAxis, SourceState
from .telemetry import ItemRecord, ItemStatus
from .tracker import ArcPath, ConveyorTracker
from .triggers import TriggerBuffer, TriggerEntry
from .window import Window, WindowPosition

__all__ = [
    "ArcGeometry", "ArcGeometryError", "ArcPath", "CatchPrediction", "ConveyorCell",
    "ConveyorTracker", "EncoderSource", "Event", "EventKind", "FRAME_LIMITS", "FrameBusyError", "FrameLink", "FrameType",
    "FramePoint", "FrameSource", "ITEM_MISSED_CODE", "ItemRecord", "ItemStatus", "KEEP", "MOTION_LIMITS",
    "Kinematics", "KinematicsError", "RobotType",
    "LINEAR", "LinearGeometry", "LinkState", "Location", "Motion",
    "MovingFrame", "NoFrameError", "ROTARY", "ROTARY_DECOUPLED", "SOFTMC_LIMIT_NAMES", "RobotGroup", "RobotOutput",
    "RotaryGeometry", "SCurve", "SimulatedAxis", "SourceState", "TooManyFramesError",
    "TriggerBuffer", "TriggerBufferFull", "TriggerEntry", "VirtualRobot", "Window",
    "WindowPosition", "arc_from_points", "compound", "frame_limits", "ominus", "oplus", "predict_catch",
    "q_axis_angle",
]
