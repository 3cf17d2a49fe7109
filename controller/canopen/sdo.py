"""A small SDO client (CiA 301 expedited transfers) on the controller's transport.

python canopen's SDO client blocks in a queue wait with its own time-out (0.3 s x 1 retry)
and is not thread-safe (canopen-notes.md); here a request waits through
``transport.run_until`` instead, so the same code runs in stepped and in real time and the
time-out is ours.  Only expedited transfers (1-4 bytes) are needed for configuration; a
segmented upload answer is reported as an error.

Errors name the node, the object (index:sub) and, for an abort, the abort code and its
meaning: ``node 11 (x): SDO abort 06090030h (Value range of parameter exceeded) writing
60C2h:02``.
"""

from __future__ import annotations

import struct

from canopen.sdo.exceptions import SdoAbortedError

from ..errors import CanError, CanTimeoutError
from .transport import Transport


def abort_text(code: int) -> str:
    return SdoAbortedError.CODES.get(code, "unknown abort code")


class SdoAbortError(CanError):
    """The slave aborted an SDO transfer."""

    def __init__(self, label: str, index: int, sub: int, code: int, action: str) -> None:
        self.label, self.index, self.sub, self.code = label, index, sub, code
        super().__init__(f"{label}: SDO abort {code:08X}h ({abort_text(code)}) {action} "
                         f"{index:04X}h:{sub:02X}")


class SdoTimeoutError(CanTimeoutError):
    def __init__(self, label: str, index: int, sub: int, action: str, timeout_s: float,
                 retries: int = 0) -> None:
        self.label, self.index, self.sub = label, index, sub
        tries = f" ({retries + 1} attempts)" if retries else ""
        super().__init__(f"{label}: no SDO response within {timeout_s:g} s{tries} {action} "
                         f"{index:04X}h:{sub:02X}")


class SdoClient:
    """Expedited SDO transfers to one node (default COB-IDs 600h/580h + node-ID)."""

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

    def _exchange(self, request: bytes, index: int, sub: int, action: str) -> bytes:
        t = self.transport
        self._response = None
        t.subscribe(0x580 + self.node_id, self._on_response)
        try:
            for attempt in range(self.retries + 1):
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
            raise SdoAbortError(self.label, index, sub, struct.unpack_from("<I", resp, 4)[0],
                                action)
        if (r_index, r_sub) != (index, sub):
            raise CanError(f"{self.label}: SDO response for {r_index:04X}h:{r_sub:02X} while "
                           f"{action} {index:04X}h:{sub:02X}")
        return resp

    def download(self, index: int, sub: int, data: bytes) -> None:
        """Write 1-4 bytes (expedited download)."""
        n = len(data)
        if not 1 <= n <= 4:
            raise ValueError(f"expedited download of {n} bytes (1...4)")
        cmd = 0x23 | ((4 - n) << 2)
        request = struct.pack("<BHB", cmd, index, sub) + bytes(data) + bytes(4 - n)
        resp = self._exchange(request, index, sub, "writing")
        if resp[0] != 0x60:
            raise CanError(f"{self.label}: unexpected SDO response {resp[0]:02X}h writing "
                           f"{index:04X}h:{sub:02X}")

    def upload(self, index: int, sub: int) -> bytes:
        """Read an object of 1-4 bytes (expedited upload)."""
        request = struct.pack("<BHB", 0x40, index, sub) + bytes(4)
        resp = self._exchange(request, index, sub, "reading")
        cmd = resp[0]
        if cmd & 0xE0 != 0x40:
            raise CanError(f"{self.label}: unexpected SDO response {cmd:02X}h reading "
                           f"{index:04X}h:{sub:02X}")
        if not cmd & 0x02:
            raise CanError(f"{self.label}: {index:04X}h:{sub:02X} needs a segmented transfer "
                           "(not supported: only objects of 1-4 bytes are read)")
        n = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
        return resp[4:4 + n]

    def upload_uint(self, index: int, sub: int) -> int:
        return int.from_bytes(self.upload(index, sub), "little")

    def upload_int(self, index: int, sub: int) -> int:
        return int.from_bytes(self.upload(index, sub), "little", signed=True)
