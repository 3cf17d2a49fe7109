"""End-to-end checks of a ``cantrack run``: its bus capture and its report.

Shared by the ``vcan`` controller tier (``tests/test_vcan_controller.py``: ``run`` against
``sim-devices`` on ``vcan0``) and the ``hil`` tier (``tests/test_hil.py``: ``run`` against a
rig).  Each ``*_problems`` function returns a list of readable problems (empty: all good), so a
test asserts ``not problems`` with the list as its message, and a rig script can print them.

- :func:`wait_file`: wait for a ``--ready-file`` while watching the processes that write it.
- :func:`cantrack_argv`: the ``cantrack`` command of this Python (``python -m controller.cli``).
- :func:`sync_problems`: SYNC count, counter sequence and period against the configuration.
- :func:`boot_problems`: the boot on the bus (NMT reset and start, boot-ups, identity SDOs, the
  controller's heartbeat before the first SYNC).
- :func:`running_states` / :data:`TRACK_CYCLE`: the tracker states of the report's RUNNING
  phase; :func:`pdo_cycles`: the PDOs after each SYNC, restricted to some COB-IDs.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from .capture import FrameClass, Kind, pdo_order_per_sync, sync_period_stats

#: the tracker states of one engage/disengage: OFF, SYNCING, SYNCED, DESYNCING, OFF
TRACK_CYCLE = ["OFF", "SYNCING", "SYNCED", "DESYNCING", "OFF"]

#: NMT command specifiers (CiA 301)
NMT_START, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x81, 0x82


def cantrack_argv() -> list[str]:
    """``[python, -m, controller.cli]``: the ``cantrack`` CLI of the running interpreter."""
    return [sys.executable, "-m", "controller.cli"]


def wait_file(path: Path, procs: Iterable[subprocess.Popen], timeout_s: float,
              running: Callable[[], bool] | None = None) -> None:
    """Wait until ``path`` exists; raise RuntimeError when one of ``procs`` exits first (or
    ``running()``, for a writer in a thread, turns false) or after ``timeout_s``."""
    from .speed import scaled
    procs = list(procs)
    timeout_s = scaled(timeout_s)  # (the cue is the file; the limit follows the load)
    t_end = time.monotonic() + timeout_s
    while not path.is_file():
        for p in procs:
            if p.poll() is not None:
                raise RuntimeError(f"{p.args!r} exited with {p.returncode} before {path.name}")
        if running is not None and not running() and not path.is_file():
            raise RuntimeError(f"the writer of {path.name} ended before writing it")
        if time.monotonic() > t_end:
            raise RuntimeError(f"no {path.name} within {timeout_s} s")
        time.sleep(0.05)


def of_kind(frames: Iterable[FrameClass], kind: Kind) -> list[FrameClass]:
    return [f for f in frames if f.kind is kind]


def sync_problems(frames: Sequence[FrameClass], *, period_s: float, overflow: int | None,
                  cycles: int | None = None, median_tol: float = 0.10,
                  mean_tol: float = 0.25) -> list[str]:
    """The SYNC frames against the configuration: the count equals the report's ``cycles``
    (when given), the counter starts at 1 and runs 1..``overflow`` without a gap (when the
    configuration has a counter), and the period is ``period_s``: the median within
    ``median_tol``, the mean within ``mean_tol`` (relative)."""
    stats = sync_period_stats(frames, overflow=overflow or None)
    out = []
    if stats.count < 2:
        return [f"{stats.count} SYNC in the capture: {stats.describe()}"]
    if overflow:
        if stats.counters[0] != 1 or stats.counter_gaps:
            out.append(f"SYNC counter does not run 1..{overflow} from 1: {stats.describe()}")
    elif any(c is not None for c in stats.counters):
        out.append(f"SYNC with a counter, the configuration has none: {stats.describe()}")
    if cycles is not None and stats.count != cycles:
        out.append(f"{stats.count} SYNC on the bus, the report has {cycles} cycles: "
                   f"{stats.describe()}")
    # two SYNC or more (checked above): the period figures exist
    assert stats.period_median_s is not None and stats.period_mean_s is not None
    if abs(stats.period_median_s - period_s) > median_tol * period_s:
        out.append(f"SYNC period median off {period_s * 1e3:g} ms by more than "
                   f"{median_tol:.0%}: {stats.describe()}")
    if abs(stats.period_mean_s - period_s) > mean_tol * period_s:
        out.append(f"SYNC period mean off {period_s * 1e3:g} ms by more than "
                   f"{mean_tol:.0%}: {stats.describe()}")
    return out


def boot_problems(frames: Sequence[FrameClass], slaves: dict[str, int], master_id: int,
                  master_heartbeat: bool = True) -> list[str]:
    """The boot on the bus, for the slaves ``{name: node-ID}`` the controller boots:

    - an NMT reset (node or communication, to the node or to all) before an NMT start of each
      slave (to it or to all);
    - a boot-up (heartbeat state 0) of each slave after its reset;
    - SDO reads of 1000h, 1018h sub 1 and sub 2 (identity) to each slave;
    - with ``master_heartbeat``: the controller's boot-up and its heartbeat (05h) before the
      first SYNC.
    """
    out = []
    nmt = of_kind(frames, Kind.NMT)
    hb = of_kind(frames, Kind.HEARTBEAT)
    sdo = of_kind(frames, Kind.SDO)
    syncs = of_kind(frames, Kind.SYNC)
    first_sync = syncs[0].time_s if syncs else float("inf")
    for name, node in slaves.items():
        who = f"node {node} ({name})"
        resets = [f for f in nmt if f.nmt_command in (NMT_RESET_NODE, NMT_RESET_COMM)
                  and f.nmt_target in (node, 0)]
        starts = [f for f in nmt if f.nmt_command == NMT_START and f.nmt_target in (node, 0)]
        if not resets:
            out.append(f"{who}: no NMT reset")
        if not starts:
            out.append(f"{who}: no NMT start")
        if resets and starts and starts[-1].time_s < resets[0].time_s:
            out.append(f"{who}: NMT start before the reset")
        t_reset = resets[0].time_s if resets else 0.0
        if not [f for f in hb if f.node_id == node and f.nmt_state == 0
                and f.time_s >= t_reset]:
            out.append(f"{who}: no boot-up after the NMT reset")
        read = {(f.sdo_index, f.sdo_subindex) for f in sdo
                if f.node_id == node and f.direction == "rx"}
        missing = {(0x1000, 0), (0x1018, 1), (0x1018, 2)} - read
        if missing:
            out.append(f"{who}: no SDO request for " + ", ".join(
                f"{i:04X}h:{s:02X}" for i, s in sorted(missing)))
    if master_heartbeat:
        master = [f for f in hb if f.can_id == 0x700 + master_id]
        if not master or master[0].nmt_state != 0:
            out.append(f"the controller (node {master_id}): no boot-up first")
        if not [f for f in master if f.time_s < first_sync and f.nmt_state == 5]:
            out.append(f"the controller (node {master_id}): no heartbeat before the first "
                       "SYNC")
    return out


def running_states(report: dict) -> list[str]:
    """The tracker states of the report's RUNNING phase, in order."""
    return [c["state"] for c in report["state_changes"] if c["phase"] == "running"]


def pdo_cycles(frames: Sequence[FrameClass], cob_ids: Iterable[int]) -> list[tuple[int, ...]]:
    """:func:`~controller.testing.capture.pdo_order_per_sync` restricted to ``cob_ids``."""
    keep = set(cob_ids)
    return [tuple(c for c in cyc if c in keep) for cyc in pdo_order_per_sync(frames)]
