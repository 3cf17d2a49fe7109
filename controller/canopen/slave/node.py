"""A simulated CANopen slave: python canopen ``LocalNode`` plus what it lacks.

python canopen's ``LocalNode`` provides the object dictionary storage and the SDO server.
It does not update its object dictionary from received PDOs (canopen issues #145, #558),
and its NMT slave sends heartbeats from a python-can periodic thread, which a stepped
simulation cannot use.  :class:`SimNode` therefore adds, on the rack's clock:

- NMT slave (CiA 301): power-on / reset node / reset communication -> boot-up message
  after ``boot_delay_ns`` -> PRE-OPERATIONAL; start, stop, enter pre-operational.  Reset node
  restores every object to its EDS default; reset communication 1000h-1FFFh only.
- heartbeat producer (1017h ms) on a timer; heartbeat consumer (1016h) with a callback;
- PDOs from the communication/mapping objects (1400h-1BFFh) as configured over SDO.  Mapping
  writes follow CiA 301: allowed only while the PDO is disabled (COB-ID bit 31) and sub 0 is
  0 (abort 06040043h otherwise); mapped objects must exist and be mappable (06040041h); at
  most 64 bits (06040042h).  Received RPDOs with transmission type 0-240 are stored and
  written into the object dictionary at the next SYNC; 254/255 at once.  TPDOs with type
  1-240 are sent on every n-th SYNC, 254/255 on change (respecting the inhibit time) and on
  the event timer;
- EMCY producer with 1001h/1003h bookkeeping;
- fault injection: heartbeat stop, silence (nothing sent at all), PDOs muted, SDO server
  mute, an SDO abort on one object, identity changes, an EMCY, power off.

Subclasses implement ``on_sync`` (before the TPDOs are sent), ``on_reset``, ``on_write``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import canopen
from canopen.objectdictionary import ODVariable

from ..io.clock import Clock
from ..protocol import od as odm
from ..protocol.pdo import INVALID, read_pdo_params
from ..protocol.sdo import (
    ABORT_GENERAL,
    ABORT_PARAM_INCOMPATIBLE,
    ABORT_PDO_LENGTH,
    ABORT_PDO_MAPPING,
    SdoAbortError,
)

NMT_INITIALISING = 0
NMT_STOPPED = 4
NMT_OPERATIONAL = 5
NMT_PRE_OPERATIONAL = 127
#: CiA 301 EMCY: unexpected SYNC data length (the counter against 1019h)
EMCY_SYNC_LENGTH = 0x8240




@dataclass
class _Pdo:
    kind: str
    number: int
    cob_id: int
    transmission: int
    inhibit_ns: int
    event_ns: int
    mapping: list[tuple[int, int, int]]
    pending: bytes | None = None  # RPDO data waiting for the next SYNC
    last_data: bytes | None = None  # TPDO: last sent data
    last_sent_ns: int | None = None
    sync_count: int = 0
    objects: frozenset = frozenset()  # the mapped (index, sub-index)
    dirty: bool = True  # TPDO: a mapped object changed since the last send


class SimNode:
    """Base of the simulated devices (one node on the rack's shared canopen Network)."""

    kind = "node"

    def __init__(self, name: str, eds: str, node_id: int, network: canopen.Network,
                 clock: Clock, boot_delay_ns: int = 5_000_000) -> None:
        self.name = name
        self.node_id = node_id
        self.clock = clock
        self.network = network
        self.od = odm.load_od(eds, node_id)
        self._vars: dict[tuple[int, int], ODVariable] = {}
        self._changed: set[tuple[int, int]] = set()  # objects changed since the last service
        self._codecs: dict[tuple[int, int], tuple[struct.Struct | None, ODVariable]] = {}
        self.node = canopen.LocalNode(node_id, self.od)
        network[node_id] = self.node  # SDO server on 600h+id
        # a node that is off or silenced does not answer SDO requests either
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        # our NMT replaces canopen's (which would start a periodic heartbeat thread)
        network.unsubscribe(0, self.node.nmt.on_command)
        # (a private list: canopen is bounded < 2.5 for it, docs/spec/tools.md#3)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_sdo_write)
        network.subscribe(0x000, self._on_nmt)
        self.boot_delay_ns = int(boot_delay_ns)
        self.nmt_state = NMT_INITIALISING
        self.powered = True
        self.silent = False
        self.pdos_muted = False
        self.sdo_muted = False
        self.heartbeat_enabled = True
        self.sync_cob = 0x80
        self._boot_at: int | None = clock.now_ns() + self.boot_delay_ns
        self._hb_next: int | None = None
        self._hb_consumers: dict[int, tuple[int, int | None]] = {}  # producer -> (ms, last ns)
        self._hb_lost: set[int] = set()
        self._rpdos: dict[int, _Pdo] = {}
        self._tpdos: list[_Pdo] = []
        self._pdo_dirty = True
        self._sdo_rejects: dict[tuple[int, int], int] = {}
        self.emcy_sent: list[tuple[int, int]] = []  # (code, ns)
        self.sync_counter: int | None = None
        #: an EMCY code sent instead of obeying NMT start (a device that refuses to start,
        #: like a CANopenNode device without its storage files: 5000h)
        self.refuse_start: int | None = None
        self._has_1019 = odm.variable(self.od, 0x1019) is not None
        network.subscribe(self.sync_cob, self._on_sync_frame)

    # -- object dictionary access -------------------------------------------------------
    def var(self, index: int, sub: int = 0) -> ODVariable:
        key = (index, sub)
        v = self._vars.get(key)
        if v is None:
            v = odm.variable(self.od, index, sub)
            if v is None:
                raise KeyError(f"{self.name}: no object {index:04X}h:{sub:02X}")
            self._vars[key] = v
        return v

    def _codec(self, index: int, sub: int) -> tuple[struct.Struct | None, ODVariable]:
        key = (index, sub)
        c = self._codecs.get(key)
        if c is None:
            v = self.var(index, sub)
            fmt = odm.STRUCT_FORMAT.get(v.data_type)
            c = (struct.Struct("<" + fmt) if fmt else None, v)
            self._codecs[key] = c
        return c

    def store(self, index: int, sub: int, value: Any) -> None:
        """Set an object's value from the application (no SDO checks, no callbacks)."""
        st, v = self._codec(index, sub)
        raw = st.pack(value) if st is not None else v.encode_raw(value)
        store = self.node.data_store
        d = store.get(index)
        if d is None:
            d = store[index] = {}
        if d.get(sub) != raw:
            d[sub] = raw
            self._changed.add((index, sub))

    def load(self, index: int, sub: int = 0) -> Any:
        """An object's current value (stored, else EDS default; REAL32 hex defaults too)."""
        d = self.node.data_store.get(index)
        raw = d.get(sub) if d is not None else None
        if raw is None:
            value = odm.default_value(self.var(index, sub))
            return 0 if value is None else value
        st, v = self._codec(index, sub)
        return st.unpack(raw)[0] if st is not None else v.decode_raw(raw)

    # -- fault injection -----------------------------------------------------------------
    def reject_sdo(self, index: int, sub: int, code: int) -> None:
        """Abort every SDO write to ``index:sub`` with ``code``."""
        self._sdo_rejects[(index, sub)] = code

    def set_identity(self, vendor: int | None = None, product: int | None = None,
                     revision: int | None = None, serial: int | None = None) -> None:
        for sub, value in ((1, vendor), (2, product), (3, revision), (4, serial)):
            if value is not None:
                self.store(0x1018, sub, value)
        self._identity_override = {sub: v for sub, v in ((1, vendor), (2, product),
                                                         (3, revision), (4, serial))
                                   if v is not None}

    def mute_pdos(self, on: bool = True) -> None:
        """Stop (or resume) sending PDOs; heartbeat, EMCY and SDO go on."""
        self.pdos_muted = on

    def mute_sdo(self, on: bool = True) -> None:
        """Stop (or resume) answering SDO requests (a hung SDO server)."""
        self.sdo_muted = on

    def silence(self, on: bool = True) -> None:
        """Stop (or resume) sending anything (the node still listens)."""
        self.silent = on

    def stop_heartbeat(self) -> None:
        self.heartbeat_enabled = False

    def resume_heartbeat(self) -> None:
        self.heartbeat_enabled = True
        self._schedule_heartbeat(self.clock.now_ns())

    def reset_itself(self) -> None:
        """The node resets on its own (a watchdog, a supply glitch): reset application, then
        its boot-up after ``boot_delay_ns``, in pre-operational with its EDS defaults."""
        self._reset(application=True)

    def power_off(self) -> None:
        """The node disappears: it neither answers nor sends."""
        self.powered = False

    def send_emcy(self, code: int, register: int | None = None, data: bytes = b"") -> None:
        """Send an EMCY (error code ``code``), updating 1001h and 1003h."""
        if register is None:
            register = 0 if code == 0 else (0x01 | (0x80 if code >> 12 in (8, 15) else 0))
        self.store(0x1001, 0, register)
        if code != 0 and 0x1003 in self.od:
            n = int(self.load(0x1003, 0))
            depth = max(s for s in self.od[0x1003].subindices)
            history = [int(self.load(0x1003, i)) for i in range(1, min(n, depth) + 1)]
            history = [code] + history[: depth - 1]
            for i, value in enumerate(history, start=1):
                self.store(0x1003, i, value)
            self.store(0x1003, 0, len(history))
        if self._can_talk() and self.nmt_state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL):
            payload = struct.pack("<HB5s", code, register, bytes(data)[:5])
            self.network.send_message(0x80 + self.node_id, payload)
        self.emcy_sent.append((code, self.clock.now_ns()))

    def _on_sdo_request(self, can_id: int, data: bytes, ts: Any) -> None:
        if self._can_talk() and self.nmt_state != NMT_INITIALISING and not self.sdo_muted:
            if len(data) != 8:
                # CiA 301: SDO frames have 8 bytes; python canopen's server would raise in
                # its unpack.  Abort 05040001h (command specifier not valid), naming what
                # index/sub-index bytes there are.
                head = bytes(data[1:4]).ljust(3, b"\0")
                self.network.send_message(0x580 + self.node_id,
                                          b"\x80" + head + (0x05040001).to_bytes(4, "little"))
                return
            self.node.sdo.on_request(can_id, data, ts)

    # -- NMT -------------------------------------------------------------------------------
    def _can_talk(self) -> bool:
        return self.powered and not self.silent

    def _sync_length_ok(self, n: int) -> bool:
        """CiA 301: with 1019h > 0 a SYNC carries the counter (1 byte), else none; a consumer
        that gets another length sends EMCY 8240h (unexpected SYNC data length) and, as
        CANopenNode does, enters pre-operational.  (Objects without 1019h: not checked.)"""
        if not self._has_1019:
            return True
        want = 1 if int(self.load(0x1019, 0)) else 0
        if n == want:
            return True
        if self.nmt_state == NMT_OPERATIONAL:
            self.send_emcy(EMCY_SYNC_LENGTH)
            self._set_nmt(NMT_PRE_OPERATIONAL)
        return False

    def _on_nmt(self, can_id: int, data: bytes, ts: Any) -> None:
        if not self.powered or len(data) < 2:
            return
        cmd, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        self._maybe_reload()
        if cmd == 0x01 and self.nmt_state != NMT_INITIALISING and self.refuse_start is not None:
            self.send_emcy(self.refuse_start)  # (as CANopenNode without its storage files)
        elif cmd == 0x01 and self.nmt_state != NMT_INITIALISING:
            self._set_nmt(NMT_OPERATIONAL)
        elif cmd == 0x02 and self.nmt_state != NMT_INITIALISING:
            self._set_nmt(NMT_STOPPED)
        elif cmd == 0x80 and self.nmt_state != NMT_INITIALISING:
            self._set_nmt(NMT_PRE_OPERATIONAL)
        elif cmd in (0x81, 0x82):
            self._reset(application=cmd == 0x81)

    def _set_nmt(self, state: int) -> None:
        if state == self.nmt_state:
            return
        old = self.nmt_state
        self.nmt_state = state
        if state == NMT_OPERATIONAL:
            self._rebuild_pdos()
            for p in self._tpdos:
                p.sync_count = 0
                p.last_data = None
        self.on_nmt(old, state)

    def _reset(self, application: bool) -> None:
        store = self.node.data_store
        for index in list(store):
            if application or 0x1000 <= index <= 0x1FFF:
                del store[index]
        for (sub, value) in getattr(self, "_identity_override", {}).items():
            self.store(0x1018, sub, value)
        self.nmt_state = NMT_INITIALISING
        self._hb_next = None
        for producer in list(self._hb_consumers):
            self.network.unsubscribe(0x700 + producer, self._on_heartbeat)
        self._hb_consumers.clear()
        self._hb_lost.clear()
        self._pdo_dirty = True
        self._rpdos.clear()
        self._tpdos.clear()
        self.sync_counter = None
        if application:
            self.on_reset()
        self._boot_at = self.clock.now_ns() + self.boot_delay_ns

    def _boot_up(self, now: int) -> None:
        self._boot_at = None
        self.nmt_state = NMT_PRE_OPERATIONAL
        if self._can_talk():
            self.network.send_message(0x700 + self.node_id, b"\x00")
        self._schedule_heartbeat(now)
        self._load_hb_consumers()
        self._rebuild_pdos()

    def _schedule_heartbeat(self, now: int) -> None:
        ms = int(self.load(0x1017, 0)) if 0x1017 in self.od else 0
        self._hb_next = now + ms * 1_000_000 if ms > 0 else None

    # -- heartbeat consumer ------------------------------------------------------------------
    def _load_hb_consumers(self) -> None:
        for producer, _ in list(self._hb_consumers.items()):
            self.network.unsubscribe(0x700 + producer, self._on_heartbeat)
        self._hb_consumers.clear()
        if 0x1016 not in self.od:
            return
        for sub in self.od[0x1016].subindices:
            if sub == 0:
                continue
            value = int(self.load(0x1016, sub))
            producer, ms = (value >> 16) & 0xFF, value & 0xFFFF
            if 1 <= producer <= 127 and ms:
                self._hb_consumers[producer] = (ms, None)
                self.network.subscribe(0x700 + producer, self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data: bytes, ts: Any) -> None:
        producer = can_id - 0x700
        if producer in self._hb_consumers and self.powered:
            ms, _ = self._hb_consumers[producer]
            self._hb_consumers[producer] = (ms, self.clock.now_ns())
            self._hb_lost.discard(producer)

    # -- SDO write hook ------------------------------------------------------------------------
    def _on_sdo_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        if not self.powered:
            raise SdoAbortError(ABORT_GENERAL)
        code = self._sdo_rejects.get((index, subindex))
        if code is not None:
            raise SdoAbortError(code)
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, data)
            self._pdo_dirty = True
        if index == 0x1017:
            ms = struct.unpack_from("<H", data)[0]
            now = self.clock.now_ns()
            self._hb_next = now + ms * 1_000_000 if ms and self.nmt_state else None
        self.on_write(index, subindex, od.decode_raw(data))
        if index == 0x1016:
            # applied at the next event (LocalNode stores the value after the callbacks)
            self._hb_reload = True

    def _maybe_reload(self) -> None:
        if getattr(self, "_hb_reload", False):
            self._hb_reload = False
            self._load_hb_consumers()

    def _check_pdo_write(self, index: int, sub: int, data: bytes) -> None:
        is_map = 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF
        if not is_map:
            return
        comm = index - 0x200
        cob = int(self.load(comm, 1))
        if not cob & INVALID:
            raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
        if sub != 0:
            if int(self.load(index, 0)) != 0:
                raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
            value = struct.unpack_from("<I", data)[0]
            obj, osub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
            if obj < 0x1000:
                return  # dummy
            var = odm.variable(self.od, obj, osub)
            if var is None or not var.pdo_mappable or len(var) != bits:
                raise SdoAbortError(ABORT_PDO_MAPPING)
            return
        n = data[0]
        total = 0
        for i in range(1, n + 1):
            try:
                entry = int(self.load(index, i))
            except KeyError:
                raise SdoAbortError(ABORT_PDO_MAPPING) from None
            total += entry & 0xFF
        if total > 64:
            raise SdoAbortError(ABORT_PDO_LENGTH)

    # -- PDO engine ----------------------------------------------------------------------------
    def _rebuild_pdos(self) -> None:
        for pdo in self._rpdos.values():
            self.network.unsubscribe(pdo.cob_id, self._on_rpdo)
        self._rpdos.clear()
        self._tpdos = []
        for comm in range(0x1400, 0x1600):
            if comm not in self.od:
                continue
            p = self._read_pdo("rpdo", comm)
            if p is not None:
                self._rpdos[p.cob_id] = p
                self.network.subscribe(p.cob_id, self._on_rpdo)
        for comm in range(0x1800, 0x1A00):
            if comm not in self.od:
                continue
            p = self._read_pdo("tpdo", comm)
            if p is not None:
                self._tpdos.append(p)
        self._pdo_dirty = False

    def _read_pdo(self, kind: str, comm: int) -> _Pdo | None:
        p = read_pdo_params(self.load, lambda i, s: odm.variable(self.od, i, s) is not None,
                            comm, kind == "tpdo")
        if p is None:
            return None
        return _Pdo(kind, comm - (0x1400 if kind == "rpdo" else 0x1800) + 1, p.cob_id,
                    p.transmission, p.inhibit_ns, p.event_ns, p.mapping,
                    objects=frozenset((i, s) for i, s, _ in p.mapping))

    def _on_rpdo(self, can_id: int, data: bytes, ts: Any) -> None:
        if not self.powered or self.nmt_state != NMT_OPERATIONAL:
            return
        pdo = self._rpdos.get(can_id)
        if pdo is None:
            return
        if pdo.transmission <= 240:
            pdo.pending = bytes(data)
        else:
            self._apply_rpdo(pdo, bytes(data))
            self.on_rpdo(pdo.number, pdo.objects)

    def _apply_rpdo(self, pdo: _Pdo, data: bytes) -> None:
        offset = 0
        store = self.node.data_store
        for index, sub, bits in pdo.mapping:
            n = bits // 8
            if index >= 0x1000:
                store.setdefault(index, {})[sub] = data[offset:offset + n]
            offset += n

    def _tpdo_data(self, pdo: _Pdo) -> bytes:
        out = bytearray()
        store = self.node.data_store
        for index, sub, bits in pdo.mapping:
            if index < 0x1000:
                out += bytes(bits // 8)
                continue
            d = store.get(index)
            raw = d.get(sub) if d is not None else None
            out += raw if raw is not None else self.node.get_data(index, sub)
        return bytes(out)

    def _on_sync_frame(self, can_id: int, data: bytes, ts: Any) -> None:
        if not self.powered or self.nmt_state in (NMT_INITIALISING, NMT_STOPPED):
            return
        self._maybe_reload()
        if self._pdo_dirty:
            self._rebuild_pdos()
        self.sync_counter = data[0] if data else None
        if not self._sync_length_ok(len(data)):
            return
        now = self.clock.now_ns()
        operational = self.nmt_state == NMT_OPERATIONAL
        if operational:
            for pdo in self._rpdos.values():
                if pdo.pending is not None:
                    self._apply_rpdo(pdo, pdo.pending)
                    pdo.pending = None
                    self.on_rpdo(pdo.number, pdo.objects)
        self.on_sync(now)
        if operational and self._can_talk() and not self.pdos_muted:
            for pdo in self._tpdos:
                t = pdo.transmission
                if 1 <= t <= 240:
                    pdo.sync_count += 1
                    if pdo.sync_count >= t:
                        pdo.sync_count = 0
                        self.network.send_message(pdo.cob_id, self._tpdo_data(pdo))
            self.service_event_pdos(now)

    def service_event_pdos(self, now: int) -> None:
        """Send the event-driven TPDOs whose data changed or whose event timer expired."""
        changed = self._changed
        if self.nmt_state != NMT_OPERATIONAL or not self._can_talk() or self.pdos_muted:
            changed.clear()
            return
        for pdo in self._tpdos:
            if pdo.transmission < 254:
                continue
            if changed and not pdo.dirty and not changed.isdisjoint(pdo.objects):
                pdo.dirty = True
            timer = pdo.event_ns and (pdo.last_sent_ns is None
                                      or now - pdo.last_sent_ns >= pdo.event_ns)
            if not (pdo.dirty or timer):
                continue
            if pdo.last_sent_ns is not None and now - pdo.last_sent_ns < pdo.inhibit_ns:
                continue
            data = self._tpdo_data(pdo)
            pdo.dirty = False
            if data != pdo.last_data or timer:
                self.network.send_message(pdo.cob_id, data)
                pdo.last_data = data
                pdo.last_sent_ns = now
        changed.clear()

    # -- timers ---------------------------------------------------------------------------------
    def next_timer_ns(self) -> int | None:
        if not self.powered:
            return None
        due = [t for t in (self._boot_at, self._hb_next if self.heartbeat_enabled else None,
                           self.device_timer_ns()) if t is not None]
        for producer, (ms, last) in self._hb_consumers.items():
            if last is not None and producer not in self._hb_lost:
                due.append(last + ms * 1_000_000)
        if self.nmt_state == NMT_OPERATIONAL and self._can_talk() and not self.pdos_muted:
            for pdo in self._tpdos:
                if pdo.transmission >= 254 and pdo.event_ns:
                    base = pdo.last_sent_ns if pdo.last_sent_ns is not None else 0
                    due.append(base + pdo.event_ns)
        return min(due) if due else None

    def on_timer(self, now: int) -> None:
        if not self.powered:
            return
        self._maybe_reload()
        if self._boot_at is not None and now >= self._boot_at:
            self._boot_up(now)
        if self._hb_next is not None and now >= self._hb_next and self.heartbeat_enabled:
            if self._can_talk():
                self.network.send_message(0x700 + self.node_id, bytes([self.nmt_state]))
            self._schedule_heartbeat(now)
        elif self._hb_next is not None and now >= self._hb_next:
            self._schedule_heartbeat(now)
        for producer, (ms, last) in list(self._hb_consumers.items()):
            if last is not None and producer not in self._hb_lost \
                    and now >= last + ms * 1_000_000:
                self._hb_lost.add(producer)
                self.on_heartbeat_lost(producer)
        self.device_timer(now)
        self.service_event_pdos(now)

    # -- hooks for subclasses --------------------------------------------------------------------
    def on_sync(self, now_ns: int) -> None:
        """A SYNC arrived (RPDOs of types 0-240 are already in the OD; TPDOs follow)."""

    def on_rpdo(self, number: int, objects: frozenset) -> None:
        """RPDO ``number`` (mapping ``objects``) was written into the OD."""

    def on_write(self, index: int, sub: int, value: Any) -> None:
        """An SDO write (raise SdoAbortError to refuse it; stored after this returns)."""

    def on_reset(self) -> None:
        """NMT reset node: back to the power-on state (the physical state stays)."""

    def on_nmt(self, old: int, new: int) -> None:
        """The NMT state changed."""

    def on_heartbeat_lost(self, producer: int) -> None:
        """A consumed heartbeat (1016h) timed out."""

    def device_timer_ns(self) -> int | None:
        return None

    def device_timer(self, now_ns: int) -> None:
        pass


Hook = Callable[[], None]
