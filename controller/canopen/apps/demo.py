"""The demo's pick and place on the softMC conveyor model (:mod:`controller.conveyor`).

One setpoint source (:class:`PickPlace`, a pure
:class:`~controller.canopen.master.source.SetpointSource`: the cycle hands it a frozen
context, it returns the setpoint, its typed status and its events) runs a
:class:`~controller.conveyor.RobotGroup` ``robot`` on a linear
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
  robot places are missed (30238) when the robot takes them from the buffer; an item the
  robot's link leaves on a tracker error (the master over the frame's VelocityMax /
  AccelerationMax) while it approaches or follows it is missed, and the sequence goes on;
- output: the robot group's setpoint (world TCP; angle about z) is the master of the
  source's own pass-through :class:`~controller.tracking.Tracker`, engaged once (absolute) at
  the start and SYNCED from then on, so it passes the setpoint through unchanged to the kinematics and
  counts (its master limits are lifted: the robot group limits its own motions with the
  tracker's sync limits).  ``imfs`` (the cycle record, status line, telemetry, PLC 2001h) is
  the robot group's.  Per-item figures come from the robot's ``ItemRecord`` (engaged and
  synchronised samples, peak errors, status): ``Item.model`` in telemetry.jsonl;
- a PLC's commands come in the context: an engage 0 (:class:`~controller.canopen.master.source.Engage`) de-syncs
  the robot (the item being approached or followed is missed), 3/5 are ignored (the sequence
  engages); a :class:`~controller.canopen.master.source.Trigger` is a photo-eye edge; a lost master
  (:class:`~controller.canopen.master.source.MasterEvent`) misses the item being followed.

The simulated side (:class:`PhotoEye`) knows the true belt travel (the encoder's speed
profile) and the items' belt positions (seeded pitch, lateral offset and angle), and turns
them into edge times.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum, StrEnum
from typing import TYPE_CHECKING

from ...conveyor import (
    ITEM_MISSED_CODE,
    EventKind,
    Location,
    MovingFrame,
    RobotGroup,
    Window,
    q_axis_angle,
)
from ...conveyor.location import q_to_axis_angle, vec3
from ...conveyor.sources import SourceState
from ...limits import CartesianLimits, Limits
from ...tracking import Imfs, Mode, MotionState, Tracker, TrackState
from ...tracking.types import motion_state
from ...tracking.values import attributes, mypyc_attr, restore
from ...errors import StateError
from ..config.demo import DemoConfig
from ..config.plc import TriggerOverflow
from ..master.events import EventKind as MasterEventKind
from ..master.source import (
    CycleContext,
    Engage,
    MasterEvent,
    SourceEvent,
    SourceOutput,
    SourceStart,
    SourceStatus,
    TrackTypes,
)
from .follow import desync_on_master_loss

#: a named tuple from all its fields in order, without the named tuple's own __new__
_new_tuple = tuple.__new__

if TYPE_CHECKING:
    from ..config.tracking import TrackingConfig
    from ..slave.encoder import SpeedProfile


class Step(Enum):
    WAIT = "wait"
    APPROACH = "approach"
    FOLLOW = "follow"
    PLACE = "place"


#: the per-cycle tests' enum members as module globals (an Enum member read from its class
#: costs some 45 ns more than a global; the step reads several each cycle)
_WAIT, _APPROACH, _FOLLOW, _PLACE = Step.WAIT, Step.APPROACH, Step.FOLLOW, Step.PLACE
_SYNCHRONIZED = Imfs.SYNCHRONIZED
_TRACK_OFF = TrackState.OFF
_MASTER_LOSS = (MasterEvent.SILENT, MasterEvent.LOST)

class Outcome(StrEnum):
    """What became of an item (its value is what the summary and telemetry print)."""

    PENDING = "pending"
    PLACED = "placed"
    MISSED = "missed"
    #: its type is not tracked (2015h / ``.tracking.items.track_types``) or the robot refused it
    IGNORED = "ignored"
    #: pushed out of a full trigger buffer
    DROPPED = "dropped"


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: a source's deepcopy)
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
    outcome: Outcome = Outcome.PENDING
    reason: str = ""
    max_error_mm: float = 0.0
    u_pick: float | None = None
    entry_id: int | None = None  # its TRIGGER entry in the robot's buffer
    item_type: int = 0  # its class (.demo.item_types; .tracking.items.track_types)
    model: dict = field(default_factory=dict)  # the conveyor model's ItemRecord.as_dict()

    def __getstate__(self) -> dict:
        return attributes(self)

    def __setstate__(self, state: dict) -> None:
        restore(self, state)


#: what :meth:`PhotoEye.edges_until` returns when no edge is due (nearly every cycle)
_NO_ITEMS: tuple[Item, ...] = ()


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: a source's deepcopy)
class PhotoEye:
    """Simulated photo-eye: item edges from the true belt travel (the encoder's profile).

    Items are made one at a time, when the previous one has been reported (``demo.items``
    may be 10**30: nothing is built up front); the edge time of the next item is the time the
    belt has travelled its pitch further (bisection on the exact travel).  A belt that never
    gets there (it stops or runs backwards for good) simply brings no more items."""

    #: how far ahead the search for the belt reaching an item looks [s of machine time]
    HORIZON_S = 1e6

    def __init__(self, profile: SpeedProfile, demo: DemoConfig, start_s: float) -> None:
        self._rng = random.Random(demo.seed)
        self._profile = profile
        self._demo = demo
        self._travel = profile.travel(start_s + demo.first_item_s)
        self._t_lo = start_s
        self.made = 0  # items of the belt made so far
        self._made_next: Item | None = None
        #: items of the PLC's trigger input not reported yet (2004h of the controller node)
        self._extra: deque[Item] = deque()
        self._count = 0  # index of the next item (belt and PLC items share the numbering)
        self._detected = 0
        self._make_next()

    def __getstate__(self) -> dict:
        return attributes(self)

    def __setstate__(self, state: dict) -> None:
        restore(self, state)

    @property
    def total(self) -> int:
        """Items the photo-eye will see from the belt (``demo.items``)."""
        return self._demo.items

    @property
    def exhausted(self) -> bool:
        """No more items will come (all made and reported, or the belt never gets there)."""
        return self._made_next is None and not self._extra

    def _make_next(self) -> None:
        """The next belt item (its edge time), or None when there is none."""
        self._made_next = None
        if self.made >= self._demo.items:
            return
        t = self._time_at(self._travel)
        if t is None:
            return
        types = self._demo.item_types
        item = Item(self._count, round(t * 1e9), self._rng.uniform(*self._demo.lateral),
                    self._rng.uniform(*self._demo.angle),
                    item_type=types[self.made % len(types)] if types else 0)
        self._count += 1
        self.made += 1
        self._t_lo = t
        self._travel += self._rng.uniform(*self._demo.pitch_mm)
        self._made_next = item

    def _time_at(self, travel: float) -> float | None:
        profile = self._profile
        lo = self._t_lo
        hi = lo + 1.0
        while profile.travel(hi) < travel:
            lo, hi = hi, hi + 2 * (hi - lo)
            if hi - self._t_lo > self.HORIZON_S:
                return None
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
        return self._detected

    def trigger(self, t_edge_ns: int, lateral: float = 0.0, angle: float = 0.0,
                item_type: int = 0) -> Item:
        """An edge reported from outside (the PLC's trigger input, 2004h of the controller
        node, with the type in 2014h): a new item of ``item_type`` at the photo-eye at
        ``t_edge_ns``, on the belt's centre line."""
        item = Item(self._count, int(t_edge_ns), lateral, angle, item_type=item_type)
        self._count += 1
        self._extra.append(item)
        return item

    def edges_until(self, t_ns: int) -> Sequence[Item]:
        """The items whose edge is at or before ``t_ns``, in edge order."""
        nxt = self._made_next
        if not self._extra and (nxt is None or nxt.t_edge_ns > t_ns):
            return _NO_ITEMS  # (no edge due: nearly every cycle, no list made)
        out = []
        while True:
            nxt = self._made_next
            extra = self._extra[0] if self._extra else None
            if extra is not None and extra.t_edge_ns <= t_ns and (
                    nxt is None or extra.t_edge_ns <= nxt.t_edge_ns):
                out.append(self._extra.popleft())
            elif nxt is not None and nxt.t_edge_ns <= t_ns:
                out.append(nxt)
                self._make_next()
            else:
                break
        self._detected += len(out)
        return out


@mypyc_attr(allow_interpreted_subclasses=True)
@dataclass
class PickPlace:
    """The demo sequence on the conveyor model (see the module docstring)."""

    demo: DemoConfig
    eye: PhotoEye | None = None
    #: where the sequence is (:class:`Step`)
    stage: Step = Step.WAIT
    #: the last ``history`` finished items (placed or missed), oldest first; the counts of
    #: all of them are ``placed`` / ``missed`` (a run of weeks keeps O(1) items)
    done_items: deque[Item] = field(default_factory=deque)
    current: Item | None = None
    frame: MovingFrame | None = None
    robot: RobotGroup | None = None
    #: the robot group's IMFS at each change (0, 1, -1, 0, ...), the last 1000 changes
    imfs_log: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    #: finished items (and conveyor-model item records) kept for the summary and telemetry
    history: int = 1000
    #: called with each item when it is finished (streaming telemetry)
    on_item: Callable[[Item], None] | None = None
    placed: int = 0
    missed: int = 0
    #: items of a type the robot does not track (.tracking.items.track_types)
    ignored: int = 0
    _by_entry: dict = field(default_factory=dict)
    #: a full trigger buffer drops the newest trigger or the oldest waiting item
    trigger_overflow: TriggerOverflow = TriggerOverflow.DROP_NEWEST
    #: items dropped because the trigger buffer was full
    triggers_dropped: int = 0
    _until: int = 0
    _end_cycle: int | None = None
    _drops_unreported: int = 0
    _drop_reported: float | None = None
    #: the pass-through tracker whose setpoint goes out (made at the start)
    tracker: Tracker | None = None
    _tc: TrackingConfig | None = None
    _T: float = 0.0
    _prev: MotionState | None = None
    _events: list[SourceEvent] = field(default_factory=list)
    #: the robot group's IMFS after its update in this step
    _robot_imfs: Imfs = Imfs.NOT_SYNCHRONIZED

    def __getstate__(self) -> dict:
        return attributes(self)

    def __setstate__(self, state: dict) -> None:
        restore(self, state)

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
                    return link.tracker.state
        return TrackState.OFF

    def start(self, start: SourceStart) -> SourceStatus:
        if self.eye is None:
            raise ValueError("PickPlace needs a photo-eye")
        tc = self._tc = start.tracking
        T = self._T = start.period_s
        self._end_cycle = start.cycle + int(self.demo.duration_s / T)
        conv = tc.conveyor
        o, d = conv.origin, conv.direction
        pe = self.demo.photo_eye
        w0, w1 = tc.window
        self.frame = MovingFrame(
            "belt", directions=[d],
            origin=Location.at(*(o[i] + d[i] * pe + (self.demo.pick_height if i == 2 else 0.0)
                                 for i in range(3))),
            window=Window.single(w0 - pe, w1 - pe))
        tp = tc.tracker
        sp = start.pose
        # TrackerParams fills the sync limits in (from the robot's maxima or the defaults)
        assert tp.sync_trans is not None and tp.sync_rot is not None
        self.robot = RobotGroup("robot", replace(tp, sample_time_s=T),
                                start=Location.from_axis_angle(sp.pos, (0.0, 0.0, 1.0), sp.ang),
                                motion_limits=CartesianLimits(tp.sync_trans, tp.sync_rot))
        if tc.track_types is not None:
            self.robot.track_types(self.frame, tc.track_types)
        self._prev = sp
        # the pass-through tracker (SYNCED, absolute) whose setpoint goes out: the robot
        # group limits its own motions, so the master limits are the robot's
        big = Limits(1e9, 1e9, 1e9)
        self.tracker = Tracker(replace(tp, master_max_trans=big, master_max_rot=big), sp)
        self.tracker.engage(Mode.ABSOLUTE)
        return self.status()

    def _across(self) -> tuple[float, float, float]:
        d = self._config().conveyor.direction
        n = math.hypot(d[0], d[1])
        return (-d[1] / n, d[0] / n, 0.0) if n > 1e-9 else (0.0, 1.0, 0.0)

    def _config(self) -> TrackingConfig:
        if self._tc is None:
            raise StateError("the conveyor demo is not started (start() reads .tracking)")
        return self._tc

    def _finish_item(self, item: Item, outcome: Outcome, reason: str = "") -> None:
        if item.outcome is not Outcome.PENDING:
            return
        item.outcome = outcome
        item.reason = reason
        if outcome is Outcome.PLACED:
            self.placed += 1
        elif outcome is Outcome.IGNORED:
            self.ignored += 1
        else:
            self.missed += 1
        self.done_items.append(item)
        if item is self.current:
            self.current = None
        r = self.robot
        if r is not None and item.entry_id is not None:
            rec = r.records.get(item.entry_id)
            if rec is not None:
                item.model = rec.as_dict()
        # bounded: the oldest finished items, their entries and model records go
        while len(self.done_items) > self.history:
            old = self.done_items.popleft()
            if old.entry_id is not None:
                self._by_entry.pop(old.entry_id, None)
                if r is not None:
                    r.records.pop(old.entry_id, None)
        if self.on_item is not None:
            self.on_item(item)

    @property
    def finished(self) -> int:
        """Items placed, missed or ignored so far."""
        return self.placed + self.missed + self.ignored

    def _cell(self) -> tuple[RobotGroup, MovingFrame]:
        """The robot group and its moving frame (made by ``setup``)."""
        if self.robot is None or self.frame is None:
            raise StateError("the conveyor demo is not set up (setup() makes its robot)")
        return self.robot, self.frame

    def step(self, ctx: CycleContext) -> SourceOutput:
        """One cycle of the sequence (see the module docstring): the PLC's commands, a lost
        master, the photo-eye's edges, the sequence, the robot group; its setpoint through the
        pass-through tracker."""
        r, f = self.robot, self.frame
        if r is None or f is None:
            r, f = self._cell()  # (raises: not set up)
        tracker = self.tracker
        assert tracker is not None
        if self._events:  # (the last step's; an empty list is kept: no list per cycle)
            self._events = []
        for cmd in ctx.commands:
            if isinstance(cmd, Engage):
                self._engage(cmd.mode)
            elif isinstance(cmd, TrackTypes):
                self._track_types(cmd.types)
            elif self.eye is not None:
                self.eye.trigger(cmd.t_ns, item_type=cmd.item_type)
        if ctx.master.event in _MASTER_LOSS:
            desync_on_master_loss(tracker, ctx.master.event)
            self._master_lost()
        m = self._update(ctx, r, f)
        out = tracker.update(m)
        # (every field in order: the named tuple made without its __new__)
        return _new_tuple(SourceOutput, (out.setpoint, self.status(self._robot_imfs),
                                         tracker.target(m),
                                         tuple(self._events) if self._events else (),
                                         None, self._done(ctx.cycle), None))

    def _update(self, ctx: CycleContext, r: RobotGroup, f: MovingFrame) -> MotionState:
        T = self._T
        cycle = ctx.cycle
        master = ctx.master
        belt = master.estimate
        master_ready = master.ready
        t_now = ctx.t_ns
        f.set_master([SourceState(belt.pos, belt.vel, belt.acc)], r.k)
        eye = self.eye
        assert eye is not None  # (start() refuses to run without one)
        for item in eye.edges_until(t_now):
            s_meas = master.belt_mm if master.belt_mm is not None else belt.pos
            item.s_item = s_meas - belt.vel * (t_now - item.t_edge_ns) * 1e-9
            item.trigger_cycle = cycle
            if r.buffer.full and not self._make_room(ctx, item):
                continue
            e = r.trigger(f, values=[item.s_item], item_type=item.item_type)
            item.entry_id = e.id
            self._by_entry[e.id] = item
            types = r.tracked_types(f)
            if types is not None and item.item_type not in types:
                self._finish_item(item, Outcome.IGNORED, f"type {item.item_type} not tracked")
        step = self.stage
        if step is _WAIT:
            entry = r.buffer.current(f.name, r.tracked_types(f))
            while entry is not None and (entry.id not in self._by_entry
                                         or self._by_entry[entry.id].outcome is not Outcome.PENDING):
                r.nextitem(f)  # (an item de-synced by STOP stays in the buffer: drop it)
                entry = r.buffer.current(f.name, r.tracked_types(f))
            if entry is not None and not r.links and master_ready:
                item = self._by_entry[entry.id]
                self.current = item
                r.set_master_frame(f, Mode.RELATIVE)
                n = self._across()
                z = f.zero(entry).pos
                r.moves(Location((z[0] + n[0] * item.lateral, z[1] + n[1] * item.lateral,
                                  z[2]), q_axis_angle((0.0, 0.0, 1.0), item.angle)),
                        name=f"approach item {item.index}")
                self.stage = Step.APPROACH
        elif step is _APPROACH:
            if r.imfs == _SYNCHRONIZED and not r.virtual.busy:
                self._until = cycle + round(self.demo.pick_dwell_s / T)
                self.stage = Step.FOLLOW
        elif step is _FOLLOW:
            cur = self.current
            assert cur is not None  # (FOLLOW follows its item)
            error = ctx.tracking_error_mm
            if error > cur.max_error_mm:  # (max() written out)
                cur.max_error_mm = error
            if cycle >= self._until:
                cur.picked_cycle = cycle
                s_item = cur.s_item
                assert s_item is not None  # (set when its trigger went in)
                cur.u_pick = self.demo.photo_eye + belt.pos - s_item
                r.nextitem(f)
                r.master_frame = None
                p = self.demo.place_position
                r.moves(Location(vec3(p), q_axis_angle((0.0, 0.0, 1.0), self.demo.place_angle)),
                        name="place")
                self.stage = Step.PLACE
        elif step is _PLACE:
            cur = self.current
            assert cur is not None  # (PLACE places the item picked)
            if not r.virtual.busy and not r.links:
                if cur.placed_cycle is None:
                    cur.placed_cycle = cycle
                if (cycle - cur.placed_cycle) * T >= self.demo.place_dwell_s:
                    self._finish_item(cur, Outcome.PLACED)
                    self.stage = Step.WAIT
        tracker = self.tracker
        if tracker is not None and tracker.state is _TRACK_OFF and master_ready:
            tracker.engage(Mode.ABSOLUTE)  # (de-synced by a silent encoder: follow again)
        out = r.update()
        self._robot_imfs = out.imfs  # (the status of this step: nothing below changes it)
        imfs = int(out.imfs)
        if not self.imfs_log or self.imfs_log[-1] != imfs:
            self.imfs_log.append(imfs)
        for ev in out.events:
            ev_item = self._by_entry.get(ev.item) if ev.item is not None else None
            if ev_item is not None and ev.kind == EventKind.ENGAGED and ev_item.outcome is Outcome.PENDING:
                ev_item.engage_cycle = cycle
                ev_item.synced_cycle = None
            elif ev_item is not None and ev.kind == EventKind.SYNCHRONIZED \
                    and ev_item.synced_cycle is None:
                ev_item.synced_cycle = cycle
            if ev.kind == EventKind.ITEM_IGNORED and ev_item is not None:
                self._finish_item(ev_item, Outcome.IGNORED, ev.message)
            if ev.kind == EventKind.ITEM_MISSED and ev.item in self._by_entry:
                item = self._by_entry[ev.item]
                self._finish_item(item, Outcome.MISSED, f"left the window ({ev.code})")
                if self.stage in (Step.APPROACH, Step.FOLLOW):
                    self.stage = Step.WAIT
                self._events.append(SourceEvent(
                    "demo", MasterEventKind.ITEM_MISSED,
                    f"item {item.index} missed ({ITEM_MISSED_CODE}): {ev.message}", level=20))
            elif ev.kind == EventKind.TRACKER_ERROR and ev_item is not None:
                self._left_on_error(ev_item, ev.message)
        loc = out.setpoint
        axis, ang = q_to_axis_angle(loc.ori)
        if axis[2] < 0:
            ang = -ang
        prev = self._prev
        assert prev is not None  # (set by start)
        vel = out.velocity  # (a 3-tuple already: the robot group's)
        v0, v1, v2 = vel
        u0, u1, u2 = prev.vel
        acc = ((v0 - u0) / T, (v1 - u1) / T, (v2 - u2) / T)
        ang_vel = (ang - prev.ang) / T
        # (MotionState without its __post_init__: every vector here is a tuple of Python
        #  floats already -- the compiled robot group's, or computed from them -- which the
        #  check would keep as given)
        m = motion_state(vec3(loc.pos), vel, acc, ang, ang_vel, (ang_vel - prev.ang_vel) / T)
        self._prev = m
        return m

    def _left_on_error(self, item: Item, error: str) -> None:
        """The robot's link left ``item`` on a tracker error (a master over the frame's
        VelocityMax / AccelerationMax, ...): being approached or followed, it will never be
        synchronised again, so it is missed and the sequence goes on (else it waited for it
        for ever)."""
        if item is not self.current or self.stage not in (Step.APPROACH, Step.FOLLOW):
            return
        self._finish_item(item, Outcome.MISSED, f"tracker error {error}")
        self.stage = Step.WAIT
        self._events.append(SourceEvent(
            "demo", MasterEventKind.ITEM_MISSED,
            f"item {item.index} missed: the robot left it (tracker error {error})", level=20))

    def _make_room(self, ctx: CycleContext, item: Item) -> bool:
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
        self._finish_item(victim, Outcome.DROPPED, f"trigger buffer full ({r.buffer.capacity} "
                          f"entries, {self.trigger_overflow.value})")
        self.triggers_dropped += 1
        self._drops_unreported += 1
        t_s = ctx.t_s
        if self._drop_reported is None or t_s - self._drop_reported >= 1.0:
            n, self._drops_unreported = self._drops_unreported, 0
            self._drop_reported = t_s
            self._events.append(SourceEvent(
                "demo", MasterEventKind.TRIGGER_DROPPED,
                f"trigger buffer of robot {r.name!r} full "
                f"({r.buffer.capacity} entries): item {victim.index} dropped"
                + (f" ({n} dropped since the last report)" if n > 1 else ""),
                f"{self.trigger_overflow.value} (the run goes on)"))
        return victim is not item

    def _engage(self, mode: Mode) -> None:
        """The PLC's 2005h: 0 de-syncs the robot from the belt (``STOP``: the item being
        approached or followed is missed); 3/5 are the program's to give (ignored)."""
        if mode == Mode.OFF and self.robot is not None:
            if self.current is not None and self.stage in (Step.APPROACH, Step.FOLLOW):
                self._finish_item(self.current, Outcome.MISSED, "disengaged by the PLC")
                self.stage = Step.WAIT
            self.robot.stop()

    def _track_types(self, types: frozenset[int] | None) -> None:
        """A PLC's tracked item types (2015h): the robot tracks only ``types`` on the belt
        from this update (None: every type); the waiting items of other types are ignored
        now, the one being approached or followed is still picked."""
        if self.robot is not None and self.frame is not None:
            self.robot.track_types(self.frame, types)
        if types is not None:
            for item in list(self._by_entry.values()):
                if item.outcome is Outcome.PENDING and item is not self.current \
                        and item.item_type not in types:
                    self._finish_item(item, Outcome.IGNORED, f"type {item.item_type} not tracked")

    def status(self, imfs: Imfs | None = None) -> SourceStatus:
        """The robot group's tracking, the pass-through tracker's, the photo-eye's count, the
        items missed and ignored.  ``imfs``: the robot group's IMFS when the caller has it
        (its last update's, in :meth:`step`), else it is asked."""
        tr = self.tracker
        detected = self.eye.detected if self.eye is not None else None
        if self.robot is None or tr is None:
            return SourceStatus(items_detected=detected, items_missed=self.missed,
                                triggers_dropped=self.triggers_dropped,
                                items_ignored=self.ignored)
        return _new_tuple(SourceStatus, (self.track_state,
                                         self.robot.imfs if imfs is None else imfs,
                                         tr.state, tr.imfs, tr.error, detected, self.missed,
                                         self.triggers_dropped, self.ignored))

    def _master_lost(self) -> None:
        if self.current is not None and self.stage in (Step.APPROACH, Step.FOLLOW):
            self._finish_item(self.current, Outcome.MISSED, "encoder silent")
            self._cell()[0].stop()
            self.stage = Step.WAIT

    def _done(self, cycle: int) -> bool:
        if self._end_cycle is not None and cycle >= self._end_cycle:
            return True
        all_seen = self.eye is not None and self.eye.exhausted \
            and self.finished == self.eye.detected
        if not (all_seen and self.stage == Step.WAIT):
            return False
        r = self._cell()[0]
        return not r.links and not r.virtual.busy

    def items(self) -> list[Item]:
        """The last ``history`` finished items and the pending ones the photo-eye reported,
        by index, with the conveyor model's telemetry in ``Item.model``."""
        if self.robot is not None:
            for it in self._by_entry.values():
                rec = self.robot.records.get(it.entry_id)
                if rec is not None:
                    it.model = rec.as_dict()
        seen = {i.index for i in self.done_items}
        rest = [i for i in self._by_entry.values() if i.index not in seen]
        return sorted(list(self.done_items) + rest, key=lambda i: i.index)
