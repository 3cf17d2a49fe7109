"""The project's exception hierarchy (python-can style).

Exceptions are for the edges (configuration, I/O, CLI).  The per-cycle path of
the tracking core reports outcomes as result/error codes instead
(:class:`controller.tracking.types.TrackError`).
"""

from __future__ import annotations


class CantrackError(Exception):
    """Root of every error raised by cantrack."""


class ConfigError(CantrackError, ValueError):
    """A configuration or scenario file is invalid.

    The message names the file, the line (when known) and the key.
    """

    def __init__(self, message: str, *, file: str | None = None, line: int | None = None,
                 key: str | None = None) -> None:
        self.file = file
        self.line = line
        self.key = key
        where = []
        if file:
            where.append(str(file) + (f":{line}" if line is not None else ""))
        if key:
            where.append(f"key '{key}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)
        self.bare_message = message


class ParameterError(CantrackError, ValueError):
    """A parameter value is out of its allowed range (names value and range)."""


class StateError(CantrackError, RuntimeError):
    """An operation is not allowed in the current state (e.g. changing a frame type while engaged)."""


class CanError(CantrackError):
    """A CANopen/CAN level failure; the message names the node id and object index."""


class CanTimeoutError(CanError, TimeoutError):
    """A CANopen step did not answer in time."""
