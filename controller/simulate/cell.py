"""The run of cell scenarios in ``cantrack simulate``: several moving frames, several robots,
item sensors and timed MasterFrame changes (hand-off between belts, two robots sharing a belt
each with its own frame object, 2-DOF frames), with its trace, summary and plot.

The schema (a scenario with a top-level ``cell:`` key) and its reader are in
:mod:`controller.cell.scenario`.  Each frame gets its own source object of its master (two
frames on one belt read the same axis: same values, own estimator).  A sensor's TRIGGER
latches the master values of its frame at the sensor time (exactly, or the encoder count
then).  Per sample: sensors, MasterFrame changes due, programs, then one step of the cell
(frames, then robots).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cell.scenario import CellScenario, FrameChange, SensorSpec, parse_cell
from ..conveyor import (ConveyorCell, EncoderSource, Event, EventKind, MovingFrame,
                        RobotGroup, SimulatedAxis, TriggerBufferFull)
from ..conveyor.frame import LINEAR
from ..conveyor.frames import LinearGeometry, RotaryGeometry
from ..conveyor.sources import quantise_counts
from ..conveyor.telemetry import ItemRecord, ItemStatus
from ..errors import CantrackError
from ..tracking import Mode, unwrap_counts
from .conveyor import MasterSpec, PickProgram, master_fn

__all__ = ["CellScenario", "CellResult", "parse_cell", "run_cell", "write_cell_trace",
           "format_cell_summary", "plot_cell_result"]


@dataclass
class _Trace:
    """One robot's samples while running (see :class:`RobotTrace`)."""

    pos: list[Any]
    ori: list[Any]
    imfs: list[int]
    slave: list[int]
    mf: list[str]
    events: list[Event]



# -- the run -----------------------------------------------------------------------------
@dataclass
class RobotTrace:
    """One robot's arrays over samples 0..N (row 0: before the first step).  mm, s."""

    name: str
    setpoint_pos: np.ndarray
    setpoint_ori: np.ndarray
    imfs: np.ndarray
    slave: np.ndarray
    master_frame: list[str]              #: the MasterFrame per sample ("" for none)
    events: list[Event]
    records: list[ItemRecord]
    picks: dict[int, float]
    robot: RobotGroup

    def count(self, status: ItemStatus) -> int:
        """The number of items whose last status is ``status``."""
        return sum(1 for r in self.records if r.status == status)

    @property
    def caught(self) -> int:
        return sum(1 for r in self.records if r.caught)


@dataclass
class CellResult:
    scenario: CellScenario
    time_s: np.ndarray
    master_values: dict[str, np.ndarray]   #: per frame: (N+1, NOF) source values
    robots: dict[str, RobotTrace]
    frames: dict[str, MovingFrame]
    triggers: list[tuple[int, str, str, int, int]] = field(default_factory=list)
    """(sample, robot, frame, item id, item type) of every TRIGGER."""

    @property
    def sample_time_s(self) -> float:
        return self.scenario.sample_time_s


def _source(ms: MasterSpec, T: float, name: str):
    fn = master_fn(ms)
    if ms.encoder is None:
        return SimulatedAxis(fn, name), fn, 1.0
    cpu, mod = ms.encoder.counts_per_unit, ms.encoder.modulus
    src = EncoderSource(T, modulus=mod, counts=lambda k: quantise_counts(fn(k * T)[0], cpu, mod),
                        window=ms.encoder.window, name=name)
    return src, fn, cpu


