"""``cantrack run CONFIG``: the controller on a real CAN bus (wall-clock time).

Boots the bus (NMT reset, identity, SDO configuration, NMT start), enables the drives in
CSP and runs the cycle until ``--duration`` or Ctrl-C; the application follows a point of
the belt (``--engage-at``/``--disengage-at``, absolute or relative), or, with a
``.tracking.cell``, runs the cell (:mod:`controller.canopen.apps.cell`: every robot on its
own drives, its MasterFrame changes or program, the cell's sensors; until ``--duration`` or,
without it, until nothing is scheduled and every robot stands), with the summary per robot,
frame and item, and each robot's items in the telemetry.  Bus flags as in
python-can's tools (-i/-c/-b, --can-config, CAN_* environment variables).

The controller's own heartbeat (``master.heartbeat_producer``) runs from the start of the
boot: a boot-up message (700h + id, 00h), then 05h every producer period, so that the drives'
heartbeat consumers (1016h, written by the boot) see it before the cycle starts; the cycle's
producer takes over.  Heartbeat supervision of the slaves counts from the start of the cycle
(heartbeats of the boot are not timed).

SIGTERM and Ctrl-C stop the run like the end of ``--duration``: disable the drives, write the
report, exit (``--ready-file PATH`` tells a script when that holds: it is written once the
bus is open and the boot starts, and removed when the command ends, however it ends).
``--telemetry`` is written as the run goes (rotated by ``--file-size``/``--file-time``,
``--keep`` files kept); the report holds summaries, not one entry per cycle.  Exit codes:
0 = normal end; 3 = a supervision reaction
happened (quick stop of the drives: heartbeat lost, drive fault, EMCY, following error,
another actor, ...) and every drive confirmed its stop; 4 = a reaction happened and a drive's
stop could not be confirmed (after the escalation, :mod:`.stopping`); 2 = an error (bad
configuration, the boot failed, an internal error in the cycle after the controlled stop;
one line on stderr).  Never 0 after a fault.

``--report run.json``: a machine-readable report (see :func:`run_report`): the configuration
(SYNC period, counter overflow, heartbeats, PDO COB-IDs), every event (cycle, time, node,
kind, reaction), the phase / tracker state changes with their cycle and time, the PDOs the
controller sent after each SYNC, timing and the exit code.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import deque
from collections.abc import Callable

from ..canopen.apps.cell import CellSource, finish_telemetry, format_cell_table
from ..canopen.apps.report import Telemetry, status_line, summary_table, timing_summary
from ..canopen.config import load_config
from ..canopen.config.busload import check_bus_load
from ..canopen.io import canbus
from ..canopen.io.cpu_latency import CpuLatencyRequest, latency_us_arg, request_cpu_latency
from ..canopen.io.files import write_json_atomic
from ..canopen.io.rotating import add_arguments as add_rotation_arguments
from ..canopen.io.transport import RealtimeTransport
from ..canopen.apps.follow import ConveyorFollow
from ..canopen.master.cycle import EXIT_ERROR, Controller
from ..canopen.master.plc_node import attach_plc_node, plc_summary
from ..errors import ConfigError
from ..tracking import Mode
from .common import StatusLine, add_bus_arguments


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="bus.yml with a .tracking section")
    add_bus_arguments(p)
    p.add_argument("--duration", type=canbus.seconds, help="stop after this many seconds")
    p.add_argument("--engage-at", type=float, help="engage this many s after tracking starts")
    p.add_argument("--disengage-at", type=float, help="disengage this many s after the start")
    p.add_argument("--offset", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"), help="the belt point to follow [mm]")
    p.add_argument("--mode", choices=("absolute", "relative"), default="relative")
    p.add_argument("--telemetry", metavar="FILE",
                   help="write JSON-lines telemetry as the run goes (rotated with --file-size, "
                        "--file-time, --keep)")
    p.add_argument("--telemetry-every", type=int, default=1, metavar="N",
                   help="a cycle line in the telemetry every N cycles (default 1)")
    p.add_argument("--report", metavar="FILE", help="write a JSON run report")
    p.add_argument("--ready-file", metavar="PATH",
                   help="write this file (JSON: pid, node-IDs) when the bus is open and the "
                        "boot starts (SIGTERM is handled from then on)")
    p.add_argument("--plc-node", action="store_true",
                   help="the controller is also a CANopen node a PLC commands "
                        "(eds/cantrack-controller.eds, docs/plc.md); on by itself with a "
                        ".plc section in the bus.yml")
    p.add_argument("-q", "--quiet", action="store_true", help="no live status line")
    p.add_argument("--fifo", type=int, metavar="PRIO", nargs="?", const=50,
                   help="real-time scheduling SCHED_FIFO at this priority (default 50; needs "
                        "root or CAP_SYS_NICE)")
    p.add_argument("--cpu", type=int, nargs="+", metavar="N",
                   help="run on these CPUs only (sched_setaffinity; e.g. an isolated core)")
    p.add_argument("--cpu-latency", type=latency_us_arg, metavar="US",
                   help="hold a CPU wake-up latency bound of US microseconds for the run "
                        "(Linux PM QoS, /dev/cpu_dma_latency; 0: the CPUs poll instead of "
                        "sleeping between cycles, as cyclictest does; needs root; "
                        "docs/hil.md)")
    add_rotation_arguments(p, "the telemetry")
    return p


def apply_scheduling(fifo: int | None, cpus: list[int] | None) -> list[str]:
    """SCHED_FIFO and CPU affinity for this process, as asked; what could not be done, as
    warnings (the run goes on with the normal scheduler)."""
    warnings = []
    if cpus:
        try:
            os.sched_setaffinity(0, set(cpus))
        except (OSError, ValueError) as exc:
            warnings.append(f"--cpu {' '.join(map(str, cpus))}: {exc}")
    if fifo is not None:
        try:
            lo, hi = os.sched_get_priority_min(os.SCHED_FIFO), \
                os.sched_get_priority_max(os.SCHED_FIFO)
            if not lo <= fifo <= hi:
                raise ValueError(f"priority must be {lo}..{hi}")
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo))
        except (OSError, ValueError, AttributeError) as exc:
            warnings.append(f"--fifo {fifo}: SCHED_FIFO not available ({exc}); normal "
                            "scheduling")
    return warnings


#: exit code when a supervision reaction (quick stop) happened (:meth:`Controller.exit_code`)
EXIT_REACTION = 3

_STATE_NAMES = {0: "OFF", 1: "SYNCING", 2: "SYNCED", 3: "DESYNCING"}


class Terminated(Exception):
    """SIGTERM during the boot."""


class BootHeartbeat:
    """A transport wrapper: the master's heartbeat during the boot, the sent PDOs per cycle.

    While ``active``, ``run_until`` waits in slices up to each heartbeat time and sends
    05h (after a first boot-up 00h); ``stop_flag()`` true raises :class:`Terminated` (SIGTERM
    during the boot).  Every frame sent after a SYNC is logged under that cycle."""

    def __init__(self, inner, node_id: int, period_ms: int,
                 stop_flag: Callable[[], bool]) -> None:
        self.inner = inner
        self.clock = inner.clock
        self.cob = 0x700 + node_id
        self.period_ns = period_ms * 1_000_000
        self.stop_flag = stop_flag
        self.active = period_ms > 0
        self._next: int | None = None
        #: the PDOs sent after each of the last SYNCs (bounded); every cycle is counted in
        #: ``sequences`` (COB-ID sequence -> cycles)
        self.cycles: deque[list[int]] = deque(maxlen=self.LAST)
        self.sequences: dict[tuple, int] = {}
        self._current: list[int] | None = None
        if self.active:
            self.inner.send(self.cob, b"\x00")  # boot-up
            self._next = self.clock.now_ns() + self.period_ns

    #: cycles whose sent PDOs are kept (the report's ``sent_pdos_last``)
    LAST = 100
    #: distinct PDO sequences counted (more are counted as one "other")
    SEQUENCES = 64

    def send(self, can_id: int, data) -> None:
        self.inner.send(can_id, data)
        if can_id == 0x80:
            self._close_cycle()
            self._current = []
            self.cycles.append(self._current)
        elif self._current is not None and 0x180 <= can_id < 0x580:
            self._current.append(can_id)

    def _close_cycle(self) -> None:
        if self._current is None:
            return
        key = tuple(self._current)
        if key in self.sequences or len(self.sequences) < self.SEQUENCES:
            self.sequences[key] = self.sequences.get(key, 0) + 1
        else:
            self.sequences[("other",)] = self.sequences.get(("other",), 0) + 1
        self._current = None

    def pdo_summary(self) -> tuple[dict[tuple, int], list[list[int]]]:
        """(sequence -> cycles) over the whole run, the last cycles' PDOs."""
        seqs = dict(self.sequences)
        if self._current is not None:
            key = tuple(self._current)
            seqs[key] = seqs.get(key, 0) + 1
        return seqs, [list(c) for c in self.cycles]

    def subscribe(self, can_id: int, callback) -> None:
        self.inner.subscribe(can_id, callback)

    def unsubscribe(self, can_id: int, callback=None) -> None:
        self.inner.unsubscribe(can_id, callback)

    def subscribe_errors(self, callback) -> None:
        self.inner.subscribe_errors(callback)

    def run_until(self, deadline_ns: int, done=None, precise: bool = False) -> bool:
        if not self.active:
            return self.inner.run_until(deadline_ns, done, precise)
        while True:
            if self.stop_flag():
                raise Terminated("terminated during the boot")
            now = self.clock.now_ns()
            if now >= self._next:
                self.inner.send(self.cob, b"\x05")
                self._next = max(self._next + self.period_ns, now + 1)
            until = min(deadline_ns, self._next, now + 200_000_000)
            if self.inner.run_until(until, done, precise) and done is not None and done():
                return True
            if self.clock.now_ns() >= deadline_ns:
                return done() if done is not None else True

    def close(self) -> None:
        self.inner.close()


