"""Cell capacity: up to which belt speed and item rate does a conveyor cell pick every item?

Not part of softMC: the integrator's question before a cell is built (docs/spec/capacity.md).
For a conveyor scenario (one frame, one robot, its pick program) :func:`capacity` sweeps the
belt speed v [frame units/s] x the item spacing s [frame units: mm on a belt, deg on a table]
(x shifts of the window, if asked) and reports, per spacing, the fastest speed at which
every item is picked, the limiting reason above it, and the whole map.

**Method** (docs/spec/capacity.md#2, #3).  One item's pick cycle - the program's approach,
sync, descent, grip, lift, de-sync and place move, run by the very model of ``cantrack simulate``
(:class:`controller.conveyor.ConveyorCell` with :class:`controller.simulate.conveyor.
PickProgram`, its catch prediction included) - is simulated for the robot starting at its
place position at rest, with the item at coordinate x0 of the frame at that moment
(x0 = 0: at the sensor).  That gives ``ok(v, x0)`` (picked) with the reason when not, and
the cycle time ``T(v, x0)`` until the program is idle again.  These do not depend on the
spacing.  With items every s, the coordinate of the next item when the robot gets free is::

    x_{k+1} = max(0, x_k + v * T(v, x_k) - s),      x_1 = 0

(0: the robot waits for the next trigger).  Every item is picked iff the sequence stays in
the region where ``ok`` holds: it settles at a fixed point (``x* = 0``: the robot is ahead of
the belt; ``v T(x*) = s``: a steady backlog) instead of growing until an item is lost.
Per speed, ``ok`` is bracketed by bisection on x0 (the largest x0 still picked, to
``x_tolerance`` of the window) and T is sampled on ``t_points`` points of [0, that x0] and
interpolated linearly; the spacings are then a cheap iteration.  Speeds run in parallel
(``workers`` processes; the sweep is deterministic whatever the number).

Limiting reasons (the first item lost, at the first spacing point above the boundary):

- ``limits``: the belt is faster than the frame's VelocityMaxTrans or the robot's sync
  velocity (the prediction or the tracker says so);
- ``approach time``: even free at the trigger, the robot cannot synchronise before the item
  leaves the window;
- ``window length``: it synchronises, but the pick (descent and grip) does not end before
  the item leaves the window;
- ``pick time``: every item alone would be picked, but the cycle is longer than the item
  period: the backlog grows until an item is lost.
"""

from __future__ import annotations

import dataclasses
import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..conveyor import Window
from ..conveyor.frame import LINEAR
from ..conveyor.frames import LinearGeometry, RotaryGeometry
from ..errors import ConfigError, ParameterError
from .conveyor import ConveyorScenario, build_conveyor

__all__ = ["CapacityResult", "CycleOutcome", "capacity", "pick_cycle", "with_speed",
           "REASONS"]

REASONS = ("limits", "approach time", "window length", "pick time")

#: warm-up before the item (the encoder estimator's window fills) [s]
WARMUP_S = 0.3


@dataclass(frozen=True)
class CycleOutcome:
    """One pick cycle: ``ok`` (picked), ``reason`` (one of :data:`REASONS` or ""),
    ``cycle_s``: from the program taking the item to idle again [s]; ``detail``: the model's
    own words."""

    ok: bool
    reason: str
    cycle_s: float
    detail: str = ""


def frame_scale(sc: ConveyorScenario) -> float:
    """Frame units (mm or deg) per master unit."""
    fs = sc.frame
    if fs.type == LINEAR:
        return fs.scale_mm_per_unit
    return 0.0 if fs.down_master is None else \
        _alpha_deg(sc) / (fs.down_master - fs.up_master)


def _alpha_deg(sc: ConveyorScenario) -> float:
    from ..conveyor import arc_from_points

    fs = sc.frame
    return arc_from_points(fs.upstream.pos, fs.arc_point, fs.downstream).alpha_deg


