"""The work cell on the bus: ``.tracking.cell`` run by the cycle (docs/spec/conveyor-extensions.md#5.1).

:class:`CellSource` is a :class:`~controller.canopen.master.source.SetpointSource` that owns
the cell's pure core: a :class:`~controller.cell.run.CellRun` (the frames, the robot groups,
their pick programs, the sensors and the timed MasterFrame changes on a
:class:`~controller.conveyor.ConveyorCell`), stepped once per cycle exactly as the offline
simulator steps a cell scenario (:func:`controller.simulate.cell.run_cell`):

- masters: every frame reads its encoders through its own
  :class:`~controller.cell.run.HeldSource` objects, set each cycle to that encoder's estimate
  in the context (``CycleContext.masters``: belt travel [mm], velocity [mm/s], acceleration
  [mm/s²] for SYNC k+1+d, the counts scaled once by the encoder's ``counts_per_mm``): master
  units are mm of belt, a frame's scale its ``scale_mm_per_unit``;
- time: loop index n (n = 0 in the first cycle after the start) makes cell sample n+1;
  MasterFrame changes and sensors are at seconds since tracking began (the start's SYNC);
- a sensor's TRIGGER latches, per DOF, the encoder's newest measured belt travel moved back
  by its estimated velocity over the time from the sensor time to this cycle's SYNC (the
  demo's photo-eye latch, :mod:`.demo`);
- output: per robot, ``Robot_real = base⁻¹ : setpoint : tool⁻¹`` through the robot's own
  kinematics (:meth:`~controller.canopen.config.cell.CellRobotConfig.machine`; the tool angle
  c [deg] the twist about z, unwrapped) gives its joints [mm | deg], robot after robot in the
  order of ``.tracking.cell.robots`` (= ``.tracking.axes``); the joint velocities [mm/s |
  deg/s] are backward differences over one period, so the cycle checks every target and
  its quick-stop end against the axis limits (:class:`AxisSetpoints` ``velocities``): a
  violation quick-stops every drive of every robot.  One period also after an overrun: a
  CSP drive interpolates between consecutive SYNC targets and the slipped periods sent no
  SYNC, so a synchronised robot's catch-up with its belt is driven in one period (a 108 ms
  stall at 10 ms: 20 mm, ~2000 mm/s): the limit quick stop is the safe reaction.

Every robot starts where its drives were enabled: when that pose is within half a count of
each axis of the robot's ``start`` the configured start is used (so the bus and the file start
alike), else the drives' pose, with a ``start_pose`` event.  The 402 enable, the supervision
and the controlled stop of all drives of all robots are the cycle's (a fault of one drive
quick-stops every drive; the run ends with exit code 3 or 4).  A PLC's engage 0 de-syncs
every robot (``STOP``); its item triggers and tracked types are not taken by a cell (the
cell's sensors and ``track_types`` say which robot takes what), each reported once.  A silent
or lost encoder de-syncs the robots following a frame it feeds; while it is not ready again,
a MasterFrame change to such a frame is refused (``command_error``) and a pick program takes
no new item on it.

Pure in the sense of :mod:`~controller.canopen.master.source`: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from itertools import islice
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from ...cell.run import CellRun, HeldSource
from ...cell.scenario import CellRobotSpec, SensorSpec
from ...conveyor import Event, EventKind, Location, RobotGroup, RobotOutput
from ...conveyor.location import q_twist_angle
from ...conveyor.sources import SourceState
from ...conveyor.telemetry import ItemRecord, ItemStatus
from ...errors import StateError
from ...kinematics import Kinematics as MachineKinematics
from ...tracking import Imfs, Mode, MotionState, TrackState
from ..config.cell import CellConfig
from ..master.events import EventKind as BusEventKind
from ..master.source import (
    AxisSetpoints,
    CycleContext,
    Engage,
    MasterEvent,
    MasterView,
    SourceEvent,
    SourceOutput,
    SourceStart,
    SourceStatus,
    Trigger,
    TrackTypes,
)

if TYPE_CHECKING:
    from .report import Telemetry

__all__ = ["CellSource", "RobotSummary", "end_summary", "format_cell_table", "frame_counts"]

_Z = (0.0, 0.0, 1.0)
_XYZ = frozenset("xyz")
#: the robot's events the cycle's event log gets (level 20: information)
_LOGGED = {EventKind.HANDOFF: BusEventKind.HANDOFF, EventKind.ITEM_MISSED: BusEventKind.ITEM_MISSED}
#: the order of a robot's tracking states when one stands for all (the PLC node, the record)
_RANK = {TrackState.SYNCED: 3, TrackState.SYNCING: 2, TrackState.DESYNCING: 1, TrackState.OFF: 0}


@dataclass
class RobotSummary:
    """One robot of the cell run so far: items triggered into its buffer, caught (synchronised),
    picked (its program), missed (30238), ignored (type not tracked), hand-offs, and the
    largest |actual - setpoint| of its drives [mm] while a frame link was synchronised (the
    setpoint the drives reach in this cycle)."""

    name: str
    triggered: int = 0
    caught: int = 0
    picked: int = 0
    missed: int = 0
    ignored: int = 0
    handoffs: int = 0
    max_error_mm: float = 0.0


@dataclass
class _Trace:
    """One robot's recorded samples (the plot and the summary of ``cantrack demo``)."""

    pos: list = field(default_factory=list)
    ori: list = field(default_factory=list)
    imfs: list = field(default_factory=list)
    slave: list = field(default_factory=list)
    mf: list = field(default_factory=list)
    events: list = field(default_factory=list)


