"""One work cell stepped sample by sample: the per-sample order both shells run
(docs/spec/conveyor-extensions.md#5).

:class:`CellRun` builds the cell of a description (frames, robots, sensors, MasterFrame
changes: :mod:`.scenario`) on the conveyor model (:class:`~controller.conveyor.ConveyorCell`)
and steps it.  The offline simulator (:func:`controller.simulate.cell.run_cell`) gives each
frame its own source objects of its masters (a function of time, an encoder in counts); the
bus controller's cell source (:mod:`controller.canopen.apps.cell`) gives them
:class:`HeldSource` objects it sets to the encoders' estimates [mm] before each sample.  So the
two shells differ only in where the master values and the sensors' latched values come from.

Per step (loop index ``k``, producing sample ``k + 1`` at time ``(k + 1) T``):

1. the sensors' TRIGGERs due (sensor time ``t`` in ``[k T, (k + 1) T)``), each latching its
   frame's master values at ``t`` as the shell says (:data:`Latch`); a full trigger buffer
   is a ``trigger_rejected`` event, the run goes on;
2. the MasterFrame changes due (time ``t`` with ``round(t / T) = k``); a rejected one (by the
   robot, or because the frame's masters cannot be followed now) is a ``command_error``
   event, the run goes on;
3. the pick programs (:class:`~.program.PickProgram`) on the events of the last sample;
4. one step of the cell (frames, then robots).

Pure: no clock, no I/O; the same sources and latches give the same outputs bit for bit.
Units: mm, deg, s; master values in master units (counts, mm of belt, deg of a table).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

from ..conveyor import (ConveyorCell, Event, EventKind, MovingFrame, RobotGroup, RobotOutput,
                        TriggerBufferFull)
from ..conveyor.frame import LINEAR
from ..conveyor.sources import MasterSource, SourceState
from ..errors import CantrackError
from ..tracking import Mode, TrackerParams
from .program import PickProgram, PickState
from .scenario import CellFrameSpec, CellRobotSpec, FrameChange, SensorSpec

__all__ = ["CellRun", "FrameSources", "HeldSource", "Latch", "TriggerRecord"]

#: a sensor's latch: (sensor, index of its trigger time) -> the master values [master units]
#: of the sensor's frame at that time (None: a group frame, whose TRIGGER reads the TCP)
Latch = Callable[[SensorSpec, int], "tuple[float, ...] | None"]

#: per frame (not a group frame): one (source, master units per source unit) per DOF; the
#: frame's scale is the cell's mm per master unit divided by the second (an encoder in
#: counts: counts per master unit)
FrameSources = Mapping[str, Sequence[tuple[MasterSource, float]]]

#: (sample, robot, frame, item id, item type) of a TRIGGER
TriggerRecord = tuple[int, str, str, int, int]


class HeldSource:
    """A master source the shell sets before each sample (:meth:`hold`): ``read`` returns
    the value held [master units, per s, per s²]."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.state = SourceState(0.0)

    def hold(self, state: SourceState) -> None:
        self.state = state

    def read(self, k: int, t_s: float) -> SourceState:
        return self.state


