"""A small SDO client (CiA 301 expedited and segmented transfers) on the controller's transport.

python canopen's SDO client blocks in a queue wait with its own time-out (0.3 s x 1 retry)
and is not thread-safe (canopen-notes.md); here a request waits through
``transport.run_until`` instead, so the same code runs in stepped and in real time and the
time-out is ours.  Objects of 1-4 bytes go expedited (one exchange); longer ones (strings such
as 1008h, 64-bit values, domains) segmented: 7 bytes per exchange with the toggle bit checked
(a wrong toggle is aborted with 05030000h, as CiA 301 asks).  Block transfers are not used.

Errors name the node, the object (index:sub) and, for an abort, the abort code and its
meaning: ``node 11 (x): SDO abort 06090030h (Value range of parameter exceeded) writing
60C2h:02``.

:class:`SdoAbortError` is the one SDO-abort type of cantrack, on both sides: the client
raises it for an abort it receives, a slave (the simulated devices, the controller's own
node) raises it to refuse a request.  It is a :class:`~controller.errors.CanError` and a
python canopen ``SdoAbortedError`` (same ``code``, same text table ``CODES``), so canopen's
``LocalNode`` SDO server answers it with that abort code.  The ``ABORT_*`` codes here are the
CiA 301 codes cantrack sends.
"""

from __future__ import annotations

import struct

from canopen.sdo.exceptions import SdoAbortedError

from ...errors import CanError, CanTimeoutError
from ..io.transport import Transport

#: CiA 301 abort codes cantrack sends (client and slaves); the texts: :func:`abort_text`
ABORT_TOGGLE = 0x05030000          # toggle bit not alternated
ABORT_COMMAND = 0x05040001         # client/server command specifier not valid or unknown
ABORT_OUT_OF_MEMORY = 0x05040005   # out of memory
ABORT_WRITE_ONLY = 0x06010001      # attempt to read a write only object
ABORT_READ_ONLY = 0x06010002       # attempt to write a read only object
ABORT_NO_OBJECT = 0x06020000       # object does not exist in the object dictionary
ABORT_PDO_MAPPING = 0x06040041     # object cannot be mapped to the PDO
ABORT_PDO_LENGTH = 0x06040042      # the mapped objects would exceed the PDO length
ABORT_PARAM_INCOMPATIBLE = 0x06040043  # general parameter incompatibility
ABORT_LENGTH = 0x06070010          # data type does not match, length does not match
ABORT_NO_SUB = 0x06090011          # sub-index does not exist
ABORT_VALUE_RANGE = 0x06090030     # value range of parameter exceeded
ABORT_GENERAL = 0x08000000         # general error
ABORT_STORE = 0x08000020           # data cannot be transferred or stored
ABORT_DEVICE_STATE = 0x08000022    # ... because of the present device state
#: the longest segmented upload accepted [bytes]
MAX_SEGMENTED_BYTES = 65536


def abort_text(code: int) -> str:
    """The CiA 301 text of abort ``code`` (python canopen's table)."""
    return SdoAbortedError.CODES.get(code, "unknown abort code")


class SdoAbortError(CanError, SdoAbortedError):
    """An SDO transfer aborted with ``code`` (CiA 301); where known, by or at whom
    (``label``), for which object (``index``:``sub``) and while doing what (``action``)."""

    def __init__(self, code: int, label: str | None = None, index: int | None = None,
                 sub: int | None = None, action: str = "") -> None:
        self.code, self.label, self.index, self.sub, self.action = code, label, index, sub, action
        where = f" {index:04X}h:{sub or 0:02X}" if index is not None else ""
        head = f"{label}: " if label else ""
        CanError.__init__(self, f"{head}SDO abort {code:08X}h ({abort_text(code)})"
                                + (f" {action}" if action else "") + where)

    def __str__(self) -> str:  # (canopen's __str__ would be "Code 0x...")
        return CanError.__str__(self)

    __eq__ = object.__eq__  # (canopen compares codes; an exception is equal only to itself)
    __hash__ = object.__hash__


class SdoTimeoutError(CanTimeoutError):
    def __init__(self, label: str, index: int, sub: int, action: str, timeout_s: float,
                 retries: int = 0) -> None:
        self.label, self.index, self.sub = label, index, sub
        tries = f" ({retries + 1} attempts)" if retries else ""
        super().__init__(f"{label}: no SDO response within {timeout_s:g} s{tries} {action} "
                         f"{index:04X}h:{sub:02X}")


