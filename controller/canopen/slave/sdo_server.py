"""python canopen's ``LocalNode`` and ``SdoServer`` on the slave-node engine
(:class:`~.engine.SlaveEngine`; its module docstring says what they change and why).

A module of their own, not compiled (setup.py ``PURE_ONLY``): they subclass python canopen's
classes, which the compile does not read (setup.py ``MYPYC_INI``), and mypyc would make a
class of its own of them, without those bases (docs/architecture.md "Compiled core").  They
serve SDO, not the SYNCs.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any

from canopen import LocalNode
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoServer

from ..protocol.sdo import ABORT_COMMAND, SdoAbortError

if TYPE_CHECKING:
    from .engine import SlaveEngine


class EngineNode(LocalNode):
    """python canopen's LocalNode whose two data calls go through the engine."""

    def __init__(self, engine: SlaveEngine, node_id: int, od: ObjectDictionary) -> None:
        super().__init__(node_id, od)
        self.engine = engine

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        return self.engine._sdo_read(index, subindex, check_readable)

    def set_data(self, index: int, subindex: int, data: bytes,
                 check_writable: bool = False) -> None:
        self.engine._sdo_write(index, subindex, bytes(data), check_writable)


class EngineSdoServer(SdoServer):
    """canopen's SDO server on the engine's bus (see the module docstring)."""

    def __init__(self, engine: SlaveEngine, node: EngineNode) -> None:
        super().__init__(0x600 + engine.node_id, 0x580 + engine.node_id, node)
        self.engine = engine
        #: the transfer in progress: ("up" | "down", index, sub, bytes left to upload)
        self.transfer: tuple[str, int, int, int] | None = None

    def send_response(self, response: bytes | bytearray) -> None:
        self.engine._send("sdo", self.tx_cobid, bytes(response))

    def _abort_with(self, index: int, sub: int, code: int) -> None:
        self.transfer = None
        self.send_response(struct.pack("<BHBI", 0x80, index, sub, code))

    def on_request(self, can_id: int, data: bytes, timestamp: Any) -> None:
        if len(data) != 8:
            # CiA 301: SDO frames have 8 bytes (canopen's server would fail in its unpack):
            # abort 05040001h, naming what index/sub-index bytes there are
            head = bytes(data[1:4]).ljust(3, b"\0")
            self.transfer = None
            self.send_response(b"\x80" + head + ABORT_COMMAND.to_bytes(4, "little"))
            return
        cmd = data[0]
        ccs = cmd >> 5
        if ccs == 4:  # the client aborts
            self.transfer = None
            return
        if ccs in (1, 2, 5, 6):
            index, sub = struct.unpack_from("<HB", data, 1)
            self.transfer = None
            try:
                if ccs in (5, 6):
                    raise SdoAbortError(ABORT_COMMAND)  # block transfer: not supported
                if ccs == 1 and not cmd & 0x02:  # segmented download: check it now
                    self.engine._check_write_access(index, sub)
                    self.transfer = ("down", index, sub, 0)
                elif ccs == 2:
                    size = len(self.engine._sdo_read(index, sub, True))
                    if size > 4:
                        self.transfer = ("up", index, sub, size)
            except SdoAbortError as exc:
                self._abort_with(index, sub, exc.code)
                return
        elif ccs in (0, 3):
            t = self.transfer
            if t is None or t[0] != ("down" if ccs == 0 else "up"):
                self._abort_with(t[1] if t else 0, t[2] if t else 0, ABORT_COMMAND)
                return
            if ccs == 3:
                left = t[3] - 7
                self.transfer = (t[0], t[1], t[2], left) if left > 0 else None
            elif cmd & 0x01:  # the last segment of a download
                self.transfer = None
        else:
            self._abort_with(0, 0, ABORT_COMMAND)
            return
        super().on_request(can_id, data, timestamp)
