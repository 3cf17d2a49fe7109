"""Validated readers shared by the scenario files of ``cantrack simulate`` (tracking,
conveyor and cell scenarios): a mapping node with file, line and dotted key path, numbers
with ranges and units, the tracker parameters, the segment master and the sampled-run base.

The YAML itself is read by :mod:`controller.yamlmarks`, and so are its marks: the lines of
keys, values and list items (``key_line``, ``value_line``, ``item_lines``) and the closest
known key of a misspelt one (``closest``) come from there, as for bus.yml.  Every problem
is a :class:`controller.errors.ConfigError` naming the file, the line and the key.  Public
names are used by :mod:`.scenario`, :mod:`.conveyor` and :mod:`.cell`; none of those
imports another's private names.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from ..errors import ConfigError, ParameterError
from ..yamlmarks import closest, is_marked, item_lines, key_line, value_line
from ..tracking import PLANNERS, Limits, Mode, Rates, SoftMcOptions, TrackerParams
from ..tracking.types import DEFAULT_ROT, DEFAULT_TRANS

__all__ = ["MAX_POSITION_MM", "MAX_SAMPLES", "MISSING", "Ctx", "CsvMaster", "EncoderSpec",
           "Node", "SampledRun", "Segment", "SegmentMaster", "check_number", "describe",
           "segment_master", "tracker_params", "unit_vector"]

#: upper bound on duration_s / sample_time_s (a typo should not run for hours)
MAX_SAMPLES = 1_000_000

_MISSING: Any = object()




# -- validated values --------------------------------------------------------------------
def _range_text(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if hi is None:
        return f"> {lo:g}" if lo_open else f">= {lo:g}"
    if lo is None:
        return f"< {hi:g}" if hi_open else f"<= {hi:g}"
    return f"in {'(' if lo_open else '['}{lo:g}...{hi:g}{')' if hi_open else ']'}"


#: the largest |coordinate| of a position in a scenario [mm] (1 km; also for angles [deg])
MAX_POSITION_MM = 1e6


class _Node:
    """A mapping under validation: its values, the lines of its keys and its dotted path."""

    def __init__(self, ctx: "_Ctx", value: Any, path: str, line: int | None) -> None:
        self.ctx = ctx
        self.path = path
        if not isinstance(value, dict):
            raise ctx.error(f"must be a mapping of keys, got {_describe(value)}",
                            line if line is not None or path else 1, path or None)
        self.m = value
        #: the line of the section's key (or list item), else where the mapping starts
        self.line = line if line is not None else getattr(value, "line", None)

    def key(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def line_of(self, key: str) -> int | None:
        return value_line(self.m, key, self.line)

    def error(self, key: str, message: str) -> ConfigError:
        return self.ctx.error(message, self.line_of(key), self.key(key))

    def check_keys(self, allowed: Iterable[str]) -> None:
        allowed = list(allowed)
        for k in self.m:
            if k in allowed:
                continue
            close = closest(k, allowed)
            hint = f"; did you mean '{close}'?" if close else ""
            where = f"'{self.path}'" if self.path else "the scenario"
            raise self.ctx.error(
                f"unknown key in {where}{hint} (valid keys: {', '.join(allowed)})",
                key_line(self.m, k, self.line), self.key(str(k)))

    def _from_file(self) -> bool:
        return is_marked(self.m)

    def has(self, key: str) -> bool:
        # a file's `key:` left empty (null) is there, to be refused by raw(); in a mapping
        # given from Python, None means "not given"
        return key in self.m and (self.m[key] is not None or self._from_file())

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        if key in self.m and self.m[key] is None and self._from_file():
            # (not the default: a value the user left empty is a mistake to name)
            raise self.error(key, "has no value (empty or null): give one or delete the key")
        if key in self.m and self.m[key] is not None:
            return self.m[key]
        if default is _MISSING:
            where = f"'{self.path}'" if self.path else "the scenario"
            raise self.ctx.error(f"required key missing in {where}", self.line, self.key(key))
        return default

    def number(self, key: str, default: Any = _MISSING, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
               unit: str = "", integer: bool = False) -> Any:
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if unit in ("mm", "deg") and lo is None and hi is None:
            lo, hi = -MAX_POSITION_MM, MAX_POSITION_MM  # (a position or an angle)
        return _check_number(value, lambda msg: self.error(key, msg), lo=lo, hi=hi,
                             lo_open=lo_open, hi_open=hi_open, unit=unit, integer=integer)

    def boolean(self, key: str, default: Any = _MISSING) -> Any:
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {_describe(value)}")
        return value

    def string(self, key: str, default: Any = _MISSING) -> Any:
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {_describe(value)}")
        return value

    def vector(self, key: str, default: Any = _MISSING, *, unit: str = "") -> Any:
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list) or len(value) != 3:
            raise self.error(key, f"must be a list of 3 numbers [x, y, z]{_unit(unit)}, "
                                  f"got {_describe(value)}")
        # a position is within MAX_POSITION_MM of the origin (1e300 would overflow the
        # planners' arithmetic; no cell is larger than a kilometre)
        bound = MAX_POSITION_MM if unit == "mm" else None
        return tuple(_check_number(v, lambda msg, i=i: self.error(key, f"item {i}: {msg}"),
                                   lo=None if bound is None else -bound, hi=bound, unit=unit)
                     for i, v in enumerate(value))

    def section(self, key: str, required: bool = False) -> "_Node | None":
        if not self.has(key):
            if required:
                self.raw(key)
            return None
        return _Node(self.ctx, self.m[key], self.key(key), key_line(self.m, key, self.line))

    def items(self, key: str) -> list[tuple[Any, int | None, str]]:
        """The items of a list value: (value, line, path)."""
        value = self.raw(key)
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, got {_describe(value)}")
        lines = item_lines(value, self.line_of(key))
        return [(v, ln, f"{self.key(key)}[{i}]") for i, (v, ln) in enumerate(zip(value, lines))]


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _describe(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return f"{value!r} ({type(value).__name__})"


def _check_number(value: Any, fail, *, lo=None, hi=None, lo_open=False, hi_open=False,
                  unit="", integer=False) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if integer else "a number"
        raise fail(f"must be {kind}{_unit(unit)}, got {_describe(value)}")
    if not math.isfinite(value):
        raise fail(f"must be a finite number, got {value!r}")
    if integer and int(value) != value:
        raise fail(f"must be an integer, got {value!r}")
    if (lo is not None and (value < lo or (lo_open and value == lo))) or \
            (hi is not None and (value > hi or (hi_open and value == hi))):
        raise fail(f"value {value!r} is out of range: must be "
                   f"{_range_text(lo, hi, lo_open, hi_open)}{_unit(unit)}")
    return int(value) if integer else float(value)


@dataclass
class _Ctx:
    file: str
    base_dir: Path

    def error(self, message: str, line: int | None, key: str | None) -> ConfigError:
        return ConfigError(message, file=self.file, line=line, key=key)


# -- the scenario ------------------------------------------------------------------------
@dataclass(frozen=True)
class Segment:
    """One master segment.  ``kind``: velocity | acceleration | speed_change | hold.

    ``direction`` is a unit vector; ``value`` the velocity [mm/s] or acceleration [mm/s^2];
    for a speed change ``to`` [mm/s], ``acc`` [mm/s^2], ``jerk`` [mm/s^3].  ``duration_s`` is
    None for a speed change without an explicit duration (its own duration is used).
    ``c_rate`` [deg/s] is None when the segment keeps the previous rate.
    """

    kind: str
    duration_s: float | None
    direction: tuple[float, float, float]
    value: float = 0.0
    to: float = 0.0
    acc: float = 0.0
    jerk: float = 0.0
    c_rate: float | None = None
    line: int | None = None
    path: str = ""
    #: 1-based lines of the segment's keys (for error messages)
    key_lines: dict = dataclasses.field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class SegmentMaster:
    """A master made of segments, starting at ``position`` [mm] / ``c`` [deg] at t = 0."""

    position: tuple[float, float, float]
    c: float
    initial_speed: float
    initial_direction: tuple[float, float, float]
    c_rate: float
    segments: tuple[Segment, ...]


@dataclass(frozen=True)
class CsvMaster:
    """A master sampled in a CSV file.  Arrays: times [s], positions [mm], angles [deg];
    velocities/accelerations None where the file does not give them (then estimated)."""

    path: Path
    time_s: tuple[float, ...]
    pos: tuple[tuple[float, float, float], ...]
    ang: tuple[float, ...]
    vel: tuple[tuple[float, float, float], ...] | None
    ang_vel: tuple[float, ...] | None
    acc: tuple[tuple[float, float, float], ...] | None
    ang_acc: tuple[float, ...] | None
    window: int


@dataclass(frozen=True)
class EncoderSpec:
    """The encoder + estimator path in front of the tracker (``estimator:`` section)."""

    quantisation_mm: float = 0.0
    quantisation_deg: float = 0.0
    delay_samples: int = 1
    window: int = 16
    lead_samples: float = 1.0
    degree: int = 2


class SampledRun:
    """Sample time and length of a scenario with ``params`` (TrackerParams) and
    ``duration_s`` (shared by the tracking and the conveyor scenarios)."""

    @property
    def sample_time_s(self) -> float:
        return self.params.sample_time_s

    @property
    def n_samples(self) -> int:
        """Number of updates N (the trace has N + 1 rows)."""
        return max(1, round(self.duration_s / self.params.sample_time_s))



_PARAM_FIELDS = {f.name: f for f in dataclasses.fields(TrackerParams)}
_LIMIT_KEYS = ("robot_max_trans", "robot_max_rot", "sync_trans", "desync_trans", "sync_rot",
               "desync_rot", "master_max_trans", "master_max_rot")
_SOFTMC_KEYS = ("literal",) + tuple(f.name for f in dataclasses.fields(SoftMcOptions))
_MODES = {"absolute": Mode.ABSOLUTE, "relative": Mode.RELATIVE}
_PARAM_MSG = re.compile(r"^(?:limit |rate )?(\w+) \(=")


def _param_error(node: _Node, exc: ParameterError, fields: Iterable[str]) -> ConfigError:
    """A core ParameterError located at the value it names (else at the section)."""
    m = _PARAM_MSG.match(str(exc))
    name = m.group(1) if m else None
    if name in fields and node.has(name):
        return node.error(name, str(exc))
    return node.ctx.error(str(exc), node.line, node.path or None)


def _limits(node: _Node, key: str, default: Limits | None) -> Limits | None:
    sec = node.section(key)
    if sec is None:
        return default
    sec.check_keys(("vel", "acc", "jerk"))
    unit = "deg" if key.endswith("_rot") else "mm"
    units = {"vel": f"{unit}/s", "acc": f"{unit}/s^2", "jerk": f"{unit}/s^3"}
    values = {}
    for f in ("vel", "acc", "jerk"):
        dflt = getattr(default, f) if default is not None else _MISSING
        values[f] = sec.number(f, dflt, unit=units[f])
    try:
        return Limits(**values)
    except ParameterError as exc:
        raise _param_error(sec, exc, ("vel", "acc", "jerk")) from exc


def _tracker_params(node: _Node) -> TrackerParams:
    node.check_keys(_PARAM_FIELDS)
    kw: dict[str, Any] = {}
    kw["sample_time_s"] = node.number("sample_time_s", unit="s")
    planner = node.string("planner")
    if planner not in PLANNERS:
        close = closest(planner, PLANNERS)
        hint = f"; did you mean '{close}'?" if close else ""
        raise node.error("planner", f"unknown planner {planner!r}{hint} "
                                    f"(one of {', '.join(sorted(PLANNERS))})")
    module = PLANNERS[planner].split(":")[0]
    if importlib.util.find_spec(module) is None:
        raise node.error("planner", f"planner {planner!r} is not available in this "
                                    f"installation (module {module} not found)")
    kw["planner"] = planner
    if node.has("mode"):
        mode = node.raw("mode")
        if isinstance(mode, str) and mode.lower() in _MODES:
            kw["mode"] = _MODES[mode.lower()]
        elif isinstance(mode, int) and not isinstance(mode, bool) and mode in (3, 5):
            kw["mode"] = Mode(mode)
        else:
            raise node.error("mode", f"must be 3 | 5 | absolute | relative, got {_describe(mode)}")
    for key in _LIMIT_KEYS:  # robot_max_* first: the sync/de-sync values start at them
        default = _PARAM_FIELDS[key].default
        if key in ("sync_trans", "desync_trans"):
            default = kw.get("robot_max_trans", DEFAULT_TRANS)
        elif key in ("sync_rot", "desync_rot"):
            default = kw.get("robot_max_rot", DEFAULT_ROT)
        if node.has(key):
            kw[key] = _limits(node, key, default if isinstance(default, Limits) else None)
    rates = node.section("rates")
    if rates is not None:
        rates.check_keys(("vel", "acc", "dec", "jerk"))
        values = {k: rates.number(k, 100.0, unit="%") for k in ("vel", "acc", "dec", "jerk")}
        try:
            kw["rates"] = Rates(**values)
        except ParameterError as exc:
            raise _param_error(rates, exc, values) from exc
    for key, unit in (("filter_factor", ""), ("damping_factor", ""), ("max_flops_time_s", "s"),
                      ("approach_timeout_s", "s")):
        if node.has(key):
            kw[key] = node.number(key, unit=unit)
    if node.has("max_flops"):
        kw["max_flops"] = node.number("max_flops", integer=True)
    if node.has("desync_from_current_acceleration"):
        kw["desync_from_current_acceleration"] = node.boolean("desync_from_current_acceleration")
    sm = node.section("softmc")
    if sm is not None:
        sm.check_keys(_SOFTMC_KEYS)
        base = SoftMcOptions.literal() if sm.boolean("literal", False) else SoftMcOptions()
        changes = {k: sm.boolean(k) for k in _SOFTMC_KEYS[1:] if sm.has(k)}
        kw["softmc"] = dataclasses.replace(base, **changes)
    try:
        return TrackerParams(**kw)
    except ParameterError as exc:
        raise _param_error(node, exc, _PARAM_FIELDS) from exc



def _unit_vector(node: _Node, key: str, default: Any) -> tuple[float, float, float]:
    v = node.vector(key, default)
    n = math.hypot(v[0], v[1], v[2])  # (no overflow for components of 1e300)
    if n == 0.0:
        raise node.error(key, "must not be the zero vector")
    return v if n == 1.0 else (v[0] / n, v[1] / n, v[2] / n)


_SEGMENT_KINDS = ("velocity", "acceleration", "speed_change")


def _segment_master(node: _Node) -> SegmentMaster:
    node.check_keys(("position", "c", "direction", "initial_speed", "c_rate", "segments"))
    d = _unit_vector(node, "direction", (1.0, 0.0, 0.0))
    segments: list[Segment] = []
    items = node.items("segments")
    if not items:
        raise node.error("segments", "must list at least one segment")
    for value, line, path in items:
        seg = _Node(node.ctx, value, path, line)
        seg.check_keys(("duration_s", "direction", "c_rate") + _SEGMENT_KINDS)
        kinds = [k for k in _SEGMENT_KINDS if seg.has(k)]
        if len(kinds) > 1:
            raise seg.error(kinds[1], f"a segment has at most one of {', '.join(_SEGMENT_KINDS)}"
                                      f" (this one has {' and '.join(kinds)})")
        kind = kinds[0] if kinds else "hold"
        d = _unit_vector(seg, "direction", d)
        c_rate = seg.number("c_rate", None, unit="deg/s")
        common = dict(direction=d, c_rate=c_rate, line=seg.line, path=path,
                      key_lines=dict(getattr(seg.m, "value_lines", {})))
        if kind == "speed_change":
            sc = seg.section("speed_change")
            sc.check_keys(("to", "acc", "jerk"))
            to = sc.number("to", unit="mm/s")
            acc = sc.number("acc", lo=0.0, lo_open=True, unit="mm/s^2")
            jerk = sc.number("jerk", lo=0.0, lo_open=True, unit="mm/s^3")
            duration = seg.number("duration_s", None, lo=0.0, lo_open=True, unit="s")
            segments.append(Segment(kind, duration, to=to, acc=acc, jerk=jerk, **common))
            continue
        duration = seg.number("duration_s", lo=0.0, lo_open=True, unit="s")
        value = seg.number(kind, unit="mm/s" if kind == "velocity" else "mm/s^2") \
            if kind != "hold" else 0.0
        segments.append(Segment(kind, duration, value=value, **common))
    first = segments[0]
    initial_speed = node.number("initial_speed", first.value if first.kind == "velocity" else 0.0,
                                unit="mm/s")
    c_rate = node.number("c_rate", first.c_rate if first.c_rate is not None else 0.0,
                         unit="deg/s")
    return SegmentMaster(node.vector("position", (0.0, 0.0, 0.0), unit="mm"),
                         node.number("c", 0.0, unit="deg"), initial_speed, first.direction, c_rate,
                         tuple(segments))



# public names (the private ones are this module's own spelling)
MISSING = _MISSING
Node = _Node
Ctx = _Ctx
check_number = _check_number
describe = _describe
tracker_params = _tracker_params
unit_vector = _unit_vector
segment_master = _segment_master
