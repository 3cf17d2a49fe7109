"""Heartbeat and EMCY consumers of the controller (observations; reactions are the cycle's).

Heartbeat (CiA 301 consumer, the master's 1016h): a node is lost when no heartbeat came
for ``producer time x heartbeat_multiplier`` (dcfgen's rule for the master's 1016h
entries); a heartbeat that shows another NMT state than expected (a boot-up 00h = the node
reset itself, 04h stopped, 7Fh pre-operational) is reported as well.  python canopen has no
heartbeat time-out detection of its own (canopen-notes.md).

A heartbeat (1 byte) or EMCY (8 bytes) frame of another length is dropped and counted
(:mod:`.frames`).

EMCY: every frame on 80h + node-ID is decoded (error code, error register, manufacturer
bytes), named by the full CiA 301 / CiA 402 table (:mod:`.emcy_codes`; python canopen's
``EmcyError`` knows only the classes) and queued for the cycle.  00xxh is an error reset.

:class:`BusActors`: the other actors of the bus.  The controller is the only NMT master and
SYNC producer, so every NMT command (000h) and every SYNC it receives (a bus does not echo
one's own frames) is another actor's; heartbeats of node-IDs nobody configured; error
frames (SocketCAN's CAN_ERR_* classes: controller error passive, bus-off).
"""

from __future__ import annotations

import math
import struct
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import can

from ..config.reactions import Disturbance
from ..io.transport import Transport
from ..protocol.emcy_codes import describe, is_error_reset
from ..protocol.frames import FrameHygiene

if TYPE_CHECKING:
    from ..config import ControllerConfig

NMT_NAMES = {0: "boot-up", 4: "stopped", 5: "operational", 127: "pre-operational"}


@dataclass
class _Watch:
    label: str
    node_id: int
    timeout_ns: int
    last_ns: int | None = None
    state: int | None = None
    lost: bool = False


@dataclass(frozen=True, slots=True)
class Emcy:
    label: str
    node_id: int
    code: int
    register: int
    data: bytes
    t_ns: int
    #: the node's device profile (1000h bits 0-15: 402 = drive), for the code's text
    profile: int | None = None

    @property
    def description(self) -> str:
        return describe(self.code, self.profile)

    @property
    def is_reset(self) -> bool:
        """00xxh: error reset / no error (CiA 301)."""
        return is_error_reset(self.code)

    def __str__(self) -> str:
        extra = f", manufacturer bytes {self.data.hex(' ').upper()}" if any(self.data) else ""
        return (f"EMCY {self.code:04X}h ({self.description}), error register "
                f"{self.register:02X}h{extra}")


class HeartbeatMonitor:
    def __init__(self, transport: Transport, hygiene: FrameHygiene | None = None) -> None:
        self.transport = transport
        self.hygiene = hygiene if hygiene is not None else FrameHygiene()
        self.watches: dict[int, _Watch] = {}
        self.expected_state = 5
        #: :meth:`check` has nothing to find up to this time [ns]: no time-out can have passed
        #: and no heartbeat showed a state since the last check (one that does sets it to
        #: -inf); a heartbeat only moves a time-out later, so an earlier value is merely a
        #: check too many.  The cycle compares it before calling :meth:`check` (one test per
        #: cycle instead of a call)
        self.quiet_until_ns: float = -math.inf

    def watch(self, node_id: int, label: str, timeout_ns: int) -> None:
        w = _Watch(label, node_id, timeout_ns)
        self.watches[node_id] = w
        self.transport.subscribe(0x700 + node_id, self._on_heartbeat)
        self.quiet_until_ns = -math.inf

    def start(self, now_ns: int) -> None:
        """Begin the time-out checks now (nodes that never sent count from here)."""
        for w in self.watches.values():
            w.state = None  # boot-up and pre-operational heartbeats of the boot are expected
            if w.last_ns is None:
                w.last_ns = now_ns
        self.quiet_until_ns = -math.inf

    def _on_heartbeat(self, can_id: int, data: bytes, t_ns: int) -> None:
        w = self.watches.get(can_id - 0x700)
        if w is None or not self.hygiene.check_exact(can_id, data, (1,),
                                                     f"heartbeat of {w.label}", t_ns):
            return
        w.last_ns = t_ns
        w.state = data[0] & 0x7F
        w.lost = False
        if w.state != self.expected_state:
            self.quiet_until_ns = -math.inf  # (news: the next check reports it)
        elif w.timeout_ns > 0 and t_ns + w.timeout_ns < self.quiet_until_ns:
            # (a lost node back: its time-out counts again)
            self.quiet_until_ns = t_ns + w.timeout_ns

    def check(self, now_ns: int) -> list[tuple[str, str, str]]:
        """New findings as (label, kind, detail): kind heartbeat_lost / node_reset (a
        boot-up: the node reset itself) / nmt_state (stopped, pre-operational, ...)."""
        if now_ns <= self.quiet_until_ns:
            return []  # (no time-out due, no state shown)
        out = []
        due = math.inf
        for w in self.watches.values():
            if w.timeout_ns <= 0 or w.last_ns is None:
                continue
            if not w.lost and now_ns - w.last_ns > w.timeout_ns:
                w.lost = True
                out.append((w.label, "heartbeat_lost",
                            (f"no heartbeat for {(now_ns - w.last_ns) / 1e6:.0f} ms "
                             f"(time-out {w.timeout_ns / 1e6:.0f} ms)")))
            if not w.lost:
                due = min(due, w.last_ns + w.timeout_ns)
            if w.state is not None and w.state != self.expected_state:
                name = NMT_NAMES.get(w.state, f"{w.state:02X}h")
                if w.state == 0:
                    out.append((w.label, "node_reset", ("boot-up message (00h) while the "
                                                        "cycle runs: the node reset itself")))
                else:
                    out.append((w.label, "nmt_state", f"heartbeat shows NMT state {name}"))
                w.state = None  # report once per heartbeat
        self.quiet_until_ns = due
        return out


