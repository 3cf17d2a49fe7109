"""PNG plot of a simulation (matplotlib, Agg canvas, no pyplot global state).

Panels, all on the time axis [s], with the tracker state shaded (SYNCING yellow, SYNCED green,
DESYNCING orange):

1. positions x, y, z [mm]: master dashed, setpoint solid, one colour per axis;
2. angle c [deg] (only when the master or the setpoint rotates);
3. tracking error |setpoint - reference| [mm] (log scale; reference = master, plus the
   offset in relative mode);
4.-6. velocity, acceleration and jerk norms of the setpoint [mm/s, mm/s^2, mm/s^3] from
   backward finite differences (as ``controller.tracking.metrics`` computes them), master
   velocity/acceleration dotted, the effective sync (and de-sync, if different) limits as
   horizontal lines.  The jerk axis is capped at 3x the larger jerk limit (the SYNCED switch
   makes a spike of about g*A/T); a peak above it is written in the panel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..tracking import TrackState
from .runner import SimulationResult

__all__ = ["plot_result"]

_SHADE = {TrackState.SYNCING: ("#f5d76e", "SYNCING"), TrackState.SYNCED: ("#8fd18f", "SYNCED"),
          TrackState.DESYNCING: ("#f5a05a", "DESYNCING")}
_AXIS_COLOURS = ("tab:blue", "tab:orange", "tab:green")


def _fd(x: np.ndarray, T: float, order: int) -> np.ndarray:
    """Backward differences of ``order``, the first ``order`` rows set to NaN."""
    d = np.asarray(x, dtype=float)
    for _ in range(order):
        d = np.concatenate([np.full((1,) + d.shape[1:], np.nan), np.diff(d, axis=0) / T])
    return d


def _norm(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x, axis=1) if x.ndim == 2 else np.abs(x)


def _spans(t: np.ndarray, state: np.ndarray) -> list[tuple[float, float, TrackState]]:
    out = []
    start = 0
    for i in range(1, len(state) + 1):
        if i == len(state) or state[i] != state[start]:
            s = TrackState(int(state[start]))
            if s in _SHADE:
                t0 = t[start] - 0.5 * (t[1] - t[0]) if len(t) > 1 else t[start]
                t1 = t[i - 1] + 0.5 * (t[1] - t[0]) if len(t) > 1 else t[i - 1]
                out.append((t0, t1, s))
            start = i
    return out


def _legend(ax, ncol: int = 1) -> None:
    """The panel's legend outside, to the right of it (never over the data)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, ncol=ncol,
              frameon=False, borderaxespad=0.0)


