"""Bus capture → pcap → independent CANopen decoding with Wireshark's ``tshark``.

The test tiers that run on a real SocketCAN bus (``vcan`` in a VM or natively, ``hil`` on a rig)
capture the bus with can-utils' ``candump -L`` (or any python-can log format: ``.log``, ``.asc``,
``.blf``, ...) and check it with a decoder that shares no code with ours: Wireshark's CANopen
dissector, run as ``tshark -r bus.pcap -d can.subdissector,canopen``.

- :func:`write_pcap` converts python-can messages to a pcap file with link type 227
  (``LINKTYPE_CAN_SOCKETCAN``: big-endian ``can_id`` with the EFF/RTR/ERR flags, payload length,
  FD flags, two reserved bytes, then the data), microsecond timestamps.
- :func:`classify_capture` runs tshark on it and returns one :class:`FrameClass` per frame: the
  kind (:class:`Kind`: NMT, SYNC, PDO, SDO, EMCY, HEARTBEAT, ...) as tshark decoded it, whether
  tshark flagged it malformed, and the decoded fields the tiers check (SYNC counter, heartbeat
  state, NMT command, EMCY code, SDO index). Each frame also carries ``expected_kind``: the kind
  its COB-ID has in the CiA 301 predefined connection set, computed here without tshark, and
  ``issues``: CiA 301 length rules tshark does not enforce (e.g. a 2-byte SYNC, an empty
  heartbeat). :func:`problems` lists every frame that is unclassified, malformed, disagrees with
  its COB-ID or breaks a length rule.
- :func:`sync_period_stats` and :func:`pdo_order_per_sync` give the SYNC period / counter
  sequence and the order of PDOs inside each SYNC cycle.

Times are in seconds (``time_s`` relative to the first frame of the capture).  Inside the VM the
clock is emulated: use the periods for correctness (is it about the configured period, is every
counter there), never for performance.
"""

from __future__ import annotations

import csv
import dataclasses
import enum
import io
import itertools
import shutil
import statistics
import struct
import subprocess
from collections.abc import Iterable, Sequence
from pathlib import Path

from ..errors import CantrackError

#: pcap link type of SocketCAN frames (tcpdump.org LINKTYPE_CAN_SOCKETCAN)
LINKTYPE_CAN_SOCKETCAN = 227

CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_FDF = 0x04

TSHARK_INSTALL_HINT = (
    "install Wireshark's command-line decoder: apt-get install tshark "
    "(preseed 'wireshark-common wireshark-common/install-setuid boolean false' with "
    "debconf-set-selections to avoid its question)")


class CaptureError(CantrackError):
    """A capture could not be read, converted or decoded (names the file and the tool)."""


class Kind(str, enum.Enum):
    """CANopen service of a frame (CiA 301 predefined connection set names)."""

    NMT = "NMT"
    SYNC = "SYNC"
    EMCY = "EMCY"
    TIME = "TIME"
    PDO = "PDO"
    SDO = "SDO"
    HEARTBEAT = "HEARTBEAT"   # NMT error control: heartbeat / boot-up (and node guarding)
    LSS = "LSS"
    UNKNOWN = "UNKNOWN"       # tshark did not decode it as CANopen (extended id, error frame, ...)