class _ItemCounts:
    """One robot's item bookkeeping of a run: the records not reported yet (``open``, in
    record order), the caught / missed / ignored counts over every record, and the
    contribution to them of each record that can still change (``watch``); finished records
    leave both (their counts stay).  ``touched_max`` [records]: the most records one cycle
    looked at (open ones among them; a test's bound on the per-cycle work)."""

    def __init__(self) -> None:
        self.seen = 0
        self.open: dict[int, ItemRecord] = {}
        self.watch: dict[int, tuple[bool, bool, bool]] = {}
        self.caught = self.missed = self.ignored = 0
        self.touched_max = 0

    def sync(self, r: RobotGroup) -> None:
        """Take the records the core made since the last call (the newest of its
        insertion-ordered dict): open, counted from nothing."""
        records = r.records
        new = len(records) - self.seen
        if new <= 0:
            return
        fresh = list(islice(reversed(records.values()), new))
        for rec in reversed(fresh):
            self.open[rec.item_id] = rec
            self.watch.setdefault(rec.item_id, (False, False, False))
        self.seen = len(records)

    def count(self, item_id: int, rec: ItemRecord) -> None:
        now = (rec.caught, rec.status is ItemStatus.MISSED, rec.status is ItemStatus.IGNORED)
        was = self.watch.get(item_id, (False, False, False))
        if now != was:
            self.caught += now[0] - was[0]
            self.missed += now[1] - was[1]
            self.ignored += now[2] - was[2]
        self.watch[item_id] = now

    def keep(self, ids: set[int]) -> None:
        """Watch only ``ids`` from now on (the others cannot change any more)."""
        for item_id in [i for i in self.watch if i not in ids]:
            del self.watch[item_id]


