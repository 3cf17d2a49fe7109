"""Output files of long runs: written as things happen, flushed, rotated with retention.

Two writers, one rotation rule (python-can's :class:`can.SizedRotatingLogger` is the model,
its file naming kept: ``bus.log`` is rotated to ``bus_<date>T<time>_#001.log``):

- :class:`BusLog`: a python-can ``SizedRotatingLogger`` (any format it writes: ``.log``,
  ``.asc``, ``.csv``, ``.blf``, ``.txt``) that also rotates by time (``max_age_s`` of message
  time, i.e. machine time in stepped runs), keeps at most ``keep`` rotated files (python-can
  keeps all: a week-long run would fill the disk) and flushes the line-based formats at least
  every ``flush_s`` of wall time, so that a SIGKILL loses at most that second and leaves at
  most the last line incomplete;
- :class:`JsonLines`: the same for JSON lines (telemetry): one strict-JSON object per line,
  flushed every ``flush_s`` and on :meth:`JsonLines.flush` (e.g. at every item).

Options as python-can's ``can.logger`` names them: ``--file_size`` (max bytes; also spelled
``--file-size``), and ours: ``--file-time`` (max seconds per file), ``--keep`` (rotated files
kept); see :func:`add_arguments`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from datetime import datetime
from pathlib import Path
from typing import Any, TextIO

import can

from .files import json_safe

#: flush at least this often [s of wall time]
FLUSH_S = 1.0


def add_arguments(p: argparse.ArgumentParser, what: str = "bus.log and telemetry") -> None:
    """``--file-size``/``--file_size``, ``--file-time``, ``--keep`` (see the module doc)."""
    g = p.add_argument_group("output rotation")
    g.add_argument("-s", "--file-size", "--file_size", dest="file_size", type=_size,
                   default=0, metavar="BYTES",
                   help=f"rotate {what} when a file reaches this size (as can.logger's "
                        "--file_size; 0 = never; suffixes k, M, G)")
    g.add_argument("--file-time", dest="file_time", type=_seconds, default=0.0, metavar="S",
                   help=f"rotate {what} after this many seconds of (machine) time per file "
                        "(0 = never)")
    g.add_argument("--keep", type=_count, default=None, metavar="N",
                   help="rotated files kept per output (older ones are deleted; default: all)")


def _size(text: str) -> int:
    m = re.fullmatch(r"\s*(\d+)\s*([kKmMgG]?)[bB]?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size in bytes (e.g. 50000000, "
                                         "50M)")
    return int(m.group(1)) * {"": 1, "k": 10 ** 3, "m": 10 ** 6, "g": 10 ** 9}[
        m.group(2).lower()]


def _seconds(text: str) -> float:
    from ...errors import ConfigError  # noqa: F401 (argparse reports the type error)
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (v >= 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number >= 0")
    return v


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be >= 0")
    return v


def rotated_name(base: Path, count: int) -> Path:
    """python-can's rotated name: ``<stem>_<date>T<time>_#<count><suffixes>``."""
    return base.parent / (base.name.split(".")[0] + "_" + datetime.now().strftime(
        "%Y-%m-%dT%H%M%S") + f"_#{count:03}" + "".join(base.suffixes[-2:]))


def rotated_files(base: Path) -> list[Path]:
    """The rotated files of ``base``, oldest first (by their rollover count)."""
    stem = base.name.split(".")[0]
    suffix = "".join(base.suffixes[-2:])
    pat = re.compile(re.escape(stem) + r"_\d{4}-\d\d-\d\dT\d{6}_#(\d+)" + re.escape(suffix)
                     + "$")
    found = []
    if base.parent.is_dir():
        for p in base.parent.iterdir():
            m = pat.match(p.name)
            if m:
                found.append((int(m.group(1)), p))
    return [p for _, p in sorted(found)]


def _retain(base: Path, keep: int | None) -> None:
    if keep is None:
        return
    old = rotated_files(base)
    for p in old[:max(0, len(old) - keep)]:
        try:
            p.unlink()
        except FileNotFoundError:
            pass


