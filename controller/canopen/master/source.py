"""The setpoint-source protocol: what the cycle hands a source and what it gets back.

Once per RUNNING cycle :class:`~controller.canopen.master.cycle.Controller` builds a frozen
:class:`CycleContext` (the cycle's index and time, the master estimate, each drive's 402
state, actual position and statusword, and the PLC's commands since the last cycle) and calls
the source's :meth:`SetpointSource.step` with it.  The source returns a :class:`SourceOutput`:
the cycle's setpoint (a tool location for the kinematics, or one position per axis), its
typed :class:`SourceStatus` (what the cycle record and the controller's own node for a PLC
read) and its requests as typed values (events to log, a quick stop, the end of the run).

The values handed over every cycle are named tuples (immutable, and cheap to make: a
frozen dataclass costs several times more per field, in the cycle's hot path); the rare ones
(commands, requests, the start) frozen dataclasses.

A source is pure: what it returns depends only on the contexts it was given (and on its
construction); it does no I/O, reads no clock and never sees the controller.  Where it needs
the tracker or a conveyor robot group (pure core objects) it owns them.  The cycle is the only
imperative part: it alone sends frames, logs events and stops the drives.  The cycle looks up
nothing on a source beyond :class:`SetpointSource`'s two methods.

Units: positions mm (deg for rotary axes and angles), time s (``t_ns``: ns of the controller
clock), the master in mm of belt travel.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, NamedTuple, Protocol

from ...tracking import Imfs, MasterEstimate, Mode, MotionState, TrackError, TrackState
from ..protocol import cia402
from ..protocol.cia402 import State
from .events import EventKind

if TYPE_CHECKING:
    from ..config.tracking import TrackingConfig


class MasterEvent(Enum):
    """What happened to the master (encoder) input in this cycle."""

    NONE = "none"
    SILENT = "silent"      #: no sample for ``silent_cycles``: a following source de-syncs
    LOST = "lost"          #: ``max_outliers`` outliers in a row: de-sync with MASTER_LOST
    OUTLIER = "outlier"    #: one sample rejected, the estimate coasts
    BACK = "back"          #: samples arrive again, the estimator restarted


class MasterView(NamedTuple):
    """The master of this cycle: ``estimate`` for the SYNC the setpoint is for (k+1+d) [mm,
    mm/s, mm/s², mm/s³]; ``belt_mm`` the newest measured belt travel [mm] (None before the
    first sample); ``ready`` the estimate is usable (its window is full, not lost)."""

    estimate: MasterEstimate
    belt_mm: float | None
    ready: bool
    event: MasterEvent = MasterEvent.NONE


class DriveView(NamedTuple):
    """One drive as its TPDOs of this cycle showed it: ``state`` the CiA 402 state (None: an
    invalid statusword), ``statusword`` 6041h, ``actual`` 6064h [mm | deg, machine
    coordinate]; ``fresh`` False when no TPDO came this cycle (the values are the last ones;
    ``statusword`` 0 and ``actual`` None before the first).  ``inputs``: 60FDh digital inputs
    (a TPDO of transmission 1 maps them; None: not mapped); ``probe``: (60B9h, 60BAh) touch
    probe status and latched position [counts] from a TPDO that maps both, the last one since
    the probe was last armed (an SDO write of 60B8h), None if none."""

    axis: str
    state: State | None
    statusword: int
    actual: float | None
    fresh: bool
    inputs: int | None = None
    probe: tuple[int, int] | None = None


@dataclass(frozen=True, slots=True)
class Engage:
    """A PLC's engage command (2005h): ``mode`` 3 absolute / 5 relative, 0 de-sync."""

    mode: Mode


@dataclass(frozen=True, slots=True)
class Trigger:
    """A PLC's item trigger edge at ``t_ns`` [ns, controller clock] for an item of
    ``item_type`` (0...255, 2014h)."""

    t_ns: int
    item_type: int = 0


@dataclass(frozen=True, slots=True)
class TrackTypes:
    """A PLC's tracked item types (2015h): only items of ``types`` from now on (None: every
    type)."""

    types: frozenset[int] | None


#: what a PLC may command, delivered with the next cycle's context in arrival order
Command = Engage | Trigger | TrackTypes


class CycleContext(NamedTuple):
    """Everything a source gets in cycle ``cycle``: ``t_s`` [s] from the start of the cycle
    clock (SYNC k's deadline), ``t_ns`` the same on the controller clock [ns]; the master; the
    drives in the order of ``.tracking.axes``; the PLC's commands since the last cycle;
    ``tracking_error_mm`` the |actual - target| over x, y, z of the last cycle's record;
    ``masters``: a cell's every encoder (``.tracking.cell.encoders``, in that order; the
    first is ``master``), empty without a cell."""

    cycle: int
    t_s: float
    t_ns: int
    master: MasterView
    drives: tuple[DriveView, ...]
    commands: tuple[Command, ...] = ()
    tracking_error_mm: float = 0.0
    masters: tuple[MasterView, ...] = ()


@dataclass(frozen=True, slots=True)
class SourceStart:
    """Tracking begins (all drives OPERATION ENABLED, the master ready) in cycle ``cycle``:
    the ``.tracking`` configuration and period [s], the joints where the drives were enabled
    [mm | deg, in the order of ``.tracking.axes``] and the tool pose there [mm, deg]."""

    cycle: int
    t_s: float
    t_ns: int
    period_s: float
    tracking: TrackingConfig
    joints: tuple[float, ...]
    pose: MotionState
    drives: tuple[DriveView, ...] = ()
    #: a cell's every encoder at the start (as :attr:`CycleContext.masters`; empty without)
    masters: tuple[MasterView, ...] = ()


