"""Results of a controller run: status line, summary table, JSON-lines telemetry, PNG plot.

Telemetry (one JSON object per line, ``type`` first): ``run`` (configuration, bus load,
timing), one ``cycle`` per cycle (:class:`~controller.canopen.master.cycle.CycleRecord` fields:
mm/deg joints, counts, s, us), every ``event`` and, for the demo, every ``item``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...tracking import TrackState
from ..io.files import json_safe

if TYPE_CHECKING:
    from ..master.cycle import Controller, CycleRecord
    from .demo import Item

_STATE = {0: "OFF", 1: "SYNCING", 2: "SYNCED", 3: "DESYNCING"}


def percentiles_us(values_ns: Sequence[int]) -> dict[str, float]:
    """p50/p99/max of ``values_ns`` in microseconds (empty -> NaN)."""
    if not len(values_ns):
        return {"p50": math.nan, "p99": math.nan, "max": math.nan, "n": 0}
    a = np.asarray(values_ns, dtype=float) / 1e3
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max()), "n": int(a.size)}


def jitter_ns(ctl: Controller) -> list[int]:
    """|SYNC interval - period| per cycle [ns]."""
    p = ctl.period_ns
    return [abs(x - p) for x in ctl.timing.sync_interval]


def status_line(ctl: Controller, rec: CycleRecord, items: str = "") -> str:
    p99 = percentiles_us(jitter_ns(ctl)[-500:])["p99"] if ctl.clock.realtime else math.nan
    jit = "stepped" if not ctl.clock.realtime else \
        "jitter p99 -- us" if math.isnan(p99) else f"jitter p99 {p99:.0f} us"
    return (f"cycle {rec.cycle:6d}  t {rec.t_s:7.3f} s  {rec.phase:<8} "
            f"{_STATE.get(rec.state, '?'):<9} IMFS {rec.imfs:+d}  "
            f"err {rec.tracking_error:7.3f} mm  {items}load {100 * ctl.bus_load.load:.1f} %  "
            f"{jit}")


def timing_summary(ctl: Controller) -> dict:
    tm = ctl.timing
    return {"sync_jitter_us": percentiles_us(jitter_ns(ctl)),
            "sync_late_us": percentiles_us(tm.sync_late),
            "latency_us": percentiles_us(tm.latency),
            "compute_us": percentiles_us(tm.compute),
            "cpu_cycle_us": percentiles_us(tm.cpu_cycle),
            "cpu_compute_us": percentiles_us(tm.cpu_compute),
            "missed": tm.missed, "late_inputs": tm.late_inputs, "overruns": tm.overruns,
            "cycles": ctl.k}


def summary_table(ctl: Controller, items: Sequence[Item], wall_s: float) -> str:
    T = ctl.cfg.period_s
    lines = [(f"{'item':>4}  {'outcome':<7}  {'trigger s':>9}  {'sync after s':>12}  "
              f"{'max err mm':>10}  {'u at pick mm':>12}  note")]
    for it in items:
        trig = f"{it.trigger_cycle * T:9.3f}" if it.trigger_cycle is not None else f"{'-':>9}"
        sync = f"{(it.synced_cycle - it.engage_cycle) * T:12.3f}" \
            if it.synced_cycle is not None and it.engage_cycle is not None else f"{'-':>12}"
        err = f"{it.max_error_mm:10.4f}" if it.synced_cycle is not None else f"{'-':>10}"
        upick = f"{it.u_pick:12.1f}" if it.u_pick is not None else f"{'-':>12}"
        lines.append(f"{it.index:>4}  {it.outcome:<7}  {trig}  {sync}  {err}  {upick}  "
                     f"{it.reason}")
    placed = sum(1 for i in items if i.outcome == "placed")
    missed = sum(1 for i in items if i.outcome == "missed")
    ignored = sum(1 for i in items if i.outcome == "ignored")
    sim_s = ctl.k * T
    lines.append("")
    lines.append(f"items placed {placed}, missed {missed}, "
                 + (f"ignored {ignored} (type not tracked), " if ignored else "")
                 + f"of {len(items)}; "
                 f"{ctl.k} cycles = {sim_s:.2f} s simulated in {wall_s:.2f} s wall "
                 f"({sim_s / wall_s if wall_s else math.inf:.1f}x real time)")
    lines.append(f"bus load {100 * ctl.bus_load.load:.1f} % "
                 f"({ctl.bus_load.bits_per_cycle:.0f} bit per {T * 1e3:g} ms cycle at "
                 f"{ctl.cfg.master.baudrate_kbit} kbit/s); events {len(ctl.events)}")
    if ctl.clock.realtime:
        t = timing_summary(ctl)
        j, lat = t["sync_jitter_us"], t["latency_us"]
        lines.append(f"SYNC jitter p50/p99/max {j['p50']:.0f}/{j['p99']:.0f}/{j['max']:.0f} us; "
                     f"master-PDO->RPDO p50/p99 {lat['p50']:.0f}/{lat['p99']:.0f} us; "
                     f"missed deadlines {t['missed']}")
    return "\n".join(lines)


def write_telemetry(path: str | Path, ctl: Controller, items: Sequence[Item] = (),
                    extra: dict | None = None) -> None:
    with open(path, "w", encoding="utf-8") as f:
        head = {"type": "run", "config": ctl.cfg.file, "period_s": ctl.cfg.period_s,
                "axes": [a.axis for a in ctl.axes], "bus_load": ctl.bus_load.load,
                "bits_per_cycle": ctl.bus_load.bits_per_cycle, "cycles": ctl.k,
                "realtime": bool(ctl.clock.realtime), "timing": timing_summary(ctl)}
        head.update(extra or {})
        f.write(json.dumps(json_safe(head), allow_nan=False) + "\n")
        for rec in ctl.trace:
            d = {"type": "cycle"}
            d.update(rec.as_dict())
            f.write(json.dumps(json_safe(d), allow_nan=False) + "\n")
        for e in ctl.events:
            d = {"type": "event"}
            d.update(e.as_dict())
            f.write(json.dumps(json_safe(d), allow_nan=False) + "\n")
        for it in items:
            d = {"type": "item"}
            d.update(asdict(it))
            f.write(json.dumps(json_safe(d), allow_nan=False) + "\n")


def plot_run(path: str | Path, ctl: Controller, items: Sequence[Item] = ()) -> None:
    """Positions, belt, tracking error and tracker state of a run (matplotlib, Agg)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    recs = [r for r in ctl.trace if r.phase in ("running", "stopping", "stopped")]
    if not recs:
        recs = ctl.trace
    t = np.array([r.t_s for r in recs])
    names = [a.axis for a in ctl.axes]
    act = np.array([r.actual for r in recs]) if recs else np.zeros((0, len(names)))
    sp = np.array([r.setpoint if r.setpoint is not None else (np.nan,) * len(names)
                   for r in recs]) if recs else np.zeros((0, len(names)))
    state = np.array([r.state for r in recs])
    err = np.array([r.tracking_error for r in recs])
    fig = Figure(figsize=(11, 9), tight_layout=True)
    FigureCanvasAgg(fig)
    axs = fig.subplots(4, 1, sharex=True)
    shade = {TrackState.SYNCING: "#f5d76e", TrackState.SYNCED: "#8fd18f",
             TrackState.DESYNCING: "#f5a05a"}
    for ax in axs:
        start = 0
        for i in range(1, len(state) + 1):
            if i == len(state) or state[i] != state[start]:
                s = TrackState(int(state[start]))
                if s in shade and len(t):
                    ax.axvspan(t[start], t[min(i, len(t) - 1)], color=shade[s], alpha=0.35,
                               lw=0)
                start = i
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
    lin = [i for i, n in enumerate(names) if n != "c"]
    for i in lin:
        axs[0].plot(t, act[:, i], color=colours[i % 4], label=f"{names[i]} actual")
        axs[0].plot(t, sp[:, i], color=colours[i % 4], ls="--", lw=0.8,
                    label=f"{names[i]} setpoint")
    axs[0].set_ylabel("position [mm]")
    axs[0].legend(loc="upper right", fontsize=7, ncol=3)
    if "c" in names:
        i = names.index("c")
        axs[1].plot(t, act[:, i], color="tab:purple", label="c actual")
        axs[1].plot(t, sp[:, i], color="tab:purple", ls="--", lw=0.8, label="c setpoint")
    belt = np.array([r.belt_mm if r.belt_mm is not None else np.nan for r in recs])
    ax2 = axs[1].twinx()
    ax2.plot(t, belt, color="grey", lw=0.8, label="belt travel")
    ax2.set_ylabel("belt [mm]")
    axs[1].set_ylabel("c [deg]")
    axs[1].legend(loc="upper left", fontsize=7)
    axs[2].semilogy(t, np.where(err > 0, err, np.nan), color="tab:red")
    axs[2].set_ylabel("tracking error [mm]")
    axs[3].step(t, state, where="post", color="k")
    axs[3].set_yticks([0, 1, 2, 3], ["OFF", "SYNCING", "SYNCED", "DESYNC"])
    axs[3].set_xlabel("time [s]")
    T = ctl.cfg.period_s
    for it in items:
        if it.trigger_cycle is not None:
            x = it.trigger_cycle * T
            axs[3].axvline(x, color="tab:blue", lw=0.6, ls=":")
            axs[3].text(x, 3.2, f"item {it.index}", fontsize=7, rotation=90, va="bottom")
    for e in ctl.events:
        if e.cycle >= 0 and e.reaction:
            axs[3].axvline(e.t_s, color="tab:red", lw=0.8)
    fig.suptitle(f"cantrack: {Path(ctl.cfg.file).name}, "
                 f"{ctl.cfg.period_s * 1e3:g} ms cycle, {len(names)} axes")
    fig.savefig(str(path), dpi=90)
