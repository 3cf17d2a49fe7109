"""A bus configuration with its supervision windows stretched: the vcan tier on a slow machine.

Inside the test VM every process runs on the share of the host's CPU the VM gets.  On a busy
machine a heartbeat comes late, a drive's TPDO misses a cycle or two, a drive confirms its
stop late, and the windows written for an idle machine (examples/bus/vcan.yml: heartbeat
time-out 4 x 200 ms, 20 silent cycles, 1 s per stop stage) fire although nothing is wrong.
:func:`stretch_bus_config` multiplies every supervision window of a bus.yml by a factor
(the machine's measured slowness, :func:`controller.testing.speed.fresh_factor`); what is
supervised (the SYNC period, the heartbeat and PDO periods, the motion) stays as written, so
that a test still sees the traffic and the motion of the file.

Stretched, absent values from their defaults (so that no idle-machine window is left):

- the heartbeat consumer time-outs: ``heartbeat_multiplier`` (``options``, ``master`` and
  each slave that sets its own) - the controller's time-out of each slave and the drives'
  1016h time-out of the controller;
- PDO ``event_deadline`` (a TPDO's receive time-out);
- the SDO writes of the drives' time windows: 6066h (following error time-out) and 6068h
  (position window time);
- ``.tracking``: ``conveyor.silent_cycles`` (the encoder's and each drive's silence; a
  cell's: every ``cell.encoders.*.silent_cycles``),
  ``cycle.max_missed_in_row`` (kept 0 = never), every ``timeouts`` ``*_s`` (boot-up, SDO,
  enable, each stop stage);
- ``.plc.commander_heartbeat_ms`` (the commander's heartbeat time-out).

Not stretched: the SYNC period (bus.yml allows at most 100 ms, the vcan tier's period),
heartbeat producer times, PDO timers, the motion, ``.simulation`` and ``.demo``.
Command-line seconds (``--duration`` ...) are the caller's.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import yaml

__all__ = ["stretch_bus_config", "stretch_mapping"]

#: SDO writes of CiA 402 time windows [ms]: 6066h following error time-out, 6068h position
#: window time
_SDO_WINDOWS = (0x6066, 0x6068)


def stretch_bus_config(src: Path, dst: Path, factor: float) -> Path:
    """Write ``src`` (a bus.yml) with its windows stretched by ``factor`` (>= 1) to ``dst``.

    Relative ``dcf`` paths are made absolute (``dst`` may live elsewhere); anchors and merge
    keys are resolved, comments dropped.  Returns ``dst``.
    """
    from ..yamlmarks import load_marked

    src = Path(src)
    data = _copy(load_marked(src.read_text(), str(src)))
    if not isinstance(data, dict):
        raise ValueError(f"{src}: not a bus.yml mapping")
    for value in data.values():
        if isinstance(value, dict) and isinstance(value.get("dcf"), str):
            p = Path(value["dcf"])
            value["dcf"] = str(p if p.is_absolute() else (src.parent / p).resolve())
    out = stretch_mapping(data, factor)
    Path(dst).write_text(f"# {src.name} with its supervision windows x {factor:.3g} "
                         f"(controller.testing.stretch)\n" + yaml.safe_dump(out, sort_keys=False))
    return Path(dst)


def stretch_mapping(data: dict[str, Any], factor: float) -> dict[str, Any]:
    """The bus.yml mapping ``data`` with its windows stretched by ``factor`` (a new mapping)."""
    from ..canopen.config.bus import Options
    from ..canopen.config.plc import PlcConfig
    from ..canopen.config.tracking import Timeouts, TrackingConfig

    f = max(1.0, float(factor))
    d = _copy(data)
    options = d.setdefault("options", {})
    options["heartbeat_multiplier"] = round(options.get(
        "heartbeat_multiplier", _default(Options, "heartbeat_multiplier")) * f, 3)
    for name, node in d.items():
        if name.startswith(".") or name == "options" or not isinstance(node, dict):
            continue
        if isinstance(node.get("heartbeat_multiplier"), (int, float)):
            node["heartbeat_multiplier"] = round(node["heartbeat_multiplier"] * f, 3)
        for kind in ("rpdo", "tpdo"):
            for pdo in (node.get(kind) or {}).values():
                if isinstance(pdo, dict) and isinstance(pdo.get("event_deadline"), int):
                    pdo["event_deadline"] = round(pdo["event_deadline"] * f)
        for w in node.get("sdo") or []:
            if isinstance(w, dict) and w.get("index") in _SDO_WINDOWS \
                    and isinstance(w.get("value"), int):
                w["value"] = min(0xFFFF, round(w["value"] * f))
    tr = d.get(".tracking")
    if isinstance(tr, dict):
        cell = tr.get("cell")
        encoders = cell.get("encoders") if isinstance(cell, dict) else None
        for conveyor in [tr.get("conveyor")] + (list(encoders.values())
                                                if isinstance(encoders, dict) else []):
            if isinstance(conveyor, dict):
                # (5: the parser's default, controller.canopen.config.tracking)
                conveyor["silent_cycles"] = math.ceil(conveyor.get("silent_cycles", 5) * f)
        cycle = tr.setdefault("cycle", {})
        cycle["max_missed_in_row"] = math.ceil(cycle.get(
            "max_missed_in_row", _default(TrackingConfig, "max_missed_in_row")) * f)
        timeouts = tr.setdefault("timeouts", {})
        for fld in dataclasses.fields(Timeouts):
            if fld.name.endswith("_s"):
                timeouts[fld.name] = round(timeouts.get(fld.name, fld.default) * f, 3)
    plc = d.get(".plc")
    if isinstance(plc, dict):
        plc["commander_heartbeat_ms"] = round(
            plc.get("commander_heartbeat_ms", _default(PlcConfig, "commander_heartbeat_ms")) * f)
    return d


def _default(cls: type, name: str) -> Any:
    """A dataclass field's default (slots dataclasses have no class attribute for it)."""
    return next(x.default for x in dataclasses.fields(cls) if x.name == name)


def _copy(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _copy(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_copy(x) for x in v]
    return v
