"""The controller itself as a CANopen node (eds/cantrack-controller.eds) that a PLC commands.

:class:`PlcNode` is a :class:`~.engine.SlaveEngine` on the controller's transport (no second
bus, no thread): SDO server (expedited and segmented: 1008h-100Ah), TPDOs, RPDO1-2, NMT slave,
heartbeat consumer of the commander.  It knows the controller only as a :class:`PlcHost`
(``master.plc_node`` binds it to a running controller).  The controller's cycle drives it
(:meth:`PlcNode.cycle`): once per cycle the node takes the cycle's :class:`PlcStatus` into
2000h-2008h, 2011h-2013h and 2016h, runs its timers (event TPDOs, the commander's heartbeat) and
its SYNC (the controller's own: TPDO types 0-240).

The commanding-node contract (docs/plc.md).  The motion-relevant objects -- 2004h trigger,
2005h engage, 2010h sync limits, 2014h trigger item type, 2015h tracked item types -- are
written, by SDO or RPDO, only

1. in NMT OPERATIONAL (the node enters it when the controller's cycle starts; a PLC may
   stop it or put it in PRE-OPERATIONAL with NMT): else SDO abort 08000022h;
2. while the configured commander's heartbeat is present (``.plc.commander``, consumed with
   ``commander_heartbeat_ms`` in 1016h:1; present from its first heartbeat until one is
   overdue): else 08000021h ("local control": the node is not under its commander's
   control); without a ``.plc`` section no node is the commander and every motion write is
   refused so;
3. within ``command_window_us`` after the controller's SYNC when that is set (like 1007h):
   else 08000022h.

A refused SDO write is answered with that abort code; a refused RPDO value is dropped (a PDO
cannot be answered).  Both are counted in 2012h and reported as an event (at most one per
second per reason, with the count).  The loss of the commander's heartbeat has the
configured reaction (``on_commander_lost``: continue, de-sync on the path, quick stop),
reported as an event, like a CiA 402 drive's 6007h.

COB-ID writes (1400h:1, 1800h:1) are checked by the engine as CANopenNode does (06090030h)
and here against the bus (08000000h): the SYNC and TIME IDs, every EMCY ID (081h-0FFh), the
default PDO IDs of the bus's nodes (except the commander's PDOs pointed our way: its TPDOs
for our RPDOs, its RPDOs for our TPDOs), the configured PDOs of the slaves, and the node's
other PDOs.

Item types (docs/spec/conveyor-extensions.md#3): each trigger edge gives its item the type
in 2014h at that moment (RPDO2 carries 2014h and 2004h: the type applies to the edge of the
same frame, whatever the order of the mapping); 2015h:1-8 is the set of tracked types as
256 bits (bit b of sub s: type 32 (s - 1) + b), loaded from ``.tracking.items.track_types``
at the start; a write changes the setpoint source's set in the next cycle (all bits set:
every type).

Trigger edges (2004h bit 0 rising) are bounded: at most ``trigger_rate_max`` per second
(over the last second); more are dropped, counted in 2013h and reported.  A full trigger
buffer in the application drops by ``trigger_overflow`` (the application counts those,
they are added to 2013h); the controller never stops for a trigger.

Other refusals: 08000020h for the objects the bus configuration owns (1005h, 1006h, 1014h,
1015h, 1016h, 1017h, 1019h, 1003h:0) and for 2010h (the sync limits are the configuration's:
readable, not changed at run time); 06090030h for 2005h not 0/3/5 and 2004h > 1; 08000022h
for an engage before tracking runs and for 2010h while the tracker is not OFF.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from ...limits import Limits
from ...resources import data_path
from ...tracking import Mode, TrackState
from ..config.plc import CommanderLoss, PlcConfig, TriggerOverflow
from ..protocol.sdo import (
    ABORT_DEVICE_STATE,
    ABORT_STORE,
    ABORT_VALUE_RANGE,
    SdoAbortError,
)
from .engine import ABORT_LOCAL_CONTROL, Nmt, SlaveBus, SlaveEngine

EDS = data_path("eds", "cantrack-controller.eds")

#: objects whose writes command motion (the contract applies)
MOTION_OBJECTS = frozenset({0x2004, 0x2005, 0x2010, 0x2014, 0x2015})
#: communication objects a PLC may not write (the bus configuration sets them)
CONFIG_OWNED = frozenset({0x1005, 0x1006, 0x1014, 0x1015, 0x1016, 0x1017, 0x1019})
ENGAGE_VALUES = (int(Mode.OFF), int(Mode.ABSOLUTE), int(Mode.RELATIVE))
#: the entries a :class:`PlcNode` history keeps (trigger times and types, engage commands,
#: refusals): the newest, the oldest dropped
HISTORY = 1000
#: item types 0...ITEM_TYPES - 1, 32 per sub-index of 2015h (sub 1...8)
ITEM_TYPES = 256
_TYPE_SUBS = range(1, ITEM_TYPES // 32 + 1)


def type_bits(types: frozenset[int] | None) -> tuple[int, ...]:
    """2015h:1-8 of a set of item types (None: every type, all bits set)."""
    if types is None:
        return tuple(0xFFFFFFFF for _ in _TYPE_SUBS)
    return tuple(sum(1 << (t - 32 * (s - 1)) for t in types if 32 * (s - 1) <= t < 32 * s)
                 for s in _TYPE_SUBS)


def bits_types(bits: tuple[int, ...]) -> frozenset[int] | None:
    """The item types of 2015h:1-8 (None: every type, all bits set)."""
    if all(b == 0xFFFFFFFF for b in bits):
        return None
    return frozenset(32 * i + b for i, word in enumerate(bits) for b in range(32)
                     if word >> b & 1)

#: 2011h command access bits
ACCESS_OPERATIONAL = 0x01
ACCESS_COMMANDER = 0x02
ACCESS_WINDOW = 0x04


@dataclass(frozen=True, slots=True)
class PlcStatus:
    """What the controller publishes through the node each cycle (2000h-2008h, 2013h)."""

    state: TrackState
    imfs: int
    error: int
    items: int  # items detected since start-up (PLC triggers included)
    missed: int  # items that left the window untracked
    tracking_error_mm: float  # |actual - target| over x, y, z at this cycle's SYNC
    belt_vel_mm_s: float
    triggers_dropped: int = 0  # by the application's full trigger buffer
    items_ignored: int = 0  # items of a type that is not tracked (2016h)


class PlcHost(Protocol):
    """What the node needs of the controller (``master.plc_node`` provides it)."""

    def tracking(self) -> bool:
        """Tracking runs (an engage can act)."""

    def track_state(self) -> TrackState:
        """The state of the belt tracking now."""

    def engage(self, mode: Mode) -> None:
        """2005h: 0 de-sync on the path, 3/5 engage."""

    def trigger(self, t_ns: int, item_type: int) -> None:
        """An item trigger edge received at ``t_ns`` (controller time) for an item of
        ``item_type`` (0...255, 2014h)."""

    def track_types(self) -> frozenset[int] | None:
        """The item types tracked at the start (None: every type; 2015h)."""

    def set_track_types(self, types: frozenset[int] | None) -> None:
        """2015h written: track only items of ``types`` from now on (None: every type)."""

    def quick_stop(self, kind: str, detail: str) -> None:
        """Stop all drives (the reaction ``stop``)."""

    def event(self, kind: str, detail: str, reaction: str, level: int) -> None:
        """Report an event in the controller's log."""

    def nmt(self, state: int) -> None:
        """The node's NMT state changed (the controller's heartbeat sends it)."""


