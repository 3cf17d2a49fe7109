"""Heartbeat and EMCY consumers of the controller (observations; reactions are the cycle's).

Heartbeat (CiA 301 consumer, the master's 1016h): a node is lost when no heartbeat came
for ``producer time x heartbeat_multiplier`` (dcfgen's rule for the master's 1016h
entries); a heartbeat that shows another NMT state than expected (a boot-up 00h = the node
reset itself, 04h stopped, 7Fh pre-operational) is reported as well.  python canopen has no
heartbeat time-out detection of its own (canopen-notes.md).

EMCY: every frame on 80h + node-ID is decoded (error code, error register, manufacturer
bytes) with python canopen's ``EmcyError`` descriptions and queued for the cycle.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from canopen.emcy import EmcyError

from ..io.transport import Transport

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

    @property
    def description(self) -> str:
        return EmcyError(self.code, self.register, self.data, 0.0).get_desc()

    def __str__(self) -> str:
        return (f"EMCY {self.code:04X}h ({self.description}), error register "
                f"{self.register:02X}h")


class HeartbeatMonitor:
    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.watches: dict[int, _Watch] = {}
        self.expected_state = 5

    def watch(self, node_id: int, label: str, timeout_ns: int) -> None:
        w = _Watch(label, node_id, timeout_ns)
        self.watches[node_id] = w
        self.transport.subscribe(0x700 + node_id, self._on_heartbeat)

    def start(self, now_ns: int) -> None:
        """Begin the time-out checks now (nodes that never sent count from here)."""
        for w in self.watches.values():
            w.state = None  # boot-up and pre-operational heartbeats of the boot are expected
            if w.last_ns is None:
                w.last_ns = now_ns

    def _on_heartbeat(self, can_id: int, data: bytes, t_ns: int) -> None:
        w = self.watches.get(can_id - 0x700)
        if w is None or not data:
            return
        w.last_ns = t_ns
        w.state = data[0] & 0x7F
        w.lost = False

    def check(self, now_ns: int) -> list[tuple[str, str, str]]:
        """New findings as (label, kind, detail): kind heartbeat_lost / nmt_state."""
        out = []
        for w in self.watches.values():
            if w.timeout_ns <= 0 or w.last_ns is None:
                continue
            if not w.lost and now_ns - w.last_ns > w.timeout_ns:
                w.lost = True
                out.append((w.label, "heartbeat_lost",
                            (f"no heartbeat for {(now_ns - w.last_ns) / 1e6:.0f} ms "
                             f"(time-out {w.timeout_ns / 1e6:.0f} ms)")))
            if w.state is not None and w.state != self.expected_state:
                name = NMT_NAMES.get(w.state, f"{w.state:02X}h")
                out.append((w.label, "nmt_state", f"heartbeat shows NMT state {name}"))
                w.state = None  # report once per heartbeat
        return out


class EmcyMonitor:
    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.labels: dict[int, tuple[str, int]] = {}
        self.queue: list[Emcy] = []
        self.log: list[Emcy] = []

    def watch(self, cob_id: int, node_id: int, label: str) -> None:
        self.labels[cob_id] = (label, node_id)
        self.transport.subscribe(cob_id, self._on_emcy)

    def _on_emcy(self, can_id: int, data: bytes, t_ns: int) -> None:
        label, node_id = self.labels[can_id]
        data = bytes(data).ljust(8, b"\0")
        code, register = struct.unpack_from("<HB", data)
        e = Emcy(label, node_id, code, register, data[3:8], t_ns)
        self.queue.append(e)
        self.log.append(e)

    def pop_all(self) -> list[Emcy]:
        out, self.queue = self.queue, []
        return out