@dataclasses.dataclass(frozen=True)
class FrameClass:
    """One captured frame as tshark's CANopen dissector decoded it.

    ``time_s``: seconds since the first frame of the capture.  ``function_code`` and ``node_id``
    are tshark's ``canopen.function_code`` / ``canopen.node_id`` (None if not decoded).
    ``pdo``: PDO number 1..4 and ``direction``: "tx"/"rx" (PDO: seen from the device; SDO: "tx" =
    server → client, "rx" = client → server).  ``sync_counter``: SYNC counter byte, None for a
    SYNC without counter.  ``nmt_state``: heartbeat state byte (0 boot-up, 4 stopped,
    5 operational, 127 pre-operational).  ``nmt_command``/``nmt_target``: NMT command specifier
    and addressed node (0 = all).  ``emcy_code``/``emcy_register``: EMCY error code and error
    register.  ``sdo_index``/``sdo_subindex``: the object an initiate request/response names.
    """

    number: int
    time_s: float
    can_id: int
    is_extended: bool
    is_remote: bool
    data: bytes
    kind: Kind
    expected_kind: Kind
    malformed: bool
    info: str
    function_code: int | None = None
    node_id: int | None = None
    pdo: int | None = None
    direction: str | None = None
    sync_counter: int | None = None
    nmt_state: int | None = None
    nmt_command: int | None = None
    nmt_target: int | None = None
    emcy_code: int | None = None
    emcy_register: int | None = None
    sdo_index: int | None = None
    sdo_subindex: int | None = None
    issues: tuple[str, ...] = ()

    @property
    def cob_id(self) -> int:
        return self.can_id

    def describe(self) -> str:
        """One line for assertion messages: number, time, id, data, tshark's info, issues."""
        parts = [(f"#{self.number} t={self.time_s:.6f}s id=0x{self.can_id:03X}"
                  f"{' RTR' if self.is_remote else ''} data={self.data.hex() or '-'}"),
                 f"tshark={self.kind.value} ({self.info!r})",
                 f"cob-id says {self.expected_kind.value}"]
        if self.malformed:
            parts.append("MALFORMED")
        parts.extend(self.issues)
        return ", ".join(parts)


# ---------------------------------------------------------------------------------------------
# pcap writing

def _pcap_record(msg) -> bytes:
    """The LINKTYPE_CAN_SOCKETCAN bytes of one python-can message (16 or 72 bytes)."""
    can_id = int(msg.arbitration_id) & (0x1FFFFFFF if msg.is_extended_id else 0x7FF)
    if msg.is_extended_id:
        can_id |= CAN_EFF_FLAG
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
    if msg.is_error_frame:
        can_id |= CAN_ERR_FLAG
    data = bytes(msg.data or b"")
    if msg.is_fd:
        flags = CANFD_FDF | (CANFD_BRS if msg.bitrate_switch else 0) | (
            CANFD_ESI if msg.error_state_indicator else 0)
        return struct.pack(">IBBBB", can_id, len(data), flags, 0, 0) + data.ljust(64, b"\0")
    length = int(msg.dlc) if msg.is_remote_frame else len(data)
    return struct.pack(">IBBBB", can_id, length, 0, 0, 0) + data.ljust(8, b"\0")


