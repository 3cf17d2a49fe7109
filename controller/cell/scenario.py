"""Cell scenarios (``cantrack simulate``; its readers are also those of the
cell of bus.yml): several moving frames, several robots, item
sensors and timed MasterFrame changes (hand-off between belts, two robots sharing a belt each
with its own frame object, 2-DOF frames).

A scenario with a top-level ``cell:`` key.  Units: mm, mm/s, deg, s; master values in master
units.  ``*`` = required::

    name: "hand-off"
    duration_s*: 6.0
    tracker*: {...}                  # as in conveyor scenarios (TrackerParams fields)
    cell*:
      masters*:                      # named master axes: the keys of conveyor.master
        belt_a: {speed: 300}         #   (speed | profile, optional encoder; no log)
        belt_b: {start: 0, speed: 200, encoder: {counts_per_unit: 100}}
      frames*:                       # a list: the keys of conveyor.frame, plus
        - name: a
          masters*: [belt_a]         # one master per DOF (NOF = the list's length)
          directions: [[1, 0, 0], [0, 1, 0]]   # linear, NOF > 1: one direction per DOF
          scales_mm_per_unit: [1, 1]           #   and one scale per DOF (default 1)
          window: {upstream: [0, 0], downstream: [500, 300]}   # NOF > 1: one limit per DOF
          world: {type: scara, dimension: 4}   # optional: the frame's kinematics system
        - name: on_a                 # or a robot's TCP as the master (frame type 3):
          group: {robot: r1, transform: {position: [..], axis: [..], angle_deg: ..},
                  axis: [0, 0, 1]}   #   the robot, its world seen from here, the turn axis
          window: {upstream: [..4], downstream: [..4]}   # optional (dx, dy, dz, angle)
          limits: {AccelerationMaxTrans: 20000}   # optional: softMC's names (the master
                                     #   robot's TCP above them is a tracker error)
      robots*:                       # a list: the keys of conveyor.robot, plus
        - name: r1
          kinematics: {type: general, dimension: 6}
          track_types: {a: [1, 2]}   # per frame: the item types tracked (default: all)
          program: {frame: a, approach_mm: 50, dwell_s: 0.1, place: [..], predict: true}
          master_frame:              # or: timed MasterFrame changes (no program)
            - {time_s: 0.2, frame: a}
            - {time_s: 3.0, frame: b}          # hand-off from a to b
            - {time_s: 5.0, frame: none}       # de-sync from every frame
      sensors*:                      # item sensors: a list of
        - frame*: a
          robots: [r1]               # whose buffers get the TRIGGER (default: every robot)
          trigger_times*: [0.1, 0.9]
          types: [1, 2]              # optional: the item type per trigger (default 0)
          radius_offsets_mm: [0, 0]  # optional (rotary frames)
          offset: {position: [80, 0, 0]}   # group frames: the item relative to the TCP

The run (:mod:`controller.simulate.cell`): each frame gets its own source object of its master (two frames on one belt read the same
axis: same values, own estimator).  A sensor's TRIGGER latches the master values of its frame
at the sensor time (exactly, or the encoder count then).  Per sample: sensors, MasterFrame
changes due, programs, then one step of the cell (frames, then robots).

Errors are :class:`controller.errors.ConfigError` naming file, line and key.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, TypeVar

from ..conveyor import FRAME_LIMITS, Kinematics, Location, Window
from ..limits import CartesianLimits
from ..errors import ParameterError
from ..tracking import TrackerParams
from ..yamlmarks import Section, check_number
from .elements import (FrameSpec, MasterSpec, ProgramSpec, RobotSpec, read_frame,
                       read_frame_limits, read_location, read_master, read_program, read_robot)
from .reading import MAX_SAMPLES, SampledRun, tracker_params

__all__ = ["GroupSpec", "CellFrameSpec", "FrameChange", "CellRobotSpec", "SensorSpec",
           "CellScenario", "parse_cell", "read_cell_frame", "read_cell_robot",
           "read_frame_changes", "read_kinematics", "read_sensor", "read_names",
           "required_section", "without_keys", "read_layout"]


# -- the scenario ------------------------------------------------------------------------
@dataclass(frozen=True)
class GroupSpec:
    """A group frame's master: robot ``robot``'s TCP through ``transform``, turning about
    ``axis`` (world)."""

    robot: str
    transform: Location = Location()
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    #: where ``robot`` is written (its errors), not part of the frame: not compared
    line: int | None = field(default=None, compare=False)
    path: str = field(default="", compare=False)


@dataclass(frozen=True)
class CellFrameSpec:
    spec: FrameSpec | None               #: the geometry (first DOF for NOF > 1; None: group)
    masters: tuple[str, ...]
    directions: tuple[tuple[float, float, float], ...]
    scales: tuple[float, ...]
    window: Window
    world: Kinematics | None = None
    group: GroupSpec | None = None
    group_name: str = ""
    #: a group frame's limits (softMC's names; the others' are in ``spec``)
    group_limits: CartesianLimits = FRAME_LIMITS

    @property
    def name(self) -> str:
        return self.spec.name if self.spec is not None else self.group_name

    @property
    def nof(self) -> int:
        return len(self.masters)


@dataclass(frozen=True)
class FrameChange:
    time_s: float
    frame: str | None                    #: None: MasterFrame = none


@dataclass(frozen=True)
class CellRobotSpec:
    robot: RobotSpec
    kinematics: Kinematics = Kinematics()
    track_types: tuple[tuple[str, frozenset[int]], ...] = ()
    program_frame: str | None = None
    program: ProgramSpec | None = None
    changes: tuple[FrameChange, ...] = ()

    @property
    def name(self) -> str:
        return self.robot.name


@dataclass(frozen=True)
class SensorSpec:
    frame: str
    robots: tuple[str, ...]
    times: tuple[float, ...]
    types: tuple[int, ...]
    dr_mm: tuple[float, ...]
    #: group frames: the item relative to the master robot's TCP (None: at the TCP)
    offset: Location | None = None


@dataclass(frozen=True)
class CellScenario(SampledRun):
    params: TrackerParams
    duration_s: float
    masters: dict[str, MasterSpec]
    frames: tuple[CellFrameSpec, ...]
    robots: tuple[CellRobotSpec, ...]
    sensors: tuple[SensorSpec, ...]
    name: str = ""
    source: Path | None = None


def required_section(node: Section, key: str) -> Section:
    """A required section (missing: "required key is missing" at the key)."""
    sec = node.section(key)
    assert sec is not None
    return sec


def without_keys(node: Section, drop: tuple[str, ...]) -> Section:
    """The node without the keys ``drop`` (read here), for a reader of the rest."""
    m = copy.copy(node.data)
    for k in drop:
        m.pop(k, None)
    return node.child(m, node.path, node.head)


def read_names(node: Section, key: str, known: Mapping[str, object] | list[str],
               what: str) -> tuple[str, ...]:
    out = []
    for v, line, path in node.list(key):
        if not isinstance(v, str) or v not in known:
            raise node.fail(f"unknown {what} {v!r} (known: "
                                 f"{', '.join(map(repr, known))})", line, path)
        out.append(v)
    return tuple(out)


def read_kinematics(node: Section | None) -> Kinematics | None:
    if node is None:
        return None
    node.check_keys(("type", "dimension"))
    try:
        return Kinematics(node.string("type", "general"),
                          node.number("dimension", 6, integer=True))
    except ParameterError as exc:
        raise node.error("dimension" if "dimension" in str(exc) else "type", str(exc)) from None


def read_group_frame(node: Section) -> CellFrameSpec:
    """A frame whose master is another robot's TCP (type 3)."""
    node.check_keys(("name", "group", "window", "limits", "world"))
    name = node.string("name")
    g = required_section(node, "group")
    g.check_keys(("robot", "transform", "axis"))
    transform = read_location(g, "transform", Location()) or Location()
    axis = g.xyz("axis", (0.0, 0.0, 1.0))
    if not any(axis):
        raise g.error("axis", "must not be the zero vector")
    window = Window.unlimited(4)
    if node.has("window"):
        w = required_section(node, "window")
        w.check_keys(("upstream", "downstream"))
        lims = []
        for key in ("upstream", "downstream"):
            items = w.list(key)
            if len(items) != 4:
                raise w.error(key, "a group frame has 4 DOFs (dx, dy, dz [mm], angle [deg] "
                                   f"since the trigger): give 4 limits, got {len(items)}")
            lims.append(tuple(check_number(v, lambda m, line=line, path=path:
                                           node.fail(m, line, path))
                              for v, line, path in items))
        try:
            window = Window(lims[0], lims[1])
        except ParameterError as exc:
            raise w.error("downstream", str(exc)) from None
    world = read_kinematics(node.optional_section("world"))
    limits = read_frame_limits(node)
    gs = GroupSpec(g.string("robot"), transform, tuple(axis), g.value_line("robot"),
                   g.key_path("robot"))
    return CellFrameSpec(None, (), (), (), window, world, gs, name, limits)


