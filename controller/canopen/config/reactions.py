"""What the controller does about a disturbance by another actor of the bus.

Where CiA 301/402 leave the reaction to the application (like Lely's error behaviour 1029h,
which says per error class whether the node goes pre-operational, stays, or stops), the
``.tracking.reactions`` section of the bus.yml chooses one :class:`Reaction` per
:class:`Disturbance`; faults of the drives themselves (FAULT state, a drive EMCY, a lost
drive heartbeat, the following-error bit) always stop all drives.

=================  ==========================================================  =========
disturbance        what was seen                                              default
=================  ==========================================================  =========
foreign_nmt        an NMT command (000h) on the bus: another master            quick_stop
foreign_sync       a SYNC the controller did not send: a second producer       quick_stop
node_reset         a configured node's boot-up (00h) while the cycle runs      quick_stop
unknown_node       a heartbeat/boot-up of a node-ID that is not configured     report
io_node_lost       the heartbeat of a slave that is neither drive nor encoder  quick_stop
bad_frame          a frame of wrong length/format on a consumed COB-ID         report
error_passive      the CAN controller error passive (error frame)              report
bus_off            the CAN controller bus-off (error frame)                    quick_stop
=================  ==========================================================  =========
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from types import MappingProxyType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ...yamlmarks import Section


class Reaction(Enum):
    QUICK_STOP = "quick_stop"
    REPORT = "report"

    @property
    def text(self) -> str:
        """The event's reaction text (the run report's ``reaction``)."""
        return "quick stop of all drives" if self is Reaction.QUICK_STOP else "reported"


class Disturbance(Enum):
    FOREIGN_NMT = "foreign_nmt"
    FOREIGN_SYNC = "foreign_sync"
    NODE_RESET = "node_reset"
    UNKNOWN_NODE = "unknown_node"
    IO_NODE_LOST = "io_node_lost"
    BAD_FRAME = "bad_frame"
    ERROR_PASSIVE = "error_passive"
    BUS_OFF = "bus_off"


DEFAULTS: Mapping[Disturbance, Reaction] = MappingProxyType({
    Disturbance.FOREIGN_NMT: Reaction.QUICK_STOP,
    Disturbance.FOREIGN_SYNC: Reaction.QUICK_STOP,
    Disturbance.NODE_RESET: Reaction.QUICK_STOP,
    Disturbance.UNKNOWN_NODE: Reaction.REPORT,
    Disturbance.IO_NODE_LOST: Reaction.QUICK_STOP,
    Disturbance.BAD_FRAME: Reaction.REPORT,
    Disturbance.ERROR_PASSIVE: Reaction.REPORT,
    Disturbance.BUS_OFF: Reaction.QUICK_STOP,
})


@dataclass(frozen=True)
class Reactions:
    """The chosen reaction per disturbance (defaults: :data:`DEFAULTS`)."""

    table: Mapping[Disturbance, Reaction] = field(default_factory=lambda: DEFAULTS)

    def of(self, disturbance: Disturbance) -> Reaction:
        return self.table[disturbance]


def parse_reactions(s: Section) -> Reactions:
    """``.tracking.reactions: {foreign_nmt: quick_stop, bad_frame: report, ...}``."""
    choices = [r.value for r in Reaction]
    table = dict(DEFAULTS)
    for d in Disturbance:
        value = s.str(d.value, DEFAULTS[d].value)
        if value not in choices:
            raise s.error(d.value, f"(={value!r}) must be one of {', '.join(choices)}")
        table[d] = Reaction(value)
    s.finish()
    return Reactions(MappingProxyType(table))