class BusLog(can.SizedRotatingLogger):
    """python-can's rotating logger + time rotation, retention and periodic flushes."""

    def __init__(self, base_filename: str | Path, max_bytes: int = 0, *,
                 max_age_s: float = 0.0, keep: int | None = None,
                 flush_s: float = FLUSH_S) -> None:
        super().__init__(base_filename, max_bytes=max_bytes)
        self.max_age_s = float(max_age_s)
        self.keep = keep
        self.flush_s = flush_s
        self._file_t0: float | None = None
        self._next_flush = time.monotonic() + flush_s

    def should_rollover(self, msg: can.Message) -> bool:
        if self._file_t0 is None:
            self._file_t0 = msg.timestamp
        if self.max_age_s > 0 and msg.timestamp - self._file_t0 >= self.max_age_s:
            return True
        return super().should_rollover(msg)

    def do_rollover(self) -> None:
        super().do_rollover()
        self._file_t0 = None
        _retain(Path(self.base_filename), self.keep)

    def on_message_received(self, msg: can.Message) -> None:
        super().on_message_received(msg)
        now = time.monotonic()
        if now >= self._next_flush:
            self._next_flush = now + self.flush_s
            self.flush()

    def flush(self) -> None:
        """Push what is buffered to the OS (a SIGKILL then loses nothing before it)."""
        f = getattr(self.writer, "file", None)
        if f is not None and not getattr(f, "closed", True):
            try:
                f.flush()
            except (OSError, ValueError):  # pragma: no cover - a closed or full file
                pass


class JsonLines:
    """JSON-lines output with the rotation of :class:`BusLog` (see the module doc).

    :meth:`write` takes a dict (``type`` first by convention) and the machine time [s] it
    belongs to (for time rotation); non-finite floats are written as null (strict JSON).
    """

    def __init__(self, path: str | Path, max_bytes: int = 0, *, max_age_s: float = 0.0,
                 keep: int | None = None, flush_s: float = FLUSH_S,
                 header: dict | None = None) -> None:
        self.path = Path(path).absolute()
        self.max_bytes = int(max_bytes)
        self.max_age_s = float(max_age_s)
        self.keep = keep
        self.flush_s = flush_s
        #: written again at the top of every new file (a rotated file reads on its own)
        self.header = header
        self.rollover_count = 0
        self.lines = 0
        self._file: TextIO | None = None
        self._open()

    def _open(self) -> None:
        self._file = open(self.path, "w", encoding="utf-8")  # noqa: SIM115 (kept open)
        self._size = 0
        self._t0: float | None = None
        self._next_flush = time.monotonic() + self.flush_s
        if self.header is not None:
            self._write_line(self.header)

    def _write_line(self, record: dict[str, Any]) -> None:
        line = json.dumps(json_safe(record), allow_nan=False, default=str) + "\n"
        assert self._file is not None
        self._file.write(line)
        self._size += len(line)
        self.lines += 1

    def write(self, record: dict[str, Any], t_s: float | None = None) -> None:
        if self._file is None:
            raise ValueError(f"{self.path}: written after close")
        if t_s is not None:
            if self._t0 is None:
                self._t0 = t_s
            elif self.max_age_s > 0 and t_s - self._t0 >= self.max_age_s:
                self.rotate()
                self._t0 = t_s
        if self.max_bytes > 0 and self._size >= self.max_bytes:
            self.rotate()
        self._write_line(record)
        now = time.monotonic()
        if now >= self._next_flush:
            self._next_flush = now + self.flush_s
            self._file.flush()

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def rotate(self) -> None:
        """Close this file, rename it the python-can way, start a new one, keep ``keep``."""
        assert self._file is not None
        self._file.close()
        os.replace(self.path, rotated_name(self.path, self.rollover_count))
        self.rollover_count += 1
        _retain(self.path, self.keep)
        self._open()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    @property
    def closed(self) -> bool:
        return self._file is None

    def __enter__(self) -> JsonLines:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
