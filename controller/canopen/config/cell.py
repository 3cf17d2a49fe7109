"""``.tracking.cell`` of bus.yml: a work cell of several encoders, moving frames and robots.

Instead of ``.tracking.conveyor``, ``.kinematics``, ``.window`` and ``.items`` (one belt, one
robot), a cell names its master encoders, its frames and its robots; the frames, robots and
sensors are written as in a cell scenario of ``cantrack simulate``
(:mod:`controller.cell.scenario`: same keys, same readers, same errors), except that the
masters are encoder nodes of this bus and each robot names its drives.  Units: mm, mm/s,
deg, s; master values in master units (mm of belt).  ``*`` = required::

    .tracking:
      cell:
        encoders:*                   # the master axes: name -> a CiA 406 encoder node
          belt_a: {node:* enc_a, counts_per_mm:* 40.96}   # .tracking.conveyor's keys
          belt_b: {node:* enc_b, counts_per_mm:* 40.96,   #   except origin and direction
                   sign: -1, estimator: {window: 16}}     #   (a frame places its belt)
        frames:*                     # cell scenario frames; masters: encoder names
          - {name: A, masters: [belt_a], direction: [1, 0, 0],
             window: {upstream: 50, downstream: 1500}}
          - {name: B, masters: [belt_b], origin: [600, -300, 0], direction: [0, 1, 0],
             window: {upstream: 50, downstream: 1200}}
        robots:*                     # cell scenario robots, plus their drives:
          - name: r1
            kinematics:*             #   .tracking.kinematics of this robot: the machine
              type: cartesian        #   type and its axes (drives), named within the robot
              axes: {x: {node: x1, counts_per_mm: 10000}, y: {...}, z: {...}}
            start*: [300, 200, 100]  #   start, base, tool, slave, buffer_capacity, motion
            track_types: {A: [1]}    #   per frame: the item types tracked (default: all)
            master_frame:            #   timed MasterFrame changes (s since tracking began)
              - {time_s: 0.1, frame: A}
              - {time_s: 2.0, frame: B}     # hand-off
            # or program: {frame: A, approach_mm: 50, dwell_s: 0.1, place: [..]}
        sensors:                     # item sensors (cell scenario sensors)
          - {frame: A, trigger_times: [0.05], types: [1]}
      tracker: {...}                 # as without a cell: one tracker set for every robot
      cycle, timeouts, reactions     # as without a cell

The cell runs on the bus with :class:`controller.canopen.apps.cell.CellSource` (``cantrack
demo``, ``cantrack run``; docs/spec/conveyor-extensions.md#5.1).

The type and dimension a robot tracks with (:class:`controller.conveyor.Kinematics`, checked
against each frame's ``world``) follow from its drives: ``cartesian`` over x, y -> dimension
2, with z -> 3, with c -> 4.  A drive belongs to one robot; a robot's axis names are its own
(two robots may both have x, y, z).  Errors are :class:`controller.errors.ConfigError`
naming file, line and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING

from ...cell.scenario import (CellFrameSpec, CellRobotSpec, SensorSpec, read_cell_robot,
                              read_layout)
from ...conveyor import Kinematics, RobotType
from ...errors import ParameterError
from ...kinematics import KINEMATICS, CountsConverter, create
from ...kinematics import Kinematics as MachineKinematics
from ...yamlmarks import Section
from .tracking import AxisConfig, ConveyorConfig, read_axes, read_encoder

if TYPE_CHECKING:
    from .bus import ControllerConfig

__all__ = ["CellConfig", "CellRobotConfig", "parse_cell_config", "robot_kinematics"]


@dataclass(frozen=True)
class CellRobotConfig:
    """One robot of the cell: the robot group (:class:`CellRobotSpec`: start, base, tool,
    slave, limits, tracked types, program or MasterFrame changes) and its drives."""

    spec: CellRobotSpec
    kinematics: str                      #: the machine type (controller.kinematics)
    axes: tuple[AxisConfig, ...]         #: its drives, in order; names within the robot

    @property
    def name(self) -> str:
        return self.spec.name

    def machine(self) -> MachineKinematics:
        """This robot's own kinematics over its own axes (tool pose [mm, deg] <-> joints)."""
        return create(self.kinematics, [a.name for a in self.axes])

    def counts(self) -> CountsConverter:
        """Joints [mm | deg] <-> counts of this robot's drives, in :attr:`axes` order."""
        return CountsConverter([a.scale for a in self.axes])