@dataclass(frozen=True, slots=True)
class Refusal:
    """Why a motion command is not accepted now (SDO abort code and the reason)."""

    code: int
    reason: str
    kind: str  # event kind: plc_not_operational, plc_no_commander, plc_outside_window


class TriggerRate:
    """At most ``max_per_s`` accepted edges within any 1 s (a sliding window) [ns times]."""

    def __init__(self, max_per_s: float) -> None:
        self.max = max(1, math.floor(max_per_s))
        self._times: deque[int] = deque()

    def accept(self, t_ns: int) -> bool:
        times = self._times
        while times and t_ns - times[0] >= 1_000_000_000:
            times.popleft()
        if len(times) >= self.max:
            return False
        times.append(t_ns)
        return True


class _Throttle:
    """Report an event at once, then at most once per second with the count meanwhile."""

    def __init__(self) -> None:
        self._last: dict[str, int] = {}
        self._pending: dict[str, int] = {}

    def due(self, kind: str, now: int) -> int | None:
        """None: not now (counted); else how many happened since the last report."""
        n = self._pending.get(kind, 0) + 1
        last = self._last.get(kind)
        if last is not None and now - last < 1_000_000_000:
            self._pending[kind] = n
            return None
        self._last[kind] = now
        self._pending[kind] = 0
        return n