def write_pcap(messages: Iterable, path: str | Path) -> int:
    """Write python-can ``messages`` to ``path`` as pcap (link type 227); return the count.

    Timestamps are the messages' ``timestamp`` (seconds, any epoch), kept to the microsecond.
    """
    n = 0
    with open(path, "wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, LINKTYPE_CAN_SOCKETCAN))
        for msg in messages:
            rec = _pcap_record(msg)
            ts = float(msg.timestamp or 0.0)
            sec = int(ts)
            usec = round((ts - sec) * 1e6)
            if usec >= 1_000_000:
                sec, usec = sec + 1, usec - 1_000_000
            f.write(struct.pack("<IIII", sec, usec, len(rec), len(rec)))
            f.write(rec)
            n += 1
    return n


def read_log(path: str | Path) -> list:
    """All CAN messages of a python-can log file (candump ``.log``, ``.asc``, ``.blf``, ...).

    Error frames are kept; a file that python-can cannot read raises :class:`CaptureError`.
    """
    import can  # python-can; imported here so that the module imports without it

    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: capture file not found")
    try:
        with can.LogReader(str(path)) as reader:
            return list(reader)
    except (ValueError, OSError) as exc:
        raise CaptureError(f"{path}: python-can cannot read this log: {exc}") from exc


def log_to_pcap(log_path: str | Path, pcap_path: str | Path | None = None) -> Path:
    """Convert a python-can readable log to pcap (default: same name, ``.pcap``); return it."""
    log_path = Path(log_path)
    out = Path(pcap_path) if pcap_path is not None else log_path.with_suffix(".pcap")
    write_pcap(read_log(log_path), out)
    return out


# ---------------------------------------------------------------------------------------------
# tshark decoding

#: the tshark fields read for each frame, in column order
TSHARK_FIELDS = (
    "frame.number", "frame.time_relative", "can.id", "can.flags.xtd", "can.flags.rtr",
    "can.flags.err", "can.len", "canopen.function_code", "canopen.node_id",
    "canopen.sync.counter", "canopen.nmt_guard.state", "canopen.nmt_ctrl.cd",
    "canopen.nmt_ctrl.node_id", "canopen.em.err_code", "canopen.em.err_reg",
    "canopen.sdo.main_idx", "canopen.sdo.sub_idx", "_ws.malformed", "_ws.col.Protocol",
    "_ws.col.Info",
)


def tshark_available() -> tuple[bool, str]:
    """(True, path) when ``tshark`` is on PATH, else (False, what to install)."""
    path = shutil.which("tshark")
    if path is None:
        return False, "tshark not found on PATH: " + TSHARK_INSTALL_HINT
    return True, path


def _int(text: str) -> int | None:
    text = text.strip().split(",")[0]
    if not text:
        return None
    return int(text, 0)


def _bool(text: str) -> bool:
    t = text.strip().lower()
    return t in ("1", "true", "yes")


def expected_kind(can_id: int, is_extended: bool = False, is_remote: bool = False) -> Kind:
    """The kind the CiA 301 predefined connection set gives an 11-bit COB-ID.

    0x000 NMT, 0x080 SYNC, 0x081..0x0FF EMCY, 0x100 TIME, 0x181..0x57F PDO1..4 tx/rx,
    0x581..0x5FF / 0x601..0x67F SDO, 0x701..0x77F NMT error control, 0x7E4/0x7E5 LSS.
    """
    if is_extended:
        return Kind.UNKNOWN
    fc, node = can_id >> 7, can_id & 0x7F
    if can_id == 0x000:
        return Kind.NMT
    if can_id == 0x080:
        return Kind.SYNC
    if fc == 0x1 and node:
        return Kind.EMCY
    if can_id == 0x100:
        return Kind.TIME
    if can_id in (0x7E4, 0x7E5):
        return Kind.LSS
    if 0x3 <= fc <= 0xA and node:
        return Kind.PDO
    if fc in (0xB, 0xC) and node:
        return Kind.SDO
    if fc == 0xE and node:
        return Kind.HEARTBEAT
    return Kind.UNKNOWN


def _length_issues(kind: Kind, length: int, is_remote: bool, data: bytes) -> tuple[str, ...]:
    """CiA 301 frame-length rules that Wireshark 4.0 does not flag as malformed."""
    issues = []
    if kind is Kind.SYNC and length > 1:
        issues.append(f"SYNC with {length} data bytes (CiA 301: 0, or 1 = counter)")
    if kind is Kind.SYNC and length == 1 and not 1 <= data[0] <= 240:
        issues.append(f"SYNC counter {data[0]} outside 1..240")
    if kind is Kind.NMT and length != 2:
        issues.append(f"NMT command with {length} data bytes (CiA 301: 2)")
    if kind is Kind.HEARTBEAT and not is_remote and length != 1:
        issues.append(f"heartbeat with {length} data bytes (CiA 301: 1)")
    if kind is Kind.HEARTBEAT and not is_remote and length == 1 and (data[0] & 0x7F) not in (
            0, 4, 5, 127):
        issues.append(f"heartbeat state 0x{data[0]:02X} is none of 0/4/5/127")
    if kind is Kind.SDO and length != 8:
        issues.append(f"SDO with {length} data bytes (CiA 301: 8)")
    if kind is Kind.EMCY and length != 8:
        issues.append(f"EMCY with {length} data bytes (CiA 301: 8)")
    if kind in (Kind.PDO, Kind.SYNC, Kind.EMCY, Kind.SDO, Kind.NMT) and is_remote:
        issues.append(f"remote frame for {kind.value}")
    return tuple(issues)


def _kind_from_tshark(fc: int | None, node: int | None, protocol: str) -> Kind:
    if fc is None or protocol.strip().upper() != "CANOPEN":
        return Kind.UNKNOWN
    if fc == 0x0:
        return Kind.NMT
    if fc == 0x1:
        return Kind.SYNC if not node else Kind.EMCY
    if fc == 0x2:
        return Kind.TIME
    if 0x3 <= fc <= 0xA:
        return Kind.PDO
    if fc in (0xB, 0xC):
        return Kind.SDO
    if fc == 0xE:
        return Kind.HEARTBEAT
    if fc == 0xF:
        return Kind.LSS
    return Kind.UNKNOWN


def decode_pcap(pcap_path: str | Path, *, messages: Sequence | None = None,
                tshark: str | None = None, timeout_s: float = 120.0) -> list[FrameClass]:
    """Run tshark's CANopen dissector on a pcap file; one :class:`FrameClass` per frame.

    ``messages`` (the python-can messages the pcap was written from, same order) supplies the
    raw data bytes; without it they are read back from the pcap.
    """
    pcap_path = Path(pcap_path)
    if tshark is None:
        ok, found = tshark_available()
        if not ok:
            raise CaptureError(f"{pcap_path}: cannot decode: {found}")
        tshark = found
    cmd = [tshark, "-n", "-r", str(pcap_path), "-d", "can.subdissector,canopen", "-T", "fields",
           "-E", "separator=/t", "-E", "occurrence=a", "-E", "aggregator=,", "-E", "quote=n"]
    for field in TSHARK_FIELDS:
        cmd += ["-e", field]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                          env=_tshark_env(), check=False)
    if proc.returncode != 0:
        raise CaptureError(f"{pcap_path}: tshark exited with {proc.returncode}: "
                           f"{proc.stderr.strip()[-2000:]}")
    raw = [bytes(m.data or b"") for m in messages] if messages is not None else _pcap_payloads(
        pcap_path)
    frames = []
    rows = list(csv.reader(io.StringIO(proc.stdout), delimiter="\t", quoting=csv.QUOTE_NONE))
    for row in rows:
        if not row:
            continue
        row = row + [""] * (len(TSHARK_FIELDS) - len(row))
        f = dict(zip(TSHARK_FIELDS, row))
        number = int(f["frame.number"])
        can_id = _int(f["can.id"]) or 0
        ext, rtr = _bool(f["can.flags.xtd"]), _bool(f["can.flags.rtr"])
        length = _int(f["can.len"]) or 0
        data = raw[number - 1][:length] if number - 1 < len(raw) else b""
        fc, node = _int(f["canopen.function_code"]), _int(f["canopen.node_id"])
        kind = _kind_from_tshark(fc, node, f["_ws.col.Protocol"])
        if _bool(f["can.flags.err"]):
            kind = Kind.UNKNOWN
        pdo = direction = None
        if kind is Kind.PDO and fc is not None:
            pdo, direction = (fc - 1) // 2, ("tx" if fc % 2 == 1 else "rx")
        elif kind is Kind.SDO and fc is not None:
            direction = "tx" if fc == 0xB else "rx"
        exp = expected_kind(can_id, ext, rtr)
        frames.append(FrameClass(
            number=number, time_s=float(f["frame.time_relative"] or 0.0), can_id=can_id,
            is_extended=ext, is_remote=rtr, data=data, kind=kind, expected_kind=exp,
            malformed=bool(f["_ws.malformed"].strip()), info=f["_ws.col.Info"].strip(),
            function_code=fc, node_id=node, pdo=pdo, direction=direction,
            sync_counter=_int(f["canopen.sync.counter"]),
            nmt_state=_int(f["canopen.nmt_guard.state"]),
            nmt_command=_int(f["canopen.nmt_ctrl.cd"]),
            nmt_target=_int(f["canopen.nmt_ctrl.node_id"]),
            emcy_code=_int(f["canopen.em.err_code"]),
            emcy_register=_int(f["canopen.em.err_reg"]),
            sdo_index=_int(f["canopen.sdo.main_idx"]),
            sdo_subindex=_int(f["canopen.sdo.sub_idx"]),
            issues=_length_issues(exp, length, rtr, data) if exp is not Kind.UNKNOWN else (),
        ))
    return frames


