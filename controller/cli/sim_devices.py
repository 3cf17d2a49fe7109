"""``cantrack sim-devices CONFIG``: only the simulated devices of a bus.yml, in real time.

The encoder and drives answer NMT, SDO, SYNC and PDOs on the given bus, so a controller in
another process (cantrack's or anybody's) can be tested against them; python-can's
``virtual`` interface only reaches the same process, so use e.g. ``-i socketcan -c vcan0``.
Faults can be scheduled: ``--inject T:NODE:ACTION[:ARG]`` with ACTION one of
``fault[:code]``, ``emcy[:code]``, ``heartbeat-stop``, ``silence``, ``mute-pdos``,
``noise:counts`` (encoder), ``disturb:counts`` (drive), ``power-off``.

``--ready-file PATH``: written (JSON: pid, devices, node-IDs) once every simulated device has
booted (sent its boot-up message), for a test harness that starts the controller next, and
removed when the command ends.  SIGTERM (and SIGINT) stop the devices cleanly with exit
code 0.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from ..canopen.config import load_config
from ..canopen.io import canbus
from ..canopen.io.clock import RealtimeClock
from ..canopen.io.transport import DeviceThread
from ..canopen.slave.drive import SimDrive
from ..canopen.slave.encoder import SimEncoder
from ..canopen.slave.node import NMT_INITIALISING
from ..canopen.slave.rack import DeviceRack
from ..errors import ConfigError
from .common import StatusLine, add_bus_arguments

ACTIONS = ("fault", "emcy", "heartbeat-stop", "silence", "mute-pdos", "noise", "disturb",
           "power-off")


def parse_injection(spec: str, names: list[str]) -> tuple[float, str, str, str | None]:
    parts = spec.split(":")
    if len(parts) < 3:
        raise ConfigError(f"--inject {spec!r}: must be T:NODE:ACTION[:ARG]")
    try:
        t = float(parts[0])
    except ValueError:
        raise ConfigError(f"--inject {spec!r}: time {parts[0]!r} is not a number") from None
    if not (math.isfinite(t) and t >= 0):
        raise ConfigError(f"--inject {spec!r}: time {parts[0]!r} must be a finite number of "
                          "seconds >= 0")
    node, action = parts[1], parts[2]
    arg = parts[3] if len(parts) > 3 else None
    if arg is not None:
        _check_arg(spec, action, arg)
    if node not in names:
        raise ConfigError(f"--inject {spec!r}: unknown node {node!r} (one of "
                          f"{', '.join(names)})")
    if action not in ACTIONS:
        raise ConfigError(f"--inject {spec!r}: unknown action {action!r} (one of "
                          f"{', '.join(ACTIONS)})")
    return t, node, action, arg


def _check_arg(spec: str, action: str, arg: str) -> None:
    """The ARG of an action: an integer code (fault, emcy), a finite number (noise, disturb)."""
    if action in ("fault", "emcy"):
        try:
            code = int(arg, 0)
        except ValueError:
            raise ConfigError(f"--inject {spec!r}: code {arg!r} is not an integer") from None
        if not 0 <= code <= 0xFFFF:
            raise ConfigError(f"--inject {spec!r}: code {arg!r} must be 0..0xFFFF")
    elif action in ("noise", "disturb"):
        try:
            v = float(arg)
        except ValueError:
            raise ConfigError(f"--inject {spec!r}: {arg!r} is not a number") from None
        if not (math.isfinite(v) and v >= 0):
            raise ConfigError(f"--inject {spec!r}: {arg!r} must be a finite number >= 0")
    else:
        raise ConfigError(f"--inject {spec!r}: {action} takes no argument")


def apply_injection(rack: DeviceRack, node: str, action: str, arg: str | None) -> None:
    d = rack.devices[node]
    def num(default: int) -> int:
        return int(arg, 0) if arg else default
    if action == "fault" and isinstance(d, SimDrive):
        d.inject_fault(num(0x1000))
    elif action == "emcy":
        d.send_emcy(num(0x1000))
    elif action == "heartbeat-stop":
        d.stop_heartbeat()
    elif action == "silence":
        d.silence(True)
    elif action == "mute-pdos":
        d.mute_pdos(True)
    elif action == "noise" and isinstance(d, SimEncoder):
        d.noise_counts = float(arg or 1.0)
    elif action == "disturb" and isinstance(d, SimDrive):
        d.disturb(float(arg or 100000))
    elif action == "power-off":
        d.power_off()
    else:
        raise ConfigError(f"action {action!r} does not apply to {node!r} ({d.kind})")


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="bus.yml (slaves and the .simulation section)")
    add_bus_arguments(p)
    p.add_argument("--only", nargs="+", metavar="NAME", help="simulate only these slaves")
    p.add_argument("--duration", type=canbus.seconds, help="stop after this many seconds")
    p.add_argument("--inject", action="append", default=[], metavar="T:NODE:ACTION[:ARG]",
                   help="schedule a fault (repeatable)")
    p.add_argument("--ready-file", metavar="PATH",
                   help="write this file (JSON) once every simulated device has booted")
    p.add_argument("-q", "--quiet", action="store_true", help="no status line")
    return p


def write_ready_file(path: str, rack: DeviceRack) -> None:
    """Atomically write the readiness file (pid, device names, node-IDs)."""
    canbus.write_ready_file(path, {"devices": {n: d.node_id for n, d in rack.devices.items()}})


def describe(rack: DeviceRack) -> str:
    parts = []
    for name, d in rack.devices.items():
        s = f"{name}[{d.node_id}] nmt {d.nmt_state}"
        if isinstance(d, SimDrive):
            s += f" {d.state.name} x={int(d.x)}"
        elif isinstance(d, SimEncoder):
            s += f" 6004h={int(d.load(0x6004))}"
        parts.append(s)
    return "  ".join(parts)


def main(argv: list[str] | None = None, prog: str = "cantrack sim-devices") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_config(args.config)
    names = list(cfg.slaves)
    if args.only:
        unknown = [n for n in args.only if n not in names]
        if unknown:
            raise ConfigError(f"--only: unknown slave(s) {', '.join(unknown)} (slaves: "
                              f"{', '.join(names)})")
    injections = sorted(parse_injection(s, names) for s in args.inject)
    bus = canbus.open_bus(args, cfg.bitrate)
    clock = RealtimeClock()
    rack = DeviceRack.from_config(cfg, bus, clock, args.only)
    thread = DeviceThread(rack, clock).start()
    if not args.quiet:
        print(f"simulating {', '.join(rack.devices)} on {bus.channel_info}", file=sys.stderr)
    t_end = None if args.duration is None else args.duration
    stopping = canbus.StopSignals().__enter__()  # SIGTERM/SIGINT: clean shutdown, exit 0
    ready = args.ready_file is None
    status = StatusLine(args.quiet, every_s=1.0, every_tty_s=0.0)
    try:
        while not stopping() and (t_end is None or clock.now_ns() * 1e-9 < t_end):
            if not ready and all(d.nmt_state != NMT_INITIALISING
                                 for d in rack.devices.values()):
                write_ready_file(args.ready_file, rack)
                ready = True
            now = clock.now_ns() * 1e-9
            while injections and injections[0][0] <= now:
                _, node, action, arg = injections.pop(0)
                apply_injection(rack, node, action, arg)
                print(f"[{now:.3f} s] injected {action} on {node}", file=sys.stderr)
            status.show(now, describe(rack))
            time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    finally:
        stopping.__exit__()
        try:
            thread.stop()
        finally:
            bus.shutdown()
            canbus.remove_ready_file(args.ready_file)
            status.close()
    return 0
