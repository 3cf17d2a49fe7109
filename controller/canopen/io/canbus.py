"""Opening a real CAN bus like python-can's own tools (``-i/-c/-b``, config file, env vars).

The flags come from :func:`controller.cli.common.add_bus_arguments` (python-can's
``can.cli.add_bus_arguments``, python-can >= 4.6, docs/spec/tools.md#4); whatever they do
not give is taken from python-can's configuration (``can.util.load_config``: the file given
with ``--can-config``, else ``~/.canrc``, ``~/.can``, ``/etc/can.conf``, and the environment
variables CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE).  Without a bitrate the bus.yml's
``master.baudrate`` is used.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import signal
from typing import Any

import can
import can.cli

from ...errors import CanError
from .files import write_json_atomic

log = logging.getLogger(__name__)

#: the CiA 301 bit rates [kbit/s] (bus.yml ``master.baudrate``)
BAUDRATES_KBIT = (10, 20, 50, 125, 250, 500, 800, 1000)


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
    return open_configured(bus_config(args, default_bitrate))


def bus_config_for(args: argparse.Namespace, cfg):
    """The python-can bus settings for ``cfg`` (a ControllerConfig) -> (settings, cfg).

    A bitrate from -b, CAN_BITRATE or python-can's config file that differs from
    ``master.baudrate`` wins (it is what the bus runs at) and is logged; the returned cfg
    carries it, so that the bus load is checked (warn > 60 %, refuse > 90 %) and reported at
    the bitrate actually used.
    """
    config = bus_config(args, cfg.bitrate)
    bitrate = int(config["bitrate"])
    if bitrate != cfg.bitrate:
        kbit = bitrate // 1000
        if bitrate % 1000 or kbit not in BAUDRATES_KBIT:
            raise CanError(f"bitrate {bitrate} bit/s (-b, CAN_BITRATE or the python-can "
                           f"config) is not a CANopen bit rate: one of "
                           f"{', '.join(str(b * 1000) for b in BAUDRATES_KBIT)}")
        log.warning("%s: the bus runs at %d kbit/s (-b, CAN_BITRATE or the python-can "
                    "config), not master.baudrate %d kbit/s: bus load computed at %d kbit/s",
                    cfg.file, kbit, cfg.master.baudrate_kbit, kbit)
        cfg = dataclasses.replace(cfg, master=dataclasses.replace(cfg.master,
                                                                  baudrate_kbit=kbit))
    return config, cfg


def open_configured(config: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**config)``; a failure is a CanError naming interface and channel."""
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

    Written to a temporary name and renamed (:func:`report.write_json_atomic`), so a waiting
    script never reads half a file.
    """
    write_json_atomic(path, {"pid": os.getpid(), **info}, indent=None)


class StopSignals:
    """SIGTERM (and SIGINT: Ctrl-C) ask the command to stop: ``requested`` becomes the
    signal's name and the command ends as at the end of its duration, writing complete files;
    the previous handlers come back on exit.  A second signal of the same kind while stopping
    is ignored.  Only the main thread can install handlers (in-process tests: a no-op)."""

    def __init__(self, sigint: bool = True) -> None:
        self.requested: str | None = None
        self._signals = [signal.SIGTERM] + ([signal.SIGINT] if sigint else [])
        self._old: dict = {}

    def _handler(self, signum, frame) -> None:
        if self.requested is None:
            self.requested = signal.Signals(signum).name.lower()

    def __call__(self) -> bool:
        return self.requested is not None

    def __enter__(self) -> StopSignals:
        for sig in self._signals:
            try:
                self._old[sig] = signal.signal(sig, self._handler)
            except ValueError:  # not the main thread
                pass
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


def remove_ready_file(path: str | None) -> None:
    """Remove a readiness file at the end of a command (a script must not take a stale one
    of an earlier run for the next)."""
    if path:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass


def seconds(text: str) -> float:
    """A duration [s]: a finite number > 0 (not inf, nan, or <= 0)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number of seconds > 0")
    return v
