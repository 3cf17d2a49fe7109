"""``bus.yml``: Lely ``dcfgen``'s bus description plus cantrack's own dot-key sections.

The file is a dcfgen input (``dcfgen -r -d OUT bus.yml`` accepts it) and is read here
strictly: every key is checked (unknown keys with the closest known one suggested, typos,
wrong types, values out of range and objects the slave's EDS does not have) and every error
is a :class:`~controller.errors.ConfigError` naming the file, the line and the dotted key.

Layout (dcfgen's keys, docs/spec/tools.md#1)::

    options: {dcf_path, heartbeat_multiplier, retry_factor}
    master:  {node_id*, baudrate [kbit/s], sync_period* [us], sync_window [us],
              sync_overflow, heartbeat_producer [ms], heartbeat_consumer, heartbeat_multiplier,
              boot_time [ms], start, start_nodes, reset_all_nodes, ...}
    <slave>: {dcf*, node_id*, heartbeat_producer [ms], heartbeat_consumer, revision_number,
              serial_number, boot, mandatory, sdo: [{index, sub_index, value}],
              rpdo/tpdo: {N: {enabled, cob_id, transmission, inhibit_time, event_timer,
                               event_deadline, sync_start, mapping: [{index, sub_index}]}}}
    .tracking:   cantrack's controller settings   (controller.canopen.config.tracking)
    .simulation: simulated devices                (controller.canopen.config.simulation)
    .demo:       the demo's items and pick/place  (controller.canopen.apps.demo)
    .plc:        the controller's node for a PLC  (controller.canopen.config.plc)

dcfgen treats every top-level key except ``options`` and ``master`` as a slave, but skips
keys that start with a dot: that is why our sections are ``.tracking`` etc.

Paths: ``dcf`` is relative to the directory of the bus.yml (dcfgen opens it relative to its
working directory: run dcfgen in the file's directory).  Differences to dcfgen, on purpose:
``master.node_id``, ``master.sync_period`` and each slave's ``node_id`` are required (dcfgen
defaults to 255 = unconfigured / 0 = no SYNC); ``enabled`` must be a YAML boolean (dcfgen
reads the string "false" as true); an SDO write to a read-only object is an error (dcfgen
only warns).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from canopen.objectdictionary import ObjectDictionary

from ...errors import ConfigError
from ...yamlmarks import Section, suggest
from ..io.canbus import BAUDRATES_KBIT
from ..protocol import od as odm
from ..protocol.eds_check import check_eds

if TYPE_CHECKING:  # (the sections are read with the bus part: they import ControllerConfig)
    from .demo import DemoConfig
    from .plc import PlcConfig
    from .simulation import SimulationConfig
    from .tracking import TrackingConfig

__all__ = ["ControllerConfig", "MasterConfig", "Options", "PdoEntry", "PdoSetting", "SdoWrite",
           "SlaveConfig", "parse_bus"]

#: a read-only empty mapping (the default of the config's mappings)
_EMPTY: Mapping[Any, Any] = MappingProxyType({})

#: top-level dot sections cantrack reads
DOT_SECTIONS = (".tracking", ".simulation", ".demo", ".plc")

_PDO_KEYS = ("enabled", "cob_id", "transmission", "inhibit_time", "event_timer",
             "event_deadline", "sync_start", "mapping")


@dataclass(frozen=True, slots=True)
class Options:
    dcf_path: str = ""
    heartbeat_multiplier: float = 3.0
    retry_factor: int = 3


@dataclass(frozen=True, slots=True)
class MasterConfig:
    """The ``master:`` section: the controller as CANopen manager and SYNC producer."""

    node_id: int
    baudrate_kbit: int = 1000
    sync_period_us: int = 2000
    #: synchronous window length [us] (1007h), written to every SYNC consumer that has
    #: 1007h (0: not written): a node that serves a SYNC later sends none of its
    #: synchronous TPDOs (docs/spec/tools.md#1)
    sync_window_us: int = 0
    #: SYNC counter overflow (1019h): 0 = SYNC without counter, else 2..240
    sync_overflow: int = 0
    heartbeat_producer_ms: int = 0
    heartbeat_consumer: bool = True
    heartbeat_multiplier: float = 3.0
    boot_time_ms: int = 0
    start: bool = True
    start_nodes: bool = True
    reset_all_nodes: bool = False
    line: int | None = None
    sync_period_line: int | None = None


@dataclass(frozen=True, slots=True)
class PdoEntry:
    index: int
    sub_index: int
    line: int | None = None


@dataclass(frozen=True, slots=True)
class PdoSetting:
    """One ``rpdo``/``tpdo`` entry as written (None = not given: the EDS default holds)."""

    number: int
    enabled: bool = True
    cob_id: int | str | None = None  # int, "auto" or None
    transmission: int | None = None
    inhibit_time: int | None = None
    event_timer: int | None = None
    event_deadline: int | None = None
    sync_start: int | None = None
    mapping: tuple[PdoEntry, ...] | None = None
    line: int | None = None
    cob_id_line: int | None = None


@dataclass(frozen=True, slots=True)
class SdoWrite:
    index: int
    sub_index: int
    value: int
    line: int | None = None


@dataclass(frozen=True, slots=True)
class SlaveConfig:
    """One slave section (any top-level key other than options/master/dot keys)."""

    name: str
    dcf: Path
    node_id: int
    heartbeat_producer_ms: int | None = None
    heartbeat_consumer: bool = False
    heartbeat_multiplier: float | None = None
    revision_number: int | None = None
    serial_number: int | None = None
    boot: bool = True
    mandatory: bool = False
    reset_communication: bool = True
    sdo: tuple[SdoWrite, ...] = ()
    rpdo: Mapping[int, PdoSetting] = field(default_factory=lambda: _EMPTY)
    tpdo: Mapping[int, PdoSetting] = field(default_factory=lambda: _EMPTY)
    line: int | None = None
    #: the dcfgen keys we accept but do not act on (kept for completeness)
    other: Mapping[str, Any] = field(default_factory=lambda: _EMPTY)

    def hb_multiplier(self, options: Options) -> float:
        return self.heartbeat_multiplier if self.heartbeat_multiplier is not None \
            else options.heartbeat_multiplier


@dataclass(frozen=True)
class ControllerConfig:
    """A loaded bus.yml: dcfgen part, object dictionaries, and our dot sections.

    Immutable: :func:`controller.canopen.config.load_config` builds it complete (the
    sections are added with :func:`dataclasses.replace`, never by mutation); a changed copy
    is made the same way.  Its mappings (``slaves``, ``ods``, each slave's ``rpdo``/``tpdo``,
    ``simulation.devices``) are read-only views (:class:`types.MappingProxyType`).  The
    object dictionaries themselves are python canopen's (mutable) objects: read them only."""

    file: str
    options: Options
    master: MasterConfig
    slaves: Mapping[str, SlaveConfig]
    ods: Mapping[str, ObjectDictionary]
    tracking: TrackingConfig | None = None
    simulation: SimulationConfig | None = None
    demo: DemoConfig | None = None
    plc: PlcConfig | None = None

    @property
    def period_ns(self) -> int:
        return self.master.sync_period_us * 1000

    @property
    def period_s(self) -> float:
        return self.master.sync_period_us * 1e-6

    @property
    def bitrate(self) -> int:
        return self.master.baudrate_kbit * 1000

    def slave_by_node(self, node_id: int) -> SlaveConfig | None:
        for s in self.slaves.values():
            if s.node_id == node_id:
                return s
        return None

    def label(self, name: str) -> str:
        """``"node 11 (x)"`` for messages."""
        return f"node {self.slaves[name].node_id} ({name})"