def with_speed(sc: ConveyorScenario, speed: float, window_shift: float = 0.0,
               items=(), duration_s: float | None = None) -> ConveyorScenario:
    """The scenario with a constant belt speed [frame units/s] (the master's start kept, no
    profile or log), the window shifted by ``window_shift`` [frame units], ``items``."""
    ms = dataclasses.replace(sc.master, speed=speed / frame_scale(sc), profile=None, log=None,
                             log_path=None)
    fs = sc.frame
    if window_shift:
        w = fs.window
        fs = dataclasses.replace(fs, window=Window(tuple(u + window_shift for u in w.upstream),
                                                   tuple(d + window_shift
                                                         for d in w.downstream)))
    return dataclasses.replace(sc, master=ms, frame=fs, items=tuple(items),
                               duration_s=duration_s if duration_s is not None
                               else sc.duration_s)


def _classify(setup, item_id: int) -> tuple[str, str]:
    prog, robot = setup.program, setup.robot
    why = prog.skipped.get(item_id) or prog.unpicked.get(item_id) or ""
    rec = robot.records.get(item_id)
    if "faster" in why or "MASTER_" in why or (rec is not None and "MASTER_" in rec.error):
        return "limits", why
    if rec is not None and rec.caught:
        return "window length", why
    return "approach time", why or (rec.status.value if rec is not None else "lost")


def pick_cycle(sc: ConveyorScenario, speed: float, x0: float, window_shift: float = 0.0,
               horizon_s: float | None = None) -> CycleOutcome:
    """Simulate one pick cycle at belt ``speed`` [frame units/s] with the item at ``x0``
    [frame units from the sensor] when the robot (at its place position, at rest) takes it."""
    s = with_speed(sc, speed, window_shift)
    # the robot waits at its place position, at rest (the steady state between two items)
    place = sc.program.place if sc.program.place is not None else sc.robot.start
    s = dataclasses.replace(s, robot=dataclasses.replace(s.robot, start=place))
    setup = build_conveyor(s)
    cell, robot, frame, prog = setup.cell, setup.robot, setup.frame, setup.program
    T = s.sample_time_s
    for _ in range(int(round(WARMUP_S / T))):
        cell.step()
    # the item is x0 past the sensor: its trigger value is the frame's continuous
    # master value now minus x0 in master units (no counter wrap: the value is not latched)
    geo = frame.geometry()
    if isinstance(geo, LinearGeometry):
        per = geo.scales[0]
    elif isinstance(geo, RotaryGeometry):
        per = geo.deg_per_unit
    else:
        raise ParameterError(f"capacity: frame {frame.name!r} is a group frame (type 3): "
                             "no belt to sweep")
    entry = robot.trigger(frame, values=(frame.source_values()[0] - x0 / per,))
    k0 = cell.k
    w = s.frame.window
    if horizon_s is None:
        horizon_s = (w.downstream[0] - x0) / speed + 6.0
    last = ()
    started = False
    for _ in range(int(math.ceil(horizon_s / T))):
        prog.tick(last)
        if prog.state != "idle":
            started = True
        elif started or entry.id in prog.skipped:
            break
        last = cell.step()[robot.name].events
    cycle = (cell.k - k0) * T
    if entry.id in prog.picks:
        if prog.state != "idle":
            return CycleOutcome(False, "pick time", cycle, "the cycle did not end within "
                                f"{horizon_s:g} s")
        return CycleOutcome(True, "", cycle)
    reason, why = _classify(setup, entry.id)
    return CycleOutcome(False, reason, cycle, why)


@dataclass(frozen=True)
class SpeedProfile:
    """What one speed's cycles say: ``x_max`` (the largest start coordinate still picked;
    -inf: none), the reason beyond it, the cycle time samples (x, T)."""

    speed: float
    window_shift: float
    x_max: float
    reason: str
    detail: str
    xs: tuple[float, ...]
    ts: tuple[float, ...]
    cycles: int

    def cycle_s(self, x: float) -> float:
        return float(np.interp(x, self.xs, self.ts))


