"""``cantrack capacity SCENARIO.yaml [--speeds LO:HI:N] [--spacings LO:HI:N]
[--window-shifts LO:HI:N] [--workers N] [--plot [PNG]] [--json OUT]``.

Sweeps belt speed x item spacing (x window placement) for a conveyor scenario and prints the
fastest belt speed at which every item is picked, per spacing, with the limiting reason
above it, and the map (:mod:`controller.simulate.capacity`, docs/spec/capacity.md).  ``--plot`` writes the map as a
PNG, ``--json`` the numbers.  Units: the frame's (mm, mm/s on a belt; deg, deg/s on a table).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Sequence

from ..errors import ConfigError

log = logging.getLogger(__name__)


def _range(text: str, what: str) -> tuple[float, ...]:
    """``LO:HI:N`` (N values, ends included) or ``A,B,C``."""
    try:
        if ":" in text:
            lo, hi, n = text.split(":")
            lo_f, hi_f, n_i = float(lo), float(hi), int(n)
            if n_i < 1 or (n_i > 1 and not hi_f > lo_f):
                raise ValueError
            if n_i == 1:
                return (lo_f,)
            return tuple(lo_f + (hi_f - lo_f) * i / (n_i - 1) for i in range(n_i))
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"--{what} (={text!r}) must be LO:HI:N (N >= 1 values, HI > LO) or "
                          "a comma-separated list of numbers") from None


def build_parser(prog: str = "cantrack capacity") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description="Up to which belt speed and item rate does this conveyor cell pick every "
                    "item?  Sweeps belt speed x item spacing (x window placement) with the "
                    "simulator's pick-cycle model and reports the boundary and its limit.")
    p.add_argument("scenario", type=Path, metavar="SCENARIO.yaml",
                   help="a conveyor scenario (frame, robot, pick program; its items and "
                        "master speed are replaced by the sweep)")
    p.add_argument("--speeds", metavar="LO:HI:N",
                   help="belt speeds [mm/s or deg/s] (default: 20 from 10 %% to 100 %% of the "
                        "frame's VelocityMaxTrans and the sync velocity, whichever is lower)")
    p.add_argument("--spacings", metavar="LO:HI:N",
                   help="item spacings [mm or deg] (default: 20 from 10 %% to 100 %% of the "
                        "window length)")
    p.add_argument("--window-shifts", metavar="LO:HI:N",
                   help="also shift the window by these [mm or deg] (window placement)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes (default: the CPUs; 1: no sub-processes)")
    p.add_argument("--plot", nargs="?", const="", default=None, metavar="PNG",
                   help="write the map as a PNG (default: <scenario stem>_capacity.png)")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the numbers as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing")
    return p


def main(argv: Sequence[str] | None = None, prog: str = "cantrack capacity") -> int:
    args = build_parser(prog).parse_args(argv)
    from ..simulate.capacity import capacity, format_capacity, plot_capacity
    from ..simulate.conveyor import ConveyorScenario
    from ..simulate.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if not isinstance(sc, ConveyorScenario):
        raise ConfigError("capacity needs a conveyor scenario (a top-level 'conveyor' "
                          "section: one frame, one robot and its pick program)",
                          file=str(args.scenario))
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers (={args.workers}) must be >= 1")
    if args.speeds:
        speeds = _range(args.speeds, "speeds")
    else:
        top = min(sc.frame.limits.trans.vel, sc.params.effective().sync_trans.vel)
        speeds = _range(f"{0.1 * top}:{top}:20", "speeds")
    w = sc.frame.window
    length = w.downstream[0] - w.upstream[0]
    spacings = _range(args.spacings, "spacings") if args.spacings else \
        _range(f"{0.1 * length}:{length}:20", "spacings")
    shifts = _range(args.window_shifts, "window-shifts") if args.window_shifts else (0.0,)
    result = capacity(sc, speeds, spacings, shifts, workers=args.workers)
    png = None
    if args.plot is not None:
        png = Path(args.plot) if args.plot else Path.cwd() / f"{args.scenario.stem}_capacity.png"
        plot_capacity(result, png)
    if args.json is not None:
        data = {"scenario": str(args.scenario), "units": result.units,
                "speeds": list(result.speeds), "spacings": list(result.spacings),
                "window_shifts": list(result.window_shifts),
                "ok": result.ok.tolist(), "reasons": result.reasons,
                "items_before_loss": result.items_before_loss,
                "boundary": result.boundary, "limit": result.limit,
                "pick_cycles": result.cycles, "elapsed_s": result.elapsed_s}
        args.json.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    if not args.quiet:
        print(format_capacity(result, str(args.scenario) + (f"  ({sc.name})" if sc.name
                                                            else "")))
        if png is not None:
            print(f"\nPlot       {png}")
        if args.json is not None:
            print(f"JSON       {args.json}")
    return 0