# -- parsing -------------------------------------------------------------------------------
def parse_bus(top: Section, base_dir: Path) -> tuple[ControllerConfig, set[str]]:
    """The dcfgen part of a bus.yml's top level ``top`` (``options``, ``master``, slaves) and
    the names of the dot sections present (read by :func:`controller.canopen.config.load`).

    The PDO COB-IDs are checked by :func:`controller.canopen.config.concise.check_cob_ids`."""
    file = top.file
    opt_s = top.section("options", None)
    options = _options(opt_s) if opt_s is not None else Options()
    master_s = top.section("master")
    master = _master(master_s, options)
    slaves: dict[str, SlaveConfig] = {}
    ods: dict[str, ObjectDictionary] = {}
    dot: set[str] = set()
    for key, value in top.items():
        if key in ("options", "master"):
            continue
        if not isinstance(key, str):
            raise top.error(key, "a top-level key must be a slave name", at_value=False)
        if key.startswith("."):
            if key not in DOT_SECTIONS:
                raise top.error(key, "unknown section" + suggest(key, DOT_SECTIONS),
                                at_value=False)
            dot.add(key)
            continue
        s = Section(value, file, key, top.value_line(key), top.key_line(key))
        slave, od = _slave(key, s, base_dir, options)
        slaves[key] = slave
        ods[key] = od
    if not slaves:
        raise ConfigError("no slave configured (any top-level key other than options, "
                          "master and dot sections is a slave)", file=file, line=1)
    _check_node_ids(top, master, slaves)
    return ControllerConfig(file, options, master, MappingProxyType(slaves),
                            MappingProxyType(ods)), dot


