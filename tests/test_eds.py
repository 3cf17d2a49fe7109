"""Checks of the EDS files of the devices cantrack defines (eds/, described in eds/README.md).

1. Lely's ``dcfchk`` (PyPI dcf-tools) accepts every file with ``-n 5`` and prints nothing;
   three deliberately broken copies show that it does reject what the notes say it rejects.
2. ``canopen.import_od`` (python canopen) reads every file: object types and access types,
   key default values, ``$NODEID`` COB-IDs, and the default PDO mappings (each entry names an
   existing, mappable object of the mapped length; at most 64 bits per PDO). The same
   mappings are decoded independently with dcf-tools' own parser and compared.
3. A ``canopen.LocalNode`` built from each file serves SDO uploads (identity, resolved
   COB-ID, REAL32 defaults) and sends / receives its default PDOs over python-can's
   ``virtual`` interface to a ``RemoteNode`` on a second bus of the same channel.

No sleeps: the PDO tests wait on a ``threading.Event`` set by the receive callback (bounded
by a time-out that only matters on failure); the SDO client waits for its reply.
"""

from __future__ import annotations

import configparser
import contextlib
import re
import shutil
import struct
import subprocess
import threading
import uuid
import warnings
from pathlib import Path
from typing import Iterator, NamedTuple

import can
import canopen
import pytest
from canopen.objectdictionary import (
    INTEGER8, INTEGER16, INTEGER32, REAL32, UNSIGNED8, UNSIGNED16, UNSIGNED32, ODVariable)
from canopen.objectdictionary.datatypes import FLOAT_TYPES, SIGNED_TYPES

EDS_DIR = Path(__file__).resolve().parents[1] / "eds"
FILES = {name: EDS_DIR / f"cantrack-{name}.eds" for name in ("encoder", "servo", "controller")}
NODE_ID = 5
DCFCHK = shutil.which("dcfchk")
SKIP_NO_DCFCHK = pytest.mark.skipif(
    DCFCHK is None, reason="dcfchk not installed (pip install 'dcf-tools>=2.4', test extra)")
#: Bound of the wait for one PDO on the in-process virtual bus, s (reached only on failure).
PDO_WAIT_S = 2.0
#: Notifier poll period, s: Network.disconnect() waits up to this long per network.
NOTIFIER_CYCLE_S = 0.02

VENDOR_ID = 0x00CA7AC0  # cantrack placeholder, not CiA-assigned (eds/README.md)
REVISION = 0x00010000
PRODUCT_CODE = {"encoder": 0x04060001, "servo": 0x04020001, "controller": 0x03010001}
DEVICE_TYPE = {"encoder": 0x00020196, "servo": 0x00020192, "controller": 0x00000000}


# ------------------------------------------------------------------------ expected content
RO, RW, CONST = "ro", "rw", "const"

