"""A CPU wake-up latency request for real-time cycles (Linux PM QoS, ``/dev/cpu_dma_latency``).

Between two SYNCs the controller's thread sleeps.  An idle CPU is put by the kernel's cpuidle
governor into an idle state; the deeper the state, the longer the wake-up, and on a virtual
machine the idle vCPU halts and is given back to the host, whose other work evicts the
guest's caches.  The cycle's work after the wake-up then runs cold: on the 2-core VM this
project is measured on, a fixed piece of Python work cost 58 us when run back to back or
after a busy wait, 112 us after a 1.7 ms sleep and 141 us after a 5 ms sleep (the
controller's compute at 2 ms: 138 us p50 against 37 us for the same cycles stepped;
docs/hil.md "CPU wake-up latency").

The kernel's PM QoS interface (Documentation/power/pm_qos_interface.rst) lets a process
bound that latency for every CPU: it writes the bound, a 32-bit integer in microseconds, to
``/dev/cpu_dma_latency`` and keeps the file open; the request holds until the file is closed,
which the kernel does for a process that exits in any way (SIGKILL included), so no setting
outlives the run.  0 means the CPUs never enter a sleeping idle state (they poll: no wake-up
cost, at the price of power), which is what cyclictest requests by default.  The file is
root's (mode 0600) unless a udev rule gives it to a group.

Nothing here is per cycle: the request is made once before the cycle starts.  The
``canopen`` and ``python-can`` libraries have no such option; a Python program has no other
way to ask for it than this file.
"""

from __future__ import annotations

import argparse
import os
import struct
from pathlib import Path

#: the PM QoS request file of the CPU wake-up latency (misc device, Linux >= 2.6.25)
DEFAULT_PATH = Path("/dev/cpu_dma_latency")
#: the largest request the kernel takes (a signed 32-bit value; PM_QOS_DEFAULT_VALUE is
#: 2000 s, "no constraint")
MAX_LATENCY_US = 2**31 - 1


class CpuLatencyRequest:
    """Hold a CPU wake-up latency bound of ``latency_us`` [us] while open (a context manager).

    ``acquire()`` raises :class:`OSError` (with the file's name: ``FileNotFoundError`` where
    the kernel has no PM QoS device, ``PermissionError`` for a user who may not write it);
    ``effective_us`` is the bound the kernel applies after the request (the smallest of all
    processes' requests), ``None`` where it cannot be read back.
    """

    def __init__(self, latency_us: int, path: Path | str = DEFAULT_PATH) -> None:
        if isinstance(latency_us, bool) or not isinstance(latency_us, int):
            raise TypeError(f"CPU latency: an integer number of microseconds, not "
                            f"{latency_us!r}")
        if not 0 <= latency_us <= MAX_LATENCY_US:
            raise ValueError(f"CPU latency {latency_us} us: must be 0..{MAX_LATENCY_US} us")
        self.latency_us = latency_us
        self.path = Path(path)
        self.effective_us: int | None = None
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> CpuLatencyRequest:
        """Open the request file and write the bound (native byte order, as the kernel reads
        an ``s32``); the request holds until :meth:`release`.  Idempotent."""
        if self._fd is not None:
            return self
        fd = os.open(self.path, os.O_RDWR if os.access(self.path, os.R_OK) else os.O_WRONLY)
        try:
            os.write(fd, struct.pack("=i", self.latency_us))
        except OSError:
            os.close(fd)
            raise
        self._fd = fd
        self.effective_us = self._read_back(fd)
        return self

    def _read_back(self, fd: int) -> int | None:
        # reading the device gives the current target of the whole system (all requests);
        # a plain file (tests) reads back what was written
        try:
            data = os.pread(fd, 4, 0)
        except OSError:
            return None
        return struct.unpack("=i", data)[0] if len(data) == 4 else None

    def release(self) -> None:
        """Close the request file: the kernel drops the request."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def __enter__(self) -> CpuLatencyRequest:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __repr__(self) -> str:
        return (f"CpuLatencyRequest({self.latency_us} us, {self.path}, "
                f"{'held' if self.held else 'not held'})")


def request_cpu_latency(latency_us: int | None,
                        path: Path | str | None = None) -> tuple[CpuLatencyRequest | None,
                                                                 str | None]:
    """``--cpu-latency US`` of a real-time command: the request held (``None`` when not asked
    for) and a warning when it could not be made (the run goes on without it).  ``path``: by
    default :data:`DEFAULT_PATH` (read at the call)."""
    if latency_us is None:
        return None, None
    req = CpuLatencyRequest(latency_us, DEFAULT_PATH if path is None else path)
    try:
        req.acquire()
    except OSError as exc:
        why = ("needs root or write access to it" if isinstance(exc, PermissionError) else
               "no PM QoS device here" if isinstance(exc, FileNotFoundError) else
               exc.strerror or str(exc))
        return None, (f"--cpu-latency {latency_us}: {req.path}: {why}; the CPUs may sleep "
                      f"deeply between cycles (slower, colder cycles)")
    return req, None


def latency_us_arg(text: str) -> int:
    """``--cpu-latency``'s value (argparse type): whole microseconds, 0..2^31-1."""
    try:
        v = int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a whole number of microseconds") from None
    if not 0 <= v <= MAX_LATENCY_US:
        raise argparse.ArgumentTypeError(f"{text!r}: must be 0..{MAX_LATENCY_US} us")
    return v
