"""The cyclic controller: SYNC, master sample, estimator, tracker, kinematics, counts, RPDOs.

One cycle k (period T = ``master.sync_period``; controller time in integer ns):

1. wait (processing frames) until the absolute deadline t_k = t0 + k*T and send SYNC k
   (own producer with counter, :mod:`controller.canopen.master.sync`);
2. the encoder answers with 6004h sampled at SYNC k, each drive with 6041h + 6064h; the
   receive callbacks store snapshots tagged with k; wait until all of this cycle's inputs are
   in, at the latest until t_k + ``compute_at`` * T (later inputs count as missing);
3. supervision (heartbeats, EMCY, statuswords); master sample -> belt travel -> estimator
   -> the belt state at t_{k+1} (the drives apply this cycle's targets at SYNC k+1);
4. by phase: ENABLING walks every drive through the 402 state machine one transition per
   cycle, the target being the drive's actual position (held once it is enabled), and
   starts the setpoint source when all are enabled; RUNNING hands the source a frozen
   :class:`~.source.CycleContext` (the master estimate for SYNC k+1+d, d =
   ``drive_delay_cycles``: the drives reach a target one interpolation period after they
   apply it; the drives' states; the PLC's commands) and takes its
   :class:`~.source.SourceOutput`: a tool setpoint goes through the kinematics, axis
   setpoints directly to the counts conversion; the limits are checked and each drive gets
   its RPDO (6040h = 0Fh, 607Ah = counts); the source's events are logged, its quick stop
   made; STOPPING sends quick stop (6040h = 02h) until every drive stands still;
5. heartbeat producer; timing figures; the cycle record.

Reactions (every one is an :class:`~controller.canopen.master.events.Event` with its cycle):
a drive fault, a drive EMCY, a lost heartbeat, a node leaving OPERATIONAL, the CSP
following-error bit (6041h bit 13), a drive that leaves OPERATION ENABLED, a drive TPDO
missing for ``silent_cycles``, a setpoint outside an axis limit -> quick stop of all
drives.  The encoder silent for ``silent_cycles`` -> the source is told
(:class:`~.source.MasterEvent`) and de-syncs on the estimator's extrapolated master.

The same code runs in stepped time (tests, demo) and real time (``run``): the only waiting
is ``transport.run_until``.
"""

from __future__ import annotations

import gc
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

from ...errors import CanError
from ...kinematics import CountsConverter
from ...kinematics import create as create_kinematics
from ...tracking import MasterEstimate, MotionState, TrackState
from ..config.busload import BusLoad, bus_load, check_bus_load
from ..config.reactions import Disturbance, Reaction
from ..io.transport import GuardedTransport, Transport
from ..protocol import cia402
from ..protocol.cia402 import State
from ..protocol.frames import FrameHygiene
from ..protocol.sdo import SdoClient
from .axisio import AxisIO
from .boot import BootResult, boot
from .events import EventLog
from .masterio import MasterInput
from .source import (
    NO_STATUS,
    AxisSetpoints,
    Command,
    CycleContext,
    DriveView,
    MasterEvent,
    MasterView,
    SdoUpload,
    SetpointSource,
    SourceOutput,
    SourceStart,
    SourceStatus,
    Transfers,
)
from .stopping import (
    SDO_POLL_CYCLES,
    DriveStop,
    StopStage,
    is_stopped,
    sdo_controlword,
    sdo_statusword_request,
    statusword_from_sdo,
)
from .supervision import BusActors, EmcyMonitor, HeartbeatMonitor
from .timing import Histogram, Ring, Run
from .sync import SyncProducer

if TYPE_CHECKING:
    from ..config import ControllerConfig


#: the 402 states of a drive fault
_FAULT_STATES = frozenset((State.FAULT, State.FAULT_REACTION_ACTIVE))
#: (the running drive's test in the supervision, module constants)
_ENABLED = State.OPERATION_ENABLED
_SW_FOLLOWING_ERROR = cia402.SW_FOLLOWING_ERROR


class EnableError(CanError):
    """A drive did not reach OPERATION ENABLED."""


class CycleError(CanError):
    """An unexpected exception inside the cycle (after the controlled stop)."""


#: exit codes of a run (``cantrack run``; :meth:`Controller.exit_code`)
EXIT_OK, EXIT_ERROR, EXIT_REACTION, EXIT_UNCONFIRMED = 0, 2, 3, 4


class Phase(Enum):
    IDLE = "idle"
    ENABLING = "enabling"
    RUNNING = "running"
    STOPPING = "stopping"
    STOPPED = "stopped"


#: the phases, the tracking-off state and the controlwords of the per-cycle tests as module
#: globals: an Enum member read from its class costs some 45 ns more than a global (each
#: cycle reads a dozen of them)
_ENABLING, _RUNNING, _STOPPING, _STOPPED = (Phase.ENABLING, Phase.RUNNING, Phase.STOPPING,
                                            Phase.STOPPED)
_TRACK_OFF = TrackState.OFF
_CW_ENABLE, _CW_QUICK_STOP = cia402.CW_ENABLE, cia402.CW_QUICK_STOP_CMD


@dataclass(slots=True)
class CycleRecord:
    """What one cycle did (units: mm/deg for joints, counts for drive values, s, us)."""

    cycle: int
    t_s: float
    phase: str
    raw: int | None
    belt_mm: float | None
    belt_vel: float | None
    state: int
    imfs: int
    error: int
    setpoint: tuple[float, ...] | None
    targets: tuple[int, ...]
    actual: tuple[float, ...]
    statuswords: tuple[int, ...]
    tracking_error: float
    sync_late_us: float
    compute_us: float

    def as_dict(self) -> dict:
        return {f: getattr(self, f) for f in self.__slots__}


@dataclass
class Timing:
    """Cycle timing [ns] in bounded memory (:mod:`.master.timing`: histograms with exact
    count/max and 0.5 % percentiles, rings of the last values); real time only (empty in
    stepped time)."""

    sync_late: Histogram = field(default_factory=Histogram)
    sync_interval: Histogram = field(default_factory=Histogram)
    #: |SYNC interval - period|
    jitter: Histogram = field(default_factory=Histogram)
    #: the last 500 jitter values (the status line's p99)
    recent_jitter: Ring = field(default_factory=lambda: Ring(500))
    compute: Histogram = field(default_factory=Histogram)
    latency: Histogram = field(default_factory=Histogram)
    cpu_cycle: Histogram = field(default_factory=Histogram)
    cpu_compute: Histogram = field(default_factory=Histogram)
    #: of ``cpu_cycle`` the SYNC's send and the wait for the inputs (their wake-ups and
    #: handling): the cycle's CPU outside the compute
    cpu_wait: Histogram = field(default_factory=Histogram)
    missed: int = 0
    #: deadlines missed in a row: the current streak, the longest, how many streaks
    missed_run: Run = field(default_factory=Run)
    late_inputs: int = 0
    #: cycles started more than a period late: the time base slipped (no SYNC burst)
    overruns: int = 0
    #: the periodic garbage collections in the cycle's slack (real time)
    gc: Histogram = field(default_factory=Histogram)
    #: the compute CPU [ns] of the first cycles (the start-up budget check), then None
    startup: list[int] | None = field(default_factory=list)