def _tshark_env() -> dict:
    import os
    env = dict(os.environ)
    # a fresh, writable profile dir keeps tshark from touching the user's Wireshark settings
    env.setdefault("WIRESHARK_CONFIG_DIR", "/nonexistent-cantrack-wireshark-profile")
    return env


def _pcap_payloads(path: Path) -> list[bytes]:
    """The CAN data bytes of every record of a LINKTYPE_CAN_SOCKETCAN pcap file."""
    blob = path.read_bytes()
    if len(blob) < 24:
        raise CaptureError(f"{path}: not a pcap file (too short)")
    magic = struct.unpack_from("<I", blob)[0]
    endian = "<" if magic in (0xA1B2C3D4, 0xA1B23C4D) else ">"
    linktype = struct.unpack_from(endian + "I", blob, 20)[0]
    if linktype != LINKTYPE_CAN_SOCKETCAN:
        raise CaptureError(f"{path}: pcap link type {linktype}, expected "
                           f"{LINKTYPE_CAN_SOCKETCAN} (LINKTYPE_CAN_SOCKETCAN)")
    out, off = [], 24
    while off + 16 <= len(blob):
        incl = struct.unpack_from(endian + "I", blob, off + 8)[0]
        rec = blob[off + 16: off + 16 + incl]
        length = rec[4] if len(rec) > 4 else 0
        out.append(bytes(rec[8: 8 + length]))
        off += 16 + incl
    return out