class EmcyMonitor:
    """The EMCYs of the watched nodes: ``queue`` (since the last :meth:`pop_all`, the cycle
    takes them) and ``log`` (the last :data:`LOG`, for :meth:`of_node`)."""

    #: EMCYs kept in ``log``
    LOG = 1000

    def __init__(self, transport: Transport, hygiene: FrameHygiene | None = None,
                 cfg: ControllerConfig | None = None) -> None:
        self.transport = transport
        self.hygiene = hygiene if hygiene is not None else FrameHygiene()
        self.cfg = cfg
        self.labels: dict[int, tuple[str, int]] = {}
        self.profiles: dict[int, int | None] = {}
        self.queue: list[Emcy] = []
        #: the last LOG EMCYs received (a drive that keeps sending them does not fill the
        #: memory of a long run - issue 12; the boot's errors name the newest of a node)
        self.log: deque[Emcy] = deque(maxlen=self.LOG)

    def watch(self, cob_id: int, node_id: int, label: str, profile: int | None = None) -> None:
        self.labels[cob_id] = (label, node_id)
        self.profiles[cob_id] = profile
        self.transport.subscribe(cob_id, self._on_emcy)

    def _on_emcy(self, can_id: int, data: bytes, t_ns: int) -> None:
        label, node_id = self.labels[can_id]
        if not self.hygiene.check_exact(can_id, data, (8,), f"EMCY of {label}", t_ns):
            return
        code, register = struct.unpack_from("<HB", data)
        e = Emcy(label, node_id, code, register, bytes(data[3:8]), t_ns,
                 self.profiles.get(can_id))
        self.queue.append(e)
        self.log.append(e)

    def pop_all(self) -> list[Emcy]:
        out, self.queue = self.queue, []
        return out

    def of_node(self, node_id: int, since_ns: int = 0) -> list[Emcy]:
        """The EMCYs ``node_id`` sent since ``since_ns`` (boot errors name them)."""
        return [e for e in self.log if e.node_id == node_id and e.t_ns >= since_ns]


#: SocketCAN error frame classes (linux/can/error.h) and controller status bits (data[1])
CAN_ERR_CRTL, CAN_ERR_BUSOFF, CAN_ERR_RESTARTED = 0x004, 0x040, 0x100
CAN_ERR_CRTL_RX_PASSIVE, CAN_ERR_CRTL_TX_PASSIVE = 0x10, 0x20


