"""The VM harness, native vcan detection, candump capture and the tshark classification.

Everything here runs without a VM except ``test_harness_round_trip`` (marked ``vcan``: one
boot, or a native run where the kernel has vcan).
"""

from __future__ import annotations

import shutil
import stat
import struct
import sys
import textwrap
from pathlib import Path

import can
import pytest

from controller.testing import candump as candump_mod
from controller.testing import capture, vcan, vm
from controller.testing.capture import Kind
from controller.testing.speed import MAX_FACTOR

# ---------------------------------------------------------------------------------------------
# initramfs

def _parse_newc(blob: bytes) -> list[tuple[str, int, bytes, tuple[int, int]]]:
    out, off = [], 0
    while True:
        hdr = blob[off: off + 110]
        assert hdr[:6] == b"070701", hdr[:6]
        f = [int(hdr[6 + 8 * i: 14 + 8 * i], 16) for i in range(13)]
        mode, size, rmaj, rmin, namesize = f[1], f[6], f[9], f[10], f[11]
        name = blob[off + 110: off + 110 + namesize - 1].decode()
        off += 110 + namesize
        off += -off % 4
        data = blob[off: off + size]
        off += size
        off += -off % 4
        if name == "TRAILER!!!":
            return out
        out.append((name, mode, data, (rmaj, rmin)))


def _fake_modules(tmp_path: Path, builtin: str = "") -> vm.KernelInfo:
    mdir = tmp_path / "lib/modules/9.9.9-test"
    lines = {
        "kernel/drivers/virtio/virtio_ring.ko": "",
        "kernel/drivers/virtio/virtio.ko": "",
        "kernel/drivers/virtio/virtio_pci.ko": "kernel/drivers/virtio/virtio.ko "
                                               "kernel/drivers/virtio/virtio_ring.ko",
        "kernel/net/9p/9pnet.ko": "",
        "kernel/net/9p/9pnet_virtio.ko": "kernel/net/9p/9pnet.ko "
                                         "kernel/drivers/virtio/virtio.ko "
                                         "kernel/drivers/virtio/virtio_ring.ko",
        "kernel/fs/netfs/netfs.ko": "",
        "kernel/fs/9p/9p.ko": "kernel/net/9p/9pnet.ko kernel/fs/netfs/netfs.ko",
        "kernel/net/can/can.ko": "",
        "kernel/net/can/can-raw.ko": "kernel/net/can/can.ko",
        "kernel/net/can/can-bcm.ko": "kernel/net/can/can.ko",
        "kernel/drivers/net/can/dev/can-dev.ko": "",
        "kernel/drivers/net/can/vcan.ko": "kernel/drivers/net/can/dev/can-dev.ko",
    }
    for path in lines:
        p = mdir / path
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"\x7fELF fake " + path.encode())
    (mdir / "modules.dep").write_text("".join(f"{k}: {v}\n" for k, v in lines.items()))
    (mdir / "modules.builtin").write_text(builtin)
    img = tmp_path / "vmlinuz-9.9.9-test"
    img.write_bytes(b"not a kernel")
    return vm.KernelInfo("9.9.9-test", img, mdir)


def test_modules_resolved_in_dependency_order(tmp_path):
    k = _fake_modules(tmp_path)
    names = [vm._mod_name(str(p)) for p in vm.resolve_modules(k)]
    assert names == ["virtio_ring", "virtio", "virtio_pci", "9pnet", "9pnet_virtio", "netfs",
                     "9p", "can", "can_raw", "can_bcm", "can_dev", "vcan"]
    for mod, deps in (("vcan", ["can_dev"]), ("9p", ["9pnet", "netfs"]),
                      ("9pnet_virtio", ["virtio", "virtio_ring", "9pnet"])):
        assert all(names.index(d) < names.index(mod) for d in deps)


def test_builtin_modules_skipped_and_missing_named(tmp_path):
    k = _fake_modules(tmp_path, builtin="kernel/drivers/virtio/virtio.ko\n"
                                        "kernel/drivers/virtio/virtio_ring.ko\n")
    names = [vm._mod_name(str(p)) for p in vm.resolve_modules(k)]
    assert "virtio" not in names and "virtio_ring" not in names and names[0] == "virtio_pci"
    with pytest.raises(vm.VmError, match=r"module 'j1939'.*modules.dep"):
        vm.resolve_modules(k, ["j1939"])


