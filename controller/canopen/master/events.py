"""Supervision events: what happened, where, in which cycle, and what the controller did."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from enum import StrEnum

log = logging.getLogger("controller.canopen")


class EventKind(StrEnum):
    """What an :class:`Event` is about (a ``str``: reports and logs show the value)."""

    BOOT = "boot"                        #: a node booted and was configured
    MISSING = "missing"                  #: a node did not answer at boot
    ENABLED = "enabled"                  #: all drives are OPERATION ENABLED
    ENABLE_TIMEOUT = "enable_timeout"    #: a drive did not reach OPERATION ENABLED in time
    FAULT_RESET = "fault_reset"          #: a drive fault was reset while enabling
    STOPPED = "stopped"                  #: the quick stop is done, all drives stand still
    LIMIT = "limit"                      #: a setpoint outside an axis limit
    EMCY = "emcy"                        #: an EMCY message
    DRIVE_FAULT = "drive_fault"          #: a drive in FAULT (statusword)
    DRIVE_SILENT = "drive_silent"        #: a drive's TPDO missing for silent_cycles
    DRIVE_DISABLED = "drive_disabled"    #: a drive left OPERATION ENABLED
    FOLLOWING_ERROR = "following_error"  #: 6041h bit 13 in CSP
    HEARTBEAT_LOST = "heartbeat_lost"    #: no heartbeat within the consumer time
    NMT_STATE = "nmt_state"              #: a node's heartbeat shows a state other than OPERATIONAL
    MASTER_SILENT = "master_silent"      #: the encoder went silent: de-sync
    MASTER_BACK = "master_back"          #: the encoder sends again
    MASTER_OUTLIER = "master_outlier"    #: an encoder sample the belt cannot have made
    MASTER_LOST = "master_lost"          #: max_outliers such samples in a row: de-sync
    ITEM_MISSED = "item_missed"          #: the demo: an item left its window unpicked
    # the controlled stop (master.stopping)
    STOP_CONFIRMED = "stop_confirmed"    #: a drive's statusword confirms its stop
    STOP_ESCALATED = "stop_escalated"    #: a drive not stopped in time: the next stage
    STOP_UNCONFIRMED = "stop_unconfirmed"  #: every stage done, the stop not confirmed
    INTERNAL_ERROR = "internal_error"    #: an unexpected exception inside the cycle
    NODE_RESET = "node_reset"            #: a configured node's boot-up mid-run
    # other actors (config.reactions.Disturbance: the configurable reactions)
    FOREIGN_NMT = "foreign_nmt"          #: an NMT command the controller did not send
    FOREIGN_SYNC = "foreign_sync"        #: a SYNC the controller did not send
    UNKNOWN_NODE = "unknown_node"        #: a heartbeat of a node-ID nobody configured
    IO_NODE_LOST = "io_node_lost"        #: the heartbeat of a slave that is no drive/encoder
    BAD_FRAME = "bad_frame"              #: a frame of wrong length/format (not processed)
    ERROR_PASSIVE = "error_passive"      #: the CAN controller error passive
    BUS_OFF = "bus_off"                  #: the CAN controller bus-off
    TRIGGER_DROPPED = "trigger_dropped"  #: the demo: a full trigger buffer dropped an item
    # a work cell (.tracking.cell, apps.cell)
    HANDOFF = "handoff"                  #: a robot's following goes over to another frame
    COMMAND_ERROR = "command_error"      #: a command the cell refused (the run goes on)
    START_POSE = "start_pose"            #: a robot starts where its drives are, not its start
    # the controller's own node for a PLC (docs/plc.md)
    PLC_NOT_OPERATIONAL = "plc_not_operational"  #: a motion write outside NMT OPERATIONAL
    PLC_NO_COMMANDER = "plc_no_commander"  #: a motion write without the commander's heartbeat
    PLC_OUTSIDE_WINDOW = "plc_outside_window"  #: a motion write outside the command window
    PLC_COMMANDER_LOST = "plc_commander_lost"  #: the commander's heartbeat timed out
    PLC_COMMANDER_BACK = "plc_commander_back"  #: the commander's heartbeat is back
    PLC_NMT = "plc_nmt"                  #: the node's NMT state changed by a command
    PLC_COB_ID_REFUSED = "plc_cob_id_refused"  #: a PDO COB-ID write refused
    PLC_TRIGGER_DROPPED = "plc_trigger_dropped"  #: trigger edges over the rate limit
    DEADLINES_MISSED = "deadlines_missed"  #: max_missed_in_row SYNC deadlines missed in a row
    CYCLE_BUDGET = "cycle_budget"        #: start-up: compute p99 above half the period


@dataclass(frozen=True, slots=True)
class Event:
    cycle: int  # -1 during the boot
    t_s: float  # controller time [s]
    source: str  # "node 11 (x)", "controller", ...
    kind: EventKind
    detail: str
    reaction: str = ""

    def as_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        cyc = f"cycle {self.cycle}" if self.cycle >= 0 else "boot"
        react = f" -> {self.reaction}" if self.reaction else ""
        return f"[{cyc}, {self.t_s:.3f} s] {self.source}: {self.kind}: {self.detail}{react}"


class EventLog:
    """The events of a run: the last ``limit`` kept (a run of weeks must not keep them all),
    every one counted, logged and passed to the ``listeners`` (streaming telemetry)."""

    #: events kept by default
    LIMIT = 1000

    def __init__(self, limit: int | None = LIMIT) -> None:
        self.events: deque[Event] = deque(maxlen=limit)
        #: events added in all
        self.total = 0
        #: events with a reaction / whose reaction was a quick stop, in all
        self.reactions = 0
        self.quick_stops = 0
        self.listeners: list[Callable[[Event], None]] = []

    def add(self, cycle: int, t_s: float, source: str, kind: EventKind | str, detail: str,
            reaction: str = "", level: int = logging.WARNING) -> Event:
        """Record and log an event; ``kind`` an :class:`EventKind` (or its value)."""
        try:
            kind = EventKind(kind)
        except ValueError:
            raise ValueError(f"unknown event kind {kind!r}: add it to EventKind "
                             "(controller.canopen.master.events)") from None
        e = Event(cycle, t_s, source, kind, detail, reaction)
        self.events.append(e)
        self.total += 1
        if reaction:
            self.reactions += 1
            if reaction.startswith("quick stop"):
                self.quick_stops += 1
        log.log(level, "%s", e)
        for listener in self.listeners:
            listener(e)
        return e

    def of_kind(self, kind: EventKind | str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]

    def __iter__(self):
        return iter(self.events)

    def __len__(self) -> int:
        return len(self.events)