def _node_of(cfg, source: str) -> int | None:
    for name, s in cfg.slaves.items():
        if cfg.label(name) == source:
            return s.node_id
    return None


def run_report(ctl: Controller, changes, pdos: BootHeartbeat,
               exit_code: int, end: str, wall_s: float, error: str | None = None,
               realtime: dict | None = None) -> dict:
    """The ``--report`` JSON of a run (see the module docstring): summaries, never a list
    per cycle (the last events, the last state changes, the PDOs of the last cycles, the
    counts of every sequence of PDOs sent after a SYNC); ``realtime``: what the run got of
    the scheduling options (:func:`realtime_settings`)."""
    cfg = ctl.cfg
    m = cfg.master
    seqs, last = pdos.pdo_summary()
    events = []
    for e in ctl.events:
        d = e.as_dict()
        d["node"] = _node_of(cfg, e.source)
        events.append(d)
    hb = {cfg.label(n): w.timeout_ns / 1e6 for n in cfg.slaves
          for w in [ctl.heartbeats.watches.get(cfg.slaves[n].node_id)] if w is not None}
    return {
        "config": str(cfg.file), "exit_code": exit_code, "end": end, "error": error,
        "sync_period_us": m.sync_period_us, "sync_overflow": m.sync_overflow,
        "master_node_id": m.node_id, "heartbeat_producer_ms": m.heartbeat_producer_ms,
        "heartbeat_timeouts_ms": hb,
        "nodes": {n: s.node_id for n, s in cfg.slaves.items()},
        "axes": [{"axis": a.axis, "node": a.node, "node_id": a.node_id,
                  "rpdo_cob_id": a.rpdo_cob} for a in ctl.axes],
        "pdos": _pdo_cobs(cfg),
        "boot_s": (ctl.boot_result.duration_ns / 1e9) if ctl.boot_result else None,
        "cycles": ctl.k, "wall_s": wall_s, "final_phase": ctl.phase.value,
        "reactions": ctl.events.reactions,
        "events_total": ctl.events.total,
        "drives": [s.as_dict() for s in ctl.stops],
        "bad_frames": {f"{cob:03X}h": n for cob, n in sorted(ctl.hygiene.counts.items())},
        "other_actors": dict(ctl.actors.counts),
        "events": events,
        "state_changes": list(changes),
        "state_changes_total": getattr(changes, "total", len(changes)),
        "sent_pdos_last": last,
        "sent_pdo_sequences": [{"cob_ids": list(k), "cycles": v} for k, v in seqs.items()],
        "timing": timing_summary(ctl) if ctl.k else None,
        "realtime": realtime,
    }