#: the decoders :func:`classify_capture` can use
DECODERS = ("tshark", "builtin", "auto")


def pick_decoder(decoder: str = "auto", tshark: str | None = None) -> tuple[str, str | None]:
    """(``"tshark"``, its path) or (``"builtin"``, None) for ``decoder`` ("tshark", "builtin"
    or "auto": tshark when it is on PATH, else the built-in decoder).

    "tshark" without tshark raises :class:`CaptureError` with what to install.
    """
    if decoder not in DECODERS:
        raise ValueError(f"decoder {decoder!r}: one of {', '.join(DECODERS)}")
    if decoder == "builtin":
        return "builtin", None
    if tshark is not None:
        return "tshark", tshark
    ok, found = tshark_available()
    if ok:
        return "tshark", found
    if decoder == "auto":
        return "builtin", None
    raise CaptureError(f"cannot decode with tshark: {found}")


def _sdo_index(direction: str, data: bytes) -> tuple[int | None, int | None]:
    """The object an SDO initiate request/response or abort names (CiA 301 7.2.4.3)."""
    if len(data) < 4:
        return None, None
    cs = data[0] >> 5
    named = {1, 2, 4, 5, 6} if direction == "rx" else {2, 3, 4, 5, 6}
    if cs not in named or (cs == 5 and direction == "tx" and data[0] & 0x03 != 0) or (
            cs == 6 and direction == "rx" and data[0] & 0x01 != 0):
        return None, None   # (block transfer sub-commands other than initiate)
    return int.from_bytes(data[1:3], "little"), data[3]


