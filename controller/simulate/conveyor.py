"""Conveyor scenarios of ``cantrack simulate``: a moving frame, items, a robot doing picks.

A scenario file with a top-level ``conveyor:`` key is a conveyor scenario (the tracking
scenarios without it are unchanged).  Units: mm, mm/s, deg, s; master values in "master
units" (what the conveyor's axis counts: mm of belt, deg of table, ...).  ``*`` = required::

    name: "belt, 300 mm/s"
    duration_s*: 8.0
    tracker*:                        # the tracking scenarios' section (TrackerParams fields;
      sample_time_s*: 0.002          #   ``mode`` is ignored: conveyor.robot.slave decides)
      planner*: softmc
      sync_trans: {vel: 2000, acc: 20000, jerk: 400000}
    conveyor*:
      frame*:
        name: cnv                    # default cnv
        type: linear                 # linear | rotary | rotary_decoupled | 0 | 1 | 2
        origin: [0, 0, 0]            # linear: MF.zero (the trigger point), a position or
                                     #   {position: [..], axis: [..], angle_deg: ..}
        direction: [1, 0, 0]         # linear: the direction of the DOF
        scale_mm_per_unit: 1.0       # linear: mm per master unit
        upstream: {position: [600, -400, 0], axis: [0, 0, 1], angle_deg: 0}   # rotary
        arc_point: [1000, 0, 0]      # rotary
        downstream: [600, 400, 0]    # rotary
        up_master: 0                 # rotary: master value at UpStream[1]
        down_master: 180             # rotary: master value at DownStream[1]
        window*: {upstream: 100, downstream: 900}   # relative to the trigger: mm / deg
        limits: {VelocityMaxTrans: 1000, AccelerationMaxTrans: 1000, ...}   # softMC's names
      master*:                       # the conveyor's master axis [master units]
        start: 0                     # value at t = 0
        speed: 300                   # constant speed [unit/s] ... or
        profile: {segments: [...]}   # ... the tracking scenarios' segment master (x used)
        encoder: {counts_per_unit: 100, modulus: 65536, window: 16}   # optional: counts,
                                     #   wrap-around, estimated velocity (MasterEstimator)
        log: encoder.csv             # replay a recorded encoder log (needs encoder)
      items*:                        # the item sensor: one of
        trigger_times: [0.1, 0.9]    #   sensor times [s]
        radius_offsets_mm: [0, -30]  #   optional, one per time (rotary: dR)
        types: [1, 2]                #   optional, the item type per time (0...255; default 0)
        csv: items.csv               #   time_s[, dr_mm][, inverse][, type]
        log: triggers.csv            #   replay: sample, robot, frame, values, dr_mm, inverse
                                     #   (robot, frame: this scenario's names, else an error)
      robot*:
        name: robot
        start*: [300, 350, 100]      # TCP (world) at t = 0: a position or a location
        base: {position: [..], axis: [..], angle_deg: ..}    # robot base frame
        tool: {position: [..], axis: [..], angle_deg: ..}    # tool frame
        slave: 5                     # 3 | 5 (the program: see PickProgram)
        buffer_capacity: 32
        track_types: [1]             # the item types it tracks (default: every type)
        motion: {vel: 800, acc: 8000, jerk: 200000, rot_vel: 180, rot_acc: 1800,
                 rot_jerk: 36000}
      program:                       # the pick program (see PickProgram)
        approach_mm: 50              # hover height above the item before going down
        dwell_s: 0.1                 # synchronised at the item ("grip")
        place: [300, 600, 100]       # where picked items go (world TCP)
        predict: true                # ask "can it catch this item?" first, skip if not

Errors are :class:`controller.errors.ConfigError` naming file, line and key (the same
machinery as the tracking scenarios).

The run (:func:`run_conveyor`): a :class:`controller.conveyor.ConveyorCell` with the frame
and the robot; per sample the item sensor's TRIGGERs (latching the exact master value at the
sensor time, or the logged values), the program's commands, then one step.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cell.elements import (FrameSpec, MasterSpec, ProgramSpec, RobotSpec, read_frame,
                             read_master, read_program, read_robot)
from ..cell.program import PickProgram, PickState
from ..cell.reading import MAX_SAMPLES, SampledRun, tracker_params
from ..conveyor import (CatchPrediction, ConveyorCell, EncoderSource, Event, EventKind,
                        MovingFrame, RobotGroup, SimulatedAxis, TriggerBufferFull)
from ..conveyor.frame import LINEAR, TYPE_NAMES, FrameType
from ..conveyor.replay import (TriggerEvent, check_trigger_log, read_trigger_log,
                               write_encoder_log, write_trigger_log)
from ..conveyor.sources import quantise_counts
from ..conveyor.telemetry import ItemRecord, ItemStatus
from ..errors import ConfigError
from ..tracking import Mode, TrackerParams
from ..yamlmarks import Section, check_number

__all__ = ["ConveyorScenario", "ConveyorResult", "PickProgram", "PickState", "parse_conveyor",
           "run_conveyor", "write_conveyor_trace", "write_logs"]


# -- the scenario ------------------------------------------------------------------------
@dataclass(frozen=True)
class ItemSpec:
    """One item: sensor time [s] (or the logged sample) and what the TRIGGER records."""

    time_s: float
    dr_mm: float = 0.0
    inverse: bool = False
    sample: int | None = None
    values: tuple[float, ...] | None = None
    item_type: int = 0


@dataclass(frozen=True)
class ConveyorScenario(SampledRun):
    params: TrackerParams
    duration_s: float
    frame: FrameSpec
    master: MasterSpec
    items: tuple[ItemSpec, ...]
    robot: RobotSpec
    program: ProgramSpec
    name: str = ""
    source: Path | None = None


# -- parsing (uses the tracking scenarios' validation helpers) ----------------------------
def _items(node, duration_s: float, n_samples: int, frame: FrameSpec,
           robot: str) -> tuple[ItemSpec, ...]:
    node.check_keys(("trigger_times", "radius_offsets_mm", "types", "csv", "log"))
    kinds = [k for k in ("trigger_times", "csv", "log") if node.has(k)]
    if len(kinds) != 1:
        raise node.error(kinds[1] if len(kinds) > 1 else "trigger_times",
                         "give exactly one of trigger_times, csv, log")
    if node.has("trigger_times"):
        times = []
        for v, line, path in node.list("trigger_times"):
            times.append(check_number(v, lambda m, line=line, path=path:
                                       node.fail(m, line, path), lo=0.0, hi=duration_s,
                                       hi_open=True, unit="s (the scenario's duration)"))
        drs = [0.0] * len(times)
        if node.has("radius_offsets_mm"):
            items = node.list("radius_offsets_mm")
            if len(items) != len(times):
                raise node.error("radius_offsets_mm", f"must give one value per trigger time "
                                                      f"({len(times)}), got {len(items)}")
            drs = [check_number(v, lambda m, line=line, path=path:
                                 node.fail(m, line, path), unit="mm")
                   for v, line, path in items]
        types = [0] * len(times)
        if node.has("types"):
            items = node.list("types")
            if len(items) != len(times):
                raise node.error("types", f"must give one item type per trigger time "
                                          f"({len(times)}), got {len(items)}")
            types = [check_number(v, lambda m, line=line, path=path:
                                  node.fail(m, line, path), lo=0, hi=255, integer=True)
                     for v, line, path in items]
        if times != sorted(times):
            raise node.error("trigger_times", "times must be in increasing order")
        return tuple(ItemSpec(t, dr, item_type=ty) for t, dr, ty in zip(times, drs, types))
    if node.has("types"):
        raise node.error("types", "goes with trigger_times (a CSV has a type column, a log "
                                  "its own)")
    path = node.file_path(kinds[0])
    if kinds[0] == "log":
        try:
            events = read_trigger_log(path)
        except OSError as exc:
            raise node.error("log", f"cannot read the trigger log {str(path)!r}: "
                                    f"{exc.strerror or exc}") from None
        # the log was recorded for one robot and one frame: replaying it on others would
        # silently run a different cell
        check_trigger_log(events, [robot], [frame.name], path)
        for e in events:
            if not 0 <= e.sample < n_samples:
                raise ConfigError(f"sample {e.sample} is outside the run (0...{n_samples - 1}"
                                  f", duration {duration_s:g} s)", file=str(path),
                                  line=e.line, key="sample")
            if e.values is not None and len(e.values) != 1:
                raise ConfigError(f"expected 1 master value (the frame {frame.name!r} has one "
                                  f"source), got {len(e.values)}", file=str(path),
                                  line=e.line, key="values")
        return tuple(ItemSpec(0.0, e.dr_mm, e.inverse, e.sample, e.values, e.item_type)
                     for e in events)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise node.error("csv", f"cannot read the items CSV {str(path)!r}: "
                                f"{exc.strerror or exc}") from None
    rows = [(i + 1, r) for i, r in enumerate(csv.reader(text.splitlines()))
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigError("the items CSV is empty (expected a header row)", file=str(path),
                          line=1)
    hl, header = rows[0]
    cols = [c.strip().lower() for c in header]
    allowed = ("time_s", "dr_mm", "inverse", "type")
    for c in cols:
        if c not in allowed:
            raise ConfigError(f"unknown column (columns: {', '.join(allowed)})",
                              file=str(path), line=hl, key=c)
    if "time_s" not in cols:
        raise ConfigError("required column missing", file=str(path), line=hl, key="time_s")
    out = []
    prev = -math.inf
    for line, r in rows[1:]:
        if len(r) != len(cols):
            raise ConfigError(f"expected {len(cols)} values, got {len(r)}", file=str(path),
                              line=line)
        vals = {}
        for c, cell in zip(cols, r):
            try:
                vals[c] = float(cell)
            except ValueError:
                raise ConfigError(f"not a number: {cell.strip()!r}", file=str(path),
                                  line=line, key=c) from None
        t = vals["time_s"]
        if not (0.0 <= t < duration_s) or t < prev:
            raise ConfigError(f"time {t!r} s must be in [0...{duration_s:g}) s and not before "
                              "the previous row", file=str(path), line=line, key="time_s")
        prev = t
        ty = vals.get("type", 0.0)
        if not (ty == int(ty) and 0 <= ty <= 255):
            raise ConfigError(f"type {ty!r} must be an integer in [0...255]", file=str(path),
                              line=line, key="type")
        out.append(ItemSpec(t, vals.get("dr_mm", 0.0), bool(vals.get("inverse", 0.0)),
                            item_type=int(ty)))
    return tuple(out)


def parse_conveyor(root: Section, source: Path | None) -> ConveyorScenario:
    """Validate a conveyor scenario (``root``: the scenario's top-level node)."""
    root.check_keys(("name", "duration_s", "tracker", "conveyor"))
    name = root.string("name", "")
    params = tracker_params(root.section("tracker"))
    duration = root.number("duration_s", lo=0.0, lo_open=True, unit="s")
    n = round(duration / params.sample_time_s)
    if n < 1 or n > MAX_SAMPLES:
        raise root.error("duration_s", f"the run has {n} samples: must be in "
                                       f"[1...{MAX_SAMPLES}]")
    cn = root.section("conveyor")
    cn.check_keys(("frame", "master", "items", "robot", "program"))
    frame = read_frame(cn.section("frame"))
    master = read_master(cn.section("master"))
    if master.log is not None and len(master.log) < n + 1:
        raise cn.error("master", f"the encoder log has {len(master.log)} samples, the run "
                                 f"needs {n + 1} (duration {duration:g} s)")
    robot = read_robot(cn.section("robot"))
    items = _items(cn.section("items"), duration, n, frame, robot.name)
    program = read_program(cn.optional_section("program"))
    return ConveyorScenario(params, float(duration), frame, master, items, robot, program,
                            name, source)


# -- the result ------------------------------------------------------------------------------
@dataclass
class ConveyorResult:
    """Arrays over samples 0..N (row 0 = the state before the first step).  Units mm, s."""

    scenario: ConveyorScenario
    time_s: np.ndarray
    master_value: np.ndarray          #: the frame's source value [source units]
    setpoint_pos: np.ndarray          #: (N+1, 3) TCP (world)
    setpoint_ori: np.ndarray          #: (N+1, 4) quaternion
    virtual_pos: np.ndarray           #: (N+1, 3) the virtual robot
    imfs: np.ndarray
    slave: np.ndarray
    item: np.ndarray                  #: id of the item the link tracks (0: none)
    events: list[Event]
    records: list[ItemRecord]
    picks: dict[int, float]
    predictions: dict[int, CatchPrediction]
    skipped: dict[int, str]
    item_paths: dict[int, tuple[np.ndarray, np.ndarray]]
    frame: MovingFrame
    robot: RobotGroup
    triggers: list[TriggerEvent] = field(default_factory=list)
    encoder_log: list[int] | None = None
    #: items the program went for (or that were caught) but not picked: {id: reason}
    unpicked: dict[int, str] = field(default_factory=dict)

    @property
    def sample_time_s(self) -> float:
        return self.scenario.sample_time_s

    def count(self, status: ItemStatus) -> int:
        """The number of items whose last status is ``status``."""
        return sum(1 for r in self.records if r.status == status)

    @property
    def caught(self) -> int:
        return sum(1 for r in self.records if r.caught)

    @property
    def missed(self) -> int:
        return self.count(ItemStatus.MISSED)

    def item_coords(self, item_id: int, k: int) -> tuple[float, ...]:
        """The item's frame coordinates at sample ``k`` (mm / deg from its trigger)."""
        t_ev = self.triggers[[r.item_id for r in self.records].index(item_id)]
        assert t_ev.values is not None  # recorded with the entry's latched values
        return tuple(self.frame.geometry().coords([self.master_value[k]], t_ev.values))

    def item_position(self, item_id: int, k: int) -> np.ndarray:
        """Where item ``item_id`` is at sample ``k`` (``<MF>.here`` of its trigger, world)."""
        t_ev = self.triggers[[r.item_id for r in self.records].index(item_id)]
        geo = self.frame.geometry()
        assert t_ev.values is not None  # recorded with the entry's latched values
        c = geo.coords([self.master_value[k]], t_ev.values)
        z = (0.0,) * geo.nof
        return np.array(geo.point(c, z, z, t_ev.dr_mm).here.pos)


def master_fn(m: MasterSpec):
    if m.profile is not None:
        from .master import build_profile

        prof = build_profile(m.profile)

        def fn(t: float) -> tuple[float, float, float]:
            s = prof.state(t)
            return m.start + s.pos[0] - m.profile.position[0], s.vel[0], s.acc[0]
        return fn
    return lambda t: (m.start + m.speed * t, m.speed, 0.0)


@dataclass
class ConveyorSetup:
    """The objects of a conveyor scenario's run: the cell, its frame, robot and program, the
    master source, the master function (t -> (pos, vel, acc) [master units]) and the encoder
    counts per master unit (1 without an encoder)."""

    cell: ConveyorCell
    frame: MovingFrame
    robot: RobotGroup
    program: "PickProgram"
    source: Any
    fn: Any
    per_unit: float


def build_conveyor(sc: ConveyorScenario) -> ConveyorSetup:
    """The cell of a validated conveyor scenario, at sample 0 (nothing triggered yet)."""
    T = sc.sample_time_s
    fs, ms = sc.frame, sc.master
    fn = master_fn(ms)
    per_unit = 1.0
    if ms.encoder is not None:
        cpu = ms.encoder.counts_per_unit
        per_unit = cpu
        if ms.log is not None:
            counts: Any = list(ms.log)
        else:
            counts = lambda k: quantise_counts(fn(k * T)[0], cpu, ms.encoder.modulus)  # noqa: E731
        source = EncoderSource(T, modulus=ms.encoder.modulus, counts=counts,
                               window=ms.encoder.window, name="encoder")
    else:
        source = SimulatedAxis(fn, "master")
    if fs.type == LINEAR:
        frame = MovingFrame(fs.name, [source], directions=[fs.direction],
                            scales=[fs.scale_mm_per_unit / per_unit], origin=fs.origin,
                            limits=fs.limits, window=fs.window)
    else:
        frame = MovingFrame(fs.name, [source], type=fs.type, upstream=fs.upstream,
                            arc_point=fs.arc_point, downstream=fs.downstream,
                            up_master=fs.up_master * per_unit,
                            down_master=fs.down_master * per_unit, limits=fs.limits,
                            window=fs.window)
    rs = sc.robot
    robot = RobotGroup(rs.name, sc.params.with_(mode=Mode(rs.slave)), start=rs.start,
                       base=rs.base, tool=rs.tool, motion_limits=rs.motion,
                       buffer_capacity=rs.buffer_capacity, default_mode=rs.slave)
    if rs.track_types is not None:
        robot.track_types(frame, rs.track_types)
    cell = ConveyorCell([frame], [robot])
    program = PickProgram(robot, frame, sc.program, rs.slave)
    return ConveyorSetup(cell, frame, robot, program, source, fn, per_unit)


def trigger_values(setup: ConveyorSetup, ms: MasterSpec, time_s: float) -> tuple[float, ...]:
    """What the item sensor's TRIGGER latches at ``time_s`` [s]: the exact master value, or
    the encoder's count then (unwrapped against the frame's continuous value)."""
    fn, frame = setup.fn, setup.frame
    if ms.encoder is None:
        return (fn(time_s)[0],)
    vals = (float(quantise_counts(fn(time_s)[0], ms.encoder.counts_per_unit,
                                  ms.encoder.modulus)),)
    if ms.encoder.modulus:
        from ..tracking import unwrap_counts

        cur = frame.source_values()[0]
        vals = (float(unwrap_counts(int(round(cur)), int(vals[0]), ms.encoder.modulus)),)
    return vals


def run_conveyor(sc: ConveyorScenario) -> ConveyorResult:
    """Run a validated conveyor scenario."""
    T = sc.sample_time_s
    n = sc.n_samples
    ms = sc.master
    setup = build_conveyor(sc)
    cell, frame, robot, program = setup.cell, setup.frame, setup.robot, setup.program
    source, fn = setup.source, setup.fn

    # the item sensor: TRIGGERs after step k, with the exact value at the sensor time
    by_k: dict[int, list[ItemSpec]] = {}
    for it in sc.items:
        k = it.sample if it.sample is not None else int(math.floor(it.time_s / T + 1e-9))
        by_k.setdefault(k, []).append(it)
    triggers: list[TriggerEvent] = []
    rejected: list[Event] = []

    def sense(k: int) -> None:
        for it in by_k.get(k, ()):
            if it.values is not None:
                vals = it.values
            elif ms.log is not None:
                vals = frame.source_values()
            elif ms.encoder is not None:
                vals = trigger_values(setup, ms, it.time_s)
            else:
                vals = (fn(it.time_s)[0],)
            try:
                e = robot.trigger(frame, values=vals, dr_mm=it.dr_mm, inverse=it.inverse,
                                  item_type=it.item_type)
            except TriggerBufferFull as exc:   # reported, never silently dropped
                rejected.append(Event(k, EventKind.TRIGGER_REJECTED, frame.name,
                                      message=str(exc)))
                continue
            triggers.append(TriggerEvent(k, robot.name, frame.name, e.values, e.dr_mm,
                                         e.inverse, e.item_type))

    sp_pos = [robot.setpoint.pos]
    sp_ori = [robot.setpoint.ori]
    vp = [robot.virtual.location.pos]
    imfs, slave, cur = [0], [0], [0]
    mval = [frame.master[0].pos]
    events: list[Event] = []
    last: tuple[Event, ...] = ()
    for k in range(n):
        sense(k)
        program.tick(last)
        out = cell.step()[robot.name]
        last = out.events
        events.extend(rejected)
        rejected.clear()
        events.extend(out.events)
        sp_pos.append(out.setpoint.pos)
        sp_ori.append(out.setpoint.ori)
        vp.append(out.virtual.pos)
        imfs.append(int(out.imfs))
        slave.append(out.slave)
        link = robot.link_for(frame)
        cur.append(link.item.id if link is not None and link.item is not None else 0)
        mval.append(frame.master[0].pos)

    unpicked = dict(program.unpicked)
    for rid in sorted(robot.records):
        rec = robot.records[rid]
        if rec.caught and rid not in program.picks and rid not in unpicked:
            unpicked[rid] = (f"the run ended before the pick (program state "
                             f"{program.state.value!r})" if program.item is not None and
                             program.item.id == rid else "caught, but the program did "
                             "not go for it")
    mv = np.array(mval)
    geo = frame.geometry()
    paths: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    ts = np.arange(n + 1) * T
    for t_ev, rec in zip(triggers, [robot.records[i] for i in sorted(robot.records)]):
        k0 = t_ev.sample
        end = rec.left_sample if rec.left_sample is not None else n
        end = min(n, end + round(0.2 / T))
        ks = np.arange(k0, end + 1, max(1, round(0.01 / T)))
        pts = []
        values = t_ev.values
        assert values is not None  # recorded with the entry's latched values
        for k in ks:
            c = geo.coords([mv[k]], values)
            pts.append(geo.point(c, (0.0,) * geo.nof, (0.0,) * geo.nof, t_ev.dr_mm).here.pos)
        paths[rec.item_id] = (ts[ks], np.array(pts).reshape(-1, 3))
    return ConveyorResult(
        scenario=sc, time_s=ts, master_value=mv, setpoint_pos=np.array(sp_pos),
        setpoint_ori=np.array(sp_ori), virtual_pos=np.array(vp), imfs=np.array(imfs),
        slave=np.array(slave), item=np.array(cur), events=events,
        records=[robot.records[i] for i in sorted(robot.records)], picks=program.picks,
        predictions=program.predictions, skipped=program.skipped, item_paths=paths,
        frame=frame, robot=robot, triggers=triggers,
        encoder_log=list(source.log) if isinstance(source, EncoderSource) else None,
        unpicked=unpicked)


# -- outputs --------------------------------------------------------------------------------
CONVEYOR_TRACE_COLUMNS = ("time_s", "master_value", "setpoint_x_mm", "setpoint_y_mm",
                          "setpoint_z_mm", "setpoint_qw", "setpoint_qx", "setpoint_qy",
                          "setpoint_qz", "virtual_x_mm", "virtual_y_mm", "virtual_z_mm", "imfs",
                          "slave", "item", "events")


def write_conveyor_trace(result: ConveyorResult, path: str | Path) -> Path:
    """One row per sample: master value, TCP setpoint (position, quaternion), virtual robot,
    IMFS, slave, the tracked item's id and the events of that sample (``;``-separated)."""
    path = Path(path)
    r = result
    T = r.sample_time_s
    by_sample: dict[int, list[str]] = {}
    for e in r.events:
        txt = e.kind.value + (f"({e.item})" if e.item is not None else "") + \
            (f"[{e.code}]" if e.code else "")
        by_sample.setdefault(e.sample, []).append(txt)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(CONVEYOR_TRACE_COLUMNS)
        for k in range(len(r.time_s)):
            w.writerow([repr(round(k * T, 12)), repr(float(r.master_value[k]))]
                       + [repr(float(x)) for x in r.setpoint_pos[k]]
                       + [repr(float(x)) for x in r.setpoint_ori[k]]
                       + [repr(float(x)) for x in r.virtual_pos[k]]
                       + [int(r.imfs[k]), int(r.slave[k]), int(r.item[k]),
                          ";".join(by_sample.get(k, ()))])
    return path


def write_logs(result: ConveyorResult, prefix: str | Path) -> tuple[Path, Path | None]:
    """Write ``<prefix>_triggers.csv`` and (with an encoder) ``<prefix>_encoder.csv``: the
    inputs of a deterministic replay (``items: {log: ...}``, ``master: {log: ...}``)."""
    prefix = Path(prefix)
    trig = write_trigger_log(prefix.with_name(prefix.name + "_triggers.csv"), result.triggers)
    enc = None
    if result.encoder_log is not None:
        enc = write_encoder_log(prefix.with_name(prefix.name + "_encoder.csv"),
                                result.sample_time_s, {"encoder": result.encoder_log})
    return trig, enc


def type_name(t: FrameType) -> str:
    return TYPE_NAMES[t]