def read_cell_frame(node: Section, masters: Mapping[str, object]) -> CellFrameSpec:
    """A frame of a cell: a moving frame on the named ``masters`` (one per DOF) or a group
    frame (a robot's TCP as master)."""
    if node.has("group"):
        return read_group_frame(node)
    extra = ("masters", "directions", "scales_mm_per_unit", "world")
    names = read_names(node, "masters", masters, "master")
    if not names:
        raise node.error("masters", "must name at least one master")
    world = read_kinematics(node.optional_section("world"))
    nof = len(names)
    if nof == 1:
        for k in ("directions", "scales_mm_per_unit"):
            if node.has(k):
                raise node.error(k, "is for frames with several masters; a 1-DOF frame uses "
                                    "direction and scale_mm_per_unit")
        spec = read_frame(without_keys(node, extra))
        return CellFrameSpec(spec, names, (spec.direction,), (spec.scale_mm_per_unit,),
                             spec.window, world)
    # several DOFs: a linear frame, one direction and scale per DOF
    for k in ("direction", "scale_mm_per_unit"):
        if node.has(k):
            raise node.error(k, f"a frame with {nof} masters gives directions and "
                                "scales_mm_per_unit (one per DOF)")
    if node.raw("type", "linear") not in ("linear", 0):
        raise node.error("type", f"a frame with {nof} masters must be linear")
    dirs = []
    for v, line, path in node.list("directions"):
        d = node.child({"d": v}, path, line).xyz("d", unit="")
        n = math.sqrt(sum(x * x for x in d))
        if n == 0.0:
            raise node.fail("must not be the zero vector", line, path)
        dirs.append(tuple(x / n for x in d))
    if len(dirs) != nof:
        raise node.error("directions", f"must give {nof} directions (one per master), got "
                                       f"{len(dirs)}")
    scales = [1.0] * nof
    if node.has("scales_mm_per_unit"):
        items = node.list("scales_mm_per_unit")
        if len(items) != nof:
            raise node.error("scales_mm_per_unit", f"must give {nof} values, got {len(items)}")
        scales = [check_number(v, lambda m, line=line, path=path: node.fail(m, line, path),
                               unit="mm per master unit") for v, line, path in items]
    w = required_section(node, "window")
    w.check_keys(("upstream", "downstream"))
    lims = []
    for key in ("upstream", "downstream"):
        items = w.list(key)
        if len(items) != nof:
            raise w.error(key, f"must give {nof} limits (one per DOF) [mm], got {len(items)}")
        lims.append(tuple(check_number(v, lambda m, line=line, path=path:
                                       node.fail(m, line, path), unit="mm")
                          for v, line, path in items))
    try:
        window = Window(lims[0], lims[1])
    except ParameterError as exc:
        raise w.error("downstream", str(exc)) from None
    m1 = copy.copy(node.data)
    for k in extra + ("type",):
        m1.pop(k, None)
    m1["window"] = {"upstream": lims[0][0], "downstream": lims[1][0]}
    m1["direction"] = list(dirs[0])
    spec = read_frame(node.child(m1, node.path, node.head))
    return CellFrameSpec(spec, names, tuple(dirs), tuple(scales), window, world)


