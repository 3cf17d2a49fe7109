"""Supervision events: what happened, where, in which cycle, and what the controller did."""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

log = logging.getLogger("controller.canopen")


@dataclass(frozen=True, slots=True)
class Event:
    cycle: int  # -1 during the boot
    t_s: float  # controller time [s]
    source: str  # "node 11 (x)", "controller", ...
    kind: str  # boot, heartbeat_lost, emcy, drive_fault, following_error, master_silent, ...
    detail: str
    reaction: str = ""

    def as_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        cyc = f"cycle {self.cycle}" if self.cycle >= 0 else "boot"
        react = f" -> {self.reaction}" if self.reaction else ""
        return f"[{cyc}, {self.t_s:.3f} s] {self.source}: {self.kind}: {self.detail}{react}"


class EventLog:
    """The list of events of a run; each one is also logged."""

    def __init__(self) -> None:
        self.events: list[Event] = []

    def add(self, cycle: int, t_s: float, source: str, kind: str, detail: str,
            reaction: str = "", level: int = logging.WARNING) -> Event:
        e = Event(cycle, t_s, source, kind, detail, reaction)
        self.events.append(e)
        log.log(level, "%s", e)
        return e

    def of_kind(self, kind: str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]

    def __iter__(self):
        return iter(self.events)

    def __len__(self) -> int:
        return len(self.events)