def plot_result(result: SimulationResult, path: str | Path, *, dpi: int = 110) -> Path:
    """Write the PNG to ``path``; returns the path."""
    from .conveyor import ConveyorResult

    if isinstance(result, ConveyorResult):
        return plot_conveyor_result(result, path, dpi=dpi)
    from .cell import CellResult, plot_cell_result

    if isinstance(result, CellResult):
        return plot_cell_result(result, path, dpi=dpi)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    r = result
    T = r.sample_time_s
    t = r.time_s
    rotates = bool(np.ptp(r.master_ang) > 0 or np.ptp(r.setpoint_ang) > 0)
    panels = ["pos"] + (["ang"] if rotates else []) + ["err", "vel", "acc", "jerk"]
    heights = {"pos": 2.2, "ang": 1.3, "err": 1.5, "vel": 1.5, "acc": 1.5, "jerk": 1.5}
    height_in = sum(heights[p] for p in panels) + 1.4
    fig = Figure(figsize=(11, height_in))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(panels), 1, sharex=True,
                        gridspec_kw={"height_ratios": [heights[p] for p in panels]})
    ax_of = dict(zip(panels, axes))
    spans = _spans(t, r.state)
    for ax in axes:
        for t0, t1, s in spans:
            ax.axvspan(t0, t1, color=_SHADE[s][0], alpha=0.35, lw=0)
        ax.grid(True, lw=0.4, alpha=0.6)

    ax = ax_of["pos"]
    for i, name in enumerate("xyz"):
        c = _AXIS_COLOURS[i]
        ax.plot(t, r.master_pos[:, i], "--", color=c, lw=1.0, label=f"master {name}")
        ax.plot(t, r.setpoint_pos[:, i], "-", color=c, lw=1.4, label=f"setpoint {name}")
    ax.set_ylabel("position [mm]")
    _legend(ax)

    if rotates:
        ax = ax_of["ang"]
        ax.plot(t, r.master_ang, "--", color="tab:purple", lw=1.0, label="master c")
        ax.plot(t, r.setpoint_ang, "-", color="tab:purple", lw=1.4, label="setpoint c")
        ax.set_ylabel("angle c [deg]")
        _legend(ax)

    ax = ax_of["err"]
    err = np.linalg.norm(r.setpoint_pos - r.reference_pos, axis=1)
    ax.semilogy(t, np.maximum(err, 1e-9), color="k", lw=1.0,
                label="|dp| translation\n(below 1e-9 drawn at 1e-9)")
    if rotates:
        err_c = np.abs(r.setpoint_ang - r.reference_ang)
        ax.semilogy(t, np.maximum(err_c, 1e-9), color="tab:purple", lw=0.8,
                    label="|dc| rotation [deg]")
    ax.axhline(0.05, color="tab:red", lw=0.8, ls=":", label="0.05 mm (sync tolerance)")
    ax.set_ylabel("tracking error [mm]")
    ax.set_ylim(5e-10, max(10.0, float(np.nanmax(err)) * 2.0))
    _legend(ax)

    lim = r.limits
    sp_v, sp_a, sp_j = (_norm(_fd(r.setpoint_pos, T, k)) for k in (1, 2, 3))
    m_v, m_a = (_norm(_fd(r.master_pos, T, k)) for k in (1, 2))
    for key, series, master, unit, attr in (
            ("vel", sp_v, m_v, "mm/s", "vel"), ("acc", sp_a, m_a, "mm/s^2", "acc"),
            ("jerk", sp_j, None, "mm/s^3", "jerk")):
        ax = ax_of[key]
        if master is not None:
            ax.plot(t, master, ":", color="tab:gray", lw=1.0, label="master")
        ax.plot(t, series, color="tab:blue", lw=1.0, label="setpoint")
        sync_l = getattr(lim.sync_trans, attr)
        desync_l = getattr(lim.desync_trans, attr)
        ax.axhline(sync_l, color="tab:red", lw=1.0, ls="--", label=f"sync limit {sync_l:g}")
        if desync_l != sync_l:
            ax.axhline(desync_l, color="tab:brown", lw=1.0, ls="-.",
                       label=f"desync limit {desync_l:g}")
        top = max(sync_l, desync_l)
        peak = float(np.nanmax(series)) if np.isfinite(series).any() else 0.0
        if key == "jerk" and peak > 3.0 * top:
            ax.set_ylim(0, 3.0 * top)
            ax.text(0.99, 0.92, f"peak {peak:.3g} {unit} (off scale)",
                    transform=ax.transAxes, ha="right", va="top", fontsize=7,
                    bbox=dict(boxstyle="round", fc="white", alpha=0.8))
        else:
            ax.set_ylim(0, 1.15 * max(top, peak))
        ax.set_ylabel(f"|{'v' if key == 'vel' else 'a' if key == 'acc' else 'j'}| [{unit}]")
        _legend(ax)

    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(t[0], t[-1])
    title = r.scenario.name or (r.scenario.source.name if r.scenario.source else "scenario")
    fig.suptitle(f"{title} - planner {r.params.planner}, mode {r.params.mode.name.lower()}, "
                 f"T = {T * 1000:g} ms", fontsize=11, x=0.01, y=1.0 - 0.08 / height_in,
                 ha="left", va="top")
    handles = [Patch(color=c, alpha=0.35, label=name) for c, name in _SHADE.values()]
    fig.legend(handles=handles, loc="upper left", ncol=3, fontsize=8, frameon=False,
               bbox_to_anchor=(0.005, 1.0 - 0.36 / height_in))
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.55 / height_in))
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path


# -- conveyor scenarios ------------------------------------------------------------------
def marker_points(result) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """The conveyor plot's markers: {item: TCP at its pick} and {item: where the item was
    at its "Item missed" (30238), i.e. at the window exit} (world, mm)."""
    r = result
    T = r.sample_time_s
    picked: dict[int, np.ndarray] = {}
    missed: dict[int, np.ndarray] = {}
    for rec in r.records:
        if rec.item_id in r.picks:
            k = int(round(r.picks[rec.item_id] / T))
            picked[rec.item_id] = np.asarray(r.setpoint_pos[k])
        elif rec.missed_sample is not None:
            missed[rec.item_id] = r.item_position(rec.item_id, rec.missed_sample)
    return picked, missed