def test_initramfs_layout(tmp_path):
    k = _fake_modules(tmp_path)
    bb = tmp_path / "busybox"
    bb.write_bytes(b"\x7fELF busybox")
    mods = vm.resolve_modules(k)
    entries = {name: (mode, data, rdev)
               for name, mode, data, rdev in _parse_newc(vm.build_initramfs_bytes(bb, mods))}
    assert entries["init"][1].decode() == vm.INIT_SCRIPT
    assert stat.S_ISREG(entries["init"][0]) and entries["init"][0] & 0o111
    assert entries["bin/busybox"][1] == b"\x7fELF busybox"
    mode, _, rdev = entries["dev/console"]
    assert stat.S_ISCHR(mode) and rdev == (5, 1)
    order = entries["modules/order"][1].decode().split()
    assert order == [f"{i:02d}-{vm._mod_name(str(m))}.ko" for i, m in enumerate(mods)]
    assert all(entries["modules/" + o][1].startswith(b"\x7fELF fake") for o in order)


def test_initramfs_cached_by_kernel_and_content(tmp_path, monkeypatch):
    k = _fake_modules(tmp_path)
    bb = tmp_path / "busybox"
    bb.write_bytes(b"\x7fELF busybox")
    monkeypatch.setenv("CANTRACK_VM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(vm, "find_busybox", lambda: bb)
    first = vm.initramfs_path(k)
    assert first.parent == tmp_path / "cache" and "9.9.9-test" in first.name
    assert vm.initramfs_path(k) == first and first.stat().st_mtime_ns == \
        vm.initramfs_path(k).stat().st_mtime_ns
    bb.write_bytes(b"\x7fELF busybox v2")
    second = vm.initramfs_path(k)
    assert second != first and not first.exists()


def _elf(phdrs: list[tuple[int, bytes]]) -> bytes:
    """A minimal ELF64 little-endian file with the given (p_type, segment bytes)."""
    phoff, phentsize = 64, 56
    head = bytearray(64)
    head[:6] = b"\x7fELF\x02\x01"
    struct.pack_into("<Q", head, 32, phoff)
    struct.pack_into("<HH", head, 54, phentsize, len(phdrs))
    body = bytearray()
    table = bytearray()
    data_off = phoff + phentsize * len(phdrs)
    for p_type, seg in phdrs:
        table += struct.pack("<IIQQQQQQ", p_type, 0, data_off + len(body), 0, 0, len(seg),
                             len(seg), 4)
        body += seg
    return bytes(head + table + body)


def _note(name: bytes, ntype: int, desc: bytes) -> bytes:
    n = name + b"\0"
    return (struct.pack("<III", len(n), len(desc), ntype) + n + b"\0" * (-len(n) % 4)
            + desc + b"\0" * (-len(desc) % 4))


def test_static_elf_and_pvh_note_detection(tmp_path):
    static = tmp_path / "static"
    static.write_bytes(_elf([(1, b"code")]))
    dynamic = tmp_path / "dynamic"
    dynamic.write_bytes(_elf([(3, b"/lib64/ld-linux-x86-64.so.2\0"), (1, b"code")]))
    assert vm._is_static_elf(static) and not vm._is_static_elf(dynamic)
    assert not vm._is_static_elf(tmp_path / "missing")
    pvh = _elf([(4, _note(b"GNU", 3, b"1234") + _note(b"Xen", 18, b"\0" * 4))])
    assert vm._elf_has_pvh_note(pvh)
    assert not vm._elf_has_pvh_note(_elf([(4, _note(b"Xen", 17, b"\0" * 4))]))
    assert not vm._elf_has_pvh_note(b"MZ not an elf")


def test_vm_available_names_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setenv("CANTRACK_VM_QEMU", str(tmp_path / "no-qemu"))
    monkeypatch.setattr(shutil, "which", lambda name: None)
    monkeypatch.setenv("CANTRACK_VM_KERNEL", str(tmp_path / "no-vmlinuz"))
    ok, why = vm.vm_available()
    assert not ok
    assert "qemu-system-x86" in why and "CANTRACK_VM_KERNEL" in why
    assert vm.VM_INSTALL_HINT in why


def test_guest_env(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONPATH", "/x/y")
    monkeypatch.setenv("SECRET_TOKEN", "not passed")
    env = vm.guest_env({"FOO": "1", "TMPDIR": "/elsewhere"}, tmp_path, "vcan0")
    assert env["PYTHONPATH"] == "/x/y" and env["FOO"] == "1" and env["TMPDIR"] == "/elsewhere"
    assert "SECRET_TOKEN" not in env and env["PYTHONDONTWRITEBYTECODE"] == "1"
    assert (env["CANTRACK_SCRATCH"], env["CANTRACK_CAN_CHANNEL"], env["CANTRACK_VCAN_MODE"]) \
        == (str(tmp_path), "vcan0", "vm")
    monkeypatch.delenv("CANTRACK_SPEED_FACTOR", raising=False)
    assert "CANTRACK_SPEED_FACTOR" not in vm.guest_env(None, tmp_path, "vcan0")
    assert vm.guest_env({"CANTRACK_SPEED_FACTOR": "9"}, tmp_path, "vcan0",
                        2.5)["CANTRACK_SPEED_FACTOR"] == "2.500"


def test_limit_factor_is_the_callers_or_measured_now(monkeypatch):
    """The VM's limits and the guest's windows: the factor the caller built its command with,
    else the host's slowness measured at this moment (not at the session's start)."""
    from controller.testing import speed
    monkeypatch.setenv(speed.ENV, "1")  # (restored afterwards: fresh_factor sets it)
    assert vm.limit_factor({"CANTRACK_SPEED_FACTOR": "3.5"}) == 3.5
    assert vm.limit_factor({"CANTRACK_SPEED_FACTOR": "0.3"}) == 1.0  # never below 1
    with pytest.raises(vm.VmError, match="not a number"):
        vm.limit_factor({"CANTRACK_SPEED_FACTOR": "fast"})
    calls = []
    monkeypatch.setattr(speed, "_GIVEN", None)
    monkeypatch.setattr(speed, "measure", lambda runs=9: calls.append(runs) or 4.0 + len(calls))
    assert vm.limit_factor(None) == 5.0 and vm.limit_factor({}) == 6.0  # measured each time
    assert speed.speed_factor() == 6.0 and speed.os.environ[speed.ENV] == "6.000"
    monkeypatch.setattr(speed, "_GIVEN", "2")  # given to this process: kept
    assert speed.fresh_factor() == 6.0 and len(calls) == 2
    monkeypatch.setattr(speed, "_factor", None)


def test_vcan_mode_and_availability(monkeypatch):
    with pytest.raises(vm.VmError, match="allowed auto, native, vm"):
        vcan.resolve_mode("kvm")
    monkeypatch.setenv("CANTRACK_VCAN_MODE", "VM")
    assert vcan.resolve_mode() == "vm"
    ok, why = vcan.af_can_available()
    assert ok or "SocketCAN" in why or "AF_CAN" in why or "BCM" in why
    ok, why = vcan.vcan_available("native")
    assert ok == vcan.native_vcan_available()[0] and why


# ---------------------------------------------------------------------------------------------
# a guest that hangs at boot: killed at the boot limit, booted once more

class _SteppedClock:
    """The boot wait's clock [s]; ``sleep`` steps it and lets the fake guests act."""

    def __init__(self):
        self.t = 100.0
        self.guests: list[_FakeGuest] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt
        for g in self.guests:
            g.act(self.t)


class _FakeGuest:
    """A VM process: prints SeaBIOS's lines, then writes ``ready`` ``ready_after_s`` after
    its start (never when None) or powers off then (``power_off``)."""

    def __init__(self, jd: Path, clock: _SteppedClock, ready_after_s: float | None,
                 power_off: bool = False):
        self.jd, self.started, self.ready_after_s = jd, clock.t, ready_after_s
        self.power_off = power_off
        self.returncode: int | None = None
        self.killed_at: float | None = None
        self.clock = clock
        (jd / "console.log").write_text("\x1bc\x1b[2JSeaBIOS (version 1.16.2-debian)\r\n"
                                        "Booting from ROM..\r\n")

    def act(self, t: float) -> None:
        if (self.returncode is None and self.ready_after_s is not None
                and t - self.started >= self.ready_after_s):
            if self.power_off:
                self.returncode = 0
            else:
                (self.jd / "ready").write_text("1.5\n")

    def poll(self):
        return self.returncode

    def kill(self):
        self.killed_at = self.clock.t
        self.returncode = -9

    def wait(self, timeout=None):
        return self.returncode


def _boot(tmp_path, *ready_after_s, power_off=False, factor=1.5):
    clock = _SteppedClock()
    plan = list(ready_after_s)

    def start(attempt):
        assert attempt == len(clock.guests) + 1
        (tmp_path / "ready").unlink(missing_ok=True)
        g = _FakeGuest(tmp_path, clock, plan[attempt - 1], power_off)
        clock.guests.append(g)
        return g

    def run():
        return vm.boot_until_ready(start, tmp_path / "ready", tmp_path / "console.log",
                                   limit_s=60.0, factor=factor, clock=clock,
                                   sleep=clock.sleep, poll_s=0.5)
    return clock, run


def test_hung_boot_killed_at_the_stretched_limit_and_booted_again(tmp_path, caplog):
    """The first guest never writes ``ready`` (as in CI: nothing after "Booting from ROM.."):
    killed 60 s x 1.5 after its start, logged, and a second boot whose guest is ready 3 s
    after its start is the one returned."""
    clock, run = _boot(tmp_path, None, 3.0)
    with caplog.at_level("WARNING", logger=vm.__name__):
        boot = run()
    first, second = clock.guests
    assert (boot.proc, boot.attempt, boot.ready_s) == (second, 2, 3.0)
    assert first.killed_at == 100.0 + 90.0 and second.killed_at is None
    assert boot.started == 190.0
    note = ("boot 1 of 2: no ready file within the boot limit of 90 s (60 s x the measured "
            "slowness 1.50), the console last printed 'Booting from ROM..': VM killed")
    assert boot.notes == (note,)
    assert [r.getMessage() for r in caplog.records] == [note + "; booting once more"]


def test_ready_at_once_is_one_boot(tmp_path, caplog):
    clock, run = _boot(tmp_path, 4.0)
    boot = run()
    assert (boot.attempt, boot.ready_s, boot.notes) == (1, 4.0, ())
    assert clock.guests[0].killed_at is None and not caplog.records


def test_two_hung_boots_fail_naming_the_limit_and_the_console(tmp_path):
    clock, run = _boot(tmp_path, None, None, factor=1.0)
    with pytest.raises(vm.VmTimeoutError) as e:
        run()
    msg = str(e.value)
    assert msg.startswith("the VM did not boot: 2 boots, none wrote its ready file within "
                          "the boot limit of 60 s (60 s x the measured slowness 1.00) (boot 1 "
                          "of 2: no ready file within the boot limit of 60 s")
    assert msg.count("the console last printed 'Booting from ROM..'") == 2
    assert "--- guest console (last lines) ---" in msg and "Booting from ROM.." in e.value.console
    assert [g.killed_at for g in clock.guests] == [160.0, 220.0]


def test_guest_powering_off_before_ready_is_not_booted_again(tmp_path):
    """An init failure (the guest powers off without ``ready``) is the caller's to report
    (the guest's init-error): no second boot."""
    clock, run = _boot(tmp_path, 2.0, None, power_off=True)
    boot = run()
    assert (boot.attempt, boot.ready_s, boot.proc.poll()) == (1, None, 0)
    assert len(clock.guests) == 1 and clock.guests[0].killed_at is None


FAKE_QEMU = r"""
J="$1/.cantrack-vm"
n=$(cat "$1/boots" 2>/dev/null || echo 0); n=$((n + 1)); echo $n > "$1/boots"
printf 'SeaBIOS (version fake)
Booting from ROM..
'
if [ $n = 1 ]; then exec sleep 600; fi
echo 0.5 > "$J/ready"
echo "guest-ran boot $n" > "$J/stdout"; : > "$J/stderr"
echo 0 > "$J/rc"
"""


def test_run_in_vm_boots_again_after_a_hung_boot(tmp_path, monkeypatch):
    """run_in_vm with a fake qemu whose first boot hangs: the hung VM killed at the boot
    limit (0.5 s here), the second boot's result, the first console kept, the retry in the
    result."""
    k = vm.KernelInfo("9.9.9-test", tmp_path / "vmlinuz", tmp_path)
    monkeypatch.setattr(vm, "find_kernel", lambda: k)
    monkeypatch.setattr(vm, "initramfs_path", lambda kernel: tmp_path / "initrd")
    monkeypatch.setattr(vm, "boot_image", lambda kernel: (tmp_path / "vmlinux", "pvh"))
    monkeypatch.setattr(vm, "find_qemu", lambda: Path("/bin/sh"))
    monkeypatch.setattr(vm, "qemu_command", lambda qemu, image, initrd, scratch, **kw: [
        "/bin/sh", "-c", FAKE_QEMU, "sh", str(scratch)])
    scratch = tmp_path / "scratch"
    r = vm.run_in_vm(["true"], timeout_s=30, env={"CANTRACK_SPEED_FACTOR": "1"},
                     scratch_dir=scratch, ready_timeout_s=0.5)
    assert (r.returncode, r.stdout, r.boot_attempts) == (0, "guest-ran boot 2\n", 2)
    assert r.boot_notes == ("boot 1 of 2: no ready file within the boot limit of 0.5 s (0.5 s x "
                            "the measured slowness 1.00), the console last printed 'Booting "
                            "from ROM..': VM killed",)
    jd = scratch / vm.JOB_DIR
    assert "Booting from ROM.." in (jd / "console-1.log").read_text()
    assert (scratch / "boots").read_text() == "2\n"


# ---------------------------------------------------------------------------------------------
# capture → pcap → tshark

def _msgs(spec):
    out = []
    for t, cid, data, *flags in spec:
        out.append(can.Message(timestamp=t, arbitration_id=cid, data=bytes(data),
                               is_extended_id="x" in flags, is_remote_frame="r" in flags,
                               dlc=len(data) if "r" not in flags else 0))
    return out


def test_pcap_bytes(tmp_path):
    p = tmp_path / "a.pcap"
    n = capture.write_pcap(_msgs([(10.25, 0x181, [1, 2, 3]), (11.5, 0x1ABCDEF, [9], "x")]), p)
    blob = p.read_bytes()
    assert n == 2
    assert struct.unpack_from("<IHHiIII", blob) == (0xA1B2C3D4, 2, 4, 0, 0, 262144, 227)
    sec, usec, incl, orig = struct.unpack_from("<IIII", blob, 24)
    assert (sec, usec, incl, orig) == (10, 250000, 16, 16)
    assert blob[40:56] == struct.pack(">IBBBB", 0x181, 3, 0, 0, 0) + bytes([1, 2, 3]) + bytes(5)
    assert struct.unpack_from(">I", blob, 72)[0] == 0x1ABCDEF | capture.CAN_EFF_FLAG


def test_expected_kind_table():
    ek = capture.expected_kind
    assert [ek(i) for i in (0x000, 0x080, 0x081, 0x0FF, 0x100, 0x181, 0x57F, 0x581, 0x67F,
                            0x701, 0x77F, 0x7E5, 0x180, 0x700, 0x7FF)] == [
        Kind.NMT, Kind.SYNC, Kind.EMCY, Kind.EMCY, Kind.TIME, Kind.PDO, Kind.PDO, Kind.SDO,
        Kind.SDO, Kind.HEARTBEAT, Kind.HEARTBEAT, Kind.LSS, Kind.UNKNOWN, Kind.UNKNOWN,
        Kind.UNKNOWN]
    assert ek(0x181, is_extended=True) is Kind.UNKNOWN


@pytest.fixture(scope="module")
def tshark():
    ok, found = capture.tshark_available()
    if not ok:
        pytest.skip(found)
    return found


def test_classify_candump_log(tmp_path, tshark):
    log = tmp_path / "bus.log"
    log.write_text(textwrap.dedent("""\
        (100.000000) vcan0 702#00
        (100.001000) vcan0 000#0100
        (100.010000) vcan0 080#01
        (100.011000) vcan0 181#112233445566
        (100.012000) vcan0 202#0F0000000000
        (100.020000) vcan0 080#02
        (100.021000) vcan0 602#4018100100000000
        (100.022000) vcan0 582#43181001C07ACA00
        (100.030000) vcan0 080#01
        (100.031000) vcan0 082#1186010000000000
        (100.032000) vcan0 702#05
        """))
    frames = capture.classify_capture(log, tshark=tshark)
    assert (log.with_suffix(".pcap")).is_file()
    assert [f.kind for f in frames] == [
        Kind.HEARTBEAT, Kind.NMT, Kind.SYNC, Kind.PDO, Kind.PDO, Kind.SYNC, Kind.SDO, Kind.SDO,
        Kind.SYNC, Kind.EMCY, Kind.HEARTBEAT]
    assert capture.problems(frames) == []
    f = {fr.number: fr for fr in frames}
    assert (f[1].node_id, f[1].nmt_state) == (2, 0)
    assert (f[2].nmt_command, f[2].nmt_target) == (1, 0)
    assert (f[4].pdo, f[4].direction, f[4].data) == (1, "tx", bytes.fromhex("112233445566"))
    assert (f[5].pdo, f[5].direction) == (1, "rx")
    assert (f[7].sdo_index, f[7].sdo_subindex, f[7].direction) == (0x1018, 1, "rx")
    assert (f[10].emcy_code, f[10].emcy_register, f[10].node_id) == (0x8611, 1, 2)
    assert f[3].time_s == pytest.approx(0.010, abs=1e-6)
    stats = capture.sync_period_stats(frames, overflow=2)
    assert stats.count == 3 and stats.counters == (1, 2, 1) and stats.counter_gaps == ()
    assert stats.period_mean_s == pytest.approx(0.010, abs=1e-6)
    assert capture.pdo_order_per_sync(frames) == [(0x181, 0x202), (), ()]
    # the same pcap decodes the same way when given directly (data read back from the pcap)
    again = capture.classify_capture(log.with_suffix(".pcap"), tshark=tshark)
    assert [(a.kind, a.data) for a in again] == [(b.kind, b.data) for b in frames]


def test_problems_flag_malformed_unknown_and_length(tmp_path, tshark):
    log = tmp_path / "bad.log"
    log.write_text(textwrap.dedent("""\
        (1.000000) vcan0 602#4018
        (1.001000) vcan0 082#1186
        (1.002000) vcan0 000#01
        (1.003000) vcan0 702#
        (1.004000) vcan0 080#0102
        (1.005000) vcan0 12345678#01
        (1.006000) vcan0 181#00
        """))
    frames = capture.classify_capture(log, tshark=tshark)
    bad = capture.problems(frames)
    assert len(bad) == 6, bad
    assert [f.malformed for f in frames][:3] == [True, True, True]
    assert "heartbeat with 0 data bytes" in bad[3]
    assert "SYNC with 2 data bytes" in bad[4]
    assert "UNKNOWN" in bad[5]


def test_sync_counter_gaps():
    def sync(n, t, c):
        return capture.FrameClass(number=n, time_s=t, can_id=0x80, is_extended=False,
                                  is_remote=False, data=bytes([c]), kind=Kind.SYNC,
                                  expected_kind=Kind.SYNC, malformed=False, info="",
                                  sync_counter=c)
    frames = [sync(i, i * 0.01, c) for i, c in enumerate([3, 4, 1, 2, 4, 1])]
    s = capture.sync_period_stats(frames, overflow=4)
    assert s.counter_gaps == (4,) and s.overflow == 4
    assert capture.sync_period_stats(frames, overflow=3).counter_gaps == (1, 4)
    assert capture.sync_period_stats(frames[1:], overflow=3).counter_gaps == (0, 3)
    assert capture.sync_period_stats(frames[:2]).overflow == 4   # largest seen


def test_read_log_errors(tmp_path):
    with pytest.raises(capture.CaptureError, match="not found"):
        capture.read_log(tmp_path / "nope.log")


# ---------------------------------------------------------------------------------------------
# candump wrapper (with a stand-in candump: the host kernel may have no CAN)

def test_candump_capture_waits_for_receiver_and_cleans_drops(tmp_path, monkeypatch):
    proc_can = tmp_path / "proc-net-can"
    proc_can.mkdir()
    rcv = proc_can / "rcvlist_all"
    rcv.write_text("receive list 'rx_all':\n  (vcan0: no entry)\n")
    fake = tmp_path / "candump"
    fake.write_text(textwrap.dedent(f"""\
        #!{sys.executable}
        import signal, sys, time
        assert sys.argv[1:] == ["-L", "-d", "-r", "8388608", "vcan0"], sys.argv
        print("(1.000000) vcan0 080#01")
        print("DROPCOUNT: dropped 3 CAN frames on 'vcan0' socket (total drops 3)")
        print("(1.010000) vcan0 080#02")
        sys.stdout.flush()
        stop = []
        signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
        with open({str(rcv)!r}, "a") as f:
            f.write("   vcan0     000    00000000  0000  0000  0  raw\\n")
        while not stop:
            signal.pause()
        """))
    fake.chmod(0o755)
    monkeypatch.setattr(candump_mod, "_PROC_CAN", proc_can)
    with candump_mod.CandumpCapture("vcan0", tmp_path / "bus.log", candump=str(fake)) as cap:
        assert candump_mod._receivers("vcan0") == 1
    info = cap.info
    assert (info.frames, info.dropped, info.returncode) == (2, 3, 0)
    assert (tmp_path / "bus.log").read_text() == \
        "(1.000000) vcan0 080#01\n(1.010000) vcan0 080#02\n"
    assert [m.data[0] for m in capture.read_log(tmp_path / "bus.log")] == [1, 2]


def test_candump_missing_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(candump_mod.CandumpError, match="apt-get install can-utils"):
        candump_mod.CandumpCapture("vcan0", tmp_path / "x.log").start()


# ---------------------------------------------------------------------------------------------
# one real run (VM boot, or native)

GUEST_CHECKS = r"""
set -e
echo "type=$(cat /sys/class/net/$CANTRACK_CAN_CHANNEL/type)"
echo "flags=$(cat /sys/class/net/$CANTRACK_CAN_CHANNEL/flags)"
echo "cwd=$(pwd)"
echo "foo=$CANTRACK_TEST_FOO"
echo "mode=$CANTRACK_VCAN_MODE"
echo "speed=$CANTRACK_SPEED_FACTOR"
echo written > "$CANTRACK_SCRATCH/from-guest.txt"
cat "$CANTRACK_SCRATCH/from-host.txt"
"$PYTHON" -S -c "import socket as S; s = S.socket(S.AF_CAN, S.SOCK_RAW, S.CAN_RAW)
s.bind(('$CANTRACK_CAN_CHANNEL',)); print('af_can=ok')"
echo to-stderr >&2
echo checks-done
exec sleep 600
"""


@pytest.mark.vcan
def test_harness_round_trip(vcan_runner, tmp_path):
    """Environment, working directory, scratch both ways, vcan0 up, AF_CAN bind, stderr, and
    the command time-out (the command sleeps past it: terminated, exit 143), the host's
    measured slowness passed on (by which the time-out was stretched).  The checks take
    about 1 s in the VM (3 s on a loaded machine); the 8 s time-out leaves room."""
    (tmp_path / "from-host.txt").write_text("host-file-seen\n")
    r = vcan_runner.run(["/bin/sh", "-c", GUEST_CHECKS], timeout_s=8,
                        env={"CANTRACK_TEST_FOO": "bar baz", "PYTHON": sys.executable},
                        cwd=tmp_path, scratch_dir=tmp_path)
    out = dict(line.split("=", 1) for line in r.stdout.splitlines() if "=" in line)
    assert "checks-done" in r.stdout, (r.stdout, r.stderr, r.console[-2000:])
    assert int(out["type"]) == 280 and int(out["flags"], 16) & 1
    assert out["cwd"] == str(tmp_path) and out["foo"] == "bar baz"
    assert out["mode"] == r.mode and out["af_can"] == "ok"
    assert "host-file-seen" in r.stdout and r.stderr.strip() == "to-stderr"
    assert (tmp_path / "from-guest.txt").read_text() == "written\n"
    assert r.timed_out and r.returncode == 143
    f = r.speed_factor
    assert 1.0 <= f <= MAX_FACTOR and float(out["speed"]) == pytest.approx(f, abs=1e-3)
    if r.mode == "vm":  # (the guest's limit: round(8 s x f); boot within 90 s x f)
        assert r.boot_s is not None and 0 < r.boot_s < 90 * f
        assert round(8 * f) - 1 <= r.command_s < 30 * f, (r.command_s, f)


# ---------------------------------------------------------------------------------------------
# hil: the same independent decoding on a real bus (passive: sends nothing)

@pytest.mark.hil
def test_hil_bus_traffic_is_clean_canopen(hil_bus_config, tmp_path):
    """Listen to the rig's bus for 2 s (its nodes' heartbeats at least) and check that every
    frame is CANopen, none malformed: decoded by tshark, or where tshark is not installed by
    the built-in CiA 301 decoder (``--hil-decoder``).  Sends nothing."""
    decoder, tshark = capture.pick_decoder(hil_bus_config.decoder)
    msgs = []
    with can.Bus(**hil_bus_config.bus_kwargs()) as bus:
        reader = can.BufferedReader()
        with can.Notifier(bus, [reader]):
            import time
            time.sleep(2.0)   # real bus, real time: this tier runs on a rig, not in CI
        while (m := reader.get_message(0)) is not None:
            msgs.append(m)
    assert msgs, (f"no frame on {hil_bus_config.describe()} in 2 s: "
                  "are the nodes powered and the bitrate right?")
    if decoder == "tshark":
        capture.write_pcap(msgs, tmp_path / "rig.pcap")
        frames = capture.decode_pcap(tmp_path / "rig.pcap", messages=msgs, tshark=tshark)
    else:
        frames = capture.decode_messages(msgs)
    bad = capture.problems(frames, allowed=set(Kind) - {Kind.UNKNOWN})
    assert not bad, f"{decoder}:\n" + "\n".join(bad[:30])


# ---------------------------------------------------------------------------------------------
# the vcan tier's windows on a slow machine

def test_window_factor_is_one_idle_and_twice_the_slowness_when_busy():
    from controller.testing.speed import MAX_FACTOR, window_factor
    assert window_factor(1.0) == 1.0 and window_factor(0.5) == 1.0
    assert window_factor(1.5) == 2.25 and window_factor(3.5) == 7.0
    assert window_factor(15.0) == MAX_FACTOR


def test_stretched_bus_config_windows_and_what_stays(tmp_path):
    """examples/bus/vcan.yml stretched x 2.5: every supervision window x 2.5 (read back by the
    config loader, defaults included), the SYNC period, heartbeat periods, PDOs and motion as
    written; x 1 reads back as the original."""
    from controller.canopen.config import load_config
    from controller.testing.stretch import stretch_bus_config, stretch_mapping

    src = Path(__file__).resolve().parents[1] / "examples" / "bus" / "vcan.yml"
    text = src.read_text() + ("\n.plc:\n  commander: 32\n")
    (tmp_path / "in").mkdir()
    idle = tmp_path / "in" / "vcan.yml"
    idle.write_text(text.replace("../../eds/", str(src.parents[2] / "eds") + "/"))
    a = load_config(idle)
    b = load_config(stretch_bus_config(idle, tmp_path / "s.yml", 2.5))
    one = load_config(stretch_bus_config(idle, tmp_path / "one.yml", 1.0))
    assert b.master.sync_period_us == a.master.sync_period_us == 100_000
    for name in ("encoder", "x", "y"):
        sa, sb = a.slaves[name], b.slaves[name]
        assert sa.heartbeat_producer_ms == sb.heartbeat_producer_ms == 200
        assert sb.hb_multiplier(b.options) == 2.5 * sa.hb_multiplier(a.options) == 10.0
        assert _plain(sb.tpdo) == _plain(sa.tpdo) and _plain(sb.rpdo) == _plain(sa.rpdo)
    assert b.master.heartbeat_multiplier == 10.0  # (the drives' 1016h time-out of us)
    fe = {w.index: w.value for w in b.slaves["x"].sdo}
    assert fe[0x6066] == 1250 and fe[0x6065] == 1_000_000 and fe[0x6085] == 20_000_000
    ta, tb = a.tracking, b.tracking
    assert tb.conveyor.silent_cycles == 50 and ta.conveyor.silent_cycles == 20
    assert tb.max_missed_in_row == 63 and ta.max_missed_in_row == 25  # (the default, x 2.5)
    assert (tb.timeouts.boot_up_s, tb.timeouts.sdo_s, tb.timeouts.enable_s,
            tb.timeouts.stop_s) == (25.0, 5.0, 50.0, 2.5)  # stop_s: the default 1 s
    assert tb.timeouts.sdo_retries == ta.timeouts.sdo_retries
    assert tb.tracker == ta.tracker and _plain(tb.axes) == _plain(ta.axes)
    assert tb.window == ta.window and _plain(b.simulation) == _plain(a.simulation)
    assert b.plc.commander_heartbeat_ms == 2.5 * a.plc.commander_heartbeat_ms == 750
    # defaults stretched where the file has no value (options' multiplier 3: 3 x 200 ms)
    bare = stretch_mapping({"master": {"node_id": 1, "sync_period": 2000}}, 2.0)
    assert bare["options"] == {"heartbeat_multiplier": 6.0} and bare["master"] == {
        "node_id": 1, "sync_period": 2000}
    # x 1: the same configuration
    assert _plain((one.master, one.options, one.slaves, one.tracking, one.plc)) == _plain(
        (a.master, a.options, a.slaves, a.tracking, a.plc))


def _plain(v):
    """A configuration value without its file line numbers."""
    import dataclasses
    from collections.abc import Mapping
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _plain(getattr(v, f.name)) for f in dataclasses.fields(v)
                if not f.name.endswith("line") and f.name != "file"}
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v
