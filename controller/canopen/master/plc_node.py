"""The controller itself as a CANopen node (eds/cantrack-controller.eds): a PLC watches and
commands it over SDO and PDO.

:class:`PlcNode` sits on the controller's transport (never a second bus, never a thread):

- object storage: the EDS (``canopen.import_od`` through :mod:`controller.canopen.protocol.od`) with ``$NODEID`` = the
  controller's ``master.node_id``; values are kept as raw little-endian bytes by
  (index, sub-index), EDS defaults first (REAL32 hex defaults decoded, eds/README.md); 1006h,
  1017h and 1019h are set from the bus configuration (the demo uses a SYNC counter, so 1019h
  = ``sync_overflow`` there, not the EDS default 0);
- SDO server on 600h+id -> 580h+id: expedited upload and download only (all objects are 1-4
  bytes), answered at once from the receive callback (nothing waits).  Aborts: 06020000h no
  object, 06090011h no sub-index, 06010002h read-only, 06010001h write-only, 06070010h length,
  06090030h value range, 08000022h device state (engage before tracking runs, 2010h while the
  tracker is not OFF), 08000020h objects owned by the bus configuration (1005h, 1006h, 1014h,
  1016h, 1017h, 1019h ...), 05040001h segmented/block transfers;
- every cycle (chained onto ``Controller.on_cycle``): 2000h-2003h and 2006h-2008h from the
  cycle record (state and IMFS: the application's ``track_state``/``imfs`` if it has them,
  the demo's robot group, else the tracker's), the tracker, the controller and the
  application; then the event-driven TPDOs
  (type 254/255: sent when the data changed and the inhibit time 18xxh:3 has passed, or when
  the event timer 18xxh:5 expired).  The TPDOs therefore go out on the cycle's time grid
  (2 ms), after the drives' RPDOs of that cycle.  A PLC may set a TPDO synchronous (18xxh:2
  = 1-240: every n-th SYNC, 0: at the SYNC after a change): each cycle is one SYNC;
- RPDO1 (200h+id, 2005h engage + 2004h trigger) and SDO writes of 2005h/2004h act at once
  (they take effect in the tracker's next update): 2005h = 3/5 -> engage with that mode,
  0 -> disengage, on every SDO write and on a change of value in the RPDO (a PLC may send
  its RPDO cyclically) (the
  application's :meth:`~.app.Application.engage` if it takes it, else ``ctl.tracker``);
  2004h bit 0 rising edge -> an item trigger (:meth:`~.app.Application.trigger`: the
  demo's photo-eye; always counted in :attr:`PlcNode.triggers`).  What the node reports of
  the application comes from its typed :meth:`~.app.Application.status`.

No NMT slave and no heartbeat here: the controller is the NMT master and already produces
its heartbeat (700h+id) itself.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canopen.objectdictionary import REAL32, REAL64, ODVariable

from ...resources import data_path
from ...tracking import Mode, TrackState
from ..protocol import od as odm
from ..protocol.pdo import INVALID, read_pdo_params
from ..protocol.sdo import (
    ABORT_COMMAND,
    ABORT_DEVICE_STATE,
    ABORT_GENERAL,
    ABORT_LENGTH,
    ABORT_NO_OBJECT,
    ABORT_NO_SUB,
    ABORT_PARAM_INCOMPATIBLE,
    ABORT_PDO_LENGTH,
    ABORT_PDO_MAPPING,
    ABORT_READ_ONLY,
    ABORT_STORE,
    ABORT_VALUE_RANGE,
    ABORT_WRITE_ONLY,
    SdoAbortError,
)

if TYPE_CHECKING:
    from .app import Application
    from .cycle import Controller, CycleRecord

EDS = data_path("eds", "cantrack-controller.eds")



#: 1000h-1FFFh objects a PLC may write (the rest is set by the bus configuration)
_WRITABLE_COMM = set(range(0x1400, 0x1600)) | set(range(0x1600, 0x1800)) \
    | set(range(0x1800, 0x1A00)) | set(range(0x1A00, 0x1C00))

ENGAGE_VALUES = (int(Mode.OFF), int(Mode.ABSOLUTE), int(Mode.RELATIVE))


@dataclass
class PdoChannel:
    """One PDO as configured by its communication and mapping objects."""

    number: int
    cob_id: int
    transmission: int
    inhibit_ns: int
    event_ns: int
    mapping: list[tuple[int, int, int]]
    last_data: bytes | None = None
    last_sent_ns: int | None = None
    sent: int = 0
    sync_count: int = 0


class PlcNode:
    """The controller's own CANopen node (see the module docstring)."""

    def __init__(self, ctl: Controller, app: Application | None = None, eds: str | Path = EDS,
                 node_id: int | None = None) -> None:
        self.ctl = ctl
        self.app = app if app is not None else ctl.app
        self.node_id = int(node_id if node_id is not None else ctl.cfg.master.node_id)
        self.od = odm.load_od(eds, self.node_id)
        self.transport = ctl.transport
        self.clock = ctl.clock
        self._store: dict[tuple[int, int], bytes] = {}
        self._vars: dict[tuple[int, int], ODVariable] = {}
        for obj in self.od.values():
            subs = [obj] if isinstance(obj, ODVariable) else list(obj.values())
            for v in subs:
                key = (v.index, v.subindex)
                self._vars[key] = v
                value = odm.default_value(v)
                if value is not None:
                    self._store[key] = self._encode(v, value)
        m = ctl.cfg.master
        self.put(0x1006, 0, int(m.sync_period_us))
        self.put(0x1019, 0, int(m.sync_overflow))
        self.put(0x1017, 0, int(m.heartbeat_producer_ms or 0))
        self._init_sync_limits()
        #: PLC item triggers received (rising edges of 2004h bit 0)
        self.triggers = 0
        self.trigger_times: list[int] = []
        #: engage commands applied: (t_ns, value)
        self.commands: list[tuple[int, int]] = []
        self.sdo_requests = 0
        self.aborts: list[tuple[int, int, int]] = []  # (index, sub, code)
        self._rpdo_engage = 0
        self.tpdos: list[PdoChannel] = []
        self.rpdos: dict[int, PdoChannel] = {}
        self._pdo_dirty = True
        self._rebuild_pdos()
        self.transport.subscribe(0x600 + self.node_id, self._on_sdo)
        self._chained: Callable | None = ctl.on_cycle
        ctl.on_cycle = self._on_cycle

    # -- object storage ----------------------------------------------------------------------
    @staticmethod
    def _encode(v: ODVariable, value: Any) -> bytes:
        fmt = odm.STRUCT_FORMAT.get(v.data_type)
        if fmt is not None:
            if v.data_type not in (REAL32, REAL64):
                value = int(value)
            return struct.pack("<" + fmt, value)
        return v.encode_raw(value)

    @staticmethod
    def _decode(v: ODVariable, raw: bytes) -> Any:
        fmt = odm.STRUCT_FORMAT.get(v.data_type)
        if fmt is not None:
            return struct.unpack("<" + fmt, raw)[0]
        return v.decode_raw(raw)

    def var(self, index: int, sub: int = 0) -> ODVariable | None:
        return self._vars.get((index, sub))

    def put(self, index: int, sub: int, value: Any) -> None:
        """Store a value (the application side: no access checks, no actions)."""
        v = self._vars[(index, sub)]
        self._store[(index, sub)] = self._encode(v, value)

    def get(self, index: int, sub: int = 0) -> Any:
        v = self._vars[(index, sub)]
        raw = self._store.get((index, sub))
        return 0 if raw is None else self._decode(v, raw)

    def _init_sync_limits(self) -> None:
        tr = getattr(self.ctl.tc, "tracker", None)
        lim = getattr(tr, "sync_trans", None)
        if lim is not None:
            for sub, name in ((1, "vel"), (2, "acc"), (3, "jerk")):
                value = getattr(lim, name, None)
                if value is not None and (0x2010, sub) in self._vars:
                    self.put(0x2010, sub, float(value))

    # -- SDO server ---------------------------------------------------------------------------
    def _on_sdo(self, can_id: int, data: bytes, t_ns: int) -> None:
        if len(data) < 8:
            return
        self.sdo_requests += 1
        ccs = data[0] >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        if ccs == 4:  # abort from the client: nothing in progress
            return
        try:
            if ccs == 2:
                resp = self._upload(index, sub)
            elif ccs == 1:
                resp = self._download(data, index, sub)
            else:
                raise SdoAbortError(ABORT_COMMAND)
        except SdoAbortError as exc:
            self.aborts.append((index, sub, exc.code))
            resp = struct.pack("<BHBI", 0x80, index, sub, exc.code)
        self.transport.send(0x580 + self.node_id, resp)

    def _lookup(self, index: int, sub: int) -> ODVariable:
        v = self._vars.get((index, sub))
        if v is None:
            raise SdoAbortError(ABORT_NO_SUB if index in self.od else ABORT_NO_OBJECT)
        return v

    def _upload(self, index: int, sub: int) -> bytes:
        v = self._lookup(index, sub)
        if v.access_type == "wo":
            raise SdoAbortError(ABORT_WRITE_ONLY)
        raw = self._store.get((index, sub))
        if raw is None:
            raw = bytes(odm.size_bytes(v))
        n = len(raw)
        if not 1 <= n <= 4:
            raise SdoAbortError(ABORT_GENERAL)  # (no such object in this EDS)
        return struct.pack("<BHB", 0x43 | ((4 - n) << 2), index, sub) + raw + bytes(4 - n)

    def _download(self, data: bytes, index: int, sub: int) -> bytes:
        cmd = data[0]
        v = self._lookup(index, sub)
        if v.access_type in ("ro", "const"):
            raise SdoAbortError(ABORT_READ_ONLY)
        if not cmd & 0x02:
            raise SdoAbortError(ABORT_COMMAND)  # segmented download: not needed (1-4 bytes)
        size = odm.size_bytes(v)
        n = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else size
        if n != size:
            raise SdoAbortError(ABORT_LENGTH)
        raw = bytes(data[4:4 + n])
        value = self._decode(v, raw)
        self._check_range(v, value)
        self._on_write(index, sub, value, raw)
        self._store[(index, sub)] = raw
        return struct.pack("<BHB", 0x60, index, sub) + bytes(4)

    @staticmethod
    def _check_range(v: ODVariable, value: Any) -> None:
        if v.data_type in (REAL32, REAL64):
            if math.isnan(value):
                raise SdoAbortError(ABORT_VALUE_RANGE)
            return
        lo, hi = getattr(v, "min", None), getattr(v, "max", None)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise SdoAbortError(ABORT_VALUE_RANGE)

    def _on_write(self, index: int, sub: int, value: Any, raw: bytes) -> None:
        """Check and act on an SDO write (raise SdoAbortError to refuse; stored afterwards)."""
        if index < 0x2000:
            if index not in _WRITABLE_COMM:
                raise SdoAbortError(ABORT_STORE)
            self._check_pdo_write(index, sub, value)
            self._pdo_dirty = True
        elif index == 0x2005:
            if value not in ENGAGE_VALUES:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            if self.ctl.tracker is None:
                raise SdoAbortError(ABORT_DEVICE_STATE)
            self._engage(value)  # (an SDO write is an explicit command: acts every time)
        elif index == 0x2004:
            if value > 1:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            self._trigger_input(value)
        elif index == 0x2010:
            tr = self.ctl.tracker
            state = self.app.status().track_state  # (the demo's robot group)
            if state is None and tr is not None:
                state = tr.state
            if state is not None and state is not TrackState.OFF:
                raise SdoAbortError(ABORT_DEVICE_STATE)
            if not value > 0:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            # stored only: the running tracker's limits are not changed yet
            raise SdoAbortError(ABORT_STORE)

    def _check_pdo_write(self, index: int, sub: int, value: int) -> None:
        """CiA 301: a mapping is written while its PDO is invalid and its sub 0 is 0."""
        if 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
            comm = index - 0x200
            if not int(self.get(comm, 1)) & INVALID:
                raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
            if sub == 0:
                total = sum(int(self.get(index, i)) & 0xFF for i in range(1, value + 1))
                if total > 64:
                    raise SdoAbortError(ABORT_PDO_LENGTH)
                return
            if int(self.get(index, 0)) != 0:
                raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
            obj, osub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
            if obj >= 0x1000:
                var = self._vars.get((obj, osub))
                if var is None or not var.pdo_mappable or len(var) != bits:
                    raise SdoAbortError(ABORT_PDO_MAPPING)

    # -- commands -----------------------------------------------------------------------------
    def _engage(self, value: int) -> None:
        ctl = self.ctl
        self.commands.append((self.clock.now_ns(), value))
        if self.app.engage(ctl, Mode(value)):
            return
        tr = ctl.tracker
        if tr is None:
            return
        if value == Mode.OFF:
            tr.disengage()
        else:
            tr.engage(Mode(value))

    def _trigger_input(self, value: int) -> None:
        old = int(self.get(0x2004)) & 1
        if value & 1 and not old:
            t = self.clock.now_ns()
            self.triggers += 1
            self.trigger_times.append(t)
            if not self.app.trigger(t):  # (else counted by the application's item sensor)
                self.put(0x2003, 0, self.item_count() & 0xFFFFFFFF)

    def _on_rpdo(self, can_id: int, data: bytes, t_ns: int) -> None:
        pdo = self.rpdos.get(can_id)
        if pdo is None:
            return
        offset = 0
        for index, sub, bits in pdo.mapping:
            n = bits // 8
            raw = bytes(data[offset:offset + n])
            offset += n
            if index < 0x1000 or len(raw) < n:
                continue
            v = self._vars.get((index, sub))
            if v is None:
                continue
            value = self._decode(v, raw)
            if index == 0x2005:
                if value not in ENGAGE_VALUES or self.ctl.tracker is None:
                    continue  # (a PDO cannot be refused: ignored, 2005h keeps its value)
                if value != self._rpdo_engage:  # (a PDO acts on a change of value)
                    self._engage(value)
                self._rpdo_engage = value
            elif index == 0x2004:
                self._trigger_input(value & 1)
            self._store[(index, sub)] = raw

    # -- PDOs ---------------------------------------------------------------------------------
    def _read_pdo(self, comm: int, number: int) -> PdoChannel | None:
        if (comm, 1) not in self._vars:
            return None
        p = read_pdo_params(self.get, lambda i, s: (i, s) in self._vars, comm, tpdo=True)
        if p is None:
            return None
        return PdoChannel(number, p.cob_id, p.transmission, p.inhibit_ns, p.event_ns, p.mapping)

    def _rebuild_pdos(self) -> None:
        for cob in self.rpdos:
            self.transport.unsubscribe(cob, self._on_rpdo)
        old = {p.number: p for p in self.tpdos}
        self.rpdos = {}
        self.tpdos = []
        for i in range(512):
            p = self._read_pdo(0x1400 + i, i + 1)
            if p is not None:
                self.rpdos[p.cob_id] = p
                self.transport.subscribe(p.cob_id, self._on_rpdo)
            p = self._read_pdo(0x1800 + i, i + 1)
            if p is not None:
                prev = old.get(p.number)
                if prev is not None and prev.cob_id == p.cob_id:
                    p.last_sent_ns, p.last_data, p.sent = \
                        prev.last_sent_ns, prev.last_data, prev.sent
                self.tpdos.append(p)
        self._pdo_dirty = False

    def tpdo_data(self, pdo: PdoChannel) -> bytes:
        out = bytearray()
        for index, sub, bits in pdo.mapping:
            raw = self._store.get((index, sub)) if index >= 0x1000 else None
            out += raw if raw is not None else bytes(bits // 8)
        return bytes(out)

    def service_tpdos(self, now: int) -> None:
        """Send the event-driven TPDOs that changed (inhibit time passed) or timed out."""
        if self._pdo_dirty:
            self._rebuild_pdos()
        for pdo in self.tpdos:
            t = pdo.transmission
            if t <= 240:  # synchronous: this cycle's SYNC is the controller's own
                data = self.tpdo_data(pdo)
                pdo.sync_count += 1
                if (t == 0 and data != pdo.last_data) or (t > 0 and pdo.sync_count >= t):
                    pdo.sync_count = 0
                    self._send_tpdo(pdo, data, now)
                continue
            if t < 254:
                continue  # (241-251 reserved, 252/253 RTR-only: not supported)
            data = self.tpdo_data(pdo)
            last = pdo.last_sent_ns
            timer = bool(pdo.event_ns) and (last is None or now - last >= pdo.event_ns)
            changed = data != pdo.last_data
            if not (changed or timer):
                continue
            if last is not None and now - last < pdo.inhibit_ns:
                continue  # (a change waits for the inhibit time: sent at a later cycle)
            self._send_tpdo(pdo, data, now)

    def _send_tpdo(self, pdo: PdoChannel, data: bytes, now: int) -> None:
        self.transport.send(pdo.cob_id, data)
        pdo.last_data = data
        pdo.last_sent_ns = now
        pdo.sent += 1

    # -- the cycle ------------------------------------------------------------------------------
    def update(self, rec: CycleRecord) -> None:
        """2000h-2003h, 2006h-2008h from this cycle."""
        ctl = self.ctl
        tr = ctl.tracker
        self.put(0x2000, 0, rec.state)  # (the application's state if it has one)
        self.put(0x2001, 0, rec.imfs)  # (the application's IMFS if it has one)
        self.put(0x2002, 0, int(tr.error) if tr is not None else rec.error)
        self.put(0x2003, 0, self.item_count() & 0xFFFFFFFF)
        self.put(0x2006, 0, self.items_missed() & 0xFFFFFFFF)
        self.put(0x2007, 0, float(ctl.last_tracking_error))
        self.put(0x2008, 0, float(rec.belt_vel) if rec.belt_vel is not None else 0.0)

    def item_count(self) -> int:
        detected = self.app.status().items_detected
        if detected is not None:
            return detected  # the application's item sensor, PLC triggers included
        return self.triggers

    def items_missed(self) -> int:
        return self.app.status().items_missed

    def _on_cycle(self, ctl: Controller, rec: CycleRecord) -> None:
        if self._chained is not None:
            self._chained(ctl, rec)
        self.update(rec)
        self.service_tpdos(self.clock.now_ns())

    def close(self) -> None:
        """Leave the bus: unsubscribe and restore the controller's callback."""
        self.transport.unsubscribe(0x600 + self.node_id, self._on_sdo)
        for cob in self.rpdos:
            self.transport.unsubscribe(cob, self._on_rpdo)
        if self.ctl.on_cycle == self._on_cycle:
            self.ctl.on_cycle = self._chained