class Controller:
    """The CANopen tracking controller for one bus (see the module docstring)."""

    #: unexpected exceptions in a row after which the cycle itself is abandoned: the last
    #: resort (:meth:`_emergency_stop`) sends quick stop and NMT stop without the cycle code
    MAX_INTERNAL_ERRORS = 3
    #: the start-up budget check: over the first BUDGET_CHECK_S of tracking, a compute p99
    #: above BUDGET_SHARE of the period is reported (a warning event)
    BUDGET_CHECK_S = 2.0
    BUDGET_SHARE = 0.5
    #: real time: the cyclic garbage is collected every this many cycles, in the slack after
    #: the RPDOs (the collector is paused while cycling: a collection at a random allocation
    #: would cost a deadline)
    GC_EVERY_CYCLES = 1000

    def __init__(self, cfg: ControllerConfig, transport: Transport,
                 source: SetpointSource, *, events: EventLog | None = None,
                 keep_trace: bool | int = True,
                 on_cycle: Callable[[Controller, CycleRecord], None] | None = None,
                 enforce_bus_load: bool = True) -> None:
        if cfg.tracking is None:
            raise CanError(f"{cfg.file}: no .tracking section: nothing to control")
        self.cfg = cfg
        self.tc = cfg.tracking
        #: frames checked before decoding, bad ones counted per COB-ID (:mod:`.frames`);
        #: every receive callback runs guarded (an exception is queued, never raised)
        self.hygiene = FrameHygiene()
        transport = GuardedTransport(transport, self.hygiene)
        self.transport = transport
        self.clock = transport.clock
        #: what makes the setpoints while RUNNING (:mod:`.source`); the cycle calls only its
        #: ``start`` and ``step``
        self.source = source
        self.events = events if events is not None else EventLog()
        self.keep_trace = keep_trace
        self.on_cycle = on_cycle
        # enforce_bus_load=False: a virtual bus, which has no bit time (benchmarks), or a caller
        # that checked the load itself (cantrack run: before opening the bus)
        self.bus_load: BusLoad = check_bus_load(cfg) if enforce_bus_load else bus_load(cfg)
        self.period_ns = cfg.period_ns
        self.compute_ns = int(self.tc.compute_at * self.period_ns)
        cell = self.tc.cell
        #: a cell (``.tracking.cell``): several robots, each its own kinematics over its own
        #: drives (the source gives axis setpoints); ``kinematics`` is then the first robot's
        #: (the pose in the source's start), the tracking error is the source's per robot
        self.kinematics = create_kinematics(self.tc.kinematics, [a.name for a in self.tc.axes]) \
            if cell is None else cell.robots[0].machine()
        self.counts = CountsConverter([a.scale for a in self.tc.axes])
        self.axes = [AxisIO(cfg, a.name, a.node, a.scale, transport, self.hygiene)
                     for a in self.tc.axes]
        #: one input per master encoder (a cell's ``encoders``, else ``.tracking.conveyor``);
        #: ``master`` is the first (the record's belt, the latency figure)
        self.masters = [MasterInput(cfg, transport, self.hygiene, encoder=e)
                        for e in self.tc.encoders] if cell is not None \
            else [MasterInput(cfg, transport, self.hygiene)]
        self.master = self.masters[0]
        self._other_masters = self.masters[1:]
        #: each master's event of this cycle (a cell's context gives them all)
        self._master_events = [MasterEvent.NONE] * len(self.masters)
        self._cell = cell is not None
        #: the axes in the order their TPDOs come last first (the devices answer a SYNC in
        #: node order): the input check after each frame stops at the first missing one
        self._axes_last_first = self.axes[::-1]
        self.sync = SyncProducer(transport, 0x80, cfg.master.sync_overflow)
        self.heartbeats = HeartbeatMonitor(transport, self.hygiene)
        self.emcy = EmcyMonitor(transport, self.hygiene, cfg)
        self._watch_nodes()
        #: NMT commands, SYNCs, unknown nodes and error frames of other actors
        self.actors = BusActors(transport, self.hygiene, cfg, sync_cob=0x80)
        self.reactions = self.tc.reactions
        self.stage_cycles = max(1, math.ceil(self.tc.timeouts.stop_s / cfg.period_s))
        self.stops = [DriveStop(a.label, a.node_id) for a in self.axes]
        #: per axis (its AxisIO, min, max [mm|deg], quick-stop deceleration, twice that) for
        #: the limit check, and the (joint, x/y/z) index pairs of the translation axes
        self._limits = [(a, a.scale.min, a.scale.max, a.quick_stop_decel,
                         2.0 * a.quick_stop_decel) for a in self.axes]
        self._xyz = [(j, "xyz".find(name)) for j, name in enumerate(self.kinematics.axes)
                     if "xyz".find(name) >= 0] if cell is None else []
        #: per translation axis (AxisIO, x/y/z index i, the counts conversion's sign, zero and
        #: counts per unit: CountsConverter.from_counts of that axis)
        self._xyz_counts = [(self.axes[j], i, *self.counts.factors[j]) for j, i in self._xyz]
        #: per axis (AxisIO, sign, zero, counts per unit of its own AxisScale)
        self._axes_counts = [(a, a.scale.sign, a.scale.zero, a.scale.counts_per_unit)
                             for a in self.axes]
        self._sdo_statusword: dict[int, int] = {}  # node-ID -> 6041h read by SDO (stopping)
        for a in self.axes:
            transport.subscribe(0x580 + a.node_id, self._on_sdo_answer)
        self._internal_errors = 0
        self._bad_reported: set[int] = set()
        #: the drives' and the encoder's labels (their heartbeat loss always stops)
        self._motion_labels = {a.label for a in self.axes} | {m.label for m in self.masters}
        #: the source has been started (tracking runs: a PLC's engage can act)
        self.tracking = False
        #: the source's status after its last start/step (the record, the PLC node)
        self.status: SourceStatus = NO_STATUS
        #: the source's output of the last RUNNING cycle (None before the first)
        self.last_output: SourceOutput | None = None
        #: the source asked to end the run (its last output's ``done``)
        self.source_done = False
        #: the PLC's commands since the last cycle (:meth:`command`), in arrival order
        self._commands: list[Command] = []
        self._master_event = MasterEvent.NONE
        #: the SDO program of the source's last output, run before the next SYNC
        self._transfers: Transfers | None = None
        self._sdo_clients: dict[int, SdoClient] = {}
        #: the drives (indices) a transfer put in homing mode (6060h = 6)
        self._homing_mode: set[int] = set()
        self.phase = Phase.IDLE
        self.k = 0
        self.t0 = 0
        self.timing = Timing()
        #: periods the time base slipped before this cycle's SYNC (an overrun), else 0
        self.slipped_periods = 0
        #: the cycle records: all (keep_trace=True: tests, short runs), the last N
        #: (keep_trace=N: bounded, long runs) or none (False)
        self.trace: list[CycleRecord] | deque[CycleRecord] = \
            deque(maxlen=keep_trace) if keep_trace is not True and keep_trace else []
        self.max_missed_in_row = self.tc.max_missed_in_row
        self._gc_paused = False
        self._budget_cycles = max(1, round(self.BUDGET_CHECK_S / cfg.period_s))
        self.failure: CanError | None = None
        self.boot_result: BootResult | None = None
        self._enable_start_ns: int | None = None
        self._stop_cycles = 0
        self._hb_next: int | None = None
        self._last_sync_sent: int | None = None
        #: master state by the cycle whose SYNC it is for (tracking error bookkeeping)
        self._master_for: dict[int, MotionState] = {}
        self._drive_silent = [0] * len(self.axes)
        self._faults_reported: set[str] = set()
        #: |actual - target| [mm] of the last cycle while the tracker is not OFF
        self.last_tracking_error = 0.0
        #: the controller's own NMT state, sent in its heartbeat (5 OPERATIONAL; the PLC
        #: node's, when there is one: a PLC may put it in PRE-OPERATIONAL or STOPPED)
        self.nmt_state = 5
        #: when the last SYNC was sent [ns] (None before the first)
        self.last_sync_ns: int | None = None

    # -- setup -------------------------------------------------------------------------------
    def _watch_nodes(self) -> None:
        from ..protocol import od as odm
        cfg = self.cfg
        for name, slave in cfg.slaves.items():
            label = cfg.label(name)
            hb = slave.heartbeat_producer_ms
            if hb is None:
                var = odm.variable(cfg.ods[name], 0x1017)
                hb = int(odm.default_value(var) or 0) if var is not None else 0
            if hb and cfg.master.heartbeat_consumer:
                timeout = int(hb * slave.hb_multiplier(cfg.options) * 1e6)
                self.heartbeats.watch(slave.node_id, label, timeout)
            self.emcy.watch(0x80 + slave.node_id, slave.node_id, label,
                            odm.profile(cfg.ods[name]))

    def boot(self) -> BootResult:
        """NMT reset, identity, SDO configuration, NMT start (:mod:`.boot`)."""
        self.boot_result = boot(self.cfg, self.transport, self.events)
        return self.boot_result

    def start(self) -> None:
        """Start the cycle: the first SYNC one period from now; the 402 enable begins."""
        now = self.clock.now_ns()
        self.t0 = now + self.period_ns
        self.k = 0
        self.phase = Phase.ENABLING
        self.heartbeats.start(now)
        if self.cfg.master.heartbeat_producer_ms:
            self._hb_next = self.t0  # then every heartbeat_producer ms, sent in the cycle

    # -- the cycle ---------------------------------------------------------------------------
    def step(self) -> CycleRecord | None:
        """Run one cycle (SYNC k ... RPDOs for SYNC k+1); first the SDO transfers the
        source asked for in the last cycle."""
        program, self._transfers = self._transfers, None
        if program is not None and self.phase is _RUNNING:
            self._run_transfers(program)
        k = self.k
        clock = self.clock
        transport = self.transport
        deadline = self.t0 + k * self.period_ns
        late = clock.now_ns() - deadline
        self.slipped_periods = 0
        if late > self.period_ns:
            # overrun by more than a period: do not fire a burst of SYNCs; the time base
            # slips by whole periods (the cycle index, the tracker's sample, goes on by one;
            # the estimator is told, so that the belt's time axis stays right)
            periods = late // self.period_ns
            slip = periods * self.period_ns
            self.t0 += slip
            deadline += slip
            self.timing.overruns += 1
            self.slipped_periods = periods
            for m in self.masters:
                m.skip(periods)  # the belt moved on meanwhile
            self._master_for.clear()
        transport.run_until(deadline, precise=True)
        self.master.cycle = k
        for m in self._other_masters:
            m.cycle = k
        for a in self.axes:
            a.cycle = k
        rt = clock.realtime
        # (the thread's CPU clock is a system call: read in real time only, its figures')
        cpu0 = time.thread_time_ns() if rt else 0
        t_sent = clock.now_ns()
        self.sync.send()
        complete = transport.run_until(deadline + self.compute_ns, self._inputs_complete)
        t_c = clock.now_ns()
        cpu1 = time.thread_time_ns() if rt else 0
        rec = self._compute(k, t_sent, deadline)
        t_done = clock.now_ns()
        tm = self.timing
        if rt:
            cpu2 = time.thread_time_ns()
            tm.sync_late.add(t_sent - deadline)
            if self._last_sync_sent is not None:
                interval = t_sent - self._last_sync_sent
                tm.sync_interval.add(interval)
                jit = abs(interval - self.period_ns)
                tm.jitter.add(jit)
                tm.recent_jitter.add(jit)
            tm.compute.add(t_done - t_c)
            snap = self.master.snapshot
            if snap is not None and snap[2] == k:
                tm.latency.add(t_done - snap[1])
            tm.cpu_compute.add(cpu2 - cpu1)
            tm.cpu_cycle.add(cpu2 - cpu0)
            tm.cpu_wait.add(cpu1 - cpu0)
            if t_done > deadline + self.period_ns:
                tm.missed += 1
                streak = tm.missed_run.hit()
                if streak == self.max_missed_in_row:
                    self._deadlines_missed(k, streak)
            else:
                tm.missed_run.miss()
            if not complete:
                tm.late_inputs += 1
            if tm.startup is not None and self.phase is _RUNNING:
                tm.startup.append(cpu2 - cpu1)
                if len(tm.startup) >= self._budget_cycles:
                    self._check_budget(k)
            if rec is not None:
                rec.sync_late_us = (t_sent - deadline) / 1e3
                rec.compute_us = (t_done - t_c) / 1e3
        self._last_sync_sent = t_sent
        self.last_sync_ns = t_sent
        hb_next = self._hb_next
        if hb_next is not None and t_done >= hb_next:  # (tested here: due every 50th cycle)
            self._produce_heartbeat(t_done)
        if self._gc_paused and k % self.GC_EVERY_CYCLES == 0 \
                and clock.now_ns() < deadline + self.period_ns // 2:
            # the collector is off while cycling (gc.freeze moved everything older into the
            # permanent generation): collect what the cycles left, in this cycle's slack
            g0 = clock.now_ns()
            gc.collect()
            tm.gc.add(clock.now_ns() - g0)
        self.k = k + 1
        if rec is not None:
            if self.keep_trace:
                self.trace.append(rec)
            if self.on_cycle is not None:
                self.on_cycle(self, rec)
        return rec

    def _deadlines_missed(self, k: int, streak: int) -> None:
        """``max_missed_in_row`` deadlines missed in a row: the machine cannot keep the
        cycle; the drives would fall back on stale setpoints -> quick stop, saying why."""
        c = self.timing.cpu_compute.summary_us()
        self.quick_stop(k, (self.clock.now_ns() - self.t0) * 1e-9, "controller",
                        "deadlines_missed",
                        f"{streak} SYNC deadlines missed in a row (RPDOs after the next SYNC; "
                        f"compute p99 {c['p99']:.0f} us of the {self.period_ns / 1e3:.0f} us "
                        f"cycle): the machine cannot keep this cycle (longer sync_period, "
                        f"SCHED_FIFO, a CPU of its own, --cpu-latency 0)")

    def _check_budget(self, k: int) -> None:
        """The start-up check: compute p99 over the first seconds against the period."""
        vals = sorted(self.timing.startup or ())
        self.timing.startup = None
        p99 = vals[min(len(vals) - 1, int(0.99 * len(vals)))]
        share = p99 / self.period_ns
        if share > self.BUDGET_SHARE:
            self.events.add(k, (self.clock.now_ns() - self.t0) * 1e-9, "controller",
                            "cycle_budget",
                            f"cycle budget tight: compute p99 {p99 / 1e3:.0f} us = "
                            f"{100 * share:.0f} % of the {self.period_ns / 1e3:.0f} us period "
                            f"over the first {self.BUDGET_CHECK_S:g} s (> "
                            f"{100 * self.BUDGET_SHARE:.0f} %): expect missed deadlines "
                            f"(SCHED_FIFO, a CPU of its own, --cpu-latency 0: docs/hil.md)",
                            level=30)

    def _inputs_complete(self) -> bool:
        """Every input of this cycle is in (asked after each frame: the fresh() tests
        written out)."""
        master = self.master
        k = master.cycle
        s = master.snapshot
        if s is None or s[2] != k:
            return False
        for m in self._other_masters:
            s = m.snapshot
            if s is None or s[2] != k:
                return False
        for a in self._axes_last_first:
            inp = a.input
            if inp is None or inp.cycle != k:
                return False
        return True

    def _produce_heartbeat(self, now: int) -> None:
        if self._hb_next is not None and now >= self._hb_next:
            self.transport.send(0x700 + self.cfg.master.node_id, bytes((self.nmt_state,)))
            self._hb_next += self.cfg.master.heartbeat_producer_ms * 1_000_000
            if self._hb_next <= now:
                self._hb_next = now + self.cfg.master.heartbeat_producer_ms * 1_000_000

    def _compute(self, k: int, t_sent: int, deadline: int) -> CycleRecord | None:
        t_s = (deadline - self.t0) * 1e-9
        self._supervise(k, t_s)
        late_s = (t_sent - deadline) * 1e-9
        event, est = self.master.update(k, late_s)
        self._master_event = _MASTER_EVENTS[event]
        if event is not None:
            self._master_report(self.master, event, k, t_s)
        if self._cell:
            self._master_events[0] = self._master_event
            for i, m in enumerate(self._other_masters, 1):
                ev = m.update(k, late_s)[0]
                self._master_events[i] = _MASTER_EVENTS[ev]
                if ev is not None:
                    self._master_report(m, ev, k, t_s)
        phase = self.phase
        setpoint = None
        if phase is _RUNNING:  # (the cycle's phase nearly always: tested first)
            setpoint = self._run_step(k, t_s, deadline, est)
        elif phase is _ENABLING:
            self._enable_step(k, t_s)
        else:
            self._commands.clear()  # (no source runs any more: nothing takes them)
            self._stop_step(k)
        if self.keep_trace or self.on_cycle is not None:
            return self._record(k, t_s, setpoint)
        self._tracking_error(k)  # nobody takes the record: only what the cycle itself uses
        return None

    def _master_report(self, m: MasterInput, event: str, k: int, t_s: float) -> None:
        """The event of master input ``m`` in this cycle (masterio's name)."""
        if event == "silent":
            self._master_silent(k, t_s, m)
        elif event == "outlier":
            self.events.add(k, t_s, m.label, "master_outlier",
                            f"encoder sample {m.outlier_mm:+.3f} mm off what the "
                            f"belt can do", "rejected, the estimate coasts", level=20)
        elif event == "lost":
            self._master_outliers_lost(k, t_s, m)
        elif event == "back":
            self.events.add(k, t_s, m.label, "master_back",
                            "encoder samples arrive again", "estimator restarted", level=20)

    def _master_views(self) -> tuple[MasterView, ...]:
        """A cell's every encoder as the source's context shows it (empty without a cell)."""
        if not self._cell:
            return ()
        zero = MasterEstimate(0.0, 0.0, 0.0)
        return tuple(MasterView(m.last_estimate if m.last_estimate is not None else zero,
                                m.belt_mm, m.ready, ev)
                     for m, ev in zip(self.masters, self._master_events))

    # -- phases ------------------------------------------------------------------------------
    def _enable_step(self, k: int, t_s: float) -> None:
        now = self.clock.now_ns()
        if self._enable_start_ns is None:
            self._enable_start_ns = now
        ready = True
        for a in self.axes:
            inp = a.input
            if inp is None or not a.fresh(k):
                ready = False
                a.send(a.controlword, a.target)
                continue
            state = inp.state
            cw = cia402.controlword_towards_enabled(state, a.controlword)
            if state is State.FAULT and cw == cia402.CW_FAULT_RESET_CMD:
                a.fault_resets += 1
                if a.fault_resets > 1:
                    self._fail(k, t_s, a.label, "drive_fault",
                               f"fault again during the enable (statusword "
                               f"{inp.statusword:04X}h)")
                    return
                self.events.add(k, t_s, a.label, "fault_reset",
                                "drive in FAULT at enable: fault reset (rising edge of "
                                "6040h bit 7)", level=20)
            if state is State.OPERATION_ENABLED:
                if a.hold is None:
                    a.hold = inp.actual
                target = a.hold
                if not inp.statusword & cia402.SW_FOLLOWS_TARGET:
                    ready = False
            else:
                a.hold = None
                target = inp.actual
                ready = False
            a.send(cw, target)
        if ready and all(m.ready for m in self.masters):
            joints = self.counts.from_counts([a.hold for a in self.axes])
            self.phase = Phase.RUNNING
            self.events.add(k, t_s, "controller", "enabled",
                            "all drives in OPERATION ENABLED, tracking starts at "
                            + ", ".join(f"{a.axis}={j:.3f}" for a, j in zip(self.axes, joints)),
                            level=20)
            self.status = self.source.start(SourceStart(
                k, t_s, self.t0 + k * self.period_ns, self.cfg.period_s, self.tc, joints,
                self.kinematics.pose(joints[:len(self.kinematics.axes)]), self._drive_views(k),
                self._master_views()))
            self.tracking = True
        elif now - self._enable_start_ns > self.tc.timeouts.enable_s * 1e9:
            for a in self.axes:
                inp = a.input
                st = inp.state if inp is not None else None
                if st is not State.OPERATION_ENABLED:
                    sw = f"{inp.statusword:04X}h ({st.value if st else 'invalid'})" \
                        if inp is not None else "no TPDO received"
                    self._fail(k, t_s, a.label, "enable_timeout",
                               f"could not enable within {self.tc.timeouts.enable_s:g} s: "
                               f"statusword {sw}, last controlword {a.controlword:04X}h")
                    return
            late = next((m for m in self.masters if not m.ready), self.master)
            self._fail(k, t_s, late.label, "enable_timeout",
                       f"no encoder samples within {self.tc.timeouts.enable_s:g} s")

    def _drive_views(self, k: int) -> tuple[DriveView, ...]:
        """The drives as this cycle's TPDOs showed them (the source's context)."""
        # (DriveView's 7 fields given in order: the named tuple made without its __new__;
        #  the actual position: AxisScale.from_counts written out)
        return tuple([_new_tuple(DriveView, (a.axis, None, 0, None, False, a.inputs, a.probe))
                      if (inp := a.input) is None else
                      _new_tuple(DriveView, (a.axis, inp.state, inp.statusword,
                                             zero + sign * inp.actual / k_, inp.cycle == k,
                                             a.inputs, a.probe))
                      for a, sign, zero, k_ in self._axes_counts])

    def _sdo(self, i: int) -> SdoClient:
        """The SDO client of drive ``i`` (the sources' transfers)."""
        c = self._sdo_clients.get(i)
        if c is None:
            a, t = self.axes[i], self.tc.timeouts
            c = self._sdo_clients[i] = SdoClient(self.transport, a.node_id, a.label, t.sdo_s,
                                                 t.sdo_retries)
        return c

    def _run_transfers(self, program: Transfers) -> None:
        """Run a source's SDO program (between two cycles): each transfer by SDO, the value
        of an upload sent back, a failed one thrown in.  A 6060h write is the drive's mode:
        in homing mode (6) statusword bit 13 is 'homing error', not a following error; a
        60B8h write re-arms touch probe 1 (what its TPDO said before no longer counts)."""
        value: int | None = None
        error: CanError | None = None
        rearmed: set[int] = set()
        try:
            while True:
                try:
                    if error is not None:
                        e, error = error, None
                        req = program.throw(e)
                    else:
                        req = program.send(value)
                except StopIteration:
                    break
                value = None
                try:
                    sdo = self._sdo(req.axis)
                    if isinstance(req, SdoUpload):
                        value = (sdo.upload_int(req.index, req.sub) if req.signed
                                 else sdo.upload_uint(req.index, req.sub))
                    else:
                        sdo.download(req.index, req.sub, req.data)
                        if req.index == 0x6060 and req.sub == 0:
                            if req.data[:1] == bytes([cia402.MODE_HM]):
                                self._homing_mode.add(req.axis)
                            else:
                                self._homing_mode.discard(req.axis)
                        elif req.index == 0x60B8:
                            rearmed.add(req.axis)
                except CanError as exc:
                    error = exc
        finally:
            for i in rearmed:
                self.axes[i].probe = None

    def command(self, cmd: Command) -> None:
        """A PLC's command (engage, item trigger): handed to the source with the next
        cycle's context (dropped once the drives are stopping)."""
        if self.phase is not Phase.STOPPING and self.phase is not Phase.STOPPED:
            self._commands.append(cmd)

    def _run_step(self, k: int, t_s: float, deadline: int,
                  est: MasterEstimate | None) -> tuple[float, ...]:
        """Hand the source this cycle's context, send what it returns (see the module
        docstring, step 4)."""
        if est is None:
            est = MasterEstimate(0.0, 0.0, 0.0)
        m = self.master
        if self._commands:
            commands = tuple(self._commands)
            self._commands.clear()
        else:
            commands = ()
        # (the named tuples with every field given in order, made without their __new__)
        ctx = _new_tuple(CycleContext, (
            k, t_s, deadline, _new_tuple(MasterView, (est, m.belt_mm, m.ready,
                                                      self._master_event)),
            self._drive_views(k), commands, self.last_tracking_error,
            self._master_views() if self._cell else ()))
        out = self.source.step(ctx)
        self.last_output = out
        self.status = out.status
        self.source_done = out.done
        self._transfers = out.transfers
        for e in out.events:
            self.events.add(k, t_s, e.source, e.kind, e.detail, e.reaction, level=e.level)
        sp = out.setpoint
        kinematics = self.kinematics
        if isinstance(sp, AxisSetpoints):
            joints = sp.positions
            if len(joints) != len(self.axes):
                raise CycleError(f"the setpoint source gave {len(joints)} axis targets for "
                                 f"{len(self.axes)} drives")
            commands_out = sp.commands
            bad = None if sp.velocities is None else \
                self._limit_violation(joints, sp.velocities)
        else:
            if self._cell:
                raise CycleError("a cell's setpoint source must give every drive's target "
                                 "(axis setpoints: each robot has its own kinematics), not "
                                 "one tool setpoint")
            joints = kinematics.joints(sp)
            commands_out = None
            bad = self._limit_violation(joints, kinematics.joint_velocities(sp))
        if out.stop is not None:  # (at the time it is made, like the cycle's own reactions)
            self.quick_stop(k, (self.clock.now_ns() - self.t0) * 1e-9, out.stop.source,
                            out.stop.kind, out.stop.detail)
        if bad is not None:
            axis, detail = bad
            if self.slipped_periods:
                # the evidence of why: the drives held their target through the slip (no
                # SYNC) and would execute the whole catch-up in one period
                detail += (f", after an overrun: the time base slipped by "
                           f"{self.slipped_periods} period(s), no SYNC sent for them")
            self.quick_stop(k, t_s, axis.label, "limit", detail)
            for a in self.axes:
                a.send(cia402.CW_QUICK_STOP_CMD, a.target)
            return joints
        counts = self.counts.to_counts(joints)
        # a source that asked for the quick stop says what each drive gets in this cycle
        # (axis setpoints); a tool setpoint: the quick stop to all
        if commands_out is not None:
            for i, (a, c) in enumerate(zip(self.axes, counts)):
                a.send(commands_out[i].controlword, c)
        else:
            cw = _CW_QUICK_STOP if self.phase is _STOPPING else _CW_ENABLE
            for a, c in zip(self.axes, counts):
                a.send(cw, c)
        if out.target is not None:
            # the tracked target (relative mode: the master plus the offset kept at engage)
            self._master_for[k + m.lead] = out.target
        return joints

    def _limit_violation(self, joints, velocities) -> tuple[AxisIO, str] | None:
        """The first axis whose setpoint, or the point where a quick stop from the
        setpoint's velocity would end (6085h deceleration), is outside its limits."""
        for (a, lo, hi, decel, decel2), p, v in zip(self._limits, joints, velocities):
            # (2 x decel made once: the same double; decel2 > 0 exactly when decel > 0)
            stop = p + v * abs(v) / decel2 if decel2 > 0 else p
            if not (lo <= p <= hi and lo <= stop <= hi):
                sc = a.scale
                unit = sc.unit
                return a, (f"setpoint {a.axis} = {p:.3f} {unit} at {v:.1f} {unit}/s (a quick "
                           f"stop at {decel:.0f} {unit}/s^2 ends at {stop:.3f}) outside "
                           f"[{sc.min:g}, {sc.max:g}]")
        return None

    def _stop_step(self, k: int) -> None:
        """The controlled stop (:mod:`.stopping`): quick stop by RPDO every cycle; a drive
        whose statusword does not confirm the stop within ``stage_cycles`` is escalated
        stage by stage; the phase is STOPPED when every drive is confirmed or, after the
        last stage, reported unconfirmed."""
        t_s = (self.clock.now_ns() - self.t0) * 1e-9
        done = True
        for a, s in zip(self.axes, self.stops):
            inp = a.input if a.fresh(k) else None
            sw = inp.statusword if inp is not None else self._sdo_statusword.pop(a.node_id,
                                                                                   None)
            if sw is not None:
                s.seen(k, sw)
            if s.confirmed_cycle is None and s.stage is not StopStage.UNCONFIRMED \
                    and s.begin_cycle is not None and sw is not None and is_stopped(sw):
                s.confirmed_cycle = k
                how = "TPDO" if inp is not None else "SDO"
                self.events.add(k, t_s, a.label, "stop_confirmed",
                                f"statusword {sw:04X}h ({s.state_name}, by {how}) after "
                                f"{k - s.begin_cycle} cycles, stage {s.stage.text}", level=20)
            target = a.input.actual if a.input is not None else a.target
            cw = cia402.CW_DISABLE_VOLTAGE if s.stage.value >= StopStage.DISABLE_VOLTAGE.value \
                else cia402.CW_QUICK_STOP_CMD
            a.send(cw, target)
            if s.finished:
                continue
            done = False
            if s.stage is not StopStage.QUICK_STOP and (k - s.stage_cycle) % SDO_POLL_CYCLES == 0:
                self.transport.send(0x600 + a.node_id, sdo_statusword_request())
            if k - s.stage_cycle >= self.stage_cycles:
                self._escalate(k, t_s, a, s)
        if self.phase is Phase.STOPPING:
            self._stop_cycles += 1
            if done:
                self.phase = Phase.STOPPED
                bad = [s.label for s in self.stops if s.confirmed_cycle is None]
                if bad:
                    self.events.add(k, t_s, "controller", "stopped",
                                    f"stop not confirmed by {', '.join(bad)}",
                                    "run ends (exit code 4)")
                else:
                    self.events.add(k, t_s, "controller", "stopped",
                                    "all drives stopped (confirmed by their statusword)",
                                    level=20)

    def _on_sdo_answer(self, can_id: int, data: bytes, t_ns: int) -> None:
        """6041h read by SDO while a drive's stop is escalated (other SDO answers: the
        boot's and the jobs' own clients, ignored here)."""
        if self.phase is Phase.STOPPING:
            sw = statusword_from_sdo(data)
            if sw is not None:
                self._sdo_statusword[can_id - 0x580] = sw

    def _escalate(self, k: int, t_s: float, a: AxisIO, s: DriveStop) -> None:
        """The next stage of ``a``'s stop (see :class:`.stopping.StopStage`)."""
        s.escalate(k)
        send = self.transport.send
        seen = (f"last statusword {s.statusword:04X}h ({s.state_name}) in cycle {s.last_cycle}"
                if s.statusword is not None else "no TPDO since the stop began")
        if s.stage is StopStage.NMT_START:
            send(0x000, bytes((0x01, a.node_id)))
            send(0x600 + a.node_id, sdo_controlword(cia402.CW_QUICK_STOP_CMD))
        elif s.stage is StopStage.DISABLE_VOLTAGE:
            send(0x600 + a.node_id, sdo_controlword(cia402.CW_DISABLE_VOLTAGE))
        elif s.stage is StopStage.NMT_STOP:
            send(0x000, bytes((0x02, a.node_id)))
            self._hb_next = None  # the drives' 1016h consumers time out: 6007h applies
        if s.stage is StopStage.UNCONFIRMED:
            self.events.add(k, t_s, a.label, "stop_unconfirmed",
                            f"stop not confirmed after every escalation stage ({seen})",
                            "drive state unknown: check it on site")
        else:
            self.events.add(k, t_s, a.label, "stop_escalated",
                            f"not stopped after {self.stage_cycles} cycles ({seen})",
                            s.stage.text)

    def _internal_error(self, k: int, error: str, where: str) -> bool:
        """An unexpected exception in cycle ``k``: the controlled stop, the run fails.
        True when the cycle code itself keeps failing (the emergency stop was made)."""
        self._internal_errors += 1
        t_s = (self.clock.now_ns() - self.t0) * 1e-9
        if self.failure is None or not isinstance(self.failure, CycleError):
            self.failure = CycleError(f"internal error in cycle {k}: {error} ({where}); the "
                                      "drives were stopped")
        if self._internal_errors >= self.MAX_INTERNAL_ERRORS:
            self._emergency_stop(k, t_s, error)
            return True
        self.quick_stop(k, t_s, "controller", "internal_error", f"{error} ({where})")
        return False

    def _emergency_stop(self, k: int, t_s: float, error: str) -> None:
        """The last resort, without the cycle code: quick stop by RPDO and NMT stop to every
        drive, the controller's heartbeat off (the drives' 1016h consumers react)."""
        self._hb_next = None
        for a, s in zip(self.axes, self.stops):
            try:
                a.send(cia402.CW_QUICK_STOP_CMD, a.target)
            finally:
                self.transport.send(0x000, bytes((0x02, a.node_id)))
            if s.confirmed_cycle is None:
                s.stage = StopStage.UNCONFIRMED
        self.phase = Phase.STOPPED
        self.events.add(k, t_s, "controller", "internal_error",
                        f"{self._internal_errors} cycles failed in a row ({error})",
                        "emergency stop: quick stop and NMT stop to every drive, heartbeat off")

    def final_states(self) -> None:
        """Each drive's last statusword into its :class:`DriveStop` (the report)."""
        for a, s in zip(self.axes, self.stops):
            if a.input is not None:
                s.seen(a.input.cycle, a.input.statusword)

    def exit_code(self) -> int:
        """0 normal end (no fault seen); 2 an error (enable failed, internal error); 3 a
        fault was seen and handled (a reaction: quick stop, de-sync, or a disturbance
        reported), every stopped drive confirmed; 4 a drive's stop is unconfirmed.  Never 0
        after a fault."""
        if self.failure is not None:
            return EXIT_ERROR
        if not self.events.reactions:  # (counted: the event log keeps only the last ones)
            return EXIT_OK
        stopping = any(s.begin_cycle is not None for s in self.stops)
        if stopping and (self.phase is not Phase.STOPPED or
                         any(s.confirmed_cycle is None for s in self.stops)):
            return EXIT_UNCONFIRMED
        return EXIT_REACTION

    # -- supervision -------------------------------------------------------------------------
    def quick_stop(self, k: int, t_s: float, source: str, kind: str, detail: str) -> None:
        """React to ``kind`` by a quick stop of all drives (once)."""
        if self.phase in (Phase.STOPPING, Phase.STOPPED):
            self.events.add(k, t_s, source, kind, detail, "(already stopping)")
            return
        self.events.add(k, t_s, source, kind, detail, "quick stop of all drives")
        self.phase = Phase.STOPPING
        for s in self.stops:
            s.begin(k)

    def disturbance(self, k: int, t_s: float, source: str, d: Disturbance,
                    detail: str) -> None:
        """React to another actor's disturbance as configured (``.tracking.reactions``)."""
        r = self.reactions.of(d)
        if r is Reaction.QUICK_STOP:
            self.quick_stop(k, t_s, source, d.value, detail)
        else:
            self.events.add(k, t_s, source, d.value, detail, r.text)

    def _fail(self, k: int, t_s: float, source: str, kind: str, detail: str) -> None:
        self.quick_stop(k, t_s, source, kind, detail)
        if self.failure is None:
            self.failure = EnableError(f"{source}: {detail}")

    def _master_outliers_lost(self, k: int, t_s: float, m: MasterInput) -> None:
        cc = m.conf.conditioning
        n = cc.max_outliers if cc is not None else 0
        engaged = self.status.engaged  # (the source de-syncs, told by the context)
        self.events.add(k, t_s, m.label, "master_lost",
                        f"{n} encoder samples in a row off what the belt can do (last "
                        f"{m.outlier_mm:+.3f} mm)",
                        "de-sync on the extrapolated master (MASTER_LOST)" if engaged else
                        "conditioner restarted")

    def _master_silent(self, k: int, t_s: float, m: MasterInput) -> None:
        engaged = self.status.engaged  # (the source de-syncs, told by the context)
        reaction = "de-sync on the extrapolated master" if engaged else "waiting for samples"
        self.events.add(k, t_s, m.label, "master_silent",
                        f"no encoder sample for {m.silent} cycles", reaction)

    def _supervise(self, k: int, t_s: float) -> None:
        now = self.clock.now_ns()
        hygiene = self.hygiene
        if hygiene.queue or hygiene.errors:  # (the queues are empty nearly every cycle)
            bad, errors = hygiene.pop_all()
            for err in errors:
                self._internal_error(k, f"{err} (in a receive callback)",
                                     err.trace.strip().splitlines()[-3].strip()
                                     if err.trace.count("\n") > 2 else "receive callback")
            for b in bad:
                if b.cob_id not in self._bad_reported:  # the first per COB-ID; all counted
                    self._bad_reported.add(b.cob_id)
                    self.disturbance(k, t_s, b.what, Disturbance.BAD_FRAME, str(b))
        if self.actors.queue:
            for source, d, detail in self.actors.pop_all():
                self.disturbance(k, t_s, source, d, detail)
        heartbeats = self.heartbeats
        # (asked only when a heartbeat showed a state or a time-out may be due: nearly never)
        for label, kind, detail in heartbeats.check(now) \
                if now > heartbeats.quiet_until_ns else ():
            if kind == "node_reset":
                self.disturbance(k, t_s, label, Disturbance.NODE_RESET, detail)
            elif kind == "heartbeat_lost" and label not in self._motion_labels:
                self.disturbance(k, t_s, label, Disturbance.IO_NODE_LOST, detail)
            else:
                self.quick_stop(k, t_s, label, kind, detail)
        for e in self.emcy.pop_all() if self.emcy.queue else ():
            if e.is_reset:
                self.events.add(k, t_s, e.label, "emcy", f"{e}: error reset", level=20)
            elif e.node_id in {a.node_id for a in self.axes}:
                self.quick_stop(k, t_s, e.label, "emcy", str(e))
            else:
                self.events.add(k, t_s, e.label, "emcy", str(e), "reported")
        phase = self.phase
        if phase is _STOPPING or phase is _STOPPED:
            for a in self.axes:
                st = a.input.state if a.fresh(k) else None
                if st in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                    if a.node not in self._faults_reported:
                        self._faults_reported.add(a.node)
                        self.events.add(k, t_s, a.label, "drive_fault",
                                        f"statusword {a.input.statusword:04X}h ({st.value})",
                                        "(already stopping)")
            return
        if phase is not _ENABLING and phase is not _RUNNING:
            return
        silent = self._drive_silent
        for i, a in enumerate(self.axes):
            inp = a.input
            if inp is None or inp.cycle != k:  # (AxisIO.fresh written out)
                silent[i] += 1
                if silent[i] == self.tc.conveyor.silent_cycles:
                    self.quick_stop(k, t_s, a.label, "drive_silent",
                                    f"no TPDO for {silent[i]} cycles")
                continue
            silent[i] = 0
            sw, _, _, _, st = inp  # (DriveInput unpacked: cheaper than two field reads)
            if st is _ENABLED and not sw & _SW_FOLLOWING_ERROR:
                continue  # the running drive: nothing to report
            if st in _FAULT_STATES:
                if self.phase is Phase.RUNNING or (a.hold is not None):
                    self._faults_reported.add(a.node)
                    self.quick_stop(k, t_s, a.label, "drive_fault",
                                    f"statusword {inp.statusword:04X}h ({st.value})")
                continue
            if st is State.OPERATION_ENABLED and inp.statusword & cia402.SW_FOLLOWING_ERROR \
                    and i not in self._homing_mode:  # (in homing mode: 'homing error')
                self.quick_stop(k, t_s, a.label, "following_error",
                                f"statusword {inp.statusword:04X}h: bit 13 following error")
            elif self.phase is Phase.RUNNING and st is not State.OPERATION_ENABLED:
                self.quick_stop(k, t_s, a.label, "drive_disabled",
                                f"left OPERATION ENABLED: statusword {inp.statusword:04X}h "
                                f"({st.value if st else 'invalid'})")

    # -- records -----------------------------------------------------------------------------
    def _record(self, k: int, t_s: float, setpoint: tuple[float, ...] | None) -> CycleRecord:
        st = self.status
        running = self.phase is Phase.RUNNING and self.tracking
        actual = self._actual()
        err = self._tracking_error(k, actual)
        master = self.master
        est = master.last_estimate
        return CycleRecord(
            cycle=k, t_s=t_s, phase=self.phase.value, raw=master.raw,
            belt_mm=master.belt_mm if master.raw is not None else None,
            belt_vel=est.vel if est is not None and master.velocity_known else None,
            state=int(st.track_state) if self.tracking else 0,
            # (while stopping: the IMFS of the tracker whose setpoint went out)
            imfs=int(st.imfs if running else st.tracker_imfs) if self.tracking else 0,
            error=int(st.error) if running else 0,
            setpoint=setpoint,
            targets=tuple([a.target for a in self.axes]),
            actual=actual,
            statuswords=tuple([a.input.statusword if a.input is not None else 0
                               for a in self.axes]),
            tracking_error=err, sync_late_us=0.0, compute_us=0.0)

    def _actual(self) -> tuple[float, ...]:
        """The drives' last actual positions [mm | deg] (0 counts before a TPDO)."""
        return self.counts.from_counts([a.input.actual if a.input is not None else 0
                                        for a in self.axes])

    def _tracking_error(self, k: int, actual: tuple[float, ...] | None = None) -> float:
        """``last_tracking_error`` of cycle ``k``: |actual - the master predicted for this
        SYNC| [mm] while the tracker whose setpoint goes out is not OFF, else 0 (``actual``:
        the drives' positions when the caller has them)."""
        err = 0.0
        m_k = self._master_for.pop(k, None)  # the master predicted for this SYNC
        if m_k is not None and self.tracking and \
                self.status.tracker_state is not _TRACK_OFF:
            if actual is not None:
                err = self._translation_error(actual, m_k)
            else:  # (_actual()'s conversion of the x, y, z axes only, then the same sum)
                p = m_k.pos
                t = 0.0
                for a, i, sign, zero, k_ in self._xyz_counts:
                    inp = a.input
                    d = (zero + sign * (inp.actual if inp is not None else 0) / k_) - p[i]
                    t += d * d
                err = math.sqrt(t)
        self.last_tracking_error = err
        return err

    def _translation_error(self, actual: tuple[float, ...], master: MotionState) -> float:
        """|actual - master| over the translation axes x, y, z [mm]."""
        p = master.pos
        s = 0.0
        for j, i in self._xyz:
            d = actual[j] - p[i]
            s += d * d
        return math.sqrt(s)

    # -- running -----------------------------------------------------------------------------
    def run(self, max_cycles: int | None = None,
            stop: Callable[[], bool] | None = None, realtime_gc: bool | None = None) -> None:
        """Step until the source is done, the drives stopped, ``max_cycles``, or
        ``stop()``; then leave the drives disabled.  Raises the failure of the enable."""
        rt = self.clock.realtime if realtime_gc is None else realtime_gc
        if rt:
            gc.collect()
            gc.freeze()
            gc.disable()
            self._gc_paused = True
        if self.phase is Phase.IDLE or (self.k == 0 and rt):
            self.start()  # (again after the gc work: the first deadline is one period ahead)
        try:
            while max_cycles is None or self.k < max_cycles:
                k0 = self.k
                try:
                    self.step()
                    self._internal_errors = 0
                except Exception as exc:  # noqa: BLE001 -- the last line of defence
                    if self.k == k0:
                        self.k = k0 + 1  # the cycle counts as done
                    if self._internal_error(k0, f"{type(exc).__name__}: {exc}",
                                            _where(exc)):
                        break
                    continue
                if self.phase is Phase.RUNNING and self.source_done:
                    break
                if self.phase is Phase.STOPPED:
                    break
                if stop is not None and stop():
                    break
        finally:
            if rt:
                self._gc_paused = False
                gc.enable()
                gc.unfreeze()
        if self.phase in (Phase.RUNNING, Phase.ENABLING):
            self.disable()  # (stopped while enabling too: no drive is left switched on)
        self.final_states()
        if self.failure is not None:
            raise self.failure

    def disable(self, cycles: int = 3) -> None:
        """Leave OPERATION ENABLED (6040h = 06h, transition 8) for a few cycles, holding."""
        self.phase = Phase.STOPPED
        for _ in range(cycles):
            k = self.k
            deadline = self.t0 + k * self.period_ns
            self.transport.run_until(deadline)
            for m in self.masters:
                m.cycle = k
            for a in self.axes:
                a.cycle = k
            self.sync.send()
            self.transport.run_until(deadline + self.compute_ns, self._inputs_complete)
            for a in self.axes:
                a.send(cia402.CW_SHUTDOWN, a.input.actual if a.input is not None else a.target)
            self._produce_heartbeat(self.clock.now_ns())
            rec = self._record(k, (deadline - self.t0) * 1e-9, None)
            if self.keep_trace:
                self.trace.append(rec)
            self.k = k + 1
            if self.on_cycle is not None:
                self.on_cycle(self, rec)


_new_tuple = tuple.__new__

#: the master input's events (masterio) as the source's context says them
_MASTER_EVENTS = {None: MasterEvent.NONE, "silent": MasterEvent.SILENT, "lost": MasterEvent.LOST,
                  "outlier": MasterEvent.OUTLIER, "back": MasterEvent.BACK}


def _where(exc: BaseException) -> str:
    """``file:line in function`` of the innermost frame of ``exc``'s traceback."""
    tb = exc.__traceback__
    if tb is None:
        return "no traceback"
    while tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code
    return f"{code.co_filename.rsplit('/', 1)[-1]}:{tb.tb_lineno} in {code.co_name}"
