"""02 - A conveyor cell: a belt, a photo-eye, items in a window, a robot that follows each.

A linear moving frame ``cnv`` on a belt at 250 mm/s (a simulated master axis in mm), its
window from 100 mm to 700 mm past the photo-eye.  The photo-eye sees an item every 0.8 s
(TRIGGER); the robot, at rest above the belt, is given ``MasterFrame = cnv`` (slave = 5) and
``MOVES cnv.zero``: it catches each item when it enters the window, follows it until it
leaves downstream, then takes the next one.  The last item arrives while the robot is still
busy with the one before and leaves the window before it can be caught: softMC error 30238,
"item missed".  Spec: docs/spec/conveyor.md#6 (the tracking formula), #7 (items and the
window), #5.1 (the trigger buffer), #10 (IMFS).

Run from the repository root:

    python examples/python/02_conveyor_cell.py

Units: mm, mm/s, s.
"""

from __future__ import annotations

from controller.conveyor import (
    ConveyorCell,
    EventKind,
    Location,
    MovingFrame,
    RobotGroup,
    SimulatedAxis,
    Window,
)
from controller.tracking import TrackerParams

BELT_MM_S = 250.0
T_S = 0.002
#: photo-eye edges [s]; the last one comes too soon after the one before to be caught
TRIGGERS_S = (0.0, 0.8, 1.6, 2.4, 2.45)
RUN_S = 6.0


def run() -> dict:
    belt = SimulatedAxis.constant_speed(BELT_MM_S, name="belt")  # mm
    cnv = MovingFrame("cnv", [belt], directions=[(1.0, 0.0, 0.0)],
                      origin=Location.at(0.0, 400.0, 0.0),       # the photo-eye's point
                      window=Window.single(100.0, 700.0))
    robot = RobotGroup("scara", TrackerParams(sample_time_s=T_S, planner="optimal"),
                       start=Location.at(200.0, 300.0, 50.0))
    cell = ConveyorCell([cnv], [robot])
    robot.master_frame = cnv                      # slave = 5
    robot.moves(cnv.zero())                       # MOVES scara cnv.zero
    triggers = [round(t / T_S) for t in TRIGGERS_S]
    events: list[tuple[float, str, int | None]] = []
    imfs_samples = {0: 0, 1: 0, -1: 0, -2: 0}
    for k in range(round(RUN_S / T_S)):
        if k in triggers:
            robot.trigger(cnv)                    # TRIGGER scara {MasterFrame = cnv}
        out = cell.step()["scara"]
        imfs_samples[int(out.imfs)] += 1
        for e in out.events:
            if e.kind in (EventKind.SYNCHRONIZED, EventKind.ITEM_LEFT, EventKind.ITEM_MISSED):
                events.append((e.sample * T_S, e.kind.value, e.item))
    items = [robot.records[i] for i in sorted(robot.records)]
    return {"items": items, "events": events, "imfs_samples": imfs_samples}


def main() -> dict:
    r = run()
    print(f"belt {BELT_MM_S:g} mm/s, window 100...700 mm, {len(TRIGGERS_S)} triggers")
    for t, kind, item in r["events"]:
        print(f"  t = {t:5.3f} s  item {item}: {kind}")
    print("item  status   time to sync [s]  peak error while following [mm]")
    for rec in r["items"]:
        tts = f"{rec.time_to_sync_s:.3f}" if rec.time_to_sync_s is not None else "-"
        print(f"{rec.item_id:4d}  {rec.status.value:<8} {tts:>16}  {rec.peak_error_synced_mm:.3g}")
    caught = sum(1 for rec in r["items"] if rec.caught)
    missed = sum(1 for rec in r["items"] if rec.missed)
    print(f"caught {caught}, missed {missed}")
    share = {k: v * T_S for k, v in r["imfs_samples"].items()}
    print(f"time per IMFS value [s]: {share}")
    return r


if __name__ == "__main__":
    main()
