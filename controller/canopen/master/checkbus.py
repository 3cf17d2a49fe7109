"""Check a bus against its configuration: who is there, who they are, how their PDOs are set.

The first thing to run on a new rig (``cantrack check-bus CONFIG``).  It only listens and
reads (SDO uploads): no NMT command, no write, so it can run next to a live bus.

1. listen ``listen_s`` for heartbeats (NMT state of every node that produces one);
2. for every node-ID of the configuration (plus an optional scan range): SDO upload of 1000h
   and 1018h sub 1..4; a configured node that does not answer is *missing*, a scanned one
   that answers but is not configured is *unexpected*;
3. identity against the EDS (1000h device type, 1018h vendor-ID, product code, revision) and
   the bus.yml (``revision_number``, ``serial_number`` when given);
4. the PDOs the configuration sets (as cantrack's boot / dcfgen's concise DCF would leave them):
   communication 1400h/1800h sub 1 (COB-ID with the valid bit) and sub 2 (transmission type),
   mapping 1600h/1A00h sub 0 (count) and each entry.  Before ``cantrack run`` has configured
   the bus the nodes show their power-on (EDS) values: the differences say what the boot will
   change.

:func:`check_bus` returns a :class:`BusCheck` (one :class:`NodeCheck` per node, each with its
list of :class:`Difference`); ``ok`` when nothing differs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..config.concise import effective_pdos
from ..protocol import od as odm
from ..protocol.sdo import SdoAbortError, SdoClient
from .supervision import NMT_NAMES

if TYPE_CHECKING:
    from ..config import ControllerConfig
    from ..io.transport import Transport

INVALID = 0x80000000


@dataclass(frozen=True)
class Difference:
    what: str         # "identity", "pdo", "nmt", "missing", "unexpected", "sdo"
    obj: str          # "1018h:02", "1A00h:01", "" ...
    expected: str
    actual: str
    source: str = ""  # where the expected value comes from (EDS file, bus.yml)

    def __str__(self) -> str:
        where = f" {self.obj}" if self.obj else ""
        src = f" ({self.source})" if self.source else ""
        return f"{self.what}{where}: expected {self.expected}{src}, found {self.actual}"


@dataclass
class NodeCheck:
    node_id: int
    name: str | None               # None: not in the configuration
    answered: bool = False
    nmt_state: int | None = None   # from its heartbeat
    identity: dict[str, int] = field(default_factory=dict)
    #: 1008h/1009h/100Ah (device name, hardware and software version) where the node has them
    #: (strings: segmented SDO uploads); informative, never a difference
    names: dict[str, str] = field(default_factory=dict)
    differences: list[Difference] = field(default_factory=list)

    @property
    def label(self) -> str:
        return f"node {self.node_id} ({self.name})" if self.name else f"node {self.node_id}"

    @property
    def ok(self) -> bool:
        return not self.differences

    def state_text(self) -> str:
        if self.nmt_state is None:
            return "no heartbeat"
        return NMT_NAMES.get(self.nmt_state, f"{self.nmt_state:02X}h")


@dataclass
class BusCheck:
    nodes: list[NodeCheck]

    @property
    def ok(self) -> bool:
        return all(n.ok for n in self.nodes)

    def node(self, node_id: int) -> NodeCheck:
        return next(n for n in self.nodes if n.node_id == node_id)

    def format(self) -> str:
        lines = []
        for n in self.nodes:
            if n.name and not n.answered:
                lines.append(f"{n.label}: MISSING: no SDO answer "
                             f"({n.state_text()}); is it powered, at the right bitrate and "
                             "node-ID?")
                continue
            ident = " ".join(f"{k} {v:08X}h" for k, v in n.identity.items())
            head = f"{n.label}: {'OK' if n.ok else 'DIFFERS'}, NMT {n.state_text()}, {ident}"
            if n.names:
                head += ", " + ", ".join(f"{k} {v!r}" for k, v in n.names.items())
            lines.append(head)
            for d in n.differences:
                lines.append(f"    {d}")
        bad = sum(1 for n in self.nodes if not n.ok)
        lines.append("all nodes match the configuration" if self.ok else
                     f"{bad} of {len(self.nodes)} node(s) differ from the configuration")
        return "\n".join(lines)


def _hex(v: int | None) -> str:
    return "-" if v is None else f"{v:08X}h"


#: the manufacturer's strings of CiA 301 read when present
NAME_OBJECTS = ((0x1008, "device name"), (0x1009, "hardware version"),
                (0x100A, "software version"))


def read_names(sdo: SdoClient) -> dict[str, str]:
    """1008h/1009h/100Ah of a node (VISIBLE_STRING, usually longer than 4 bytes: segmented
    uploads); an object the node does not have (abort) is left out."""
    out = {}
    for index, what in NAME_OBJECTS:
        try:
            raw = sdo.upload(index, 0)
        except SdoAbortError:
            continue
        out[what] = raw.rstrip(b"\0").decode("utf-8", errors="replace")
    return out


def expected_identity(cfg: ControllerConfig, name: str) -> list[tuple[int, int, str, int | None, str]]:
    """(index, sub, what, expected value or None, source) of the identity objects."""
    slave = cfg.slaves[name]
    od = cfg.ods[name]
    eds = f"EDS {slave.dcf.name}"

    def from_eds(index: int, sub: int) -> int | None:
        var = odm.variable(od, index, sub)
        value = odm.default_value(var) if var is not None else None
        return None if value is None else int(value)

    rev = (slave.revision_number, "bus.yml") if slave.revision_number is not None \
        else (from_eds(0x1018, 3), eds)
    return [(0x1000, 0, "device type", from_eds(0x1000, 0), eds),
            (0x1018, 1, "vendor-ID", from_eds(0x1018, 1), eds),
            (0x1018, 2, "product code", from_eds(0x1018, 2), eds),
            (0x1018, 3, "revision number", rev[0], rev[1]),
            (0x1018, 4, "serial number", slave.serial_number, "bus.yml")]


def _check_pdos(cfg: ControllerConfig, name: str, sdo: SdoClient, nc: NodeCheck) -> None:
    pdos = effective_pdos(cfg)[name]
    for p in sorted(pdos.all(), key=lambda p: p.comm_index):
        comm = p.comm_index
        mapi = comm + 0x200
        kind = f"{p.kind.upper()}{p.number}"
        want_cob = p.cob_id | (0 if p.enabled else INVALID)
        try:
            cob = sdo.upload_uint(comm, 1)
        except SdoAbortError as exc:
            nc.differences.append(Difference("pdo", f"{comm:04X}h:01", f"{kind} COB-ID "
                                             f"{want_cob:08X}h", f"abort {exc.code:08X}h"))
            continue
        valid = not cob & INVALID
        if valid != p.enabled or (p.enabled and (cob & 0x7FF) != p.cob_id):
            nc.differences.append(Difference(
                "pdo", f"{comm:04X}h:01", f"{kind} COB-ID {want_cob:08X}h "
                f"({'enabled' if p.enabled else 'disabled'})",
                f"{cob:08X}h ({'enabled' if valid else 'disabled'})", "bus.yml"))
        if not p.enabled:
            continue
        trans = sdo.upload_uint(comm, 2)
        if trans != p.transmission:
            nc.differences.append(Difference("pdo", f"{comm:04X}h:02",
                                             f"{kind} transmission type {p.transmission}",
                                             str(trans), "bus.yml"))
        count = sdo.upload_uint(mapi, 0)
        want = [(i << 16) | (s << 8) | bits for i, s, bits in p.mapping]
        if count != len(want):
            nc.differences.append(Difference("pdo", f"{mapi:04X}h:00",
                                             f"{kind} {len(want)} mapped objects", str(count),
                                             "bus.yml"))
        for k, w in enumerate(want, start=1):
            got = sdo.upload_uint(mapi, k) if k <= count else None
            if got != w:
                nc.differences.append(Difference(
                    "pdo", f"{mapi:04X}h:{k:02X}",
                    f"{kind} entry {k} = {w >> 16:04X}h:{(w >> 8) & 0xFF:02X} "
                    f"{w & 0xFF} bit ({w:08X}h)",
                    "-" if got is None else f"{got >> 16:04X}h:{(got >> 8) & 0xFF:02X} "
                    f"{got & 0xFF} bit ({got:08X}h)", "bus.yml"))


def check_bus(cfg: ControllerConfig, transport: Transport, *, scan: range | None = None,
              listen_s: float | None = None, sdo_timeout_s: float | None = None,
              pdos: bool = True) -> BusCheck:
    """Steps 1-4 of the module docstring on ``transport``."""
    clock = transport.clock
    tmo = cfg.tracking.timeouts if cfg.tracking is not None else None
    sdo_s = sdo_timeout_s if sdo_timeout_s is not None else (tmo.sdo_s if tmo else 0.5)
    by_id = {s.node_id: name for name, s in cfg.slaves.items()}
    ids = sorted(set(by_id) | set(scan or ()))
    ids = [i for i in ids if i != cfg.master.node_id or i in by_id]
    if listen_s is None:
        hbs = [s.heartbeat_producer_ms or 0 for s in cfg.slaves.values()]
        listen_s = max(0.5, 1.5 * max(hbs, default=0) / 1e3)
    states: dict[int, int] = {}

    def on_hb(can_id: int, data: bytes, t_ns: int) -> None:
        if data:
            states[can_id - 0x700] = data[0] & 0x7F

    for i in ids:
        transport.subscribe(0x700 + i, on_hb)
    transport.run_until(clock.now_ns() + int(listen_s * 1e9))
    nodes = []
    for i in ids:
        name = by_id.get(i)
        nc = NodeCheck(i, name, nmt_state=states.get(i))
        sdo = SdoClient(transport, i, nc.label, sdo_s, 0)
        try:
            nc.identity["device type"] = sdo.upload_uint(0x1000, 0)
            nc.answered = True
        except SdoAbortError as exc:
            nc.answered = True
            nc.differences.append(Difference("sdo", "1000h:00", "device type",
                                             f"SDO abort {exc.code:08X}h"))
        except Exception:  # noqa: BLE001 -- a time-out: nobody there
            nc.answered = False
        if not nc.answered:
            if name is not None:
                nc.differences.append(Difference(
                    "missing", "", "a node answering SDO", "no answer within "
                    f"{sdo_s:g} s, {nc.state_text()}", f"bus.yml {name}"))
                nodes.append(nc)
            elif i in states:  # heartbeat but no SDO server
                nc.differences.append(Difference("unexpected", "", "no node",
                                                 f"heartbeat {nc.state_text()}, no SDO"))
                nodes.append(nc)
            continue
        if name is None:
            for sub, what in ((1, "vendor-ID"), (2, "product code")):
                try:
                    nc.identity[what] = sdo.upload_uint(0x1018, sub)
                except Exception:  # noqa: BLE001, S110 -- identity is optional here
                    pass
            nc.differences.append(Difference("unexpected", "", "no node (not in the "
                                             "configuration)", "a node answering SDO"))
            nodes.append(nc)
            continue
        for index, sub, what, want, source in expected_identity(cfg, name):
            if index == 0x1000:
                got = nc.identity["device type"]
            else:
                try:
                    got = sdo.upload_uint(index, sub)
                except SdoAbortError as exc:
                    if want is not None:
                        nc.differences.append(Difference("identity", f"{index:04X}h:{sub:02X}",
                                                         f"{what} {_hex(want)}",
                                                         f"SDO abort {exc.code:08X}h", source))
                    continue
                nc.identity[what] = got
            if want is not None and got != want:
                nc.differences.append(Difference("identity", f"{index:04X}h:{sub:02X}",
                                                 f"{what} {_hex(want)}", _hex(got), source))
        nc.names = read_names(sdo)
        if nc.nmt_state is None and (cfg.slaves[name].heartbeat_producer_ms or 0) > 0:
            nc.differences.append(Difference("nmt", "1017h", "a heartbeat every "
                                             f"{cfg.slaves[name].heartbeat_producer_ms} ms",
                                             f"none in {listen_s:g} s", "bus.yml"))
        if pdos:
            try:
                _check_pdos(cfg, name, sdo, nc)
            except Exception as exc:  # noqa: BLE001 -- a time-out half-way
                nc.differences.append(Difference("sdo", "", "PDO objects readable", str(exc)))
        nodes.append(nc)
    for i in ids:
        transport.unsubscribe(0x700 + i, on_hb)
    return BusCheck(nodes)


def parse_scan(text: str) -> range:
    """``"1-127"`` or ``"5"`` -> a range of node-IDs."""
    lo, _, hi = text.partition("-")
    a, b = int(lo, 0), int(hi or lo, 0)
    if not 1 <= a <= b <= 127:
        raise ValueError(f"--scan {text!r}: node-IDs 1..127, e.g. 1-127")
    return range(a, b + 1)