def run_cell(sc: CellScenario) -> CellResult:
    """Run a validated cell scenario."""
    T = sc.sample_time_s
    n = sc.n_samples
    frames: dict[str, MovingFrame] = {}
    latch: dict[str, list] = {}
    for fs in sc.frames:
        if fs.group is not None:
            continue   # made once its master robot exists
        srcs, fns = [], []
        per = []
        for mname in fs.masters:
            src, fn, cpu = _source(sc.masters[mname], T, mname)
            srcs.append(src)
            fns.append((fn, sc.masters[mname]))
            per.append(cpu)
        s = fs.spec
        assert s is not None   # (a frame with masters has its geometry)
        if s.type == LINEAR:
            frames[fs.name] = MovingFrame(
                fs.name, srcs, directions=list(fs.directions),
                scales=[k / c for k, c in zip(fs.scales, per)], origin=s.origin,
                limits=s.limits, window=fs.window, world=fs.world)
        else:
            frames[fs.name] = MovingFrame(
                fs.name, srcs, type=s.type, upstream=s.upstream, arc_point=s.arc_point,
                downstream=s.downstream, up_master=s.up_master * per[0],
                down_master=s.down_master * per[0], limits=s.limits, window=fs.window,
                world=fs.world)
        latch[fs.name] = fns
    robots: dict[str, RobotGroup] = {}
    programs: dict[str, PickProgram] = {}
    for rs in sc.robots:
        r = rs.robot
        robot = RobotGroup(r.name, sc.params.with_(mode=Mode(r.slave)), start=r.start,
                           base=r.base, tool=r.tool, motion_limits=r.motion,
                           buffer_capacity=r.buffer_capacity, default_mode=r.slave,
                           kinematics=rs.kinematics)
        for fname, types in rs.track_types:
            robot.track_types(fname, types)
        robots[r.name] = robot
    for fs in sc.frames:
        if fs.group is not None:
            frames[fs.name] = MovingFrame.group(
                fs.name, robots[fs.group.robot], transform=fs.group.transform,
                axis=fs.group.axis, window=fs.window, world=fs.world)
    frames = {fs.name: frames[fs.name] for fs in sc.frames}   # the file's order
    for rs in sc.robots:
        r = rs.robot
        robot = robots[r.name]
        if rs.program is not None:
            assert rs.program_frame is not None
            programs[r.name] = PickProgram(robot, frames[rs.program_frame], rs.program, r.slave)
    cell = ConveyorCell(list(frames.values()), list(robots.values()))

    def values_at(fname: str, t: float) -> tuple[float, ...]:
        out = []
        f = frames[fname]
        for i, (fn, ms) in enumerate(latch[fname]):
            v = fn(t)[0]
            if ms.encoder is not None:
                c = quantise_counts(v, ms.encoder.counts_per_unit, ms.encoder.modulus)
                if ms.encoder.modulus:
                    c = unwrap_counts(int(round(f.source_values()[i])), c, ms.encoder.modulus)
                v = float(c)
            out.append(v)
        return tuple(out)

    by_k: dict[int, list[tuple[SensorSpec, int]]] = {}
    for sen in sc.sensors:
        for i, t in enumerate(sen.times):
            by_k.setdefault(int(math.floor(t / T + 1e-9)), []).append((sen, i))
    changes: dict[int, list[tuple[str, FrameChange]]] = {}
    for rs in sc.robots:
        for c in rs.changes:
            changes.setdefault(int(round(c.time_s / T)), []).append((rs.name, c))
    triggers: list[tuple[int, str, str, int, int]] = []
    extra: dict[str, list[Event]] = {name: [] for name in robots}
    traces = {name: _Trace([rg.setpoint.pos], [rg.setpoint.ori], [0], [0], [""], [])
              for name, rg in robots.items()}
    mvals = {name: [f.source_values()] for name, f in frames.items()}
    last: dict[str, tuple[Event, ...]] = dict.fromkeys(robots, ())
    for k in range(n):
        for sen, i in by_k.get(k, ()):
            group = frames[sen.frame].group_source is not None
            vals = None if group else values_at(sen.frame, sen.times[i])
            for rname in sen.robots:
                try:
                    e = robots[rname].trigger(frames[sen.frame], values=vals, dr_mm=sen.dr_mm[i],
                                              item_type=sen.types[i],
                                              offset=sen.offset if group else None)
                except TriggerBufferFull as exc:
                    extra[rname].append(Event(k, EventKind.TRIGGER_REJECTED, sen.frame, message=str(exc)))
                    continue
                triggers.append((k, rname, sen.frame, e.id, e.item_type))
        for rname, c in changes.get(k, ()):
            try:
                robots[rname].set_master_frame(frames[c.frame] if c.frame else None)
            except CantrackError as exc:
                extra[rname].append(Event(k, EventKind.COMMAND_ERROR, c.frame or "",
                                          message=str(exc)))
        for rname, prog in programs.items():
            prog.tick(last[rname])
        outs = cell.step()
        for rname, out in outs.items():
            tr = traces[rname]
            last[rname] = out.events
            tr.events.extend(extra[rname])
            extra[rname].clear()
            tr.events.extend(out.events)
            tr.pos.append(out.setpoint.pos)
            tr.ori.append(out.setpoint.ori)
            tr.imfs.append(int(out.imfs))
            tr.slave.append(out.slave)
            tr.mf.append(out.master_frame or "")
        for name, f in frames.items():
            mvals[name].append(f.source_values())
    rt = {}
    for name, rg in robots.items():
        tr = traces[name]
        pg = programs.get(name)
        rt[name] = RobotTrace(name, np.array(tr.pos), np.array(tr.ori), np.array(tr.imfs),
                              np.array(tr.slave), tr.mf, tr.events,
                              [rg.records[i] for i in sorted(rg.records)],
                              dict(pg.picks) if pg is not None else {}, rg)
    return CellResult(sc, np.arange(n + 1) * T, {k: np.array(v) for k, v in mvals.items()},
                      rt, frames, triggers)


