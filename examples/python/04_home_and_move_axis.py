"""04 - Home an axis and move it, through the CANopen shell on simulated CiA 402 drives.

The demo's bus (``examples/bus/demo.yml``: an encoder and four CSP drives x, y, z, c) runs on
simulated devices in stepped time.  Axis x homes with the drive's own homing mode (CiA 402
mode 6, method 21: towards the home switch in the negative direction), then moves to
100 mm with a jerk-limited point-to-point profile (Sled_Y), streamed as 607Ah targets every
SYNC.  Both jobs run in one session, so the move starts where homing left the axis.
Spec: docs/spec/axis.md#3 (point-to-point), #5.3 (the drive's homing mode), #6 (counts).

Run from the repository root:

    python examples/python/04_home_and_move_axis.py [--to 100]

On a real bus pass ``transport=`` (a bus opened with ``controller.canopen`` on ``can0``)
instead of the simulated world: the same calls, the same reports.  Units: mm, counts, s.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from controller.canopen.apps.axis_motion import home, move
from controller.canopen.config import load_config
from controller.canopen.slave.world import SimWorld

BUS_YML = Path(__file__).resolve().parents[1] / "bus" / "demo.yml"


def run(target_mm: float = 100.0) -> dict:
    cfg = load_config(BUS_YML)
    axis = next(a for a in cfg.tracking.axes if a.name == "x")
    with SimWorld(cfg) as world:                      # the simulated drives, stepped time
        homed = home(cfg, "x", transport=world.transport)[0]
        moved = move(cfg, "x", target_mm, transport=world.transport)
    steps = [abs(b - a) for a, b in zip(moved.targets, moved.targets[1:])]
    return {"axis": axis, "period_s": cfg.period_s, "home": homed, "move": moved,
            "max_step_counts": max(steps) if steps else 0}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--to", type=float, default=100.0, help="move target [mm]")
    args = ap.parse_args(argv)
    r = run(args.to)
    h, m, ax = r["home"], r["move"], r["axis"]
    print(f"home x: {h.result} ({h.message}); from {h.start_mm:.3f} mm to {h.end_mm:.3f} mm "
          f"in {h.time_s:.3f} s, home offset {h.home_offset_mm} mm")
    print(f"move x: {m.result}, states {' -> '.join(m.states)}")
    print(f"move from: {m.start_mm:.4f} mm")
    print(f"move end: {m.end_mm:.4f} mm, 6064h = {m.end_counts} counts")
    print(f"move time: {m.time_s:.3f} s ({m.cycles} cycles of {r['period_s'] * 1e3:g} ms)")
    lim = ax.motion.limits
    bound = math.ceil(ax.scale.counts_per_unit * lim.vel * r["period_s"])
    print(f"largest 607Ah step per cycle: {r['max_step_counts']} counts (bound {bound}: "
          f"V = {lim.vel:g} mm/s)")
    return r


if __name__ == "__main__":
    main()
