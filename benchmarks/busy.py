"""Run a command while busy loops load the machine (issue 12 #6: the suite under load).

Starts ``--loops`` processes (default 3) that each spin a CPU at normal priority, runs the
command, then stops the loops (by their process ids) however the command ends: exit,
Ctrl-C, SIGTERM.  Prints the machine's measured slowness before the command
(:func:`controller.testing.speed.fresh_factor`: 1 idle, ~2-4 with three loops on 2 cores;
the vcan tier stretches its windows by it) and the command's wall time; exits with the
command's exit code.

    python benchmarks/busy.py -- python -m pytest -q -m "not vcan"
    python benchmarks/busy.py --loops 3 -- bash .ci/run
    python benchmarks/busy.py -- python -m pytest -q -m vcan tests/test_vcan_tier.py

The command gets the environment as it is (``PYTHONPATH`` etc.; not the measured factor:
the tiers measure for themselves); it is not run in a shell (quote a pipeline as
``bash -c '...'``).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller.testing.speed import fresh_factor  # noqa: E402

#: one busy loop: pure interpreter work, no I/O, no memory growth
LOOP = "while True:\n    pass\n"


def start_loops(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", LOOP], stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for _ in range(n)]


def stop_loops(loops: list[subprocess.Popen]) -> None:
    """Stop each loop by its own process id (SIGTERM, then SIGKILL after 2 s)."""
    for p in loops:
        if p.poll() is None:
            p.terminate()
    for p in loops:
        try:
            p.wait(2.0)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--loops", type=int, default=3, help="busy loops (default 3)")
    p.add_argument("command", nargs=argparse.REMAINDER,
                   help="the command to run under load (after --)")
    args = p.parse_args(argv)
    cmd = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not cmd:
        p.error("no command given (busy.py [--loops N] -- COMMAND ...)")
    if args.loops < 0:
        p.error(f"--loops (={args.loops}) must be >= 0")
    loops = start_loops(args.loops)
    child: subprocess.Popen | None = None

    def _term(signum, frame):  # SIGTERM: end the command, then the loops (finally)
        if child is not None and child.poll() is None:
            child.terminate()
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    # the command's environment as given: fresh_factor() puts its figure into ours, and a
    # factor passed on would freeze the tiers' own measurements (the VM harness measures
    # again before each boot)
    env = dict(os.environ)
    t0 = time.perf_counter()
    try:
        time.sleep(0.5)  # the loops are running before the measurement
        f = fresh_factor()
        print(f"busy.py: {args.loops} busy loops (pids {[q.pid for q in loops]}) on "
              f"{os.cpu_count()} CPUs; measured slowness {f:.1f} (1 = idle); running: "
              f"{' '.join(cmd)}", flush=True)
        try:
            child = subprocess.Popen(cmd, env=env)
        except OSError as exc:
            print(f"busy.py: cannot run {cmd[0]!r}: {exc}", file=sys.stderr)
            return 127
        rc = child.wait()
    except KeyboardInterrupt:
        if child is not None and child.poll() is None:
            child.terminate()
            try:
                child.wait(10.0)
            except subprocess.TimeoutExpired:
                child.kill()
        rc = 130
    finally:
        stop_loops(loops)
        signal.signal(signal.SIGTERM, old)
    print(f"busy.py: exit {rc} after {time.perf_counter() - t0:.0f} s under "
          f"{args.loops} busy loops (stopped)", flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
