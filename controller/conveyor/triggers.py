"""The trigger ring buffer of a robot (docs/spec/conveyor.md#5.1).

"The trigger values will be stored in a ring buffer ... with additional information indicating
the relevant Moving Frame for each value entered.  The ring buffer is an element of robot."

- Each entry (:class:`TriggerEntry`, one item) is tagged with its moving frame's name and holds
  the master source values at the trigger (one per DOF, source units), the radius offset dR
  [mm] (rotary frames) and the window direction flag.
- ``TRIGGER <robot> {NDOF = <index> Value = <value>} {MasterFrame = <MovingFrame>}`` and
  ``NEXTITEM <robot> {MasterFrame = <MovingFrame>}`` are
  :meth:`controller.conveyor.robot.RobotGroup.trigger` / ``.nextitem``; which frame an entry
  belongs to is resolved there (an error when none is named and the robot is engaged to
  several frames).
- An entry for a frame not linked to the robot is kept, marked (``linked = False``).
- NEXTITEM works on the entries of its frame only; entries of other frames are skipped (kept).
- ``slave = 0`` deletes every entry (:meth:`TriggerBuffer.clear`).
- A full buffer rejects the new entry with :class:`TriggerBufferFull`: never a silent drop.
- Item types ("you can classify objects in the working frame and only track certain types of
  objects"): an entry carries ``item_type`` (an integer 0...255, 0 by default) and optional
  ``attributes``; :meth:`TriggerBuffer.current` / :meth:`TriggerBuffer.nextitem` take the
  set of tracked types and skip (keep) entries of other types.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
from ..tracking.values import as_stored, mypyc_attr, python_class
from typing import AbstractSet, Iterator

from ..errors import ParameterError
from .location import Location
from .errors import TriggerBufferFull


@python_class
@dataclass(frozen=True, slots=True)
class TriggerEntry:
    """One item: ``frame`` (name), ``values`` per DOF [source units], ``dr_mm``, ``inverse``.

    ``id``: running number per robot; ``sample``: the robot sample of the TRIGGER command;
    ``linked``: whether the frame was linked to the robot when the entry was made;
    ``item_type``: the item's class (0...255); ``attributes``: (name, value) pairs the sensor
    gave with it (e.g. ``(("height_mm", 42.0),)``), kept for the program.
    """

    id: int
    frame: str
    values: tuple[float, ...]
    dr_mm: float = 0.0
    inverse: bool = False
    sample: int = 0
    linked: bool = True
    item_type: int = 0
    attributes: tuple[tuple[str, float | str], ...] = ()
    #: group frames (type 3): the item's full location at the trigger, W0 (world)
    zero: Location | None = None

    def attribute(self, name: str, default: float | str | None = None) -> float | str | None:
        """The value of attribute ``name`` (``default`` if the trigger did not give it)."""
        for k, v in self.attributes:
            if k == name:
                return v
        return default

    def with_(self, **changes) -> "TriggerEntry":
        return replace(self, **changes)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class TriggerBuffer:
    """A bounded FIFO of :class:`TriggerEntry` (``capacity`` entries)."""

    def __init__(self, capacity: int = 32, owner: str = "robot") -> None:
        if int(as_stored(capacity)) != as_stored(capacity) or capacity < 1:
            raise ParameterError(f"trigger buffer capacity (={capacity!r}) must be an "
                                 "integer >= 1")
        self.capacity = int(capacity)
        self.owner = owner
        self._entries: deque[TriggerEntry] = deque()

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[TriggerEntry]:
        return iter(tuple(self._entries))

    @property
    def full(self) -> bool:
        return len(self._entries) >= self.capacity

    def add(self, entry: TriggerEntry) -> TriggerEntry:
        if self.full:
            raise TriggerBufferFull(
                f"robot {self.owner!r}: trigger buffer full ({self.capacity} entries); the "
                f"trigger of frame {entry.frame!r} (values {entry.values!r}) is rejected - "
                "take items with NEXTITEM or enlarge the buffer")
        self._entries.append(entry)
        return entry

    def entries(self, frame: str | None = None) -> tuple[TriggerEntry, ...]:
        """Entries (oldest first), only those of ``frame`` if given."""
        return tuple(e for e in self._entries if frame is None or e.frame == frame)

    def current(self, frame: str, types: AbstractSet[int] | None = None
                ) -> TriggerEntry | None:
        """The oldest entry of ``frame`` of a type in ``types`` (None: any type), or None."""
        for e in self._entries:
            if e.frame == frame and (types is None or e.item_type in types):
                return e
        return None

    def nextitem(self, frame: str, types: AbstractSet[int] | None = None
                 ) -> TriggerEntry | None:
        """Delete the oldest entry of ``frame`` of a tracked type (skipping other frames' and
        other types'); returns it or None."""
        e = self.current(frame, types)
        if e is not None:
            self._entries.remove(e)
        return e

    def remove(self, entry: TriggerEntry) -> bool:
        try:
            self._entries.remove(entry)
            return True
        except ValueError:
            return False

    def drop_untracked_before(self, entry: TriggerEntry, types: AbstractSet[int]
                              ) -> list[TriggerEntry]:
        """Delete the entries of ``entry``'s frame with a type not in ``types`` that are
        older than ``entry`` (triggered before it, so further on the belt: the robot will
        never track them); returns them."""
        out = [e for e in self._entries if e.frame == entry.frame and e.id < entry.id
               and e.item_type not in types]
        for e in out:
            self._entries.remove(e)
        return out

    def clear(self) -> int:
        """Delete every entry (``slave = 0``); returns how many were deleted."""
        n = len(self._entries)
        self._entries.clear()
        return n