def _options(s: Section) -> Options:
    o = Options(dcf_path=s.str("dcf_path", ""),
                heartbeat_multiplier=s.float("heartbeat_multiplier", 3.0, min=1.0),
                retry_factor=s.int("retry_factor", 3, min=0, max=100))
    s.finish()
    return o


def _master(s: Section, options: Options) -> MasterConfig:
    period = s.int("sync_period", min=100, max=100_000)
    m = MasterConfig(
        node_id=s.int("node_id", min=1, max=127),
        baudrate_kbit=s.int("baudrate", 1000, allowed=BAUDRATES_KBIT),
        sync_period_us=period,
        sync_window_us=s.int("sync_window", 0, min=0, max=period),
        sync_overflow=s.int("sync_overflow", 0, min=0, max=240),
        heartbeat_producer_ms=s.int("heartbeat_producer", 0, min=0, max=0xFFFF),
        heartbeat_consumer=s.bool("heartbeat_consumer", True),
        heartbeat_multiplier=s.float("heartbeat_multiplier", options.heartbeat_multiplier,
                                     min=1.0),
        boot_time_ms=s.int("boot_time", 0, min=0, max=600_000),
        start=s.bool("start", True),
        start_nodes=s.bool("start_nodes", True),
        reset_all_nodes=s.bool("reset_all_nodes", False),
        line=s.line, sync_period_line=s.value_line("sync_period"),
    )
    if m.sync_overflow == 1:
        raise s.error("sync_overflow", "(=1) must be 0 (no counter) or in [2...240]")
    # accepted dcfgen keys without effect here
    for key in ("vendor_id", "product_code", "revision_number", "serial_number",
                "time_cob_id"):
        s.int(key, None, min=0, max=0xFFFFFFFF)
    for key in ("emcy_inhibit_time", "nmt_inhibit_time"):
        s.int(key, None, min=0, max=0xFFFF)
    for key in ("start_all_nodes", "stop_all_nodes"):
        s.bool(key, None)
    s.section("error_behavior", None)
    s.finish()
    return m


