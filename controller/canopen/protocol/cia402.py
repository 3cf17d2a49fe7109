"""CiA 402 (IEC 61800-7-201) drive state machine: states, statusword, controlword, transitions.

Shared by the controller (which computes the next controlword) and the simulated drive
(which applies it).  Pure functions, no I/O.

Statusword (6041h) decoding, mask/value (CiA 402-2, table "state coding")::

    0x4F/0x00 NOT_READY_TO_SWITCH_ON      0x4F/0x40 SWITCH_ON_DISABLED
    0x6F/0x21 READY_TO_SWITCH_ON          0x6F/0x23 SWITCHED_ON
    0x6F/0x27 OPERATION_ENABLED           0x6F/0x07 QUICK_STOP_ACTIVE
    0x4F/0x0F FAULT_REACTION_ACTIVE       0x4F/0x08 FAULT

Controlword (6040h) commands, mask/value: shutdown 0x87/0x06, switch on 0x8F/0x07,
switch on + enable operation 0x8F/0x0F, disable voltage 0x82/0x00, quick stop 0x86/0x02,
disable operation 0x8F/0x07, enable operation 0x8F/0x0F, fault reset = rising edge of bit 7.
"""

from __future__ import annotations

from enum import Enum
from functools import lru_cache

# statusword bits
SW_READY = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # 1 = NOT in quick stop (active low)
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_FOLLOWS_TARGET = 1 << 12  # CSP: drive follows the command value
SW_FOLLOWING_ERROR = 1 << 13  # CSP: following error

# controlword bits and commands
CW_SWITCH_ON = 1 << 0
CW_ENABLE_VOLTAGE = 1 << 1
CW_QUICK_STOP = 1 << 2  # 0 = quick stop (active low)
CW_ENABLE_OPERATION = 1 << 3
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8

CW_SHUTDOWN = 0x06
CW_SWITCH_ON_CMD = 0x07
CW_ENABLE = 0x0F
CW_DISABLE_VOLTAGE = 0x00
CW_QUICK_STOP_CMD = 0x02
CW_DISABLE_OPERATION = 0x07
CW_FAULT_RESET_CMD = 0x80

MODE_PP = 1
MODE_HM = 6
MODE_CSP = 8


class State(Enum):
    # (Enum hashes a member by its name in Python code; the members are singletons compared
    #  by identity, so the identity hash gives the same dicts and sets, several times faster:
    #  a state is a key in the drive's tables every cycle)
    __hash__ = object.__hash__

    NOT_READY_TO_SWITCH_ON = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


#: state -> the statusword bits 0-6 (bit 4 "voltage enabled" is set by the drive when powered)
STATE_BITS: dict[State, int] = {
    State.NOT_READY_TO_SWITCH_ON: 0x00,
    State.SWITCH_ON_DISABLED: 0x40,
    State.READY_TO_SWITCH_ON: 0x21,
    State.SWITCHED_ON: 0x23,
    State.OPERATION_ENABLED: 0x27,
    State.QUICK_STOP_ACTIVE: 0x07,
    State.FAULT_REACTION_ACTIVE: 0x0F,
    State.FAULT: 0x08,
}