def realtime_settings(cpu_latency: CpuLatencyRequest | None) -> dict:
    """The scheduling this process runs with (as the kernel says, not as asked): policy and
    priority, the CPUs, the CPU latency request held (the bound asked for, the system's
    effective one) or None."""
    try:
        policy = os.sched_getscheduler(0)
        prio = os.sched_getparam(0).sched_priority
        cpus: list[int] | None = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # (not Linux)
        policy, prio, cpus = None, None, None
    names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR",
                                         "SCHED_BATCH", "SCHED_IDLE") if hasattr(os, n)}
    return {"policy": names.get(policy, policy), "priority": prio, "cpus": cpus,
            "cpu_latency_us": None if cpu_latency is None else {
                "requested": cpu_latency.latency_us, "effective": cpu_latency.effective_us}}


def _pdo_cobs(cfg) -> dict:
    from ..canopen.config.concise import effective_pdos
    out = {}
    for name, p in effective_pdos(cfg).items():
        out[name] = {"node_id": cfg.slaves[name].node_id,
                     "rpdo": [x.cob_id for x in p.rpdo.values() if x.enabled],
                     "tpdo": [x.cob_id for x in p.tpdo.values() if x.enabled]}
    return out


class _Changes(deque):
    """The phase / tracker state changes of a run: the last 1000, and how many in all."""

    def __init__(self) -> None:
        super().__init__(maxlen=1000)
        self.total = 0

    def append(self, x) -> None:
        super().append(x)
        self.total += 1