def _slave(name: str, s: Section, base_dir: Path,
           options: Options) -> tuple[SlaveConfig, ObjectDictionary]:
    dcf_text = s.str("dcf")
    dcf = (base_dir / dcf_text) if not Path(dcf_text).is_absolute() else Path(dcf_text)
    if not dcf.is_file():
        raise s.error("dcf", f"EDS/DCF file {str(dcf)!r} not found (relative paths are "
                             "taken from the directory of the bus.yml)")
    node_id = s.int("node_id", min=1, max=127)
    try:
        check_eds(dcf, node_id)  # CiA 306 first: python canopen reads broken files silently
    except ConfigError as exc:
        raise ConfigError(f"{exc.bare_message} (the dcf of '{name}', {s.file}:"
                          f"{s.value_line('dcf')})", file=exc.file, line=exc.line,
                          key=exc.key) from None
    try:
        od = odm.load_od(dcf, node_id)
    except Exception as exc:  # canopen raises assorted errors on a broken file
        raise s.error("dcf", f"cannot read {dcf.name}: {exc}") from exc
    hb = s.int("heartbeat_producer", None, min=0, max=0xFFFF)
    if hb is not None and odm.variable(od, 0x1017) is None:
        raise s.error("heartbeat_producer", f"{dcf.name} has no object 1017h")
    other: dict[str, Any] = {}
    for key in ("dcf_path", "software_file", "configuration_file"):
        other[key] = s.str(key, None)
    for key in ("retry_factor", "software_version", "restore_configuration"):
        other[key] = s.int(key, None, min=0, max=0xFFFFFFFF)
    for key in ("guard_time", "life_time_factor", "time_cob_id", "error_behavior"):
        if s.has(key):
            s.raw(key)
            raise s.error(key, "is a dcfgen key that cantrack's boot does not apply (node "
                               "guarding, TIME and error behaviour are not used); remove it "
                               "or write the object with an 'sdo' entry", at_value=False)
    sdo = tuple(_sdo_write(item, line, path, s.file, od, dcf.name)
                for item, line, path in s.list("sdo", None))
    rpdo = _pdos(s, "rpdo", od, dcf.name)
    tpdo = _pdos(s, "tpdo", od, dcf.name)
    slave = SlaveConfig(
        name=name, dcf=dcf, node_id=node_id, heartbeat_producer_ms=hb,
        heartbeat_consumer=s.bool("heartbeat_consumer", False),
        heartbeat_multiplier=s.float("heartbeat_multiplier", None, min=1.0),
        revision_number=s.int("revision_number", None, min=0, max=0xFFFFFFFF),
        serial_number=s.int("serial_number", None, min=0, max=0xFFFFFFFF),
        boot=s.bool("boot", True), mandatory=s.bool("mandatory", False),
        reset_communication=s.bool("reset_communication", True),
        sdo=sdo, rpdo=MappingProxyType(rpdo), tpdo=MappingProxyType(tpdo), line=s.line,
        other=MappingProxyType({k: v for k, v in other.items() if v is not None}))
    s.finish()
    return slave, od


def _sdo_write(item: Any, line: int | None, path: str, file: str, od: ObjectDictionary,
               eds: str) -> SdoWrite:
    s = Section(item, file, path, line)
    index = s.int("index", min=0x1000, max=0xFFFF)
    sub = s.int("sub_index", 0, min=0, max=0xFF)
    value = s.int("value", 0)
    s.finish()
    var = odm.variable(od, index, sub)
    if var is None:
        raise s.error("index", f"object {index:04X}h:{sub:02X} does not exist in {eds}")
    if not var.writable:
        raise s.error("index", f"object {index:04X}h:{sub:02X} is read-only in {eds} "
                               "(dcfgen only warns; the slave would abort the SDO "
                               "with 06010002h)")
    rng = odm.type_range(var)
    if rng is not None and not (rng[0] <= value <= rng[1]):
        raise s.error("value", f"(={value}) must be in [{rng[0]}...{rng[1]}] for "
                               f"{index:04X}h:{sub:02X}")
    return SdoWrite(index, sub, value, s.line)


def _pdos(s: Section, key: str, od: ObjectDictionary, eds: str) -> dict[int, PdoSetting]:
    sec = s.section(key, None)
    if sec is None:
        return {}
    base = 0x1400 if key == "rpdo" else 0x1800
    out: dict[int, PdoSetting] = {}
    for number, value in sec.items():
        if isinstance(number, bool) or not isinstance(number, int) or not 1 <= number <= 512:
            raise sec.error(number, f"must be a PDO number in [1...512], not {number!r}",
                            at_value=False)
        if (base + number - 1) not in od or (base + 0x200 + number - 1) not in od:
            available = sorted(i - base + 1 for i in od.indices if base <= i < base + 0x200)
            raise sec.error(number, f"{key.upper()} {number} not available in {eds} "
                                    f"(it has {', '.join(map(str, available)) or 'none'})",
                            at_value=False)
        out[number] = _pdo(Section(value, s.file, sec.key_path(number),
                                   sec.value_line(number), sec.key_line(number)),
                           number, key == "rpdo", od, eds)
    return out