class PlcNode(SlaveEngine):
    """The controller's own node (see the module docstring).

    ``host``: the controller side (:class:`PlcHost`); ``bus``: the controller's transport;
    ``reserved``: COB-ID -> (what uses it on the bus, the kind of our PDO that may use it
    anyway), from :func:`reserved_cob_ids`; the master values are the bus configuration's.
    The host calls :meth:`cycle` once per controller cycle.
    """

    kind = "controller"

    def __init__(self, host: PlcHost, bus: SlaveBus, node_id: int, *, sync_period_us: int,
                 sync_overflow: int, heartbeat_ms: int, sync_limits: Limits,
                 config: PlcConfig | None = None,
                 reserved: Mapping[int, tuple[str, str | None]] | None = None,
                 eds: str | Path = EDS, version: str = "") -> None:
        self.host = host
        self.config = config if config is not None else PlcConfig()
        super().__init__("controller", eds, node_id, bus, heartbeat_producer=False,
                         sync_cob_id=None)
        # (the node runs as long as the controller: its histories keep the last HISTORY
        #  entries, the counts count all - issue 12: O(1) memory in long runs)
        self.refused = 0  # refused motion writes (SDO and RPDO)
        self.triggers = 0  # accepted trigger edges
        self.triggers_dropped = 0  # by the rate limit
        #: the time [ns] and the item type (2014h) of the last HISTORY accepted edges
        self.trigger_times: deque[int] = deque(maxlen=HISTORY)
        self.trigger_types: deque[int] = deque(maxlen=HISTORY)
        #: the last HISTORY engage commands applied: (t_ns, value)
        self.commands: deque[tuple[int, int]] = deque(maxlen=HISTORY)
        #: the last HISTORY refused writes: (index, sub, SDO abort code)
        self.refusals: deque[tuple[int, int, int]] = deque(maxlen=HISTORY)
        self._throttle = _Throttle()
        self._rate = TriggerRate(self.config.trigger_rate_max)
        self._rpdo_engage = 0
        self._sync_ns: int | None = None
        self._started = False
        self._reserved = dict(reserved or {})
        self.boot_now(send_boot_up=False)
        self._configure(sync_period_us, sync_overflow, heartbeat_ms, sync_limits, version)

    # -- configuration ------------------------------------------------------------------
    def _configure(self, period_us: int, overflow: int, heartbeat_ms: int,
                   limits: Limits, version: str) -> None:
        self.store(0x1006, 0, int(period_us))
        self.store(0x1019, 0, int(overflow))
        self.store(0x1017, 0, int(heartbeat_ms))
        c = self.config
        if c.commander is not None:
            self.store(0x1016, 1, (c.commander << 16) | c.commander_heartbeat_ms)
            self._load_consumers()
        settings: tuple[tuple[int, int], ...] = (
            (1, c.commander or 0), (2, list(CommanderLoss).index(c.on_commander_lost)),
            (3, c.command_window_us), (4, int(c.trigger_rate_max)),
            (5, list(TriggerOverflow).index(c.trigger_overflow)))
        for sub, setting in settings:
            self.store(0x2020, sub, setting)
        for sub, value in zip((1, 2, 3), (limits.vel, limits.acc, limits.jerk)):
            self.store(0x2010, sub, float(value))
        for sub, word in zip(_TYPE_SUBS, type_bits(self.host.track_types())):
            self.store(0x2015, sub, word)
        if version:
            self.store(0x100A, 0, version)
        self._changed.clear()

    # -- the contract ----------------------------------------------------------------------
    def command_access(self) -> int:
        """2011h: bit 0 NMT OPERATIONAL, bit 1 commander present, bit 2 in the window."""
        bits = 0
        if self.nmt_state is Nmt.OPERATIONAL:
            bits |= ACCESS_OPERATIONAL
        c = self.config.commander
        if c is not None and self.heartbeat_present(c):
            bits |= ACCESS_COMMANDER
        if self._in_window():
            bits |= ACCESS_WINDOW
        return bits

    def _in_window(self) -> bool:
        w = self.config.command_window_us
        if not w:
            return True
        if self._sync_ns is None:
            return False
        return self.clock.now_ns() - self._sync_ns <= w * 1000

    def refusal(self) -> Refusal | None:
        """Why a motion command would be refused now (None: accepted)."""
        if self.nmt_state is not Nmt.OPERATIONAL:
            return Refusal(ABORT_DEVICE_STATE, f"NMT state {self.nmt_state.name}, not "
                           "OPERATIONAL", "plc_not_operational")
        c = self.config.commander
        if c is None:
            return Refusal(ABORT_LOCAL_CONTROL, "no commander configured (.plc.commander)",
                           "plc_no_commander")
        if not self.heartbeat_present(c):
            return Refusal(ABORT_LOCAL_CONTROL, f"the commander's heartbeat (node {c}, "
                           f"{self.config.commander_heartbeat_ms} ms) is not present",
                           "plc_no_commander")
        if not self._in_window():
            return Refusal(ABORT_DEVICE_STATE, f"outside the command window "
                           f"({self.config.command_window_us} us after the SYNC)",
                           "plc_outside_window")
        return None

    def _refuse(self, index: int, sub: int, r: Refusal, via: str) -> None:
        self.refused += 1
        self.refusals.append((index, sub, r.code))
        self.store(0x2012, 0, self.refused & 0xFFFFFFFF)
        n = self._throttle.due(r.kind, self.clock.now_ns())
        if n is not None:
            more = f" ({n} refused since the last report)" if n > 1 else ""
            self.host.event(r.kind, f"{via} write {index:04X}h:{sub:02X}: {r.reason}{more}",
                            f"refused (SDO abort {r.code:08X}h)" if via == "SDO"
                            else "ignored (PDO)", 30)

    # -- engine hooks ------------------------------------------------------------------------
    def check_access(self, index: int, sub: int) -> None:
        if index in CONFIG_OWNED or (index == 0x1003 and sub == 0):
            raise SdoAbortError(ABORT_STORE)
        if index in MOTION_OBJECTS:
            r = self.refusal()
            if r is not None:
                self._refuse(index, sub, r, "SDO")
                raise SdoAbortError(r.code)

    def cob_id_conflict(self, kind: str, number: int, can_id: int) -> str | None:
        for p in (*self.rpdos.values(), *self.tpdos):
            if p.cob_id == can_id and not (p.kind == kind and p.number == number):
                return f"{p.kind.upper()}{p.number} of this node"
        hit = self._reserved.get(can_id)
        if hit is not None and hit[1] != kind:
            return hit[0]
        return None

    def _check_pdo_cob_id(self, kind: str, comm: int, value: int) -> None:
        try:
            super()._check_pdo_cob_id(kind, comm, value)
        except SdoAbortError as exc:
            number = comm - (0x1400 if kind == "rpdo" else 0x1800) + 1
            why = self.cob_id_conflict(kind, number, value & 0x7FF)
            self.host.event(
                "plc_cob_id_refused", f"SDO write {comm:04X}h:01 = {value:08X}h: "
                + (f"CAN-ID {value & 0x7FF:03X}h is used by {why}" if why else
                   "not a valid COB-ID here (CiA 301: a restricted CAN-ID, bits 11-29 set, "
                   "changed while valid, or no mapping)"),
                f"refused (SDO abort {exc.code:08X}h)", 30)
            raise

    def on_write(self, index: int, sub: int, value: Any) -> None:
        if index == 0x2005:
            if value not in ENGAGE_VALUES:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            if not self.host.tracking():
                raise SdoAbortError(ABORT_DEVICE_STATE)
            self._engage(int(value))  # (an SDO write is an explicit command: acts every time)
        elif index == 0x2004:
            if value > 1:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            self._trigger_input(int(value), int(self.load(0x2014)))
        elif index == 0x2015:
            words = [int(self.load(0x2015, s)) for s in _TYPE_SUBS]
            words[sub - 1] = int(value)
            self.host.set_track_types(bits_types(tuple(words)))
        elif index == 0x2010:
            if self.host.track_state() is not TrackState.OFF:
                raise SdoAbortError(ABORT_DEVICE_STATE)
            if not value > 0:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            # (the limits are the configuration's: not changed at run time)
            raise SdoAbortError(ABORT_STORE)

    def on_rpdo_data(self, number: int, values: list[tuple[int, int, bytes]]
                     ) -> list[tuple[int, int, bytes]]:
        kept = []
        refusal = self.refusal()
        # the item type of this frame's edge: 2014h of the same PDO wherever it is mapped
        item_type = int(self.load(0x2014))
        if refusal is None:
            for index, sub, raw in values:
                if index == 0x2014:
                    item_type = int(self.decode(index, sub, raw))
        for index, sub, raw in values:
            if index in MOTION_OBJECTS and refusal is not None:
                self._refuse(index, sub, refusal, f"RPDO{number}")
                continue
            value = self.decode(index, sub, raw)
            if index == 0x2005:
                if value not in ENGAGE_VALUES or not self.host.tracking():
                    continue  # (a PDO cannot be refused: ignored, 2005h keeps its value)
                if value != self._rpdo_engage:  # (a PDO acts on a change of value)
                    self._engage(int(value))
                self._rpdo_engage = int(value)
            elif index == 0x2004:
                self._trigger_input(int(value) & 1, item_type)
                raw = bytes([int(value) & 1])
            kept.append((index, sub, raw))
        return kept

    def on_heartbeat_lost(self, producer: int) -> None:
        if producer != self.config.commander:
            return
        reaction = self.config.on_commander_lost
        detail = (f"heartbeat of the commander (node {producer}) lost: none for "
                  f"{self.config.commander_heartbeat_ms} ms")
        if reaction is CommanderLoss.STOP:
            self.host.quick_stop("plc_commander_lost", detail)
        elif reaction is CommanderLoss.DESYNC:
            if self.host.tracking():
                self._engage(int(Mode.OFF))
            self.host.event("plc_commander_lost", detail, "de-sync on the path", 30)
        else:
            self.host.event("plc_commander_lost", detail,
                            "continue (on_commander_lost: continue)", 30)

    def on_heartbeat_back(self, producer: int) -> None:
        if producer == self.config.commander:
            self.host.event("plc_commander_back", f"heartbeat of the commander (node "
                            f"{producer}) received again", "commands accepted again", 20)

    def on_nmt(self, old: Nmt, new: Nmt) -> None:
        self.host.nmt(int(new))
        if self._started and old is not Nmt.INITIALISING:
            self.host.event("plc_nmt", f"NMT {old.name} -> {new.name}", "", 20)

    # -- commands ---------------------------------------------------------------------------
    def _engage(self, value: int) -> None:
        self.commands.append((self.clock.now_ns(), value))
        self.host.engage(Mode(value))

    def _trigger_input(self, value: int, item_type: int) -> None:
        old = int(self.load(0x2004)) & 1
        if not (value & 1 and not old):
            return
        t = self.clock.now_ns()
        if not self._rate.accept(t):
            self.triggers_dropped += 1
            n = self._throttle.due("plc_trigger_rate", t)
            if n is not None:
                self.host.event("plc_trigger_dropped",
                                f"more than {self._rate.max} trigger edges within 1 s"
                                + (f" ({n} dropped since the last report)" if n > 1 else ""),
                                "trigger dropped (counted in 2013h)", 30)
            return
        self.triggers += 1
        self.trigger_times.append(t)
        self.trigger_types.append(item_type)
        self.host.trigger(t, item_type)

    # -- the cycle ----------------------------------------------------------------------------
    def cycle(self, status: PlcStatus, sync_ns: int | None, sync_counter: int | None) -> None:
        """Once per controller cycle, after its SYNC (``sync_ns``, counter or None): this
        cycle's status into the objects, the node's timers, its SYNC (TPDO types 0-240)."""
        now = self.clock.now_ns()
        if not self._started:
            self.set_nmt(Nmt.OPERATIONAL)  # (the NMT master starts itself with its cycle)
            self._started = True
        self._sync_ns = sync_ns
        self.store(0x2000, 0, int(status.state))
        self.store(0x2001, 0, int(status.imfs))
        self.store(0x2002, 0, int(status.error))
        self.store(0x2003, 0, status.items & 0xFFFFFFFF)
        self.store(0x2006, 0, status.missed & 0xFFFFFFFF)
        self.store(0x2007, 0, float(status.tracking_error_mm))
        self.store(0x2008, 0, float(status.belt_vel_mm_s))
        self.store(0x2011, 0, self.command_access())
        self.store(0x2012, 0, self.refused & 0xFFFFFFFF)
        self.store(0x2013, 0, (self.triggers_dropped + status.triggers_dropped) & 0xFFFFFFFF)
        self.store(0x2016, 0, status.items_ignored & 0xFFFFFFFF)
        due = self.next_timer_ns()
        if due is not None and due <= now:
            self.on_timer(now)
        self.process_sync(sync_counter)


