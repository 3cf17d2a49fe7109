"""Boot of the bus: NMT reset -> boot-up -> identity -> SDO configuration -> NMT start.

Steps (the 402 enable follows in the cycle, with SYNC and the RPDOs running):

1. NMT "reset node" (81h) to every slave with ``boot: true`` (or to all, ``reset_all_nodes``);
   wait for each boot-up message (700h + id, data 00h) within ``timeouts.boot_up_s``.
   A missing slave that the tracking uses, or that is ``mandatory``, stops the boot;
   another one is reported and left out.
2. Identity check against the EDS: 1000h device type, 1018h sub1 vendor-ID and sub2 product
   code must equal the EDS; sub3 revision and sub4 serial number must equal the bus.yml's
   ``revision_number`` / ``serial_number`` when given (else the revision the EDS states).
3. SDO configuration: the list dcfgen would write (:mod:`controller.canopen.config.concise`: consumer
   heartbeat, producer heartbeat, PDO communication and mapping, the ``sdo`` list), then
   cantrack's own writes to each tracking drive: 60C2h = the SYNC period (value x 10^index s),
   6060h = 8 (CSP), 607Dh software limits from the axis limits, and 607Ah = 6064h (read back),
   so that the first target the drive sees is where it stands.
4. NMT "start remote node" (01h) to each slave (``master.start_nodes``).

Every error names the node, the object (index:sub) and, for an SDO abort, the abort code;
and the EMCYs the node sent during the boot (a CANopenNode device that refuses NMT start
says why in its EMCY just before, e.g. 5000h with no storage files).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ...errors import CanError
from ..config.concise import SdoValue, concise_configuration
from ..config.tracking import Timeouts
from ..io.transport import Transport
from ..protocol import cia402
from ..protocol import od as odm
from ..protocol.sdo import SdoAbortError, SdoClient
from .events import EventLog

if TYPE_CHECKING:
    from ..config import ControllerConfig


class BootError(CanError):
    """The boot stopped; the message names the node, the step and the object."""

    def __init__(self, message: str, node_id: int | None = None) -> None:
        super().__init__(message)
        self.node_id = node_id


class BootEmcys:
    """The EMCYs of the booting slaves (80h + node-ID), collected during the boot: each is
    an event, and a boot error of a node names the ones that node sent."""

    def __init__(self, cfg: ControllerConfig, transport: Transport, slaves: list) -> None:
        self.transport = transport
        self.cfg = cfg
        self.seen: dict[int, list[str]] = {}
        self.labels = {s.node_id: cfg.label(s.name) for s in slaves}
        self.profiles = {s.node_id: odm.profile(cfg.ods[s.name]) for s in slaves}
        for node in self.labels:
            transport.subscribe(0x80 + node, self._on_emcy)

    def _on_emcy(self, can_id: int, data: bytes, t_ns: int) -> None:
        from .supervision import Emcy
        node = can_id - 0x80
        if len(data) != 8:  # (CiA 301: 8 bytes; the controller's EMCY consumer counts it)
            return
        e = Emcy(self.labels[node], node, int.from_bytes(data[0:2], "little"), data[2],
                 bytes(data[3:8]), t_ns, self.profiles[node])
        self.seen.setdefault(node, []).append(str(e))

    def close(self, events: EventLog, t_s: float) -> None:
        for node in self.labels:
            self.transport.unsubscribe(0x80 + node, self._on_emcy)
        for node, texts in self.seen.items():
            for text in texts:
                events.add(-1, t_s, self.labels[node], "emcy", f"{text} during the boot",
                           "reported")

    def suffix(self, node_id: int | None) -> str:
        texts = self.seen.get(node_id, []) if node_id is not None else []
        return f"; during the boot the node sent {'; '.join(texts)}" if texts else ""


@dataclass
class NodeBoot:
    name: str
    node_id: int
    bootup_ns: int | None = None
    identity: tuple[int, int, int, int] | None = None
    sdo_writes: int = 0
    actual_counts: int | None = None


@dataclass
class BootResult:
    nodes: dict[str, NodeBoot] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    duration_ns: int = 0


def interpolation_period(period_us: int) -> tuple[int, int]:
    """60C2h (value, index) with value x 10^index s = ``period_us``, value <= 255."""
    for index in (-3, -4, -5, -6):
        value = period_us / 10 ** (index + 6)
        if value == int(value) and 1 <= value <= 255:
            return int(value), index
    raise ValueError(f"sync period {period_us} us cannot be written as 60C2h "
                     "(value 1...255 x 10^-3...-6 s)")


def sync_consumer(od) -> bool:
    """The node consumes SYNC: 1005h exists with bit 30 (generate) clear."""
    var = odm.variable(od, 0x1005)
    value = odm.default_value(var) if var is not None else None
    return value is not None and not int(value) & 0x40000000


def cantrack_sdos(cfg: ControllerConfig, name: str) -> list[SdoValue]:
    """cantrack's own SDO writes to slave ``name`` (after the bus.yml's)."""
    out = []
    od = cfg.ods[name]
    if sync_consumer(od) and odm.variable(od, 0x1019) is not None and \
            not any(w.index == 0x1019 for w in cfg.slaves[name].sdo):
        out.append(SdoValue(0x1019, 0, cfg.master.sync_overflow, 1, "cantrack"))
    # 1007h from ``sync_window`` (0: not written, the node keeps its own): a node that
    # serves a SYNC after the window sends none of its synchronous TPDOs (CiA 301), so a
    # late answer is missing, never taken for the next SYNC's
    if cfg.master.sync_window_us and sync_consumer(od) and \
            odm.variable(od, 0x1007) is not None and \
            not any(w.index == 0x1007 for w in cfg.slaves[name].sdo):
        out.append(SdoValue(0x1007, 0, cfg.master.sync_window_us, 4, "cantrack"))
    t = cfg.tracking
    if t is None or name not in t.drive_nodes:
        return out
    axis = next(a for a in t.axes if a.node == name)
    value, index = interpolation_period(cfg.master.sync_period_us)
    lo, hi = axis.scale.limit_counts()
    return out + [
        SdoValue(0x60C2, 1, value, 1, "cantrack"),
        SdoValue(0x60C2, 2, index, 1, "cantrack"),
        SdoValue(0x6060, 0, cia402.MODE_CSP, 1, "cantrack"),
        SdoValue(0x607D, 1, lo, 4, "cantrack"),
        SdoValue(0x607D, 2, hi, 4, "cantrack"),
    ]


def required_slaves(cfg: ControllerConfig) -> set[str]:
    req = {n for n, s in cfg.slaves.items() if s.mandatory}
    if cfg.tracking is not None:
        req.add(cfg.tracking.conveyor.node)
        req.update(cfg.tracking.drive_nodes)
    return req


def boot(cfg: ControllerConfig, transport: Transport, events: EventLog | None = None,
         timeouts: Timeouts | None = None) -> BootResult:
    """Run steps 1-4; returns what each node reported.  Raises BootError (naming the EMCYs
    the failing node sent during the boot)."""
    events = events if events is not None else EventLog()
    if timeouts is None:
        timeouts = cfg.tracking.timeouts if cfg.tracking is not None else Timeouts()
    slaves = [s for s in cfg.slaves.values() if s.boot]
    emcys = BootEmcys(cfg, transport, slaves)
    current: list[int | None] = [None]  # the node being configured
    try:
        return _boot(cfg, transport, events, timeouts, slaves, current)
    except BootError as exc:
        node = exc.node_id if exc.node_id is not None else current[0]
        if not emcys.suffix(node):
            raise
        raise BootError(f"{exc}{emcys.suffix(node)}", node) from exc.__cause__
    except CanError as exc:  # an SDO time-out or protocol error of the node being booted
        if not emcys.suffix(current[0]):
            raise
        raise BootError(f"{exc}{emcys.suffix(current[0])}", current[0]) from exc
    finally:
        emcys.close(events, transport.clock.now_ns() * 1e-9)


def _boot(cfg: ControllerConfig, transport: Transport, events: EventLog, timeouts: Timeouts,
          slaves: list, current: list[int | None]) -> BootResult:
    clock = transport.clock
    t_start = clock.now_ns()
    result = BootResult()
    for s in slaves:
        result.nodes[s.name] = NodeBoot(s.name, s.node_id)
    by_id = {s.node_id: result.nodes[s.name] for s in slaves}

    # 1. NMT reset node -> boot-up
    def on_bootup(can_id: int, data: bytes, t_ns: int) -> None:
        nb = by_id.get(can_id - 0x700)
        if nb is not None and data[:1] == b"\x00":
            nb.bootup_ns = t_ns

    for s in slaves:
        transport.subscribe(0x700 + s.node_id, on_bootup)
    if cfg.master.reset_all_nodes:
        transport.send(0x000, bytes((0x81, 0)))
    else:
        for s in slaves:
            transport.send(0x000, bytes((0x81, s.node_id)))
    transport.run_until(clock.now_ns() + int(timeouts.boot_up_s * 1e9),
                        lambda: all(nb.bootup_ns is not None for nb in by_id.values()))
    for s in slaves:
        transport.unsubscribe(0x700 + s.node_id, on_bootup)
    required = required_slaves(cfg)
    for s in slaves:
        if result.nodes[s.name].bootup_ns is None:
            label = cfg.label(s.name)
            if s.name in required:
                raise BootError(f"{label}: no boot-up message within {timeouts.boot_up_s:g} s "
                                f"after NMT reset node (is it powered, on the bus at "
                                f"{cfg.master.baudrate_kbit} kbit/s, node-ID {s.node_id}?)",
                                s.node_id)
            events.add(-1, clock.now_ns() * 1e-9, label, "missing",
                       f"no boot-up within {timeouts.boot_up_s:g} s", "left out")
            result.missing.append(s.name)
    present = [s for s in slaves if s.name not in result.missing]

    concise = concise_configuration(cfg)
    for s in present:
        current[0] = s.node_id
        label = cfg.label(s.name)
        sdo = SdoClient(transport, s.node_id, label, timeouts.sdo_s, timeouts.sdo_retries)
        od = cfg.ods[s.name]
        nb = result.nodes[s.name]
        # 2. identity
        nb.identity = _check_identity(cfg, s.name, sdo, od)
        # 3. configuration
        writes = concise[s.name].sdos + cantrack_sdos(cfg, s.name)
        for i, w in enumerate(writes, start=1):
            try:
                sdo.download(w.index, w.sub_index, w.data())
            except SdoAbortError as exc:
                raise BootError(f"{exc} (configuration write {i} of {len(writes)}, value "
                                f"{w.value} from {w.origin})") from exc
            nb.sdo_writes += 1
        if cfg.tracking is not None and s.name in cfg.tracking.drive_nodes:
            actual = sdo.upload_int(0x6064, 0)
            try:
                sdo.download(0x607A, 0, actual.to_bytes(4, "little", signed=True))
            except SdoAbortError as exc:
                raise BootError(f"{exc} (607Ah = 6064h before the enable)") from exc
            nb.actual_counts = actual
        events.add(-1, clock.now_ns() * 1e-9, label, "boot",
                   f"identity ok, {nb.sdo_writes} SDO writes", level=20)

    # 4. NMT start, confirmed by the next heartbeat of each node (state 05h)
    current[0] = None
    if cfg.master.start_nodes:
        _start_nodes(cfg, transport, present)
    result.duration_ns = clock.now_ns() - t_start
    return result


def heartbeat_ms(cfg: ControllerConfig, name: str) -> int:
    """The producer heartbeat time of slave ``name`` after the boot [ms] (0 = none)."""
    hb = cfg.slaves[name].heartbeat_producer_ms
    if hb is None:
        var = odm.variable(cfg.ods[name], 0x1017)
        hb = int(odm.default_value(var) or 0) if var is not None else 0
    return hb


def _start_nodes(cfg: ControllerConfig, transport: Transport, present: list) -> None:
    clock = transport.clock
    state: dict[int, int] = {}
    watched = {s.node_id: s for s in present if heartbeat_ms(cfg, s.name) > 0}

    def on_heartbeat(can_id: int, data: bytes, t_ns: int) -> None:
        if data:
            state[can_id - 0x700] = data[0] & 0x7F

    for node_id in watched:
        transport.subscribe(0x700 + node_id, on_heartbeat)
    for s in present:
        transport.send(0x000, bytes((0x01, s.node_id)))
    if watched:
        wait_ms = max(heartbeat_ms(cfg, s.name) * s.hb_multiplier(cfg.options)
                      for s in watched.values())
        transport.run_until(clock.now_ns() + int(wait_ms * 1e6),
                            lambda: all(state.get(n) == 5 for n in watched))
    else:
        transport.run_until(clock.now_ns())
    for node_id in watched:
        transport.unsubscribe(0x700 + node_id, on_heartbeat)
    for node_id, s in watched.items():
        if state.get(node_id) != 5:
            shown = "no heartbeat" if node_id not in state else \
                f"its heartbeat shows state {state[node_id]:02X}h"
            raise BootError(f"{cfg.label(s.name)}: NMT start not confirmed: {shown} "
                            f"(05h = operational expected)", node_id)


def _check_identity(cfg: ControllerConfig, name: str, sdo: SdoClient, od) -> tuple[int, ...]:
    slave = cfg.slaves[name]
    eds = slave.dcf.name

    def expected(index: int, sub: int) -> int | None:
        var = odm.variable(od, index, sub)
        value = odm.default_value(var) if var is not None else None
        return None if value is None else int(value)

    checks = [(0x1000, 0, "device type", expected(0x1000, 0), f"the EDS {eds}"),
              (0x1018, 1, "vendor-ID", expected(0x1018, 1), f"the EDS {eds}"),
              (0x1018, 2, "product code", expected(0x1018, 2), f"the EDS {eds}")]
    if slave.revision_number is not None:
        checks.append((0x1018, 3, "revision number", slave.revision_number, "bus.yml"))
    else:
        checks.append((0x1018, 3, "revision number", expected(0x1018, 3), f"the EDS {eds}"))
    if slave.serial_number is not None:
        checks.append((0x1018, 4, "serial number", slave.serial_number, "bus.yml"))
    got = []
    for index, sub, what, want, source in checks:
        try:
            value = sdo.upload_uint(index, sub)
        except SdoAbortError as exc:
            raise BootError(f"{exc} (identity check)") from exc
        got.append(value)
        if want is not None and value != want:
            raise BootError(f"{cfg.label(name)}: wrong identity: {what} {index:04X}h:{sub:02X} "
                            f"is {value:08X}h, {source} says {want:08X}h")
    serial = got[4] if len(got) > 4 else 0
    return got[1], got[2], got[3], serial