class CellSource:
    """Run ``.tracking.cell`` (see the module docstring).

    ``duration_s`` [s of tracking]: the run ends after it (None: once nothing is scheduled any
    more and every robot stands); ``record`` up to this many samples of every robot's setpoint,
    IMFS, slave, MasterFrame and events (0: none; for the plot and summary of a short run);
    ``on_item(robot, record)`` is called with each item when its outcome is final (streaming
    telemetry)."""

    def __init__(self, cell: CellConfig, *, duration_s: float | None = None,
                 record: int = 0,
                 on_item: Callable[[str, ItemRecord], None] | None = None,
                 keep_inputs: bool = False) -> None:
        self.cell = cell
        self.duration_s = duration_s
        self.record = record
        self.on_item = on_item
        self.run: CellRun | None = None
        self.start_cycle = 0
        self.start_t_s = 0.0
        self.T = 0.0
        self._end_n: int | None = None
        self._held: dict[str, list[tuple[int, HeldSource]]] = {}
        self._enc_index = {name: i for i, name in enumerate(cell.encoders)}
        self._enc_names = list(cell.encoders)
        self._machines: list[tuple[RobotGroup, MachineKinematics, int, int, Location,
                                   Location]] = []
        self._joints: list[float] = []
        #: per robot: base and tool are identity; it has a tool axis c
        self._plain: list[bool] = []
        self._turns: list[bool] = []
        #: the joints sent in the last 1 + drive_delay_cycles cycles (the tracking error)
        self._sent: deque[tuple[float, ...]] = deque(maxlen=2)
        self._prev_c: dict[str, float] = {}
        self.summaries: dict[str, RobotSummary] = {r.name: RobotSummary(r.name)
                                                   for r in cell.robots}
        self._items = {r.name: _ItemCounts() for r in cell.robots}
        self._warned: set[str] = set()
        self.traces: dict[str, _Trace] = {r.name: _Trace() for r in cell.robots}
        self.master_values: dict[str, list[tuple[float, ...]]] = {}
        self.recorded = 0
        #: ``keep_inputs``: the frames' master values [mm, mm/s, mm/s²] held for sample 0
        #: (the start) and each loop index after it, and the sensors' latched values by
        #: (loop index, frame, trigger index), as given to the core (an identity test feeds
        #: them to the simulator: :func:`controller.simulate.cell.replay_cell`)
        self.keep_inputs = keep_inputs
        self.inputs: list[dict[str, tuple[SourceState, ...]]] = []
        self.latches: dict[tuple[int, str, int], tuple[float, ...]] = {}
        self._events: list[SourceEvent] = []
        self._status = SourceStatus()

    # -- start -----------------------------------------------------------------------------
    def start(self, start: SourceStart) -> SourceStatus:
        tc = start.tracking
        if not start.masters or len(start.masters) != len(self.cell.encoders):
            raise StateError("the cell source needs one master view per encoder of "
                             ".tracking.cell (the controller of a cell gives them)")
        T = self.T = start.period_s
        self._sent = deque(maxlen=1 + tc.drive_delay_cycles)
        self.start_cycle = start.cycle
        self.start_t_s = start.t_s
        if self.duration_s is not None:
            self._end_n = max(1, round(self.duration_s / T))
        params = replace(tc.tracker, sample_time_s=T)
        frames = self.cell.frames
        sources: dict[str, list[tuple[HeldSource, float]]] = {}
        for fs in frames:
            if fs.group is not None:
                continue
            held = [(self._enc_index[m], HeldSource(f"{fs.name}.{m}")) for m in fs.masters]
            self._held[fs.name] = held
            sources[fs.name] = [(h, 1.0) for _, h in held]
        held0 = self._hold(start.masters)
        if self.keep_inputs:
            self.inputs.append(held0)
        robots: list[CellRobotSpec] = []
        self._events = []
        j0 = 0
        joints = start.joints
        for rc in self.cell.robots:
            machine = rc.machine()
            n = len(rc.axes)
            spec = rc.spec
            rs = spec.robot
            mine = joints[j0:j0 + n]
            pose = machine.pose(mine)
            real = Location.from_axis_angle(pose.pos, _Z, pose.ang)
            world = rs.base.compound(real).compound(rs.tool)
            configured = rs.base.inverse().compound(rs.start).compound(rs.tool.inverse())
            cj = machine.joints(_state(configured, _unwrap(q_twist_angle(configured.ori, _Z),
                                                           pose.ang)))
            if all(abs(a - b) * ax.scale.counts_per_unit <= 0.5
                   for a, b, ax in zip(cj, mine, rc.axes)):
                begin = rs.start
            else:
                begin = world
                self._events.append(SourceEvent(
                    rc.name, BusEventKind.START_POSE,
                    f"robot {rc.name!r} starts where its drives are, "
                    + ", ".join(f"{a.name}={v:.3f}" for a, v in zip(rc.axes, mine))
                    + " (its start: " + ", ".join(f"{a.name}={v:.3f}"
                                                   for a, v in zip(rc.axes, cj)) + ")",
                    level=20))
            robots.append(replace(spec, robot=replace(rs, start=begin)))
            # the tool angle c [deg] is unwrapped from where the drive is (a c of 350 deg
            # stays 350, not -10)
            self._prev_c[rc.name] = pose.ang
            j0 += n
        self.run = CellRun(frames, robots, self.cell.sensors, params, sources)
        j0 = 0
        for rc in self.cell.robots:
            n = len(rc.axes)
            rs = rc.spec.robot
            self._machines.append((self.run.robots[rc.name], rc.machine(), j0, n,
                                   rs.base.inverse(), rs.tool.inverse()))
            self._plain.append(rs.base == Location() and rs.tool == Location())
            self._turns.append("c" in (a.name for a in rc.axes))
            j0 += n
        self._joints = list(joints)
        for name, r in self.run.robots.items():
            self._record_sample(name, r.setpoint, Imfs.NOT_SYNCHRONIZED, 0, "", ())
        self._record_masters()
        self._status = self._make_status()
        return self._status

    def _hold(self, masters: tuple[MasterView, ...]) -> dict[str, tuple[SourceState, ...]]:
        held: dict[str, tuple[SourceState, ...]] = {}
        for fname, srcs in self._held.items():
            vals = []
            for i, h in srcs:
                e = masters[i].estimate
                s = SourceState(e.pos, e.vel, e.acc)
                h.hold(s)
                vals.append(s)
            held[fname] = tuple(vals)
        return held

    # -- a cycle ---------------------------------------------------------------------------
    def step(self, ctx: CycleContext) -> SourceOutput:
        run = self.run
        assert run is not None, "step() before start()"
        events = self._events
        self._events = []
        masters = ctx.masters
        for cmd in ctx.commands:
            if isinstance(cmd, Engage):
                if cmd.mode == Mode.OFF:
                    for r in run.robots.values():
                        r.stop()
            elif isinstance(cmd, Trigger | TrackTypes):
                kind = "trigger" if isinstance(cmd, Trigger) else "track_types"
                if kind not in self._warned:
                    self._warned.add(kind)
                    events.append(SourceEvent(
                        "cell", BusEventKind.COMMAND_ERROR,
                        f"a PLC {kind.replace('_', ' ')} command is not taken by a cell "
                        "(its sensors and track_types say which robot takes what)",
                        "ignored (reported once)"))
        lost = {i for i, m in enumerate(masters)
                if m.event is MasterEvent.SILENT or m.event is MasterEvent.LOST}
        if lost:
            self._master_lost(lost)
        held = self._hold(masters)
        n = run.k
        tau_now = ctx.t_s - self.start_t_s

        def latch(sen: SensorSpec, i: int) -> tuple[float, ...]:
            out = []
            for j, _h in self._held[sen.frame]:
                m = masters[j]
                e = m.estimate
                s = m.belt_mm if m.belt_mm is not None else e.pos
                out.append(s - e.vel * (tau_now - sen.times[i]))
            vals = tuple(out)
            if self.keep_inputs:
                self.latches[(n, sen.frame, i)] = vals
            return vals

        def usable(frame: str) -> str | None:
            for j, _h in self._held.get(frame, ()):
                if not masters[j].ready:
                    return (f"encoder {self._enc_names[j]!r} not ready (silent or lost: the "
                            "belt is only extrapolated)")
            return None

        if self.keep_inputs:
            self.inputs.append(held)
        outs, extra = run.step(latch, usable)
        # the velocities over ONE period, also after an overrun: the drive interpolates
        # between consecutive SYNC targets and the slipped periods sent no SYNC (it held the
        # last target), so the whole catch-up is executed in the next period; that is the
        # velocity the axis limits must see (dividing by the slipped periods hid it)
        positions, velocities = self._setpoints(outs)
        self._bookkeeping(ctx, outs, extra, events)
        self._sent.append(positions)
        self._record_masters()
        self._status = self._make_status()
        done = (self._end_n is not None and run.k >= self._end_n) or \
            (self._end_n is None and run.at_rest())
        return SourceOutput(AxisSetpoints(positions, None, velocities), self._status,
                            events=tuple(events), done=done)

    def _setpoints(self, outs: dict[str, RobotOutput]
                   ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Every robot's joints [mm | deg] and their velocities [mm/s | deg/s] (backward
        differences over one period), robot after robot."""
        T = self.T
        joints: list[float] = []
        for (r, machine, _j0, _n, base_inv, tool_inv), plain, turns in zip(
                self._machines, self._plain, self._turns):
            real = outs[r.name].setpoint
            if not plain:   # (base and tool identity: Robot_real is the setpoint)
                real = base_inv.compound(real).compound(tool_inv)
            c = 0.0
            if turns:       # (a robot without a tool axis c: its angle is not driven)
                c = self._prev_c[r.name] = _unwrap(q_twist_angle(real.ori, _Z),
                                                   self._prev_c[r.name])
            joints.extend(machine.joints(_state(real, c)))
        prev_j = self._joints
        vel = tuple((a - b) / T for a, b in zip(joints, prev_j))
        self._joints = joints
        return tuple(joints), vel

    def _bookkeeping(self, ctx: CycleContext, outs: dict[str, RobotOutput],
                     extra: dict[str, list[Event]], events: list[SourceEvent]) -> None:
        run = self.run
        assert run is not None
        T = self.T
        for i, rc in enumerate(self.cell.robots):
            name = rc.name
            out = outs[name]
            sm = self.summaries[name]
            r = run.robots[name]
            evs = tuple(extra[name]) + out.events
            for e in evs:
                kind = _LOGGED.get(e.kind)
                if kind is not None:
                    what = (f"item {e.item} missed (30238) on frame {e.frame!r}"
                            if e.kind is EventKind.ITEM_MISSED
                            else f"hands off to frame {e.frame!r}")
                    events.append(SourceEvent(name, kind, f"robot {name!r}: {what}"
                                              + (f": {e.message}" if e.message else ""),
                                              level=20))
                    if e.kind is EventKind.HANDOFF:
                        sm.handoffs += 1
                elif e.kind in (EventKind.COMMAND_ERROR, EventKind.TRIGGER_REJECTED):
                    events.append(SourceEvent(
                        name, BusEventKind.COMMAND_ERROR if e.kind is EventKind.COMMAND_ERROR
                        else BusEventKind.TRIGGER_DROPPED,
                        f"robot {name!r}, frame {e.frame!r}: {e.message}",
                        "refused, the run goes on"))
            if r.imfs == Imfs.SYNCHRONIZED:
                _r, _m, j0, n, _b, _t = self._machines[i]
                sm.max_error_mm = max(sm.max_error_mm, self._error(ctx, j0, n))
            self._record_sample(name, out.setpoint, out.imfs, out.slave,
                                out.master_frame or "", evs)
            self._finish_items(name, r, T)

    def _error(self, ctx: CycleContext, j0: int, n: int) -> float:
        """|actual - target| over a robot's x, y, z [mm]: the drives' actual positions of
        this SYNC (fresh TPDOs only) against the joints sent ``1 + drive_delay_cycles``
        cycles ago (the target they reach now); 0 until there is one."""
        if len(self._sent) < self._sent.maxlen:  # type: ignore[operator]  # (maxlen set)
            return 0.0
        target = self._sent[0]
        s = 0.0
        for view, goal in zip(ctx.drives[j0:j0 + n], target[j0:j0 + n]):
            if view.axis in _XYZ and view.fresh and view.actual is not None:
                d = view.actual - goal
                s += d * d
        return math.sqrt(s)

    def _finish_items(self, name: str, r: RobotGroup, T: float) -> None:
        """Report the items whose outcome became final (``on_item``, in record order) and
        update the robot's counts.  Only the records that can still change are looked at:
        the ones not reported yet, those in the trigger buffer or a link's current item
        (the core changes no other record: a SKIPPED item is taken again only from the
        buffer), and those that were so at the last cycle; the buffer bounds them, not the
        number of items of the run (issue 12: O(1) work per cycle in long runs)."""
        sm = self.summaries[name]
        prog = self.run.programs.get(name) if self.run is not None else None
        ic = self._items[name]
        ic.sync(r)
        final = (ItemStatus.MISSED, ItemStatus.SKIPPED, ItemStatus.LOST, ItemStatus.IGNORED)
        watch = set(ic.open)
        watch.update(e.id for e in r.buffer)
        watch.update(link.record.item_id for link in r.links if link.record is not None)
        records = r.records
        looked = ic.watch.keys() | watch
        for item_id in looked:
            rec = records.get(item_id)
            if rec is not None:
                ic.count(item_id, rec)
        ic.keep(watch)
        ic.touched_max = max(ic.touched_max, len(looked))
        if ic.open:
            done_ids = []
            for item_id, rec in ic.open.items():
                if rec.status in final or (rec.status is ItemStatus.CAUGHT and (
                        rec.left_sample is not None or
                        (prog is not None and rec.item_id in prog.picks))):
                    done_ids.append(item_id)
                    if self.on_item is not None:
                        self.on_item(name, rec)
            for item_id in done_ids:
                del ic.open[item_id]
        sm.triggered, sm.caught, sm.missed, sm.ignored = (
            len(records), ic.caught, ic.missed, ic.ignored)
        sm.picked = len(prog.picks) if prog is not None else 0

    def _master_lost(self, lost: set[int]) -> None:
        """De-sync (STOP) every robot that follows a frame fed by a lost encoder."""
        run = self.run
        assert run is not None
        frames = {f for f, srcs in self._held.items() if any(i in lost for i, _ in srcs)}
        for r in run.robots.values():
            if any(link.frame.name in frames for link in r.links):
                r.stop()

    def _make_status(self) -> SourceStatus:
        """The cell as one status (the record, the status line, the PLC node): the most
        engaged robot's tracking (SYNCED > SYNCING > DESYNCING > OFF) and IMFS; the items of
        every robot."""
        run = self.run
        best, imfs = TrackState.OFF, Imfs.NOT_SYNCHRONIZED
        if run is not None:
            for r in run.robots.values():
                st = TrackState.OFF
                for link in r.links:
                    if not link.done:
                        st = TrackState(link.tracker.state)
                        break
                if _RANK[st] > _RANK[best]:
                    best, imfs = st, r.imfs
        sm = self.summaries.values()
        return SourceStatus(best, imfs, best, imfs, items_detected=len(run.triggers)
                            if run is not None else 0,
                            items_missed=sum(s.missed for s in sm),
                            items_ignored=sum(s.ignored for s in sm))

    # -- records ---------------------------------------------------------------------------
    def _record_sample(self, name: str, loc: Location, imfs: Imfs, slave: int, mf: str,
                       evs: tuple[Event, ...]) -> None:
        if self.recorded >= self.record:
            return
        tr = self.traces[name]
        tr.pos.append(loc.pos)
        tr.ori.append(loc.ori)
        tr.imfs.append(int(imfs))
        tr.slave.append(slave)
        tr.mf.append(mf)
        tr.events.extend(evs)

    def _record_masters(self) -> None:
        if self.recorded >= self.record or self.run is None:
            return
        for name, f in self.run.frames.items():
            self.master_values.setdefault(name, []).append(f.source_values())
        self.recorded += 1

    def unfinished(self) -> list[tuple[str, ItemRecord]]:
        """(robot, record) of every item whose outcome is not final yet (still pending or
        being tracked when the run ended; ``on_item`` has not had them)."""
        out: list[tuple[str, ItemRecord]] = []
        for rc in self.cell.robots:
            ic = self._items[rc.name]
            if self.run is not None:
                ic.sync(self.run.robots[rc.name])
            out.extend((rc.name, ic.open[i]) for i in sorted(ic.open))
        return out

    def records(self, name: str) -> list[ItemRecord]:
        """Robot ``name``'s item records, by item id."""
        if self.run is None:
            return []
        r = self.run.robots[name]
        return [r.records[i] for i in sorted(r.records)]


