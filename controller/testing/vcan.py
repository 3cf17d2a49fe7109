"""Run a command on a real SocketCAN ``vcan0``: natively when the kernel has vcan, else in the VM.

:func:`run_with_vcan` is the one entry point of the ``vcan`` test tier.  ``mode``:

- ``"native"``: the host kernel has AF_CAN (and CAN_BCM) and the interface exists and is up,
  or can be created because we are root (``modprobe vcan``, ``ip link add dev vcan0 type vcan``,
  ``ip link set up vcan0``).  The command runs as a normal subprocess.
- ``"vm"``: :func:`controller.testing.vm.run_in_vm` (qemu, ~4 s boot).
- ``"auto"`` (default; ``$CANTRACK_VCAN_MODE`` overrides): native first, then the VM.

Both return the same :class:`~controller.testing.vm.VmResult` and give the command
``$CANTRACK_SCRATCH`` (a writable directory, same path for host and command),
``$CANTRACK_CAN_CHANNEL`` and ``$CANTRACK_VCAN_MODE``.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from .vm import DEFAULT_CHANNEL, VmError, VmResult, limit_factor, run_in_vm, vm_available

MODES = ("auto", "native", "vm")
_IFF_UP = 0x1
_ARPHRD_CAN = 280


def af_can_available() -> tuple[bool, str]:
    """(True, "") when this kernel opens AF_CAN raw and BCM sockets, else (False, why)."""
    if not hasattr(socket, "AF_CAN"):
        return False, "this Python has no socket.AF_CAN (not Linux?)"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as exc:
        return False, f"the host kernel has no SocketCAN (AF_CAN raw socket: {exc.strerror})"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_DGRAM, socket.CAN_BCM).close()
    except OSError as exc:
        return False, (f"the host kernel has no CAN broadcast manager (CAN_BCM socket: "
                       f"{exc.strerror}; try: modprobe can-bcm)")
    return True, ""


def _iface(channel: str) -> tuple[bool, bool, bool]:
    """(exists, is a CAN interface, is up) from /sys/class/net."""
    base = Path("/sys/class/net") / channel
    if not base.exists():
        return False, False, False
    try:
        is_can = int((base / "type").read_text().strip()) == _ARPHRD_CAN
        up = bool(int((base / "flags").read_text().strip(), 16) & _IFF_UP)
    except (OSError, ValueError):
        return True, False, False
    return True, is_can, up


def _run(cmd: list[str]) -> tuple[bool, str]:
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"{' '.join(cmd)}: {exc}"
    return p.returncode == 0, (p.stderr or p.stdout).strip()


def ensure_native_vcan(channel: str = DEFAULT_CHANNEL, *, create: bool = True) -> tuple[bool, str]:
    """(True, description) when ``channel`` is a usable SocketCAN interface on this host.

    Creates a vcan interface (or brings it up) when it is missing (down) and we are root and
    ``create``; otherwise (False, why and the commands to run).
    """
    ok, why = af_can_available()
    if not ok:
        return False, why
    exists, is_can, up = _iface(channel)
    if exists and not is_can:
        return False, f"{channel} exists but is not a CAN interface"
    if exists and up:
        return True, f"native: existing {channel}"
    cmds = ([] if exists else [["ip", "link", "add", "dev", channel, "type", "vcan"]]) + [
        ["ip", "link", "set", "up", channel]]
    human = " && ".join("sudo " + " ".join(c) for c in cmds)
    if not create or os.geteuid() != 0:
        return False, f"{channel} is {'down' if exists else 'missing'}: run {human}"
    if shutil.which("ip") is None:
        return False, f"{channel} is missing and there is no 'ip' command: apt-get install iproute2"
    if not exists and shutil.which("modprobe"):
        _run(["modprobe", "vcan"])
    for c in cmds:
        ok, msg = _run(c)
        if not ok:
            return False, f"{' '.join(c)} failed: {msg}"
    exists, is_can, up = _iface(channel)
    if not (exists and is_can and up):
        return False, f"{channel} still not up after {human}"
    return True, f"native: created {channel}"


def native_vcan_available(channel: str = DEFAULT_CHANNEL) -> tuple[bool, str]:
    """Like :func:`ensure_native_vcan` but never changes anything (root could create it)."""
    ok, why = af_can_available()
    if not ok:
        return False, why
    exists, is_can, up = _iface(channel)
    if exists and is_can and up:
        return True, f"native: existing {channel}"
    if os.geteuid() == 0 and shutil.which("ip"):
        return True, f"native: {channel} will be created (root)"
    return False, f"{channel} is missing or down and we are not root"


def resolve_mode(mode: str | None = None) -> str:
    """``mode`` or ``$CANTRACK_VCAN_MODE`` or "auto"; checked against :data:`MODES`."""
    m = (mode or os.environ.get("CANTRACK_VCAN_MODE") or "auto").strip().lower()
    if m not in MODES:
        raise VmError(f"vcan mode {m!r}: allowed {', '.join(MODES)}")
    return m


def vcan_available(mode: str | None = None, channel: str = DEFAULT_CHANNEL) -> tuple[bool, str]:
    """(True, "native: ..." / "VM: ...") when :func:`run_with_vcan` can run, else (False, what
    is missing in each way and what to install)."""
    m = resolve_mode(mode)
    reasons = []
    if m in ("auto", "native"):
        ok, why = native_vcan_available(channel)
        if ok:
            return True, why
        reasons.append("native vcan: " + why)
    if m in ("auto", "vm"):
        ok, why = vm_available()
        if ok:
            return True, why
        reasons.append(why)
    return False, "; ".join(reasons)


def pick_mode(mode: str | None = None, channel: str = DEFAULT_CHANNEL) -> str:
    """"native" or "vm" for ``mode`` (auto: native first); :class:`VmError` if neither."""
    m = resolve_mode(mode)
    if m in ("auto", "native"):
        ok, why = native_vcan_available(channel)
        if ok:
            return "native"
        if m == "native":
            raise VmError("native vcan not possible: " + why)
    ok, why = vm_available()
    if ok:
        return "vm"
    _, all_why = vcan_available(m, channel)
    raise VmError("no real SocketCAN here: " + all_why)


def run_native(argv: Sequence[str], timeout_s: float = 120.0,
               env: Mapping[str, str] | None = None, *, cwd: str | Path | None = None,
               scratch_dir: str | Path | None = None,
               channel: str = DEFAULT_CHANNEL) -> VmResult:
    """Run ``argv`` on the host's own ``channel`` (created when missing and root)."""
    ok, why = ensure_native_vcan(channel)
    if not ok:
        raise VmError("native vcan not possible: " + why)
    factor = limit_factor(env)  # (a limit: stretched by the machine's slowness measured now)
    timeout_s *= factor
    scratch = Path(scratch_dir) if scratch_dir is not None else Path(
        tempfile.mkdtemp(prefix="cantrack-vcan-"))
    scratch.mkdir(parents=True, exist_ok=True)
    scratch = scratch.resolve()
    full_env = dict(os.environ)
    full_env.update({"PYTHONUNBUFFERED": "1"})
    if env:
        full_env.update(env)
    full_env.update({"CANTRACK_SCRATCH": str(scratch), "CANTRACK_CAN_CHANNEL": channel,
                     "CANTRACK_VCAN_MODE": "native", "CANTRACK_SPEED_FACTOR": f"{factor:.3f}"})
    m0 = time.monotonic()
    timed_out = False
    with subprocess.Popen(list(map(str, argv)), cwd=cwd, env=full_env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                          start_new_session=True) as proc:
        try:
            out, err = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            timed_out = True
            proc.terminate()
            try:
                out, err = proc.communicate(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
    wall = time.monotonic() - m0
    rc = proc.returncode
    if rc < 0:   # killed by a signal: report it like a shell (and the VM) does, 128 + signal
        rc = 128 - rc
    return VmResult(returncode=rc, stdout=out, stderr=err, scratch_dir=scratch,
                    mode="native", boot_s=None, command_s=wall, wall_s=wall, console="",
                    channel=channel, timed_out=timed_out, speed_factor=factor)


def run_with_vcan(argv: Sequence[str], timeout_s: float = 120.0,
                  env: Mapping[str, str] | None = None, *, mode: str | None = None,
                  cwd: str | Path | None = None, scratch_dir: str | Path | None = None,
                  channel: str = DEFAULT_CHANNEL) -> VmResult:
    """Run ``argv`` with a real SocketCAN ``channel``: natively if possible, else in the VM.

    Same arguments and result as :func:`controller.testing.vm.run_in_vm`; ``mode`` is "auto"
    (default, or ``$CANTRACK_VCAN_MODE``), "native" or "vm".  In native mode ``env`` is added
    to the full host environment; in the VM to :func:`controller.testing.vm.guest_env`.
    """
    chosen = pick_mode(mode, channel)
    if chosen == "native":
        return run_native(argv, timeout_s, env, cwd=cwd, scratch_dir=scratch_dir,
                          channel=channel)
    return run_in_vm(argv, timeout_s, env, cwd=cwd, scratch_dir=scratch_dir, channel=channel)