def read_frame_changes(node: Section, frames: Mapping[str, CellFrameSpec], duration: float
             ) -> tuple[FrameChange, ...]:
    out = []
    prev = -math.inf
    for v, line, path in node.list("master_frame"):
        c = node.child(v, path, line)
        c.check_keys(("time_s", "frame"))
        t = c.number("time_s", lo=0.0, hi=duration, hi_open=True, unit="s")
        if t < prev:
            raise c.error("time_s", "times must be in increasing order")
        prev = t
        name = c.string("frame")
        if name != "none" and name not in frames:
            raise c.error("frame", f"unknown frame {name!r} (known: "
                                   f"{', '.join(map(repr, frames))}, or none)")
        out.append(FrameChange(t, None if name == "none" else name))
    return tuple(out)


def read_cell_robot(node: Section, frames: Mapping[str, CellFrameSpec], duration: float,
                    *, kinematics: Kinematics | None = None, extra: tuple[str, ...] = ()
                    ) -> CellRobotSpec:
    """A robot of a cell (``duration`` [s]: the bound of its MasterFrame times).
    ``kinematics``: the robot's type and dimension when the caller knows them (bus.yml: from
    its drives), else read from the ``kinematics`` key; ``extra``: keys the caller reads."""
    skip = ("kinematics", "track_types", "program", "master_frame") + extra
    rs = read_robot(without_keys(node, skip))
    kin = kinematics if kinematics is not None else (
        read_kinematics(node.optional_section("kinematics")) or Kinematics())
    types: list[tuple[str, frozenset[int]]] = []
    tn = node.optional_section("track_types")
    if tn is not None:
        tn.check_keys(tuple(frames))
        for fname in frames:
            if tn.has(fname):
                ts = [check_number(v, lambda m, line=line, path=path:
                                   node.fail(m, line, path), lo=0, hi=255, integer=True)
                      for v, line, path in tn.list(fname)]
                if not ts:
                    raise tn.error(fname, "must list at least one item type")
                types.append((fname, frozenset(int(t) for t in ts)))
    if node.has("program") and node.has("master_frame"):
        raise node.error("master_frame", "give either a program or master_frame changes, "
                                         "not both")
    prog, pframe = None, None
    if node.has("program"):
        pn = required_section(node, "program")
        pframe = pn.string("frame")
        if pframe not in frames:
            raise pn.error("frame", f"unknown frame {pframe!r} (known: "
                                    f"{', '.join(map(repr, frames))})")
        prog = read_program(without_keys(pn, ("frame",)))
    changes = read_frame_changes(node, frames, duration) if node.has("master_frame") else ()
    if prog is None and not changes:
        raise node.error("program", "give a program (on one frame) or master_frame changes")
    return CellRobotSpec(rs, kin, tuple(types), pframe, prog, changes)