def decode_messages(messages: Sequence) -> list[FrameClass]:
    """The built-in decoder: one :class:`FrameClass` per python-can message, from the CiA 301
    predefined connection set of its COB-ID and its data bytes, without tshark.

    It is *not* independent of our own reading of CiA 301 (``kind`` is always
    ``expected_kind``; nothing is ever ``malformed``; the length rules still apply): use it
    where tshark is not installed (a rig PC); the ``vcan`` tier uses tshark.
    """
    frames = []
    t0 = None
    for number, msg in enumerate(messages, start=1):
        ts = float(msg.timestamp or 0.0)
        t0 = ts if t0 is None else t0
        ext, rtr = bool(msg.is_extended_id), bool(msg.is_remote_frame)
        can_id = int(msg.arbitration_id) & (0x1FFFFFFF if ext else 0x7FF)
        data = bytes(msg.data or b"")
        length = int(msg.dlc) if rtr else len(data)
        exp = Kind.UNKNOWN if msg.is_error_frame else expected_kind(can_id, ext, rtr)
        fields: dict = {}
        if exp is not Kind.UNKNOWN:
            fc, node = can_id >> 7, can_id & 0x7F
            fields.update(function_code=fc, node_id=node)
            if exp is Kind.PDO:
                fields.update(pdo=(fc - 1) // 2, direction="tx" if fc % 2 == 1 else "rx")
            elif exp is Kind.SDO:
                direction = "tx" if fc == 0xB else "rx"
                index, sub = _sdo_index(direction, data)
                fields.update(direction=direction, sdo_index=index, sdo_subindex=sub)
            elif exp is Kind.SYNC and length >= 1:
                fields.update(sync_counter=data[0])
            elif exp is Kind.HEARTBEAT and not rtr and length >= 1:
                fields.update(nmt_state=data[0] & 0x7F)
            elif exp is Kind.NMT and length >= 2:
                fields.update(nmt_command=data[0], nmt_target=data[1])
            elif exp is Kind.EMCY and length >= 3:
                fields.update(emcy_code=int.from_bytes(data[:2], "little"),
                              emcy_register=data[2])
        frames.append(FrameClass(
            number=number, time_s=ts - t0, can_id=can_id, is_extended=ext, is_remote=rtr,
            data=data, kind=exp, expected_kind=exp, malformed=False,
            info=f"builtin: {exp.value}",
            issues=_length_issues(exp, length, rtr, data) if exp is not Kind.UNKNOWN else (),
            **fields))
    return frames


def classify_capture(path: str | Path, *, pcap_path: str | Path | None = None,
                     tshark: str | None = None, decoder: str = "tshark") -> list[FrameClass]:
    """Decode a bus capture with tshark's CANopen dissector; one :class:`FrameClass` per frame.

    ``path``: a pcap with link type 227 (``.pcap``) or any python-can log (candump ``-L``
    ``.log``, ``.asc``, ``.blf``, ...), which is first converted to ``pcap_path`` (default: the
    same name with ``.pcap``).  Raises :class:`CaptureError` when the file cannot be read or
    tshark is missing (the message says what to install).

    ``decoder``: "tshark" (the default), "builtin" (:func:`decode_messages`, no tshark) or
    "auto" (tshark when it is on PATH, else builtin; :func:`pick_decoder` says which).
    """
    path = Path(path)
    name, tshark = pick_decoder(decoder, tshark)
    if path.suffix.lower() in (".pcap", ".cap"):
        if name == "builtin":
            raise CaptureError(f"{path}: the built-in decoder reads python-can logs, not pcap")
        return decode_pcap(path, tshark=tshark)
    messages = read_log(path)
    if name == "builtin":
        return decode_messages(messages)
    out = Path(pcap_path) if pcap_path is not None else path.with_suffix(".pcap")
    write_pcap(messages, out)
    return decode_pcap(out, messages=messages, tshark=tshark)


def problems(frames: Iterable[FrameClass],
             allowed: Iterable[Kind] = (Kind.NMT, Kind.SYNC, Kind.PDO, Kind.SDO, Kind.EMCY,
                                        Kind.HEARTBEAT)) -> list[str]:
    """Every frame that is not cleanly classified, one :meth:`FrameClass.describe` line each.

    A frame is a problem when tshark did not classify it as one of ``allowed``, flagged it
    malformed, classified it differently from its COB-ID's predefined-connection-set kind, or
    it breaks a CiA 301 length rule (:attr:`FrameClass.issues`).
    """
    allowed = set(allowed)
    out = []
    for fr in frames:
        if (fr.kind not in allowed or fr.malformed or fr.kind is not fr.expected_kind
                or fr.issues):
            out.append(fr.describe())
    return out


def kinds_count(frames: Iterable[FrameClass]) -> dict[Kind, int]:
    """Number of frames of each kind."""
    counts: dict[Kind, int] = {}
    for fr in frames:
        counts[fr.kind] = counts.get(fr.kind, 0) + 1
    return counts


# ---------------------------------------------------------------------------------------------
# SYNC and PDO checks

@dataclasses.dataclass(frozen=True)
class SyncStats:
    """SYNC frames of a capture: count, period statistics [s] and the counter sequence.

    ``counter_gaps``: positions i where counter[i] does not follow counter[i-1] (next value,
    wrapping from ``overflow`` back to 1; position 0 when the first counter is outside
    1..overflow); empty when the counters are complete or absent.
    ``overflow``: the largest counter seen (the configured 1019 overflow value when the run
    wrapped at least once).
    """

    count: int
    period_mean_s: float | None
    period_median_s: float | None
    period_min_s: float | None
    period_max_s: float | None
    period_stdev_s: float | None
    counters: tuple[int | None, ...]
    overflow: int | None
    counter_gaps: tuple[int, ...]

    def describe(self) -> str:
        def ms(v):
            return "-" if v is None else f"{v * 1e3:.3f} ms"
        return (f"{self.count} SYNC, period mean {ms(self.period_mean_s)}, median "
                f"{ms(self.period_median_s)}, min {ms(self.period_min_s)}, max "
                f"{ms(self.period_max_s)}, stdev {ms(self.period_stdev_s)}; counter overflow "
                f"{self.overflow}, gaps at {list(self.counter_gaps)}")


def sync_period_stats(frames: Iterable[FrameClass], *, overflow: int | None = None,
                      start_s: float | None = None, end_s: float | None = None) -> SyncStats:
    """Statistics of the SYNC frames in ``frames`` (optionally within [start_s, end_s]).

    ``overflow``: the configured SYNC counter overflow value (object 1019); when given, a counter
    must go 1, 2, ..., overflow, 1, ...; when None, the largest counter seen is used.
    """
    syncs = [f for f in frames if f.kind is Kind.SYNC
             and (start_s is None or f.time_s >= start_s)
             and (end_s is None or f.time_s <= end_s)]
    times = [f.time_s for f in syncs]
    periods = [b - a for a, b in itertools.pairwise(times)]
    counters = tuple(f.sync_counter for f in syncs)
    seen = [c for c in counters if c is not None]
    top = overflow if overflow is not None else (max(seen) if seen else None)
    gaps = []
    if top is not None:  # some SYNC has a counter
        if counters[0] is not None and not 1 <= counters[0] <= top:
            gaps.append(0)
        for i in range(1, len(counters)):
            prev, cur = counters[i - 1], counters[i]
            if prev is None or cur is None:
                gaps.append(i)
                continue
            want = 1 if prev >= top else prev + 1
            if cur != want:
                gaps.append(i)
    return SyncStats(
        count=len(syncs),
        period_mean_s=statistics.fmean(periods) if periods else None,
        period_median_s=statistics.median(periods) if periods else None,
        period_min_s=min(periods) if periods else None,
        period_max_s=max(periods) if periods else None,
        period_stdev_s=statistics.pstdev(periods) if len(periods) > 1 else None,
        counters=counters, overflow=top, counter_gaps=tuple(gaps))


def pdo_order_per_sync(frames: Iterable[FrameClass]) -> list[tuple[int, ...]]:
    """For each SYNC, the COB-IDs of the PDOs that follow it before the next SYNC, in order.

    PDOs before the first SYNC are not included.  The last cycle is included (it may be cut
    short by the end of the capture).
    """
    cycles: list[list[int]] = []
    for fr in frames:
        if fr.kind is Kind.SYNC:
            cycles.append([])
        elif fr.kind is Kind.PDO and cycles:
            cycles[-1].append(fr.can_id)
    return [tuple(c) for c in cycles]