# -- outputs --------------------------------------------------------------------------------
def write_cell_trace(result: CellResult, path: str | Path) -> Path:
    """One row per sample: every frame's master values, then per robot the TCP setpoint
    (position, quaternion), IMFS, slave, MasterFrame and the events of that sample."""
    path = Path(path)
    r = result
    T = r.sample_time_s
    head = ["time_s"]
    for name, mv in r.master_values.items():
        head += [f"{name}_master{i + 1}" for i in range(mv.shape[1])]
    ev: dict[str, dict[int, list[str]]] = {}
    for rn, tr in r.robots.items():
        head += [f"{rn}_{c}" for c in ("x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz", "imfs",
                                       "slave", "master_frame", "events")]
        d: dict[int, list[str]] = {}
        for e in tr.events:
            d.setdefault(e.sample, []).append(
                e.kind.value + (f"({e.item})" if e.item is not None else "")
                + (f"[{e.code}]" if e.code else ""))
        ev[rn] = d
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(head)
        for k in range(len(r.time_s)):
            row: list[Any] = [repr(round(k * T, 12))]
            for mv in r.master_values.values():
                row += [repr(float(x)) for x in mv[k]]
            for rn, tr in r.robots.items():
                row += [repr(float(x)) for x in tr.setpoint_pos[k]]
                row += [repr(float(x)) for x in tr.setpoint_ori[k]]
                row += [int(tr.imfs[k]), int(tr.slave[k]), tr.master_frame[k],
                        ";".join(ev[rn].get(k, ()))]
            w.writerow(row)
    return path


def format_cell_summary(result: CellResult) -> str:
    """The summary of a cell scenario: every frame, then every robot with its items."""
    from ..conveyor import ITEM_MISSED_CODE
    from ..tracking import Imfs
    from .conveyor import type_name

    r = result
    sc = r.scenario
    T = sc.sample_time_s
    title = str(sc.source) if sc.source is not None else "<scenario>"
    if sc.name:
        title += f"  ({sc.name})"
    lines = [f"Scenario   {title}",
             f"Cell       {len(sc.frames)} frame(s), {len(sc.robots)} robot(s), planner "
             f"{sc.params.planner}, T = {T * 1000:g} ms, {sc.n_samples} samples = "
             f"{sc.n_samples * T:.3f} s"]
    for fs in sc.frames:
        if fs.group is not None:
            lines.append(f"Frame      '{fs.name}' group: the TCP of robot '{fs.group.robot}' "
                         f"(4 DOFs: dx, dy, dz, angle about {fs.group.axis})")
            continue
        assert fs.spec is not None
        unit = "mm" if fs.spec.type == LINEAR else "deg"
        w = fs.window
        win = ", ".join(f"{u:g}...{d:g}" for u, d in zip(w.upstream, w.downstream))
        lines.append(f"Frame      '{fs.name}' {type_name(fs.spec.type)}, NOF {fs.nof} "
                     f"(masters {', '.join(fs.masters)}), window {win} {unit}")
    for rs in sc.robots:
        tr = r.robots[rs.name]
        how = (f"program on '{rs.program_frame}'" if rs.program is not None else
               "MasterFrame " + ", ".join(f"{c.frame or 'none'} @{c.time_s:g} s"
                                          for c in rs.changes))
        lines.append("")
        types = "; ".join(f"{f}: types {sorted(t)}" for f, t in rs.track_types)
        lines.append(f"Robot      '{rs.name}' ({rs.kinematics}), slave {rs.robot.slave}, {how}"
                     + (f"; {types}" if types else ""))
        n = len(tr.records)
        lines.append(f"  items    {n} triggered: {tr.caught} caught, {len(tr.picks)} picked, "
                     f"{tr.count(ItemStatus.MISSED)} missed ({ITEM_MISSED_CODE}), "
                     f"{tr.count(ItemStatus.SKIPPED)} skipped, {tr.count(ItemStatus.IGNORED)} ignored "
                     f"(type not tracked), {tr.count(ItemStatus.LOST)} lost")
        for rec in tr.records:
            lines.append(f"  item {rec.item_id:3d} frame '{rec.frame}' type {rec.item_type}: "
                         f"{rec.status.value:8s} trigger {rec.trigger_s:.3f} s"
                         + ("" if rec.synced_s is None else f", synced {rec.synced_s:.3f} s")
                         + ("" if rec.time_to_sync_s is None
                            else f" (to sync {rec.time_to_sync_s:.3f} s)"))
        hand = [e for e in tr.events if e.kind in (EventKind.HANDOFF, EventKind.ITEM_MISSED,
                                                   EventKind.TRACKER_ERROR,
                                                   EventKind.COMMAND_ERROR)]
        for e in hand:
            lines.append(f"  {e.sample * T:.3f} s  {e.kind.value}  {e.frame}  "
                         f"{e.message}".rstrip())
        lines.append(f"  final    IMFS {Imfs(int(tr.imfs[-1])).name}, slave "
                     f"{int(tr.slave[-1])}, MasterFrame {tr.master_frame[-1] or 'none'}, "
                     f"{len(tr.robot.buffer)} item(s) left in the buffer")
    return "\n".join(lines)


