"""Deterministic record and replay of encoder counts and triggers (an extension of the softMC
model, docs/spec/conveyor.md#1).

A run of a :class:`controller.conveyor.cell.ConveyorCell` is a pure function of its inputs:
the raw encoder counts per sample and the commands given between samples.  This module
writes and reads those inputs as two CSV files and replays them:

- encoder log: ``sample, time_s, <source name>...`` - one row per sample (from 0), the raw
  counts each :class:`controller.conveyor.sources.EncoderSource` read
  (:attr:`EncoderSource.log`);
- trigger log: ``sample, robot, frame, values, dr_mm, inverse`` - one row per TRIGGER,
  given after step ``sample`` (``values``: the latched master values, ``;``-separated, exact
  ``repr`` floats).

:func:`replay` rebuilds nothing itself: the caller builds the cell with
``EncoderSource(counts=log[name])`` sources and hands the trigger events over; the outputs
then equal the recorded run's bit for bit (tested).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from ..errors import ConfigError
from ..tracking.values import python_class
from .cell import ConveyorCell
from .robot import RobotOutput


@python_class
@dataclass(frozen=True, slots=True)
class TriggerEvent:
    """A TRIGGER given after step ``sample``."""

    sample: int
    robot: str
    frame: str
    values: tuple[float, ...] | None = None
    dr_mm: float = 0.0
    inverse: bool = False
    #: the item type (0...255)
    item_type: int = 0
    #: the line of the trigger log it was read from (None: not read from a file)
    line: int | None = field(default=None, compare=False, repr=False)


def write_encoder_log(path: str | Path, sample_time_s: float,
                      logs: dict[str, Sequence[int]]) -> Path:
    path = Path(path)
    names = list(logs)
    n = min(len(v) for v in logs.values()) if logs else 0
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["sample", "time_s"] + names)
        for k in range(n):
            w.writerow([k, repr(round(k * sample_time_s, 12))] + [int(logs[c][k]) for c in names])
    return path


def read_encoder_log(path: str | Path) -> dict[str, list[int]]:
    """{source name: raw counts per sample}.  Rows must be samples 0, 1, 2, ... in order."""
    path = Path(path)
    rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigError("the encoder log is empty (expected a header row)", file=str(path),
                          line=1)
    header = [c.strip() for c in rows[0]]
    if header[:2] != ["sample", "time_s"] or len(header) < 3:
        raise ConfigError("header must be: sample, time_s, <source name>...", file=str(path),
                          line=1, key=header[0] if header else None)
    out: dict[str, list[int]] = {c: [] for c in header[2:]}
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise ConfigError(f"expected {len(header)} values, got {len(r)}", file=str(path),
                              line=i)
        try:
            k = int(r[0])
        except ValueError:
            raise ConfigError(f"not an integer: {r[0]!r}", file=str(path), line=i,
                              key="sample") from None
        if k != i - 2:
            raise ConfigError(f"sample {k} out of order (expected {i - 2})", file=str(path),
                              line=i, key="sample")
        for c, cell in zip(header[2:], r[2:]):
            try:
                out[c].append(int(cell))
            except ValueError:
                raise ConfigError(f"not an integer count: {cell!r}", file=str(path), line=i,
                                  key=c) from None
    return out


def write_trigger_log(path: str | Path, events: Sequence[TriggerEvent]) -> Path:
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        typed = any(e.item_type for e in events)   # the type column only when used
        w.writerow(list(TRIGGER_LOG_COLUMNS) + (["type"] if typed else []))
        for e in events:
            vals = "" if e.values is None else ";".join(repr(float(v)) for v in e.values)
            w.writerow([e.sample, e.robot, e.frame, vals, repr(float(e.dr_mm)), int(e.inverse)]
                       + ([e.item_type] if typed else []))
    return path


TRIGGER_LOG_COLUMNS = ("sample", "robot", "frame", "values", "dr_mm", "inverse")
#: the optional last column: the item type
TRIGGER_LOG_TYPE = "type"


def read_trigger_log(path: str | Path) -> list[TriggerEvent]:
    """The TRIGGERs of a trigger log (:func:`write_trigger_log`), each with its ``line``.

    A bad row raises :class:`ConfigError` naming the file, the line and the column (key).
    Check the robot and frame columns against a cell with :func:`check_trigger_log`.
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    rows = [(i, r) for i, r in enumerate(csv.reader(lines), start=1)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    expected = list(TRIGGER_LOG_COLUMNS)
    header = [c.strip() for c in rows[0][1]] if rows else []
    if header == expected + [TRIGGER_LOG_TYPE]:
        expected = header
    if header != expected:
        raise ConfigError(f"header must be: {', '.join(expected)}[, {TRIGGER_LOG_TYPE}]",
                          file=str(path), line=rows[0][0] if rows else 1)
    out = []
    prev = 0
    for i, r in rows[1:]:
        if len(r) != len(expected):
            raise ConfigError(f"expected {len(expected)} values ({', '.join(expected)}), got "
                              f"{len(r)}", file=str(path), line=i)

        def bad(col: str, what: str, i=i) -> ConfigError:
            return ConfigError(what, file=str(path), line=i, key=col)
        cell = dict(zip(expected, (c.strip() for c in r)))
        try:
            sample = int(cell["sample"])
        except ValueError:
            raise bad("sample", f"not an integer: {cell['sample']!r}") from None
        if sample < prev:
            raise bad("sample", f"sample {sample} is before the previous row's ({prev}): "
                                "rows must be in sample order")
        prev = sample
        for col in ("robot", "frame"):
            if not cell[col]:
                raise bad(col, "empty name")
        try:
            vals = tuple(float(x) for x in cell["values"].split(";")) if cell["values"] \
                else None
        except ValueError:
            raise bad("values", f"not a ';'-separated list of numbers: "
                                f"{cell['values']!r}") from None
        try:
            dr = float(cell["dr_mm"])
        except ValueError:
            raise bad("dr_mm", f"not a number: {cell['dr_mm']!r}") from None
        if cell["inverse"] not in ("0", "1"):
            raise bad("inverse", f"must be 0 or 1, got {cell['inverse']!r}")
        item_type = 0
        if TRIGGER_LOG_TYPE in cell:
            t = cell[TRIGGER_LOG_TYPE]
            if not (t.isdigit() and 0 <= int(t) <= 255):
                raise bad(TRIGGER_LOG_TYPE, f"must be an integer in [0...255], got {t!r}")
            item_type = int(t)
        out.append(TriggerEvent(sample, cell["robot"], cell["frame"], vals, dr,
                                cell["inverse"] == "1", item_type, line=i))
    return out


def check_trigger_log(events: Sequence[TriggerEvent], robots: Sequence[str],
                      frames: Sequence[str], path: str | Path | None = None) -> None:
    """Every TRIGGER's robot and frame must be one of ``robots`` / ``frames`` (the names of
    the cell it is replayed on): else :class:`ConfigError` naming file, line and column."""
    file = None if path is None else str(path)
    for e in events:
        for col, name, names, what in (("robot", e.robot, robots, "robot group"),
                                       ("frame", e.frame, frames, "moving frame")):
            if name not in names:
                raise ConfigError(
                    f"{what} {name!r} is not in the scenario (expected "
                    f"{' or '.join(repr(n) for n in names)})", file=file, line=e.line,
                    key=col)


def replay(cell: ConveyorCell, triggers: Sequence[TriggerEvent], n_samples: int,
           on_sample: Callable[[ConveyorCell, dict[str, RobotOutput]], None] | None = None
           ) -> list[dict[str, RobotOutput]]:
    """Step ``cell`` ``n_samples`` times, giving each TRIGGER after its sample.

    ``on_sample(cell, outputs)`` runs after every step (e.g. a robot program; it must be
    deterministic too).  Triggers for sample 0 are given before the first step.  A TRIGGER
    naming a robot or frame the cell does not have raises :class:`ConfigError` (before the
    first step).
    """
    check_trigger_log(triggers, [r.name for r in cell.robots], [f.name for f in cell.frames])
    by_sample: dict[int, list[TriggerEvent]] = {}
    for e in triggers:
        by_sample.setdefault(e.sample, []).append(e)
    frames = {f.name: f for f in cell.frames}
    outputs = []

    def give(k: int) -> None:
        for e in by_sample.get(k, ()):
            cell.robot(e.robot).trigger(frames.get(e.frame, e.frame), values=e.values,
                                        dr_mm=e.dr_mm, inverse=e.inverse,
                                        item_type=e.item_type)

    give(cell.k)
    for _ in range(n_samples):
        out = cell.step()
        outputs.append(out)
        if on_sample is not None:
            on_sample(cell, out)
        give(cell.k)
    return outputs