class BusActors:
    """Frames of other actors (see the module docstring), queued as
    (source, :class:`Disturbance`, detail) for the cycle; each kind of finding is reported
    once per node / command, later ones are counted in :attr:`counts`."""

    def __init__(self, transport: Transport, hygiene: FrameHygiene, cfg: ControllerConfig,
                 sync_cob: int = 0x80) -> None:
        self.transport = transport
        self.hygiene = hygiene
        self.cfg = cfg
        self.queue: list[tuple[str, Disturbance, str]] = []
        self.counts: dict[str, int] = {}
        self._reported: set[tuple] = set()
        self.master_id = cfg.master.node_id
        #: NMT commands to the controller's own node-ID belong to its PLC node (an NMT slave
        #: that obeys them, docs/plc.md), not to another master (set by ``attach_plc_node``)
        self.nmt_slave = False
        known = {s.node_id for s in cfg.slaves.values()} | {self.master_id}
        transport.subscribe(0x000, self._on_nmt)
        transport.subscribe(sync_cob, self._on_sync)
        for node in range(1, 128):
            if node not in known:
                transport.subscribe(0x700 + node, self._on_unknown)
        transport.subscribe_errors(self._on_error_frame)

    def _add(self, key: tuple, source: str, d: Disturbance, detail: str) -> None:
        name = d.value
        self.counts[name] = self.counts.get(name, 0) + 1
        if key not in self._reported:
            self._reported.add(key)
            self.queue.append((source, d, detail))

    def _target(self, node: int) -> str:
        if node == 0:
            return "all nodes"
        s = self.cfg.slave_by_node(node)
        return self.cfg.label(s.name) if s is not None else \
            ("the controller" if node == self.master_id else f"node {node} (not configured)")

    def node_known(self, node: int) -> None:
        """``node`` is on the bus on purpose (the PLC node's commander): its heartbeat is no
        unknown node."""
        self.transport.unsubscribe(0x700 + node, self._on_unknown)

    def _on_nmt(self, can_id: int, data: bytes, t_ns: int) -> None:
        if not self.hygiene.check_exact(can_id, data, (2,), "NMT command", t_ns):
            return
        cmd, node = data[0], data[1]
        if node == self.master_id and self.nmt_slave:
            return  # (the PLC node's: it obeys or reports it)
        name = NMT_COMMANDS.get(cmd, f"command {cmd:02X}h")
        self._add(("nmt", cmd, node), "another NMT master", Disturbance.FOREIGN_NMT,
                  f"NMT {name} ({cmd:02X}h) to {self._target(node)}, not sent by the "
                  "controller")

    def _on_sync(self, can_id: int, data: bytes, t_ns: int) -> None:
        counter = f" with counter {data[0]}" if len(data) == 1 else \
            (f" with {len(data)} data bytes" if data else "")
        self._add(("sync",), "a second SYNC producer", Disturbance.FOREIGN_SYNC,
                  f"SYNC ({can_id:03X}h){counter} not sent by the controller")

    def _on_unknown(self, can_id: int, data: bytes, t_ns: int) -> None:
        node = can_id - 0x700
        state = NMT_NAMES.get(data[0] & 0x7F, f"{data[0]:02X}h") if data else "empty"
        self._add(("unknown", node), f"node {node} (not configured)",
                  Disturbance.UNKNOWN_NODE,
                  f"heartbeat/boot-up ({state}) of node-ID {node}, which the bus.yml does "
                  "not configure")

    def _on_error_frame(self, msg: can.Message) -> None:
        cls = msg.arbitration_id
        data = bytes(msg.data)
        status = data[1] if len(data) > 1 else 0
        if cls & CAN_ERR_BUSOFF:
            self._add(("busoff",), "CAN controller", Disturbance.BUS_OFF,
                      f"bus-off (error frame class {cls:03X}h)")
        elif cls & CAN_ERR_CRTL and status & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            side = " and ".join(n for b, n in ((CAN_ERR_CRTL_RX_PASSIVE, "rx"),
                                               (CAN_ERR_CRTL_TX_PASSIVE, "tx"))
                                if status & b)
            self._add(("passive",), "CAN controller", Disturbance.ERROR_PASSIVE,
                      f"error passive ({side}; error frame class {cls:03X}h, status "
                      f"{status:02X}h)")
        else:
            self.counts["bus_error"] = self.counts.get("bus_error", 0) + 1

    def pop_all(self) -> list[tuple[str, Disturbance, str]]:
        out, self.queue = self.queue, []
        return out


NMT_COMMANDS = {0x01: "start remote node", 0x02: "stop remote node",
                0x80: "enter pre-operational", 0x81: "reset node",
                0x82: "reset communication"}
