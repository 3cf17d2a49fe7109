"""Capture a SocketCAN bus with can-utils' ``candump -L`` (in the VM, natively or on a rig).

:class:`CandumpCapture` starts ``candump -L -d -r <rcvbuf> <channel>`` with its output in a
candump log file, waits until the kernel lists candump's receiver on the interface (so no frame
sent afterwards is missed), and on :meth:`~CandumpCapture.stop` terminates it (SIGTERM, which
candump handles by flushing and exiting), removes the ``DROPCOUNT`` lines that ``-d`` adds and
reports how many frames the capture socket dropped.  The log is python-can readable
(``can.LogReader``) and :func:`controller.testing.capture.classify_capture` decodes it.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path
from typing import BinaryIO

from ..errors import CantrackError

CAN_UTILS_HINT = "install can-utils (apt-get install can-utils)"
_PROC_CAN = Path("/proc/net/can")
_DROP_RE = re.compile(r"DROPCOUNT: dropped (\d+) CAN frame")


class CandumpError(CantrackError):
    """candump is missing, did not start, or did not stop."""


@dataclasses.dataclass(frozen=True)
class CaptureInfo:
    """A finished capture: the candump log, its number of frames, frames the socket dropped."""

    path: Path
    frames: int
    dropped: int
    returncode: int | None
    stderr: str


def _receivers(channel: str) -> int:
    """Number of CAN receivers the kernel lists for ``channel`` (/proc/net/can/rcvlist_*)."""
    n = 0
    for f in _PROC_CAN.glob("rcvlist_*"):
        try:
            for line in f.read_text().splitlines():
                parts = line.split()
                if parts and parts[0] == channel and len(parts) >= 6:
                    n += 1
        except OSError:
            continue
    return n


class CandumpCapture:
    """``with CandumpCapture("vcan0", "bus.log") as cap: ...``; then ``cap.info``.

    ``rcvbuf_bytes``: candump's ``-r`` (socket receive buffer; root may exceed rmem_max), large
    so that a slow (emulated) capture process does not drop frames.
    """

    def __init__(self, channel: str, path: str | Path, *, rcvbuf_bytes: int = 8 << 20,
                 candump: str | None = None) -> None:
        self.channel = channel
        self.path = Path(path)
        self.rcvbuf_bytes = rcvbuf_bytes
        self.candump = candump or shutil.which("candump")
        self.proc: subprocess.Popen | None = None
        self.info: CaptureInfo | None = None
        self._out: BinaryIO | None = None

    def start(self, timeout_s: float = 20.0) -> CandumpCapture:
        if self.candump is None:
            raise CandumpError("candump not found on PATH: " + CAN_UTILS_HINT)
        before = _receivers(self.channel) if _PROC_CAN.is_dir() else None
        self._out = open(self.path, "wb")  # noqa: SIM115 -- open while candump runs
        self.proc = subprocess.Popen(
            [self.candump, "-L", "-d", "-r", str(self.rcvbuf_bytes), self.channel],
            stdout=self._out, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
                self._out.close()
                raise CandumpError(f"candump on {self.channel} exited with "
                                   f"{self.proc.returncode} at start: {err.strip()}")
            if before is None:
                time.sleep(0.5)   # no /proc/net/can: give candump time to bind
                break
            if _receivers(self.channel) > before:
                break
            if time.monotonic() > deadline:
                self.proc.kill()
                self.proc.wait()
                self._out.close()
                raise CandumpError(f"candump on {self.channel}: no receiver listed in "
                                   f"{_PROC_CAN}/rcvlist_* after {timeout_s:.0f} s")
            time.sleep(0.02)
        return self

    def stop(self, timeout_s: float = 20.0) -> CaptureInfo:
        """Terminate candump, clean the log (DROPCOUNT lines), return :class:`CaptureInfo`."""
        if self.info is not None:
            return self.info
        if self.proc is None:
            raise CandumpError("candump was not started")
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
        if self._out is not None:
            self._out.close()
        text = self.path.read_text(errors="replace")
        dropped, frames, keep = 0, 0, []
        for line in text.splitlines():
            m = _DROP_RE.search(line)
            if m:
                dropped += int(m.group(1))
                continue
            if line.strip():
                keep.append(line)
                frames += 1
        tmp = self.path.with_name(self.path.name + f".tmp{os.getpid()}")
        tmp.write_text("\n".join(keep) + ("\n" if keep else ""))
        os.replace(tmp, self.path)
        self.info = CaptureInfo(self.path, frames, dropped, self.proc.returncode, err)
        return self.info

    def __enter__(self) -> CandumpCapture:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
