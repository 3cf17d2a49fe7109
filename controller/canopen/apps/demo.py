"""The demo's pick and place on the softMC conveyor model (:mod:`controller.conveyor`).

One application (:class:`PickPlace`, the :class:`~controller.canopen.master.app.Application`
interface) runs a :class:`~controller.conveyor.RobotGroup` ``robot`` on a linear
:class:`~controller.conveyor.MovingFrame` ``belt``, one sample per controller cycle:

- master source: the belt travel [mm] the controller estimates from the encoder (position,
  velocity, acceleration of :class:`~controller.tracking.MasterEstimate`), set on the frame
  each cycle (``MovingFrame.set_master``).  The counts are scaled once, by
  ``.tracking.conveyor.counts_per_mm`` in the estimator, so the frame's scale is 1 mm/unit;
  frame direction and origin are ``.tracking.conveyor``'s, moved to the photo-eye (the
  trigger point, MF.zero) at ``pick.height``;
- photo-eye: each rising edge is a ``TRIGGER robot {MasterFrame = belt}`` whose value is the
  belt travel at the edge (this cycle's measurement moved back by the estimated velocity x
  (t_cycle - t_edge)); the entry goes into the robot's trigger buffer;
- window: ``.tracking.window`` relative to the photo-eye (``Window.single(start - eye,
  end - eye)``); the frame link engages the oldest item when it is inside the window and
  reports an item that leaves it before the robot is synchronised: ``item_missed``, code
  30238 (:data:`~controller.conveyor.ITEM_MISSED_CODE`);
- the sequence (:class:`Step`): WAIT (an item in the buffer, no frame link left) ->
  ``MasterFrame = belt`` (slave 5) and ``MOVES`` to the item's zero (lateral offset, angle) ->
  APPROACH (IMFS 1 and the move done) -> FOLLOW ``pick.dwell_s`` -> ``NEXTITEM``,
  ``MasterFrame = none`` (de-sync on the path), ``MOVES`` to the place -> PLACE (move done,
  frame detached, dwell ``place.dwell_s``) -> WAIT.  Items that pass the window while the
  robot places are missed (30238) when the robot takes them from the buffer;
- output: the robot group's setpoint (world TCP; angle about z) is the master of the
  controller's :class:`~controller.tracking.Tracker`, engaged once (absolute) at the start and
  SYNCED from then on, so it passes the setpoint through unchanged to the kinematics and
  counts (its master limits are lifted: the robot group limits its own motions with the
  tracker's sync limits).  ``imfs`` (the cycle record, status line, telemetry, PLC 2001h) is
  the robot group's.  Per-item figures come from the robot's ``ItemRecord`` (engaged and
  synchronised samples, peak errors, status): ``Item.model`` in telemetry.jsonl.

The simulated side (:class:`PhotoEye`) knows the true belt travel (the encoder's speed
profile) and the items' belt positions (seeded pitch, lateral offset and angle), and turns
them into edge times.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import TYPE_CHECKING

from ...conveyor import (
    ITEM_MISSED_CODE,
    Location,
    MotionLimits,
    MovingFrame,
    RobotGroup,
    Window,
    q_axis_angle,
)
from ...conveyor.location import q_to_axis_angle, vec3
from ...conveyor.sources import SourceState
from ...tracking import Imfs, Limits, MasterEstimate, Mode, MotionState, Tracker, TrackState
from ...errors import StateError
from ..config.demo import DemoConfig
from ..master.app import AppStatus
from ..config.plc import TriggerOverflow

if TYPE_CHECKING:
    from ..master.cycle import Controller
    from ..slave.encoder import SpeedProfile


class Step(Enum):
    WAIT = "wait"
    APPROACH = "approach"
    FOLLOW = "follow"
    PLACE = "place"


@dataclass
class Item:
    """One item: seen by the photo-eye at controller time ``t_edge_ns``."""

    index: int
    t_edge_ns: int
    lateral: float  # mm across the belt
    angle: float  # deg
    s_item: float | None = None  # belt travel when it passed the photo-eye [mm]
    trigger_cycle: int | None = None
    engage_cycle: int | None = None
    synced_cycle: int | None = None
    picked_cycle: int | None = None
    placed_cycle: int | None = None
    outcome: str = "pending"  # pending, placed, missed, ignored, dropped (buffer full)
    reason: str = ""
    max_error_mm: float = 0.0
    u_pick: float | None = None
    entry_id: int | None = None  # its TRIGGER entry in the robot's buffer
    item_type: int = 0  # its class (.demo.item_types; .tracking.items.track_types)
    model: dict = field(default_factory=dict)  # the conveyor model's ItemRecord.as_dict()


class PhotoEye:
    """Simulated photo-eye: item edges from the true belt travel (the encoder's profile)."""

    def __init__(self, profile: SpeedProfile, demo: DemoConfig, start_s: float) -> None:
        rng = random.Random(demo.seed)
        self.items: list[Item] = []
        b = profile.travel(start_s + demo.first_item_s)
        for i in range(demo.items):
            t = self._time_at(profile, b, start_s)
            self.items.append(Item(i, round(t * 1e9), rng.uniform(*demo.lateral),
                                   rng.uniform(*demo.angle),
                                   item_type=demo.item_types[i % len(demo.item_types)]
                                   if demo.item_types else 0))
            b += rng.uniform(*demo.pitch_mm)
        self._next = 0

    @staticmethod
    def _time_at(profile: SpeedProfile, travel: float, t_lo: float) -> float:
        lo, hi = t_lo, t_lo + 1.0
        while profile.travel(hi) < travel:
            hi += 2 * (hi - lo)
            if hi > 1e6:
                raise ValueError("the belt never reaches the item (speed profile <= 0?)")
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if profile.travel(mid) < travel:
                lo = mid
            else:
                hi = mid
        return hi

    @property
    def detected(self) -> int:
        """Items whose edge has been reported so far (PLC triggers included)."""
        return self._next

    def trigger(self, t_edge_ns: int, lateral: float = 0.0, angle: float = 0.0) -> Item:
        """An edge reported from outside (the PLC's trigger input, 2004h of the controller
        node): a new item at the photo-eye at ``t_edge_ns``, on the belt's centre line."""
        item = Item(len(self.items), int(t_edge_ns), lateral, angle)
        i = self._next
        while i < len(self.items) and self.items[i].t_edge_ns <= item.t_edge_ns:
            i += 1
        self.items.insert(i, item)
        return item

    def edges_until(self, t_ns: int) -> list[Item]:
        out = []
        while self._next < len(self.items) and self.items[self._next].t_edge_ns <= t_ns:
            out.append(self.items[self._next])
            self._next += 1
        return out


@dataclass
class PickPlace:
    """The demo sequence on the conveyor model (see the module docstring)."""

    demo: DemoConfig
    eye: PhotoEye | None = None
    step: Step = Step.WAIT
    done_items: list[Item] = field(default_factory=list)
    current: Item | None = None
    frame: MovingFrame | None = None
    robot: RobotGroup | None = None
    imfs_log: list[int] = field(default_factory=list)
    #: items missed so far (counted as they end, for :meth:`status`)
    missed: int = 0
    _by_entry: dict = field(default_factory=dict)
    #: a full trigger buffer drops the newest trigger or the oldest waiting item
    trigger_overflow: TriggerOverflow = TriggerOverflow.DROP_NEWEST
    #: items dropped because the trigger buffer was full
    triggers_dropped: int = 0
    _until: int = 0
    _end_cycle: int | None = None
    _drops_unreported: int = 0
    _drop_reported: float | None = None

    @property
    def imfs(self) -> int:
        """IMFS of the robot group (0 before the start)."""
        return int(self.robot.imfs) if self.robot is not None else 0

    @property
    def track_state(self) -> TrackState:
        """The state of the robot's belt tracking: its (first) frame link's tracker, OFF
        without a link (the controller's own tracker just passes the setpoint through)."""
        if self.robot is not None:
            for link in self.robot.links:
                if not link.done:
                    return TrackState(link.tracker.state)
        return TrackState.OFF

    def start(self, ctl: Controller, cycle: int) -> None:
        if self.eye is None:
            raise ValueError("PickPlace needs a photo-eye")
        self._end_cycle = cycle + int(self.demo.duration_s / ctl.cfg.period_s)
        conv = ctl.cfg.tracking.conveyor
        o, d = conv.origin, conv.direction
        pe = self.demo.photo_eye
        w0, w1 = ctl.cfg.tracking.window
        self.frame = MovingFrame(
            "belt", directions=[d],
            origin=Location.at(*(o[i] + d[i] * pe + (self.demo.pick_height if i == 2 else 0.0)
                                 for i in range(3))),
            window=Window.single(w0 - pe, w1 - pe))
        tp = ctl.cfg.tracking.tracker
        sp = ctl.tracker.setpoint
        self._T = ctl.cfg.period_s
        self.robot = RobotGroup("robot", replace(tp, sample_time_s=ctl.cfg.period_s),
                                start=Location.from_axis_angle(sp.pos, (0.0, 0.0, 1.0), sp.ang),
                                motion_limits=MotionLimits(
                                    tp.sync_trans.vel, tp.sync_trans.acc, tp.sync_trans.jerk,
                                    tp.sync_rot.vel, tp.sync_rot.acc, tp.sync_rot.jerk))
        if ctl.cfg.tracking.track_types is not None:
            self.robot.track_types(self.frame, ctl.cfg.tracking.track_types)
        self._prev = sp
        # the controller's tracker passes the robot's setpoint through (SYNCED, absolute);
        # the robot group limits its own motions, so the master limits are the robot's
        big = Limits(1e9, 1e9, 1e9)
        ctl.tracker = Tracker(replace(tp, master_max_trans=big, master_max_rot=big), sp)
        ctl.tracker.engage(Mode.ABSOLUTE)

    def _across(self, ctl: Controller) -> tuple[float, float, float]:
        d = ctl.cfg.tracking.conveyor.direction
        n = math.hypot(d[0], d[1])
        return (-d[1] / n, d[0] / n, 0.0) if n > 1e-9 else (0.0, 1.0, 0.0)

    def _finish_item(self, item: Item, outcome: str, reason: str = "") -> None:
        if item.outcome != "pending":
            return
        item.outcome = outcome
        item.reason = reason
        self.done_items.append(item)
        self.missed += outcome == "missed"
        if item is self.current:
            self.current = None

    def _cell(self) -> tuple[RobotGroup, MovingFrame]:
        """The robot group and its moving frame (made by ``setup``)."""
        if self.robot is None or self.frame is None:
            raise StateError("the conveyor demo is not set up (setup() makes its robot)")
        return self.robot, self.frame

    def update(self, ctl: Controller, cycle: int, belt: MasterEstimate) -> MotionState:
        r, f = self._cell()
        T = self._T
        t_now = ctl.t0 + cycle * ctl.period_ns
        f.set_master([SourceState(belt.pos, belt.vel, belt.acc)], r.k)
        for item in self.eye.edges_until(t_now):
            s_meas = ctl.master.belt_mm if ctl.master.belt_mm is not None else belt.pos
            item.s_item = s_meas - belt.vel * (t_now - item.t_edge_ns) * 1e-9
            item.trigger_cycle = cycle
            if r.buffer.full and not self._make_room(ctl, cycle, t_now, item):
                continue
            e = r.trigger(f, values=[item.s_item], item_type=item.item_type)
            item.entry_id = e.id
            self._by_entry[e.id] = item
            types = r.tracked_types(f)
            if types is not None and item.item_type not in types:
                self._finish_item(item, "ignored", f"type {item.item_type} not tracked")
        step = self.step
        if step == Step.WAIT:
            entry = r.buffer.current(f.name, r.tracked_types(f))
            while entry is not None and self._by_entry[entry.id].outcome != "pending":
                r.nextitem(f)  # (an item de-synced by STOP stays in the buffer: drop it)
                entry = r.buffer.current(f.name, r.tracked_types(f))
            if entry is not None and not r.links and ctl.master.ready:
                item = self._by_entry[entry.id]
                self.current = item
                r.set_master_frame(f, Mode.RELATIVE)
                n = self._across(ctl)
                z = f.zero(entry).pos
                r.moves(Location((z[0] + n[0] * item.lateral, z[1] + n[1] * item.lateral,
                                  z[2]), q_axis_angle((0.0, 0.0, 1.0), item.angle)),
                        name=f"approach item {item.index}")
                self.step = Step.APPROACH
        elif step == Step.APPROACH:
            if r.imfs == Imfs.SYNCHRONIZED and not r.virtual.busy:
                self._until = cycle + round(self.demo.pick_dwell_s / T)
                self.step = Step.FOLLOW
        elif step == Step.FOLLOW:
            item = self.current
            item.max_error_mm = max(item.max_error_mm, ctl.last_tracking_error)
            if cycle >= self._until:
                item.picked_cycle = cycle
                item.u_pick = self.demo.photo_eye + belt.pos - item.s_item
                r.nextitem(f)
                r.master_frame = None
                p = self.demo.place_position
                r.moves(Location(tuple(p), q_axis_angle((0.0, 0.0, 1.0), self.demo.place_angle)),
                        name="place")
                self.step = Step.PLACE
        elif step == Step.PLACE:
            item = self.current
            if not r.virtual.busy and not r.links:
                if item.placed_cycle is None:
                    item.placed_cycle = cycle
                if (cycle - item.placed_cycle) * T >= self.demo.place_dwell_s:
                    self._finish_item(item, "placed")
                    self.step = Step.WAIT
        if ctl.tracker.state is TrackState.OFF and ctl.master.ready:
            ctl.tracker.engage(Mode.ABSOLUTE)  # (de-synced by a silent encoder: follow again)
        out = r.update()
        self.imfs_log.append(int(out.imfs))
        for ev in out.events:
            ev_item = self._by_entry.get(ev.item) if ev.item is not None else None
            if ev_item is not None and ev.kind == "engaged" and ev_item.outcome == "pending":
                ev_item.engage_cycle = cycle
                ev_item.synced_cycle = None
            elif ev_item is not None and ev.kind == "synchronized" \
                    and ev_item.synced_cycle is None:
                ev_item.synced_cycle = cycle
            if ev.kind == "item_missed" and ev.item in self._by_entry:
                item = self._by_entry[ev.item]
                self._finish_item(item, "missed", f"left the window ({ev.code})")
                if self.step in (Step.APPROACH, Step.FOLLOW):
                    self.step = Step.WAIT
                ctl.events.add(cycle, (t_now - ctl.t0) * 1e-9, "demo", "item_missed",
                               f"item {item.index} missed ({ITEM_MISSED_CODE}): {ev.message}",
                               level=20)
        loc = out.setpoint
        axis, ang = q_to_axis_angle(loc.ori)
        if axis[2] < 0:
            ang = -ang
        prev = self._prev
        vel = vec3(out.velocity)
        acc = vec3((a - b) / T for a, b in zip(vel, prev.vel))
        ang_vel = (ang - prev.ang) / T
        m = MotionState(vec3(loc.pos), vel, acc, ang, ang_vel, (ang_vel - prev.ang_vel) / T)
        self._prev = m
        return m

    def _make_room(self, ctl: Controller, cycle: int, t_now: int, item: Item) -> bool:
        """The robot's trigger buffer is full: drop the new item (``drop_newest``) or the
        oldest waiting one that is not being tracked (``drop_oldest``); count it, report it
        (at most one event per second); True when ``item`` may go in now."""
        r, f = self._cell()
        victim = item
        if self.trigger_overflow is TriggerOverflow.DROP_OLDEST:
            busy = self.current.entry_id if self.current is not None else None
            for e in r.buffer.entries(f.name):
                if e.id != busy:
                    r.buffer.remove(e)
                    victim = self._by_entry.get(e.id, item)
                    break
        self._finish_item(victim, "dropped", f"trigger buffer full ({r.buffer.capacity} "
                          f"entries, {self.trigger_overflow.value})")
        self.triggers_dropped += 1
        self._drops_unreported += 1
        t_s = (t_now - ctl.t0) * 1e-9
        if self._drop_reported is None or t_s - self._drop_reported >= 1.0:
            n, self._drops_unreported = self._drops_unreported, 0
            self._drop_reported = t_s
            ctl.events.add(cycle, t_s, "demo", "trigger_dropped",
                           f"trigger buffer of robot {r.name!r} full "
                           f"({r.buffer.capacity} entries): item {victim.index} dropped"
                           + (f" ({n} dropped since the last report)" if n > 1 else ""),
                           f"{self.trigger_overflow.value} (the run goes on)")
        return victim is not item

    def engage(self, ctl: Controller, mode: Mode) -> bool:
        """The PLC's 2005h: 0 de-syncs the robot from the belt (``STOP``: the item being
        approached or followed is missed); 3/5 are the program's to give (ignored)."""
        if mode == Mode.OFF and self.robot is not None:
            if self.current is not None and self.step in (Step.APPROACH, Step.FOLLOW):
                self._finish_item(self.current, "missed", "disengaged by the PLC")
                self.step = Step.WAIT
            self.robot.stop()
        return True

    def trigger(self, t_ns: int) -> bool:
        """A PLC's item trigger: an item edge of the photo-eye (counted once the cycle takes
        the item in)."""
        if self.eye is None:
            return False
        self.eye.trigger(t_ns)
        return True

    def status(self) -> AppStatus:
        """The robot group's tracking, the photo-eye's count, the items missed."""
        return AppStatus(self.track_state if self.robot is not None else None,
                         Imfs(self.imfs) if self.robot is not None else None,
                         self.eye.detected if self.eye is not None else None, self.missed,
                         self.triggers_dropped)

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        if self.current is not None and self.step in (Step.APPROACH, Step.FOLLOW):
            self._finish_item(self.current, "missed", "encoder silent")
            self._cell()[0].stop()
            self.step = Step.WAIT

    def done(self, ctl: Controller, cycle: int) -> bool:
        if self._end_cycle is not None and cycle >= self._end_cycle:
            return True
        all_seen = self.eye is not None and len(self.done_items) == len(self.eye.items)
        if not (all_seen and self.step == Step.WAIT):
            return False
        r = self._cell()[0]
        return not r.links and not r.virtual.busy

    def items(self) -> list[Item]:
        """All items (by index), with the conveyor model's telemetry in ``Item.model``."""
        if self.robot is not None:
            for it in self._by_entry.values():
                rec = self.robot.records.get(it.entry_id)
                if rec is not None:
                    it.model = rec.as_dict()
        seen = {i.index for i in self.done_items}
        rest = [i for i in (self.eye.items if self.eye else []) if i.index not in seen]
        return sorted(self.done_items + rest, key=lambda i: i.index)
