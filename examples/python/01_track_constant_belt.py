"""01 - Track a point on a belt that moves at constant speed, with the tracking core alone.

The robot stands still 250 mm behind and 150 mm beside a point on a belt moving at 300 mm/s
along x.  ``engage()`` (slave = 3, absolute) brings the robot onto the point, the tracker then
follows it exactly, and ``disengage()`` stops the robot on the path with the de-sync limits.
Spec: docs/spec/tracking.md#2.1 (states), #2.3 (modes), #6 (the default planner ``optimal``),
#3 (``--planner softmc``), #5 (the stop on the path).

Run from the repository root:

    python examples/python/01_track_constant_belt.py [--planner softmc] [--sample-time 0.002]

Units: mm, mm/s, mm/s^2, s.
"""

from __future__ import annotations

import argparse
import math

from controller.tracking import MotionState, Tracker, TrackerParams, TrackState

BELT_SPEED_MM_S = 300.0
ROBOT_START_MM = (-250.0, 150.0, 0.0)  # relative to the belt point at t = 0


def norm(v) -> float:
    return math.sqrt(sum(x * x for x in v))


def run(planner: str = "optimal", sample_time_s: float = 0.002, follow_s: float = 1.0) -> dict:
    """Engage at t = 0, follow for ``follow_s`` after synchronising, disengage; the figures."""
    params = TrackerParams(sample_time_s=sample_time_s, planner=planner)
    limits = params.effective().sync_trans
    tracker = Tracker(params, MotionState.at(*ROBOT_START_MM))
    tracker.engage()

    def belt(k: int) -> MotionState:
        t = k * sample_time_s
        return MotionState((BELT_SPEED_MM_S * t, 0.0, 0.0), (BELT_SPEED_MM_S, 0.0, 0.0))

    k = 0
    peak_acc = peak_vel = 0.0
    synced_at = None
    error_after_sync = 0.0
    while True:
        k += 1
        out = tracker.update(belt(k))
        sp = out.setpoint
        peak_vel = max(peak_vel, norm(sp.vel))
        peak_acc = max(peak_acc, norm(sp.acc))
        if out.state == TrackState.SYNCED:
            if synced_at is None:
                synced_at = k
            error_after_sync = max(error_after_sync, norm(
                [a - b for a, b in zip(sp.pos, belt(k).pos)]))
            if (k - synced_at) * sample_time_s >= follow_s:
                break
        if k * sample_time_s > 10.0:
            raise SystemExit("not synchronised within 10 s")
    tracker.disengage()
    start = tracker.setpoint
    while out.state != TrackState.OFF:  # the stop on the path
        k += 1
        out = tracker.update(belt(k))
    return {
        "planner": planner,
        "sample_time_s": sample_time_s,
        "time_to_sync_s": synced_at * sample_time_s,
        "error_after_sync_mm": error_after_sync,
        "peak_velocity_mm_s": peak_vel,
        "velocity_limit_mm_s": limits.vel,
        "peak_acceleration_mm_s2": peak_acc,
        "acceleration_limit_mm_s2": limits.acc,
        "stop_distance_mm": out.setpoint.pos[0] - start.pos[0],
        "final_speed_mm_s": norm(out.setpoint.vel),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--planner", default="optimal", choices=["optimal", "softmc"])
    ap.add_argument("--sample-time", type=float, default=0.002, help="sample period [s]")
    args = ap.parse_args(argv)
    r = run(args.planner, args.sample_time)
    print(f"planner {r['planner']}, T = {r['sample_time_s'] * 1e3:g} ms, "
          f"belt {BELT_SPEED_MM_S:g} mm/s")
    print(f"time to sync: {r['time_to_sync_s']:.3f} s")
    print(f"error after sync: {r['error_after_sync_mm']:.3g} mm")
    print(f"peak velocity: {r['peak_velocity_mm_s']:.1f} mm/s "
          f"(limit {r['velocity_limit_mm_s']:g})")
    print(f"peak acceleration: {r['peak_acceleration_mm_s2']:.0f} mm/s^2 "
          f"(limit {r['acceleration_limit_mm_s2']:g})")
    print(f"stop distance after disengage: {r['stop_distance_mm']:.2f} mm, "
          f"final speed {r['final_speed_mm_s']:.3g} mm/s")
    return r


if __name__ == "__main__":
    main()
