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
keeps the limits as written) and at most :data:`MAX_FACTOR`.  :func:`fresh_factor` measures
again (the load of this moment, not of the session's start): the VM harness does so before
each boot and gives the guest that factor, by which the vcan tier stretches its real-time
windows (:mod:`controller.testing.stretch`).
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
#: the factor this process was given (``CANTRACK_SPEED_FACTOR`` at import: forced by the user
#: or passed on by the parent process) - :func:`fresh_factor` keeps it
_GIVEN = os.environ.get(ENV)


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


def fresh_factor(runs: int = 15) -> float:
    """The factor measured now (median of ``runs``), unless this process was given one in
    ``CANTRACK_SPEED_FACTOR`` (then that one); it becomes :func:`speed_factor`'s and the
    environment's."""
    global _factor
    if _GIVEN is not None:
        return speed_factor()
    _factor = measure(runs)
    os.environ[ENV] = f"{_factor:.3f}"
    return _factor


def window_factor(factor: float | None = None) -> float:
    """The factor for real-time *windows* (heartbeat time-outs, silences, a run's length after
    a kill) on a machine ``factor`` (default :func:`speed_factor`) times slower than the
    reference: ``factor x min(2, factor)``, at most :data:`MAX_FACTOR` - 1 when idle, twice
    the measured slowness from a factor of 2 on.  A limit only has to be long enough; a window
    must also hold the longest stall of a process in a busy VM: the measurement's spread on a
    busy machine is about +-30 %, and a guest near saturation stalls longer than in proportion
    (seen: at a measured 3.5 the simulated devices' heartbeats stalled 3.1 s, 3.8 x the idle
    window of 800 ms)."""
    f = speed_factor() if factor is None else max(1.0, factor)
    return min(MAX_FACTOR, f * min(2.0, f))


def scaled(seconds: float) -> float:
    """A time limit [s] stretched by the machine's present slowness."""
    return seconds * speed_factor()
