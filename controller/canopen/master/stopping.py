"""The controlled stop: confirmed by each drive's statusword, or escalated.

After a reaction every drive gets the quick stop (6040h = 0002h, CiA 402 transition 11) by
its RPDO every cycle.  The stop of a drive is *confirmed* when a fresh TPDO shows a stopped
state (:func:`is_stopped`: switch on disabled, ready to switch on, switched on, not ready,
fault, or quick stop active with bit 10 "target reached" = halted).  A drive that does not
confirm within ``timeouts.stop_s`` goes to the next :class:`StopStage`, each again for
``stop_s``:

1. ``NMT_START``: NMT start remote node (01h): a node that another master stopped or put
   pre-operational processes RPDOs again (CiA 301); the quick stop also by SDO (6040h, an
   expedited download: pre-operational nodes serve SDO);
2. ``DISABLE_VOLTAGE``: 6040h = 0000h by RPDO and SDO (transition 9/12: the power stage off,
   the brake engages);
3. ``NMT_STOP``: NMT stop (02h) to the node and the controller's heartbeat off: the drive's
   heartbeat consumer (1016h) times out and applies its abort-connection option 6007h;
From stage 1 on the statusword is also read by SDO (6041h, every few cycles): a node without
TPDOs (pre-operational, stopped) still answers SDO in pre-operational.

4. ``UNCONFIRMED``: nothing more the bus can do: an event ``stop_unconfirmed`` names the last
   statusword seen, the run ends with exit code 4.

Each drive's final state (stage, statusword, the cycle it was confirmed) goes into the run
report (:meth:`DriveStop.as_dict`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum

from ..protocol import cia402
from ..protocol.cia402 import State

#: the states in which a drive does not move on its own
STOPPED_STATES = frozenset({State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON,
                            State.SWITCHED_ON, State.NOT_READY_TO_SWITCH_ON, State.FAULT})


class StopStage(Enum):
    QUICK_STOP = 0
    NMT_START = 1
    DISABLE_VOLTAGE = 2
    NMT_STOP = 3
    UNCONFIRMED = 4

    @property
    def text(self) -> str:
        return _TEXT[self]


_TEXT = {
    StopStage.QUICK_STOP: "quick stop (6040h = 0002h by RPDO)",
    StopStage.NMT_START: "NMT start + quick stop by RPDO and SDO",
    StopStage.DISABLE_VOLTAGE: "disable voltage (6040h = 0000h by RPDO and SDO)",
    StopStage.NMT_STOP: "NMT stop + the controller's heartbeat off (the drive's 6007h)",
    StopStage.UNCONFIRMED: "unconfirmed",
}


def is_stopped(statusword: int) -> bool:
    """A stopped state (see the module docstring)."""
    st = cia402.decode_statusword(statusword)
    if st in STOPPED_STATES:
        return True
    return st is State.QUICK_STOP_ACTIVE and bool(statusword & cia402.SW_TARGET_REACHED)


#: cycles between two SDO reads of 6041h of a drive being escalated
SDO_POLL_CYCLES = 5


def sdo_statusword_request() -> bytes:
    """An SDO upload request of 6041h:00: a drive that sends no TPDO (pre-operational,
    stopped by another master) still answers SDO in pre-operational."""
    return struct.pack("<BHB4x", 0x40, 0x6041, 0)


def statusword_from_sdo(data: bytes) -> int | None:
    """The statusword of an expedited upload response of 6041h:00, else None."""
    if len(data) != 8 or data[0] & 0xE3 not in (0x43, 0x42) or \
            struct.unpack_from("<HB", data, 1) != (0x6041, 0):
        return None
    return struct.unpack_from("<H", data, 4)[0]


def sdo_controlword(controlword: int) -> bytes:
    """An expedited SDO download of 6040h:00 (2 bytes), sent without waiting for the answer
    (the statusword is the confirmation)."""
    return struct.pack("<BHBH2x", 0x2B, 0x6040, 0, controlword)


@dataclass
class DriveStop:
    """One drive's controlled stop."""

    label: str
    node_id: int
    stage: StopStage = StopStage.QUICK_STOP
    begin_cycle: int | None = None  # the cycle the stop began (None: no stop)
    stage_cycle: int = 0  # the cycle the current stage began
    confirmed_cycle: int | None = None
    statusword: int | None = None  # the last one seen
    last_cycle: int | None = None  # the cycle of the last TPDO seen

    def begin(self, k: int) -> None:
        if self.begin_cycle is None:
            self.begin_cycle = self.stage_cycle = k

    def seen(self, k: int, statusword: int) -> None:
        self.statusword = statusword
        self.last_cycle = k

    def escalate(self, k: int) -> None:
        self.stage = StopStage(min(self.stage.value + 1, StopStage.UNCONFIRMED.value))
        self.stage_cycle = k

    @property
    def finished(self) -> bool:
        return self.confirmed_cycle is not None or self.stage is StopStage.UNCONFIRMED

    @property
    def state_name(self) -> str:
        st = cia402.decode_statusword(self.statusword) if self.statusword is not None else None
        return st.value if st is not None else "unknown"

    def as_dict(self) -> dict:
        return {"drive": self.label, "node_id": self.node_id, "state": self.state_name,
                "statusword": self.statusword, "last_tpdo_cycle": self.last_cycle,
                "stop_began": self.begin_cycle, "stage": self.stage.name.lower(),
                "confirmed": self.confirmed_cycle is not None,
                "confirmed_cycle": self.confirmed_cycle,
                "cycles_to_stop": (None if self.confirmed_cycle is None or self.begin_cycle
                                   is None else self.confirmed_cycle - self.begin_cycle)}
