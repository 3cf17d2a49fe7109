"""Errors of the conveyor model (subclasses of the project's hierarchy in controller.errors).

Commands (``TRIGGER``, ``<robot>.MasterFrame = ...``, ``<MF>.type = ...``) raise these at the
edge; the per-sample ``update()`` never raises: it reports outcomes as event and error codes
(``controller.tracking.TrackError``; softMC's "Item missed" is :data:`ITEM_MISSED_CODE`).
"""

from __future__ import annotations

from ..errors import ParameterError, StateError

#: softMC error number of "Item missed..." (docs/spec/conveyor.md#7)
ITEM_MISSED_CODE = 30238


class ArcGeometryError(ParameterError):
    """The three points of a rotary moving frame do not define an arc (collinear/coincident).

    Raised where softMC raises it (docs/spec/conveyor.md#3.4.1): when
    ``<MF>.center`` is queried while the frame is not linked to any robot, and when the frame
    is assigned to ``<robot>.MasterFrame``.
    """


class FrameBusyError(StateError):
    """A moving frame cannot be engaged now (engaged by another robot, or still de-syncing)."""


class TooManyFramesError(StateError):
    """A third moving frame given to a robot that follows two (docs/spec/conveyor.md#9.3)."""


class TriggerBufferFull(StateError):
    """The robot's trigger ring buffer is full: the trigger is rejected, never dropped."""


class NoFrameError(StateError):
    """A command needs a moving frame and none was named (or the name is ambiguous)."""
