"""EDS/DCF files checked as CiA 306 describes them, before python canopen reads them.

python canopen's ``import_od`` is lenient by design (it reads what it can: an unknown
AccessType, ObjectType 0x99, DataType 0xFFFF or PDOMapping=7 load without a word, a missing
sub-index surfaces later as a ``KeyError`` in the middle of a run).  A controller that
configures drives from the file must not guess, so :func:`check_eds` rejects, naming the file,
the line, the section and the key:

- the mandatory sections [FileInfo], [DeviceInfo], [MandatoryObjects]; the object lists
  ([Mandatory|Optional|ManufacturerObjects]: ``SupportedObjects`` = the number of entries
  ``1..N``, each an index whose object section exists; 1000h and 1001h in
  [MandatoryObjects]); every object section listed in one of them;
- per object ([XXXX], [XXXXsubYY]): ``ParameterName``; ``ObjectType`` one of 0x2 DOMAIN,
  0x5 DEFTYPE, 0x6 DEFSTRUCT, 0x7 VAR (the default), 0x8 ARRAY, 0x9 RECORD; a VAR/DOMAIN/
  DEFTYPE: ``DataType`` a CiA 301 data type (0001h..001Bh, or a type defined in the file),
  ``AccessType`` ro | wo | rw | rwr | rww | const, ``PDOMapping`` 0 or 1, ``DefaultValue``,
  ``LowLimit``, ``HighLimit`` within the data type (``$NODEID`` terms allowed); an
  ARRAY/RECORD: ``SubNumber`` = its sub-index sections, sub-index 0 present; no sub-index
  section without its object;
- [DeviceInfo]: the 0/1 flags (``BaudRate_*``, ``SimpleBootUp*``, ``DynamicChannelsSupported``,
  ``GroupMessaging``, ``LSS_Supported``), ``Granularity`` 0..64, ``NrOfRXPDO``/``NrOfTXPDO``
  0..512 and the vendor/product/revision numbers as UNSIGNED32;
- the device profile's mandatory objects (1000h bits 0-15): CiA 402 drives 6040h, 6041h,
  6060h, 6061h, 6502h; CiA 406 encoders 6000h, 6004h; every file 1000h, 1001h, 1018h.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

from ...errors import ConfigError

#: CiA 301 basic data types: number -> (name, value range or None for non-integers)
DATA_TYPES: dict[int, tuple[str, tuple[int, int] | None]] = {
    0x01: ("BOOLEAN", (0, 1)), 0x02: ("INTEGER8", (-2 ** 7, 2 ** 7 - 1)),
    0x03: ("INTEGER16", (-2 ** 15, 2 ** 15 - 1)), 0x04: ("INTEGER32", (-2 ** 31, 2 ** 31 - 1)),
    0x05: ("UNSIGNED8", (0, 2 ** 8 - 1)), 0x06: ("UNSIGNED16", (0, 2 ** 16 - 1)),
    0x07: ("UNSIGNED32", (0, 2 ** 32 - 1)), 0x08: ("REAL32", None),
    0x09: ("VISIBLE_STRING", None), 0x0A: ("OCTET_STRING", None),
    0x0B: ("UNICODE_STRING", None), 0x0C: ("TIME_OF_DAY", None),
    0x0D: ("TIME_DIFFERENCE", None), 0x0F: ("DOMAIN", None),
    0x10: ("INTEGER24", (-2 ** 23, 2 ** 23 - 1)), 0x11: ("REAL64", None),
    0x12: ("INTEGER40", (-2 ** 39, 2 ** 39 - 1)), 0x13: ("INTEGER48", (-2 ** 47, 2 ** 47 - 1)),
    0x14: ("INTEGER56", (-2 ** 55, 2 ** 55 - 1)), 0x15: ("INTEGER64", (-2 ** 63, 2 ** 63 - 1)),
    0x16: ("UNSIGNED24", (0, 2 ** 24 - 1)), 0x18: ("UNSIGNED40", (0, 2 ** 40 - 1)),
    0x19: ("UNSIGNED48", (0, 2 ** 48 - 1)), 0x1A: ("UNSIGNED56", (0, 2 ** 56 - 1)),
    0x1B: ("UNSIGNED64", (0, 2 ** 64 - 1)),
}
ACCESS_TYPES = ("ro", "wo", "rw", "rwr", "rww", "const")
OBJECT_TYPES = {0x2: "DOMAIN", 0x5: "DEFTYPE", 0x6: "DEFSTRUCT", 0x7: "VAR", 0x8: "ARRAY",
                0x9: "RECORD"}
#: device profile (1000h bits 0-15) -> objects the profile makes mandatory
PROFILE_OBJECTS: dict[int, tuple[int, ...]] = {
    402: (0x6040, 0x6041, 0x6060, 0x6061, 0x6502),
    406: (0x6000, 0x6004),
}
COMMON_OBJECTS = (0x1000, 0x1001, 0x1018)

_U8, _U16, _U32, _I8, _I32 = 0x05, 0x06, 0x07, 0x02, 0x04


def standard_type(index: int, sub: int | None) -> int | None:
    """The data type CiA 301 (communication objects) and CiA 402/406 (the objects cantrack
    drives) give ``index:sub``, or None where the file may choose."""
    if sub is None or sub == 0 and index in (0x1000, 0x1001, 0x1005, 0x1006, 0x1007, 0x1014,
                                            0x1015, 0x1017, 0x6040, 0x6041, 0x6060, 0x6061,
                                            0x6064, 0x607A, 0x6004):
        return {0x1000: _U32, 0x1001: _U8, 0x1005: _U32, 0x1006: _U32, 0x1007: _U32,
                0x1014: _U32, 0x1015: _U16, 0x1017: _U16, 0x6040: _U16, 0x6041: _U16,
                0x6060: _I8, 0x6061: _I8, 0x6064: _I32, 0x607A: _I32}.get(index)
    if 0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF:  # PDO communication
        return {0: _U8, 1: _U32, 2: _U8, 3: _U16, 5: _U16}.get(sub)
    if 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:  # PDO mapping
        return _U8 if sub == 0 else _U32
    if index == 0x1018:
        return _U8 if sub == 0 else _U32
    if index in (0x1016, 0x1003):
        return _U8 if sub == 0 else _U32
    return None
_FLAGS = ("simplebootupmaster", "simplebootupslave", "dynamicchannelssupported",
          "groupmessaging", "lss_supported")
_LISTS = ("mandatoryobjects", "optionalobjects", "manufacturerobjects")
_OBJECT = re.compile(r"^([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?$")
_NODEID = re.compile(r"\$NODEID", re.IGNORECASE)


@dataclass
class _Section:
    name: str
    line: int
    entries: dict[str, tuple[str, str, int]] = field(default_factory=dict)  # lower -> (key, value, line)

    def get(self, key: str) -> tuple[str, str, int] | None:
        return self.entries.get(key.lower())


class _File:
    def __init__(self, path: Path, text: str) -> None:
        self.path = str(path)
        self.sections: dict[str, _Section] = {}
        current: _Section | None = None
        for i, raw in enumerate(text.splitlines(), 1):
            line = raw.strip()
            if not line or line.startswith((";", "#")):
                continue
            if line.startswith("["):
                if not line.endswith("]"):
                    self.fail(i, None, f"section header {line!r} has no closing ']'")
                name = line[1:-1].strip()
                if name.lower() in self.sections:
                    self.fail(i, f"[{name}]", "section given twice (first on line "
                                              f"{self.sections[name.lower()].line})")
                current = _Section(name, i)
                self.sections[name.lower()] = current
                continue
            if "=" not in line:
                self.fail(i, f"[{current.name}]" if current else None,
                          f"{line!r} is neither 'key=value' nor a [section]")
            if current is None:
                self.fail(i, None, "an entry before the first [section]")
            key, value = line.split("=", 1)
            key = key.strip()
            value = value.split(";", 1)[0].strip() if ";" in value and not \
                key.lower().endswith("name") else value.strip()
            if key.lower() in current.entries:
                self.fail(i, f"[{current.name}] {key}", "key given twice in the section")
            current.entries[key.lower()] = (key, value, i)

    def fail(self, line: int | None, where: str | None, message: str) -> NoReturn:
        raise ConfigError(f"{message} (CiA 306)", file=self.path, line=line, key=where)

    def section(self, name: str) -> _Section | None:
        return self.sections.get(name.lower())

    def need(self, name: str) -> _Section:
        """A section checked to be there (:func:`check_eds` does it first)."""
        sec = self.section(name)
        if sec is None:
            self.fail(1, f"[{name}]", "mandatory section is missing")
        return sec


def _number(text: str) -> int | None:
    """An EDS integer: decimal, 0x hex or 0 octal (CiA 306 2.2), None if it is not one."""
    t = text.strip()
    if not t:
        return None
    try:
        if re.fullmatch(r"[-+]?0[xX][0-9A-Fa-f]+", t):
            return int(t, 16)
        if re.fullmatch(r"[-+]?0[0-7]+", t):
            return int(t, 8)
        if re.fullmatch(r"[-+]?[0-9]+", t):
            if len(t) > 25:
                return None
            return int(t, 10)
    except ValueError:  # pragma: no cover - the patterns exclude it
        return None
    return None


def _value(text: str, node_id: int) -> int | None:
    """A value with ``$NODEID`` terms (``$NODEID+0x180``, ``0x180+$NODEID``) resolved."""
    t = text.strip()
    if _NODEID.search(t):
        parts = [p.strip() for p in t.split("+")]
        total = 0
        for p in parts:
            if _NODEID.fullmatch(p):
                total += node_id
            else:
                n = _number(p)
                if n is None:
                    return None
                total += n
        return total
    return _number(t)


def _float(text: str) -> bool:
    t = text.strip()
    if _number(t) is not None:
        return True  # (a hex bit pattern or an integer)
    try:
        v = float(t)
    except ValueError:
        return False
    return math.isfinite(v)


def check_eds(path: str | Path, node_id: int = 1) -> None:
    """Check an EDS/DCF file (see the module docstring); raises ConfigError."""
    p = Path(path)
    data = p.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # (EDS files are often Latin-1; both are fine)
    f = _File(p, text)
    for name in ("FileInfo", "DeviceInfo", "MandatoryObjects"):
        if f.section(name) is None:
            f.fail(1, f"[{name}]", "mandatory section is missing")
    types = _check_lists(f)
    _check_device_info(f)
    for sec in f.sections.values():
        m = _OBJECT.match(sec.name)
        if m:
            _check_object(f, sec, m, types, node_id)
    _check_profile(f, node_id)


def _check_lists(f: _File) -> set[int]:
    listed: set[int] = set()
    for lname in _LISTS:
        sec = f.section(lname)
        if sec is None:
            continue
        so = sec.get("SupportedObjects")
        if so is None:
            f.fail(sec.line, f"[{sec.name}] SupportedObjects", "entry is missing")
        n = _number(so[1])
        if n is None or not 0 <= n <= 0xFFFF:
            f.fail(so[2], f"[{sec.name}] SupportedObjects",
                   f"(={so[1]!r}) must be a number of objects")
        numbered = {k: v for k, v in sec.entries.items() if k != "supportedobjects"}
        for i in range(1, n + 1):
            e = sec.get(str(i))
            if e is None:
                f.fail(so[2], f"[{sec.name}] {i}",
                       f"SupportedObjects={n} but entry {i} is missing")
            idx = _number(e[1])
            if idx is None or not 0 < idx <= 0xFFFF:
                f.fail(e[2], f"[{sec.name}] {e[0]}", f"(={e[1]!r}) must be an object index "
                                                     "(0x0001..0xFFFF)")
            if f.section(f"{idx:04X}") is None:
                f.fail(e[2], f"[{sec.name}] {e[0]}",
                       f"lists object {idx:04X}h, which has no [{idx:04X}] section")
            listed.add(idx)
        for k, (key, _value, line) in numbered.items():
            if not (k.isdigit() and 1 <= int(k) <= n):
                f.fail(line, f"[{sec.name}] {key}",
                       f"is not one of the entries 1..{n} (SupportedObjects={n})")
    mand = f.need("MandatoryObjects")
    mand_idx = {_number(v[1]) for k, v in mand.entries.items() if k != "supportedobjects"}
    for idx in (0x1000, 0x1001):
        if idx not in mand_idx:
            f.fail(mand.line, "[MandatoryObjects]", f"does not list {idx:04X}h")
    for sec in f.sections.values():
        m = _OBJECT.match(sec.name)
        if m and m.group(2) is None and int(m.group(1), 16) not in listed \
                and int(m.group(1), 16) >= 0x1000:
            f.fail(sec.line, f"[{sec.name}]", "object section not listed in "
                                               "[Mandatory|Optional|ManufacturerObjects]")
    # types the file defines itself (DEFTYPE/DEFSTRUCT below 1000h)
    return {int(m.group(1), 16) for s in f.sections.values()
            if (m := _OBJECT.match(s.name)) and m.group(2) is None
            and int(m.group(1), 16) < 0x1000}


def _check_device_info(f: _File) -> None:
    sec = f.need("DeviceInfo")
    for k, (key, value, line) in sec.entries.items():
        n = _number(value)
        if k.startswith("baudrate_") or k in _FLAGS:
            if n not in (0, 1):
                f.fail(line, f"[DeviceInfo] {key}", f"(={value!r}) must be 0 or 1")
        elif k == "granularity":
            if n is None or not 0 <= n <= 64:
                f.fail(line, f"[DeviceInfo] {key}", f"(={value!r}) must be 0..64")
        elif k in ("nrofrxpdo", "nroftxpdo"):
            if n is None or not 0 <= n <= 512:
                f.fail(line, f"[DeviceInfo] {key}", f"(={value!r}) must be 0..512")
        elif k in ("vendornumber", "productnumber", "revisionnumber", "ordercode_number"):
            if value and (n is None or not 0 <= n <= 0xFFFFFFFF):
                f.fail(line, f"[DeviceInfo] {key}", f"(={value!r}) must be an UNSIGNED32")


def _check_object(f: _File, sec: _Section, m: re.Match, types: set[int], node_id: int) -> None:
    where = f"[{sec.name}]"
    index = int(m.group(1), 16)
    is_sub = m.group(2) is not None
    if is_sub and f.section(f"{m.group(1)}") is None:
        f.fail(sec.line, where, f"sub-index section without its object [{m.group(1)}]")
    name = sec.get("ParameterName")
    if name is None or not name[1]:
        f.fail(name[2] if name else sec.line, f"{where} ParameterName",
               "mandatory entry is missing or empty")
    ot = sec.get("ObjectType")
    otype: int | None = 0x7
    if ot is not None:
        otype = _number(ot[1])
        if otype is None or otype not in OBJECT_TYPES:
            f.fail(ot[2], f"{where} ObjectType", f"(={ot[1]!r}) must be one of "
                   + ", ".join(f"0x{k:X} {v}" for k, v in OBJECT_TYPES.items()))
    if otype in (0x8, 0x9):
        if is_sub:
            f.fail(ot[2] if ot else sec.line, f"{where} ObjectType",
                   "a sub-index cannot be an ARRAY or RECORD")
        sn = sec.get("SubNumber")
        if sn is None:
            f.fail(sec.line, f"{where} SubNumber", f"mandatory for an "
                                                   f"{OBJECT_TYPES[otype]}, missing")
        n = _number(sn[1])
        if n is None or not 1 <= n <= 256:
            f.fail(sn[2], f"{where} SubNumber", f"(={sn[1]!r}) must be 1..256")
        prefix = f"{m.group(1).lower()}sub"
        subs = [s for k, s in f.sections.items() if k.startswith(prefix)
                and _OBJECT.match(s.name)]
        if len(subs) != n:
            f.fail(sn[2], f"{where} SubNumber",
                   f"(={n}) but the file has {len(subs)} [{m.group(1)}subX] sections")
        if f.section(f"{m.group(1)}sub0") is None:
            f.fail(sec.line, f"[{m.group(1)}sub0]", "sub-index 0 of an "
                                                     f"{OBJECT_TYPES[otype]} is missing")
        return
    if otype == 0x6:  # DEFSTRUCT: described by its sub-indices
        return
    dt = sec.get("DataType")
    if dt is None:
        f.fail(sec.line, f"{where} DataType", "mandatory entry is missing")
    dtype = _number(dt[1])
    if dtype is None or (dtype not in DATA_TYPES and dtype not in types):
        f.fail(dt[2], f"{where} DataType", f"(={dt[1]!r}) is not a CiA 301 data type "
                                           "(0x0001..0x001B) nor one defined in the file")
    want = standard_type(index, int(m.group(2), 16) if is_sub else None)
    if want is not None and dtype != want and dtype in DATA_TYPES:
        f.fail(dt[2], f"{where} DataType",
               f"(={dt[1]!r}, {DATA_TYPES[dtype][0]}) must be 0x{want:04X} "
               f"({DATA_TYPES[want][0]}) for {index:04X}h (CiA 301/402/406)")
    at = sec.get("AccessType")
    if at is None:
        f.fail(sec.line, f"{where} AccessType", "mandatory entry is missing")
    if at[1].strip().lower() not in ACCESS_TYPES:
        f.fail(at[2], f"{where} AccessType", f"(={at[1]!r}) must be one of "
                                             + ", ".join(ACCESS_TYPES))
    pm = sec.get("PDOMapping")
    if pm is not None and _number(pm[1]) not in (0, 1):
        f.fail(pm[2], f"{where} PDOMapping", f"(={pm[1]!r}) must be 0 or 1")
    info = DATA_TYPES.get(dtype)
    for key in ("DefaultValue", "LowLimit", "HighLimit", "ParameterValue"):
        e = sec.get(key)
        if e is None or not e[1] or info is None:
            continue
        tname, rng = info
        if rng is not None:
            v = _value(e[1], node_id)
            if v is None:
                f.fail(e[2], f"{where} {e[0]}", f"(={e[1]!r}) is not a number ({tname})")
            lo, hi = rng
            if not lo <= v <= hi:
                # (a negative type's value may be written as its two's complement bit pattern)
                bits = {0x02: 8, 0x03: 16, 0x04: 32, 0x10: 24, 0x12: 40, 0x13: 48,
                        0x14: 56, 0x15: 64}.get(dtype)
                if not (bits and 0 <= v < (1 << bits)):
                    f.fail(e[2], f"{where} {e[0]}",
                           f"(={e[1]!r}) outside {tname} [{lo}..{hi}]")
        elif tname in ("REAL32", "REAL64"):
            if not _float(e[1]) or (tname == "REAL32" and not _real32_ok(e[1])):
                f.fail(e[2], f"{where} {e[0]}", f"(={e[1]!r}) is not a finite {tname}")


def _real32_ok(text: str) -> bool:
    n = _number(text)
    if n is not None:
        return 0 <= n <= 0xFFFFFFFF or -(1 << 31) <= n < (1 << 31)
    try:
        struct.pack("<f", float(text))
    except (OverflowError, ValueError):
        return False
    return True


def _check_profile(f: _File, node_id: int) -> None:
    for idx in COMMON_OBJECTS:
        if f.section(f"{idx:04X}") is None:
            f.fail(1, f"[{idx:04X}]", f"object {idx:04X}h is mandatory (CiA 301)")
    dev = f.section("1000")
    dv = dev.get("DefaultValue") if dev else None
    if dv is None or not dv[1]:
        return
    profile = (_value(dv[1], node_id) or 0) & 0xFFFF
    for idx in PROFILE_OBJECTS.get(profile, ()):
        if f.section(f"{idx:04X}") is None:
            f.fail(dv[2], f"[{idx:04X}]", f"object {idx:04X}h is mandatory for a CiA "
                                          f"{profile} device (1000h = {dv[1]})")