def speed_profile(sc: ConveyorScenario, speed: float, window_shift: float = 0.0,
                  t_points: int = 6, x_tolerance: float = 0.02) -> SpeedProfile:
    """``ok`` and ``T`` of one speed (module docstring)."""
    n = 0
    first = pick_cycle(sc, speed, 0.0, window_shift)
    n += 1
    if not first.ok:
        return SpeedProfile(speed, window_shift, -math.inf, first.reason, first.detail,
                            (0.0,), (first.cycle_s,), n)
    w = sc.frame.window
    hi = w.downstream[0] + window_shift
    tol = max(x_tolerance * (w.downstream[0] - w.upstream[0]), 1e-6)
    lo = 0.0
    end = pick_cycle(sc, speed, hi, window_shift)
    n += 1
    reason, detail = end.reason, end.detail
    if end.ok:
        lo = hi
    while hi - lo > tol and not end.ok:
        mid = 0.5 * (lo + hi)
        out = pick_cycle(sc, speed, mid, window_shift)
        n += 1
        if out.ok:
            lo = mid
        else:
            hi = mid
            reason, detail = out.reason, out.detail
    xs = tuple(np.linspace(0.0, lo, max(2, t_points))) if lo > 0 else (0.0,)
    ts = [first.cycle_s]
    for x in xs[1:]:
        ts.append(pick_cycle(sc, speed, float(x), window_shift).cycle_s)
        n += 1
    return SpeedProfile(speed, window_shift, lo, reason or "approach time", detail, xs,
                        tuple(ts), n)


@dataclass(frozen=True)
class PointResult:
    """One (speed, spacing[, shift]) point: ``ok``; ``reason`` when not; ``items_picked``
    before the first loss (None: all, the sequence settles); ``backlog``: the steady start
    coordinate x* [frame units] (None when not ok)."""

    ok: bool
    reason: str
    items_picked: int | None
    backlog: float | None


def iterate_spacing(p: SpeedProfile, spacing: float, max_items: int = 200) -> PointResult:
    """The item sequence x_{k+1} = max(0, x_k + v T(x_k) - s) for one spacing."""
    if p.x_max == -math.inf:
        return PointResult(False, p.reason, 0, None)
    x = 0.0
    for k in range(max_items):
        if x > p.x_max + 1e-12:
            return PointResult(False, "pick time", k, None)
        nxt = max(0.0, x + p.speed * p.cycle_s(x) - spacing)
        if abs(nxt - x) <= 1e-9 * max(1.0, abs(x)):
            return PointResult(True, "", None, x)
        x = nxt
    # not settled within max_items but still picking: a slowly converging backlog
    return PointResult(x <= p.x_max, "" if x <= p.x_max else "pick time",
                       None if x <= p.x_max else max_items, x if x <= p.x_max else None)


@dataclass
class CapacityResult:
    """The sweep.  ``ok[i_shift, i_spacing, i_speed]``; ``boundary[i_shift][i_spacing]``: the
    fastest speed of the grid below which every speed picks every item (None: not even the
    slowest), ``limit[i_shift][i_spacing]``: the reason at the next faster speed."""

    speeds: tuple[float, ...]
    spacings: tuple[float, ...]
    window_shifts: tuple[float, ...]
    units: str
    ok: np.ndarray
    reasons: list[list[list[str]]]
    #: items picked before the first loss (None: every item)
    items_before_loss: list[list[list[int | None]]]
    boundary: list[list[float | None]]
    limit: list[list[str]]
    profiles: list[SpeedProfile] = field(default_factory=list)
    cycles: int = 0
    elapsed_s: float = 0.0

    def point(self, speed: float, spacing: float, shift: float = 0.0
              ) -> tuple[bool, str, int | None]:
        """(good, reason, items picked before the first loss) of a grid point."""
        i = self.window_shifts.index(shift)
        j = self.spacings.index(spacing)
        k = self.speeds.index(speed)
        return bool(self.ok[i, j, k]), self.reasons[i][j][k], self.items_before_loss[i][j][k]


def _profile_job(args) -> SpeedProfile:
    sc, speed, shift, t_points, tol = args
    return speed_profile(sc, speed, shift, t_points, tol)


