"""PDOs (CiA 301): communication/mapping parameters, a configured PDO, packing of its data.

:class:`PdoSpec` is one PDO as configured (the bus.yml on top of the EDS defaults is applied
by :func:`controller.canopen.config.concise.effective_pdos`).  :class:`PdoCodec` packs and
unpacks one PDO's mapped
values with one precompiled ``struct`` (little endian, CiA 301 byte order); only byte-aligned
mappings of 8/16/32/64-bit objects (and dummy entries) are supported, which is what the EDS
files' granularity of 8 allows.

Transmission types (CiA 301): 0 acyclic synchronous, 1-240 every n-th SYNC, 252/253 RTR,
254/255 event driven.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

from canopen.objectdictionary import ObjectDictionary

from . import od as odm

#: COB-ID bit 31: the PDO is not valid (disabled)
INVALID = 0x80000000
_DUMMY_FORMAT = {0x0001: "?", 0x0002: "b", 0x0003: "h", 0x0004: "i", 0x0005: "B",
                 0x0006: "H", 0x0007: "I"}


@dataclass(frozen=True)
class PdoParams:
    """A PDO as its communication (1400h/1800h + n) and mapping (+200h) objects describe it."""

    cob_id: int
    transmission: int
    inhibit_ns: int  # sub 3, in 100 us units on the bus (0: none or not a TPDO)
    event_ns: int  # sub 5, in ms on the bus (0: none or not a TPDO)
    mapping: list[tuple[int, int, int]]  # (index, sub-index, bit length)


def read_pdo_params(load, has, comm: int, tpdo: bool) -> PdoParams | None:
    """Decode the PDO at communication object ``comm`` from an object store.

    ``load(index, sub)`` returns a stored value, ``has(index, sub)`` whether the object exists.
    None when the PDO is invalid (COB-ID bit 31) or maps nothing.  Inhibit time and event
    timer are read for TPDOs only.
    """
    cob = int(load(comm, 1))
    if cob & INVALID:
        return None
    n = int(load(comm + 0x200, 0))
    mapping = []
    for i in range(1, n + 1):
        v = int(load(comm + 0x200, i))
        mapping.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
    if not mapping:
        return None
    inhibit = int(load(comm, 3)) * 100_000 if tpdo and has(comm, 3) else 0
    event = int(load(comm, 5)) * 1_000_000 if tpdo and has(comm, 5) else 0
    return PdoParams(cob & 0x7FF, int(load(comm, 2)), inhibit, event, mapping)


def is_cyclic(transmission: int) -> bool:
    """Sent on SYNC (transmission types 0...240)."""
    return 0 <= transmission <= 240


@dataclass(frozen=True, slots=True)
class PdoSpec:
    """A configured PDO of a slave (``kind`` from the slave's point of view)."""

    kind: str  # "rpdo" (the slave receives) | "tpdo" (the slave transmits)
    number: int
    cob_id: int  # 11-bit identifier
    enabled: bool
    transmission: int
    inhibit_time: int
    event_timer: int
    sync_start: int
    mapping: tuple[tuple[int, int, int], ...]  # (index, sub-index, bits)
    line: int | None = None

    @property
    def comm_index(self) -> int:
        return (0x1400 if self.kind == "rpdo" else 0x1800) + self.number - 1

    @property
    def size(self) -> int:
        """Data bytes on the wire."""
        return sum(bits for _, _, bits in self.mapping) // 8

    def maps(self, index: int, sub_index: int = 0) -> bool:
        return any(i == index and s == sub_index for i, s, _ in self.mapping)

    def objects(self) -> list[tuple[int, int]]:
        return [(i, s) for i, s, _ in self.mapping]


@dataclass(frozen=True)
class NodePdos:
    rpdo: dict[int, PdoSpec]
    tpdo: dict[int, PdoSpec]

    def all(self) -> Iterator[PdoSpec]:
        yield from self.rpdo.values()
        yield from self.tpdo.values()

    def find(self, kind: str, objects: Iterable[tuple[int, int]]) -> PdoSpec | None:
        """The first enabled PDO of ``kind`` that maps all ``objects``."""
        wanted = list(objects)
        for p in (self.rpdo if kind == "rpdo" else self.tpdo).values():
            if p.enabled and all(p.maps(i, s) for i, s in wanted):
                return p
        return None


class PdoCodec:
    """Pack/unpack the values of one PDO (one value per mapping entry, in order)."""

    def __init__(self, spec: PdoSpec, od: ObjectDictionary) -> None:
        fmt = "<"
        for index, sub, bits in spec.mapping:
            if index < 0x1000:
                fmt += _DUMMY_FORMAT.get(index, "x" * (bits // 8))
                continue
            var = odm.variable(od, index, sub)
            if var is None or var.data_type not in odm.STRUCT_FORMAT or len(var) != bits:
                raise ValueError(f"{spec.kind.upper()} {spec.number}: cannot pack "
                                 f"{index:04X}h:{sub:02X} ({bits} bits)")
            fmt += odm.STRUCT_FORMAT[var.data_type]
        self.spec = spec
        self.struct = struct.Struct(fmt)
        self.objects = spec.objects()

    def pack(self, values: Sequence[int | float]) -> bytes:
        return self.struct.pack(*values)

    def unpack(self, data: bytes | bytearray) -> tuple:
        return self.struct.unpack_from(data)

    def position(self, index: int, sub_index: int = 0) -> int:
        """Position of ``index:sub_index`` in the packed tuple."""
        return self.objects.index((index, sub_index))
