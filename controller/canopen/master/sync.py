"""The SYNC producer, with the CiA 301 counter (1019h synchronous counter overflow value).

Our own, not python canopen's ``network.sync.start()``: that one sends SYNC without a
counter and from its own python-can periodic-send thread, so the controller could not put
its cycle on the SYNC (compute after the SYNC, RPDOs before the next) nor keep one time
base.  Here the cycle sends the SYNC itself at its absolute deadline
``t0 + k * period`` (integer ns, :mod:`controller.canopen.master.cycle`).

Counter (``overflow`` = 2...240): 1, 2, ..., overflow, 1, ... (one data byte); ``overflow``
= 0: no data byte.
"""

from __future__ import annotations

from ..io.transport import Transport

#: the SYNC's data for each counter value (made once: no bytes object per cycle)
_COUNTER_DATA = tuple(bytes((c,)) for c in range(241))


class SyncProducer:
    def __init__(self, transport: Transport, cob_id: int = 0x80, overflow: int = 0) -> None:
        if overflow == 1 or not 0 <= overflow <= 240:
            raise ValueError(f"overflow (={overflow}) must be 0 or in [2...240]")
        self.transport = transport
        self.cob_id = cob_id
        self.overflow = overflow
        self.counter = 0
        self.sent = 0

    def send(self) -> int | None:
        """Send one SYNC; returns its counter (None without counter)."""
        self.sent += 1
        if not self.overflow:
            self.transport.send(self.cob_id, b"")
            return None
        counter = self.counter = self.counter % self.overflow + 1
        self.transport.send(self.cob_id, _COUNTER_DATA[counter])
        return counter