def capacity(sc: ConveyorScenario, speeds: Sequence[float], spacings: Sequence[float],
             window_shifts: Sequence[float] = (0.0,), *, workers: int | None = None,
             t_points: int = 6, x_tolerance: float = 0.02) -> CapacityResult:
    """Sweep belt speed x item spacing (x window shift) - see the module docstring.

    ``speeds`` [frame units/s] > 0, ``spacings`` [frame units] > 0, ``window_shifts``
    [frame units]; ``workers``: processes (default: the CPUs, at most the number of speeds;
    1: in this process).  Raises ParameterError for bad values.
    """
    import time

    t0 = time.perf_counter()
    if not isinstance(sc, ConveyorScenario):
        raise ConfigError("capacity needs a conveyor scenario (a 'conveyor' section: one "
                          "frame, one robot and its pick program)")
    for name, vals in (("speeds", speeds), ("spacings", spacings)):
        if not vals or any(not (math.isfinite(v) and v > 0) for v in vals):
            raise ParameterError(f"capacity {name} (={list(vals)!r}) must be numbers > 0")
    if frame_scale(sc) == 0.0:
        raise ParameterError("capacity: the frame's master scale is unknown (rotary frame "
                             "without down_master)")
    speeds = tuple(sorted(float(v) for v in speeds))
    spacings = tuple(sorted(float(s) for s in spacings))
    shifts = tuple(float(x) for x in window_shifts) or (0.0,)
    jobs = [(sc, v, sh, t_points, x_tolerance) for sh in shifts for v in speeds]
    n_workers = workers if workers is not None else min(os.cpu_count() or 1, len(jobs))
    if n_workers <= 1:
        profiles = [_profile_job(j) for j in jobs]
    else:
        with ProcessPoolExecutor(max_workers=n_workers) as ex:
            profiles = list(ex.map(_profile_job, jobs, chunksize=1))
    ok = np.zeros((len(shifts), len(spacings), len(speeds)), dtype=bool)
    reasons = [[["" for _ in speeds] for _ in spacings] for _ in shifts]
    items: list[list[list[int | None]]] = [[[None for _ in speeds] for _ in spacings]
                                           for _ in shifts]
    boundary: list[list[float | None]] = []
    limit: list[list[str]] = []
    for i, _sh in enumerate(shifts):
        prof = profiles[i * len(speeds):(i + 1) * len(speeds)]
        brow, lrow = [], []
        for j, s in enumerate(spacings):
            best, why = None, ""
            for k, p in enumerate(prof):
                pr = iterate_spacing(p, s)
                ok[i, j, k] = pr.ok
                reasons[i][j][k] = pr.reason
                items[i][j][k] = pr.items_picked
            for k in range(len(speeds)):
                if not ok[i, j, k]:
                    why = reasons[i][j][k]
                    break
                best = speeds[k]
            brow.append(best)
            lrow.append(why)
        boundary.append(brow)
        limit.append(lrow)
    units = "mm" if sc.frame.type == LINEAR else "deg"
    return CapacityResult(speeds, spacings, shifts, units, ok, reasons, items, boundary, limit,
                          profiles, sum(p.cycles for p in profiles),
                          time.perf_counter() - t0)


def format_capacity(result: CapacityResult, title: str = "") -> str:
    """The boundary per spacing (and window shift) and the map as text."""
    r = result
    u = r.units
    lines = []
    if title:
        lines.append(f"Scenario   {title}")
    lines.append(f"Sweep      {len(r.speeds)} belt speeds {r.speeds[0]:g}...{r.speeds[-1]:g} "
                 f"{u}/s x {len(r.spacings)} item spacings {r.spacings[0]:g}..."
                 f"{r.spacings[-1]:g} {u}" + (f" x {len(r.window_shifts)} window shifts"
                                              if len(r.window_shifts) > 1 else "")
                 + f": {r.cycles} pick cycles simulated in {r.elapsed_s:.1f} s")
    for i, sh in enumerate(r.window_shifts):
        lines.append("")
        if len(r.window_shifts) > 1 or sh:
            lines.append(f"Window shifted by {sh:g} {u}")
        lines.append(f"  spacing [{u}]  items/min at the boundary  fastest 100 % belt speed "
                     f"[{u}/s]  limited by (above it)")
        for j, s in enumerate(r.spacings):
            b = r.boundary[i][j]
            rate = "-" if b is None else f"{60.0 * b / s:.1f}"
            lines.append(f"  {s:12g}  {rate:>24}  {('-' if b is None else f'{b:g}'):>26}  "
                         f"{r.limit[i][j] or '(all speeds of the sweep pick every item)'}")
        lines.append("")
        lines.append("  map (rows: spacing, columns: belt speed; '#' every item picked, "
                     "L limits, A approach time, W window length, P pick time)")
        code = {"limits": "L", "approach time": "A", "window length": "W", "pick time": "P"}
        for j, s in enumerate(r.spacings):
            row = "".join("#" if r.ok[i, j, k] else code.get(r.reasons[i][j][k], "?")
                          for k in range(len(r.speeds)))
            lines.append(f"  {s:10g} {row}")
    return "\n".join(lines)