def main(argv: list[str] | None = None, prog: str = "cantrack run") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_config(args.config)
    if args.telemetry_every < 1:
        raise ConfigError(f"--telemetry-every (={args.telemetry_every}) must be >= 1")
    period = cfg.period_s
    def cyc(s: float | None) -> int | None:
        return None if s is None else round(s / period)
    telemetry: list[Telemetry] = []
    cell = cfg.tracking.cell if cfg.tracking is not None else None
    app: ConveyorFollow | CellSource
    if cell is not None:
        # a cell: its robots follow their MasterFrame changes (or programs) and sensors
        for flag, given in (("--engage-at", args.engage_at is not None),
                            ("--disengage-at", args.disengage_at is not None)):
            if given:
                raise ConfigError(f"{flag} is for one belt: a cell's robots engage by their "
                                  "master_frame changes or programs", file=cfg.file,
                                  key=".tracking.cell")

        def on_item(robot: str, rec) -> None:
            if telemetry:
                telemetry[0].cell_item(robot, rec)
        app = CellSource(cell, duration_s=args.duration, on_item=on_item)
    else:
        app = ConveyorFollow(cyc(args.engage_at), cyc(args.disengage_at), args.offset,
                             Mode.ABSOLUTE if args.mode == "absolute" else Mode.RELATIVE,
                             end_cycle=cyc(args.duration))
    settings, cfg = canbus.bus_config_for(args, cfg)
    check_bus_load(cfg)  # before the bus is opened: a refusal leaves nothing to clean up
    for warning in apply_scheduling(args.fifo, args.cpu):
        print(f"cantrack: warning: {warning}", file=sys.stderr)
    bus = canbus.open_configured(settings)
    status = StatusLine(args.quiet, every_s=1.0, every_tty_s=0.2)
    changes = _Changes()
    prev: list = [None]
    signals = canbus.StopSignals().__enter__()

    def on_cycle(ctl: Controller, rec) -> None:
        key = (rec.phase, rec.state)
        if key != prev[0]:
            prev[0] = key
            changes.append({"cycle": rec.cycle, "t_s": rec.t_s, "phase": rec.phase,
                            "state": _STATE_NAMES.get(rec.state, str(rec.state))})
        if telemetry:
            telemetry[0].cycle(rec)
        if status.due(rec.t_s):
            status.show(rec.t_s, status_line(ctl, rec))

    def stop() -> bool:
        # SIGTERM/SIGINT.  (A controlled stop ends by itself: confirmed, or unconfirmed after
        # its escalation; while running, --duration counts from the tracking start.)
        return signals()

    inner = RealtimeTransport(bus)
    transport = BootHeartbeat(inner, cfg.master.node_id, cfg.master.heartbeat_producer_ms,
                              signals)
    wall0 = time.perf_counter()
    ctl = Controller(cfg, transport, app, on_cycle=on_cycle, keep_trace=False,
                     enforce_bus_load=False)  # (checked above, at the bus's bitrate)
    plc = attach_plc_node(ctl, cfg.plc) if (args.plc_node or cfg.plc is not None) \
        else None
    if plc is not None:
        print(plc_summary(plc), file=sys.stderr)
    if args.telemetry:
        telemetry.append(Telemetry(args.telemetry, ctl, max_bytes=args.file_size,
                                   max_age_s=args.file_time, keep=args.keep,
                                   every=args.telemetry_every))

    def close_telemetry(end: str, error: str | None, code: int) -> None:
        # every exit alike (as cantrack demo's cell run): a cell's items still pending, then
        # the end line with the exit code and the cell's end extras (finish_telemetry)
        if not telemetry:
            return
        extra: dict = {"exit_code": code}
        if isinstance(app, CellSource):
            extra.update(finish_telemetry(telemetry[0], app))
        telemetry[0].close(end, error, extra=extra)

    # (held from here to the end of the run; the kernel drops it too if the process dies)
    cpu_latency, latency_warning = request_cpu_latency(args.cpu_latency)
    if latency_warning:
        print(f"cantrack: warning: {latency_warning}", file=sys.stderr)
    end, error, code = "duration", None, 0
    try:
        if args.ready_file:  # (from here on SIGTERM is handled and the file is removed)
            canbus.write_ready_file(args.ready_file, {
                "master": cfg.master.node_id,
                "nodes": {name: sl.node_id for name, sl in cfg.slaves.items()}})
        try:
            ctl.boot()
            transport.active = False  # the cycle's heartbeat producer takes over
            for w in ctl.heartbeats.watches.values():
                w.last_ns = None      # supervision counts from the cycle start
                w.lost = False
            ctl.run(stop=stop)
            if signals.requested:
                end = signals.requested
            elif ctl.phase.value == "stopped" and ctl.events.reactions:
                end = "stopped"
        except Terminated:
            end = signals.requested or "sigterm"
        except BaseException as exc:  # every exit writes complete files, then reports
            end, error = "error", str(exc) or type(exc).__name__
            ctl.final_states()
            close_telemetry(end, error, EXIT_ERROR)
            if args.report:
                write_json_atomic(args.report, run_report(
                    ctl, changes, transport, EXIT_ERROR, end, time.perf_counter() - wall0, error,
                    realtime_settings(cpu_latency)))
            raise
    finally:
        signals.__exit__()
        transport.close()
        canbus.remove_ready_file(args.ready_file)
        status.close()
        if cpu_latency is not None:
            cpu_latency.release()
    code = ctl.exit_code()
    close_telemetry(end, error, code)
    if args.report:
        write_json_atomic(args.report, run_report(ctl, changes, transport, code, end,
                                                  time.perf_counter() - wall0, error,
                                                  realtime_settings(cpu_latency)))
    if isinstance(app, CellSource):
        print(format_cell_table(app))
        print()
    print(summary_table(ctl, [], time.perf_counter() - wall0,
                        item_rows=not isinstance(app, CellSource)))
    if ctl.k:
        t = timing_summary(ctl)
        print(f"compute p99 {t['compute_us']['p99']:.0f} us, cpu/cycle p50 "
              f"{t['cpu_cycle_us']['p50']:.0f} us")
    for e in ctl.events:
        if e.reaction:
            print(f"event: {e}")
    if plc is not None:
        print(f"plc node: {plc.triggers} triggers taken, {plc.triggers_dropped} dropped, "
              f"{plc.refused} commands refused, "
              + ", ".join(f"TPDO{p.number} {p.cob_id:03X}h x{p.sent}" for p in plc.tpdos))
    return code
