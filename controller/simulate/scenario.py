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
    conditioning:                    # optional, instead of estimator: an encoder through the
                                     #   master conditioner (controller.tracking.conditioning,
                                     #   one per axis, the frame's limits from
                                     #   tracker.master_max_trans / master_max_rot)
      resolution_mm: 0.01            # one count [mm] (0: none)
      resolution_deg: 0              # one count of the angle [deg]
      latency_samples: 1             # the sample of time k arrives for sample k + latency
                                     #   (the conditioner predicts it back to k)
      jitter: 0.1                    # sampling instants off by up to this share of T (known
                                     #   to the conditioner, as the CAN shell knows its SYNC
                                     #   lateness); segment masters only
      design: kinematic              # kinematic (default) or otg
      jerk_reserve: 3                # output jerk up to (1 + this) x JerkMax
      outlier_mm: 0.25               # outlier gate [mm] (default max(0.25, 5 counts))
      max_outliers: 10               # consecutive outliers = master lost
      seed: 0                        # of the jitter

Timing: the tracker counts samples k (time k*T).  Row 0 is the robot state before the first
update.  A command at time t acts at sample k = round(t/T): the tracker is told before the
update that computes sample k+1, so sample k is the last sample before the engage (the row 0
of ``controller.tracking.metrics.analyze``).  Times are rounded to the nearest sample.