#: (index, sub-index) -> (data type, access type), common to the three files
COMMON_OBJECTS = {
    (0x1000, 0): (UNSIGNED32, RO), (0x1001, 0): (UNSIGNED8, RO),
    (0x1003, 0): (UNSIGNED8, RW), (0x1003, 1): (UNSIGNED32, RO),
    (0x1005, 0): (UNSIGNED32, RW), (0x1006, 0): (UNSIGNED32, RW),
    (0x1014, 0): (UNSIGNED32, RW), (0x1015, 0): (UNSIGNED16, RW),
    (0x1017, 0): (UNSIGNED16, RW),
    (0x1018, 0): (UNSIGNED8, RO), (0x1018, 1): (UNSIGNED32, RO), (0x1018, 2): (UNSIGNED32, RO),
    (0x1018, 3): (UNSIGNED32, RO), (0x1018, 4): (UNSIGNED32, RO),
    (0x1200, 1): (UNSIGNED32, RO), (0x1200, 2): (UNSIGNED32, RO),
}
PROFILE_OBJECTS = {
    "encoder": {
        (0x6000, 0): (UNSIGNED16, RW), (0x6001, 0): (UNSIGNED32, RW),
        (0x6002, 0): (UNSIGNED32, RW), (0x6003, 0): (UNSIGNED32, RW),
        (0x6004, 0): (UNSIGNED32, RO), (0x6030, 0): (UNSIGNED8, RO),
        (0x6030, 1): (INTEGER16, RO), (0x6200, 0): (UNSIGNED16, RW),
        (0x6500, 0): (UNSIGNED16, RO), (0x6501, 0): (UNSIGNED32, RO),
        (0x6502, 0): (UNSIGNED16, RO),
    },
    "servo": {
        (0x1016, 1): (UNSIGNED32, RW), (0x6007, 0): (INTEGER16, RW),
        (0x603F, 0): (UNSIGNED16, RO), (0x6040, 0): (UNSIGNED16, RW),
        (0x6041, 0): (UNSIGNED16, RO), (0x605A, 0): (INTEGER16, RW),
        (0x6060, 0): (INTEGER8, RW), (0x6061, 0): (INTEGER8, RO),
        (0x6064, 0): (INTEGER32, RO), (0x6065, 0): (UNSIGNED32, RW),
        (0x6066, 0): (UNSIGNED16, RW), (0x606C, 0): (INTEGER32, RO),
        (0x607A, 0): (INTEGER32, RW), (0x607C, 0): (INTEGER32, RW),
        (0x607D, 1): (INTEGER32, RW), (0x607D, 2): (INTEGER32, RW),
        (0x6081, 0): (UNSIGNED32, RW), (0x6083, 0): (UNSIGNED32, RW),
        (0x6084, 0): (UNSIGNED32, RW), (0x6085, 0): (UNSIGNED32, RW),
        (0x608F, 1): (UNSIGNED32, RO), (0x608F, 2): (UNSIGNED32, RO),
        (0x6098, 0): (INTEGER8, RW), (0x6099, 1): (UNSIGNED32, RW),
        (0x6099, 2): (UNSIGNED32, RW), (0x609A, 0): (UNSIGNED32, RW),
        (0x60B0, 0): (INTEGER32, RW), (0x60B1, 0): (INTEGER32, RW),
        (0x60B8, 0): (UNSIGNED16, RW), (0x60B9, 0): (UNSIGNED16, RO),
        (0x60BA, 0): (INTEGER32, RO), (0x60C2, 0): (UNSIGNED8, RO),
        (0x60C2, 1): (UNSIGNED8, RW), (0x60C2, 2): (INTEGER8, RW),
        (0x60F4, 0): (INTEGER32, RO), (0x60FD, 0): (UNSIGNED32, RO),
        (0x6502, 0): (UNSIGNED32, RO),
    },
    "controller": {
        (0x1016, 0): (UNSIGNED8, RO), (0x1016, 1): (UNSIGNED32, RW),
        (0x1016, 8): (UNSIGNED32, RW), (0x1019, 0): (UNSIGNED8, RW),
        (0x2000, 0): (UNSIGNED8, RO), (0x2001, 0): (INTEGER8, RO),
        (0x2002, 0): (UNSIGNED16, RO), (0x2003, 0): (UNSIGNED32, RO),
        (0x2004, 0): (UNSIGNED8, RW), (0x2005, 0): (UNSIGNED8, RW),
        (0x2006, 0): (UNSIGNED32, RO), (0x2007, 0): (REAL32, RO),
        (0x2008, 0): (REAL32, RO), (0x2010, 0): (UNSIGNED8, RO),
        (0x2010, 1): (REAL32, RW), (0x2010, 2): (REAL32, RW), (0x2010, 3): (REAL32, RW),
        (0x2011, 0): (UNSIGNED8, RO), (0x2012, 0): (UNSIGNED32, RO),
        (0x2013, 0): (UNSIGNED32, RO), (0x2014, 0): (UNSIGNED8, RW),
        (0x2015, 0): (UNSIGNED8, RO), (0x2015, 1): (UNSIGNED32, RW),
        (0x2015, 8): (UNSIGNED32, RW), (0x2016, 0): (UNSIGNED32, RO),
        (0x2020, 0): (UNSIGNED8, RO),
        (0x2020, 1): (UNSIGNED8, RO), (0x2020, 2): (UNSIGNED8, RO),
        (0x2020, 3): (UNSIGNED32, RO), (0x2020, 4): (UNSIGNED16, RO),
        (0x2020, 5): (UNSIGNED8, RO),
    },
}