def plot_cell_result(result: CellResult, path: str | Path, *, dpi: int = 110) -> Path:
    """PNG of a cell scenario: left, the XY plane [mm] with every frame's path and window and
    every robot's TCP path; right, per robot, the TCP's x, y, z over time [s] and its IMFS
    with the MasterFrame named where it changes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    r = result
    nr = len(r.robots)
    fig = Figure(figsize=(13, 3.2 + 2.6 * nr))
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(2 * nr, 2, width_ratios=[1.0, 1.25],
                          height_ratios=[2.2, 1.0] * nr, left=0.06, right=0.98, bottom=0.07,
                          top=0.93, wspace=0.2, hspace=0.45)
    ax = fig.add_subplot(gs[:, 0])
    colours = ["tab:orange", "tab:purple", "tab:brown", "tab:olive", "tab:cyan"]
    for i, (name, f) in enumerate(r.frames.items()):
        if f.group_source is not None:
            continue   # a robot's TCP: drawn as that robot's path
        g = f.geometry()
        c = colours[i % len(colours)]
        w = f.window
        if isinstance(g, LinearGeometry):
            o = np.array(g.origin.pos)
            pts = [o]
            corners = []
            for dv, (u, dn) in zip(g.directions, zip(w.upstream, w.downstream)):
                corners.append((np.array(dv), max(u, -1e5), min(dn, 1e5)))
            if len(corners) == 1:
                d, u, dn = corners[0]
                seg = np.array([o + d * u, o + d * dn])
                ax.plot(seg[:, 0], seg[:, 1], color=c, lw=5, alpha=0.45, solid_capstyle="butt",
                        label=f"frame {name} window")
            else:
                (d1, u1, e1), (d2, u2, e2) = corners[:2]
                box = np.array([o + d1 * a + d2 * b for a, b in
                                ((u1, u2), (e1, u2), (e1, e2), (u1, e2), (u1, u2))])
                ax.plot(box[:, 0], box[:, 1], color=c, lw=2, label=f"frame {name} window")
            ax.plot(pts[0][0], pts[0][1], "s", color=c, ms=5)
        elif isinstance(g, RotaryGeometry):
            arc = g.arc
            xs = np.linspace(max(0.0, w.upstream[0]), min(arc.alpha_deg, w.downstream[0]), 91)
            win = np.array([arc.position(x) for x in xs])
            ax.plot(win[:, 0], win[:, 1], color=c, lw=5, alpha=0.45, solid_capstyle="butt",
                    label=f"frame {name} window")
    for j, (rn, tr) in enumerate(r.robots.items()):
        ax.plot(tr.setpoint_pos[:, 0], tr.setpoint_pos[:, 1], lw=1.2, label=f"robot {rn} TCP")
        t = r.time_s
        at = fig.add_subplot(gs[2 * j, 1])
        ai = fig.add_subplot(gs[2 * j + 1, 1], sharex=at)
        for i, (cn, c) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"))):
            at.plot(t, tr.setpoint_pos[:, i], color=c, lw=1.0, label=f"{cn}")
        for rec in tr.records:
            if rec.synced_s is not None:
                at.axvline(rec.synced_s, color="tab:green", lw=0.6, alpha=0.6)
            if rec.missed_sample is not None:
                at.axvline(rec.missed_sample * r.sample_time_s, color="tab:red", lw=0.8)
        at.set_title(f"robot {rn}: {len(tr.records)} items, {tr.caught} caught, "
                     f"{tr.count(ItemStatus.MISSED)} missed", fontsize=9)
        at.set_ylabel("TCP [mm]")
        at.grid(True, lw=0.4, alpha=0.6)
        at.legend(loc="upper left", fontsize=7, ncol=3)
        ai.step(t, tr.imfs, where="post", color="k", lw=1.0)
        prev = ""
        for k, mf in enumerate(tr.master_frame):
            if mf != prev:
                ai.annotate(mf or "none", (t[k], 1.05), fontsize=7, color="tab:blue")
                prev = mf
        ai.set_ylim(-2.4, 1.6)
        ai.set_yticks([-2, -1, 0, 1])
        ai.set_ylabel("IMFS")
        ai.grid(True, lw=0.4, alpha=0.6)
        ai.set_xlim(t[0], t[-1])
    ai.set_xlabel("time [s]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.grid(True, lw=0.4, alpha=0.6)
    ax.legend(loc="best", fontsize=7)
    sc = r.scenario
    ax.set_title(sc.name or (sc.source.name if sc.source else "cell scenario"), fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path