def plot_conveyor_result(result, path: str | Path, *, dpi: int = 110) -> Path:
    """PNG of a conveyor scenario.

    Left: the XY plane [mm] - the conveyor path (the trigger point and, for a rotary frame,
    the arc; the window part drawn thick), each item's path (grey), where items were picked
    (green dots) or missed (red crosses), and the robot's TCP path (blue; the virtual robot
    dotted).  Right, on the time axis [s]: the TCP's x, y, z and the IMFS value (-2...1),
    with the items' sync times marked.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    r = result
    sc = r.scenario
    f = r.frame
    g = f.geometry()
    fig = Figure(figsize=(13, 6.2))
    FigureCanvasAgg(fig)
    ax, (at, ai) = fig.add_subplot(1, 2, 1), fig.subplots(2, 1, sharex=True, gridspec_kw={
        "left": 0.62, "right": 0.985, "height_ratios": [3, 1.3]})
    w = f.window
    if sc.frame.type == 0:
        d = g.directions[0]
        o = g.origin.pos
        lo = min(0.0, w.upstream[0])
        hi = w.downstream[0] * 1.1

        def seg(a, b):
            return np.array([[o[i] + d[i] * s for i in range(3)] for s in (a, b)])
        full = seg(lo, hi)
        win = seg(w.upstream[0], w.downstream[0])
    else:
        arc = g.arc
        xs = np.linspace(0.0, arc.alpha_deg, 181)
        full = np.array([arc.position(x) for x in xs])
        xw = np.linspace(max(0.0, w.upstream[0]), min(arc.alpha_deg, w.downstream[0]), 91)
        win = np.array([arc.position(x) for x in xw])
        circle = np.array([arc.position(x) for x in np.linspace(0, 360, 181)])
        ax.plot(circle[:, 0], circle[:, 1], color="0.85", lw=0.8)
        ax.plot(*arc.center[:2], "+", color="0.5")
    ax.plot(full[:, 0], full[:, 1], color="0.55", lw=1.2, label="conveyor path")
    ax.plot(win[:, 0], win[:, 1], color="tab:orange", lw=5, alpha=0.5, solid_capstyle="butt",
            label="window")
    zero = f.zero()
    ax.plot(zero.pos[0], zero.pos[1], "s", color="k", ms=5, label="trigger point (MF.zero)")
    for _rid, (_ts, pts) in r.item_paths.items():
        ax.plot(pts[:, 0], pts[:, 1], color="0.6", lw=0.6)
    T = r.sample_time_s
    picked, missed = marker_points(r)
    picked_x, picked_y = [p[0] for p in picked.values()], [p[1] for p in picked.values()]
    missed_x, missed_y = [p[0] for p in missed.values()], [p[1] for p in missed.values()]
    ax.plot(r.virtual_pos[:, 0], r.virtual_pos[:, 1], ":", color="tab:blue", lw=0.8,
            label="virtual robot")
    ax.plot(r.setpoint_pos[:, 0], r.setpoint_pos[:, 1], color="tab:blue", lw=1.3,
            label="robot TCP")
    if picked_x:
        ax.plot(picked_x, picked_y, "o", color="tab:green", ms=7, label="picked")
    if missed_x:
        ax.plot(missed_x, missed_y, "x", color="tab:red", ms=9, mew=2, label="missed (30238)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.grid(True, lw=0.4, alpha=0.6)
    ax.legend(loc="best", fontsize=7)
    title = sc.name or (sc.source.name if sc.source else "conveyor scenario")
    ax.set_title(f"{title}\n{len(r.records)} items: {r.caught} caught, {len(r.picks)} picked, "
                 f"{r.missed} missed", fontsize=10)

    t = r.time_s
    for i, (name, c) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"))):
        at.plot(t, r.setpoint_pos[:, i], color=c, lw=1.1, label=f"TCP {name}")
        at.plot(t, r.virtual_pos[:, i], ":", color=c, lw=0.8)
    for rec in r.records:
        if rec.synced_s is not None:
            at.axvline(rec.synced_s, color="tab:green", lw=0.6, alpha=0.6)
        if rec.missed_sample is not None:
            at.axvline(rec.missed_sample * T, color="tab:red", lw=0.8, alpha=0.8)
    at.set_ylabel("position [mm]\n(virtual dotted)")
    at.grid(True, lw=0.4, alpha=0.6)
    at.legend(loc="upper left", fontsize=7, ncol=3)
    at.set_title("TCP over time (green: item synchronised, red: item missed)", fontsize=9)
    ai.step(t, r.imfs, where="post", color="k", lw=1.0)
    ai.set_yticks([-2, -1, 0, 1])
    ai.set_ylim(-2.4, 1.4)
    ai.set_ylabel("IMFS")
    ai.set_xlabel("time [s]")
    ai.grid(True, lw=0.4, alpha=0.6)
    ai.set_xlim(t[0], t[-1])
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.09, top=0.9, wspace=0.25)
    ax.set_position([0.065, 0.09, 0.47, 0.8])
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path
