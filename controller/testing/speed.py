"""How fast this machine is right now, for the test tiers' waits and windows.

A test that waits for a readiness file, a process or a VM must not give up because other
jobs share the cores (CI runners, a developer machine running three builds).  The waits are
cues with a time limit; :func:`scaled` stretches each limit by :func:`speed_factor`, measured,
not guessed: the wall time of a fixed piece of Python work (5 ms, run 9 times, the median)
against the same work on an idle reference machine (:data:`REFERENCE_S`, measured here on one
core of the project's 2-core machine, nothing else running).  Busy loops on every core make
the median slower by the share of the CPU this process gets, so the factor follows the load.

The factor is measured once per process and passed on to sub-processes (and the VM's guest)
in ``CANTRACK_SPEED_FACTOR``; set it to force a value.  It is at least 1 (a fast machine
keeps the limits as written) and at most :data:`MAX_FACTOR`.
"""

from __future__ import annotations

import json
import os
import time

#: the work's median wall time on the idle reference machine [s]
REFERENCE_S = 0.0052
#: the largest factor (a limit stretched further hides a hang)
MAX_FACTOR = 20.0
ENV = "CANTRACK_SPEED_FACTOR"

_factor: float | None = None


def _work() -> float:
    """A fixed piece of interpreter work like the harness's own (dicts, floats, JSON)."""
    t0 = time.perf_counter()
    acc = 0.0
    d: dict[int, float] = {}
    for i in range(60_000):
        acc += (i * 0.5) ** 0.5
        d[i & 255] = acc
    json.dumps(d)
    return time.perf_counter() - t0


def measure(runs: int = 9) -> float:
    """The factor now: median work time / :data:`REFERENCE_S`, clamped to [1, MAX_FACTOR]."""
    times = sorted(_work() for _ in range(runs))
    return min(MAX_FACTOR, max(1.0, times[len(times) // 2] / REFERENCE_S))


def speed_factor() -> float:
    """The factor of this process (``CANTRACK_SPEED_FACTOR`` if set, else measured once)."""
    global _factor
    if _factor is None:
        env = os.environ.get(ENV)
        try:
            _factor = min(MAX_FACTOR, max(1.0, float(env))) if env else measure()
        except ValueError:
            _factor = measure()
        os.environ[ENV] = f"{_factor:.3f}"  # (sub-processes inherit it)
    return _factor


def scaled(seconds: float) -> float:
    """A time limit [s] stretched by the machine's present slowness."""
    return seconds * speed_factor()
