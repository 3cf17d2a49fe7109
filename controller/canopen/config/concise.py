"""The slaves' configuration as dcfgen computes it: the SDO writes and the resulting PDOs.

Lely's ``dcfgen`` turns each slave section into a "concise DCF" (a list of SDO downloads,
``<slave>.bin``) that the master writes at boot.  :func:`concise_configuration` reproduces
that list in the same order and with the same values (``tests/test_config_dcfgen.py``
compares it with ``dcfgen -v``), and the PDO settings the slave ends up with.  Order per
slave (dcf-tools 2.4.2, ``dcfgen/cli.py``): 1016h (consumer heartbeat of the master, inserted
first), 1017h, then per RPDO then TPDO in file order: disable (COB-ID | 80000000h), 1st
transmission type, inhibit time, event timer, SYNC start, mapping (sub0 = 0, entries,
sub0 = n), enable; then the ``sdo`` list.

dcfgen quirks kept here: the ``cob_id: auto`` numbering (predefined set for PDO 1-4, else
0x680 upwards over all slaves in file order); a PDO whose EDS COB-ID has bit 31 set and no
``cob_id`` given stays disabled even with ``enabled: true`` (the config loader reports that
as an error); a value equal to the EDS default is not written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from canopen.objectdictionary import ObjectDictionary

from ...errors import ConfigError
from ..protocol import od as odm
from ..protocol.pdo import INVALID, NodePdos, PdoSpec

if TYPE_CHECKING:
    from .bus import ControllerConfig, PdoSetting, SlaveConfig



@dataclass(frozen=True, slots=True)
class SdoValue:
    """One SDO download: ``value`` into ``index:sub_index`` with ``size`` bytes."""

    index: int
    sub_index: int
    value: int
    size: int
    #: where it comes from (for messages): "bus.yml", "cantrack", ...
    origin: str = "bus.yml"

    def data(self) -> bytes:
        mask = (1 << (8 * self.size)) - 1
        return (self.value & mask).to_bytes(self.size, "little")


@dataclass(slots=True)
class PdoState:
    """A PDO after configuration (dcfgen's ``dcf.PDO``, with our names)."""

    kind: str  # "rpdo" | "tpdo"
    number: int
    cob_id: int  # including bit 31 (invalid)
    transmission: int = 0
    inhibit_time: int = 0
    event_timer: int = 0
    #: RPDO 14xxh:05: the deadline monitoring time of the slave's consumer [ms] (0 = off)
    event_deadline: int = 0
    sync_start: int = 0
    mapping: list[tuple[int, int, int]] = field(default_factory=list)  # (index, sub, bits)
    line: int | None = None

    @property
    def comm_index(self) -> int:
        return (0x1400 if self.kind == "rpdo" else 0x1800) + self.number - 1

    @property
    def enabled(self) -> bool:
        return not (self.cob_id & INVALID) and bool(self.mapping)


@dataclass
class SlaveConcise:
    sdos: list[SdoValue]
    rpdo: dict[int, PdoState]
    tpdo: dict[int, PdoState]


def _var_default(od: ObjectDictionary, index: int, sub: int) -> int:
    var = odm.variable(od, index, sub)
    value = odm.default_value(var) if var is not None else None
    return int(value or 0)


def _size(od: ObjectDictionary, index: int, sub: int) -> int:
    var = odm.variable(od, index, sub)
    if var is None:
        # dcfgen writes sub 0 of an array/record as UNSIGNED8
        return 1
    return odm.size_bytes(var)


def pdo_from_od(od: ObjectDictionary, kind: str, number: int) -> PdoState | None:
    """The PDO as the EDS defines it (dcf-tools' ``PDO.from_device``)."""
    comm = (0x1400 if kind == "rpdo" else 0x1800) + number - 1
    if comm not in od or comm + 0x200 not in od:
        return None
    highest = _var_default(od, comm, 0)
    p = PdoState(kind, number, INVALID)
    if highest >= 1:
        p.cob_id = _var_default(od, comm, 1)
    if highest >= 2:
        p.transmission = _var_default(od, comm, 2)
    if kind == "rpdo" and highest >= 5 and odm.variable(od, comm, 5) is not None:
        p.event_deadline = _var_default(od, comm, 5)
    if kind == "tpdo":
        if highest >= 3 and odm.variable(od, comm, 3) is not None:
            p.inhibit_time = _var_default(od, comm, 3)
        if highest >= 5 and odm.variable(od, comm, 5) is not None:
            p.event_timer = _var_default(od, comm, 5)
        if highest >= 6 and odm.variable(od, comm, 6) is not None:
            p.sync_start = _var_default(od, comm, 6)
    n = _var_default(od, comm + 0x200, 0)
    for i in range(1, n + 1):
        value = _var_default(od, comm + 0x200, i)
        if value:
            p.mapping.append(((value >> 16) & 0xFFFF, (value >> 8) & 0xFF, value & 0xFF))
    return p


def _configure_pdo(p: PdoState, s: PdoSetting, od: ObjectDictionary, node_id: int,
                   next_cob: list[int]) -> list[SdoValue]:
    sdo: list[SdoValue] = []
    comm = p.comm_index
    is_tpdo = p.kind == "tpdo"
    eds_cob = p.cob_id
    if s.cob_id is not None:
        if s.cob_id == "auto":
            i = comm & 0x01FF
            if i < 4:
                p.cob_id = (i + 1) * 0x100 + (0x80 if is_tpdo else 0x100) + node_id
            else:
                p.cob_id = next_cob[0]
                next_cob[0] += 1
        else:
            p.cob_id = int(s.cob_id)
    if eds_cob != p.cob_id | INVALID:
        sdo.append(SdoValue(comm, 1, p.cob_id | INVALID, 4))
    if not (p.cob_id & INVALID):
        if s.transmission is not None and s.transmission != p.transmission:
            p.transmission = s.transmission
            sdo.append(SdoValue(comm, 2, s.transmission, 1))
        if s.inhibit_time is not None and s.inhibit_time != p.inhibit_time:
            p.inhibit_time = s.inhibit_time
            if is_tpdo:
                sdo.append(SdoValue(comm, 3, s.inhibit_time, 2))
        if s.event_timer is not None and s.event_timer != p.event_timer:
            p.event_timer = s.event_timer
            if is_tpdo:
                sdo.append(SdoValue(comm, 5, s.event_timer, 2))
        if s.event_deadline is not None and s.event_deadline != p.event_deadline:
            # (dcf-tools 2.4.2 writes the *event_timer*'s value here, a bug: we write the
            # event_deadline itself; the config loader refuses it for a TPDO or an EDS
            # without 14xxh:05)
            p.event_deadline = s.event_deadline
            if not is_tpdo:
                sdo.append(SdoValue(comm, 5, s.event_deadline, 2))
        if s.sync_start is not None and s.sync_start != p.sync_start:
            p.sync_start = s.sync_start
            if is_tpdo:
                sdo.append(SdoValue(comm, 6, s.sync_start, 1))
        if s.mapping is not None:
            mapidx = comm + 0x200
            if p.mapping or s.mapping:
                p.mapping = []
                sdo.append(SdoValue(mapidx, 0, 0, 1))
            for n, e in enumerate(s.mapping, start=1):
                var = odm.variable(od, e.index, e.sub_index)
                if var is None:
                    raise ConfigError(f"node {node_id}: PDO mapping entry "
                                      f"{e.index:04X}h sub {e.sub_index} is not in the EDS")
                bits = len(var)
                p.mapping.append((e.index, e.sub_index, bits))
                sdo.append(SdoValue(mapidx, n, (e.index << 16) | (e.sub_index << 8) | bits, 4))
            if p.mapping:
                sdo.append(SdoValue(mapidx, 0, len(p.mapping), 1))
        if s.enabled:
            sdo.append(SdoValue(comm, 1, p.cob_id, 4))
        else:
            p.cob_id |= INVALID
    p.line = s.line
    return sdo


def concise_configuration(cfg: ControllerConfig) -> dict[str, SlaveConcise]:
    """Per slave: dcfgen's SDO list and the PDOs it leaves configured."""
    next_cob = [0x680]
    out: dict[str, SlaveConcise] = {}
    master = cfg.master
    for name, slave in cfg.slaves.items():
        od = cfg.ods[name]
        sdos: list[SdoValue] = []
        hb = slave.heartbeat_producer_ms
        if hb is not None and hb != _var_default(od, 0x1017, 0):
            sdos.append(SdoValue(0x1017, 0, hb, 2))
        rpdo = {n: p for n in range(1, 513) if (p := pdo_from_od(od, "rpdo", n)) is not None}
        tpdo = {n: p for n in range(1, 513) if (p := pdo_from_od(od, "tpdo", n)) is not None}
        for number, setting in slave.rpdo.items():
            sdos += _configure_pdo(rpdo[number], setting, od, slave.node_id, next_cob)
        for number, setting in slave.tpdo.items():
            sdos += _configure_pdo(tpdo[number], setting, od, slave.node_id, next_cob)
        for w in slave.sdo:
            sdos.append(SdoValue(w.index, w.sub_index, w.value, _size(od, w.index, w.sub_index)))
        out[name] = SlaveConcise(sdos, rpdo, tpdo)
    # the master's part: consumer heartbeat entries on the slaves (inserted first)
    heartbeat = int(master.heartbeat_producer_ms * master.heartbeat_multiplier)
    for name, slave in cfg.slaves.items():
        od = cfg.ods[name]
        if 0x1016 not in od:
            continue
        subs = [s for s in od[0x1016].subindices if s != 0] if hasattr(od[0x1016], "subindices") \
            else []
        if slave.heartbeat_consumer and heartbeat > 0:
            chosen = 0
            for sub in subs:
                if (_var_default(od, 0x1016, sub) >> 16) & 0xFF == master.node_id:
                    chosen = sub
                    break
            if not chosen:
                for sub in subs:
                    value = _var_default(od, 0x1016, sub)
                    nid = (value >> 16) & 0xFF
                    if value & 0xFFFF == 0 or nid == 0 or nid > 127:
                        chosen = sub
                        break
            if chosen:
                out[name].sdos.insert(0, SdoValue(
                    0x1016, chosen, ((master.node_id & 0xFF) << 16) | (heartbeat & 0xFFFF), 4))
        else:
            for sub in subs:
                value = _var_default(od, 0x1016, sub)
                nid = (value >> 16) & 0xFF
                if value & 0xFFFF and nid == master.node_id:
                    out[name].sdos.insert(0, SdoValue(0x1016, sub, nid << 16, 4))
    return out


def slave_label(slave: SlaveConfig) -> str:
    return f"node {slave.node_id} ({slave.name})"


def pdo_spec(p: PdoState) -> PdoSpec:
    """The configured PDO ``p`` as the master and the devices use it (11-bit COB-ID)."""
    return PdoSpec(p.kind, p.number, p.cob_id & 0x7FF, p.enabled, p.transmission,
                   p.inhibit_time, p.event_timer, p.sync_start, tuple(p.mapping), p.line)


def effective_pdos(cfg: ControllerConfig) -> dict[str, NodePdos]:
    """Per slave name: the PDOs as configured at the end of the boot."""
    out = {}
    for name, c in concise_configuration(cfg).items():
        out[name] = NodePdos({n: pdo_spec(p) for n, p in c.rpdo.items()},
                             {n: pdo_spec(p) for n, p in c.tpdo.items()})
    return out


def pdo_enable_conflicts(cfg: ControllerConfig) -> list[tuple[str, str, int, int | None]]:
    """(slave, kind, number, line) of PDOs asked to be enabled that dcfgen leaves disabled
    (EDS COB-ID with bit 31 set and no ``cob_id`` given)."""
    out = []
    for name, slave in cfg.slaves.items():
        for kind, settings in (("rpdo", slave.rpdo), ("tpdo", slave.tpdo)):
            for number, s in settings.items():
                base = pdo_from_od(cfg.ods[name], kind, number)
                if s.enabled and s.cob_id is None and base is not None \
                        and base.cob_id & INVALID:
                    out.append((name, kind, number, s.line))
    return out


#: CiA 301 (7.3.5, table 3): CAN-IDs reserved for the predefined connection set and NMT;
#: a PDO must not use them
RESTRICTED_CAN_IDS = ((0x000, 0x000), (0x001, 0x07F), (0x101, 0x180), (0x581, 0x5FF),
                      (0x601, 0x67F), (0x6E0, 0x6FF), (0x701, 0x77F), (0x780, 0x7FF))
#: the predefined connection set's default services of node n (CiA 301 7.3.3): EMCY and
#: the first four TPDOs/RPDOs (SDO and heartbeat are restricted anyway)
DEFAULT_SERVICES = ((0x080, "EMCY"), (0x180, "TPDO1"), (0x200, "RPDO1"), (0x280, "TPDO2"),
                    (0x300, "RPDO2"), (0x380, "TPDO3"), (0x400, "RPDO3"), (0x480, "TPDO4"),
                    (0x500, "RPDO4"))


def cob_id_conflict(cob_id: int, own_node: int, nodes: dict[int, str]) -> str | None:
    """Why ``cob_id`` cannot be a PDO of node ``own_node`` on a bus with ``nodes``
    (node-ID -> label, the master included), or None: the SYNC COB-ID, another node's
    predefined EMCY/PDO COB-ID, a restricted CAN-ID."""
    if cob_id == 0x080:
        return "is the SYNC COB-ID (1005h)"
    for base, service in DEFAULT_SERVICES:
        n = cob_id - base
        if 1 <= n <= 127 and n != own_node and n in nodes:
            return f"is the default {service} COB-ID of {nodes[n]} (CiA 301 predefined set)"
    for lo, hi in RESTRICTED_CAN_IDS:
        if lo <= cob_id <= hi:
            return (f"is a restricted CAN-ID (CiA 301: {lo:03X}h..{hi:03X}h are reserved for "
                    "NMT, SYNC, EMCY, SDO and heartbeat)")
    return None


def check_cob_ids(cfg: ControllerConfig) -> None:
    """A PDO enabled in bus.yml but left disabled by dcfgen, two PDOs with one COB-ID, a
    COB-ID that :func:`cob_id_conflict` refuses: :class:`~controller.errors.ConfigError`
    naming the file, line and key."""
    for name, kind, number, line in pdo_enable_conflicts(cfg):
        raise ConfigError(f"{kind.upper()} {number} is disabled in "
                          f"{cfg.slaves[name].dcf.name} (COB-ID bit 31 set): dcfgen keeps it "
                          "disabled unless a cob_id (a number or auto) is given",
                          file=cfg.file, line=line, key=f"{name}.{kind}.{number}")
    owner: dict[int, str] = {}
    nodes = {s.node_id: f"node {s.node_id} ({n})" for n, s in cfg.slaves.items()}
    nodes[cfg.master.node_id] = f"the master (node {cfg.master.node_id})"
    for name, (node_pdos) in effective_pdos(cfg).items():
        slave = cfg.slaves[name]
        for p in node_pdos.all():
            if not p.enabled:
                continue
            what = f"{name} {p.kind.upper()} {p.number}"
            setting = (slave.rpdo if p.kind == "rpdo" else slave.tpdo).get(p.number)
            line = (setting.cob_id_line or setting.line) if setting is not None \
                else slave.line
            if p.cob_id in owner:
                raise ConfigError(f"COB-ID 0x{p.cob_id:03X} of {what} is also used by "
                                  f"{owner[p.cob_id]}", file=cfg.file, line=line,
                                  key=f"{name}.{p.kind}.{p.number}.cob_id")
            why = cob_id_conflict(p.cob_id, slave.node_id, nodes)
            if why is not None:
                origin = "" if setting is not None and setting.cob_id is not None else \
                    f" (the EDS default of {slave.dcf.name})"
                raise ConfigError(f"COB-ID 0x{p.cob_id:03X} of {what}{origin} {why}",
                                  file=cfg.file, line=line,
                                  key=f"{name}.{p.kind}.{p.number}.cob_id")
            owner[p.cob_id] = what
