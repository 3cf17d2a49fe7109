"""The ``.plc:`` section of bus.yml: the controller's own CANopen node for a PLC.

With the section, ``cantrack run`` (and ``cantrack demo``) make the controller a node a PLC
commands (eds/cantrack-controller.eds, docs/plc.md).  Keys::

    .plc:
      commander: 0x20              # node-ID of the commanding PLC (required)
      commander_heartbeat_ms: 300  # consumer heartbeat time of the PLC's heartbeat (1016h)
      on_commander_lost: desync    # continue | desync | stop (like CiA 402 6007h)
      command_window_us: 0         # > 0: commands only within this time after the SYNC
      trigger_rate_max: 100        # trigger edges per second accepted (more: dropped)
      trigger_overflow: drop_newest  # full trigger buffer: drop_newest | drop_oldest

The node-ID of the controller's node is ``master.node_id``.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, TypeVar

from ...yamlmarks import Section

if TYPE_CHECKING:
    from .bus import ControllerConfig


E = TypeVar("E", bound=Enum)


class CommanderLoss(Enum):
    """Reaction to the loss of the commander's heartbeat (CiA 402 6007h's idea)."""

    CONTINUE = "continue"  # an event only
    DESYNC = "desync"  # de-sync on the path (as an engage command 0)
    STOP = "stop"  # quick stop of all drives


class TriggerOverflow(Enum):
    """What a full trigger buffer does with one more trigger (never: abort)."""

    DROP_NEWEST = "drop_newest"  # the new trigger is dropped
    DROP_OLDEST = "drop_oldest"  # the oldest waiting item is dropped for it


@dataclass(frozen=True)
class PlcConfig:
    """The ``.plc:`` section (see the module docstring; times in ms / us, rate in 1/s)."""

    commander: int | None = None
    commander_heartbeat_ms: int = 300
    on_commander_lost: CommanderLoss = CommanderLoss.DESYNC
    command_window_us: int = 0
    trigger_rate_max: float = 100.0
    trigger_overflow: TriggerOverflow = TriggerOverflow.DROP_NEWEST


def _choice(s: Section, key: str, enum: type[E], default: E) -> E:
    value = s.str(key, default.value, choices=[e.value for e in enum])
    return enum(value)


def parse_plc(s: Section, cfg: ControllerConfig) -> PlcConfig:
    d = PlcConfig()
    commander = s.int("commander", None, min=1, max=127)
    if commander is None:
        raise s.error("commander", "is required: the node-ID of the PLC that commands the "
                      "controller (its heartbeat is consumed, 1016h)", at_value=False)
    if commander == cfg.master.node_id:
        raise s.error("commander", f"(={commander}) is the controller's own node-ID "
                      "(master.node_id)")
    other = cfg.slave_by_node(commander)
    if other is not None:
        raise s.error("commander", f"(={commander}) is the node-ID of slave {other.name!r}")
    period_us = cfg.master.sync_period_us
    out = PlcConfig(
        commander=commander,
        commander_heartbeat_ms=s.int("commander_heartbeat_ms", d.commander_heartbeat_ms,
                                     min=1, max=0xFFFF),
        on_commander_lost=_choice(s, "on_commander_lost", CommanderLoss,
                                  d.on_commander_lost),
        command_window_us=s.int("command_window_us", d.command_window_us, min=0,
                                max=period_us),
        trigger_rate_max=s.float("trigger_rate_max", d.trigger_rate_max, above=0.0),
        trigger_overflow=_choice(s, "trigger_overflow", TriggerOverflow,
                                 d.trigger_overflow))
    s.finish()
    return out
