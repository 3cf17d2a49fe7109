"""``cantrack run CONFIG``: the controller on a real CAN bus (wall-clock time).

Boots the bus (NMT reset, identity, SDO configuration, NMT start), enables the drives in
CSP and runs the cycle until ``--duration`` or Ctrl-C; the application follows a point of
the belt (``--engage-at``/``--disengage-at``, absolute or relative).  Bus flags as in
python-can's tools (-i/-c/-b, --can-config, CAN_* environment variables).

The controller's own heartbeat (``master.heartbeat_producer``) runs from the start of the
boot: a boot-up message (700h + id, 00h), then 05h every producer period, so that the drives'
heartbeat consumers (1016h, written by the boot) see it before the cycle starts; the cycle's
producer takes over.  Heartbeat supervision of the slaves counts from the start of the cycle
(heartbeats of the boot are not timed).

SIGTERM and Ctrl-C stop the run like the end of ``--duration``: disable the drives, write the
report, exit (``--ready-file PATH`` tells a script when that holds: it is written once the
bus is open and the boot starts).  Exit codes: 0 = normal end; 3 = a supervision reaction
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
import sys
import time
from collections.abc import Callable

from ..canopen.apps.report import status_line, summary_table, timing_summary, write_telemetry
from ..canopen.config import load_bus_config
from ..canopen.config.busload import check_bus_load
from ..canopen.io import canbus
from ..canopen.io.files import write_json_atomic
from ..canopen.io.transport import RealtimeTransport
from ..canopen.master.app import ConveyorFollow
from ..canopen.master.cycle import Controller
from ..canopen.master.plc_node import attach_plc_node, plc_summary
from ..errors import CanError
from ..tracking import Mode
from .common import StatusLine, add_bus_arguments


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="bus.yml with a .tracking section")
    add_bus_arguments(p)
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--engage-at", type=float, help="engage this many s after tracking starts")
    p.add_argument("--disengage-at", type=float, help="disengage this many s after the start")
    p.add_argument("--offset", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"), help="the belt point to follow [mm]")
    p.add_argument("--mode", choices=("absolute", "relative"), default="relative")
    p.add_argument("--telemetry", metavar="FILE", help="write JSON-lines telemetry")
    p.add_argument("--report", metavar="FILE", help="write a JSON run report")
    p.add_argument("--ready-file", metavar="PATH",
                   help="write this file (JSON: pid, node-IDs) when the bus is open and the "
                        "boot starts (SIGTERM is handled from then on)")
    p.add_argument("--plc-node", action="store_true",
                   help="the controller is also a CANopen node a PLC commands "
                        "(eds/cantrack-controller.eds, docs/plc.md); on by itself with a "
                        ".plc section in the bus.yml")
    p.add_argument("-q", "--quiet", action="store_true", help="no live status line")
    return p


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
        self.cycles: list[list[int]] = []
        if self.active:
            self.inner.send(self.cob, b"\x00")  # boot-up
            self._next = self.clock.now_ns() + self.period_ns

    def send(self, can_id: int, data) -> None:
        self.inner.send(can_id, data)
        if can_id == 0x80:
            self.cycles.append([])
        elif self.cycles and 0x180 <= can_id < 0x580:
            self.cycles[-1].append(can_id)

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


def run_report(ctl: Controller, changes: list[dict], pdo_cycles: list[list[int]],
               exit_code: int, end: str, wall_s: float, error: str | None = None) -> dict:
    """The ``--report`` JSON of a run (see the module docstring)."""
    cfg = ctl.cfg
    m = cfg.master
    seqs: dict[tuple, int] = {}
    for c in pdo_cycles:
        seqs[tuple(c)] = seqs.get(tuple(c), 0) + 1
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
        "reactions": sum(1 for e in ctl.events if e.reaction),
        "drives": [s.as_dict() for s in ctl.stops],
        "bad_frames": {f"{cob:03X}h": n for cob, n in sorted(ctl.hygiene.counts.items())},
        "other_actors": dict(ctl.actors.counts),
        "events": events,
        "state_changes": changes,
        "sent_pdos_per_sync": [list(c) for c in pdo_cycles],
        "sent_pdo_sequences": [{"cob_ids": list(k), "cycles": v} for k, v in seqs.items()],
        "timing": timing_summary(ctl) if ctl.k else None,
    }


def _pdo_cobs(cfg) -> dict:
    from ..canopen.config.concise import effective_pdos
    out = {}
    for name, p in effective_pdos(cfg).items():
        out[name] = {"node_id": cfg.slaves[name].node_id,
                     "rpdo": [x.cob_id for x in p.rpdo.values() if x.enabled],
                     "tpdo": [x.cob_id for x in p.tpdo.values() if x.enabled]}
    return out


def main(argv: list[str] | None = None, prog: str = "cantrack run") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_bus_config(args.config)
    period = cfg.period_s
    def cyc(s: float | None) -> int | None:
        return None if s is None else round(s / period)
    app = ConveyorFollow(cyc(args.engage_at), cyc(args.disengage_at), args.offset,
                         Mode.ABSOLUTE if args.mode == "absolute" else Mode.RELATIVE,
                         end_cycle=cyc(args.duration))
    settings, cfg = canbus.bus_config_for(args, cfg)
    check_bus_load(cfg)  # before the bus is opened: a refusal leaves nothing to clean up
    bus = canbus.open_configured(settings)
    status = StatusLine(args.quiet, every_s=1.0, every_tty_s=0.2)
    changes: list[dict] = []
    prev: list = [None]
    terminated = [False]

    def on_term(signum, frame) -> None:
        terminated[0] = True

    old_term = canbus.set_sigterm(on_term)
    if args.ready_file:
        canbus.write_ready_file(args.ready_file, {"master": cfg.master.node_id,
                                                  "nodes": {name: sl.node_id
                                                            for name, sl in cfg.slaves.items()}})

    def on_cycle(ctl: Controller, rec) -> None:
        key = (rec.phase, rec.state)
        if key != prev[0]:
            prev[0] = key
            changes.append({"cycle": rec.cycle, "t_s": rec.t_s, "phase": rec.phase,
                            "state": _STATE_NAMES.get(rec.state, str(rec.state))})
        if status.due(rec.t_s):
            status.show(rec.t_s, status_line(ctl, rec))

    def stop() -> bool:
        # SIGTERM.  (A controlled stop ends by itself: confirmed, or unconfirmed after its
        # escalation; while running, --duration counts from the tracking start.)
        return terminated[0]

    inner = RealtimeTransport(bus)
    transport = BootHeartbeat(inner, cfg.master.node_id, cfg.master.heartbeat_producer_ms,
                              lambda: terminated[0])
    wall0 = time.perf_counter()
    ctl = Controller(cfg, transport, app, on_cycle=on_cycle, keep_trace=args.telemetry is not None,
                     enforce_bus_load=False)  # (checked above, at the bus's bitrate)
    plc = attach_plc_node(ctl, app, cfg.plc) if (args.plc_node or cfg.plc is not None) \
        else None
    if plc is not None:
        print(plc_summary(plc), file=sys.stderr)
    end, error, code = "duration", None, 0
    try:
        try:
            ctl.boot()
            transport.active = False  # the cycle's heartbeat producer takes over
            for w in ctl.heartbeats.watches.values():
                w.last_ns = None      # supervision counts from the cycle start
                w.lost = False
            ctl.run(stop=stop)
            if terminated[0]:
                end = "sigterm"
            elif ctl.phase.value == "stopped" and any(e.reaction for e in ctl.events):
                end = "stopped"
        except KeyboardInterrupt:
            end = "interrupted"
            ctl.disable()
        except Terminated:
            end = "sigterm"
        except CanError as exc:
            end, error = "error", str(exc)
            ctl.final_states()
            if args.report:
                write_json_atomic(args.report, run_report(ctl, changes, transport.cycles, 2, end,
                                                    time.perf_counter() - wall0, error))
            raise
    finally:
        canbus.set_sigterm(old_term)
        transport.close()
        status.close()
    code = ctl.exit_code()
    if args.telemetry:
        write_telemetry(args.telemetry, ctl)
    if args.report:
        write_json_atomic(args.report, run_report(ctl, changes, transport.cycles, code, end,
                                            time.perf_counter() - wall0, error))
    print(summary_table(ctl, [], time.perf_counter() - wall0))
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