class Pdo(NamedTuple):
    """Expected default of one PDO: communication index, enabled, COB-ID without node-ID,
    transmission type, mapping as (index, sub-index, bits)."""

    comm: int
    enabled: bool
    cob_base: int
    trans_type: int
    mapping: tuple[tuple[int, int, int], ...]


PDOS = {
    "encoder": (
        Pdo(0x1800, True, 0x180, 1, ((0x6004, 0, 32), (0x6030, 1, 16))),
        Pdo(0x1801, False, 0x280, 254, ((0x6004, 0, 32),)),
    ),
    "servo": (
        Pdo(0x1400, True, 0x200, 1, ((0x6040, 0, 16), (0x607A, 0, 32))),
        Pdo(0x1401, True, 0x300, 255, ((0x6060, 0, 8), (0x60B8, 0, 16))),
        Pdo(0x1402, False, 0x400, 1, ((0x60B1, 0, 32),)),
        Pdo(0x1403, False, 0x500, 255, ()),
        Pdo(0x1800, True, 0x180, 1, ((0x6041, 0, 16), (0x6064, 0, 32))),
        Pdo(0x1801, True, 0x280, 255, ((0x60B9, 0, 16), (0x60BA, 0, 32))),
        Pdo(0x1802, True, 0x380, 255, ((0x60FD, 0, 32), (0x603F, 0, 16), (0x6061, 0, 8))),
        Pdo(0x1803, False, 0x480, 1, ((0x606C, 0, 32), (0x60F4, 0, 32))),
    ),
    "controller": (
        Pdo(0x1400, True, 0x200, 254, ((0x2005, 0, 8), (0x2004, 0, 8))),
        Pdo(0x1401, True, 0x300, 254, ((0x2014, 0, 8), (0x2004, 0, 8))),
        Pdo(0x1800, True, 0x180, 254,
            ((0x2000, 0, 8), (0x2001, 0, 8), (0x2002, 0, 16), (0x2003, 0, 32))),
        Pdo(0x1801, True, 0x280, 254, ((0x2007, 0, 32), (0x2008, 0, 32))),
        Pdo(0x1802, True, 0x380, 254, ((0x2006, 0, 32),)),
    ),
}


# ------------------------------------------------------------------------ helpers
def _od(name: str, node_id: int = NODE_ID) -> canopen.ObjectDictionary:
    return canopen.import_od(str(FILES[name]), node_id=node_id)


def _entry(od: canopen.ObjectDictionary, index: int, sub: int) -> ODVariable | None:
    """The variable at index/sub, or None. Unlike ``od[index][sub]`` this does not let an
    ODArray invent a missing sub-index from its sub 1 template."""
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if sub == 0 else None
    return obj.subindices.get(sub)


def _real32(bit_pattern: str) -> float:
    """A REAL32 EDS default written as an IEEE 754 bit pattern ('0x447A0000' -> 1000.0).

    canopen 2.4.1 parses REAL defaults with float() and leaves ``default`` None for hex
    patterns; dcfchk insists on the pattern. ``default_raw`` keeps the text.
    """
    return struct.unpack(">f", int(bit_pattern, 16).to_bytes(4, "big"))[0]


def _decode_mapping(od: canopen.ObjectDictionary, map_index: int) -> list[tuple[int, int, int]]:
    count = od[map_index][0].default
    out = []
    for sub in range(1, count + 1):
        value = od[map_index][sub].default
        out.append((value >> 16, (value >> 8) & 0xFF, value & 0xFF))
    return out


def _ini(name: str) -> configparser.RawConfigParser:
    ini = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    ini.optionxform = str
    ini.read(FILES[name])
    return ini


def _test_value(var: ODVariable) -> int | float:
    """A value that exercises the sign / top bit of ``var`` and respects its EDS limits."""
    if var.data_type in FLOAT_TYPES:
        return 1234.5
    bits = len(var)
    if var.data_type in SIGNED_TYPES:
        return var.min if var.min is not None else -(1 << (bits - 2)) - 3
    return var.max if var.max is not None else (1 << (bits - 1)) + 3


