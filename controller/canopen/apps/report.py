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
from typing import TYPE_CHECKING, Any

import numpy as np

from ...tracking import TrackState
from ..io.files import json_safe
from .demo import Outcome

if TYPE_CHECKING:
    from ...conveyor.telemetry import ItemRecord
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
    """|SYNC interval - period| of the last 500 cycles [ns] (the whole run is in
    ``ctl.timing.jitter``, a histogram)."""
    return ctl.timing.recent_jitter.values()


def status_line(ctl: Controller, rec: CycleRecord, items: str = "") -> str:
    p99 = percentiles_us(jitter_ns(ctl))["p99"] if ctl.clock.realtime else math.nan
    jit = "stepped" if not ctl.clock.realtime else \
        "jitter p99 -- us" if math.isnan(p99) else f"jitter p99 {p99:.0f} us"
    return (f"cycle {rec.cycle:6d}  t {rec.t_s:7.3f} s  {rec.phase:<8} "
            f"{_STATE.get(rec.state, '?'):<9} IMFS {rec.imfs:+d}  "
            f"err {rec.tracking_error:7.3f} mm  {items}load {100 * ctl.bus_load.load:.1f} %  "
            f"{jit}")


def timing_summary(ctl: Controller) -> dict:
    tm = ctl.timing
    return {"sync_jitter_us": tm.jitter.summary_us(),
            "sync_late_us": tm.sync_late.summary_us(),
            "latency_us": tm.latency.summary_us(),
            "compute_us": tm.compute.summary_us(),
            "cpu_cycle_us": tm.cpu_cycle.summary_us(),
            "cpu_compute_us": tm.cpu_compute.summary_us(),
            "gc_us": tm.gc.summary_us(),
            "missed": tm.missed, "missed_in_row_max": tm.missed_run.longest,
            "late_inputs": tm.late_inputs, "overruns": tm.overruns,
            "cycles": ctl.k}


#: item rows of the summary table (the last ones; the counts cover all)
TABLE_ROWS = 30


def summary_table(ctl: Controller, items: Sequence[Item], wall_s: float,
                  counts: tuple[int, int, int] | None = None,
                  ignored_count: int | None = None, item_rows: bool = True) -> str:
    """The run's summary; ``counts`` = (placed, missed, seen) of all items when ``items``
    holds only the last ones; ``item_rows`` False: only the run's lines (cycles, bus load,
    timing; a cell prints its items itself)."""
    T = ctl.cfg.period_s
    lines = [(f"{'item':>4}  {'outcome':<7}  {'trigger s':>9}  {'sync after s':>12}  "
              f"{'max err mm':>10}  {'u at pick mm':>12}  note")]
    if not item_rows:
        lines = []
    if len(items) > TABLE_ROWS:
        lines.append(f"  ... {len(items) - TABLE_ROWS} items before these")
        items = items[-TABLE_ROWS:]
    for it in items:
        trig = f"{it.trigger_cycle * T:9.3f}" if it.trigger_cycle is not None else f"{'-':>9}"
        sync = f"{(it.synced_cycle - it.engage_cycle) * T:12.3f}" \
            if it.synced_cycle is not None and it.engage_cycle is not None else f"{'-':>12}"
        err = f"{it.max_error_mm:10.4f}" if it.synced_cycle is not None else f"{'-':>10}"
        upick = f"{it.u_pick:12.1f}" if it.u_pick is not None else f"{'-':>12}"
        lines.append(f"{it.index:>4}  {it.outcome:<7}  {trig}  {sync}  {err}  {upick}  "
                     f"{it.reason}")
    if counts is not None:
        placed, missed, seen = counts
        seen = max(seen, len(items))
        ignored = sum(1 for i in items if i.outcome is Outcome.IGNORED) if ignored_count is None \
            else ignored_count
    else:
        placed = sum(1 for i in items if i.outcome is Outcome.PLACED)
        missed = sum(1 for i in items if i.outcome is Outcome.MISSED)
        ignored = sum(1 for i in items if i.outcome is Outcome.IGNORED)
        seen = len(items)
    sim_s = ctl.k * T
    run = (f"{ctl.k} cycles = {sim_s:.2f} s simulated in {wall_s:.2f} s wall "
           f"({sim_s / wall_s if wall_s else math.inf:.1f}x real time)")
    if item_rows:
        lines.append("")
        lines.append(f"items placed {placed}, missed {missed}, "
                     + (f"ignored {ignored} (type not tracked), " if ignored else "")
                     + f"of {seen}; " + run)
    else:
        lines.append(run)
    lines.append(f"bus load {100 * ctl.bus_load.load:.1f} % "
                 f"({ctl.bus_load.bits_per_cycle:.0f} bit per {T * 1e3:g} ms cycle at "
                 f"{ctl.cfg.master.baudrate_kbit} kbit/s); events {ctl.events.total}")
    if ctl.clock.realtime:
        t = timing_summary(ctl)
        j, lat = t["sync_jitter_us"], t["latency_us"]
        lines.append(f"SYNC jitter p50/p99/max {j['p50']:.0f}/{j['p99']:.0f}/{j['max']:.0f} us; "
                     f"master-PDO->RPDO p50/p99 {lat['p50']:.0f}/{lat['p99']:.0f} us; "
                     f"missed deadlines {t['missed']}")
    return "\n".join(lines)


