"""Readers shared by the scenario files of ``cantrack simulate`` (tracking, conveyor and
cell scenarios) and by the cell of bus.yml: the tracker parameters, the segment master and
the sampled-run base.

The files are read as bus.yml is, by :mod:`controller.yamlmarks`: the YAML with its line
marks (``load_marked``) and each mapping as a :class:`~controller.yamlmarks.Section` (file,
line and dotted key path; the scenario getters ``number``/``boolean``/``string``/``xyz``/
``optional_section``/``check_keys`` with units and open or closed bounds).  Every problem is
a :class:`controller.errors.ConfigError` naming the file, the line and the key.  Public
names are used by :mod:`controller.simulate.scenario`, :mod:`.elements` and :mod:`.scenario`;
none of those imports another's private names.
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
from ..limits import Limits
from ..tracking import PLANNERS, Mode, Rates, SoftMcOptions, TrackerParams
from ..tracking.types import DEFAULT_ROT, DEFAULT_TRANS
from ..yamlmarks import MAX_POSITION, MISSING, Section, closest, describe

__all__ = ["MAX_POSITION_MM", "MAX_SAMPLES", "CsvMaster", "EncoderSpec", "SampledRun",
           "Segment", "SegmentMaster", "segment_master", "tracker_params", "unit_vector"]

#: upper bound on duration_s / sample_time_s (a typo should not run for hours)
MAX_SAMPLES = 1_000_000

#: the largest |coordinate| of a position in a scenario [mm] (1 km; also for angles [deg])
MAX_POSITION_MM = MAX_POSITION


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

    params: TrackerParams        #: declared here, a field of each scenario dataclass
    duration_s: float            #: [s]

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
_PARAM_MSG = re.compile(r"^(?:Limits\.|rate )?(\w+) \(=")


def _param_error(node: Section, exc: ParameterError, fields: Iterable[str]) -> ConfigError:
    """A core ParameterError located at the value it names (else at the section)."""
    m = _PARAM_MSG.match(str(exc))
    name = m.group(1) if m else None
    if name is not None and name in fields and node.has(name):
        return node.error(name, str(exc))
    return node.fail(str(exc), node.head, node.path or None)


def _limits(node: Section, key: str, default: Limits | None) -> Limits | None:
    sec = node.optional_section(key)
    if sec is None:
        return default
    sec.check_keys(("vel", "acc", "jerk"))
    unit = "deg" if key.endswith("_rot") else "mm"
    units = {"vel": f"{unit}/s", "acc": f"{unit}/s^2", "jerk": f"{unit}/s^3"}
    values = {}
    for f in ("vel", "acc", "jerk"):
        dflt = getattr(default, f) if default is not None else MISSING
        values[f] = sec.number(f, dflt, unit=units[f])
    try:
        return Limits(**values)
    except ParameterError as exc:
        raise _param_error(sec, exc, ("vel", "acc", "jerk")) from exc


def tracker_params(node: Section) -> TrackerParams:
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
            raise node.error("mode", f"must be 3 | 5 | absolute | relative, got {describe(mode)}")
    for key in _LIMIT_KEYS:  # robot_max_* first: the sync/de-sync values start at them
        default = _PARAM_FIELDS[key].default
        if key in ("sync_trans", "desync_trans"):
            default = kw.get("robot_max_trans", DEFAULT_TRANS)
        elif key in ("sync_rot", "desync_rot"):
            default = kw.get("robot_max_rot", DEFAULT_ROT)
        if node.has(key):
            kw[key] = _limits(node, key, default if isinstance(default, Limits) else None)
    rates = node.optional_section("rates")
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
    sm = node.optional_section("softmc")
    if sm is not None:
        sm.check_keys(_SOFTMC_KEYS)
        base = SoftMcOptions.literal() if sm.boolean("literal", False) else SoftMcOptions()
        changes = {k: sm.boolean(k) for k in _SOFTMC_KEYS[1:] if sm.has(k)}
        kw["softmc"] = dataclasses.replace(base, **changes)
    try:
        return TrackerParams(**kw)
    except ParameterError as exc:
        raise _param_error(node, exc, _PARAM_FIELDS) from exc



def unit_vector(node: Section, key: str, default: Any) -> tuple[float, float, float]:
    v = node.xyz(key, default)
    n = math.hypot(v[0], v[1], v[2])  # (no overflow for components of 1e300)
    if n == 0.0:
        raise node.error(key, "must not be the zero vector")
    return v if n == 1.0 else (v[0] / n, v[1] / n, v[2] / n)


_SEGMENT_KINDS = ("velocity", "acceleration", "speed_change")


def segment_master(node: Section) -> SegmentMaster:
    node.check_keys(("position", "c", "direction", "initial_speed", "c_rate", "segments"))
    d = unit_vector(node, "direction", (1.0, 0.0, 0.0))
    segments: list[Segment] = []
    items = node.list("segments")
    if not items:
        raise node.error("segments", "must list at least one segment")
    for value, line, path in items:
        seg = node.child(value, path, line)
        seg.check_keys(("duration_s", "direction", "c_rate") + _SEGMENT_KINDS)
        kinds = [k for k in _SEGMENT_KINDS if seg.has(k)]
        if len(kinds) > 1:
            raise seg.error(kinds[1], f"a segment has at most one of {', '.join(_SEGMENT_KINDS)}"
                                      f" (this one has {' and '.join(kinds)})")
        kind = kinds[0] if kinds else "hold"
        d = unit_vector(seg, "direction", d)
        c_rate = seg.number("c_rate", None, unit="deg/s")
        common = dict(direction=d, c_rate=c_rate, line=seg.head, path=path,
                      key_lines=dict(getattr(seg.data, "value_lines", {})))
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
    return SegmentMaster(node.xyz("position", (0.0, 0.0, 0.0), unit="mm"),
                         node.number("c", 0.0, unit="deg"), initial_speed, first.direction, c_rate,
                         tuple(segments))