def read_sensor(node: Section, frames: Mapping[str, CellFrameSpec], robots: list[str],
            duration: float) -> SensorSpec:
    node.check_keys(("frame", "robots", "trigger_times", "types", "radius_offsets_mm",
                     "offset"))
    fname = node.string("frame")
    if fname not in frames:
        raise node.error("frame", f"unknown frame {fname!r} (known: "
                                  f"{', '.join(map(repr, frames))})")
    offset = None
    if node.has("offset"):
        if frames[fname].group is None:
            raise node.error("offset", "is for group frames (a robot's TCP as the master)")
        offset = read_location(node, "offset", Location())
    names = read_names(node, "robots", robots, "robot") if node.has("robots") else tuple(robots)
    times = tuple(check_number(v, lambda m, line=line, path=path: node.fail(m, line, path),
                               lo=0.0, hi=duration, hi_open=True,
                               unit="s (the scenario's duration)")
                  for v, line, path in node.list("trigger_times"))
    if list(times) != sorted(times):
        raise node.error("trigger_times", "times must be in increasing order")

    def per_time(key: str, default: Any, **kw) -> tuple:
        if not node.has(key):
            return (default,) * len(times)
        items = node.list(key)
        if len(items) != len(times):
            raise node.error(key, f"must give one value per trigger time ({len(times)}), got "
                                  f"{len(items)}")
        return tuple(check_number(v, lambda m, line=line, path=path:
                                  node.fail(m, line, path), **kw)
                     for v, line, path in items)
    types = per_time("types", 0, lo=0, hi=255, integer=True)
    drs = per_time("radius_offsets_mm", 0.0, unit="mm")
    return SensorSpec(fname, names, times, types, drs, offset)


