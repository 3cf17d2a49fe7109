"""The one CiA 301 slave-node engine: object dictionary, NMT slave, heartbeat producer and
consumer, SDO server (expedited and segmented), PDOs, EMCY.

Every CANopen node cantrack plays uses it: the simulated drive and encoder
(:mod:`.node` adds fault injection, :mod:`.drive`/:mod:`.encoder` the device models) and the
controller's own node for a PLC (:mod:`.plc`).  The engine owns no thread and no bus: it
sits on a :class:`SlaveBus` (``send``/``subscribe``/``unsubscribe`` + ``clock``: the
controller's transport or a device rack's port) and its host calls :meth:`SlaveEngine.on_timer`
when :meth:`SlaveEngine.next_timer_ns` falls due (the rack's timers; the controller's cycle).

What python canopen gives and what is added here, and why:

- storage and the SDO protocol are python canopen's ``LocalNode`` and ``SdoServer``
  (expedited and segmented upload/download; block transfers are refused, 05040001h).  Only
  public API is used: :class:`~.sdo_server.EngineNode` overrides
  ``LocalNode.get_data``/``set_data`` (the two calls the server makes), so the engine's
  checks run on every SDO access and canopen's ``NmtSlave`` (which would start a python-can
  periodic heartbeat thread on a 1017h write) is never called;
  :class:`~.sdo_server.EngineSdoServer` (both in :mod:`.sdo_server`, not compiled) overrides
  ``on_request``/``send_response`` to answer on the engine's bus, to refuse a segmented download at its first frame (not after the last
  segment), and to answer a segment that belongs to no transfer with 05040001h (canopen
  would fail on its empty buffer);
- checks on every SDO write (CiA 301 / CANopenNode's rules): access (06010002h), length
  (06070010h), EDS LowLimit/HighLimit (06090030h), COB-IDs of PDOs and EMCY (bits 11-29 set,
  a restricted CAN-ID, a changed CAN-ID while the PDO is valid, a valid PDO without mapping:
  06090030h; an ID that :meth:`SlaveEngine.cob_id_conflict` names: 08000000h), PDO
  transmission types 241-253 (06090030h: no RTR), mapping writes only while the PDO is
  invalid and its sub 0 is 0 (06040043h), mappable objects of the right size (06040041h),
  at most 64 bits (06040042h);
- NMT slave: power-on / reset node / reset communication -> boot-up message after
  ``boot_delay_ns`` -> PRE-OPERATIONAL; start, stop, enter pre-operational.  Reset node
  restores every object to its EDS default, reset communication 1000h-1FFFh only.  SDO is
  served in PRE-OPERATIONAL and OPERATIONAL, PDOs only in OPERATIONAL;
- heartbeat producer (1017h ms) on the engine's clock; consumer (1016h entries
  ``node-ID << 16 | ms``): a producer is *present* from its first heartbeat until one is
  overdue (:meth:`on_heartbeat_lost`, :meth:`on_heartbeat_back`);
- PDOs from 1400h-1BFFh as configured: RPDOs of types 0-240 are applied at the next SYNC,
  254/255 at once; TPDOs of type 0 go out at a SYNC when a mapped object changed since the
  last one, 1-240 at every n-th SYNC (from the SYNC counter = 18xxh:6 when both are set),
  254/255 on a change (inhibit time 18xxh:3 respected) and on the event timer 18xxh:5;
  the synchronous ones only within the synchronous window 1007h after their SYNC (served
  later: discarded, as CANopenNode does); a device samples at the SYNC's bus time;
- EMCY producer with 1001h/1003h bookkeeping.

Per SYNC (issue 12: the simulated devices share the controller's process) the work is
prepared when the configuration changes, not at every frame: each PDO's mapping is compiled
into a plan when the PDOs are read again (after a write to 1400h-1BFFh or 1007h, an NMT
change or a reset), the PDOs are indexed by what serves them (a SYNC touches the
synchronous ones only), :meth:`SlaveEngine.service_event_pdos` returns at once while no
object changed and no event timer or inhibit time is pending, and
:meth:`SlaveEngine.next_timer_ns` is cached for the nodes that declare it
(:attr:`SlaveEngine.cache_timers`) until :meth:`SlaveEngine._retime`.

Subclasses implement the hooks at the end of :class:`SlaveEngine`.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any, ClassVar, Protocol

from canopen.objectdictionary import (
    NUMBER_TYPES,
    REAL32,
    REAL64,
    ObjectDictionary,
    ODVariable,
)

from ...tracking.values import mypyc_attr
from ..io.clock import Clock
from ..protocol import od as odm
from ..protocol.pdo import INVALID
from ..protocol.sdo import (
    ABORT_GENERAL,
    ABORT_LENGTH,
    ABORT_NO_OBJECT,
    ABORT_NO_SUB,
    ABORT_PARAM_INCOMPATIBLE,
    ABORT_PDO_LENGTH,
    ABORT_PDO_MAPPING,
    ABORT_READ_ONLY,
    ABORT_VALUE_RANGE,
    ABORT_WRITE_ONLY,
    SdoAbortError,
)
from .sdo_server import EngineNode, EngineSdoServer

#: CiA 301 "data cannot be transferred or stored because of local control" (the node is
#: not under its commander's control)
ABORT_LOCAL_CONTROL = 0x08000021

#: CiA 301 EMCY: unexpected SYNC data length (the counter against 1019h)
EMCY_SYNC_LENGTH = 0x8240

#: COB-ID bits 11-29 must be 0 (11-bit identifiers only; bit 30 is RTR/"no RTR" for PDOs)
COB_ID_RESERVED_BITS = 0x3FFFF800


class Nmt(IntEnum):
    """NMT states (the heartbeat byte, CiA 301 table 59)."""

    INITIALISING = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


# (module constants for the per-SYNC paths: a global instead of a class attribute lookup)
_INITIALISING, _STOPPED, _OPERATIONAL = Nmt.INITIALISING, Nmt.STOPPED, Nmt.OPERATIONAL


def restricted_can_id(can_id: int) -> bool:
    """CiA 301 restricted CAN-IDs (not for SYNC, TIME, EMCY, PDO, SDO): 000h-07Fh,
    101h-180h, 581h-5FFh, 601h-67Fh, 6E0h-6FFh, 701h-7FFh (CANopenNode's
    ``CO_IS_RESTRICTED_CAN_ID``)."""
    return (can_id <= 0x7F or 0x101 <= can_id <= 0x180 or 0x581 <= can_id <= 0x5FF
            or 0x601 <= can_id <= 0x67F or 0x6E0 <= can_id <= 0x6FF or can_id >= 0x701)


Receiver = Callable[[int, bytes, int], None]

_NOTHING = object()  #: no value stored by a StorePlan yet


class StorePlan:
    """:meth:`SlaveEngine.store_plan`: (index, sub, (index, sub), pack, value made an int
    first) of each object, and (value, the bytes object stored) of each as last stored."""

    __slots__ = ("items", "last")

    def __init__(self, items: tuple[tuple[int, int, tuple[int, int],
                                          Callable[[Any], bytes], bool], ...]) -> None:
        self.items = items
        self.last: list[tuple[Any, Any]] = [(_NOTHING, _NOTHING)] * len(items)


class TimerHost(Protocol):
    """A host that caches the earliest timer of its nodes (the device rack): told by each
    node whose timers may have changed (:attr:`SlaveEngine.timer_host`)."""

    def retime(self) -> None: ...


class SlaveBus(Protocol):
    """What the engine needs of its bus (a transport, a port)."""

    clock: Clock

    def send(self, can_id: int, data: bytes | bytearray) -> None: ...

    def subscribe(self, can_id: int, callback: Receiver) -> None: ...

    def unsubscribe(self, can_id: int, callback: Receiver | None = None) -> None: ...


@dataclass
class PdoChannel:
    """One PDO of the node as its communication and mapping objects configure it."""

    kind: str  # "rpdo" | "tpdo"
    number: int  # 1-based
    cob_id: int
    transmission: int
    inhibit_ns: int
    event_ns: int
    sync_start: int
    mapping: list[tuple[int, int, int]]
    objects: frozenset[tuple[int, int]] = frozenset()
    pending: bytes | None = None  # RPDO data waiting for the next SYNC
    last_data: bytes | None = None  # TPDO: last sent data
    last_sent_ns: int | None = None
    sync_count: int = 0
    started: bool = True  # TPDO with a SYNC start value: False until the counter matches
    dirty: bool = True  # TPDO: a mapped object changed since the last send
    sent: int = 0
    size: int = 0  # [bytes] the mapping's length
    #: the mapping compiled when the PDO is (re)read (:meth:`SlaveEngine._read_pdo`):
    #: RPDO: (index, sub, first byte, end byte, (index, sub)) of each object, the dummy
    #: entries left out; TPDO: (index, sub, padding) of each entry (padding: the zero
    #: bytes of a dummy entry, else None)
    rplan: tuple[tuple[int, int, int, int, tuple[int, int]], ...] = ()
    tplan: tuple[tuple[int, int, bytes | None], ...] = ()


@dataclass
class _Consumer:
    producer: int
    timeout_ns: int
    last_ns: int | None = None
    lost: bool = False
    state: int | None = None  # the producer's NMT state in its last heartbeat


@mypyc_attr(allow_interpreted_subclasses=True)  # (PlcNode and tests subclass it in Python)
class SlaveEngine:
    """One CANopen slave node (see the module docstring)."""

    kind = "node"

    #: :meth:`next_timer_ns` is cached until :meth:`_retime` (True: the subclass's
    #: ``listening``, ``may_send`` and ``device_timer_ns`` change only inside the engine's
    #: entry points -- frames, ``on_timer``, ``reset``, ``set_nmt`` -- or where it calls
    #: :meth:`_retime`; a subclass that cannot say so keeps False: asked every time)
    cache_timers: ClassVar[bool] = False

    def __init__(self, name: str, eds: str | Path | ObjectDictionary, node_id: int,
                 bus: SlaveBus, *, boot_delay_ns: int = 5_000_000,
                 heartbeat_producer: bool = True, sync_cob_id: int | None = 0x80) -> None:
        self.name = name
        self.node_id = int(node_id)
        self.bus = bus
        self.clock: Clock = bus.clock
        self.od = eds if isinstance(eds, ObjectDictionary) else odm.load_od(eds, node_id)
        self.heartbeat_producer = heartbeat_producer
        self._vars: dict[tuple[int, int], ODVariable] = {}
        self._codecs: dict[tuple[int, int], tuple[struct.Struct | None, ODVariable]] = {}
        self._packers: dict[tuple[int, int], tuple[Callable[[Any], bytes], bool]] = {}
        #: (the raw 1019h the SYNC length was last checked against, the length it wants;
        #: None: no 1019h) -- see _sync_length_ok
        self._sync_len: tuple[bytes | None, int | None] | None = None
        self._changed: set[tuple[int, int]] = set()  # objects changed since the last service
        self.node = EngineNode(self, self.node_id, self.od)
        self.sdo = EngineSdoServer(self, self.node)
        self.node.sdo = self.sdo
        self.boot_delay_ns = int(boot_delay_ns)
        self.nmt_state = Nmt.INITIALISING
        self._boot_at: int | None = self.clock.now_ns() + self.boot_delay_ns
        self._hb_next: int | None = None
        self._consumers: dict[int, _Consumer] = {}
        self.rpdos: dict[int, PdoChannel] = {}
        self.tpdos: list[PdoChannel] = []
        # the PDOs by what serves them (built with them, _rebuild_pdos): the RPDOs applied
        # at a SYNC (types 0-240), the TPDOs sent at a SYNC (0-240), the event-driven TPDOs
        # (254/255) and the TPDOs that send on a change (0, 254/255: their ``dirty``)
        self._sync_rpdos: list[PdoChannel] = []
        self._sync_tpdos: list[PdoChannel] = []
        self._event_tpdos: list[PdoChannel] = []
        self._change_tpdos: list[PdoChannel] = []
        #: the objects the _change_tpdos map (a change of another object makes none dirty)
        self._watched: frozenset[tuple[int, int]] = frozenset()
        #: when service_event_pdos has work without a change [ns] (None: never; see there)
        self._event_due: int | None = -1
        #: on_rpdo_data is the engine's own (every value stored: the mapping's plan applied)
        self._plain_rpdo_data = type(self).on_rpdo_data is SlaveEngine.on_rpdo_data
        self._pdo_dirty = True
        #: the next timer's cache: (the _due_gen it was computed at, the time); a change of
        #: the timers increments _due_gen (_retime) -- a count, not a flag, so that a
        #: change from another thread while it is computed is never overwritten
        self._due_gen = 0
        self._due: tuple[int, int | None] = (-1, None)
        #: told when this node's timers may have changed (a host caching over its nodes)
        self.timer_host: TimerHost | None = None
        #: the last 1000 EMCYs sent: (code, ns) (a long run's faults do not fill the memory)
        self.emcy_sent: deque[tuple[int, int]] = deque(maxlen=1000)
        self.sync_counter: int | None = None
        self.sync_cob_id = sync_cob_id
        #: 1007h synchronous window length [ns] (0: none; read with the PDOs)
        self.sync_window_ns = 0
        #: synchronous TPDOs not sent because their SYNC was served after the window
        self.sync_tpdos_discarded = 0
        #: set by a host that serves frames late (the device rack in a thread) while it
        #: hands over a SYNC behind which the next SYNC [bus time, ns] is already in: this
        #: SYNC's synchronous TPDOs would follow the next SYNC on the bus (discarded)
        self.next_sync_ns: int | None = None
        bus.subscribe(0x600 + self.node_id, self._on_sdo_frame)
        bus.subscribe(0x000, self._on_nmt)
        if sync_cob_id is not None:
            bus.subscribe(sync_cob_id, self._on_sync_frame)

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

    def _subs(self, index: int) -> list[int]:
        """The sub-indices of a record/array object (``[0]`` for a plain variable)."""
        obj = self.od[index]
        return [0] if isinstance(obj, ODVariable) else list(obj.subindices)

    def has(self, index: int, sub: int = 0) -> bool:
        key = (index, sub)
        v = self._vars.get(key)  # (the object dictionary's structure does not change)
        if v is None:
            v = odm.variable(self.od, index, sub)
            if v is None:
                return False
            self._vars[key] = v
        return True

    def _codec(self, index: int, sub: int) -> tuple[struct.Struct | None, ODVariable]:
        key = (index, sub)
        c = self._codecs.get(key)
        if c is None:
            v = self.var(index, sub)
            fmt = odm.STRUCT_FORMAT.get(v.data_type) if v.data_type is not None else None
            c = (struct.Struct("<" + fmt) if fmt else None, v)
            self._codecs[key] = c
        return c

    def encode(self, index: int, sub: int, value: Any) -> bytes:
        st, v = self._codec(index, sub)
        if st is None:
            return v.encode_raw(value)
        if v.data_type not in (REAL32, REAL64):
            value = int(value)
        return st.pack(value)

    def decode(self, index: int, sub: int, raw: bytes) -> Any:
        st, v = self._codec(index, sub)
        return st.unpack(raw)[0] if st is not None else v.decode_raw(raw)

    def _packer(self, key: tuple[int, int]) -> tuple[Callable[[Any], bytes], bool]:
        """How :meth:`encode` makes an object's bytes: (pack, value made an int first)."""
        st, v = self._codec(*key)
        c = (v.encode_raw, False) if st is None else (st.pack, v.data_type not in (REAL32,
                                                                                 REAL64))
        self._packers[key] = c
        return c

    def store(self, index: int, sub: int, value: Any) -> None:
        """Set an object's value from the application (no SDO checks, no callbacks)."""
        key = (index, sub)
        c = self._packers.get(key)  # (encode() with its lookups made once per object)
        pack, whole = c if c is not None else self._packer(key)
        raw = pack(int(value)) if whole else pack(value)
        ds = self.node.data_store
        d = ds.get(index)  # (setdefault without its empty dict made for every call)
        if d is None:
            d = ds[index] = {}
        if d.get(sub) != raw:
            d[sub] = raw
            self._changed.add(key)

    def store_plan(self, keys: tuple[tuple[int, int], ...]) -> StorePlan:
        """:meth:`store` of the objects ``keys`` (index, sub) compiled once, for
        :meth:`store_all` (a device's values of every SYNC)."""
        return StorePlan(tuple((index, sub, (index, sub), *(self._packers.get((index, sub))
                                                            or self._packer((index, sub))))
                               for index, sub in keys))

    def store_all(self, plan: StorePlan, values: tuple[Any, ...]) -> None:
        """:meth:`store` of each value of ``values`` into its object of ``plan``.

        An integer value equal to the one this plan stored last is not packed again while
        the object still holds the very bytes object stored then (anything else that wrote
        it -- :meth:`store`, an SDO write, an RPDO, a reset -- put another one there).  Each
        (value, bytes) pair is kept as one tuple: with two threads storing at once
        (``cantrack sim-devices``' injections beside its device thread) no pair is torn."""
        ds = self.node.data_store
        changed = self._changed
        last = plan.last
        i = -1
        for (index, sub, key, pack, whole), value in zip(plan.items, values):
            i += 1
            d = ds.get(index)
            if d is None:
                d = ds[index] = {}
            held = d.get(sub)
            if whole:
                kept = last[i]
                if held is kept[1] and value == kept[0]:
                    continue
                raw = pack(int(value))
            else:
                raw = pack(value)
            if held != raw:
                d[sub] = raw
                changed.add(key)
                held = raw
            if whole:
                last[i] = (value, held)

    def raw(self, index: int, sub: int = 0) -> bytes:
        """An object's current value as bytes (stored, else the EDS default)."""
        d = self.node.data_store.get(index)
        raw = d.get(sub) if d is not None else None
        if raw is not None:
            return raw
        v = self.var(index, sub)
        value = odm.default_value(v)
        if value is None:
            return bytes(odm.size_bytes(v)) if v.data_type in NUMBER_TYPES else b""
        return self.encode(index, sub, value)

    def load(self, index: int, sub: int = 0) -> Any:
        """An object's current value (stored, else EDS default; REAL32 hex defaults too)."""
        d = self.node.data_store.get(index)
        raw = d.get(sub) if d is not None else None
        if raw is None:
            value = odm.default_value(self.var(index, sub))
            return 0 if value is None else value
        c = self._codecs.get((index, sub))  # (decode() written out)
        st, v = c if c is not None else self._codec(index, sub)
        return st.unpack(raw)[0] if st is not None else v.decode_raw(raw)

    # -- SDO server side --------------------------------------------------------------------
    def _find(self, index: int, sub: int) -> ODVariable:
        v = odm.variable(self.od, index, sub)
        if v is None:
            raise SdoAbortError(ABORT_NO_SUB if index in self.od else ABORT_NO_OBJECT)
        return v

    def _sdo_read(self, index: int, sub: int, check_readable: bool) -> bytes:
        v = self._find(index, sub)
        if check_readable and not v.readable:
            raise SdoAbortError(ABORT_WRITE_ONLY)
        self.check_read(index, sub)
        return self.raw(index, sub)

    def _check_write_access(self, index: int, sub: int) -> ODVariable:
        """The checks of a write that need no value (also at a segmented download's start)."""
        v = self._find(index, sub)
        if not v.writable:
            raise SdoAbortError(ABORT_READ_ONLY)
        self.check_access(index, sub)
        return v

    def _sdo_write(self, index: int, sub: int, data: bytes, check_writable: bool) -> None:
        v = self._check_write_access(index, sub) if check_writable else self._find(index, sub)
        if v.data_type in NUMBER_TYPES and 8 * len(data) != len(v):
            raise SdoAbortError(ABORT_LENGTH)
        value = self.decode(index, sub, data) if v.data_type in NUMBER_TYPES else data
        self._check_range(v, value)
        if 0x1000 <= index <= 0x1FFF:
            self._check_comm_write(index, sub, value)
        self.on_write(index, sub, value)
        store = self.node.data_store.setdefault(index, {})
        if store.get(sub) != data:
            store[sub] = data
            self._changed.add((index, sub))
        self._after_comm_write(index, sub, value)

    @staticmethod
    def _check_range(v: ODVariable, value: Any) -> None:
        if v.data_type in (REAL32, REAL64):
            if math.isnan(value):
                raise SdoAbortError(ABORT_VALUE_RANGE)
            return
        if not isinstance(value, int):
            return
        lo, hi = v.min, v.max
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise SdoAbortError(ABORT_VALUE_RANGE)

    def _check_comm_write(self, index: int, sub: int, value: Any) -> None:
        if (0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF):
            kind = "rpdo" if index < 0x1800 else "tpdo"
            if sub == 1:
                self._check_pdo_cob_id(kind, index, int(value))
            elif sub == 2 and 241 <= int(value) <= 253:
                raise SdoAbortError(ABORT_VALUE_RANGE)  # (no RTR: as CANopenNode)
            elif sub == 6 and kind == "tpdo" and (int(value) > 240
                                                  or not int(self.load(index, 1)) & INVALID):
                raise SdoAbortError(ABORT_VALUE_RANGE)  # (CANopenNode: while invalid)
        elif 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
            self._check_pdo_mapping(index, sub, int(value))
        elif index == 0x1014 and sub == 0:
            can_id = int(value) & 0x7FF
            if int(value) & 0x7FFFF800 or (not int(value) & INVALID and can_id != 0x80
                                          + self.node_id and restricted_can_id(can_id)):
                raise SdoAbortError(ABORT_VALUE_RANGE)

    def _check_pdo_cob_id(self, kind: str, comm: int, value: int) -> None:
        """CANopenNode's OD_write_14xx/18xx rules, then :meth:`cob_id_conflict`."""
        can_id = value & 0x7FF
        valid = not value & INVALID
        old = int(self.load(comm, 1))
        old_valid = not old & INVALID
        mapped = int(self.load(comm + 0x200, 0)) if self.has(comm + 0x200, 0) else 0
        if value & COB_ID_RESERVED_BITS or (valid and old_valid and can_id != old & 0x7FF) \
                or (valid and restricted_can_id(can_id)) or (valid and mapped == 0):
            raise SdoAbortError(ABORT_VALUE_RANGE)
        if valid and self.cob_id_conflict(kind, comm - (0x1400 if kind == "rpdo" else 0x1800)
                                          + 1, can_id) is not None:
            raise SdoAbortError(ABORT_GENERAL)

    def _check_pdo_mapping(self, index: int, sub: int, value: int) -> None:
        """CiA 301: a mapping is changed while its PDO is invalid and its sub 0 is 0."""
        comm = index - 0x200
        if not int(self.load(comm, 1)) & INVALID:
            raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
        if sub == 0:
            total = 0
            for i in range(1, value + 1):
                if not self.has(index, i):
                    raise SdoAbortError(ABORT_PDO_MAPPING)
                total += int(self.load(index, i)) & 0xFF
            if total > 64:
                raise SdoAbortError(ABORT_PDO_LENGTH)
            return
        if int(self.load(index, 0)) != 0:
            raise SdoAbortError(ABORT_PARAM_INCOMPATIBLE)
        obj, osub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if obj < 0x1000:
            return  # a dummy entry
        v = odm.variable(self.od, obj, osub)
        # an RPDO writes what it maps, a TPDO reads it: a read-only object (6064h) cannot be
        # mapped into an RPDO nor a write-only one into a TPDO (CiA 301: abort 0604 0041h,
        # "object cannot be mapped to the PDO"; CANopenNode's PDOconfigMap tests its
        # ODA_RPDO / ODA_TPDO attribute so)
        if v is None or not v.pdo_mappable or len(v) != bits \
                or not (v.writable if index < 0x1A00 else v.readable):
            raise SdoAbortError(ABORT_PDO_MAPPING)

    def _after_comm_write(self, index: int, sub: int, value: Any) -> None:
        self._retime()
        if 0x1400 <= index <= 0x1BFF or index == 0x1007:
            self._pdo_dirty = True
        elif index == 0x1017:
            ms = int(value)
            now = self.clock.now_ns()
            self._hb_next = now + ms * 1_000_000 if ms and self.nmt_state else None
        elif index == 0x1016:
            self._load_consumers()

    # -- sending ------------------------------------------------------------------------------
    def _send(self, kind: str, can_id: int, data: bytes) -> None:
        """Every frame of the node goes out here (``kind``: nmt, hb, sdo, pdo, emcy)."""
        if self.may_send(kind):
            self.bus.send(can_id, data)

    def send_emcy(self, code: int, register: int | None = None, data: bytes = b"") -> None:
        """Send an EMCY (error code ``code``), updating 1001h and 1003h."""
        if register is None:
            register = 0 if code == 0 else (0x01 | (0x80 if code >> 12 in (8, 15) else 0))
        self.store(0x1001, 0, register)
        if code != 0 and 0x1003 in self.od:
            n = int(self.load(0x1003, 0))
            depth = max(s for s in self._subs(0x1003))
            history = [int(self.load(0x1003, i)) for i in range(1, min(n, depth) + 1)]
            history = [code] + history[: depth - 1]
            for i, value in enumerate(history, start=1):
                self.store(0x1003, i, value)
            self.store(0x1003, 0, len(history))
        if self.nmt_state in (Nmt.PRE_OPERATIONAL, Nmt.OPERATIONAL):
            cob = int(self.load(0x1014, 0)) if self.has(0x1014) else 0x80 + self.node_id
            if not cob & INVALID:
                payload = struct.pack("<HB5s", code, register, bytes(data)[:5])
                self._send("emcy", cob & 0x7FF, payload)
        self.emcy_sent.append((code, self.clock.now_ns()))

    # -- NMT ----------------------------------------------------------------------------------
    def _on_sdo_frame(self, can_id: int, data: bytes, t: Any) -> None:
        if self.listening() and self.nmt_state in (Nmt.PRE_OPERATIONAL, Nmt.OPERATIONAL):
            self.sdo.on_request(can_id, data, t)
            self._retime()  # (a write may change what the device's timer depends on)

    def _on_nmt(self, can_id: int, data: bytes, t: Any) -> None:
        if not self.listening() or len(data) < 2:
            return
        cmd, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        if self.nmt_state is Nmt.INITIALISING and cmd not in (0x81, 0x82):
            return
        if cmd == 0x01:
            if self.accept_start():
                self.set_nmt(Nmt.OPERATIONAL)
        elif cmd == 0x02:
            self.set_nmt(Nmt.STOPPED)
        elif cmd == 0x80:
            self.set_nmt(Nmt.PRE_OPERATIONAL)
        elif cmd in (0x81, 0x82):
            self.reset(application=cmd == 0x81)
        self._retime()

    def set_nmt(self, state: Nmt) -> None:
        """Enter an NMT state (a command received, or the node's own decision)."""
        if state == self.nmt_state:
            return
        old = self.nmt_state
        self.nmt_state = state
        self._retime()
        if state is Nmt.OPERATIONAL:
            self._rebuild_pdos()
            for p in self.tpdos:
                p.sync_count = 0
                p.last_data = None
                p.started = not p.sync_start
        self.on_nmt(old, state)

    def reset(self, application: bool) -> None:
        """NMT reset node (``application``) or reset communication."""
        store = self.node.data_store
        for index in list(store):
            if application or 0x1000 <= index <= 0x1FFF:
                del store[index]
        old = self.nmt_state
        self.nmt_state = Nmt.INITIALISING
        self._hb_next = None
        for producer in list(self._consumers):
            self.bus.unsubscribe(0x700 + producer, self._on_heartbeat)
        self._consumers.clear()
        self._pdo_dirty = True
        for p in self.rpdos.values():
            self.bus.unsubscribe(p.cob_id, self._on_rpdo)
        self.rpdos.clear()
        self.tpdos.clear()
        self._index_pdos()
        self.sync_counter = None
        self.on_comm_reset()
        if application:
            self.on_reset()
        self._boot_at = self.clock.now_ns() + self.boot_delay_ns
        self._retime()
        self.on_nmt(old, Nmt.INITIALISING)

    def boot_now(self, send_boot_up: bool = True) -> None:
        """End the initialisation at once (the host node's own start-up)."""
        self._boot_up(self.clock.now_ns(), send_boot_up)

    def _boot_up(self, now: int, send_boot_up: bool = True) -> None:
        self._boot_at = None
        self._retime()
        old = self.nmt_state
        self.nmt_state = Nmt.PRE_OPERATIONAL
        if send_boot_up:
            self._send("nmt", 0x700 + self.node_id, b"\x00")
        self._schedule_heartbeat(now)
        self._load_consumers()
        self._rebuild_pdos()
        self.on_nmt(old, Nmt.PRE_OPERATIONAL)

    def _schedule_heartbeat(self, now: int) -> None:
        ms = int(self.load(0x1017, 0)) if self.heartbeat_producer and self.has(0x1017) else 0
        self._hb_next = now + ms * 1_000_000 if ms > 0 else None
        self._retime()

    # -- heartbeat consumer ---------------------------------------------------------------------
    def _load_consumers(self) -> None:
        self._retime()
        for producer in list(self._consumers):
            self.bus.unsubscribe(0x700 + producer, self._on_heartbeat)
        old = self._consumers
        self._consumers = {}
        if 0x1016 not in self.od:
            return
        for sub in self._subs(0x1016):
            if sub == 0:
                continue
            value = int(self.load(0x1016, sub))
            producer, ms = (value >> 16) & 0xFF, value & 0xFFFF
            if 1 <= producer <= 127 and ms:
                c = _Consumer(producer, ms * 1_000_000)
                prev = old.get(producer)
                if prev is not None:  # (a changed time keeps what was seen)
                    c.last_ns, c.lost, c.state = prev.last_ns, prev.lost, prev.state
                self._consumers[producer] = c
                self.bus.subscribe(0x700 + producer, self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data: bytes, t: Any) -> None:
        c = self._consumers.get(can_id - 0x700)
        if c is None or not self.listening() or not data:
            return
        back = c.lost
        c.last_ns = self.clock.now_ns()
        c.state = data[0]
        c.lost = False
        self._retime()
        if back:
            self.on_heartbeat_back(c.producer)

    def heartbeat_present(self, producer: int) -> bool:
        """A consumed producer (1016h) has been heard and its heartbeat is not overdue."""
        c = self._consumers.get(producer)
        if c is None or c.last_ns is None or c.lost:
            return False
        return self.clock.now_ns() < c.last_ns + c.timeout_ns

    def consumed(self, producer: int) -> int | None:
        """The consumer heartbeat time [ns] of ``producer`` (1016h), None if not consumed."""
        c = self._consumers.get(producer)
        return c.timeout_ns if c is not None else None

    # -- PDOs -------------------------------------------------------------------------------------
    def _rebuild_pdos(self) -> None:
        for pdo in self.rpdos.values():
            self.bus.unsubscribe(pdo.cob_id, self._on_rpdo)
        old = {p.number: p for p in self.tpdos}
        self.rpdos = {}
        self.tpdos = []
        for comm in range(0x1400, 0x1600):
            if comm in self.od:
                p = self._read_pdo("rpdo", comm)
                if p is not None:
                    self.rpdos[p.cob_id] = p
                    self.bus.subscribe(p.cob_id, self._on_rpdo)
        for comm in range(0x1800, 0x1A00):
            if comm in self.od:
                p = self._read_pdo("tpdo", comm)
                if p is not None:
                    prev = old.get(p.number)
                    if prev is not None and prev.cob_id == p.cob_id:
                        p.last_sent_ns, p.last_data, p.sent = \
                            prev.last_sent_ns, prev.last_data, prev.sent
                        p.sync_count, p.started = prev.sync_count, prev.started
                    self.tpdos.append(p)
        self._index_pdos()
        self.sync_window_ns = int(self.load(0x1007, 0)) * 1000 if self.has(0x1007) else 0
        self._pdo_dirty = False
        self._retime()

    def _index_pdos(self) -> None:
        """The PDOs by what serves them (see ``__init__``), in their order."""
        self._sync_rpdos = [p for p in self.rpdos.values() if p.transmission <= 240]
        self._sync_tpdos = [p for p in self.tpdos if p.transmission <= 240]
        self._event_tpdos = [p for p in self.tpdos if p.transmission >= 254]
        self._change_tpdos = [p for p in self.tpdos
                              if p.transmission == 0 or p.transmission >= 254]
        self._watched = frozenset().union(*(p.objects for p in self._change_tpdos))
        self._event_due = -1  # (the new TPDOs are dirty: served at the next service)

    def _read_pdo(self, kind: str, comm: int) -> PdoChannel | None:
        if int(self.load(comm, 1)) & INVALID:
            return None
        n = int(self.load(comm + 0x200, 0)) if self.has(comm + 0x200, 0) else 0
        mapping = []
        for i in range(1, n + 1):
            v = int(self.load(comm + 0x200, i))
            mapping.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
        if not mapping:
            return None
        tpdo = kind == "tpdo"
        inhibit = int(self.load(comm, 3)) * 100_000 if tpdo and self.has(comm, 3) else 0
        event = int(self.load(comm, 5)) * 1_000_000 if tpdo and self.has(comm, 5) else 0
        start = int(self.load(comm, 6)) if tpdo and self.has(comm, 6) else 0
        rplan = []
        offset = 0
        for index, sub, bits in mapping:
            n = bits // 8
            if index >= 0x1000:
                rplan.append((index, sub, offset, offset + n, (index, sub)))
            offset += n
        tplan = tuple((index, sub, bytes(bits // 8) if index < 0x1000 else None)
                      for index, sub, bits in mapping)
        return PdoChannel(kind, comm - (0x1800 if tpdo else 0x1400) + 1,
                          int(self.load(comm, 1)) & 0x7FF, int(self.load(comm, 2)), inhibit,
                          event, start, mapping,
                          objects=frozenset((i, s) for i, s, _ in mapping if i >= 0x1000),
                          started=not start, size=sum(bits for _, _, bits in mapping) // 8,
                          rplan=tuple(rplan), tplan=tplan)

    def _on_rpdo(self, can_id: int, data: bytes, t: Any) -> None:
        if not self.listening() or self.nmt_state is not _OPERATIONAL:
            return
        pdo = self.rpdos.get(can_id)
        if pdo is None:
            return
        if pdo.transmission <= 240:
            pdo.pending = bytes(data)
        else:
            self._apply_rpdo(pdo, bytes(data))
            self._retime()  # (on_rpdo acted at once)

    def _apply_rpdo(self, pdo: PdoChannel, data: bytes) -> None:
        if len(data) < pdo.size:
            return  # (CiA 301: a too short PDO is not processed; EMCY 8210h in real nodes)
        store = self.node.data_store
        changed = self._changed
        if self._plain_rpdo_data:  # (every value stored: the plan applied directly)
            for index, sub, start, end, key in pdo.rplan:
                raw = data[start:end]
                d = store.get(index)
                if d is None:
                    d = store[index] = {}
                if d.get(sub) != raw:
                    d[sub] = raw
                    changed.add(key)
        else:
            values = [(index, sub, data[start:end]) for index, sub, start, end, _ in pdo.rplan]
            for index, sub, raw in self.on_rpdo_data(pdo.number, values):
                d = store.get(index)
                if d is None:
                    d = store[index] = {}
                if d.get(sub) != raw:
                    d[sub] = raw
                    changed.add((index, sub))
        self.on_rpdo(pdo.number, pdo.objects)

    def tpdo_data(self, pdo: PdoChannel) -> bytes:
        store = self.node.data_store
        parts = []
        for index, sub, padding in pdo.tplan:
            if padding is not None:
                parts.append(padding)  # a dummy entry
                continue
            d = store.get(index)  # (raw() written out: the stored value, else the default)
            raw = d.get(sub) if d is not None else None
            parts.append(raw if raw is not None else self.raw(index, sub))
        return b"".join(parts)

    def _send_tpdo(self, pdo: PdoChannel, data: bytes, now: int) -> None:
        if self.may_send("pdo"):  # (_send written out)
            self.bus.send(pdo.cob_id, data)
        pdo.last_data = data
        pdo.last_sent_ns = now
        pdo.sent += 1
        pdo.dirty = False
        if pdo.event_ns:
            self._retime()  # (its event timer starts again)

    def _on_sync_frame(self, can_id: int, data: bytes, t: Any) -> None:
        if not self.listening():
            return
        c = self._sync_len  # (_sync_length_ok's answer while 1019h is the same object)
        if c is not None and (c[1] is None or len(data) == c[1]):
            d = self.node.data_store.get(0x1019)
            if c[0] is (d.get(0) if d is not None else None):
                self.process_sync(data[0] if data else None, t)
                return
        if not self._sync_length_ok(len(data)):
            self.sync_counter = data[0] if data else None
            return
        self.process_sync(data[0] if data else None, t)

    def _sync_length_ok(self, n: int) -> bool:
        """CiA 301: with 1019h > 0 a SYNC carries the counter (1 byte), else none; a consumer
        that gets another length sends EMCY 8240h (unexpected SYNC data length) and, as
        CANopenNode does, enters pre-operational.  (Objects without 1019h: not checked.)"""
        d = self.node.data_store.get(0x1019)
        raw = d.get(0) if d is not None else None
        c = self._sync_len
        if c is None or c[0] is not raw:  # (looked up again when 1019h is written)
            want = (1 if int(self.load(0x1019, 0)) else 0) if self.has(0x1019) else None
            c = self._sync_len = (raw, want)
        want = c[1]
        if want is None or n == want:
            return True
        if self.nmt_state is Nmt.OPERATIONAL:
            self.send_emcy(EMCY_SYNC_LENGTH)
            self.set_nmt(Nmt.PRE_OPERATIONAL)
        return False

    def process_sync(self, counter: int | None = None, t_ns: int | None = None) -> None:
        """A SYNC (received, or the host's own): synchronous RPDOs into the OD, the
        device's :meth:`on_sync`, then the synchronous and event TPDOs.

        ``t_ns``: when the SYNC was on the bus (the bus port's frame time; default now).
        The device samples at that time, as hardware latches its inputs at the SYNC's
        reception, even when its host serves the frame later (a simulated device in a
        thread waiting for the interpreter).  Served after the synchronous window (1007h,
        CiA 301: synchronous PDOs only within it after the SYNC) the synchronous TPDOs are
        discarded, as CANopenNode clears its pending synchronous TPDOs when the window has
        passed: a late answer is never taken for the next SYNC's (counted in
        ``sync_tpdos_discarded``).  Likewise when the host has the next SYNC already
        (:attr:`next_sync_ns`): a real device would have answered before it."""
        if not self.listening():
            return
        nmt = self.nmt_state
        if nmt is _INITIALISING or nmt is _STOPPED:
            return
        if self._pdo_dirty:
            self._rebuild_pdos()
        self.sync_counter = counter
        now = self.clock.now_ns()
        t_sync = now if t_ns is None or t_ns > now else t_ns
        window = self.sync_window_ns
        outside = (window > 0 and now - t_sync > window) or self.next_sync_ns is not None
        operational = nmt is _OPERATIONAL
        if operational:
            for pdo in self._sync_rpdos:  # (the RPDOs of types 0-240: only they wait)
                if pdo.pending is not None:
                    data, pdo.pending = pdo.pending, None
                    self._apply_rpdo(pdo, data)
        self.on_sync(t_sync)
        if not operational:
            self._changed.clear()
            return
        changed = self._changed
        for pdo in self._sync_tpdos:  # (types 0-240)
            t = pdo.transmission
            if t == 0 and changed and not changed.isdisjoint(pdo.objects):
                pdo.dirty = True  # (read by type 0 only)
            if not pdo.started:  # (CANopenNode: the first at the counter = 18xxh:6)
                if counter is not None and counter != pdo.sync_start:
                    continue
                pdo.started = True
                if counter is not None and t > 0:
                    pdo.sync_count = 0
                    if outside:
                        self.sync_tpdos_discarded += 1
                    else:
                        self._send_tpdo(pdo, self.tpdo_data(pdo), now)
                    continue
            if t == 0:  # acyclic synchronous: at the SYNC after a change
                if outside:  # (still to send: at the next SYNC served in its window)
                    if pdo.dirty or pdo.last_data is None:
                        self.sync_tpdos_discarded += 1
                    continue
                if pdo.dirty or pdo.last_data is None:
                    data = self.tpdo_data(pdo)
                    if data != pdo.last_data:
                        self._send_tpdo(pdo, data, now)
                    pdo.dirty = False
                continue
            pdo.sync_count += 1
            if pdo.sync_count >= t:
                pdo.sync_count = 0
                if outside:
                    self.sync_tpdos_discarded += 1
                else:
                    self._send_tpdo(pdo, self.tpdo_data(pdo), now)
        self.service_event_pdos(now)

    def service_event_pdos(self, now: int) -> None:
        """Send the event-driven TPDOs whose data changed or whose event timer expired."""
        if self._pdo_dirty:
            self._rebuild_pdos()
        changed = self._changed
        if self.nmt_state is not _OPERATIONAL or not self.may_send("pdo"):
            changed.clear()
            return
        if changed and not changed.isdisjoint(self._watched):
            for pdo in self._change_tpdos:  # (``dirty`` is read by types 0, 254, 255 only)
                if not changed.isdisjoint(pdo.objects):
                    pdo.dirty = True
            changed.clear()
        else:
            changed.clear()  # (no mapped object among them)
            due = self._event_due
            if due is None or now < due:
                return  # (no change, no dirty event TPDO, no event timer expired)
        events = self._event_tpdos
        for pdo in events:
            timer = bool(pdo.event_ns) and (pdo.last_sent_ns is None
                                            or now - pdo.last_sent_ns >= pdo.event_ns)
            if not (pdo.dirty or timer):
                continue
            if pdo.last_sent_ns is not None and now - pdo.last_sent_ns < pdo.inhibit_ns:
                continue  # (a change waits for the inhibit time: sent at a later service)
            data = self.tpdo_data(pdo)
            pdo.dirty = False
            if data != pdo.last_data or timer:
                self._send_tpdo(pdo, data, now)
        # when a service without a change has something to do: at once while a TPDO is
        # dirty (waiting for its inhibit time) or never sent with an event timer, else at
        # the earliest event timer
        due = None
        for pdo in events:
            last = pdo.last_sent_ns
            if pdo.dirty or (pdo.event_ns and last is None):
                due = -1
                break
            if pdo.event_ns and last is not None:
                t = last + pdo.event_ns
                if due is None or t < due:
                    due = t
        self._event_due = due

    # -- timers -----------------------------------------------------------------------------------
    def _retime(self) -> None:
        """The node's timers may have changed: :meth:`next_timer_ns` computes them again."""
        self._due_gen += 1
        host = self.timer_host
        if host is not None:
            host.retime()

    def next_timer_ns(self) -> int | None:
        """When :meth:`on_timer` is due next [ns] (None: no timer); cached with
        :attr:`cache_timers` (asked several times per frame batch by the hosts)."""
        c = self._due
        gen = self._due_gen
        if c[0] == gen:
            return c[1]
        t = self._next_timer()
        if self.cache_timers:
            self._due = (gen, t)
        return t

    def _next_timer(self) -> int | None:
        if not self.listening():
            return None
        # (the earliest of the timers, without a list: asked after every frame batch)
        best = self._boot_at
        t = self._hb_next
        if t is not None and (best is None or t < best):
            best = t
        t = self.device_timer_ns()
        if t is not None and (best is None or t < best):
            best = t
        for c in self._consumers.values():
            if c.last_ns is not None and not c.lost:
                t = c.last_ns + c.timeout_ns
                if best is None or t < best:
                    best = t
        if self.nmt_state is Nmt.OPERATIONAL and self.may_send("pdo"):
            for pdo in self.tpdos:
                if pdo.transmission >= 254 and pdo.event_ns:
                    base = pdo.last_sent_ns if pdo.last_sent_ns is not None else 0
                    t = base + pdo.event_ns
                    if best is None or t < best:
                        best = t
        return best

    def on_timer(self, now: int) -> None:
        if not self.listening():
            return
        if self._boot_at is not None and now >= self._boot_at:
            self._boot_up(now)
        if self._hb_next is not None and now >= self._hb_next:
            self._send("hb", 0x700 + self.node_id, bytes([int(self.nmt_state)]))
            self._schedule_heartbeat(now)
        for c in list(self._consumers.values()):
            if c.last_ns is not None and not c.lost and now >= c.last_ns + c.timeout_ns:
                c.lost = True
                self.on_heartbeat_lost(c.producer)
        self.device_timer(now)
        self.service_event_pdos(now)
        self._retime()

    def close(self) -> None:
        """Leave the bus (unsubscribe everything)."""
        self.bus.unsubscribe(0x600 + self.node_id, self._on_sdo_frame)
        self.bus.unsubscribe(0x000, self._on_nmt)
        if self.sync_cob_id is not None:
            self.bus.unsubscribe(self.sync_cob_id, self._on_sync_frame)
        for p in self.rpdos.values():
            self.bus.unsubscribe(p.cob_id, self._on_rpdo)
        for producer in self._consumers:
            self.bus.unsubscribe(0x700 + producer, self._on_heartbeat)

    # -- hooks for subclasses ---------------------------------------------------------------------
    def accept_start(self) -> bool:
        """NMT start received: False refuses it (a device that cannot start)."""
        return True

    def listening(self) -> bool:
        """False: the node hears nothing and does nothing (a simulated power-off)."""
        return True

    def may_send(self, kind: str) -> bool:
        """Whether a frame of ``kind`` (nmt, hb, sdo, pdo, emcy) may go out (fault injection)."""
        return True

    def check_read(self, index: int, sub: int) -> None:
        """An SDO upload of ``index:sub`` (raise SdoAbortError to refuse it)."""

    def check_access(self, index: int, sub: int) -> None:
        """An SDO download to ``index:sub`` starts (raise SdoAbortError to refuse it)."""

    def cob_id_conflict(self, kind: str, number: int, can_id: int) -> str | None:
        """Why ``can_id`` may not be used by PDO ``number`` of ``kind`` (None: it may)."""
        return None

    def on_write(self, index: int, sub: int, value: Any) -> None:
        """An SDO write (raise SdoAbortError to refuse it; stored after this returns)."""

    def on_rpdo_data(self, number: int, values: list[tuple[int, int, bytes]]
                     ) -> list[tuple[int, int, bytes]]:
        """RPDO ``number`` carries ``(index, sub, raw)``: return what is stored (a PDO
        cannot be refused; a device drops what it does not accept)."""
        return values

    def on_sync(self, now_ns: int) -> None:
        """A SYNC arrived (RPDOs of types 0-240 are already in the OD; TPDOs follow)."""

    def on_rpdo(self, number: int, objects: frozenset[tuple[int, int]]) -> None:
        """RPDO ``number`` (mapping ``objects``) was written into the OD."""

    def on_comm_reset(self) -> None:
        """NMT reset communication or reset node (after the objects were reset)."""

    def on_reset(self) -> None:
        """NMT reset node: back to the power-on state (the physical state stays)."""

    def on_nmt(self, old: Nmt, new: Nmt) -> None:
        """The NMT state changed."""

    def on_heartbeat_lost(self, producer: int) -> None:
        """A consumed heartbeat (1016h) timed out."""

    def on_heartbeat_back(self, producer: int) -> None:
        """A consumed heartbeat that had timed out is received again."""

    def device_timer_ns(self) -> int | None:
        return None

    def device_timer(self, now_ns: int) -> None:
        pass

