"""The simulated devices' CPU per SYNC (issue 12: "the simulated devices likewise cheaper").

The workload of ``benchmarks/cycle.py`` (examples/bus/demo.yml at 2 ms: the encoder and four
CiA 402 drives, the pick-and-place demo) in stepped time, one thread: the device rack's
three entry points -- ``handle`` (every frame the devices receive: SYNC, RPDOs, NMT, SDO,
heartbeats), ``next_timer_ns`` and ``on_timer`` -- are timed with ``time.perf_counter_ns``
from the controller's start (after boot) to the end of the run, and the sum is divided by
the number of SYNCs.  That is what the device thread of the real-time benchmark spends per
SYNC (the same calls, served by :class:`~controller.canopen.io.transport.DeviceThread`),
without the thread's waiting.

Also printed: a SHA-256 of every frame on the bus (time, COB-ID, data), to check that a
change of the devices leaves the bus traffic as it was.

``--baseline DIR`` (a checkout of an earlier cantrack, e.g. ``git worktree add DIR main``):
this script runs ``--pairs`` times with DIR's ``controller`` on the path, then with this
checkout's, alternately (back-to-back pairs on a shared machine), and prints the minimum of
each and the ratio.  The earlier checkout needs no copy of this script (only the public
API it calls: ``SimWorld``, ``Controller``, ``PickPlace``).  Both run the tracking core's
Python source (``CANTRACK_PURE=1``) unless ``--native``: a checkout made with
``git worktree add`` has no compiled core (the simulated devices, compiled with it since
issue 12.4, then run their source too).  For this checkout compiled against its own source,
run it once with ``CANTRACK_PURE=1`` and once without.

    python benchmarks/devices.py                        # this checkout, 20 s simulated
    python benchmarks/devices.py --baseline /tmp/before --pairs 3
    python benchmarks/devices.py --profile              # cProfile of the device side
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(seconds: float, profile: bool = False, tree: Path = HERE.parent) -> dict:
    """One stepped run of the cycle benchmark's 2 ms workload; the rack's time per SYNC.
    ``tree``: the checkout whose ``controller`` and ``benchmarks/cycle.py`` run."""
    sys.path[:0] = [str(tree), str(tree / "benchmarks")]
    import cycle  # (the workload: the checkout's benchmarks/cycle.py)
    from controller.canopen.apps.demo import PhotoEye, PickPlace
    from controller.canopen.master.cycle import Controller
    from controller.canopen.slave.world import SimWorld

    tmp = Path(tempfile.mkdtemp())
    cfg, demo = cycle._workload(2000, seconds, tmp)
    app = PickPlace(demo)
    spent = {"handle": 0, "next_timer_ns": 0, "on_timer": 0}
    calls = dict.fromkeys(spent, 0)
    with SimWorld(cfg, record=True) as world:
        ctl = Controller(cfg, world.transport, app, keep_trace=False, enforce_bus_load=False)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, demo,
                           world.clock.now_ns() * 1e-9)
        rack = world.rack
        clock = time.perf_counter_ns
        prof = None
        if profile:
            import cProfile
            prof = cProfile.Profile()
        # the time of each SYNC: from the SYNC frame's handling to the next SYNC's
        per_sync: list[int] = []
        acc = [0]
        sync_cob = 0x80

        def timed(name):
            inner = getattr(rack, name)
            sync = name == "handle"

            def call(*a):
                if sync and a[0].arbitration_id == sync_cob:
                    per_sync.append(acc[0])
                    acc[0] = 0
                t0 = clock()
                if prof is not None:
                    r = prof.runcall(inner, *a)
                else:
                    r = inner(*a)
                dt = clock() - t0
                spent[name] += dt
                acc[0] += dt
                calls[name] += 1
                return r
            return call

        # the rack's place in the stepped world taken by a participant that times each of
        # its entry points (not the rack's methods replaced on the instance: a compiled
        # DeviceRack has no __dict__)
        timed_rack = type("TimedRack", (), {"bus": rack.bus})()
        for name in spent:
            setattr(timed_rack, name, timed(name))
        endpoints = world.world.endpoints
        endpoints[next(i for i, ep in enumerate(endpoints) if ep is rack)] = timed_rack
        k0 = ctl.k
        ctl.run()
        syncs = ctl.k - k0
        frames = world.recorder.frames
    digest = hashlib.sha256()
    for t, cob, data in frames:
        digest.update(b"%d %x " % (t, cob) + data.hex().encode() + b"\n")
    out = {"syncs": syncs, "frames": len(frames), "bus_sha256": digest.hexdigest()[:16],
           "placed": app.placed, "missed": app.missed,
           "us_per_sync": {k: v / syncs / 1e3 for k, v in spent.items()},
           "calls_per_sync": {k: v / syncs for k, v in calls.items()}}
    out["us_per_sync"]["total"] = sum(spent.values()) / syncs / 1e3
    per = sorted(per_sync[1:])  # (the first: what came before the first SYNC)
    out["us_per_sync"]["p50"] = per[len(per) // 2] / 1e3
    if prof is not None:
        import pstats
        pstats.Stats(prof).sort_stats("tottime").print_stats(40)
    return out


def _run(tree: Path, seconds: float, native: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    if not native:
        env["CANTRACK_PURE"] = "1"
    r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--seconds",
                        str(seconds), "--json-out", str(tree)], env=env, cwd=str(tree),
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"run in {tree} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _line(label: str, r: dict) -> str:
    u = r["us_per_sync"]
    return (f"{label:<10} devices p50 {u['p50']:6.1f} mean {u['total']:6.1f} us/SYNC "
            f"(handle {u['handle']:.1f}, "
            f"next_timer_ns {u['next_timer_ns']:.1f}, on_timer {u['on_timer']:.1f}); "
            f"{r['syncs']} SYNCs, {r['frames']} frames, bus {r['bus_sha256']}, "
            f"placed {r['placed']}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0, help="simulated (default 20)")
    p.add_argument("--baseline", metavar="DIR", help="an earlier checkout to compare with")
    p.add_argument("--pairs", type=int, default=3, help="before/after pairs (default 3)")
    p.add_argument("--native", action="store_true",
                   help="with --baseline: the compiled tracking core where there is one")
    p.add_argument("--profile", action="store_true", help="cProfile of the device side")
    p.add_argument("--json-out", metavar="TREE", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.json_out:
        import controller
        out = measure(args.seconds, tree=Path(args.json_out))
        if Path(controller.__file__).resolve().parents[1] != Path(args.json_out).resolve():
            raise SystemExit(f"measured {controller.__file__}, not {args.json_out}")
        print(json.dumps(out))
        return 0
    if args.baseline is None:
        r = measure(args.seconds, args.profile)
        print(_line("this", r))
        return 0
    base, here = Path(args.baseline).resolve(), HERE.parent
    print(f"python {sys.version.split()[0]}, load average {os.getloadavg()[0]:.2f}, "
          f"{args.seconds:g} s simulated per run, {args.pairs} pairs")
    before, after = [], []
    for i in range(args.pairs):
        before.append(_run(base, args.seconds, args.native))
        print(_line(f"before {i + 1}", before[-1]), flush=True)
        after.append(_run(here, args.seconds, args.native))
        print(_line(f"after {i + 1}", after[-1]), flush=True)
    same = {r["bus_sha256"] for r in before} == {r["bus_sha256"] for r in after}
    for key, what in (("p50", "median per SYNC"), ("total", "mean per SYNC")):
        b = min(r["us_per_sync"][key] for r in before)
        a = min(r["us_per_sync"][key] for r in after)
        print(f"devices, {what}, min of {args.pairs}: before {b:.1f} us, after {a:.1f} us, "
              f"after/before {a / b:.2f}")
    print(f"bus traffic before/after: {'identical' if same else 'DIFFERENT'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
