"""Scenario files of ``cantrack simulate``: loading and validation.

A scenario is a YAML mapping.  Units: mm, mm/s, mm/s^2, mm/s^3 for translation; deg, deg/s,
deg/s^2, deg/s^3 for the rotation channel ``c`` (one angle about the tool axis); s for time.
Keys (``*`` = required)::

    name: "300 mm/s conveyor"        # free text, shown in the summary
    duration_s: 3.0                  # simulated time [s]; default: the end of the master's
                                     # segments, or the last time of its CSV file
    engage*: 0.1                     # time(s) of the engage command [s]: a number or a list
    disengage: [2.5]                 # time(s) of the disengage command [s] (optional)
                                     # lists alternate: engage[0] < disengage[0] < engage[1] ...
    tracker*:                        # exactly the fields of controller.tracking.TrackerParams
      sample_time_s*: 0.002          # [1e-5...0.1] s
      planner*: softmc               # softmc | optimal (controller.tracking.PLANNERS)
      mode: absolute                 # 3 | 5 | absolute | relative
      sync_trans: {vel: 2000, acc: 20000, jerk: 400000}   # Limits; missing (fields) start at
      desync_trans: {...}            #   robot_max_trans, else built-ins: docs/spec/tracking.md#2.5
      sync_rot: {vel: 360, acc: 3600, jerk: 72000}        # deg/s, deg/s^2, deg/s^3
      desync_rot: {...}              #   (robot_max_rot, else 360/3600/72000)
      robot_max_trans: {vel: .., acc: .., jerk: ..}       # optional caps (all three fields)
      robot_max_rot: {...}
      rates: {vel: 100, acc: 100, dec: 100, jerk: 100}    # percent (VRATE, ARATE, DRATE, JRATE)
      filter_factor: 1.0
      damping_factor: 1.0
      max_flops: 10
      max_flops_time_s: 1.0
      approach_timeout_s: 5.0
      master_max_trans: {vel: 1000, acc: 1000, jerk: 1000}   # moving-frame maxima
      master_max_rot: {vel: 100, acc: 100, jerk: 100}
      desync_from_current_acceleration: true
      softmc:                        # SoftMcOptions; ``literal: true`` starts from
        literal: false               #   SoftMcOptions.literal(), the named switches override
        pred_acc_from_master: true
        init_increments_from_state: true
        end_of_sample_feedback: true
        braking_distance_velocity: true
        take_the_middle: true
        unit_consistent_thresholds: true
    robot*:                          # the robot setpoint at t = 0 (before the first update)
      position*: [x, y, z]           # mm
      c: 0                           # deg
      velocity: [0, 0, 0]            # mm/s
      acceleration: [0, 0, 0]        # mm/s^2
      c_rate: 0                      # deg/s
      c_acceleration: 0              # deg/s^2
    master*:                         # the moving frame: either segments ...
      position: [0, 0, 0]            # at t = 0 [mm]
      c: 0                           # at t = 0 [deg]
      direction: [1, 0, 0]           # default direction of the segments (normalised)
      initial_speed: 300             # speed at t = 0 along the direction [mm/s]; default:
                                     #   the first segment's ``velocity``, else 0
      c_rate: 0                      # rotation rate at t = 0 [deg/s]
      segments:                      # one after the other; each has duration_s and at most
        - duration_s: 1.0            #   one of velocity / acceleration / speed_change
          velocity: 300              # constant speed [mm/s] (a step if it differs)
        - duration_s: 0.5
          acceleration: 200          # constant acceleration from the current speed [mm/s^2]
        - speed_change: {to: 500, acc: 1000, jerk: 20000}   # jerk-limited S-curve from the
                                     #   current speed (acceleration 0 at both ends);
                                     #   duration_s defaults to the change's own duration;
                                     #   a longer one holds the target speed afterwards
          direction: [1, 1, 0]       # optional: a new direction (a velocity step if moving)
          c_rate: 10                 # optional: the rotation rate in this segment [deg/s]
                                     # no kind given: keep the current speed
      # ... or a CSV file of samples (path relative to the scenario file):
      csv: master.csv                # header: time_s, x, y, z [, c] [, vx, vy, vz [, vc]]
                                     #   [, ax, ay, az [, ac]]  (units mm, deg, s; aliases
                                     #   t, time, x_mm, y_mm, z_mm, c_deg; # comments)
      window: 16                     # MasterEstimator window for velocities/accelerations
                                     #   the file does not give (lead 0)
    estimator:                       # optional: feed the tracker what an encoder would give
      quantisation_mm: 0.01          # position step of the encoder [mm] (0: none)
      quantisation_deg: 0            # angle step [deg] (0: none)
      delay_samples: 1               # the sample of time k arrives at k + delay
      window: 16                     # MasterEstimator window (>= 3)
      lead_samples: 1                # prediction lead; default: delay_samples
      degree: 2                      # 1 (linear) or 2 (quadratic fit)

Timing: the tracker counts samples k (time k*T).  Row 0 is the robot state before the first
update.  A command at time t acts at sample k = round(t/T): the tracker is told before the
update that computes sample k+1, so sample k is the last sample before the engage (the row 0
of ``controller.tracking.metrics.analyze``).  Times are rounded to the nearest sample.

After its last segment the master keeps its final speed and rotation rate.  Before t = 0
(needed only by the encoder estimator's history) the master moves at its initial speed; a
CSV master holds its first row's values.  A CSV master is interpolated linearly at the sample
times; its first row must be at time <= 0 and its last at or after ``duration_s``.

Conveyor scenarios (a top-level ``conveyor:`` key: a moving frame, items, a robot doing pick
motions) have their own schema, documented in :mod:`controller.simulate.conveyor`.

Errors: every problem is a :class:`controller.errors.ConfigError` naming the file, the line
and the key (dotted path such as ``master.segments[1].velocity``), with the allowed range;
an unknown key suggests the closest valid one.  ``TrackerParams``' own ``ParameterError`` is
re-raised as a ConfigError located at the offending value.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import importlib.util
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from ..errors import ConfigError, ParameterError
from ..yamlmarks import MarkedList, MarkedMap, load_marked, read_text
from ..tracking import PLANNERS, Limits, Mode, MotionState, Rates, SoftMcOptions, TrackerParams
from ..tracking.types import DEFAULT_ROT, DEFAULT_TRANS
from .master import SegmentError, build_profile

__all__ = ["CsvMaster", "EncoderSpec", "Scenario", "Segment", "SegmentMaster", "load_scenario",
           "MAX_SAMPLES"]

#: upper bound on duration_s / sample_time_s (a typo should not run for hours)
MAX_SAMPLES = 1_000_000

_MISSING: Any = object()


# -- YAML with line numbers: the shared loader ------------------------------------------
_Mapping = MarkedMap
_Sequence = MarkedList
_load_yaml = load_marked


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
        lines = getattr(self.m, "value_lines", None)
        if lines and key in lines:
            return lines[key]
        return self.line

    def error(self, key: str, message: str) -> ConfigError:
        return self.ctx.error(message, self.line_of(key), self.key(key))

    def check_keys(self, allowed: Iterable[str]) -> None:
        allowed = list(allowed)
        key_lines = getattr(self.m, "key_lines", {})
        for k in self.m:
            if k in allowed:
                continue
            close = difflib.get_close_matches(str(k), allowed, n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            where = f"'{self.path}'" if self.path else "the scenario"
            raise self.ctx.error(
                f"unknown key in {where}{hint} (valid keys: {', '.join(allowed)})",
                key_lines.get(k, self.line), self.key(str(k)))

    def _from_file(self) -> bool:
        return hasattr(self.m, "key_lines")

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
        key_line = getattr(self.m, "key_lines", {}).get(key, self.line)
        return _Node(self.ctx, self.m[key], self.key(key), key_line)

    def items(self, key: str) -> list[tuple[Any, int | None, str]]:
        """The items of a list value: (value, line, path)."""
        value = self.raw(key)
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, got {_describe(value)}")
        lines = getattr(value, "item_lines", None) or [self.line_of(key)] * len(value)
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


@dataclass(frozen=True)
class Scenario(SampledRun):
    """A validated scenario.  ``engage``/``disengage`` are times [s]; ``*_samples`` the
    sample indices k at which the commands are given (they act on sample k + 1)."""

    params: TrackerParams
    robot: MotionState
    master: SegmentMaster | CsvMaster
    duration_s: float
    engage: tuple[float, ...]
    disengage: tuple[float, ...] = ()
    estimator: EncoderSpec | None = None
    name: str = ""
    source: Path | None = None

    @property
    def engage_samples(self) -> tuple[int, ...]:
        return tuple(round(t / self.params.sample_time_s) for t in self.engage)

    @property
    def disengage_samples(self) -> tuple[int, ...]:
        return tuple(round(t / self.params.sample_time_s) for t in self.disengage)


# -- parsing -----------------------------------------------------------------------------
_TOP_KEYS = ("name", "duration_s", "engage", "disengage", "tracker", "robot", "master",
             "estimator")
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
        close = difflib.get_close_matches(planner, list(PLANNERS), n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
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


def _robot(node: _Node) -> MotionState:
    node.check_keys(("position", "c", "velocity", "acceleration", "c_rate", "c_acceleration"))
    zero = (0.0, 0.0, 0.0)
    return MotionState(node.vector("position", unit="mm"), node.vector("velocity", zero),
                       node.vector("acceleration", zero), node.number("c", 0.0, unit="deg"),
                       node.number("c_rate", 0.0, unit="deg/s"),
                       node.number("c_acceleration", 0.0, unit="deg/s^2"))


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


_CSV_COLUMNS = ("time_s", "x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac")
_CSV_ALIASES = {"t": "time_s", "time": "time_s", "x_mm": "x", "y_mm": "y", "z_mm": "z",
                "c_deg": "c"}


def _csv_master(node: _Node) -> CsvMaster:
    node.check_keys(("csv", "window"))
    name = node.string("csv")
    window = node.number("window", 16, lo=3, hi=10000, integer=True)
    path = Path(name)
    if not path.is_absolute():
        path = node.ctx.base_dir / path
    try:
        text = read_text(path)
    except OSError as exc:
        raise node.error("csv", f"cannot read the master CSV {str(path)!r}: "
                                f"{exc.strerror or exc}") from None
    file = str(path)
    rows = list(csv.reader(text.splitlines()))
    numbered = [(i + 1, r) for i, r in enumerate(rows)
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not numbered:
        raise ConfigError("the CSV file is empty (expected a header row)", file=file, line=1)
    header_line, header = numbered[0]
    columns = []
    for c in header:
        c = c.strip().lower()
        c = _CSV_ALIASES.get(c, c)
        if c not in _CSV_COLUMNS:
            close = difflib.get_close_matches(c, _CSV_COLUMNS, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise ConfigError(f"unknown column{hint} (columns: {', '.join(_CSV_COLUMNS)})",
                              file=file, line=header_line, key=c)
        if c in columns:
            raise ConfigError("column given twice", file=file, line=header_line, key=c)
        columns.append(c)
    for req in ("time_s", "x", "y", "z"):
        if req not in columns:
            raise ConfigError(f"required column missing (header: {', '.join(columns)})",
                              file=file, line=header_line, key=req)
    for group in (("vx", "vy", "vz"), ("ax", "ay", "az")):
        given = [g for g in group if g in columns]
        if given and len(given) != 3:
            missing = [g for g in group if g not in columns]
            raise ConfigError(f"give all of {', '.join(group)} or none", file=file,
                              line=header_line, key=missing[0])
    for rot, tran in (("vc", "vx"), ("ac", "ax")):
        if rot in columns and tran not in columns:
            raise ConfigError(f"column {rot} needs the translation columns ({tran}, ...) too",
                              file=file, line=header_line, key=rot)
    data: dict[str, list[float]] = {c: [] for c in columns}
    prev_t = -math.inf
    for line, row in numbered[1:]:
        if len(row) != len(columns):
            raise ConfigError(f"expected {len(columns)} values ({', '.join(columns)}), "
                              f"got {len(row)}", file=file, line=line,
                              key=columns[min(len(row), len(columns) - 1)])
        for c, cell in zip(columns, row):
            try:
                x = float(cell)
            except ValueError:
                raise ConfigError(f"not a number: {cell.strip()!r}", file=file, line=line,
                                  key=c) from None
            if not math.isfinite(x):
                raise ConfigError(f"not a finite number: {cell.strip()!r}", file=file,
                                  line=line, key=c)
            data[c].append(x)
        t = data["time_s"][-1]
        if t <= prev_t:
            raise ConfigError(f"time must increase from row to row ({t!r} after {prev_t!r})",
                              file=file, line=line, key="time_s")
        prev_t = t
    if data["time_s"] and data["time_s"][0] > 0.0:
        raise ConfigError(f"the first sample's time ({data['time_s'][0]!r} s) must be <= 0: "
                          "the master must be known from t = 0", file=file,
                          line=numbered[1][0], key="time_s")
    if len(data["time_s"]) < 2:
        raise ConfigError("the CSV master needs at least 2 rows of samples", file=file,
                          line=header_line)
    n = len(data["time_s"])

    def col(c: str) -> tuple[float, ...]:
        return tuple(data[c]) if c in data else (0.0,) * n

    def vec(a: str, b: str, c: str) -> tuple[tuple[float, float, float], ...]:
        return tuple(zip(col(a), col(b), col(c)))

    has_v = "vx" in data
    has_a = "ax" in data
    return CsvMaster(path, tuple(data["time_s"]), vec("x", "y", "z"), col("c"),
                     vec("vx", "vy", "vz") if has_v else None, col("vc") if has_v else None,
                     vec("ax", "ay", "az") if has_a else None, col("ac") if has_a else None,
                     window)


def _estimator(node: _Node) -> EncoderSpec:
    node.check_keys(("quantisation_mm", "quantisation_deg", "delay_samples", "window",
                     "lead_samples", "degree"))
    delay = node.number("delay_samples", 1, lo=0, hi=1000, integer=True)
    return EncoderSpec(
        quantisation_mm=node.number("quantisation_mm", 0.0, lo=0.0, unit="mm"),
        quantisation_deg=node.number("quantisation_deg", 0.0, lo=0.0, unit="deg"),
        delay_samples=delay,
        window=node.number("window", 16, lo=3, hi=10000, integer=True),
        lead_samples=node.number("lead_samples", float(delay), lo=0.0, hi=1000.0),
        degree=node.number("degree", 2, lo=1, hi=2, integer=True))


def _times(node: _Node, key: str, duration_s: float, required: bool) -> tuple[float, ...]:
    if not node.has(key):
        if required:
            node.raw(key)
        return ()
    value = node.raw(key)
    if isinstance(value, list):
        items = node.items(key)
    else:
        items = [(value, node.line_of(key), node.key(key))]
    times = []
    for v, line, path in items:
        times.append(_check_number(
            v, lambda msg, line=line, path=path: node.ctx.error(msg, line, path),
            lo=0.0, hi=duration_s, hi_open=True, unit="s (the scenario's duration)"))
    return tuple(times)


def _parse(data: Any, ctx: _Ctx, source: Path | None) -> Scenario:
    root = _Node(ctx, data, "", 1 if isinstance(data, (_Mapping, _Sequence)) else None)
    if "conveyor" in root.m:
        # a conveyor scenario (moving frame, items, robot program): controller.simulate.conveyor
        from .conveyor import parse_conveyor

        return parse_conveyor(root, ctx, source)
    root.check_keys(_TOP_KEYS)
    name = root.string("name", "")
    params = _tracker_params(root.section("tracker", required=True))
    robot = _robot(root.section("robot", required=True))
    mnode = root.section("master", required=True)
    if mnode.has("csv") and mnode.has("segments"):
        raise mnode.error("csv", "give either segments or csv, not both")
    if mnode.has("csv"):
        master: SegmentMaster | CsvMaster = _csv_master(mnode)
        end_s = master.time_s[-1]
    elif mnode.has("segments"):
        master = _segment_master(mnode)
        try:
            end_s = build_profile(master).end_s
        except SegmentError as exc:
            seg = master.segments[exc.index]
            raise ctx.error(exc.message, seg.key_lines.get(exc.key, seg.line),
                            f"{seg.path}.{exc.key}") from None
    else:
        raise mnode.ctx.error("required key missing in 'master': segments or csv",
                              mnode.line, mnode.key("segments"))
    T = params.sample_time_s
    duration = root.number("duration_s", None, lo=0.0, lo_open=True, unit="s")
    if duration is None:
        duration = end_s
    if isinstance(master, CsvMaster) and duration > end_s + 1e-9:
        raise root.error("duration_s", f"value {duration!r} is out of range: the master CSV "
                                       f"ends at {end_s!r} s")
    n = round(duration / T)
    if n < 1 or n > MAX_SAMPLES:
        raise root.error("duration_s" if root.has("duration_s") else "master",
                         f"the run has {n} samples (duration {duration:g} s / sample time "
                         f"{T:g} s): must be in [1...{MAX_SAMPLES}]")
    engage = _times(root, "engage", duration, True)
    disengage = _times(root, "disengage", duration, False)
    if not engage:
        raise root.error("engage", "must give at least one engage time")
    events = sorted([(round(t / T), "engage", i) for i, t in enumerate(engage)]
                    + [(round(t / T), "disengage", i) for i, t in enumerate(disengage)])
    expected = "engage"
    for k, kind, i in events:
        if kind != expected or (k >= n):
            key = f"{kind}[{i}]" if isinstance(root.raw(kind), list) else kind
            lines = getattr(root.raw(kind), "item_lines", None)
            line = lines[i] if lines else root.line_of(kind)
            why = (f"acts after the last sample (sample {k} of {n})" if k >= n else
                   "engage and disengage times must alternate, engage first, at least one "
                   "sample apart: engage[0] < disengage[0] < engage[1] < ...")
            raise ctx.error(why, line, key)
        expected = "disengage" if kind == "engage" else "engage"
    estimator = _estimator(root.section("estimator")) if root.has("estimator") else None
    return Scenario(params, robot, master, float(duration), engage, disengage, estimator, name,
                    source)


def load_scenario(source: str | Path | dict, *, base_dir: str | Path | None = None) -> Scenario:
    """Load and validate a scenario from a YAML file (path) or an already parsed mapping.

    A mapping with a top-level ``conveyor`` key is a conveyor scenario and gives a
    :class:`controller.simulate.conveyor.ConveyorScenario` (schema in that module).

    ``base_dir``: where relative CSV paths of a mapping are resolved (default: the cwd; for a
    file its own directory).  Raises :class:`ConfigError` naming the file, line and key.
    """
    if isinstance(source, dict):
        ctx = _Ctx("<scenario>", Path(base_dir) if base_dir is not None else Path.cwd())
        return _parse(source, ctx, None)
    path = Path(source)
    text = read_text(path)  # OSError propagates (the CLI reports it)
    ctx = _Ctx(str(path), Path(base_dir) if base_dir is not None else path.parent)
    data = _load_yaml(text, str(path))
    if data is None:
        raise ConfigError("the scenario file is empty", file=str(path), line=1)
    scenario = _parse(data, ctx, path)
    return scenario
