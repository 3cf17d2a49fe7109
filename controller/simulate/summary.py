"""The printed summary of a simulation (plain text, aligned columns).

Every figure comes from :class:`controller.simulate.runner.CycleResult` (that is, from
:func:`controller.tracking.metrics.analyze`) or from the tracker's outputs; nothing is
recomputed here.  Times to sync are relative to the engage time.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..conveyor import EventKind, ItemStatus
from ..tracking import TrackError, TrackState
from ..tracking.metrics import PHASES, POS_TOL_MM, VEL_TOL
from .runner import CycleResult, SimulationResult

__all__ = ["PhaseRow", "phase_rows", "format_summary"]

TOLERANCES = (1e-6, 0.01)


@dataclass(frozen=True)
class PhaseRow:
    """One line of the peaks table: finite-difference norm peaks of one channel in one phase."""

    channel: str  #: "trans" (mm) or "rot" (deg)
    phase: str
    peak: dict[str, float]  #: vel/acc/jerk
    ratio: dict[str, float]
    violations: dict[float, int]  #: tolerance -> samples over limit*(1+tol)


def phase_rows(cycle: CycleResult) -> list[PhaseRow]:
    """The rows of the peaks table of one cycle (phases without motion are left out)."""
    rows = []
    for channel, m in (("trans", cycle.trans), ("rot", cycle.rot)):
        for ph in PHASES:
            viol = {tol: m.violations[tol][ph] for tol in TOLERANCES}
            if not any(m.peak[ph].values()) and not any(viol.values()):
                continue
            rows.append(PhaseRow(channel, ph, dict(m.peak[ph]), dict(m.ratio[ph]), viol))
    return rows


def _table(header: list[str], rows: list[list[str]], left: int = 1, indent: str = "  "
           ) -> list[str]:
    """Aligned columns: the first ``left`` columns left-aligned, the others right-aligned."""
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    out = []
    for r in [header] + rows:
        cells = [c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in
                 enumerate(zip(r, widths))]
        out.append(indent + "  ".join(cells).rstrip())
    return out


def _g(x: float | None, digits: int = 4) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}g}"


def _s(x: float | None, suffix: str = "") -> str:
    return "never" if x is None else f"{x:.3f} s{suffix}"


def format_summary(result: SimulationResult) -> str:
    """The human-readable summary printed by ``cantrack simulate``."""
    from .conveyor import ConveyorResult

    if isinstance(result, ConveyorResult):
        return format_conveyor_summary(result)
    from .cell import CellResult, format_cell_summary

    if isinstance(result, CellResult):
        return format_cell_summary(result)
    r = result
    sc = r.scenario
    p = r.params
    T = p.sample_time_s
    lines = []
    title = str(sc.source) if sc.source is not None else "<scenario>"
    if sc.name:
        title += f"  ({sc.name})"
    lines.append(f"Scenario   {title}")
    master = "CSV " + sc.master.path.name if hasattr(sc.master, "path") else \
        f"{len(sc.master.segments)} segment(s)"
    if sc.estimator is not None:
        e = sc.estimator
        master += (f", through the estimator (quantisation {e.quantisation_mm:g} mm, delay "
                   f"{e.delay_samples}, window {e.window}, lead {e.lead_samples:g})")
    if sc.conditioning is not None:
        cs = sc.conditioning
        master += (f", through the conditioner ({cs.design.name.lower()}, counts "
                   f"{cs.resolution_mm:g} mm, latency {cs.latency_samples}, jitter "
                   f"{100 * cs.jitter:g} %)")
    lines.append(f"Tracker    planner {p.planner}, mode {p.mode.name.lower()} ({int(p.mode)}), "
                 f"T = {T * 1000:g} ms, {sc.n_samples} samples = {sc.n_samples * T:.3f} s")
    lines.append(f"Master     {master}")
    lines.append("")
    lim = r.limits
    lines.append("Limits (effective)")
    lines += _table(
        ["", "vel", "acc", "jerk", "unit"],
        [[name, _g(L.vel, 6), _g(L.acc, 6), _g(L.jerk, 6), unit] for name, L, unit in (
            ("sync trans", lim.sync_trans, "mm/s, mm/s^2, mm/s^3"),
            ("desync trans", lim.desync_trans, "mm/s, mm/s^2, mm/s^3"),
            ("sync rot", lim.sync_rot, "deg/s, deg/s^2, deg/s^3"),
            ("desync rot", lim.desync_rot, "deg/s, deg/s^2, deg/s^3"))], left=1)
    for c in r.cycles:
        lines.append("")
        dis = f", disengage at {c.disengage_s:.3f} s" if c.disengage_s is not None else ""
        lines.append(f"Cycle {c.index + 1}: engage at {c.engage_s:.3f} s{dis}, "
                     f"mode {c.mode.name.lower()}, rows {c.first_row}..{c.last_row}")
        tts_t = (c.trans.time_to_sync_s - c.engage_s) if c.trans.synced else None
        tts_r = (c.rot.time_to_sync_s - c.engage_s) if c.rot.synced else None
        err_a = (f"trans {_g(c.trans.error_after_sync_mm, 3)} mm, "
                 f"rot {_g(c.rot.error_after_sync_mm, 3)} deg")
        info = [
            ["tracker SYNCED", _s(c.synced_after_s, " after engage")],
            ["time to sync", f"{_s(c.time_to_sync_s, ' after engage')} (trans {_s(tts_t)}, "
                             f"rot {_s(tts_r)}; |dp| <= {POS_TOL_MM:g}, |dv| <= {VEL_TOL:g})"],
            ["largest error after sync", err_a],
            ["oscillation flips", f"trans {c.trans.oscillation_flips}, "
                                  f"rot {c.rot.oscillation_flips}"
                                  + ("  OSCILLATING" if c.trans.oscillating or
                                     c.rot.oscillating else "")],
            ["errors", ", ".join(f"{e.name} at {t:.3f} s" for t, e in c.errors) or "none"],
        ]
        if c.mode.name == "RELATIVE":
            o = c.offset_pos
            info.insert(0, ["relative offset", f"({o[0]:.3f}, {o[1]:.3f}, {o[2]:.3f}) mm, "
                                               f"{c.offset_ang:.3f} deg"])
        lines += _table(["", ""], info, left=2)[1:]
        rows = phase_rows(c)
        lines.append("")
        if rows:
            lines += _table(
                ["channel", "phase", "peak vel", "ratio", "peak acc", "ratio", "peak jerk",
                 "ratio", ">1e-6", ">1%"],
                [[row.channel, row.phase,
                  _g(row.peak["vel"]), f"{row.ratio['vel']:.3f}",
                  _g(row.peak["acc"]), f"{row.ratio['acc']:.3f}",
                  _g(row.peak["jerk"]), f"{row.ratio['jerk']:.3f}",
                  str(row.violations[TOLERANCES[0]]), str(row.violations[TOLERANCES[1]])]
                 for row in rows], left=2)
            lines.append("  (finite-difference norms of the setpoint; ratio = peak / limit, "
                         "desync against the de-sync limits;")
            lines.append("   >1e-6, >1%: samples over the limit by more than that)")
    lines.append("")
    final_err = TrackError(int(r.error[-1]))
    lines.append(f"Final      state {TrackState(int(r.state[-1])).name}, imfs {int(r.imfs[-1])}, "
                 f"error {final_err.name}")
    return "\n".join(lines)


# -- conveyor scenarios ------------------------------------------------------------------
def format_conveyor_summary(result) -> str:
    """The summary of a conveyor scenario: items caught/missed/skipped, per-item time to
    sync, peak tracking errors, oscillation count, pick time and prediction."""
    from ..conveyor import ITEM_MISSED_CODE
    from ..tracking import Imfs
    from .conveyor import type_name

    r = result
    sc = r.scenario
    p = sc.params
    T = p.sample_time_s
    f = r.frame
    fs = sc.frame
    lines = []
    title = str(sc.source) if sc.source is not None else "<scenario>"
    if sc.name:
        title += f"  ({sc.name})"
    lines.append(f"Scenario   {title}")
    unit = "mm" if fs.type == 0 else "deg"
    w = fs.window
    desc = f"'{f.name}' {type_name(fs.type)}, window {w.upstream[0]:g}...{w.downstream[0]:g} " \
           f"{unit} from the trigger"
    if fs.type != 0:
        g = f.geometry()
        desc += (f", center ({', '.join(f'{x:.1f}' for x in g.center)}) mm, R {g.radius:.1f} "
                 f"mm, alpha {g.alpha_deg:.1f} deg")
    lines.append(f"Frame      {desc}")
    m = sc.master
    src = "encoder log " + m.log_path.name if m.log_path is not None else (
        "segment profile" if m.profile is not None else f"{m.speed:g} units/s")
    if m.encoder is not None:
        src += (f", encoder {m.encoder.counts_per_unit:g} counts/unit, modulus "
                f"{m.encoder.modulus}, estimator window {m.encoder.window}")
    lines.append(f"Master     {src}")
    lines.append(f"Robot      '{sc.robot.name}', slave {sc.robot.slave}, planner {p.planner}, "
                 f"T = {T * 1000:g} ms, {sc.n_samples} samples = {sc.n_samples * T:.3f} s")
    n = len(r.records)
    skipped_pred = len(r.skipped)
    lines.append(f"Items      {n} triggered: {r.caught} caught, {len(r.picks)} picked, "
                 f"{r.missed} missed ({ITEM_MISSED_CODE}), {r.count(ItemStatus.SKIPPED)} skipped "
                 f"({skipped_pred} by the prediction), {r.count(ItemStatus.LOST)} lost"
                 + (f", {r.count(ItemStatus.IGNORED)} ignored (type not tracked)"
                    if r.count(ItemStatus.IGNORED) else ""))
    lines.append("")
    rows = []
    for rec in r.records:
        pred = r.predictions.get(rec.item_id)
        ptxt = "-" if pred is None else (f"yes @{pred.time_s:.3f}" if pred.can_catch
                                         else "no")
        pick = r.picks.get(rec.item_id)
        rows.append([str(rec.item_id), f"{rec.trigger_s:.3f}",
                     "-" if rec.entered_s is None else f"{rec.entered_s:.3f}",
                     "-" if rec.synced_s is None else f"{rec.synced_s:.3f}",
                     "-" if rec.time_to_sync_s is None else f"{rec.time_to_sync_s:.3f}",
                     f"{rec.peak_error_approach_mm:.2f}", f"{rec.peak_error_synced_mm:.2g}",
                     str(rec.oscillations), rec.status.value,
                     "-" if pick is None else f"{pick:.3f}", ptxt])
    if rows:
        lines += _table(["item", "trigger", "entered", "synced", "to sync", "peak err",
                         "err synced", "osc", "status", "picked", "prediction"], rows, left=1)
        lines.append("  (times in s; entered: when the robot's frame link took the item in its "
                     "window; peak err: largest")
        lines.append("   |target - contribution| while approaching [mm]; err synced: while "
                     "synchronised [mm];")
        lines.append("   osc: sign flips of the velocity error during the approach)")
    for rid, why in r.skipped.items():
        lines.append(f"  item {rid} skipped: {why}")
    for rid, why in sorted(getattr(r, "unpicked", {}).items()):
        lines.append(f"  item {rid} not picked: {why}")
    errs = [e for e in r.events if e.kind in (EventKind.ITEM_MISSED, EventKind.TRACKER_ERROR,
                                              EventKind.COMMAND_ERROR)]
    if errs:
        lines.append("")
        lines.append("Errors")
        for e in errs:
            code = f" [{e.code}]" if e.code else ""
            lines.append(f"  {e.sample * T:.3f} s  {e.kind.value}{code}  item {e.item}  "
                         f"{e.message}".rstrip())
    ttss = [rec.time_to_sync_s for rec in r.records if rec.time_to_sync_s is not None]
    if ttss:
        lines.append("")
        lines.append(f"Time to sync   min {min(ttss):.3f} s, mean {sum(ttss) / len(ttss):.3f} s, "
                     f"max {max(ttss):.3f} s")
    lines.append("")
    lines.append(f"Final      IMFS {Imfs(int(r.imfs[-1])).name} ({int(r.imfs[-1])}), slave "
                 f"{int(r.slave[-1])}, {len(r.robot.buffer)} item(s) left in the buffer")
    return "\n".join(lines)
