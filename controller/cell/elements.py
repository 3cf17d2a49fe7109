"""The elements of conveyor and cell scenarios, read from a marked YAML section: a moving
frame (:class:`FrameSpec`), a master axis (:class:`MasterSpec`), a robot group
(:class:`RobotSpec`) and its pick program (:class:`ProgramSpec`).  The schema of each is in
:mod:`controller.simulate.conveyor` (``conveyor.frame``, ``.master``, ``.robot``,
``.program``); cell scenarios and the cell of bus.yml use the same readers.

Units: mm, mm/s, deg, s; master values in master units.  Errors are
:class:`controller.errors.ConfigError` naming file, line and key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

from ..conveyor import (FRAME_LIMITS, MOTION_LIMITS, SOFTMC_LIMIT_NAMES, Location, Window,
                        frame_limits)
from ..limits import CartesianLimits, Limits
from ..conveyor.frame import LINEAR, ROTARY, ROTARY_DECOUPLED, FrameType
from ..conveyor.replay import read_encoder_log
from ..errors import ConfigError, ParameterError
from ..yamlmarks import Section, check_number
from .reading import segment_master, unit_vector

__all__ = ["FrameSpec", "EncoderSpec", "MasterSpec", "RobotSpec", "ProgramSpec",
           "read_location", "required_location", "read_frame", "read_master", "read_robot", "read_program"]

_TYPES = {"linear": LINEAR, "rotary": ROTARY, "rotary_decoupled": ROTARY_DECOUPLED,
          0: LINEAR, 1: ROTARY, 2: ROTARY_DECOUPLED}


@dataclass(frozen=True)
class FrameSpec:
    name: str
    type: FrameType
    window: Window
    limits: CartesianLimits
    origin: Location = Location()
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    scale_mm_per_unit: float = 1.0
    upstream: Location | None = None
    arc_point: tuple[float, float, float] | None = None
    downstream: tuple[float, float, float] | None = None
    up_master: float = 0.0
    down_master: float | None = None


@dataclass(frozen=True)
class EncoderSpec:
    counts_per_unit: float
    modulus: int = 0
    window: int = 16


@dataclass(frozen=True)
class MasterSpec:
    start: float = 0.0
    speed: float = 0.0
    profile: Any = None  #: a SegmentMaster (x component used) or None
    encoder: EncoderSpec | None = None
    log: tuple[int, ...] | None = None
    log_path: Path | None = None


@dataclass(frozen=True)
class RobotSpec:
    name: str
    start: Location
    base: Location = Location()
    tool: Location = Location()
    slave: int = 5
    buffer_capacity: int = 32
    motion: CartesianLimits = MOTION_LIMITS
    #: the item types the robot tracks on the frame (None: every type)
    track_types: frozenset[int] | None = None


@dataclass(frozen=True)
class ProgramSpec:
    approach_mm: float = 50.0
    dwell_s: float = 0.1
    place: Location | None = None
    predict: bool = True


@overload
def read_location(node: Section, key: str, default: Location) -> Location: ...
@overload
def read_location(node: Section, key: str, default: None = None) -> Location | None: ...


def read_location(node: Section, key: str, default: Location | None = None
                  ) -> Location | None:
    """A location at ``key``: a position [mm] or {position, axis, angle_deg} (``default``
    when the key is missing)."""
    if not node.has(key):
        return default
    value = node.raw(key)
    if isinstance(value, list):
        return Location(node.xyz(key, unit="mm"))
    sub = node.child(value, node.key_path(key), node.value_line(key))
    sub.check_keys(("position", "axis", "angle_deg"))
    pos = sub.xyz("position", unit="mm")
    angle = sub.number("angle_deg", 0.0, unit="deg")
    axis = sub.xyz("axis", (0.0, 0.0, 1.0))
    try:
        return Location.from_axis_angle(pos, axis, angle)
    except ParameterError as exc:
        raise sub.error("axis", str(exc)) from None


def required_location(node: Section, key: str) -> Location:
    """A required location at ``key`` (missing: "required key is missing" at the key)."""
    loc = read_location(node, key)
    if loc is None:
        node.raw(key)            # raises the missing-key error
        raise AssertionError(key)
    return loc


def read_frame_limits(node: Section) -> CartesianLimits:
    """A frame's ``limits`` by softMC's names (VelocityMaxTrans [mm/s], ... JerkMaxRot
    [deg/s³]; docs/spec/conveyor.md#3.5), softMC's defaults for those not given."""
    limits = FRAME_LIMITS
    ln = node.optional_section("limits")
    if ln is not None:
        ln.check_keys(list(SOFTMC_LIMIT_NAMES))
        limits = frame_limits(**{
            f: ln.number(f, getattr(getattr(limits, channel), bound), lo=0.0, lo_open=True)
            for f, (channel, bound) in SOFTMC_LIMIT_NAMES.items()})
    return limits


def read_frame(node: Section) -> FrameSpec:
    node.check_keys(("name", "type", "origin", "direction", "scale_mm_per_unit", "upstream",
                     "arc_point", "downstream", "up_master", "down_master", "window",
                     "limits"))
    name = node.string("name", "cnv")
    t = node.raw("type", "linear")
    key = t.lower() if isinstance(t, str) else t
    if isinstance(t, bool) or not isinstance(key, (str, int)) or key not in _TYPES:
        raise node.error("type", f"must be linear | rotary | rotary_decoupled | 0 | 1 | 2, "
                                 f"got {t!r}")
    ftype = _TYPES[key]
    w = node.section("window")
    w.check_keys(("upstream", "downstream"))
    unit = "mm" if ftype == LINEAR else "deg"
    up = w.number("upstream", unit=unit)
    down = w.number("downstream", unit=unit)
    if not up < down:
        raise w.error("downstream", f"value {down!r} is out of range: must be > upstream "
                                    f"({up!r}) {unit}")
    window = Window.single(up, down)
    limits = read_frame_limits(node)
    if ftype == LINEAR:
        for k in ("upstream", "arc_point", "downstream", "up_master", "down_master"):
            if node.has(k):
                raise node.error(k, "is a rotary frame key (type: rotary); a linear frame "
                                    "uses origin, direction, scale_mm_per_unit")
        scale = node.number("scale_mm_per_unit", 1.0, unit="mm per master unit")
        if scale == 0.0:
            raise node.error("scale_mm_per_unit", "must not be 0")
        return FrameSpec(name, ftype, window, limits, read_location(node, "origin", Location()),
                         unit_vector(node, "direction", (1.0, 0.0, 0.0)), scale)
    for k in ("origin", "direction", "scale_mm_per_unit"):
        if node.has(k):
            raise node.error(k, "is a linear frame key; a rotary frame uses upstream, "
                                "arc_point, downstream, up_master, down_master")
    upstream = required_location(node, "upstream")
    arc_point = node.xyz("arc_point", unit="mm")
    downstream = node.xyz("downstream", unit="mm")
    up_master = node.number("up_master", 0.0)
    down_master = node.number("down_master")
    if down_master == up_master:
        raise node.error("down_master", f"must differ from up_master ({up_master!r})")
    spec = FrameSpec(name, ftype, window, limits, upstream=upstream, arc_point=arc_point,
                     downstream=downstream, up_master=up_master, down_master=down_master)
    try:
        from ..conveyor import arc_from_points

        arc_from_points(upstream.pos, arc_point, downstream)
    except ParameterError as exc:
        raise node.error("arc_point", str(exc)) from None
    return spec


def read_master(node: Section) -> MasterSpec:
    node.check_keys(("start", "speed", "profile", "encoder", "log"))
    kinds = [k for k in ("speed", "profile", "log") if node.has(k)]
    if len(kinds) != 1:
        raise node.error(kinds[1] if len(kinds) > 1 else "speed",
                         "give exactly one of speed, profile, log")
    start = node.number("start", 0.0)
    enc = None
    en = node.optional_section("encoder")
    if en is not None:
        en.check_keys(("counts_per_unit", "modulus", "window"))
        enc = EncoderSpec(en.number("counts_per_unit", lo=0.0, lo_open=True),
                          en.number("modulus", 0, lo=0, integer=True),
                          en.number("window", 16, lo=3, hi=10000, integer=True))
    if node.has("log"):
        if enc is None:
            raise node.error("log", "an encoder log needs the encoder section "
                                    "(counts_per_unit, modulus)")
        path = node.file_path("log")
        try:
            logs = read_encoder_log(path)
        except OSError as exc:
            raise node.error("log", f"cannot read the encoder log {str(path)!r}: "
                                    f"{exc.strerror or exc}") from None
        if len(logs) != 1:
            raise ConfigError(f"the encoder log must have one source column, found "
                              f"{len(logs)}", file=str(path), line=1)
        counts = tuple(next(iter(logs.values())))
        return MasterSpec(start, 0.0, None, enc, counts, path)
    if node.has("profile"):
        prof = node.optional_section("profile")
        assert prof is not None          # has("profile")
        return MasterSpec(start, 0.0, segment_master(prof), enc)
    return MasterSpec(start, node.number("speed", unit="master units/s"), None, enc)


def read_robot(node: Section) -> RobotSpec:
    node.check_keys(("name", "start", "base", "tool", "slave", "buffer_capacity", "motion",
                     "track_types"))
    slave = node.number("slave", 5, integer=True)
    if slave not in (3, 5):
        raise node.error("slave", f"value {slave!r} is out of range: must be 3 or 5")
    ml = MOTION_LIMITS
    mn = node.optional_section("motion")
    if mn is not None:
        mn.check_keys(("vel", "acc", "jerk", "rot_vel", "rot_acc", "rot_jerk"))
        ml = CartesianLimits(*(Limits(*(mn.number(prefix + k, getattr(lim, k), lo=0.0,
                                                  lo_open=True) for k in ("vel", "acc", "jerk")))
                               for prefix, lim in (("", ml.trans), ("rot_", ml.rot))))
    types = None
    if node.has("track_types"):
        types = frozenset(int(check_number(v, lambda m, line=line, path=path:
                                       node.fail(m, line, path), lo=0, hi=255,
                                           integer=True))
                          for v, line, path in node.list("track_types"))
        if not types:
            raise node.error("track_types", "must list at least one item type (leave the key "
                                            "out to track every type)")
    return RobotSpec(node.string("name", "robot"), required_location(node, "start"),
                     read_location(node, "base", Location()),
                     read_location(node, "tool", Location()),
                     slave, node.number("buffer_capacity", 32, lo=1, hi=100000, integer=True),
                     ml, types)


def read_program(node: Section | None) -> ProgramSpec:
    if node is None:
        return ProgramSpec()
    node.check_keys(("approach_mm", "dwell_s", "place", "predict"))
    return ProgramSpec(node.number("approach_mm", 50.0, lo=0.0, unit="mm"),
                       node.number("dwell_s", 0.1, lo=0.0, unit="s"),
                       read_location(node, "place", None), node.boolean("predict", True))