@contextlib.contextmanager
def _virtual_pair(tag: str) -> Iterator[tuple[canopen.Network, canopen.Network]]:
    """Two canopen networks on two python-can virtual buses of one fresh channel."""
    channel = f"eds-test-{tag}-{uuid.uuid4().hex[:8]}"
    buses = [can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
             for _ in range(2)]
    networks = [canopen.Network(bus) for bus in buses]
    try:
        for net in networks:
            net.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            net.connect()
        yield networks[0], networks[1]
    finally:
        errors = []
        for net in networks:
            try:
                net.disconnect()  # stops the notifier, shuts the bus down, re-raises its errors
            except Exception as exc:  # noqa: BLE001 - disconnect the other network first
                errors.append(exc)
        for bus in buses:
            bus.shutdown()  # idempotent; covers a network whose connect() failed
        if errors:
            raise errors[0]


def _transfer(sender_map, receiver_map) -> list:
    """Send ``sender_map`` once and return the values ``receiver_map`` decoded from it."""
    received = threading.Event()
    snapshot: list = []

    def on_pdo(pdo_map) -> None:
        snapshot[:] = [var.raw for var in pdo_map.map]  # snapshot inside the callback
        received.set()

    receiver_map.add_callback(on_pdo)
    sender_map.transmit()
    assert received.wait(PDO_WAIT_S), f"{sender_map.name}: no frame within {PDO_WAIT_S} s"
    return snapshot


# ------------------------------------------------------------------------ 1. dcfchk
@SKIP_NO_DCFCHK
@pytest.mark.parametrize("name", FILES)
def test_dcfchk_accepts_without_warnings(name):
    result = subprocess.run([DCFCHK, "-n", str(NODE_ID), str(FILES[name])],
                            capture_output=True, text=True, timeout=60)
    output = (result.stdout + result.stderr).strip()
    assert result.returncode == 0 and output == "", (
        f"dcfchk -n {NODE_ID} {FILES[name]}: exit code {result.returncode}\n{output}")


#: Mutations of the controller file that the notes say dcfchk rejects (exit code 1):
#: case -> (text, replacement, dcfchk's warning)
BROKEN = {
    "nodeid-first": ("DefaultValue=$NODEID+0x180", "DefaultValue=0x180+$NODEID",
                     "invalid DefaultValue in [1800sub1]"),
    "description-key": ("ParameterName=Tracker state",
                        "ParameterName=Tracker state\nDescription=0 OFF",
                        "invalid entry in [2000]: Description"),
    "decimal-real": ("DefaultValue=0x447A0000", "DefaultValue=1000.0",
                     "invalid DefaultValue in [2010sub1]"),
    "undefined-object": ("10=0x2010", "10=0x2019", "object 0x2019 not found"),
}