_DECODE = (
    (0x4F, 0x00, State.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)


def _decode(statusword: int) -> State | None:
    for mask, value, state in _DECODE:
        if statusword & mask == value:
            return state
    return None


#: every mask of _DECODE is within 6Fh: the state of each pattern of those bits, once
STATE_OF_BITS: tuple[State | None, ...] = tuple(_decode(bits) for bits in range(0x70))


def decode_statusword(statusword: int) -> State | None:
    """The state a statusword shows, or None for an invalid pattern."""
    return STATE_OF_BITS[statusword & 0x6F]


# -- controlword commands (mask, value) -----------------------------------------------------
class Command(Enum):
    """Controlword commands as (mask, value, name).  "switch on" and "disable operation"
    share a bit pattern (as do "switch on + enable operation" and "enable operation"); the
    state they are given in tells them apart, so each keeps its own member (the name makes
    the values unique instead of aliases)."""

    SHUTDOWN = (0x87, 0x06, "shutdown")
    SWITCH_ON = (0x8F, 0x07, "switch on")
    SWITCH_ON_ENABLE = (0x8F, 0x0F, "switch on + enable operation")  # 3 then 4
    DISABLE_VOLTAGE = (0x82, 0x00, "disable voltage")
    QUICK_STOP = (0x86, 0x02, "quick stop")
    DISABLE_OPERATION = (0x8F, 0x07, "disable operation")
    ENABLE_OPERATION = (0x8F, 0x0F, "enable operation")

    def matches(self, controlword: int) -> bool:
        mask, value, _ = self.value
        return controlword & mask == value


S = State
#: (from, to) -> (transition number, command or None for an automatic transition)
#: CiA 402-2 figure "state machine" and its transition table.
TRANSITIONS: dict[tuple[State, State], tuple[int, Command | None]] = {
    (S.NOT_READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED): (1, None),
    (S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON): (2, Command.SHUTDOWN),
    (S.READY_TO_SWITCH_ON, S.SWITCHED_ON): (3, Command.SWITCH_ON),
    (S.SWITCHED_ON, S.OPERATION_ENABLED): (4, Command.ENABLE_OPERATION),
    (S.OPERATION_ENABLED, S.SWITCHED_ON): (5, Command.DISABLE_OPERATION),
    (S.SWITCHED_ON, S.READY_TO_SWITCH_ON): (6, Command.SHUTDOWN),
    (S.READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED): (7, Command.DISABLE_VOLTAGE),
    (S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON): (8, Command.SHUTDOWN),
    (S.OPERATION_ENABLED, S.SWITCH_ON_DISABLED): (9, Command.DISABLE_VOLTAGE),
    (S.SWITCHED_ON, S.SWITCH_ON_DISABLED): (10, Command.DISABLE_VOLTAGE),
    (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE): (11, Command.QUICK_STOP),
    (S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED): (12, Command.DISABLE_VOLTAGE),
    # 13: any state -> FAULT_REACTION_ACTIVE on a fault (automatic; not a table entry)
    (S.FAULT_REACTION_ACTIVE, S.FAULT): (14, None),
    (S.FAULT, S.SWITCH_ON_DISABLED): (15, None),  # rising edge of controlword bit 7
    (S.QUICK_STOP_ACTIVE, S.OPERATION_ENABLED): (16, Command.ENABLE_OPERATION),
}
#: quick stop also leads from these states to SWITCH ON DISABLED (transitions 7 and 10)
QUICK_STOP_TO_DISABLED = {(S.READY_TO_SWITCH_ON, 7), (S.SWITCHED_ON, 10)}

FAULT_TRANSITION = 13

#: the command sequence the controller uses to reach OPERATION ENABLED from each state
_TOWARDS_ENABLED: dict[State, int] = {
    S.SWITCH_ON_DISABLED: CW_SHUTDOWN,  # 2
    S.READY_TO_SWITCH_ON: CW_SWITCH_ON_CMD,  # 3
    S.SWITCHED_ON: CW_ENABLE,  # 4
    S.OPERATION_ENABLED: CW_ENABLE,  # stay
    S.QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,  # 12, then 2, 3, 4
    S.NOT_READY_TO_SWITCH_ON: CW_DISABLE_VOLTAGE,  # wait for 1
    S.FAULT_REACTION_ACTIVE: CW_DISABLE_VOLTAGE,  # wait for 14
}


def controlword_towards_enabled(state: State | None, previous_controlword: int) -> int:
    """The next controlword on the way to OPERATION ENABLED, one transition at a time.

    From FAULT: 0x00 first, then 0x80 (fault reset needs a rising edge of bit 7,
    transition 15).  Pure function of the shown state and the last controlword sent.
    """
    if state is None:
        return CW_DISABLE_VOLTAGE
    if state is S.FAULT:
        return CW_FAULT_RESET_CMD if not previous_controlword & CW_FAULT_RESET \
            and previous_controlword == CW_DISABLE_VOLTAGE else CW_DISABLE_VOLTAGE
    return _TOWARDS_ENABLED[state]


def transition_for(state: State, controlword: int, previous_controlword: int,
                   quick_stop_option: int = 2) -> tuple[State, int] | None:
    """(new state, transition number) that ``controlword`` triggers in ``state``, or None
    (see :func:`_transition_for`; memoised: the answer depends on a few bits only)."""
    return _transition_cached(state, controlword & 0x1FF,
                              bool(previous_controlword & CW_FAULT_RESET),
                              quick_stop_option in (5, 6, 7, 8))


@lru_cache(maxsize=4096)
def _transition_cached(state: State, controlword: int, previous_reset: bool,
                       qs_stays: bool) -> tuple[State, int] | None:
    return _transition_for(state, controlword, CW_FAULT_RESET if previous_reset else 0,
                           5 if qs_stays else 2)


def _transition_for(state: State, controlword: int, previous_controlword: int,
                    quick_stop_option: int = 2) -> tuple[State, int] | None:
    """(new state, transition number) that ``controlword`` triggers in ``state``, or None.

    Used by the simulated drive.  Commands that the table does not allow from ``state``
    are ignored (the drive stays where it is), which is what makes a controller that skips
    a step fail.  ``quick_stop_option`` (605Ah) decides whether ENABLE OPERATION leaves
    QUICK STOP ACTIVE (transition 16, options 5-8 only).
    """
    if state is S.FAULT:
        if controlword & CW_FAULT_RESET and not previous_controlword & CW_FAULT_RESET:
            return S.SWITCH_ON_DISABLED, 15
        return None
    if state in (S.NOT_READY_TO_SWITCH_ON, S.FAULT_REACTION_ACTIVE):
        return None  # automatic transitions only
    # quick stop / disable voltage take precedence (they are checked on bits 1 and 2)
    if state is S.OPERATION_ENABLED and Command.QUICK_STOP.matches(controlword):
        return S.QUICK_STOP_ACTIVE, 11
    if state in (S.READY_TO_SWITCH_ON, S.SWITCHED_ON) and (
            Command.QUICK_STOP.matches(controlword)
            or Command.DISABLE_VOLTAGE.matches(controlword)):
        return S.SWITCH_ON_DISABLED, 7 if state is S.READY_TO_SWITCH_ON else 10
    if Command.DISABLE_VOLTAGE.matches(controlword) and state in (
            S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):
        return S.SWITCH_ON_DISABLED, 9 if state is S.OPERATION_ENABLED else 12
    if state is S.QUICK_STOP_ACTIVE:
        if Command.ENABLE_OPERATION.matches(controlword) and quick_stop_option in (5, 6, 7, 8):
            return S.OPERATION_ENABLED, 16
        return None
    for (src, dst), (number, cmd) in TRANSITIONS.items():
        if src is state and cmd is not None and cmd.matches(controlword):
            return dst, number
    if state is S.READY_TO_SWITCH_ON and Command.SWITCH_ON_ENABLE.matches(controlword):
        return S.OPERATION_ENABLED, 4  # 3 and 4 in one step ("switch on + enable operation")
    return None
