"""What a sleep costs the work after it: a fixed piece of Python work timed after sleeps.

The real-time cycle sleeps between SYNCs; on an idle CPU the kernel's cpuidle governor may
pick a deep idle state (on a virtual machine: HLT, the vCPU given back to the host) and the
work after the wake-up runs with cold caches.  This prints the thread CPU time and the wall
time (median of ``--reps``) of the same work (~60 us of dict and float operations) run back
to back, after a busy wait and after sleeps of 0.1-5 ms; then the same with the CPU wake-up
latency request that ``cantrack run --cpu-latency`` holds (Linux PM QoS,
``controller/canopen/io/cpu_latency.py``; needs root), unless ``--no-request``.  The cpuidle
driver and governor are printed where sysfs has them.  docs/hil.md "CPU wake-up latency".

    python benchmarks/wakeup.py [--reps 2000] [--latency-us 0]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller.canopen.io.cpu_latency import latency_us_arg, request_cpu_latency

#: (label, how the gap is spent, gap [ns])
GAPS = (("back to back", "none", 0), ("busy wait 1.7 ms", "spin", 1_700_000),
        ("sleep 0.1 ms", "sleep", 100_000), ("sleep 0.5 ms", "sleep", 500_000),
        ("sleep 1.7 ms", "sleep", 1_700_000), ("sleep 5 ms", "sleep", 5_000_000))


def work(n: int = 600) -> float:
    """The fixed work: dict stores and loads, float arithmetic (like a cycle's Python)."""
    d: dict[int, float] = {}
    s = 0.0
    for i in range(n):
        d[i % 37] = i * 1.5
        s += d[i % 37] ** 0.5
    return s


def measure(mode: str, gap_ns: int, reps: int) -> tuple[float, float]:
    """Median thread CPU and wall time [us] of :func:`work` after each gap."""
    cpu, wall = [], []
    work()  # (warm: the first call is not timed)
    for _ in range(reps):
        if mode == "sleep":
            time.sleep(gap_ns / 1e9)
        elif mode == "spin":
            end = time.perf_counter_ns() + gap_ns
            while time.perf_counter_ns() < end:
                pass
        c0, w0 = time.thread_time_ns(), time.perf_counter_ns()
        work()
        cpu.append((time.thread_time_ns() - c0) / 1e3)
        wall.append((time.perf_counter_ns() - w0) / 1e3)
    return statistics.median(cpu), statistics.median(wall)


def _cpuidle() -> str:
    base = Path("/sys/devices/system/cpu/cpuidle")
    try:
        return (f"cpuidle driver {(base / 'current_driver').read_text().strip()}, governor "
                f"{(base / 'current_governor_ro').read_text().strip()}")
    except OSError:
        return "cpuidle: not in sysfs"


def table(reps: int) -> dict[str, tuple[float, float]]:
    rows = {}
    for label, mode, gap in GAPS:
        rows[label] = measure(mode, gap, reps)
        c, w = rows[label]
        print(f"  {label:<18} cpu {c:7.1f} us   wall {w:7.1f} us")
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--reps", type=int, default=2000, help="timed runs per gap (default 2000)")
    p.add_argument("--latency-us", type=latency_us_arg, default=0,
                   help="the request of the second table [us] (default 0)")
    p.add_argument("--no-request", action="store_true", help="only the first table")
    args = p.parse_args(argv)
    print(f"python {sys.version.split()[0]}; {_cpuidle()}")
    print("without a CPU latency request:")
    plain = table(args.reps)
    if args.no_request:
        return 0
    req, warning = request_cpu_latency(args.latency_us)
    if req is None:
        print(f"with the request: not made ({warning})")
        return 0
    try:
        print(f"with a CPU latency request of {req.latency_us} us (effective "
              f"{req.effective_us} us):")
        held = table(args.reps)
    finally:
        req.release()
    key = "sleep 1.7 ms"
    print(f"work after a 1.7 ms sleep / back to back: {plain[key][0] / plain['back to back'][0]:.2f}"
          f" without, {held[key][0] / held['back to back'][0]:.2f} with the request")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