def _state(loc: Location, c_deg: float) -> MotionState:
    """The machine pose of a robot location [mm] with tool angle ``c_deg`` [deg]."""
    p = loc.pos
    return MotionState.at(p[0], p[1], p[2], c_deg)


def finish_telemetry(tel: Telemetry, src: CellSource) -> dict[str, dict]:
    """The end of a cell run's telemetry, however it ends (``cantrack demo`` and ``cantrack
    run`` alike): the items still pending written, then the end line's extras
    (:func:`end_summary`) returned for ``tel.close``."""
    for robot, rec in src.unfinished():
        tel.cell_item(robot, rec)
    return end_summary(src)


def end_summary(src: CellSource) -> dict[str, dict]:
    """The telemetry's end-line extras of a cell run (``cantrack demo`` and ``cantrack run``
    alike): every robot's :class:`RobotSummary` and :func:`frame_counts`."""
    return {"robots": {n: vars(s) for n, s in src.summaries.items()},
            "frames": frame_counts(src)}


def frame_counts(src: CellSource) -> dict[str, dict[str, int]]:
    """Per frame: items triggered on it (into any robot's buffer), caught, missed (30238),
    ignored (type not tracked)."""
    out = {fs.name: {"triggered": 0, "caught": 0, "missed": 0, "ignored": 0}
           for fs in src.cell.frames}
    for rc in src.cell.robots:
        for rec in src.records(rc.name):
            c = out[rec.frame]
            c["triggered"] += 1
            c["caught"] += rec.caught
            c["missed"] += rec.status is ItemStatus.MISSED
            c["ignored"] += rec.status is ItemStatus.IGNORED
    return out