@dataclass(frozen=True)
class CellConfig:
    """``.tracking.cell``: the encoders by name, the frames, the robots, the sensors."""

    encoders: Mapping[str, ConveyorConfig]   #: read-only
    frames: tuple[CellFrameSpec, ...]
    robots: tuple[CellRobotConfig, ...]
    sensors: tuple[SensorSpec, ...]

    def robot(self, name: str) -> CellRobotConfig:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(name)

    @property
    def axes(self) -> tuple[AxisConfig, ...]:
        """Every robot's drives, robot by robot."""
        return tuple(a for r in self.robots for a in r.axes)


def robot_kinematics(kind: str, axes: tuple[str, ...]) -> Kinematics:
    """The type and dimension a robot of machine type ``kind`` over ``axes`` tracks with."""
    if kind != "cartesian":            # KINEMATICS has only cartesian today
        raise ParameterError(f"kinematics type (={kind!r}) has no conveyor robot type")
    dim = 4 if "c" in axes else 3 if "z" in axes else 2
    return Kinematics(RobotType.CARTESIAN, dim)


def _robot(node: Section, frames: Mapping[str, CellFrameSpec], cfg: ControllerConfig,
           used: dict[str, str]) -> CellRobotConfig:
    name = node.string("name", "robot")
    kin = node.section("kinematics")
    kind = kin.str("type", "cartesian", choices=list(KINEMATICS))
    axes = read_axes(kin.section("axes"), cfg, str(name))
    kin.finish()
    for a in axes:
        if a.node in used:
            raise kin.error("axes", f"drive {a.node!r} already belongs to robot "
                                    f"{used[a.node]!r}: a drive moves one robot")
        used[a.node] = str(name)
    names = tuple(a.name for a in axes)
    try:
        create(kind, names)
        world = robot_kinematics(kind, names)
    except ParameterError as exc:
        raise kin.error("axes", str(exc)) from None
    spec = read_cell_robot(node, frames, math.inf, kinematics=world)
    return CellRobotConfig(spec, kind, axes)


def parse_cell_config(cn: Section, cfg: ControllerConfig) -> CellConfig:
    """Read ``.tracking.cell`` (``cn``) of the bus ``cfg``."""
    cn.check_keys(("encoders", "frames", "robots", "sensors"))
    en = cn.section("encoders")
    encoders: dict[str, ConveyorConfig] = {}
    nodes: dict[str, str] = {}
    for key, _ in list(en.items()):
        sec = en.section(key)
        for k in ("origin", "direction"):
            if sec.has(k):
                raise sec.error(k, "a cell's frame places its belt (frames: origin, "
                                   "direction); an encoder gives only its counts",
                                at_value=False)
        enc = read_encoder(sec, cfg)
        if enc.node in nodes:
            raise sec.error("node", f"(={enc.node!r}) is already the encoder "
                                    f"{nodes[enc.node]!r}")
        nodes[enc.node] = str(key)
        encoders[str(key)] = enc
    if not encoders:
        raise cn.error("encoders", "must name at least one encoder")
    used: dict[str, str] = {}
    frames, robots, sensors = read_layout(
        cn, encoders, math.inf, lambda node, fr: _robot(node, fr, cfg, used))
    return CellConfig(MappingProxyType(encoders), tuple(frames.values()), robots, sensors)
