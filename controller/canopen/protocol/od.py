"""Object dictionaries from the EDS files (python canopen's ``import_od``) and their types.

Only reading: which objects exist, their type, access and default.  canopen 2.4.1 quirks
handled here (eds/README.md): REAL32 defaults written as hex bit patterns are not loaded
(``default`` is None, the text is in ``default_raw``).
"""

from __future__ import annotations

import struct
from functools import lru_cache
from pathlib import Path

import canopen
from canopen.objectdictionary import (
    BOOLEAN,
    INTEGER8,
    INTEGER16,
    INTEGER32,
    INTEGER64,
    REAL32,
    REAL64,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    UNSIGNED64,
    ObjectDictionary,
    ODVariable,
)

#: CANopen data type -> struct format character (little endian packing is added by users)
STRUCT_FORMAT: dict[int, str] = {
    BOOLEAN: "?", INTEGER8: "b", INTEGER16: "h", INTEGER32: "i", INTEGER64: "q",
    UNSIGNED8: "B", UNSIGNED16: "H", UNSIGNED32: "I", UNSIGNED64: "Q",
    REAL32: "f", REAL64: "d",
}

#: value range of the integer types: data type -> (min, max)
INT_RANGE: dict[int, tuple[int, int]] = {
    BOOLEAN: (0, 1),
    INTEGER8: (-0x80, 0x7F), INTEGER16: (-0x8000, 0x7FFF),
    INTEGER32: (-0x80000000, 0x7FFFFFFF), INTEGER64: (-(1 << 63), (1 << 63) - 1),
    UNSIGNED8: (0, 0xFF), UNSIGNED16: (0, 0xFFFF), UNSIGNED32: (0, 0xFFFFFFFF),
    UNSIGNED64: (0, (1 << 64) - 1),
}

#: CiA 301 1000h device type, low 16 bits = device profile number
PROFILE_DRIVE = 402
PROFILE_ENCODER = 406


@lru_cache(maxsize=64)
def _load(path: str, node_id: int, mtime: float) -> ObjectDictionary:
    return canopen.import_od(path, node_id)


def load_od(path: str | Path, node_id: int) -> ObjectDictionary:
    """The object dictionary of an EDS/DCF file with ``$NODEID`` resolved (cached)."""
    p = Path(path)
    return _load(str(p.resolve()), int(node_id), p.stat().st_mtime)


def variable(od: ObjectDictionary, index: int, sub_index: int = 0) -> ODVariable | None:
    """The variable ``index:sub_index`` (a plain VAR answers sub-index 0), or None."""
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if sub_index == 0 else None
    if sub_index not in obj:
        return None
    return obj[sub_index]


def default_value(var: ODVariable) -> int | float | None:
    """The EDS default of ``var``; REAL32 hex bit patterns decoded (canopen leaves None)."""
    if var.default is not None:
        return var.default
    raw = getattr(var, "default_raw", None)
    if raw and var.data_type == REAL32 and raw.lower().startswith("0x"):
        return struct.unpack("<f", struct.pack("<I", int(raw, 16)))[0]
    return None


def size_bytes(var: ODVariable) -> int:
    """Size of a numeric variable in bytes."""
    return max(1, len(var) // 8)


def profile(od: ObjectDictionary) -> int:
    """The device profile number (1000h bits 0-15): 402 drive, 406 encoder, 0 none."""
    var = variable(od, 0x1000)
    value = default_value(var) if var is not None else None
    return int(value or 0) & 0xFFFF


def in_range(var: ODVariable, value: int) -> bool:
    rng = type_range(var)
    return rng is None or rng[0] <= value <= rng[1]


def type_range(var: ODVariable) -> tuple[int, int] | None:
    """The value range of an integer data type; None for other types (or none given)."""
    return INT_RANGE.get(var.data_type) if var.data_type is not None else None