def reserved_cob_ids(node_id: int, commander: int | None, slaves: Mapping[int, str],
                     configured: Mapping[int, str]) -> dict[int, tuple[str, str | None]]:
    """The CAN-IDs the node's PDOs may not use: COB-ID -> (what uses it, the kind of our PDO
    that may use it anyway).  ``slaves``: node-ID -> label of the bus's slaves;
    ``configured``: COB-ID -> label of the slaves' configured PDOs."""
    out: dict[int, tuple[str, str | None]] = {0x080: ("the SYNC", None),
                                              0x100: ("the TIME stamp", None)}
    for node in range(1, 128):
        if node != node_id:
            out[0x80 + node] = (f"the EMCY of node {node}", None)
    nodes = dict(slaves)
    if commander is not None:
        nodes[commander] = f"node {commander} (the commander)"
    for node, label in nodes.items():
        ours_rx = "rpdo" if node == commander else None  # its TPDOs: what our RPDOs receive
        ours_tx = "tpdo" if node == commander else None  # its RPDOs: where our TPDOs send
        for n in range(4):
            out[0x180 + 0x100 * n + node] = (f"TPDO{n + 1} of {label}", ours_rx)
            out[0x200 + 0x100 * n + node] = (f"RPDO{n + 1} of {label}", ours_tx)
    for cob, label in configured.items():
        out[cob] = (label, None)
    return out
