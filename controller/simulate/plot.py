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