def format_cell_table(src: CellSource) -> str:
    """The cell's summary: one row per robot (items triggered, caught, picked, missed,
    ignored, hand-offs, largest tracking error [mm] while synchronised), one per frame, one
    per item (robot, frame, type, outcome, trigger and synchronised times [s since tracking
    began], time to sync [s])."""
    lines = [f"{'robot':<8} {'items':>5} {'caught':>6} {'picked':>6} {'missed':>6} "
             f"{'ignored':>7} {'hand-offs':>9} {'max err mm':>10}"]
    for s in src.summaries.values():
        lines.append(f"{s.name:<8} {s.triggered:>5} {s.caught:>6} {s.picked:>6} "
                     f"{s.missed:>6} {s.ignored:>7} {s.handoffs:>9} {s.max_error_mm:>10.4f}")
    lines.append("")
    lines.append(f"{'frame':<8} {'items':>5} {'caught':>6} {'missed':>6} {'ignored':>7}")
    for name, c in frame_counts(src).items():
        lines.append(f"{name:<8} {c['triggered']:>5} {c['caught']:>6} {c['missed']:>6} "
                     f"{c['ignored']:>7}")
    lines.append("")
    lines.append(f"{'robot':<8} {'item':>4} {'frame':<8} {'type':>4} {'outcome':<8} "
                 f"{'trigger s':>9} {'synced s':>9} {'to sync s':>9}")
    for rc in src.cell.robots:
        for rec in src.records(rc.name):
            syn = f"{rec.synced_s:9.3f}" if rec.synced_s is not None else f"{'-':>9}"
            tts = rec.time_to_sync_s
            lines.append(f"{rc.name:<8} {rec.item_id:>4} {rec.frame:<8} {rec.item_type:>4} "
                         f"{rec.status.value:<8} {rec.trigger_s:9.3f} {syn} "
                         + (f"{tts:9.3f}" if tts is not None else f"{'-':>9}"))
    return "\n".join(lines)


def _unwrap(angle_deg: float, near_deg: float) -> float:
    """``angle_deg`` plus the whole turns that bring it within 180 deg of ``near_deg``."""
    d = (angle_deg - near_deg) % 360.0
    return near_deg + (d - 360.0 if d > 180.0 else d)