class CellRun:
    """The cell of ``frames``, ``robots`` and ``sensors`` on the sources ``sources``, with
    every robot's tracker ``params`` (its mode from the robot's ``slave``).  Sample 0 (the
    frames' first read of their sources) is taken at construction: hold the sources' first
    values before."""

    def __init__(self, frames: Sequence[CellFrameSpec], robots: Sequence[CellRobotSpec],
                 sensors: Sequence[SensorSpec], params: TrackerParams,
                 sources: FrameSources) -> None:
        T = params.sample_time_s
        self.T = T
        self.specs = tuple(frames)
        self.robot_specs = tuple(robots)
        made: dict[str, MovingFrame] = {}
        for fs in frames:
            if fs.group is not None:
                continue   # made once its master robot exists
            srcs = [s for s, _ in sources[fs.name]]
            per = [c for _, c in sources[fs.name]]
            s = fs.spec
            assert s is not None   # (a frame with masters has its geometry)
            if s.type == LINEAR:
                made[fs.name] = MovingFrame(
                    fs.name, srcs, directions=list(fs.directions),
                    scales=[k / c for k, c in zip(fs.scales, per)], origin=s.origin,
                    limits=s.limits, window=fs.window, world=fs.world)
            else:
                made[fs.name] = MovingFrame(
                    fs.name, srcs, type=s.type, upstream=s.upstream, arc_point=s.arc_point,
                    downstream=s.downstream, up_master=s.up_master * per[0],
                    down_master=None if s.down_master is None else s.down_master * per[0],
                    limits=s.limits, window=fs.window, world=fs.world)
        self.robots: dict[str, RobotGroup] = {}
        for rs in robots:
            r = rs.robot
            robot = RobotGroup(r.name, params.with_(mode=Mode(r.slave)), start=r.start,
                               base=r.base, tool=r.tool, motion_limits=r.motion,
                               buffer_capacity=r.buffer_capacity, default_mode=r.slave,
                               kinematics=rs.kinematics)
            for fname, types in rs.track_types:
                robot.track_types(fname, types)
            self.robots[r.name] = robot
        for fs in frames:
            if fs.group is not None:
                made[fs.name] = MovingFrame.group(
                    fs.name, self.robots[fs.group.robot], transform=fs.group.transform,
                    axis=fs.group.axis, window=fs.window, limits=fs.group_limits,
                    world=fs.world)
        #: the frames in the description's order
        self.frames: dict[str, MovingFrame] = {fs.name: made[fs.name] for fs in frames}
        self.programs: dict[str, PickProgram] = {}
        for rs in robots:
            if rs.program is not None:
                assert rs.program_frame is not None
                self.programs[rs.name] = PickProgram(self.robots[rs.name],
                                                     self.frames[rs.program_frame],
                                                     rs.program, rs.robot.slave)
        self.cell = ConveyorCell(list(self.frames.values()), list(self.robots.values()))
        self._sensors: dict[int, list[tuple[SensorSpec, int]]] = {}
        for sen in sensors:
            for i, t in enumerate(sen.times):
                self._sensors.setdefault(int(math.floor(t / T + 1e-9)), []).append((sen, i))
        self._changes: dict[int, list[tuple[str, FrameChange]]] = {}
        for rs in robots:
            for c in rs.changes:
                self._changes.setdefault(int(round(c.time_s / T)), []).append((rs.name, c))
        #: the last loop index with a sensor or a MasterFrame change (-1: none)
        self.last_scheduled = max(list(self._sensors) + list(self._changes), default=-1)
        #: every TRIGGER given so far
        self.triggers: list[TriggerRecord] = []
        self._last: dict[str, tuple[Event, ...]] = dict.fromkeys(self.robots, ())
        self.k = 0

    def sensor_frames(self, k: int) -> tuple[str, ...]:
        """The frames whose sensors trigger in loop index ``k`` (the shell latches them)."""
        return tuple(sen.frame for sen, _ in self._sensors.get(k, ()))

    def step(self, latch: Latch, usable: Callable[[str], str | None] | None = None
             ) -> tuple[dict[str, RobotOutput], dict[str, list[Event]]]:
        """Loop index ``self.k`` (see the module docstring); returns each robot's output of
        the new sample and the events of the shell's commands (rejected TRIGGERs and
        MasterFrame changes) by robot, which precede the output's own events.

        ``usable(frame)``: why the frame's masters cannot be followed now (the bus: an
        encoder silent or lost), None when they can; a MasterFrame change to such a frame is
        refused (``command_error``) and a pick program waiting for its next item on it does
        not take one.  None: every frame is usable (the simulator)."""
        k = self.k
        frames, robots = self.frames, self.robots
        extra: dict[str, list[Event]] = {name: [] for name in robots}
        for sen, i in self._sensors.get(k, ()):
            group = frames[sen.frame].group_source is not None
            vals = None if group else latch(sen, i)
            for rname in sen.robots:
                try:
                    e = robots[rname].trigger(frames[sen.frame], values=vals,
                                              dr_mm=sen.dr_mm[i], item_type=sen.types[i],
                                              offset=sen.offset if group else None)
                except TriggerBufferFull as exc:
                    extra[rname].append(Event(k, EventKind.TRIGGER_REJECTED, sen.frame,
                                              message=str(exc)))
                    continue
                self.triggers.append((k, rname, sen.frame, e.id, e.item_type))
        for rname, c in self._changes.get(k, ()):
            why = usable(c.frame) if usable is not None and c.frame else None
            if why is not None:
                extra[rname].append(Event(k, EventKind.COMMAND_ERROR, c.frame or "",
                                          message=f"MasterFrame = {c.frame} refused: {why}"))
                continue
            try:
                robots[rname].set_master_frame(frames[c.frame] if c.frame else None)
            except CantrackError as exc:
                extra[rname].append(Event(k, EventKind.COMMAND_ERROR, c.frame or "",
                                          message=str(exc)))
        for rname, prog in self.programs.items():
            if usable is not None and prog.state is PickState.IDLE and \
                    usable(prog.frame.name) is not None:
                continue   # (no new item on a frame that cannot be followed)
            prog.tick(self._last[rname])
        outs = self.cell.step()
        for rname, out in outs.items():
            self._last[rname] = out.events
        self.k = k + 1
        return outs, extra

    def at_rest(self) -> bool:
        """Nothing is scheduled any more and every robot stands: no frame link, no motion,
        its program (if any) idle with no item of its frame left in the buffer."""
        if self.k <= self.last_scheduled:
            return False
        for name, r in self.robots.items():
            if r.links or r.virtual.busy:
                return False
            prog = self.programs.get(name)
            if prog is not None and (prog.item is not None or
                                     r.current_item(prog.frame) is not None):
                return False
        return True
