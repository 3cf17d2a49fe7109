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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cell.run import CellRun, HeldSource, Latch
from ..cell.scenario import CellScenario, SensorSpec, parse_cell
from ..conveyor import EncoderSource, Event, EventKind, MovingFrame, RobotGroup, SimulatedAxis
from ..conveyor.frame import LINEAR
from ..conveyor.frames import LinearGeometry, RotaryGeometry
from ..conveyor.sources import SourceState, quantise_counts
from ..conveyor.telemetry import ItemRecord, ItemStatus
from ..tracking import unwrap_counts
from .conveyor import MasterSpec, master_fn

__all__ = ["CellScenario", "CellResult", "parse_cell", "run_cell", "record_cell", "replay_cell",
           "write_cell_trace",
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
    """Run a validated cell scenario (the per-sample order of :class:`~controller.cell.run.CellRun`;
    each frame its own source object per master, a sensor's TRIGGER latching the exact master
    value at the sensor time, or the encoder count then)."""
    T = sc.sample_time_s
    n = sc.n_samples
    sources: dict[str, list[tuple[Any, float]]] = {}
    latch_fns: dict[str, list] = {}
    for fs in sc.frames:
        if fs.group is not None:
            continue
        per = []
        fns = []
        for mname in fs.masters:
            src, fn, cpu = _source(sc.masters[mname], T, mname)
            per.append((src, cpu))
            fns.append((fn, sc.masters[mname]))
        sources[fs.name] = per
        latch_fns[fs.name] = fns
    run = CellRun(sc.frames, sc.robots, sc.sensors, sc.params, sources)
    frames = run.frames

    def values_at(sen: SensorSpec, i: int) -> tuple[float, ...]:
        t = sen.times[i]
        out = []
        f = frames[sen.frame]
        for j, (fn, ms) in enumerate(latch_fns[sen.frame]):
            v = fn(t)[0]
            if ms.encoder is not None:
                c = quantise_counts(v, ms.encoder.counts_per_unit, ms.encoder.modulus)
                if ms.encoder.modulus:
                    c = unwrap_counts(int(round(f.source_values()[j])), c, ms.encoder.modulus)
                v = float(c)
            out.append(v)
        return tuple(out)

    return record_cell(sc, run, n, values_at)


def replay_cell(sc: CellScenario, inputs: Sequence[Mapping[str, Sequence[SourceState]]],
                latches: Mapping[tuple[int, str, int], tuple[float, ...]]) -> CellResult:
    """Run ``sc`` on given inputs instead of its masters: each frame's master values of
    sample 0 and of every loop index after it (``inputs[k][frame]``: one
    :class:`~controller.conveyor.sources.SourceState` per DOF [mm of belt, mm/s, mm/s²]:
    master units are mm, whatever counts the scenario's encoders give) and the sensors'
    latched values ``latches[(k, frame, trigger index)]`` [mm].  The bus controller's cell
    source records both (``CellSource(keep_inputs=True)``): the identity test between the
    shells feeds them here.  ``len(inputs) - 1`` loop indices are run."""
    held: dict[str, list[HeldSource]] = {}
    for fs in sc.frames:
        if fs.group is None:
            held[fs.name] = [HeldSource(f"{fs.name}.{m}") for m in fs.masters]

    def hold(k: int) -> None:
        for fname, srcs in held.items():
            for h, s in zip(srcs, inputs[k][fname]):
                h.hold(s)

    hold(0)
    run = CellRun(sc.frames, sc.robots, sc.sensors, sc.params,
                  {f: [(h, 1.0) for h in hs] for f, hs in held.items()})

    def latch(sen: SensorSpec, i: int) -> tuple[float, ...]:
        return latches[(run.k, sen.frame, i)]

    return record_cell(sc, run, len(inputs) - 1, latch, before=lambda k: hold(k + 1))


def record_cell(sc: CellScenario, run: CellRun, n: int, latch: Latch,
                before: Callable[[int], None] | None = None) -> CellResult:
    """Step ``run`` ``n`` times with the sensors' ``latch`` and record every sample (the
    :class:`CellResult` of the scenario ``sc``); ``before(k)`` is called before loop index
    ``k`` (a replay holds its inputs)."""
    T = sc.sample_time_s
    frames, robots = run.frames, run.robots
    traces = {name: _Trace([rg.setpoint.pos], [rg.setpoint.ori], [0], [0], [""], [])
              for name, rg in robots.items()}
    mvals = {name: [f.source_values()] for name, f in frames.items()}
    for k in range(n):
        if before is not None:
            before(k)
        outs, extra = run.step(latch)
        for rname, out in outs.items():
            tr = traces[rname]
            tr.events.extend(extra[rname])
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
        pg = run.programs.get(name)
        rt[name] = RobotTrace(name, np.array(tr.pos), np.array(tr.ori), np.array(tr.imfs),
                              np.array(tr.slave), tr.mf, tr.events,
                              [rg.records[i] for i in sorted(rg.records)],
                              dict(pg.picks) if pg is not None else {}, rg)
    return CellResult(sc, np.arange(n + 1) * T, {k: np.array(v) for k, v in mvals.items()},
                      rt, frames, list(run.triggers))


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

