"""03 - The stepped bus demo from Python: the whole controller on a virtual CAN bus.

What ``cantrack demo`` does, as library calls: the demo's bus (``examples/bus/demo.yml``) with
a simulated conveyor encoder (CiA 406), four simulated CiA 402 drives (x, y, z, c) and a
photo-eye, all on an embedded python-can virtual bus in stepped time (deterministic, faster
than real time).  The controller boots the bus (NMT reset, identity check, SDO configuration,
enable without a jump), then the pick-and-place application catches each item in the window,
follows it for the pick, de-syncs on the path and places it.  The bus is recorded in candump
format.  Spec: docs/spec/conveyor.md#7 (items and the window), docs/spec/tracking.md#5 (the
de-sync); the bus configuration: examples/bus/README.md.

Run from the repository root:

    python examples/python/03_bus_demo.py [--items 2] [-o DIR]

Units: mm, s; CAN identifiers in hex.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from dataclasses import replace
from pathlib import Path

from controller.canopen.apps.demo import PhotoEye, PickPlace
from controller.canopen.config import load_config
from controller.canopen.master.cycle import Controller
from controller.canopen.slave.world import SimWorld

BUS_YML = Path(__file__).resolve().parents[1] / "bus" / "demo.yml"


def run(items: int, out_dir: Path) -> dict:
    cfg = load_config(BUS_YML)
    demo = replace(cfg.demo, items=items)
    app = PickPlace(demo)
    bus_log = out_dir / "bus.log"
    with SimWorld(cfg, realtime=False, bus_log=bus_log) as world:
        ctl = Controller(cfg, world.transport, app)
        ctl.boot()                                    # NMT, identity, SDO, 402 enable
        ctl.start()                                   # SYNC producer, cyclic PDOs
        encoder = world.device(cfg.tracking.conveyor.node)
        app.eye = PhotoEye(encoder.profile, demo, world.clock.now_ns() * 1e-9)
        ctl.run()                                     # until every item is done
    frames = Counter()
    for line in bus_log.read_text().splitlines():     # "(t) vcan0 080#..." candump lines
        frames[line.split()[2].split("#")[0]] += 1
    return {"cfg": cfg, "controller": ctl, "items": app.items(), "frames": frames,
            "bus_log": bus_log}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--items", type=int, default=2, help="items the photo-eye sees")
    ap.add_argument("-o", "--out-dir", type=Path, default=None, help="where bus.log goes")
    args = ap.parse_args(argv)
    out = args.out_dir or Path(tempfile.mkdtemp(prefix="cantrack-demo-"))
    out.mkdir(parents=True, exist_ok=True)
    r = run(args.items, out)
    ctl, cfg = r["controller"], r["cfg"]
    T = cfg.period_s
    print(f"cycles: {ctl.k} of {T * 1e3:g} ms = {ctl.k * T:.3f} s of machine time")
    print("item  outcome  sync after [s]  max error [mm]")
    for it in r["items"]:
        sync = ((it.synced_cycle - it.engage_cycle) * T
                if it.synced_cycle is not None and it.engage_cycle is not None else None)
        print(f"{it.index:4d}  {it.outcome:<7}  {sync if sync is None else f'{sync:.3f}':>14}"
              f"  {it.max_error_mm:.4f}")
    placed = sum(1 for it in r["items"] if it.outcome == "placed")
    print(f"items placed: {placed} of {len(r['items'])}")
    print(f"bus load: {100 * ctl.bus_load.load:.1f} %")
    f = r["frames"]
    print(f"SYNC frames (080): {f['080']}")
    print("frames per identifier: " + ", ".join(f"{k} x{v}" for k, v in sorted(f.items())))
    print(f"bus log: {r['bus_log']}")
    return r


if __name__ == "__main__":
    main()