After its last segment the master keeps its final speed and rotation rate.  Before t = 0
(needed only by the encoder estimator's history) the master moves at its initial speed; a
CSV master holds its first row's values.  A CSV master is interpolated linearly at the sample
times; its first row must be at time <= 0 and its last at or after ``duration_s``.

Conveyor scenarios (a top-level ``conveyor:`` key: a moving frame, items, a robot doing pick
motions) have their own schema, documented in :mod:`controller.simulate.conveyor`; cell
scenarios (a top-level ``cell:`` key: several frames and robots, item sensors, timed
MasterFrame changes) in :mod:`controller.simulate.cell`.

Errors: every problem is a :class:`controller.errors.ConfigError` naming the file, the line
and the key (dotted path such as ``master.segments[1].velocity``), with the allowed range;
an unknown key suggests the closest valid one.  ``TrackerParams``' own ``ParameterError`` is
re-raised as a ConfigError located at the offending value.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..tracking import MotionState, TrackerParams
from ..tracking.conditioning import ConditionerDesign
from ..yamlmarks import (MarkedList, MarkedMap, Section, check_number, closest, load_marked, read_text)
from .master import SegmentError, build_profile
from ..cell.reading import (MAX_POSITION_MM, MAX_SAMPLES, CsvMaster, EncoderSpec, SampledRun,
                      Segment, SegmentMaster, segment_master, tracker_params)

__all__ = ["ConditioningSpec", "CsvMaster", "EncoderSpec", "Scenario", "Segment", "SegmentMaster", "load_scenario",
           "MAX_SAMPLES", "MAX_POSITION_MM"]

_Mapping = MarkedMap
_Sequence = MarkedList
_load_yaml = load_marked

@dataclass(frozen=True)
class ConditioningSpec:
    """An encoder through the master conditioner (``conditioning:`` section)."""

    resolution_mm: float = 0.0
    resolution_deg: float = 0.0
    latency_samples: int = 1
    jitter: float = 0.0
    design: ConditionerDesign = ConditionerDesign.KINEMATIC
    jerk_reserve: float = 3.0
    outlier_mm: float | None = None
    max_outliers: int = 10
    seed: int = 0


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
    conditioning: ConditioningSpec | None = None

    @property
    def engage_samples(self) -> tuple[int, ...]:
        return tuple(round(t / self.params.sample_time_s) for t in self.engage)

    @property
    def disengage_samples(self) -> tuple[int, ...]:
        return tuple(round(t / self.params.sample_time_s) for t in self.disengage)


# -- parsing -----------------------------------------------------------------------------
_TOP_KEYS = ("name", "duration_s", "engage", "disengage", "tracker", "robot", "master",
             "estimator", "conditioning")
def _robot(node: Section) -> MotionState:
    node.check_keys(("position", "c", "velocity", "acceleration", "c_rate", "c_acceleration"))
    zero = (0.0, 0.0, 0.0)
    return MotionState(node.xyz("position", unit="mm"), node.xyz("velocity", zero),
                       node.xyz("acceleration", zero), node.number("c", 0.0, unit="deg"),
                       node.number("c_rate", 0.0, unit="deg/s"),
                       node.number("c_acceleration", 0.0, unit="deg/s^2"))


_CSV_COLUMNS = ("time_s", "x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac")
_CSV_ALIASES = {"t": "time_s", "time": "time_s", "x_mm": "x", "y_mm": "y", "z_mm": "z",
                "c_deg": "c"}


def _csv_master(node: Section) -> CsvMaster:
    node.check_keys(("csv", "window"))
    path = node.file_path("csv")
    window = node.number("window", 16, lo=3, hi=10000, integer=True)
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
            close = closest(c, _CSV_COLUMNS)
            hint = f"; did you mean '{close}'?" if close else ""
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


def _estimator(node: Section) -> EncoderSpec:
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


def _conditioning(node: Section) -> ConditioningSpec:
    node.check_keys(("resolution_mm", "resolution_deg", "latency_samples", "jitter", "design",
                     "jerk_reserve", "outlier_mm", "max_outliers", "seed"))
    design = ConditionerDesign.KINEMATIC
    if node.has("design"):
        raw = node.raw("design")
        names = {d.name.lower(): d for d in ConditionerDesign}
        if raw not in names:
            raise node.error("design", f"value {raw!r} must be one of {', '.join(names)}")
        design = names[raw]
    outlier = (node.number("outlier_mm", lo=0.0, lo_open=True, hi=1e6, unit="mm")
               if node.has("outlier_mm") else None)
    return ConditioningSpec(
        resolution_mm=node.number("resolution_mm", 0.0, lo=0.0, hi=1e3, unit="mm"),
        resolution_deg=node.number("resolution_deg", 0.0, lo=0.0, hi=360.0, unit="deg"),
        latency_samples=node.number("latency_samples", 1, lo=0, hi=100, integer=True),
        jitter=node.number("jitter", 0.0, lo=0.0, hi=0.5),
        design=design,
        jerk_reserve=node.number("jerk_reserve", 3.0, lo=0.0, hi=100.0),
        outlier_mm=outlier,
        max_outliers=node.number("max_outliers", 10, lo=1, hi=100000, integer=True),
        seed=node.number("seed", 0, lo=0, hi=2 ** 31, integer=True))


def _times(node: Section, key: str, duration_s: float, required: bool) -> tuple[float, ...]:
    if not node.has(key):
        if required:
            node.raw(key)
        return ()
    value = node.raw(key)
    if isinstance(value, list):
        items = node.list(key)
    else:
        items = [(value, node.value_line(key), node.key_path(key))]
    times = []
    for v, line, path in items:
        times.append(check_number(
            v, lambda msg, line=line, path=path: node.fail(msg, line, path),
            lo=0.0, hi=duration_s, hi_open=True, unit="s (the scenario's duration)"))
    return tuple(times)


def _parse(data: Any, file: str, base_dir: Path, source: Path | None) -> Scenario:
    root = Section(data, file, "", 1 if isinstance(data, (_Mapping, _Sequence)) else None,
                   base_dir=base_dir, root="the scenario")
    if "cell" in root.data:
        # several frames and robots, item sensors, timed MasterFrame changes
        from .cell import parse_cell

        return parse_cell(root, source)
    if "conveyor" in root.data:
        # a conveyor scenario (moving frame, items, robot program): controller.simulate.conveyor
        from .conveyor import parse_conveyor

        return parse_conveyor(root, source)
    root.check_keys(_TOP_KEYS)
    name = root.string("name", "")
    params = tracker_params(root.section("tracker"))
    robot = _robot(root.section("robot"))
    mnode = root.section("master")
    if mnode.has("csv") and mnode.has("segments"):
        raise mnode.error("csv", "give either segments or csv, not both")
    if mnode.has("csv"):
        master: SegmentMaster | CsvMaster = _csv_master(mnode)
        end_s = master.time_s[-1]
    elif mnode.has("segments"):
        master = segment_master(mnode)
        try:
            end_s = build_profile(master).end_s
        except SegmentError as exc:
            seg = master.segments[exc.index]
            raise root.fail(exc.message, seg.key_lines.get(exc.key, seg.line),
                            f"{seg.path}.{exc.key}") from None
    else:
        raise mnode.fail("required key is missing in 'master': segments or csv",
                         mnode.head, mnode.key_path("segments"))
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
            line = lines[i] if lines else root.value_line(kind)
            why = (f"acts after the last sample (sample {k} of {n})" if k >= n else
                   "engage and disengage times must alternate, engage first, at least one "
                   "sample apart: engage[0] < disengage[0] < engage[1] < ...")
            raise root.fail(why, line, key)
        expected = "disengage" if kind == "engage" else "engage"
    estimator = _estimator(root.section("estimator")) if root.has("estimator") else None
    conditioning = None
    if root.has("conditioning"):
        if estimator is not None:
            raise root.error("conditioning", "give either an estimator or a conditioning "
                                             "section, not both")
        cnode = root.section("conditioning")
        assert cnode is not None  # root.has() said so
        conditioning = _conditioning(cnode)
        if isinstance(master, CsvMaster) and conditioning.jitter:
            raise root.error("conditioning", "jitter needs a segment master (a CSV master is "
                                             "known at its sample times only)")
    return Scenario(params, robot, master, float(duration), engage, disengage, estimator, name,
                    source, conditioning)


def load_scenario(source: str | Path | dict, *, base_dir: str | Path | None = None) -> Scenario:
    """Load and validate a scenario from a YAML file (path) or an already parsed mapping.

    A mapping with a top-level ``conveyor`` key is a conveyor scenario and gives a
    :class:`controller.simulate.conveyor.ConveyorScenario` (schema in that module).

    ``base_dir``: where relative CSV paths of a mapping are resolved (default: the cwd; for a
    file its own directory).  Raises :class:`ConfigError` naming the file, line and key.
    """
    if isinstance(source, dict):
        return _parse(source, "<scenario>",
                      Path(base_dir) if base_dir is not None else Path.cwd(), None)
    path = Path(source)
    text = read_text(path)  # OSError propagates (the CLI reports it)
    data = _load_yaml(text, str(path))
    if data is None:
        raise ConfigError("the scenario file is empty", file=str(path), line=1)
    scenario = _parse(data, str(path), Path(base_dir) if base_dir is not None
                      else path.parent, path)
    return scenario
