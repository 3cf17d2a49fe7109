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
   cycle, the target being the drive's actual position (held once it is enabled);
   RUNNING asks the application for the master state (for SYNC k+1+d, d =
   ``drive_delay_cycles``: the drives reach a target one interpolation period after they
   apply it), runs ``Tracker.update``, the
   kinematics and the counts conversion, and sends each drive its RPDO (6040h = 0Fh,
   607Ah = counts); STOPPING sends quick stop (6040h = 02h) until every drive stands still;
5. heartbeat producer; timing figures; the cycle record.

Reactions (every one is an :class:`~controller.canopen.master.events.Event` with its cycle):
a drive fault, a drive EMCY, a lost heartbeat, a node leaving OPERATIONAL, the CSP
following-error bit (6041h bit 13), a drive that leaves OPERATION ENABLED, a drive TPDO
missing for ``silent_cycles``, a setpoint outside an axis limit -> quick stop of all
drives.  The encoder silent for ``silent_cycles`` -> ``Tracker.disengage()``: the de-sync
runs on the estimator's extrapolated master.

The same code runs in stepped time (tests, demo) and real time (``run``): the only waiting
is ``transport.run_until``.
"""

from __future__ import annotations

import gc
import math
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

from ...errors import CanError
from ...kinematics import CountsConverter
from ...kinematics import create as create_kinematics
from ...tracking import MasterEstimate, MotionState, Tracker, TrackState
from ..config.busload import BusLoad, bus_load, check_bus_load
from ..io.transport import Transport
from ..protocol import cia402
from ..protocol.cia402 import State
from .app import Application, ConveyorFollow
from .axisio import AxisIO
from .boot import BootResult, boot
from .events import EventLog
from .masterio import MasterInput
from .supervision import EmcyMonitor, HeartbeatMonitor
from .sync import SyncProducer

if TYPE_CHECKING:
    from ..config import BusConfig


class EnableError(CanError):
    """A drive did not reach OPERATION ENABLED."""


class Phase(Enum):
    IDLE = "idle"
    ENABLING = "enabling"
    RUNNING = "running"
    STOPPING = "stopping"
    STOPPED = "stopped"


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
    """Per-cycle timing [ns] (real time only; all zero in stepped time)."""

    sync_late: array = field(default_factory=lambda: array("q"))
    sync_interval: array = field(default_factory=lambda: array("q"))
    compute: array = field(default_factory=lambda: array("q"))
    latency: array = field(default_factory=lambda: array("q"))
    cpu_cycle: array = field(default_factory=lambda: array("q"))
    cpu_compute: array = field(default_factory=lambda: array("q"))
    missed: int = 0
    late_inputs: int = 0
    #: cycles started more than a period late: the time base slipped (no SYNC burst)
    overruns: int = 0


class Controller:
    """The CANopen tracking controller for one bus (see the module docstring)."""

    #: cycles the drives get to stop (quick stop) before the run gives up waiting
    STOP_CYCLES_MAX = 5000

    def __init__(self, cfg: BusConfig, transport: Transport,
                 app: Application | None = None, *, events: EventLog | None = None,
                 keep_trace: bool = True,
                 on_cycle: Callable[[Controller, CycleRecord], None] | None = None,
                 enforce_bus_load: bool = True) -> None:
        if cfg.tracking is None:
            raise CanError(f"{cfg.file}: no .tracking section: nothing to control")
        self.cfg = cfg
        self.tc = cfg.tracking
        self.transport = transport
        self.clock = transport.clock
        self.app: Application = app if app is not None else ConveyorFollow()
        self.events = events if events is not None else EventLog()
        self.keep_trace = keep_trace
        self.on_cycle = on_cycle
        # enforce_bus_load=False: a virtual bus, which has no bit time (benchmarks), or a caller
        # that checked the load itself (cantrack run: before opening the bus)
        self.bus_load: BusLoad = check_bus_load(cfg) if enforce_bus_load else bus_load(cfg)
        self.period_ns = cfg.period_ns
        self.compute_ns = int(self.tc.compute_at * self.period_ns)
        self.kinematics = create_kinematics(self.tc.kinematics, [a.name for a in self.tc.axes])
        self.counts = CountsConverter([a.scale for a in self.tc.axes])
        self.axes = [AxisIO(cfg, a.name, a.node, a.scale, transport) for a in self.tc.axes]
        self.master = MasterInput(cfg, transport)
        self.sync = SyncProducer(transport, 0x80, cfg.master.sync_overflow)
        self.heartbeats = HeartbeatMonitor(transport)
        self.emcy = EmcyMonitor(transport)
        self._watch_nodes()
        self.tracker: Tracker | None = None
        self.phase = Phase.IDLE
        self.k = 0
        self.t0 = 0
        self.timing = Timing()
        self.trace: list[CycleRecord] = []
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
        self.last_output = None
        #: |actual - master| [mm] of the last cycle while the tracker is not OFF
        self.last_tracking_error = 0.0

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
            self.emcy.watch(0x80 + slave.node_id, slave.node_id, label)

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
        """Run one cycle (SYNC k ... RPDOs for SYNC k+1)."""
        k = self.k
        clock = self.clock
        transport = self.transport
        deadline = self.t0 + k * self.period_ns
        late = clock.now_ns() - deadline
        if late > self.period_ns:
            # overrun by more than a period: do not fire a burst of SYNCs; the time base
            # slips by whole periods (the cycle index, the tracker's sample, goes on by one;
            # the estimator is told, so that the belt's time axis stays right)
            periods = late // self.period_ns
            slip = periods * self.period_ns
            self.t0 += slip
            deadline += slip
            self.timing.overruns += 1
            self.master.skip(periods)  # the belt moved on meanwhile
            self._master_for.clear()
        transport.run_until(deadline, precise=True)
        self.master.cycle = k
        for a in self.axes:
            a.cycle = k
        cpu0 = time.thread_time_ns()
        t_sent = clock.now_ns()
        self.sync.send()
        complete = transport.run_until(deadline + self.compute_ns, self._inputs_complete)
        t_c = clock.now_ns()
        cpu1 = time.thread_time_ns()
        rec = self._compute(k, t_sent, deadline)
        t_done = clock.now_ns()
        cpu2 = time.thread_time_ns()
        tm = self.timing
        if clock.realtime:
            tm.sync_late.append(t_sent - deadline)
            if self._last_sync_sent is not None:
                tm.sync_interval.append(t_sent - self._last_sync_sent)
            tm.compute.append(t_done - t_c)
            snap = self.master.snapshot
            if snap is not None and snap[2] == k:
                tm.latency.append(t_done - snap[1])
            tm.cpu_compute.append(cpu2 - cpu1)
            tm.cpu_cycle.append(cpu2 - cpu0)
            if t_done > deadline + self.period_ns:
                tm.missed += 1
            if not complete:
                tm.late_inputs += 1
            if rec is not None:
                rec.sync_late_us = (t_sent - deadline) / 1e3
                rec.compute_us = (t_done - t_c) / 1e3
        self._last_sync_sent = t_sent
        self._produce_heartbeat(t_done)
        self.k = k + 1
        if rec is not None:
            if self.keep_trace:
                self.trace.append(rec)
            if self.on_cycle is not None:
                self.on_cycle(self, rec)
        return rec

    def _inputs_complete(self) -> bool:
        k = self.master.cycle
        if not self.master.fresh(k):
            return False
        for a in self.axes:
            if not a.fresh(k):
                return False
        return True

    def _produce_heartbeat(self, now: int) -> None:
        if self._hb_next is not None and now >= self._hb_next:
            self.transport.send(0x700 + self.cfg.master.node_id, b"\x05")
            self._hb_next += self.cfg.master.heartbeat_producer_ms * 1_000_000
            if self._hb_next <= now:
                self._hb_next = now + self.cfg.master.heartbeat_producer_ms * 1_000_000

    def _compute(self, k: int, t_sent: int, deadline: int) -> CycleRecord:
        t_s = (deadline - self.t0) * 1e-9
        self._supervise(k, t_s)
        event, est = self.master.update(k, (t_sent - deadline) * 1e-9)
        if event == "silent":
            self._master_silent(k, t_s)
        elif event == "back":
            self.events.add(k, t_s, self.master.label, "master_back",
                            "encoder samples arrive again", "estimator restarted", level=20)
        phase = self.phase
        setpoint = None
        if phase is Phase.ENABLING:
            self._enable_step(k, t_s)
        elif phase is Phase.RUNNING:
            setpoint = self._run_step(k, t_s, est)
        else:
            self._stop_step(k)
        return self._record(k, t_s, setpoint)

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
        if ready and self.master.ready:
            joints = self.counts.from_counts([a.hold for a in self.axes])
            self.tracker = Tracker(self.tc.tracker, self.kinematics.pose(joints))
            self.phase = Phase.RUNNING
            self.events.add(k, t_s, "controller", "enabled",
                            "all drives in OPERATION ENABLED, tracking starts at "
                            + ", ".join(f"{a.axis}={j:.3f}" for a, j in zip(self.axes, joints)),
                            level=20)
            self.app.start(self, k)
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
            self._fail(k, t_s, self.master.label, "enable_timeout",
                       f"no encoder samples within {self.tc.timeouts.enable_s:g} s")

    def _run_step(self, k: int, t_s: float, est: MasterEstimate | None) -> tuple[float, ...]:
        tracker = self.tracker
        assert tracker is not None
        if est is None:
            est = MasterEstimate(0.0, 0.0, 0.0)
        m = self.app.update(self, k, est)
        out = tracker.update(m)
        self.last_output = out
        joints = self.kinematics.joints(out.setpoint)
        bad = self._limit_violation(joints, self.kinematics.joint_velocities(out.setpoint))
        if bad is not None:
            axis, detail = bad
            self.quick_stop(k, t_s, axis.label, "limit", detail)
            for a in self.axes:
                a.send(cia402.CW_QUICK_STOP_CMD, a.target)
            return joints
        counts = self.counts.to_counts(joints)
        for a, c in zip(self.axes, counts):
            a.send(cia402.CW_ENABLE, c)
        self._master_for[k + self.master.lead] = m
        return joints

    def _limit_violation(self, joints, velocities) -> tuple[AxisIO, str] | None:
        """The first axis whose setpoint, or the point where a quick stop from the
        setpoint's velocity would end (6085h deceleration), is outside its limits."""
        for a, p, v in zip(self.axes, joints, velocities):
            sc = a.scale
            decel = a.quick_stop_decel
            stop = p + v * abs(v) / (2.0 * decel) if decel > 0 else p
            if not (sc.min <= p <= sc.max and sc.min <= stop <= sc.max):
                unit = sc.unit
                return a, (f"setpoint {a.axis} = {p:.3f} {unit} at {v:.1f} {unit}/s (a quick "
                           f"stop at {decel:.0f} {unit}/s^2 ends at {stop:.3f}) outside "
                           f"[{sc.min:g}, {sc.max:g}]")
        return None

    def _stop_step(self, k: int) -> None:
        still = True
        for a in self.axes:
            inp = a.input
            target = inp.actual if inp is not None else a.target
            a.send(cia402.CW_QUICK_STOP_CMD, target)
            st = inp.state if inp is not None else None
            if st in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE,
                      State.OPERATION_ENABLED):
                still = False
        if self.phase is Phase.STOPPING:
            self._stop_cycles += 1
            if still:
                self.phase = Phase.STOPPED
                self.events.add(k, (self.clock.now_ns() - self.t0) * 1e-9, "controller",
                                "stopped", "all drives stand still (quick stop done)",
                                level=20)

    # -- supervision -------------------------------------------------------------------------
    def quick_stop(self, k: int, t_s: float, source: str, kind: str, detail: str) -> None:
        """React to ``kind`` by a quick stop of all drives (once)."""
        if self.phase in (Phase.STOPPING, Phase.STOPPED):
            self.events.add(k, t_s, source, kind, detail, "(already stopping)")
            return
        self.events.add(k, t_s, source, kind, detail, "quick stop of all drives")
        self.phase = Phase.STOPPING

    def _fail(self, k: int, t_s: float, source: str, kind: str, detail: str) -> None:
        self.quick_stop(k, t_s, source, kind, detail)
        if self.failure is None:
            self.failure = EnableError(f"{source}: {detail}")

    def _master_silent(self, k: int, t_s: float) -> None:
        tr = self.tracker
        engaged = tr is not None and tr.state in (TrackState.SYNCING, TrackState.SYNCED)
        reaction = "de-sync on the extrapolated master" if engaged else "waiting for samples"
        self.events.add(k, t_s, self.master.label, "master_silent",
                        f"no encoder sample for {self.master.silent} cycles", reaction)
        if engaged:
            tr.disengage()
        if self.phase is Phase.RUNNING:
            self.app.master_lost(self, k)

    def _supervise(self, k: int, t_s: float) -> None:
        now = self.clock.now_ns()
        for label, kind, detail in self.heartbeats.check(now):
            self.quick_stop(k, t_s, label, kind, detail)
        for e in self.emcy.pop_all():
            if e.code == 0:
                self.events.add(k, t_s, e.label, "emcy", f"{e}: error reset", level=20)
            elif e.node_id in {a.node_id for a in self.axes}:
                self.quick_stop(k, t_s, e.label, "emcy", str(e))
            else:
                self.events.add(k, t_s, e.label, "emcy", str(e), "reported")
        if self.phase in (Phase.STOPPING, Phase.STOPPED):
            for a in self.axes:
                st = a.input.state if a.fresh(k) else None
                if st in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                    if a.node not in self._faults_reported:
                        self._faults_reported.add(a.node)
                        self.events.add(k, t_s, a.label, "drive_fault",
                                        f"statusword {a.input.statusword:04X}h ({st.value})",
                                        "(already stopping)")
            return
        if self.phase is not Phase.ENABLING and self.phase is not Phase.RUNNING:
            return
        for i, a in enumerate(self.axes):
            if not a.fresh(k):
                self._drive_silent[i] += 1
                if self._drive_silent[i] == self.tc.conveyor.silent_cycles:
                    self.quick_stop(k, t_s, a.label, "drive_silent",
                                    f"no TPDO for {self._drive_silent[i]} cycles")
                continue
            self._drive_silent[i] = 0
            inp = a.input
            st = inp.state
            if st in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                if self.phase is Phase.RUNNING or (a.hold is not None):
                    self._faults_reported.add(a.node)
                    self.quick_stop(k, t_s, a.label, "drive_fault",
                                    f"statusword {inp.statusword:04X}h ({st.value})")
                continue
            if st is State.OPERATION_ENABLED and inp.statusword & cia402.SW_FOLLOWING_ERROR:
                self.quick_stop(k, t_s, a.label, "following_error",
                                f"statusword {inp.statusword:04X}h: bit 13 following error")
            elif self.phase is Phase.RUNNING and st is not State.OPERATION_ENABLED:
                self.quick_stop(k, t_s, a.label, "drive_disabled",
                                f"left OPERATION ENABLED: statusword {inp.statusword:04X}h "
                                f"({st.value if st else 'invalid'})")

    # -- records -----------------------------------------------------------------------------
    def _record(self, k: int, t_s: float, setpoint: tuple[float, ...] | None) -> CycleRecord:
        tr = self.tracker
        out = self.last_output if self.phase is Phase.RUNNING else None
        actual = self.counts.from_counts([a.input.actual if a.input is not None else 0
                                          for a in self.axes])
        err = 0.0
        m_k = self._master_for.pop(k, None)  # the master predicted for this SYNC
        if m_k is not None and tr is not None and tr.state is not TrackState.OFF:
            err = self._translation_error(actual, m_k)
        self.last_tracking_error = err
        master = self.master
        est = master.last_estimate
        return CycleRecord(
            cycle=k, t_s=t_s, phase=self.phase.value, raw=master.raw,
            belt_mm=master.belt_mm if master.raw is not None else None,
            belt_vel=est.vel if est is not None and master.estimator.samples >= 3 else None,
            state=self._track_state(tr),
            imfs=self._imfs(tr),
            error=int(out.error) if out is not None else 0,
            setpoint=setpoint,
            targets=tuple([a.target for a in self.axes]),
            actual=actual,
            statuswords=tuple([a.input.statusword if a.input is not None else 0
                               for a in self.axes]),
            tracking_error=err, sync_late_us=0.0, compute_us=0.0)

    def _track_state(self, tr: Tracker | None) -> int:
        """Tracker state of the cycle record: the application's if it has one (the demo's
        robot group; the controller's tracker passes its setpoint through), else the
        tracker's."""
        st = getattr(self.app, "track_state", None)
        if st is not None and self.phase is Phase.RUNNING:
            return int(st)
        return int(tr.state) if tr is not None else 0

    def _imfs(self, tr: Tracker | None) -> int:
        """IMFS of the cycle record: the application's (the demo's robot group) if it has
        one, else the tracker's."""
        imfs = getattr(self.app, "imfs", None)
        if imfs is not None and self.phase is Phase.RUNNING:
            return int(imfs)
        return int(tr.imfs) if tr is not None else 0

    def _translation_error(self, actual: tuple[float, ...], master: MotionState) -> float:
        """|actual - master| over the translation axes x, y, z [mm]."""
        p = master.pos
        s = 0.0
        for name, value in zip(self.kinematics.axes, actual):
            i = "xyz".find(name)
            if i >= 0:
                d = value - p[i]
                s += d * d
        return math.sqrt(s)

    # -- running -----------------------------------------------------------------------------
    def run(self, max_cycles: int | None = None,
            stop: Callable[[], bool] | None = None, realtime_gc: bool | None = None) -> None:
        """Step until the application is done, the drives stopped, ``max_cycles``, or
        ``stop()``; then leave the drives disabled.  Raises the failure of the enable."""
        rt = self.clock.realtime if realtime_gc is None else realtime_gc
        if rt:
            gc.collect()
            gc.freeze()
            gc.disable()
        if self.phase is Phase.IDLE or (self.k == 0 and rt):
            self.start()  # (again after the gc work: the first deadline is one period ahead)
        try:
            while max_cycles is None or self.k < max_cycles:
                self.step()
                if self.phase is Phase.RUNNING and self.app.done(self, self.k - 1):
                    break
                if self.phase is Phase.STOPPED:
                    break
                if self.phase is Phase.STOPPING and self._stop_cycles > self.STOP_CYCLES_MAX:
                    break
                if stop is not None and stop():
                    break
        finally:
            if rt:
                gc.enable()
                gc.unfreeze()
        if self.phase is Phase.RUNNING:
            self.disable()
        if self.failure is not None:
            raise self.failure

    def disable(self, cycles: int = 3) -> None:
        """Leave OPERATION ENABLED (6040h = 06h, transition 8) for a few cycles, holding."""
        self.phase = Phase.STOPPED
        for _ in range(cycles):
            k = self.k
            deadline = self.t0 + k * self.period_ns
            self.transport.run_until(deadline)
            self.master.cycle = k
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
