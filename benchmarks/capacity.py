"""Benchmark of ``cantrack capacity``: the wall time of a 20 x 20 sweep (belt speed x item
spacing) of the shipped linear cell, examples/conveyor_linear.yaml, on 2 worker processes
(target: under 60 s on 2 cores).  Prints the figures (and writes them as JSON with --json).

    python benchmarks/capacity.py [--speeds N] [--spacings N] [--workers 2] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller.simulate.capacity import capacity  # noqa: E402
from controller.simulate.scenario import load_scenario  # noqa: E402

TARGET_S = 60.0


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", type=Path, default=ROOT / "examples" / "conveyor_linear.yaml")
    p.add_argument("--speeds", type=int, default=20)
    p.add_argument("--spacings", type=int, default=20)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    sc = load_scenario(a.scenario)
    top = min(sc.frame.limits.trans.vel, sc.params.effective().sync_trans.vel)
    w = sc.frame.window
    length = w.downstream[0] - w.upstream[0]
    speeds = [top * (0.1 + 0.9 * i / max(1, a.speeds - 1)) for i in range(a.speeds)]
    spacings = [length * (0.1 + 0.9 * i / max(1, a.spacings - 1)) for i in range(a.spacings)]
    t0 = time.perf_counter()
    r = capacity(sc, speeds, spacings, workers=a.workers)
    wall = time.perf_counter() - t0
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    fig = {"scenario": str(a.scenario.relative_to(ROOT) if a.scenario.is_relative_to(ROOT)
                           else a.scenario),
           "grid": f"{a.speeds} x {a.spacings}", "workers": a.workers, "cpus": os.cpu_count(),
           "load_1min": load, "pick_cycles": r.cycles, "wall_s": wall,
           "per_cycle_ms": 1000.0 * wall * a.workers / max(1, r.cycles),
           "target_s": TARGET_S, "within_target": wall < TARGET_S,
           "boundary_mm_s": dict(zip([round(s, 1) for s in spacings], r.boundary[0]))}
    print(f"capacity sweep {fig['grid']} of {fig['scenario']}: {wall:.1f} s wall on "
          f"{a.workers} workers ({r.cycles} pick cycles, {fig['per_cycle_ms']:.0f} ms each; "
          f"load {load:.1f} on {os.cpu_count()} CPUs); target < {TARGET_S:g} s: "
          f"{'met' if fig['within_target'] else 'NOT met'}")
    if a.json:
        a.json.write_text(json.dumps(fig, indent=1) + "\n", encoding="utf-8")
    return fig


if __name__ == "__main__":
    main()