def plot_capacity(result: CapacityResult, path, *, dpi: int = 110):
    """PNG: per window shift a map over (belt speed, spacing), every item picked in green,
    the limiting reason coloured otherwise, the boundary drawn; items/min iso-lines."""
    from pathlib import Path

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    r = result
    n = len(r.window_shifts)
    fig = Figure(figsize=(6.5 * n, 5.2))
    FigureCanvasAgg(fig)
    cmap = ListedColormap(["tab:green", "tab:red", "tab:orange", "gold", "tab:purple"])
    codes = {"": 0, "limits": 1, "approach time": 2, "window length": 3, "pick time": 4}
    v = np.array(r.speeds)
    s = np.array(r.spacings)
    for i, sh in enumerate(r.window_shifts):
        ax = fig.add_subplot(1, n, i + 1)
        grid = np.array([[codes.get(r.reasons[i][j][k], 4) if not r.ok[i, j, k] else 0
                          for k in range(len(v))] for j in range(len(s))])
        ax.pcolormesh(_edges(v), _edges(s), grid, cmap=cmap, vmin=-0.5, vmax=4.5,
                      shading="flat")
        bx = list(r.boundary[i])
        ax.plot([b if b is not None else np.nan for b in bx], s, "k.-", lw=1.5,
                label="fastest 100 % speed")
        vv, ss = np.meshgrid(np.linspace(v[0], v[-1], 50), np.linspace(s[0], s[-1], 50))
        cs = ax.contour(vv, ss, 60.0 * vv / ss, colors="0.3", linewidths=0.5)
        ax.clabel(cs, fontsize=6, fmt="%.0f/min")
        ax.set_xlabel(f"belt speed [{r.units}/s]")
        ax.set_ylabel(f"item spacing [{r.units}]")
        ax.set_title(f"window shift {sh:g} {r.units}" if n > 1 or sh else
                     "every item picked (green); else the limit", fontsize=9)
        for name, c in codes.items():
            ax.plot([], [], "s", color=cmap(c), label=name or "every item picked")
        ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path


def _edges(x: np.ndarray) -> np.ndarray:
    if len(x) == 1:
        return np.array([x[0] * 0.95, x[0] * 1.05])
    mid = (x[1:] + x[:-1]) / 2
    return np.concatenate([[x[0] - (mid[0] - x[0])], mid, [x[-1] + (x[-1] - mid[-1])]])


def full_simulation(sc: ConveyorScenario, speed: float, spacing: float, n_items: int,
                    window_shift: float = 0.0, first_s: float = WARMUP_S
                    ) -> tuple[int, int, dict[int, str]]:
    """The check of a map point: the whole scenario run (``run_conveyor``) at ``speed``
    with ``n_items`` items ``spacing`` apart (the first at ``first_s``); returns (picked,
    triggered, {item: why not picked})."""
    from .conveyor import ItemSpec, run_conveyor

    period = spacing / speed
    items = [ItemSpec(first_s + i * period) for i in range(n_items)]
    w = sc.frame.window
    tail = (w.downstream[0] + window_shift) / speed + 4.0
    s = with_speed(sc, speed, window_shift, items, items[-1].time_s + tail)
    r = run_conveyor(s)
    why = dict(r.skipped)
    why.update(r.unpicked)
    for rec in r.records:
        if rec.item_id not in r.picks and rec.item_id not in why:
            why[rec.item_id] = rec.status.value
    return len(r.picks), len(r.records), why
