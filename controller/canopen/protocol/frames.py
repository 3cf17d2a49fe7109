"""CiA 301 frame hygiene: received frames checked before they are decoded.

Every consumer of the controller checks a frame's length (and format) against what it
expects before unpacking it; a bad frame is *not processed* (CiA 301 7.2.2.5: a PDO with
fewer data bytes than mapped is not processed, a slave would send EMCY 8210h; one with more
is processed with its first bytes, EMCY 8220h), counted per COB-ID and queued for the cycle,
which reports it as an event.  Nothing in a receive path raises: a frame from another actor
can never end the controller.

Formats checked (CiA 301): NMT 000h = 2 bytes (command, node-ID); SYNC = 0 bytes, or 1
(the counter) when ``sync_overflow`` is set; EMCY = 8 bytes (error code, error register,
5 manufacturer bytes); heartbeat = 1 byte (the NMT state); PDO = the mapped length.

:class:`FrameHygiene` is also the last line of defence of the receive path:
:meth:`FrameHygiene.guard` wraps a callback so that an unexpected exception inside it is
caught, counted and queued as an *internal error* (the cycle then makes the controlled stop
and the run fails) instead of unwinding through python-can's receive loop.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

Callback = Callable[[int, bytes, int], None]


class FrameFault(Enum):
    SHORT = "shorter than expected: not processed"
    LONG = "longer than expected: the first bytes used"
    FORMAT = "wrong format: not processed"


#: CiA 301's EMCY code a slave would send for the fault (reported in the event's detail)
EMCY_OF = {FrameFault.SHORT: 0x8210, FrameFault.LONG: 0x8220, FrameFault.FORMAT: 0x8200}


@dataclass(frozen=True, slots=True)
class BadFrame:
    cob_id: int
    data: bytes
    what: str  # "TPDO1 of node 10 (encoder)", "heartbeat", ...
    expected: str  # "4 bytes", ...
    fault: FrameFault
    t_ns: int

    def __str__(self) -> str:
        return (f"{self.cob_id:03X}h ({self.what}) with {len(self.data)} bytes "
                f"[{self.data.hex(' ').upper()}]: {self.fault.value} (expected "
                f"{self.expected}; CiA 301 EMCY {EMCY_OF[self.fault]:04X}h)")


@dataclass(frozen=True, slots=True)
class CallbackError:
    cob_id: int
    data: bytes
    error: str
    trace: str
    t_ns: int

    def __str__(self) -> str:
        return (f"unexpected {self.error} while handling {self.cob_id:03X}h "
                f"[{self.data.hex(' ').upper()}]")


@dataclass
class FrameHygiene:
    """Counts per COB-ID and the queue of bad frames / callback errors for the cycle."""

    counts: dict[int, int] = field(default_factory=dict)
    queue: list[BadFrame] = field(default_factory=list)
    errors: list[CallbackError] = field(default_factory=list)
    #: bad frames kept in the queue at most (a flood is counted, not stored)
    max_queued: int = 64

    def drop(self, cob_id: int, data: bytes, what: str, expected: str, fault: FrameFault,
             t_ns: int) -> None:
        self.counts[cob_id] = self.counts.get(cob_id, 0) + 1
        if len(self.queue) < self.max_queued:
            self.queue.append(BadFrame(cob_id, bytes(data), what, expected, fault, t_ns))

    def check_length(self, cob_id: int, data: bytes, size: int, what: str,
                     t_ns: int) -> bool:
        """True when ``data`` can be decoded as ``size`` bytes (longer: counted, still
        used, CiA 301); False (dropped, counted) when it is shorter."""
        n = len(data)
        if n == size:
            return True
        fault = FrameFault.SHORT if n < size else FrameFault.LONG
        self.drop(cob_id, data, what, f"{size} bytes", fault, t_ns)
        return n > size

    def check_exact(self, cob_id: int, data: bytes, sizes: tuple[int, ...], what: str,
                    t_ns: int) -> bool:
        """True when ``len(data)`` is one of ``sizes`` (a fixed-format service: NMT, SYNC,
        EMCY, heartbeat); otherwise dropped and counted."""
        if len(data) in sizes:
            return True
        self.drop(cob_id, data, what, " or ".join(f"{s} bytes" for s in sizes),
                  FrameFault.FORMAT, t_ns)
        return False

    def guard(self, callback: Callback) -> Callback:
        """``callback`` with every exception caught and queued as an internal error."""
        def guarded(can_id: int, data: bytes, t_ns: int) -> None:
            try:
                callback(can_id, data, t_ns)
            except Exception as exc:  # noqa: BLE001 -- the last line of defence
                self.errors.append(CallbackError(can_id, bytes(data),
                                                 f"{type(exc).__name__}: {exc}",
                                                 traceback.format_exc(), t_ns))
        guarded.__wrapped__ = callback  # type: ignore[attr-defined]
        return guarded

    def pop_all(self) -> tuple[list[BadFrame], list[CallbackError]]:
        bad, errors = self.queue, self.errors
        self.queue, self.errors = [], []
        return bad, errors

    @property
    def total(self) -> int:
        return sum(self.counts.values())