def _pdo(s: Section, number: int, is_rpdo: bool, od: ObjectDictionary, eds: str) -> PdoSetting:
    cob = s.raw("cob_id", None)
    if cob is not None and cob != "auto":
        cob = s.int("cob_id", min=0x001, max=0x7FF)
    trans_allowed = "[0...240], 254 or 255" if is_rpdo else "[0...240] or [252...255]"
    trans = s.int("transmission", None, min=0, max=255)
    if trans is not None and (241 <= trans <= 251 or (is_rpdo and trans in (252, 253))):
        raise s.error("transmission", f"(={trans}) must be in {trans_allowed}")
    mapping = None
    if s.has("mapping"):
        entries = []
        bits = 0
        for item, line, path in s.list("mapping"):
            m = Section(item, s.file, path, line)
            index = m.int("index", min=0x0001, max=0xFFFF)
            sub = m.int("sub_index", 0, min=0, max=0xFF)
            m.finish()
            var = odm.variable(od, index, sub)
            if var is None:
                key = "sub_index" if index in od else "index"  # the object is there, not the sub
                raise m.error(key, f"object {index:04X}h:{sub:02X} does not exist in {eds}")
            if not var.pdo_mappable and not 0x0001 <= index <= 0x0007:
                raise m.error("index", f"object {index:04X}h:{sub:02X} cannot be mapped "
                                       f"into a PDO ({eds}: PDOMapping=0)")
            if is_rpdo and not var.writable:
                raise m.error("index", f"object {index:04X}h:{sub:02X} is read-only: it "
                                       "cannot be mapped into an RPDO")
            bits += len(var)
            entries.append(PdoEntry(index, sub, m.line))
        if bits > 64:
            raise s.error("mapping", f"maps {bits} bits, a CAN frame holds at most 64",
                          at_value=False)
        mapping = tuple(entries)
    deadline = s.int("event_deadline", None, min=0, max=0xFFFF)
    if deadline is not None:
        comm = (0x1400 if is_rpdo else 0x1800) + number - 1
        if not is_rpdo:
            raise s.error("event_deadline", "is an RPDO setting (14xxh:05, the slave's deadline "
                                            "monitoring); a TPDO has event_timer")
        if odm.variable(od, comm, 5) is None:
            raise s.error("event_deadline", f"cannot be applied: {eds} has no {comm:04X}h:05 "
                                            "(event timer / deadline monitoring)")
    setting = PdoSetting(
        number=number, enabled=s.bool("enabled", True), cob_id=cob, transmission=trans,
        inhibit_time=s.int("inhibit_time", None, min=0, max=0xFFFF),
        event_timer=s.int("event_timer", None, min=0, max=0xFFFF),
        event_deadline=deadline,
        sync_start=s.int("sync_start", None, min=0, max=240),
        mapping=mapping, line=s.head,
        cob_id_line=s.value_line("cob_id") if s.has("cob_id") else None)
    s.finish()
    return setting


def _check_node_ids(top: Section, master: MasterConfig,
                    slaves: Mapping[str, SlaveConfig]) -> None:
    seen: dict[int, str] = {}
    for name, slave in slaves.items():
        sec = Section(top.data[name], top.file, name, slave.line)
        if slave.node_id == master.node_id:
            raise sec.error("node_id", f"(={slave.node_id}) is the master's node_id")
        if slave.node_id in seen:
            raise sec.error("node_id", f"(={slave.node_id}) is also the node_id of "
                                       f"'{seen[slave.node_id]}'")
        seen[slave.node_id] = name