class SdoClient:
    """SDO transfers (expedited, segmented) to one node (default COB-IDs 600h/580h + node-ID)."""

    def __init__(self, transport: Transport, node_id: int, label: str,
                 timeout_s: float = 0.5, retries: int = 0) -> None:
        self.transport = transport
        self.node_id = node_id
        self.label = label
        self.timeout_s = timeout_s
        #: a request that times out is sent again this many times (not after an abort)
        self.retries = retries
        self._response: bytes | None = None
        self.requests = 0

    def _on_response(self, can_id: int, data: bytes, t_ns: int) -> None:
        self._response = data

    def _exchange(self, request: bytes, index: int, sub: int, action: str,
                  mux: bool = True) -> bytes:
        """One request/response; ``mux``: the response must name index:sub (not for the
        segments of a segmented transfer, which carry data there)."""
        t = self.transport
        self._response = None
        t.subscribe(0x580 + self.node_id, self._on_response)
        try:
            for _attempt in range(self.retries + 1):
                t.send(0x600 + self.node_id, request)
                self.requests += 1
                deadline = t.clock.now_ns() + int(self.timeout_s * 1e9)
                if t.run_until(deadline, lambda: self._response is not None):
                    break
            else:
                raise SdoTimeoutError(self.label, index, sub, action, self.timeout_s,
                                      self.retries)
        finally:
            t.unsubscribe(0x580 + self.node_id, self._on_response)
        resp = self._response
        assert resp is not None
        if len(resp) < 8:
            raise CanError(f"{self.label}: short SDO response ({len(resp)} bytes) {action} "
                           f"{index:04X}h:{sub:02X}")
        r_index, r_sub = struct.unpack_from("<HB", resp, 1)
        if resp[0] == 0x80:
            raise SdoAbortError(struct.unpack_from("<I", resp, 4)[0], self.label, index, sub,
                                action)
        if mux and (r_index, r_sub) != (index, sub):
            raise CanError(f"{self.label}: SDO response for {r_index:04X}h:{r_sub:02X} while "
                           f"{action} {index:04X}h:{sub:02X}")
        return resp

    def _unexpected(self, cmd: int, index: int, sub: int, action: str) -> CanError:
        return CanError(f"{self.label}: unexpected SDO response {cmd:02X}h {action} "
                        f"{index:04X}h:{sub:02X}")

    def _abort(self, index: int, sub: int, code: int) -> None:
        """Abort a transfer from our side (no answer expected)."""
        self.transport.send(0x600 + self.node_id, struct.pack("<BHBI", 0x80, index, sub, code))

    def _toggle_error(self, index: int, sub: int, action: str) -> CanError:
        self._abort(index, sub, ABORT_TOGGLE)
        return CanError(f"{self.label}: SDO toggle bit not alternated {action} "
                        f"{index:04X}h:{sub:02X} (aborted: {ABORT_TOGGLE:08X}h)")

    def download(self, index: int, sub: int, data: bytes) -> None:
        """Write ``data``: 1-4 bytes expedited, longer segmented (7 bytes per segment)."""
        data = bytes(data)
        n = len(data)
        if n == 0:
            raise ValueError("SDO download of 0 bytes")
        if n <= 4:
            cmd = 0x23 | ((4 - n) << 2)
            request = struct.pack("<BHB", cmd, index, sub) + data + bytes(4 - n)
            resp = self._exchange(request, index, sub, "writing")
            if resp[0] != 0x60:
                raise self._unexpected(resp[0], index, sub, "writing")
            return
        resp = self._exchange(struct.pack("<BHBI", 0x21, index, sub, n), index, sub, "writing")
        if resp[0] != 0x60:
            raise self._unexpected(resp[0], index, sub, "writing")
        toggle = 0
        for off in range(0, n, 7):
            chunk = data[off:off + 7]
            last = off + 7 >= n
            cmd = (toggle << 4) | ((7 - len(chunk)) << 1) | int(last)
            resp = self._exchange(bytes([cmd]) + chunk + bytes(7 - len(chunk)), index, sub,
                                  "writing", mux=False)
            if resp[0] & 0xE0 != 0x20:
                raise self._unexpected(resp[0], index, sub, "writing")
            if (resp[0] >> 4) & 1 != toggle:
                raise self._toggle_error(index, sub, "writing")
            toggle ^= 1

    def upload(self, index: int, sub: int) -> bytes:
        """Read an object: expedited (1-4 bytes) or segmented, as the server answers."""
        request = struct.pack("<BHB", 0x40, index, sub) + bytes(4)
        resp = self._exchange(request, index, sub, "reading")
        cmd = resp[0]
        if cmd & 0xE0 != 0x40:
            raise self._unexpected(cmd, index, sub, "reading")
        if cmd & 0x02:  # expedited
            n = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
            return resp[4:4 + n]
        size = struct.unpack_from("<I", resp, 4)[0] if cmd & 0x01 else None
        out = bytearray()
        toggle = 0
        limit = MAX_SEGMENTED_BYTES if size is None else min(size, MAX_SEGMENTED_BYTES)
        while True:
            resp = self._exchange(bytes([0x60 | (toggle << 4)]) + bytes(7), index, sub,
                                  "reading", mux=False)
            seg = resp[0]
            if seg & 0xE0 != 0x00:
                raise self._unexpected(seg, index, sub, "reading")
            if (seg >> 4) & 1 != toggle:
                raise self._toggle_error(index, sub, "reading")
            out += resp[1:8 - ((seg >> 1) & 0x7)]
            if seg & 0x01:
                break
            if len(out) > limit:
                self._abort(index, sub, ABORT_OUT_OF_MEMORY)
                raise CanError(f"{self.label}: segmented upload of {index:04X}h:{sub:02X} "
                               f"longer than {limit} bytes (aborted)")
            toggle ^= 1
        if size is not None and len(out) != size:
            raise CanError(f"{self.label}: segmented upload of {index:04X}h:{sub:02X}: "
                           f"{len(out)} bytes received, {size} indicated")
        return bytes(out)

    def upload_uint(self, index: int, sub: int) -> int:
        return int.from_bytes(self.upload(index, sub), "little")

    def upload_int(self, index: int, sub: int) -> int:
        return int.from_bytes(self.upload(index, sub), "little", signed=True)