def parse_cell(root: Section, source: Path | None) -> CellScenario:
    """Validate a cell scenario (``root``: the scenario's top-level node)."""
    root.check_keys(("name", "duration_s", "tracker", "cell"))
    name = root.string("name", "")
    params = tracker_params(required_section(root, "tracker"))
    duration = root.number("duration_s", lo=0.0, lo_open=True, unit="s")
    n = round(duration / params.sample_time_s)
    if n < 1 or n > MAX_SAMPLES:
        raise root.error("duration_s", f"the run has {n} samples: must be in "
                                       f"[1...{MAX_SAMPLES}]")
    cn = required_section(root, "cell")
    cn.check_keys(("masters", "frames", "robots", "sensors"))
    mn = required_section(cn, "masters")
    masters: dict[str, MasterSpec] = {}
    for key in mn.data:
        sec = required_section(mn, key)
        if sec.has("log"):
            raise sec.error("log", "encoder logs replay single-frame conveyor scenarios only")
        masters[str(key)] = read_master(sec)
    if not masters:
        raise cn.error("masters", "must define at least one master")
    frames, robots, sensors = read_layout(
        cn, masters, duration, lambda node, frames: read_cell_robot(node, frames, duration))
    return CellScenario(params, float(duration), masters, tuple(frames.values()),
                        robots, sensors, name, source)


class _Named(Protocol):
    @property
    def name(self) -> str: ...


R = TypeVar("R", bound=_Named)


def read_layout(cn: Section, masters: Mapping[str, object], duration: float,
                robot: Callable[[Section, Mapping[str, CellFrameSpec]], R]
                ) -> tuple[dict[str, CellFrameSpec], tuple[R, ...], tuple[SensorSpec, ...]]:
    """The ``frames``, ``robots`` and ``sensors`` of a cell section ``cn`` (the masters
    named by ``masters``; ``robot`` reads one robot; ``duration`` [s]: the bound of every
    time), with the names checked (unique, every reference known)."""
    frames: dict[str, CellFrameSpec] = {}
    for v, line, path in cn.list("frames"):
        fs = read_cell_frame(cn.child(v, path, line), masters)
        if fs.name in frames:
            raise cn.fail(f"frame name {fs.name!r} is used twice", line, path)
        frames[fs.name] = fs
    robots: list[R] = []
    for v, line, path in cn.list("robots"):
        rs = robot(cn.child(v, path, line), frames)
        if rs.name in [r.name for r in robots]:
            raise cn.fail(f"robot name {rs.name!r} is used twice", line, path)
        robots.append(rs)
    if not frames or not robots:
        raise cn.error("frames" if not frames else "robots", "must list at least one")
    names = [r.name for r in robots]
    for fs in frames.values():
        if fs.group is not None and fs.group.robot not in names:
            raise cn.fail(f"unknown robot {fs.group.robot!r} (known: "
                          f"{', '.join(map(repr, names))})", fs.group.line, fs.group.path)
    sensors = tuple(read_sensor(cn.child(v, path, line), frames, names, duration)
                    for v, line, path in cn.list("sensors"))
    return frames, tuple(robots), sensors