def run_header(ctl: Controller, extra: dict | None = None) -> dict:
    """The ``run`` line of the telemetry (what the run is; its figures are in ``end``)."""
    head = {"type": "run", "config": ctl.cfg.file, "period_s": ctl.cfg.period_s,
            "axes": [a.axis for a in ctl.axes], "bus_load": ctl.bus_load.load,
            "bits_per_cycle": ctl.bus_load.bits_per_cycle,
            "realtime": bool(ctl.clock.realtime)}
    head.update(extra or {})
    return head


class Telemetry:
    """The telemetry of a run, written as it happens (JSON lines, :mod:`.io.rotating`).

    Lines: ``run`` (the top of every file, also after a rotation), ``event`` (each event as
    it is added), ``cycle`` (every ``every``-th cycle record), ``item`` (each item when it is
    finished: flushed at once), ``end`` (timing summary, counts, how the run ended; written
    by :meth:`close` on every exit the process survives).  Flushed at least once a second,
    so that after a SIGKILL at most the last line is incomplete.
    """

    def __init__(self, path: str | Path, ctl: Controller, *, max_bytes: int = 0,
                 max_age_s: float = 0.0, keep: int | None = None, every: int = 1,
                 extra: dict | None = None) -> None:
        from ..io.rotating import JsonLines
        self.ctl = ctl
        self.every = max(1, int(every))
        self.out = JsonLines(path, max_bytes, max_age_s=max_age_s, keep=keep,
                             header=run_header(ctl, extra))
        ctl.events.listeners.append(self.event)

    @property
    def path(self) -> Path:
        return self.out.path

    def _t(self) -> float:
        ctl = self.ctl
        return (ctl.t0 + ctl.k * ctl.period_ns) * 1e-9 if ctl.t0 else 0.0

    def event(self, e) -> None:
        d = {"type": "event"}
        d.update(e.as_dict())
        self.out.write(d, t_s=max(e.t_s, 0.0))

    def cycle(self, rec: CycleRecord) -> None:
        if rec.cycle % self.every == 0:
            d = {"type": "cycle"}
            d.update(rec.as_dict())
            self.out.write(d, t_s=rec.t_s)

    def item(self, it: Item, t_s: float | None = None) -> None:
        d: dict[str, Any] = {"type": "item"}
        d.update(asdict(it))
        d["t_s"] = t_s if t_s is not None else self.ctl.k * self.ctl.cfg.period_s
        self.out.write(d, t_s=d["t_s"])
        self.out.flush()

    def cell_item(self, robot: str, rec: ItemRecord) -> None:
        """An item of a cell's robot (:mod:`.cell`): its conveyor-model record (frame, type,
        status, times [s since tracking began], peak errors [mm])."""
        d: dict[str, Any] = {"type": "item"}
        d.update(rec.as_dict())
        d["robot"] = robot
        d["t_s"] = self.ctl.k * self.ctl.cfg.period_s
        self.out.write(d, t_s=d["t_s"])
        self.out.flush()

    def close(self, end: str = "end", error: str | None = None,
              items: Sequence[Item] = (), extra: dict | None = None) -> None:
        """The items still pending, the ``end`` line, close (once; later calls do nothing)."""
        if self.out.closed:
            return
        ctl = self.ctl
        for it in items:
            if it.outcome is Outcome.PENDING:
                self.item(it)
        d = {"type": "end", "end": end, "error": error, "cycles": ctl.k,
             "t_s": ctl.k * ctl.cfg.period_s, "phase": ctl.phase.value,
             "events": ctl.events.total, "reactions": ctl.events.reactions,
             "timing": timing_summary(ctl)}
        d.update(extra or {})
        self.out.write(d)
        self.out.close()
        if self.event in ctl.events.listeners:
            ctl.events.listeners.remove(self.event)


class PlotTrace:
    """A bounded, decimated trace of the cycle records for the plot: at most ``size``
    records; when full, every second one is dropped and only every 2nd, 4th, ... cycle is
    taken from then on (the plot of a week is as light as a minute's)."""

    def __init__(self, size: int = 20_000) -> None:
        self.size = size
        self.stride = 1
        self.records: list[CycleRecord] = []

    def add(self, rec: CycleRecord) -> None:
        if rec.cycle % self.stride:
            return
        self.records.append(rec)
        if len(self.records) >= self.size:
            self.stride *= 2
            self.records = [r for r in self.records if r.cycle % self.stride == 0]

    def __iter__(self):
        return iter(self.records)

    def __len__(self) -> int:
        return len(self.records)


def write_telemetry(path: str | Path, ctl: Controller, items: Sequence[Item] = (),
                    extra: dict | None = None) -> None:
    """The whole telemetry of a finished run at once (its ``trace``, events, items);
    long-running commands stream it with :class:`Telemetry` instead."""
    with open(path, "w", encoding="utf-8") as f:
        head = run_header(ctl, {"cycles": ctl.k, "timing": timing_summary(ctl)})
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


def plot_run(path: str | Path, ctl: Controller, items: Sequence[Item] = (),
             trace=None) -> None:
    """Positions, belt, tracking error and tracker state of a run (matplotlib, Agg);
    ``trace``: the records to plot (default ``ctl.trace``; a :class:`PlotTrace`)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    trace = list(ctl.trace if trace is None else trace)
    recs = [r for r in trace if r.phase in ("running", "stopping", "stopped")]
    if not recs:
        recs = trace
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
