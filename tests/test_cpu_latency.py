"""The CPU wake-up latency request (controller/canopen/io/cpu_latency.py; ``cantrack run
--cpu-latency``, ``benchmarks/cycle.py --cpu-latency``): what it writes, that it holds while
open and is dropped on every exit, and the clear refusals."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import pytest

from controller.canopen.io import cpu_latency
from controller.canopen.io.cpu_latency import (
    DEFAULT_PATH,
    MAX_LATENCY_US,
    CpuLatencyRequest,
    request_cpu_latency,
)

ROOT = Path(__file__).resolve().parents[1]


def _open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


def test_the_request_writes_a_native_s32_and_holds_its_file_until_released(tmp_path):
    path = tmp_path / "cpu_dma_latency"
    path.write_bytes(b"")
    before = _open_fds()
    req = CpuLatencyRequest(125, path)
    assert not req.held and req.effective_us is None
    with req as held:
        assert held is req and req.held
        assert path.read_bytes() == struct.pack("=i", 125)
        assert req.effective_us == 125            # (a plain file reads back what was written)
        assert len(_open_fds() - before) == 1     # one file open for the request's life
        assert req.acquire() is req and len(_open_fds() - before) == 1  # idempotent
    assert not req.held and _open_fds() == before
    req.release()                                 # (again: nothing to do)
    assert "not held" in repr(req) and "125 us" in repr(req)


@pytest.mark.parametrize("value, error, words", [
    (-1, ValueError, "-1 us: must be 0..2147483647"),
    (MAX_LATENCY_US + 1, ValueError, "must be 0.."),
    (True, TypeError, "an integer number of microseconds"),
    (0.5, TypeError, "not 0.5"),
])
def test_a_bad_bound_is_refused_naming_it(tmp_path, value, error, words):
    with pytest.raises(error, match=words.replace(".", r"\.")):
        CpuLatencyRequest(value, tmp_path / "x")


def test_a_request_that_cannot_be_made_is_a_warning_naming_the_file_and_why(tmp_path,
                                                                         monkeypatch):
    assert request_cpu_latency(None) == (None, None)   # not asked for: nothing opened
    req, warning = request_cpu_latency(0, tmp_path / "absent")
    assert req is None
    assert warning == (f"--cpu-latency 0: {tmp_path / 'absent'}: no PM QoS device here; the "
                       f"CPUs may sleep deeply between cycles (slower, colder cycles)")

    def refuse(path, flags, *a):
        raise PermissionError(13, "Permission denied", str(path))
    monkeypatch.setattr(cpu_latency.os, "open", refuse)
    req, warning = request_cpu_latency(7, tmp_path / "dev")
    assert req is None and warning is not None
    assert warning.startswith(f"--cpu-latency 7: {tmp_path / 'dev'}: needs root or write "
                              "access to it;")


def test_a_failed_write_closes_the_file(tmp_path, monkeypatch):
    path = tmp_path / "dev"
    path.write_bytes(b"")
    before = _open_fds()

    def no_write(fd, data):
        raise OSError(22, "Invalid argument")
    monkeypatch.setattr(cpu_latency.os, "write", no_write)
    req, warning = request_cpu_latency(3, path)
    assert req is None and warning is not None and warning.endswith(
        "Invalid argument; the CPUs may sleep deeply between cycles (slower, colder cycles)")
    assert _open_fds() == before


def test_the_kernel_takes_the_request_while_it_is_held():
    """On Linux with PM QoS, as root: while held, the system's CPU latency target (read from
    the device itself) is at most the request."""
    if not DEFAULT_PATH.exists() or not os.access(DEFAULT_PATH, os.W_OK):
        pytest.skip(f"{DEFAULT_PATH}: absent or not writable here (needs root)")
    with CpuLatencyRequest(123) as req:
        with open(DEFAULT_PATH, "rb", buffering=0) as f:
            target = struct.unpack("=i", f.read(4))[0]
        assert target <= 123 and req.effective_us is not None and req.effective_us <= 123


@pytest.mark.parametrize("text, words", [("-1", "'-1': must be 0..2147483647 us"),
                                         ("x", "'x' is not a whole number of microseconds"),
                                         ("1.5", "'1.5' is not a whole number")])
def test_cantrack_run_refuses_a_bad_cpu_latency(capsys, text, words):
    from controller.cli import run as cmd_run
    with pytest.raises(SystemExit) as info:
        cmd_run.main([str(ROOT / "examples" / "bus" / "demo.yml"), "-i", "virtual", "-c",
                      "nobody", "--cpu-latency", text])
    assert info.value.code == 2
    assert f"--cpu-latency: {words}" in capsys.readouterr().err


def test_cantrack_run_holds_the_request_and_drops_it_when_the_run_ends(tmp_path,
                                                                      monkeypatch):
    """A run whose boot fails (nothing on its channel: no boot-up within 2 s) made the request
    before the boot and dropped it on that exit, too."""
    from controller.cli import run as cmd_run
    from controller.errors import CanError

    dev = tmp_path / "cpu_dma_latency"
    dev.write_bytes(b"")
    monkeypatch.setattr(cpu_latency, "DEFAULT_PATH", dev)
    made: list[CpuLatencyRequest | None] = []

    def record(us, path=None):
        req, warning = request_cpu_latency(us, path)
        made.append(req)
        return req, warning
    monkeypatch.setattr(cmd_run, "request_cpu_latency", record)
    before = _open_fds()
    with pytest.raises(CanError, match="no boot-up message"):
        cmd_run.main([str(ROOT / "examples" / "bus" / "demo.yml"), "-i", "virtual", "-c",
                      f"qos-{os.getpid()}", "-q", "--cpu-latency", "0"])
    assert len(made) == 1 and made[0] is not None and made[0].latency_us == 0
    assert dev.read_bytes() == struct.pack("=i", 0)
    assert not made[0].held and _open_fds() == before