@dataclass(frozen=True, slots=True)
class SdoDownload:
    """Write ``data`` to ``index``:``sub`` of the drive of axis ``axis`` (its index in
    ``.tracking.axes``) by SDO."""

    axis: int
    index: int
    sub: int
    data: bytes


@dataclass(frozen=True, slots=True)
class SdoUpload:
    """Read ``index``:``sub`` of the drive of axis ``axis`` by SDO; the value (an integer,
    ``signed`` or not) is sent back into the transfer program."""

    axis: int
    index: int
    sub: int
    signed: bool = False


Transfer = SdoDownload | SdoUpload

#: a source's SDO program between two cycles: a generator that yields the transfers one by
#: one and is sent each upload's value (None after a download); a transfer that fails is
#: thrown into it (the :class:`~controller.errors.CanError`), where the program may handle it.
#: The cycle runs it before the next SYNC; the program itself does no I/O.
Transfers = Generator[Transfer, int | None, None]


class DriveCommand(Enum):
    """What a drive is told besides its target (the controlword 6040h it is sent)."""

    ENABLE = cia402.CW_ENABLE                        #: CSP: follow the target
    HOMING_START = cia402.CW_ENABLE | 1 << 4         #: homing mode: bit 4 starts the homing
    QUICK_STOP = cia402.CW_QUICK_STOP_CMD            #: quick stop (this axis)

    @property
    def controlword(self) -> int:
        return int(self.value)


class AxisSetpoints(NamedTuple):
    """One target per axis [mm | deg, machine coordinate, the order of ``.tracking.axes``],
    and per axis what its drive is told (None: every drive ENABLE).  ``velocities`` [mm/s |
    deg/s per axis]: given, the cycle checks the targets against the axis limits as it does
    a tool setpoint's joints (the target, and where a quick stop at 6085h from that velocity
    ends); None: the source keeps its axes within their limits itself (the axis jobs)."""

    positions: tuple[float, ...]
    commands: tuple[DriveCommand, ...] | None = None
    velocities: tuple[float, ...] | None = None


#: a cycle's setpoint: a tool location [mm, deg] (through the kinematics) or axis targets
Setpoint = MotionState | AxisSetpoints


class SourceStatus(NamedTuple):
    """What a source reports after a cycle (the cycle record, the PLC node, the status line).

    ``track_state``/``imfs``: the belt tracking to report (2011h, the record; the demo's: its
    robot group's).  ``tracker_state``/``tracker_imfs``/``error``: the tracker whose setpoint
    goes out (the demo's pass-through; OFF for axis jobs): not OFF -> the tracking error is
    measured; SYNCING/SYNCED -> a master loss de-syncs.  ``items_detected``: items seen by the
    source's item sensor (None: it has none, the PLC node counts its own triggers);
    ``items_missed``; ``triggers_dropped`` by a full trigger buffer; ``items_ignored``."""

    track_state: TrackState = TrackState.OFF
    imfs: Imfs = Imfs.NOT_SYNCHRONIZED
    tracker_state: TrackState = TrackState.OFF
    tracker_imfs: Imfs = Imfs.NOT_SYNCHRONIZED
    error: TrackError = TrackError.NONE
    items_detected: int | None = None
    items_missed: int = 0
    triggers_dropped: int = 0
    #: items of a type the source does not track (2016h)
    items_ignored: int = 0

    @property
    def engaged(self) -> bool:
        """The tracker follows the master (a master loss de-syncs it)."""
        return self.tracker_state in (TrackState.SYNCING, TrackState.SYNCED)


#: the status of a source that tracks nothing and has no items
NO_STATUS = SourceStatus()


@dataclass(frozen=True, slots=True)
class SourceEvent:
    """An event the source asks the cycle to log (in this cycle, at its time)."""

    source: str
    kind: EventKind
    detail: str
    reaction: str = ""
    level: int = logging.WARNING


@dataclass(frozen=True, slots=True)
class QuickStop:
    """The source asks for the quick stop of all drives (``source``: the axis' label)."""

    source: str
    kind: EventKind
    detail: str


class SourceOutput(NamedTuple):
    """What :meth:`SetpointSource.step` returns: the setpoint for SYNC k+1, the status,
    ``target`` the master the tracker follows at SYNC k+1+d [mm, deg] (the tracking error;
    None: not measured), and the requests: ``events`` to log, a ``stop``, ``done`` (the run
    is over after this cycle), ``transfers`` an SDO program to run before the next SYNC
    (:data:`Transfers`: a generator)."""

    setpoint: Setpoint
    status: SourceStatus = NO_STATUS
    target: MotionState | None = None
    events: tuple[SourceEvent, ...] = ()
    stop: QuickStop | None = None
    done: bool = False
    transfers: Transfers | None = None


class SetpointSource(Protocol):
    """What the cycle runs while RUNNING (see the module docstring).  Both methods are pure
    in the sense above: deterministic in their arguments and the source's construction."""

    def start(self, start: SourceStart) -> SourceStatus:
        """Tracking begins; the status before the first :meth:`step`."""

    def step(self, ctx: CycleContext) -> SourceOutput:
        """One cycle: the setpoint for the next SYNC, the status, the requests."""