@SKIP_NO_DCFCHK
@pytest.mark.parametrize("case", BROKEN)
def test_dcfchk_rejects_known_mistakes(case, tmp_path):
    """Guards the test above against passing vacuously."""
    old, new, warning = BROKEN[case]
    text = FILES["controller"].read_text()
    assert text.count(old) >= 1, f"mutation {case!r}: {old!r} not in the controller EDS"
    broken = tmp_path / "broken.eds"
    broken.write_text(text.replace(old, new, 1))
    result = subprocess.run([DCFCHK, "-n", str(NODE_ID), str(broken)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, f"dcfchk accepted mutation {case!r}"
    assert warning in result.stderr, f"{case!r}: expected {warning!r} in\n{result.stderr}"


def test_dcf_tools_decodes_the_same_pdos():
    """dcf-tools' own parser (what dcfgen/dcf2dev use) decodes the expected PDO defaults."""
    dcf = pytest.importorskip("dcf", reason="dcf-tools not installed")
    for name, pdos in PDOS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            cfg = dcf.parse_file(str(FILES[name]))
            assert dcf.lint(cfg), f"{FILES[name]}: dcf-tools lint failed"
            dev = dcf.Device(cfg, {"NODEID": NODE_ID})
        assert dev.vendor_id == VENDOR_ID and dev.product_code == PRODUCT_CODE[name]
        for pdo in pdos:
            table = dev.tpdo if pdo.comm >= 0x1800 else dev.rpdo
            got = table[(pdo.comm & 0x1FF) + 1]
            where = f"{FILES[name].name} 0x{pdo.comm:04X}"
            cob_id = (0 if pdo.enabled else 0x80000000) | (pdo.cob_base + NODE_ID)
            assert got.cob_id == cob_id, where
            assert got.transmission_type == pdo.trans_type, where
            mapping = tuple((s.index, s.sub_index, s.data_type.bits())
                            for _, s in sorted(got.mapping.items()))
            assert mapping == pdo.mapping, where


# ------------------------------------------------------------------------ 2. file structure
@pytest.mark.parametrize("name", FILES)
def test_object_lists_match_sections_and_device_info(name):
    """Every object section is listed exactly once, and [DeviceInfo] agrees with 1018 and the
    PDO count (dcfchk checks only that listed objects exist, and canopen 2.4.1 looks for
    'NrOfRXPDO', not CiA 306's 'NrOfRxPDO', so neither checks these)."""
    ini = _ini(name)
    defined = {int(s, 16) for s in ini.sections() if re.fullmatch(r"[0-9A-Fa-f]{4}", s)}
    lists = {}
    for section in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        count = int(ini[section]["SupportedObjects"])
        lists[section] = [int(ini[section][str(i)], 16) for i in range(1, count + 1)]
    listed = [index for lst in lists.values() for index in lst]
    assert sorted(listed) == sorted(defined), (
        f"{FILES[name].name}: defined but not listed "
        f"{sorted(hex(i) for i in defined - set(listed))}, listed twice or undefined "
        f"{sorted(hex(i) for i in set(listed) if listed.count(i) > 1 or i not in defined)}")
    assert lists["MandatoryObjects"] == [0x1000, 0x1001, 0x1018]
    assert all(0x2000 <= i < 0x6000 for i in lists["ManufacturerObjects"])

    info, file_info = ini["DeviceInfo"], ini["FileInfo"]
    assert file_info["FileName"] == FILES[name].name
    assert file_info["EDSVersion"] == "4.0"
    assert int(info["VendorNumber"], 0) == int(ini["1018sub1"]["DefaultValue"], 0) == VENDOR_ID
    assert int(info["ProductNumber"], 0) == int(ini["1018sub2"]["DefaultValue"], 0)
    assert int(info["RevisionNumber"], 0) == int(ini["1018sub3"]["DefaultValue"], 0) == REVISION
    assert int(info["NrOfRxPDO"]) == sum(0x1400 <= i < 0x1600 for i in defined)
    assert int(info["NrOfTxPDO"]) == sum(0x1800 <= i < 0x1A00 for i in defined)
    assert int(info["Granularity"]) == 8
    for key in ("LSS_Supported", "SimpleBootUpMaster", "SimpleBootUpSlave"):
        assert info[key] in ("0", "1"), key
    rates = [r for r in (10, 20, 50, 125, 250, 500, 800, 1000) if info[f"BaudRate_{r}"] == "1"]
    assert {500, 1000} <= set(rates), f"{FILES[name].name}: baud rates {rates}"
    assert set(ini["DummyUsage"]) == {f"Dummy{i:04d}" for i in range(1, 8)}  # canopen reads all 7


def test_manufacturer_objects_documented():
    """dcfchk forbids Description keys, so each 2xxx object is described in the file's comment
    header and in the eds/README.md table; neither may fall behind the objects."""
    readme = (EDS_DIR / "README.md").read_text()
    for name in FILES:
        ini = _ini(name)
        header = "".join(line for line in FILES[name].read_text().splitlines(keepends=True)
                         if line.startswith(";"))
        section = ini["ManufacturerObjects"]
        for i in range(1, int(section["SupportedObjects"]) + 1):
            index = section[str(i)][2:].upper()
            assert re.search(rf"^;\s+{index} ", header, re.M), f"{name}: {index} not in header"
            assert f"| {index} |" in readme, f"{index} missing from the eds/README.md table"


# ------------------------------------------------------------------------ 3. canopen OD
@pytest.mark.parametrize("name", FILES)
def test_object_types_and_access(name):
    od = _od(name)
    wrong = []
    for (index, sub), (data_type, access) in {**COMMON_OBJECTS, **PROFILE_OBJECTS[name]}.items():
        var = _entry(od, index, sub)
        if var is None:
            wrong.append(f"0x{index:04X}sub{sub} missing")
        elif (var.data_type, var.access_type) != (data_type, access):
            wrong.append(f"0x{index:04X}sub{sub}: type 0x{var.data_type:04X} {var.access_type},"
                         f" expected 0x{data_type:04X} {access}")
    assert not wrong, f"{FILES[name].name}:\n" + "\n".join(wrong)


@pytest.mark.parametrize("name", FILES)
def test_identity_and_device_type(name):
    od = _od(name)
    assert od[0x1000].default == DEVICE_TYPE[name]
    assert od[0x1018][0].default == 4
    assert od[0x1018][1].default == VENDOR_ID
    assert od[0x1018][2].default == PRODUCT_CODE[name]
    assert od[0x1018][3].default == REVISION


@pytest.mark.parametrize("node_id", [NODE_ID, 1, 127])
@pytest.mark.parametrize("name", FILES)
def test_nodeid_cob_ids_resolve(name, node_id):
    od = _od(name, node_id)
    assert od[0x1014].default == 0x80 + node_id
    assert od[0x1200][1].default == 0x600 + node_id
    assert od[0x1200][2].default == 0x580 + node_id
    assert od[0x1800][1].default == 0x180 + node_id
    assert od[0x1800][1].relative
    for pdo in PDOS[name]:
        expected = (0 if pdo.enabled else 0x80000000) | (pdo.cob_base + node_id)
        assert od[pdo.comm][1].default == expected, f"0x{pdo.comm:04X}sub1"


@pytest.mark.parametrize("name", FILES)
def test_default_pdo_mappings(name):
    od = _od(name)
    pdo_indices = {i for i in od if 0x1400 <= i < 0x1600 or 0x1800 <= i < 0x1A00}
    assert pdo_indices == {p.comm for p in PDOS[name]}, "a PDO is missing from the table"
    for pdo in PDOS[name]:
        where = f"{FILES[name].name} 0x{pdo.comm:04X}"
        is_tpdo = pdo.comm >= 0x1800
        assert od[pdo.comm][2].default == pdo.trans_type, where
        assert od[pdo.comm][0].default == max(od[pdo.comm].subindices), where
        mapping = _decode_mapping(od, pdo.comm + 0x200)
        assert tuple(mapping) == pdo.mapping, where
        for index, sub, bits in mapping:
            var = _entry(od, index, sub)
            assert var is not None, f"{where} maps missing object 0x{index:04X}sub{sub}"
            assert bits == len(var), f"{where}: 0x{index:04X}sub{sub} mapped as {bits} bits"
            assert var.pdo_mappable, f"{where}: 0x{index:04X}sub{sub} not PDOMapping=1"
            assert (var.readable if is_tpdo else var.writable), f"{where}: 0x{index:04X} access"
        assert sum(bits for *_, bits in mapping) <= 64, where
        unused = [od[pdo.comm + 0x200][s].default for s in range(len(mapping) + 1, 9)]
        assert unused == [0] * len(unused), f"{where}: stale entries after the count"


def test_profile_defaults():
    enc, servo, ctl = _od("encoder"), _od("servo"), _od("controller")
    # encoder: multi-turn 4096 x 4096, scaling on, TPDO1 on every SYNC
    assert enc[0x6001].default == 4096 and enc[0x6501].default == 4096
    assert enc[0x6002].default == enc[0x6001].default * enc[0x6502].default
    assert enc[0x6000].default & 0x4
    # servo: supported modes PP (1), HM (6), CSP (8); no mode until the controller writes one
    modes = servo[0x6502].default
    assert [m for m in range(1, 11) if modes >> (m - 1) & 1] == [1, 6, 8]
    assert servo[0x6060].default == 0 and servo[0x6098].default == 0
    assert servo[0x605A].default == 2
    assert (servo[0x607D][1].default, servo[0x607D][2].default) == (-(2**31), 2**31 - 1)
    assert servo[0x608F][1].default == 2**20 and servo[0x608F][2].default == 1
    # 60C2 = value * 10^index s equals the controller's SYNC period 1006 (us)
    period_s = servo[0x60C2][1].default * 10.0 ** servo[0x60C2][2].default
    assert period_s == pytest.approx(ctl[0x1006].default * 1e-6) == pytest.approx(0.002)
    # controller: SYNC producer without counter, heartbeat 100 ms, 8 consumer entries
    assert ctl[0x1005].default == 0x40000080 and ctl[0x1019].default == 0
    assert ctl[0x1017].default == 100 and ctl[0x1016][0].default == 8
    assert (ctl[0x2001].min, ctl[0x2001].max) == (-2, 1)
    assert ctl[0x2005].max == 5
    # REAL32 defaults are IEEE 754 bit patterns (dcfchk); decode them from default_raw
    reals = {(0x2007, 0): 0.0, (0x2008, 0): 0.0,
             (0x2010, 1): 1000.0, (0x2010, 2): 10000.0, (0x2010, 3): 100000.0}
    for (index, sub), value in reals.items():
        var = _entry(ctl, index, sub)
        assert re.fullmatch(r"0x[0-9A-F]{8}", var.default_raw), var.default_raw
        assert _real32(var.default_raw) == value
        assert var.default in (None, value)  # canopen 2.4.1: None (float('0x..') fails)


# ------------------------------------------------------------------------ 4. on a bus
@pytest.mark.parametrize("name", FILES)
def test_local_node_serves_sdo_on_virtual_bus(name):
    od = _od(name)
    local = canopen.LocalNode(NODE_ID, od)
    remote = canopen.RemoteNode(NODE_ID, _od(name))
    with _virtual_pair(f"sdo-{name}") as (local_net, remote_net):
        local_net.add_node(local)
        remote_net.add_node(remote)
        # The application seeds REAL32 defaults (canopen leaves them None, see above).
        for index in od:
            for var in ([od[index]] if isinstance(od[index], ODVariable)
                        else od[index].subindices.values()):
                if var.data_type == REAL32 and var.default is None:
                    local.set_data(index, var.subindex, var.encode_raw(_real32(var.default_raw)))
        assert remote.sdo[0x1018][1].raw == VENDOR_ID
        assert remote.sdo[0x1018][2].raw == PRODUCT_CODE[name]
        assert remote.sdo[0x1000].raw == DEVICE_TYPE[name]
        assert remote.sdo[0x1800][1].raw == 0x180 + NODE_ID
        if name == "controller":
            assert remote.sdo[0x2010][1].raw == 1000.0
            assert remote.sdo[0x2007].raw == 0.0
        if name == "servo":
            assert remote.sdo[0x60C2][2].raw == -3


@pytest.mark.parametrize("name", FILES)
def test_default_pdos_on_virtual_bus(name):
    """TPDO1 from the LocalNode to the RemoteNode and RPDO1 the other way, both decoded with
    the default mappings read from the EDS."""
    local = canopen.LocalNode(NODE_ID, _od(name))
    remote = canopen.RemoteNode(NODE_ID, _od(name))
    with _virtual_pair(f"pdo-{name}") as (local_net, remote_net):
        local_net.add_node(local)
        remote_net.add_node(remote)
        for node in (local, remote):
            node.tpdo.read(from_od=True)
            node.rpdo.read(from_od=True)
        directions = [(local.tpdo[1], remote.tpdo[1])]
        if 1 in local.rpdo.map:
            directions.append((remote.rpdo[1], local.rpdo[1]))
        for sender, receiver in directions:
            assert sender.enabled and sender.cob_id == receiver.cob_id
            expected = []
            for var in sender.map:
                value = _test_value(var.od)
                var.raw = value
                expected.append(value)
            assert len(sender.data) * 8 == sum(var.length for var in sender.map) <= 64
            assert _transfer(sender, receiver) == expected, sender.name
