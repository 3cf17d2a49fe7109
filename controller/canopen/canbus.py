"""Opening a real CAN bus like python-can's own tools (``-i/-c/-b``, config file, env vars).

The flags come from ``can.cli.add_bus_arguments`` (python-can >= 4.5); whatever they do not
give is taken from python-can's configuration (``can.util.load_config``: the file given with
``--can-config``, else ``~/.canrc``, ``~/.can``, ``/etc/can.conf``, and the environment
variables CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE).  Without a bitrate the bus.yml's
``master.baudrate`` is used.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
from pathlib import Path
from typing import Any

import can
import can.cli

from ..errors import CanError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    can.cli.add_bus_arguments(parser)
    parser.add_argument("--can-config", metavar="FILE",
                        help="python-can configuration file (default: ~/.canrc etc.)")


def bus_config(args: argparse.Namespace, default_bitrate: int) -> dict[str, Any]:
    given: dict[str, Any] = {}
    for key in ("interface", "channel", "bitrate", "fd", "data_bitrate", "timing"):
        if key in args:
            given[key] = getattr(args, key)
    given.update(getattr(args, "bus_kwargs", {}) or {})
    try:
        config = dict(can.util.load_config(path=args.can_config, config=given))
    except Exception as exc:
        if "None" in str(exc):  # no interface anywhere
            config = {}
        else:
            raise CanError(f"python-can configuration: {exc}") from exc
    if not config.get("interface"):
        raise CanError("no CAN interface: give -i/--interface (e.g. -i socketcan -c can0), "
                       "a python-can config file or CAN_INTERFACE")
    config.setdefault("bitrate", default_bitrate)
    if config.get("bitrate") is None:
        config["bitrate"] = default_bitrate
    return config


def open_bus(args: argparse.Namespace, default_bitrate: int) -> can.BusABC:
    config = bus_config(args, default_bitrate)
    try:
        return can.Bus(**config)
    except Exception as exc:  # python-can raises assorted errors per backend
        raise CanError(f"cannot open the CAN bus {config.get('interface')}:"
                       f"{config.get('channel')}: {exc}") from exc


def set_sigterm(handler):
    """Install a SIGTERM handler; returns the previous one.  Only the main thread can: elsewhere
    (a command run in-process by a test) it is a no-op returning None, as is ``handler=None``."""
    if handler is None:
        return None
    try:
        return signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        return None


def write_ready_file(path: str, info: dict[str, Any]) -> None:
    """Atomically write a readiness file (JSON; ``pid`` added) for scripts that wait on it.

    Written to a temporary name and renamed, so a waiting script never reads half a file.
    """
    tmp = Path(f"{path}.tmp{os.getpid()}")
    tmp.write_text(json.dumps({"pid": os.getpid(), **info}))
    os.replace(tmp, path)
