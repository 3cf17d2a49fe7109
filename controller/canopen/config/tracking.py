"""The ``.tracking:`` section of bus.yml: what the controller does with the bus.

Units: mm, mm/s, mm/s^2, mm/s^3, deg, s (counts only as ``counts_per_mm``/``counts_per_deg``
scales).  Keys (``*`` = required)::

    .tracking:
      cell:                          # a work cell (several encoders, frames, robots: see
                                     #   controller.canopen.config.cell) instead of
                                     #   conveyor, kinematics, window and items
      conveyor:*                     # the master axis (a CiA 406 encoder)
        node:* encoder               # slave name
        index: 0x6004                # object with the position, mapped in a TPDO that is
        sub_index: 0                 #   sent on every SYNC (transmission 1)
        counts_per_mm:* 40.96        # encoder counts per mm of belt travel (> 0)
        sign: 1                      # +1 / -1: counting direction vs. belt direction
        modulus: 16777216            # wrap of the count (6002h); default: the slave's
                                     #   sdo write of 6002h, else the EDS default, else 0
        origin: [0, 0, 0]            # machine position [mm] of belt coordinate 0
        direction: [1, 0, 0]         # belt direction in machine coordinates (normalised)
        estimator: {window: 16, degree: 2}   # controller.tracking.MasterEstimator
        conditioning:                # instead of estimator: the master conditioner
                                     #   (controller.tracking.conditioning; counts of
                                     #   1/counts_per_mm, VelocityMax/AccelerationMax from
                                     #   tracker.master_max_trans)
          jerk_max: 5000             # the belt's JerkMax [mm/s^3]
          design: kinematic          # kinematic | otg
          jerk_reserve: 3            # output jerk up to (1 + this) x jerk_max
          outlier_mm: 0.25           # outlier gate (default max(0.25 mm, 5 counts))
          max_outliers: 10           # consecutive outliers: master lost (de-sync)
        silent_cycles: 5             # no sample for this many cycles -> de-sync on the
                                     #   extrapolated master (>= 1)
      kinematics:*
        type: cartesian              # controller.kinematics.KINEMATICS
        axes:*                       # drive order; x, y, z in mm, c in deg
          x: {node:* x, counts_per_mm:* 1000, zero: 0, sign: 1, min: -1e9, max: 1e9}
          c: {node:* c, counts_per_deg:* 1000, ...}
          y:                         # optional per axis, for home/move/jog (axis_motion):
            motion: {vel: 200, acc: 2000, jerk: 50000,      # limits [mm/s, mm/s^2, mm/s^3]
                     brake_release_s: 0, brake_engage_s: 0, stop_time_s: 0}
            homing:
              method: gotoy          # gotoy (slow-down + home switch, 60FDh bits 16 / 2)
                                     #   | drive (the drive's homing mode 6060h = 6) | none
              direction: -1          # gotoy: search towards -1 / +1
              search_vel: 50         # gotoy: CONST speed [mm/s] (<= motion.vel)
              creep_vel: 5           # gotoy: SMALL_V/DOGE/BACK speed [mm/s] (<= search)
              push_in_counts: 0      # gotoy: DOGE push-in m [drive counts]
              back_off: 0            # gotoy: BACK distance [mm]
              timeout_s: 60          # gotoy: whole procedure; drive: "homing attained"
              state_timeouts: {small_v_s: 10}   # gotoy: per state (HomingTimeouts fields)
              home_offset: 0         # none: raw position [mm] of the axis' 0;
                                     #   drive: 607Ch [mm]; gotoy: what the latched
                                     #   home reads afterwards [mm] (drive position set)
              touch_probe: false     # gotoy: the home switch is also wired to the drive's
                                     #   touch-probe-1 input: 60B8h armed (SDO) before the
                                     #   search, home = the drive's latch of 6064h at the
                                     #   switch edge (60BAh, read by SDO once DNP is seen)
                                     #   instead of the setpoint of the sample; no edge
                                     #   stored (60B9h bit 1) is an error.  The drive's EDS
                                     #   must have 60B8h, 60B9h, 60BAh
              drive_method: 19       # drive: 6098h
              switch_vel: 50         # drive: 6099h:01 [mm/s]
              zero_vel: 5            # drive: 6099h:02 [mm/s]
              drive_acc: 500         # drive: 609Ah [mm/s^2]
      tracker:                       # controller.tracking.TrackerParams fields except
        planner: optimal             #   sample_time_s (= master.sync_period)
        mode: absolute               # absolute | relative | 3 | 5
        sync_trans: {vel: 2000, acc: 20000, jerk: 400000}   # and every other field; sync/
                                     #   desync not given: robot_max_* (docs/spec/tracking.md#2.5)
      window: {start: 200, end: 900} # pick window along the conveyor direction [mm]
      items:                         # item classification (docs/spec/conveyor-extensions.md#3)
        track_types: [1, 2]          # the item types the robot tracks (0...255; default:
                                     #   every type); the others are never engaged or missed
      cycle:
        compute_at: 0.5              # the cycle computes at the latest this fraction of the
                                     #   period after its SYNC (inputs late -> stale)
        max_missed_in_row: 25        # quick stop after this many SYNC deadlines missed in a
                                     #   row ("deadlines_missed"; 0 = never)
        drive_delay_cycles: 1        # a drive reaches the target it applies at SYNC k+1 at
                                     #   SYNC k+1+this (CSP interpolation over one period);
                                     #   the master is predicted that much further ahead
      timeouts:                      # [s]
        boot_up_s: 2.0               # NMT reset -> boot-up message
        sdo_s: 0.5                   # one SDO request -> response
        sdo_retries: 1               # an unanswered SDO request is sent again (a node that
                                     #   was still resetting when its boot-up came in)
        enable_s: 2.0                # 402 enable: switch on disabled -> operation enabled
        stop_s: 1.0                  # controlled stop: per stage (quick stop, then each
                                     #   escalation step) until the statusword confirms
      reactions:                     # to other actors (controller.canopen.reactions):
        foreign_nmt: quick_stop      #   quick_stop | report, per disturbance
        bad_frame: report
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ...errors import ConfigError, ParameterError
from ...kinematics import KINEMATICS, AxisScale
from ...limits import Limits
from ...tracking import PLANNERS, Mode, Rates, SoftMcOptions, TrackerParams
from ...tracking.conditioning import ConditionerDesign
from ...yamlmarks import Section
from ..protocol import od as odm
from .reactions import Reactions, parse_reactions

if TYPE_CHECKING:
    from .bus import ControllerConfig
    from .cell import CellConfig

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class ConveyorConfig:
    node: str
    index: int
    sub_index: int
    counts_per_mm: float
    sign: int
    modulus: int
    origin: Vec3
    direction: Vec3
    window: int
    degree: int
    silent_cycles: int
    #: the master conditioner instead of the estimator (None: the estimator)
    conditioning: "ConveyorConditioning | None" = None


@dataclass(frozen=True, slots=True)
class ConveyorConditioning:
    """``conveyor.conditioning``: mm/s^3, mm (docs/spec/master-conditioning.md)."""

    jerk_max: float = 5000.0
    design: ConditionerDesign = ConditionerDesign.KINEMATIC
    jerk_reserve: float = 3.0
    outlier_mm: float | None = None
    max_outliers: int = 10


@dataclass(frozen=True, slots=True)
class AxisMotionConfig:
    """Per-axis ``motion:`` section: the axis' limits and brake times for point-to-point
    moves, homing and jog (``motion.vel``/``acc``/``jerk`` in the YAML, [mm/s, mm/s^2,
    mm/s^3] or, for a rotary axis, [deg/s, ...]; times [s])."""

    limits: Limits = Limits(200.0, 2000.0, 50000.0)
    brake_release_s: float = 0.0
    brake_engage_s: float = 0.0
    stop_time_s: float = 0.0


HOMING_METHODS = ("gotoy", "drive", "none")
_STATE_TIMEOUTS = ("brake_s", "accel_s", "const_s", "deaccel_s", "small_v_s", "doge_s",
                   "back_s")


@dataclass(frozen=True, slots=True)
class AxisHomingConfig:
    """Per-axis ``homing:`` section (see the module docstring)."""

    method: str = "gotoy"
    direction: int = -1
    search_vel: float = 50.0
    creep_vel: float = 5.0
    push_in_counts: int = 0
    back_off: float = 0.0
    timeout_s: float = 60.0
    state_timeouts: tuple[tuple[str, float], ...] = ()
    home_offset: float = 0.0
    drive_method: int = 19
    switch_vel: float | None = None
    zero_vel: float | None = None
    drive_acc: float | None = None
    touch_probe: bool = False


@dataclass(frozen=True, slots=True)
class AxisConfig:
    name: str
    node: str
    scale: AxisScale
    motion: AxisMotionConfig = AxisMotionConfig()
    homing: AxisHomingConfig | None = None
    #: the robot the drive belongs to in a cell (``.tracking.cell.robots``; "" otherwise)
    robot: str = ""


@dataclass(frozen=True, slots=True)
class Timeouts:
    boot_up_s: float = 2.0
    sdo_s: float = 0.5
    enable_s: float = 2.0
    sdo_retries: int = 1
    #: time a drive gets per stage of the controlled stop to confirm it by its statusword
    #: (quick stop, then each escalation step: :mod:`controller.canopen.stopping`) [s]
    stop_s: float = 1.0


@dataclass(frozen=True)
class TrackingConfig:
    conveyor: ConveyorConfig
    kinematics: str
    axes: tuple[AxisConfig, ...]
    tracker: TrackerParams
    window: tuple[float, float]
    compute_at: float
    timeouts: Timeouts
    drive_delay_cycles: int = 1
    #: the item types the robot tracks (None: every type)
    track_types: frozenset[int] | None = None
    #: the reaction to each disturbance by another actor (:mod:`.reactions`)
    reactions: Reactions = field(default_factory=Reactions)
    #: quick stop after this many SYNC deadlines missed in a row (0: never)
    max_missed_in_row: int = 25
    #: a work cell of several encoders, frames and robots (``.tracking.cell``, :mod:`.cell`);
    #: then ``conveyor`` is its first encoder and ``axes`` every robot's drives
    cell: CellConfig | None = None

    @property
    def drive_nodes(self) -> tuple[str, ...]:
        return tuple(a.node for a in self.axes)

    @property
    def encoders(self) -> tuple[ConveyorConfig, ...]:
        """Every master encoder: the cell's, else the conveyor's."""
        return tuple(self.cell.encoders.values()) if self.cell is not None else (self.conveyor,)


def parse_tracking(s: Section, cfg: ControllerConfig) -> TrackingConfig:
    if s.has("cell"):
        return _parse_cell(s, cfg)
    conveyor = read_encoder(s.section("conveyor"), cfg)
    kin = s.section("kinematics")
    kind = kin.str("type", "cartesian", choices=list(KINEMATICS))
    axes = read_axes(kin.section("axes"), cfg)
    kin.finish()
    try:
        from ...kinematics import create
        create(kind, [a.name for a in axes])
    except ParameterError as exc:
        raise kin.error("axes", str(exc)) from None
    return _parse_common(s, cfg, conveyor, kind, axes)


#: the keys of one belt and one robot, which a cell gives in ``.tracking.cell``
SINGLE_FRAME_KEYS = ("conveyor", "kinematics", "window", "items")


def _parse_cell(s: Section, cfg: ControllerConfig) -> TrackingConfig:
    """``.tracking`` with a ``cell``: ``conveyor`` is the cell's first encoder, ``axes``
    every robot's drives (robot by robot), ``kinematics`` the first robot's type."""
    from .cell import parse_cell_config

    for k in SINGLE_FRAME_KEYS:
        if s.has(k):
            raise s.error(k, "is a key of one belt and one robot: a cell gives its encoders, "
                             "frames and robots in .tracking.cell", at_value=False)
    cell = parse_cell_config(s.section("cell"), cfg)
    return _parse_common(s, cfg, next(iter(cell.encoders.values())),
                         cell.robots[0].kinematics, cell.axes, cell)


def _parse_common(s: Section, cfg: ControllerConfig, conveyor: ConveyorConfig, kind: str,
                  axes: tuple[AxisConfig, ...], cell: CellConfig | None = None
                  ) -> TrackingConfig:
    tracker = _tracker(s.section("tracker", {}), cfg.period_s)
    w = s.section("window", {})
    start = w.float("start", -math.inf)
    end = w.float("end", math.inf)
    if not start < end:
        raise w.error("end", f"(={end}) must be > start (={start})")
    w.finish()
    track_types = None
    it = s.section("items", {})
    if it.has("track_types"):
        types = []
        for v, line, path in it.list("track_types"):
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
                raise ConfigError(f"(={v!r}) must be an item type, an integer in [0...255]",
                                  file=it.file, line=line, key=path)
            types.append(v)
        if not types:
            raise it.error("track_types", "must list at least one item type (leave the key "
                                          "out to track every type)")
        track_types = frozenset(types)
    it.finish()
    c = s.section("cycle", {})
    compute_at = c.float("compute_at", 0.5, min=0.05, max=0.95)
    max_missed_in_row = c.int("max_missed_in_row", 25, min=0, max=1_000_000)
    delay = c.int("drive_delay_cycles", 1, min=0, max=10)
    c.finish()
    t = s.section("timeouts", {})
    timeouts = Timeouts(boot_up_s=t.float("boot_up_s", 2.0, above=0.0),
                        sdo_s=t.float("sdo_s", 0.5, above=0.0),
                        enable_s=t.float("enable_s", 2.0, above=0.0),
                        sdo_retries=t.int("sdo_retries", 1, min=0, max=10),
                        stop_s=t.float("stop_s", 1.0, above=0.0, max=60.0))
    t.finish()
    reactions = parse_reactions(s.section("reactions", {}))
    s.finish()
    return TrackingConfig(conveyor, kind, axes, tracker, (start, end), compute_at, timeouts,
                          delay, track_types, reactions, max_missed_in_row, cell)


def _slave_ref(s: Section, key: str, cfg: ControllerConfig, profile: int, what: str) -> str:
    name = s.str(key)
    if name not in cfg.slaves:
        from ...yamlmarks import suggest
        raise s.error(key, f"(={name!r}) is not a slave of this bus" + suggest(name, cfg.slaves))
    prof = odm.profile(cfg.ods[name])
    if prof != profile:
        raise s.error(key, f"(={name!r}) must be a CiA {profile} {what}; its EDS "
                           f"{cfg.slaves[name].dcf.name} has device profile {prof}")
    return name


def read_encoder(s: Section, cfg: ControllerConfig) -> ConveyorConfig:
    """A master axis: a CiA 406 encoder node of the bus (``.tracking.conveyor``'s keys)."""
    from .concise import effective_pdos
    node = _slave_ref(s, "node", cfg, odm.PROFILE_ENCODER, "encoder")
    index = s.int("index", 0x6004, min=0x1000, max=0xFFFF)
    sub = s.int("sub_index", 0, min=0, max=0xFF)
    od = cfg.ods[node]
    if odm.variable(od, index, sub) is None:
        raise s.error("index", f"object {index:04X}h:{sub:02X} does not exist in "
                               f"{cfg.slaves[node].dcf.name}")
    pdo = effective_pdos(cfg)[node].find("tpdo", [(index, sub)])
    if pdo is None or pdo.transmission != 1:
        raise s.error("index", f"{index:04X}h:{sub:02X} of '{node}' must be mapped in an "
                               "enabled TPDO with transmission 1 (every SYNC)")
    modulus = s.int("modulus", None, min=0, max=0xFFFFFFFF)
    if modulus is None:
        modulus = _configured_value(cfg, node, 0x6002, 0)
    direction = s.vector("direction", 3, (1.0, 0.0, 0.0))
    n = math.sqrt(sum(x * x for x in direction))
    if n == 0:
        raise s.error("direction", "must not be the zero vector")
    est = s.section("estimator", {})
    window = est.int("window", 16, min=3, max=256)
    degree = est.int("degree", 2, allowed=(1, 2))
    est.finish()
    conditioning = None
    if s.has("conditioning"):
        if s.has("estimator"):
            raise s.error("conditioning", "give either estimator or conditioning, not both")
        cs = s.section("conditioning", {})
        designs = {d.name.lower(): d for d in ConditionerDesign}
        design = cs.str("design", "kinematic", choices=tuple(designs))
        outlier = cs.float("outlier_mm", None, above=0.0) if cs.has("outlier_mm") else None
        conditioning = ConveyorConditioning(
            jerk_max=cs.float("jerk_max", 5000.0, above=0.0),
            design=designs[design],
            jerk_reserve=cs.float("jerk_reserve", 3.0, min=0.0, max=100.0),
            outlier_mm=outlier,
            max_outliers=cs.int("max_outliers", 10, min=1, max=100_000))
        cs.finish()
    conv = ConveyorConfig(
        node=node, index=index, sub_index=sub,
        counts_per_mm=s.float("counts_per_mm", above=0.0),
        sign=s.int("sign", 1, allowed=(1, -1)), modulus=modulus,
        origin=s.vector("origin", 3, (0.0, 0.0, 0.0)),
        direction=(direction[0] / n, direction[1] / n, direction[2] / n),
        window=window, degree=degree,
        silent_cycles=s.int("silent_cycles", 5, min=1, max=10_000),
        conditioning=conditioning)
    s.finish()
    return conv


def _configured_value(cfg: ControllerConfig, node: str, index: int, sub: int) -> int:
    for w in cfg.slaves[node].sdo:
        if w.index == index and w.sub_index == sub:
            return w.value
    var = odm.variable(cfg.ods[node], index, sub)
    value = odm.default_value(var) if var is not None else None
    return int(value or 0)


def read_axes(s: Section, cfg: ControllerConfig, robot: str = "") -> tuple[AxisConfig, ...]:
    """The drives of a robot (``.tracking.kinematics.axes``; ``robot``: its name in a cell)."""
    from .concise import effective_pdos
    pdos = effective_pdos(cfg)
    out = []
    used: dict[str, str] = {}
    for name, _ in list(s.items()):
        a = s.section(name)
        node = _slave_ref(a, "node", cfg, odm.PROFILE_DRIVE, "drive")
        if node in used:
            raise a.error("node", f"(={node!r}) already drives axis {used[node]}")
        used[node] = str(name)
        unit_key = "counts_per_deg" if name == "c" else "counts_per_mm"
        cpu = a.float(unit_key, above=0.0)
        lo = a.float("min", -math.inf)
        hi = a.float("max", math.inf)
        if not lo < hi:
            raise a.error("max", f"(={hi}) must be > min (={lo})")
        scale = AxisScale(str(name), cpu, a.float("zero", 0.0),
                          a.int("sign", 1, allowed=(1, -1)), lo, hi)
        motion = _axis_motion(a.section("motion", None))
        homing = _axis_homing(a.section("homing", None), motion, cfg, node)
        a.finish()
        rp = pdos[node].find("rpdo", [(0x6040, 0), (0x607A, 0)])
        tp = pdos[node].find("tpdo", [(0x6041, 0), (0x6064, 0)])
        if rp is None or not (0 <= rp.transmission <= 240):
            raise a.error("node", f"'{node}' needs an enabled synchronous RPDO (transmission "
                                  "0...240) mapping 6040h and 607Ah")
        if tp is None or tp.transmission != 1:
            raise a.error("node", f"'{node}' needs an enabled TPDO with transmission 1 "
                                  "mapping 6041h and 6064h")
        out.append(AxisConfig(str(name), node, scale, motion, homing, robot))
    if not out:
        raise s.error(next(iter(s.data), "axes"), "at least one axis is required")
    return tuple(out)


def _axis_motion(s: Section | None) -> AxisMotionConfig:
    d = AxisMotionConfig()
    if s is None:
        return d
    out = AxisMotionConfig(
        Limits(s.float("vel", d.limits.vel, above=0.0), s.float("acc", d.limits.acc, above=0.0),
               s.float("jerk", d.limits.jerk, above=0.0)),
        brake_release_s=s.float("brake_release_s", 0.0, min=0.0),
        brake_engage_s=s.float("brake_engage_s", 0.0, min=0.0),
        stop_time_s=s.float("stop_time_s", 0.0, min=0.0))
    s.finish()
    return out


#: touch probe 1 objects GotoY uses with ``touch_probe: true``
TOUCH_PROBE_OBJECTS = ((0x60B8, "touch probe function"), (0x60B9, "touch probe status"),
                       (0x60BA, "touch probe 1 positive edge position"))


def _axis_homing(s: Section | None, motion: AxisMotionConfig, cfg: ControllerConfig | None = None,
                 node: str | None = None) -> AxisHomingConfig | None:
    if s is None:
        return None
    d = AxisHomingConfig()
    method = s.str("method", d.method, choices=HOMING_METHODS)
    search = s.float("search_vel", min(d.search_vel, motion.limits.vel), above=0.0,
                     max=motion.limits.vel)
    creep = s.float("creep_vel", min(d.creep_vel, search), above=0.0, max=search)
    st = s.section("state_timeouts", None)
    state_timeouts: list[tuple[str, float]] = []
    if st is not None:
        for key in _STATE_TIMEOUTS:
            if st.has(key):
                state_timeouts.append((key, st.float(key, above=0.0)))
        st.finish()
    drive_method = s.int("drive_method", d.drive_method, min=-128, max=127)
    if method == "drive":
        from ...motion import DriveHomingConfig
        try:
            DriveHomingConfig(drive_method, 1.0)
        except ParameterError as exc:
            raise s.error("drive_method", str(exc)) from None
    out = AxisHomingConfig(
        method=method, direction=s.int("direction", d.direction, allowed=(-1, 1)),
        search_vel=search, creep_vel=creep,
        push_in_counts=s.int("push_in_counts", 0, min=0),
        back_off=s.float("back_off", 0.0, min=0.0),
        timeout_s=s.float("timeout_s", d.timeout_s, above=0.0),
        state_timeouts=tuple(state_timeouts),
        home_offset=s.float("home_offset", 0.0),
        drive_method=drive_method,
        switch_vel=s.float("switch_vel", None, above=0.0),
        zero_vel=s.float("zero_vel", None, above=0.0),
        drive_acc=s.float("drive_acc", None, above=0.0),
        touch_probe=s.bool("touch_probe", False))
    if out.touch_probe and method != "gotoy":
        raise s.error("touch_probe", f"(=true) only applies to method gotoy, not {method}")
    if out.touch_probe and cfg is not None and node is not None:
        missing = [f"{index:04X}h ({what})" for index, what in TOUCH_PROBE_OBJECTS
                   if odm.variable(cfg.ods[node], index, 0) is None]
        if missing:
            raise s.error("touch_probe", f"(=true) needs touch probe 1 in the drive's EDS "
                                         f"{cfg.slaves[node].dcf.name}: missing "
                                         + ", ".join(missing))
    s.finish()
    return out


# -- TrackerParams -------------------------------------------------------------------------
_LIMIT_FIELDS = ("vel", "acc", "jerk")


def _limits(s: Section, default: Limits | None) -> Limits:
    if default is None:
        vals = {k: s.float(k, above=0.0) for k in _LIMIT_FIELDS}
    else:
        vals = {k: s.float(k, getattr(default, k), above=0.0) for k in _LIMIT_FIELDS}
    s.finish()
    return Limits(**vals)


def _tracker(s: Section, sample_time_s: float) -> TrackerParams:
    base = TrackerParams(sample_time_s=sample_time_s)
    changes: dict[str, Any] = {}
    # the robot's maxima first: the sync/de-sync values not given start at them
    # (docs/spec/tracking.md#2.5)
    keys = sorted((f.name for f in dataclasses.fields(TrackerParams)),
                  key=lambda k: not k.startswith("robot_max_"))
    for key in keys:
        if key == "sample_time_s" or not s.has(key):
            continue
        default = getattr(base, key)
        if key in ("sync_trans", "desync_trans", "sync_rot", "desync_rot"):
            robot = changes.get("robot_max_trans" if key.endswith("trans") else "robot_max_rot")
            default = robot if robot is not None else default
        if key == "planner":
            changes[key] = s.str(key, choices=sorted(PLANNERS))
        elif key == "mode":
            raw = s.raw(key)
            names = {"absolute": Mode.ABSOLUTE, "relative": Mode.RELATIVE, 3: Mode.ABSOLUTE,
                     5: Mode.RELATIVE}
            if isinstance(raw, bool) or not isinstance(raw, (str, int)) or raw not in names:
                raise s.error(key, f"(={raw!r}) must be absolute, relative, 3 or 5")
            changes[key] = names[raw]
        elif key in ("sync_trans", "desync_trans", "sync_rot", "desync_rot",
                     "master_max_trans", "master_max_rot"):
            changes[key] = _limits(s.section(key), default)
        elif key in ("robot_max_trans", "robot_max_rot"):
            changes[key] = _limits(s.section(key), None)
        elif key == "rates":
            r = s.section(key)
            changes[key] = Rates(**{k: r.float(k, getattr(default, k), above=0.0, max=100.0)
                                    for k in ("vel", "acc", "dec", "jerk")})
            r.finish()
        elif key == "softmc":
            o = s.section(key)
            start = SoftMcOptions.literal() if o.bool("literal", False) else SoftMcOptions()
            vals: dict[str, Any] = {g.name: o.bool(g.name, getattr(start, g.name))
                    for g in dataclasses.fields(SoftMcOptions)}
            o.finish()
            changes[key] = SoftMcOptions(**vals)
        elif isinstance(default, bool):
            changes[key] = s.bool(key)
        elif key == "max_flops":
            changes[key] = s.int(key, min=1)
        else:
            changes[key] = s.float(key, above=0.0)
    if s.has("sample_time_s"):
        raise s.error("sample_time_s", "is not set here: the sample time is the SYNC period "
                                       "(master.sync_period)", at_value=False)
    s.finish()
    try:
        return TrackerParams(sample_time_s=sample_time_s, **changes)
    except ParameterError as exc:
        raise ConfigError(str(exc), file=s.file, line=s.line, key=s.path) from None
