"""A throwaway qemu VM that gives a real Linux SocketCAN ``vcan0`` on a host kernel without CAN.

How it works (see ``docs/hil.md`` and the project notes "vcan in a VM"):

- Kernel: ``/boot/vmlinuz-<ver>`` with its modules in ``/lib/modules/<ver>`` (Debian package
  ``linux-image-amd64``); override with ``CANTRACK_VM_KERNEL=/path/to/vmlinuz``.
- A tiny initramfs, built once per kernel and cached in ``$XDG_CACHE_HOME/cantrack-vm`` (default
  ``~/.cache/cantrack-vm``; override ``CANTRACK_VM_CACHE``): a static busybox (Debian package
  ``busybox-static``), ``/init`` (:data:`INIT_SCRIPT`) and the modules for virtio-pci, 9p,
  CAN raw/BCM and vcan, packed in dependency order resolved from ``modules.dep`` (for Debian's
  6.1 kernel: virtio_ring, virtio, virtio_pci_legacy_dev, virtio_pci_modern_dev, virtio_pci,
  netfs, fscache, 9pnet, 9pnet_virtio, 9p, can, can-raw, can-bcm, can-dev, vcan).
- qemu (Debian package ``qemu-system-x86``) with TCG (a KVM guest hung at boot on the project's
  machines; ``CANTRACK_VM_ACCEL=kvm`` to try it), two 9p shares: the host's ``/`` read-only
  (tag ``hostroot``) and a writable scratch directory (tag ``scratch``).
- The guest's ``/init`` mounts /proc, /sys, /dev, loads the modules with ``insmod``, mounts the
  scratch share, mounts the host root read-only on ``/newroot`` with fresh /proc, /sys, /dev,
  /dev/shm, a tmpfs on ``/run`` (``TMPDIR=/run/tmp``), and bind-mounts the scratch directory at
  the *same path* it has on the host, creates ``vcan0`` (and brings ``lo`` up), then runs the
  command chrooted into the host root with the host's interpreter, working directory and
  (filtered) environment.  stdout, stderr and the exit code go to ``<scratch>/.cantrack-vm/``;
  the guest powers off with ``poweroff -f``.

Timing inside the TCG guest is emulated: use it for correctness, never for speed.
"""

from __future__ import annotations

import bz2
import dataclasses
import fcntl
import gzip
import hashlib
import logging
import lzma
import os
import re
import shlex
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Protocol

from ..errors import CantrackError

#: the apt command that makes the VM possible on Debian/Ubuntu
VM_APT_PACKAGES = ("qemu-system-x86", "linux-image-amd64", "busybox-static")
VM_INSTALL_HINT = ("apt-get install --no-install-recommends " + " ".join(VM_APT_PACKAGES))

#: modules the guest needs (dependencies are added from modules.dep); built-ins are skipped
GUEST_MODULES = ("virtio_pci", "9pnet_virtio", "9p", "can", "can_raw", "can_bcm", "vcan")

#: the environment variables passed from the host into the guest command (plus ``env=``)
PASSED_ENV = ("PATH", "PYTHONPATH", "HOME", "LANG", "LC_ALL", "LC_CTYPE", "VIRTUAL_ENV",
              "PYTHONHASHSEED", "PYTHONWARNINGS", "PYTHONIOENCODING", "TZ", "USER", "LOGNAME")

#: result files in ``<scratch>/.cantrack-vm/``
JOB_DIR = ".cantrack-vm"

DEFAULT_CHANNEL = "vcan0"

#: guest kernel command line; the options after rdinit= skip work that is slow under TCG
#: (TSC calibration/watchdog, crypto self-tests, spectre mitigations, probing 4 UARTs)
KERNEL_CMDLINE = ("console=ttyS0 quiet panic=-1 rdinit=/init tsc=reliable no_timer_check "
                  "cryptomgr.notests mitigations=off 8250.nr_uarts=1 random.trust_cpu=on")
_FORMAT = 4  # bump when the initramfs layout or INIT_SCRIPT changes meaning

#: the time [s, idle machine; x the measured slowness] from starting qemu until the guest's
#: ``ready`` file (vcan0 up, the command about to start): an idle boot takes about 4 s, so
#: past 15 times that the guest hangs (seen once in CI: nothing after SeaBIOS's "Booting from
#: ROM.." for 245 s) and is killed and booted again (:func:`boot_until_ready`)
READY_LIMIT_S = 60.0
#: boots tried before giving up (the command has not started when ``ready`` is missing, so a
#: second boot is safe)
BOOT_ATTEMPTS = 2
#: the files of one boot in the job directory, removed before another boot
_BOOT_FILES = ("ready", "rc", "rc.tmp", "stdout", "stderr", "timed-out", "uptime-end",
               "init-error")

_log = logging.getLogger(__name__)


class VmError(CantrackError):
    """The VM could not be prepared, booted, or did not report the command's exit code."""

    def __init__(self, message: str, *, console: str = "", scratch_dir: Path | None = None):
        self.console = console
        self.scratch_dir = scratch_dir
        tail = console.strip().splitlines()[-25:]
        if tail:
            message += "\n--- guest console (last lines) ---\n" + "\n".join(tail)
        super().__init__(message)


class VmTimeoutError(VmError, TimeoutError):
    """The VM did not power off within the time-out (it was killed)."""


@dataclasses.dataclass(frozen=True)
class VmResult:
    """What a command run on a real SocketCAN bus returned.

    ``returncode``/``stdout``/``stderr``: the command's.  ``scratch_dir``: the writable directory
    shared with the command (same path on host and guest; also ``$CANTRACK_SCRATCH``).
    ``mode``: "vm" or "native".  ``boot_s``: host seconds from starting qemu until the guest's
    vcan0 was up and the command started (None in native mode).  ``command_s``: seconds the
    command ran; ``wall_s``: everything.  ``console``: the guest's serial console (kernel and
    init messages; empty in native mode).  ``channel``: the SocketCAN interface (``vcan0``).
    ``timed_out``: the command was still running at its time-out and was terminated.
    ``speed_factor``: the host's measured slowness at the start
    (:func:`controller.testing.speed.fresh_factor`), by which the time limits were stretched
    and which the command got in ``CANTRACK_SPEED_FACTOR``.  ``boot_attempts``: the VM boots
    it took (2: the first hung before ``ready`` and was killed; ``boot_notes`` says why, with
    what its console last printed; ``boot_s`` is the boot that ran the command).
    """

    returncode: int
    stdout: str
    stderr: str
    scratch_dir: Path
    mode: str = "vm"
    boot_s: float | None = None
    command_s: float | None = None
    wall_s: float | None = None
    console: str = ""
    channel: str = DEFAULT_CHANNEL
    timed_out: bool = False
    speed_factor: float = 1.0
    boot_attempts: int = 1
    boot_notes: tuple[str, ...] = ()

    def check(self) -> VmResult:
        """Raise :class:`VmError` with stdout/stderr when the command failed; else self."""
        if self.returncode != 0:
            raise VmError(f"command exited with {self.returncode} ({self.mode} mode)\n"
                          f"--- stdout ---\n{self.stdout[-4000:]}\n"
                          f"--- stderr ---\n{self.stderr[-4000:]}", console=self.console,
                          scratch_dir=self.scratch_dir)
        return self


@dataclasses.dataclass(frozen=True)
class KernelInfo:
    """A bootable kernel image and its modules directory."""

    version: str
    image: Path
    modules_dir: Path


# ---------------------------------------------------------------------------------------------
# discovery

def _version_key(v: str):
    return [int(x) if x.isdigit() else x for x in re.split(r"(\d+)", v)]


def find_kernel() -> KernelInfo:
    """The kernel the VM boots: ``$CANTRACK_VM_KERNEL`` or the newest ``/boot/vmlinuz-*``
    that has a ``/lib/modules/<version>/modules.dep`` with ``vcan``.

    Raises :class:`VmError` naming what is missing and what to install.
    """
    override = os.environ.get("CANTRACK_VM_KERNEL")
    candidates: list[tuple[str, Path]] = []
    if override:
        img = Path(override)
        ver = img.name.split("vmlinuz-", 1)[-1] if "vmlinuz-" in img.name else ""
        if not img.is_file():
            raise VmError(f"CANTRACK_VM_KERNEL={override}: no such file")
        candidates.append((ver, img))
    else:
        for img in Path("/boot").glob("vmlinuz-*"):
            candidates.append((img.name[len("vmlinuz-"):], img))
    if not candidates:
        raise VmError("no kernel image /boot/vmlinuz-* found: " + VM_INSTALL_HINT)
    problems = []
    for ver, img in sorted(candidates, key=lambda c: _version_key(c[0]), reverse=True):
        mod_dir = Path("/lib/modules") / ver
        dep = mod_dir / "modules.dep"
        if not dep.is_file():
            problems.append(f"{img}: no {dep}")
            continue
        if not os.access(img, os.R_OK):
            problems.append(f"{img}: not readable by this user (run as root, or "
                            f"chmod o+r {img})")
            continue
        if "vcan.ko" not in dep.read_text():
            problems.append(f"{img}: its modules ({mod_dir}) have no vcan")
            continue
        return KernelInfo(ver, img, mod_dir)
    raise VmError("no usable kernel for the VM: " + "; ".join(problems) + "; " + VM_INSTALL_HINT)


def _is_static_elf(path: Path) -> bool:
    """True for an ELF executable without a PT_INTERP program header (statically linked)."""
    try:
        with open(path, "rb") as f:
            head = f.read(64)
            if head[:4] != b"\x7fELF" or head[4] != 2:   # 64-bit only
                return False
            endian = "<" if head[5] == 1 else ">"
            phoff = struct.unpack_from(endian + "Q", head, 32)[0]
            phentsize, phnum = struct.unpack_from(endian + "HH", head, 54)
            f.seek(phoff)
            table = f.read(phentsize * phnum)
        for i in range(phnum):
            if struct.unpack_from(endian + "I", table, i * phentsize)[0] == 3:   # PT_INTERP
                return False
        return True
    except OSError:
        return False


def find_busybox() -> Path:
    """A statically linked busybox (``$CANTRACK_VM_BUSYBOX``, ``/bin/busybox``, ...)."""
    cands = [os.environ.get("CANTRACK_VM_BUSYBOX"), "/bin/busybox", "/usr/bin/busybox",
             "/usr/lib/busybox-static/busybox", shutil.which("busybox")]
    seen = []
    for c in cands:
        if not c or c in seen:
            continue
        seen.append(c)
        p = Path(c)
        if p.is_file() and _is_static_elf(p):
            return p
    if any(Path(c).is_file() for c in seen):
        raise VmError("busybox found but it is dynamically linked (the initramfs has no libc): "
                      "apt-get install busybox-static")
    raise VmError("no static busybox found: apt-get install busybox-static")


def find_qemu() -> Path:
    """``qemu-system-x86_64`` (``$CANTRACK_VM_QEMU`` overrides)."""
    q = os.environ.get("CANTRACK_VM_QEMU") or shutil.which("qemu-system-x86_64")
    if not q or not Path(q).is_file():
        raise VmError("qemu-system-x86_64 not found: apt-get install --no-install-recommends "
                      "qemu-system-x86")
    return Path(q)


def _parse_modules_dep(mod_dir: Path) -> dict[str, tuple[str, list[str]]]:
    """module name (``-`` → ``_``) → (relative path, [dependency paths])."""
    out = {}
    for line in (mod_dir / "modules.dep").read_text().splitlines():
        if ":" not in line:
            continue
        path, deps = line.split(":", 1)
        out[_mod_name(path)] = (path, deps.split())
    return out


def _mod_name(path: str) -> str:
    base = path.rsplit("/", 1)[-1]
    base = re.sub(r"\.ko(\.(xz|gz|zst))?$", "", base)
    return base.replace("-", "_")


def _builtin(mod_dir: Path) -> set[str]:
    f = mod_dir / "modules.builtin"
    if not f.is_file():
        return set()
    return {_mod_name(line.strip()) for line in f.read_text().splitlines() if line.strip()}


def resolve_modules(kernel: KernelInfo, wanted: Sequence[str] = GUEST_MODULES) -> list[Path]:
    """The module files to ``insmod``, dependencies first (built-in modules are skipped)."""
    deps = _parse_modules_dep(kernel.modules_dir)
    builtin = _builtin(kernel.modules_dir)
    order: list[str] = []

    def visit(name: str, chain: tuple[str, ...]):
        if name in order or name in builtin:
            return
        if name not in deps:
            raise VmError(f"kernel {kernel.version}: module {name!r} (needed for "
                          f"{' <- '.join(chain) or name}) is neither in "
                          f"{kernel.modules_dir}/modules.dep nor built in")
        _path, dlist = deps[name]
        # modules.dep lists the deepest dependencies last: load them first
        for d in reversed(dlist):
            visit(_mod_name(d), chain + (name,))
        if name not in order:
            order.append(name)

    for w in wanted:
        visit(w.replace("-", "_"), ())
    return [kernel.modules_dir / deps[n][0] for n in order]


# ---------------------------------------------------------------------------------------------
# initramfs

INIT_SCRIPT = r"""#!/bin/busybox sh
# cantrack VM init: mount, insmod, vcan0, run the job chrooted in the read-only host root.
/bin/busybox mkdir -p /proc /sys /dev /newroot /scratch /tmp
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev 2>/dev/null
J=/scratch/.cantrack-vm
say() { echo "cantrack-vm: $*" > /dev/console; }
fail() {
  say "FAILED: $*"
  [ -d "$J" ] && echo "$*" > "$J/init-error"
  sync; poweroff -f; sleep 5
}
for m in $(cat /modules/order); do
  insmod "/modules/$m" || fail "insmod $m"
done
O9P=trans=virtio,version=9p2000.L,msize=524288
mount -t 9p -o $O9P scratch /scratch || fail "mount the scratch 9p share"
[ -f "$J/job" ] || fail "no $J/job"
. "$J/job"
mount -t 9p -o $O9P,ro${ROOT_CACHE:+,cache=$ROOT_CACHE} hostroot /newroot \
  || fail "mount the host root 9p share"
R=/newroot
mount -t proc proc $R/proc || fail "mount /proc"
mount -t sysfs sysfs $R/sys || fail "mount /sys"
mount -t devtmpfs devtmpfs $R/dev || fail "mount /dev"
mkdir -p $R/dev/pts $R/dev/shm
mount -t devpts devpts $R/dev/pts
mount -t tmpfs -o mode=1777 tmpfs $R/dev/shm
mount -t tmpfs -o mode=755 tmpfs $R/run || fail "mount a tmpfs on /run"
mkdir -p $R/run/tmp && chmod 1777 $R/run/tmp
mkdir -p "$R$SCRATCH" 2>/dev/null
mount --bind /scratch "$R$SCRATCH" || fail "bind the scratch share at $SCRATCH"
hostname cantrack-vm
ip link set lo up
ip link add dev "$CHANNEL" type vcan || fail "ip link add dev $CHANNEL type vcan"
ip link set up "$CHANNEL" || fail "ip link set up $CHANNEL"
cut -d' ' -f1 /proc/uptime > "$J/ready"
chroot $R /bin/sh "$SCRATCH/.cantrack-vm/run.sh" > "$J/stdout" 2> "$J/stderr" < /dev/null &
CPID=$!
( sleep "$TIMEOUT"; if kill -0 $CPID 2>/dev/null; then
    echo "$TIMEOUT" > "$J/timed-out"; kill -TERM $CPID; sleep 5; kill -KILL $CPID; fi ) &
wait $CPID
echo $? > "$J/rc.tmp"
cut -d' ' -f1 /proc/uptime > "$J/uptime-end"
mv "$J/rc.tmp" "$J/rc"
sync
umount "$R$SCRATCH" 2>/dev/null
umount /scratch 2>/dev/null
poweroff -f
"""


def _cpio_entry(name: str, mode: int, data: bytes = b"", ino: int = 1,
                rdev: tuple[int, int] = (0, 0)) -> bytes:
    """One 'newc' cpio record (header, name, data, 4-byte padding)."""
    nm = name.encode() + b"\0"
    hdr = "070701" + "".join(f"{v:08X}" for v in (
        ino, mode, 0, 0, 1, 0, len(data), 0, 0, rdev[0], rdev[1], len(nm), 0))
    out = hdr.encode() + nm
    out += b"\0" * (-len(out) % 4)
    out += data
    out += b"\0" * (-len(out) % 4)
    return out


def _read_module(path: Path) -> bytes:
    raw = path.read_bytes()
    name = path.name
    if name.endswith(".xz"):
        return lzma.decompress(raw)
    if name.endswith(".gz"):
        return gzip.decompress(raw)
    if name.endswith(".zst"):
        zstd = shutil.which("zstd")
        if not zstd:
            raise VmError(f"{path}: zstd-compressed module and no zstd: apt-get install zstd")
        return subprocess.run([zstd, "-dc", str(path)], capture_output=True, check=True).stdout
    return raw


def build_initramfs_bytes(busybox: Path, modules: Sequence[Path]) -> bytes:
    """An uncompressed newc initramfs: /init, /bin/busybox, /dev/console, /modules/*.ko."""
    entries = []
    ino = 100

    def add(name, mode, data=b"", rdev=(0, 0)):
        nonlocal ino
        ino += 1
        entries.append(_cpio_entry(name, mode, data, ino, rdev))

    for d in ("bin", "dev", "proc", "sys", "newroot", "scratch", "modules", "tmp"):
        add(d, 0o040755)
    add("dev/console", 0o020600, rdev=(5, 1))
    add("bin/busybox", 0o100755, busybox.read_bytes())
    add("init", 0o100755, INIT_SCRIPT.encode())
    order = []
    for i, m in enumerate(modules):
        fname = f"{i:02d}-{_mod_name(str(m))}.ko"
        add("modules/" + fname, 0o100644, _read_module(m))
        order.append(fname)
    add("modules/order", 0o100644, ("\n".join(order) + "\n").encode())
    entries.append(_cpio_entry("TRAILER!!!", 0, b"", 0))
    return b"".join(entries)


def _elf_has_pvh_note(blob: bytes) -> bool:
    """True when an ELF64 kernel has the Xen PVH entry note (XEN_ELFNOTE_PHYS32_ENTRY = 18)."""
    if blob[:4] != b"\x7fELF" or blob[4] != 2 or blob[5] != 1:
        return False
    phoff = struct.unpack_from("<Q", blob, 32)[0]
    phentsize, phnum = struct.unpack_from("<HH", blob, 54)
    for i in range(phnum):
        p_type, _flags, p_offset, _va, _pa, p_filesz = struct.unpack_from(
            "<IIQQQQ", blob, phoff + i * phentsize)
        if p_type != 4:   # PT_NOTE
            continue
        off, end = p_offset, p_offset + p_filesz
        while off + 12 <= end:
            namesz, descsz, ntype = struct.unpack_from("<III", blob, off)
            name = blob[off + 12: off + 12 + namesz].rstrip(b"\0")
            if name == b"Xen" and ntype == 18:
                return True
            off += 12 + ((namesz + 3) & ~3) + ((descsz + 3) & ~3)
    return False


def _decompress_bzimage(image: Path) -> bytes | None:
    """The ELF ``vmlinux`` inside a bzImage (xz, gzip, bzip2 or zstd payload), or None."""
    blob = image.read_bytes()
    tries = [(b"\xfd7zXZ\x00", lambda b: lzma.LZMADecompressor().decompress(b)),
             (b"\x1f\x8b\x08", lambda b: zlib.decompressobj(31).decompress(b)),
             (b"BZh", lambda b: bz2.BZ2Decompressor().decompress(b)),
             (b"\x28\xb5\x2f\xfd", _zstd_stream)]
    for magic, fn in tries:
        start = 0
        while True:
            i = blob.find(magic, start)
            if i < 0:
                break
            start = i + 1
            try:
                out = fn(blob[i:])
            except (lzma.LZMAError, zlib.error, OSError, EOFError, ValueError):
                continue   # not a real stream at this offset: keep looking
            if out and out[:4] == b"\x7fELF":
                return out
    return None


def _zstd_stream(data: bytes) -> bytes:
    zstd = shutil.which("zstd")
    if not zstd:
        return b""
    return subprocess.run([zstd, "-dc"], input=data, capture_output=True, check=False).stdout


def boot_image(kernel: KernelInfo) -> tuple[Path, str]:
    """The image qemu boots and how: the cached uncompressed ``vmlinux`` through its PVH entry
    ("pvh": no in-guest decompression, about 3 s faster under TCG), else the bzImage ("bzimage").

    ``CANTRACK_VM_PVH=0`` forces the bzImage.
    """
    if os.environ.get("CANTRACK_VM_PVH", "1") == "0":
        return kernel.image, "bzimage"
    st = kernel.image.stat()
    key = hashlib.sha256(f"{kernel.image}:{st.st_size}:{st.st_mtime_ns}".encode()).hexdigest()
    out_dir = cache_dir()
    out = out_dir / f"vmlinux-{kernel.version}-{key[:12]}"
    marker = out_dir / f"vmlinux-{kernel.version}-{key[:12]}.nopvh"
    if out.is_file():
        return out, "pvh"
    if marker.is_file():
        return kernel.image, "bzimage"
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if out.is_file():
            return out, "pvh"
        elf = _decompress_bzimage(kernel.image)
        if elf is None or not _elf_has_pvh_note(elf):
            marker.write_text("no PVH-bootable vmlinux in this image: booting the bzImage\n")
            return kernel.image, "bzimage"
        tmp = out.with_name(out.name + f".tmp{os.getpid()}")
        tmp.write_bytes(elf)
        os.replace(tmp, out)
        for old in out_dir.glob(f"vmlinux-{kernel.version}-*"):
            if old != out and not old.name.endswith(".nopvh"):
                old.unlink(missing_ok=True)
    return out, "pvh"


def cache_dir() -> Path:
    """``$CANTRACK_VM_CACHE`` or ``$XDG_CACHE_HOME/cantrack-vm`` or ``~/.cache/cantrack-vm``."""
    if os.environ.get("CANTRACK_VM_CACHE"):
        return Path(os.environ["CANTRACK_VM_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cantrack-vm"


def initramfs_path(kernel: KernelInfo | None = None) -> Path:
    """The cached initramfs for ``kernel``; built (under a file lock) when missing."""
    kernel = kernel or find_kernel()
    busybox = find_busybox()
    modules = resolve_modules(kernel)
    h = hashlib.sha256()
    h.update(f"{_FORMAT}\n{kernel.version}\n".encode())
    h.update(INIT_SCRIPT.encode())
    for p in [busybox, *modules]:
        st = p.stat()
        h.update(f"{p}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    out_dir = cache_dir()
    out = out_dir / f"initramfs-{kernel.version}-{h.hexdigest()[:12]}.cpio"
    if out.is_file():
        return out
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if out.is_file():
            return out
        blob = build_initramfs_bytes(busybox, modules)
        tmp = out.with_suffix(f".tmp{os.getpid()}")
        tmp.write_bytes(blob)
        os.replace(tmp, out)
        for old in out_dir.glob(f"initramfs-{kernel.version}-*.cpio"):
            if old != out:
                old.unlink(missing_ok=True)
    return out


# ---------------------------------------------------------------------------------------------
# availability and running

def vm_available() -> tuple[bool, str]:
    """(True, what will be used) when the VM can run here, else (False, what to install/fix)."""
    if sys.platform != "linux":
        return False, f"the VM harness needs a Linux host (this is {sys.platform})"
    missing = []
    details = []
    try:
        details.append(f"qemu {find_qemu()}")
    except VmError as exc:
        missing.append(str(exc))
    try:
        k = find_kernel()
        details.append(f"kernel {k.version}")
        try:
            resolve_modules(k)
        except VmError as exc:
            missing.append(str(exc))
    except VmError as exc:
        missing.append(str(exc))
    try:
        details.append(f"busybox {find_busybox()}")
    except VmError as exc:
        missing.append(str(exc))
    if missing:
        return False, ("no VM for vcan: " + "; ".join(missing) +
                       f" (all at once: {VM_INSTALL_HINT})")
    return True, "VM: " + ", ".join(details)


def limit_factor(env: Mapping[str, str] | None) -> float:
    """The factor a command's time limits and windows are stretched by: ``env``'s
    ``CANTRACK_SPEED_FACTOR`` when the caller chose one (it built the command's arguments
    with it), else the host's slowness measured now (:func:`controller.testing.speed.
    fresh_factor`)."""
    from .speed import ENV, MAX_FACTOR, fresh_factor
    if env and env.get(ENV):
        try:
            return min(MAX_FACTOR, max(1.0, float(env[ENV])))
        except ValueError:
            raise VmError(f"{ENV}={env[ENV]!r}: not a number") from None
    return fresh_factor()


def guest_env(env: Mapping[str, str] | None, scratch: Path, channel: str,
              speed_factor: float | None = None) -> dict[str, str]:
    """The environment of the guest command: :data:`PASSED_ENV` from the host, then ``env``,
    then the harness's own variables (``CANTRACK_SCRATCH``, ``CANTRACK_CAN_CHANNEL``,
    ``CANTRACK_SPEED_FACTOR`` = ``speed_factor`` when given, ...)."""
    out = {k: os.environ[k] for k in PASSED_ENV if k in os.environ}
    out.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin:/usr/sbin:/sbin")
    out["PYTHONDONTWRITEBYTECODE"] = "1"   # the host root is read-only in the guest
    out["PYTHONUNBUFFERED"] = "1"
    out["TMPDIR"] = "/run/tmp"
    if env:
        out.update(env)
    out["CANTRACK_SCRATCH"] = str(scratch)
    out["CANTRACK_CAN_CHANNEL"] = channel
    out["CANTRACK_VCAN_MODE"] = "vm"
    if speed_factor is not None:
        out["CANTRACK_SPEED_FACTOR"] = f"{speed_factor:.3f}"
    return out


class GuestProcess(Protocol):
    """What :func:`boot_until_ready` needs of a started VM (a ``subprocess.Popen``)."""

    returncode: int | None

    def poll(self) -> int | None: ...

    def kill(self) -> None: ...

    def wait(self, timeout: float | None = None) -> int: ...


@dataclasses.dataclass(frozen=True)
class GuestBoot:
    """A VM that booted: ``proc`` (still running, or powered off before ``ready`` when
    ``ready_s`` is None: an init failure, reported by the caller), the boot ``attempt`` (1 or
    2), ``started`` (``clock()`` when that boot was started), ``ready_s`` (seconds from there to
    the ``ready`` file) and a note per boot that hung before it (``notes``)."""

    proc: GuestProcess
    attempt: int
    started: float
    ready_s: float | None
    notes: tuple[str, ...] = ()


def _last_printed(console: str) -> str:
    """The console's last non-empty line without terminal escapes (SeaBIOS clears the
    screen), or "(nothing)"."""
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b.", "", console).replace("\r", "\n")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else "(nothing)"


def _kill(proc: GuestProcess) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def boot_until_ready(start: Callable[[int], GuestProcess], ready: Path, console: Path, *,
                     limit_s: float = READY_LIMIT_S, factor: float = 1.0,
                     attempts: int = BOOT_ATTEMPTS,
                     clock: Callable[[], float] = time.monotonic,
                     sleep: Callable[[float], object] = time.sleep,
                     poll_s: float = 0.05) -> GuestBoot:
    """Start the VM (``start(attempt)``, attempt 1, 2, ...) and wait until the guest writes its
    ``ready`` file, at most ``limit_s`` x ``factor`` (the boot limit stretched by the measured
    slowness, as the harness's other limits); a guest that has not written it by then is
    killed and booted once more (its command has not started: a retry is safe), logged and
    noted in the result.  The guest powering off before ``ready`` returns at once (the
    caller reports the init failure).

    Raises :class:`VmTimeoutError` naming the boot limit and the last line each boot's
    ``console`` printed when every attempt hung, or when ``ready`` appeared only as the VM was
    killed (the command may have started: no retry).  ``clock``/``sleep``/``poll_s``: the
    polling (a test steps them).
    """
    limit = limit_s * factor
    def sec(x: float) -> str:
        return f"{x:.1f}".rstrip("0").rstrip(".")
    how = f"{sec(limit)} s ({sec(limit_s)} s x the measured slowness {factor:.2f})"
    notes: list[str] = []
    for attempt in range(1, attempts + 1):
        proc = start(attempt)
        started = clock()
        booted: GuestBoot | None = None
        try:
            while booted is None and clock() - started < limit:
                if ready.is_file():
                    booted = GuestBoot(proc, attempt, started, clock() - started, tuple(notes))
                elif proc.poll() is not None:   # powered off: an init failure, not a hang
                    booted = GuestBoot(proc, attempt, started, None, tuple(notes))
                else:
                    sleep(poll_s)
        finally:
            if booted is None:   # hung (or KeyboardInterrupt etc.): never leave a VM behind
                _kill(proc)
        if booted is not None:
            return booted
        text = _read(console)
        if ready.is_file():
            raise VmTimeoutError(f"VM boot {attempt}: the ready file came only as the VM was "
                                 f"killed at the boot limit of {how}; its command may have "
                                 "started, so it is not booted again", console=text)
        notes.append(f"boot {attempt} of {attempts}: no ready file within the boot limit of "
                     f"{how}, the console last printed {_last_printed(text)!r}: VM killed")
        if attempt < attempts:
            _log.warning("%s; booting once more", notes[-1])
    raise VmTimeoutError(f"the VM did not boot: {attempts} boots, none wrote its ready file "
                         f"within the boot limit of {how} (" + "; ".join(notes) + ")",
                         console=_read(console))


def run_in_vm(argv: Sequence[str], timeout_s: float = 120.0, env: Mapping[str, str] | None = None,
              *, cwd: str | Path | None = None, scratch_dir: str | Path | None = None,
              channel: str = DEFAULT_CHANNEL, memory_mb: int = 1024, smp: int = 2,
              boot_timeout_s: float = 90.0, ready_timeout_s: float = READY_LIMIT_S) -> VmResult:
    """Boot the VM, run ``argv`` on a real SocketCAN ``channel`` (``vcan0``), power off.

    ``argv`` uses host paths (the guest sees the host's ``/`` read-only); the command runs as
    root in the guest, in ``cwd`` (default: the current directory), with the environment of
    :func:`guest_env` (``PATH``, ``PYTHONPATH``, ... from the host, then ``env``).
    ``scratch_dir``: the writable directory shared with the guest at the same path and passed as
    ``$CANTRACK_SCRATCH`` (created with ``tempfile.mkdtemp`` when None; the caller removes it).

    ``timeout_s`` limits the command (seconds, guest time): past it the guest's init sends
    SIGTERM (SIGKILL 5 s later), the result has ``timed_out=True``.  ``ready_timeout_s``
    limits the boot until the guest's ``ready`` file: a guest that hangs before it is killed
    and booted once more (:func:`boot_until_ready`; ``boot_attempts``/``boot_notes`` of the
    result, logged), :class:`VmTimeoutError` when the second boot hangs too.
    ``boot_timeout_s`` is added to the command's limit for booting and powering off; past
    both (from the start of the boot that ran the command), qemu is killed and
    :class:`VmTimeoutError` raised.  All three are stretched by :func:`limit_factor`, which
    the command gets in ``CANTRACK_SPEED_FACTOR``.  :class:`VmError` when the guest powered off
    without an exit code (boot or init failure; the message ends with the guest console's last
    lines).
    """
    if not argv:
        raise VmError("run_in_vm: empty argv")
    # (limits, not waits: stretched by the host's slowness measured now, so that a busy
    #  machine does not time a healthy guest out; the guest gets the same factor for its
    #  real-time windows)
    factor = limit_factor(env)
    timeout_s, boot_timeout_s = timeout_s * factor, boot_timeout_s * factor
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,15}", channel):
        raise VmError(f"run_in_vm: channel {channel!r} is not an interface name "
                      "(1-15 characters of A-Z a-z 0-9 _ . -)")
    kernel = find_kernel()
    initrd = initramfs_path(kernel)
    image, _how = boot_image(kernel)
    qemu = find_qemu()
    scratch = Path(scratch_dir) if scratch_dir is not None else Path(
        tempfile.mkdtemp(prefix="cantrack-vm-"))
    scratch.mkdir(parents=True, exist_ok=True)
    scratch = scratch.resolve()
    jd = scratch / JOB_DIR
    if jd.exists():
        shutil.rmtree(jd)
    jd.mkdir(parents=True)
    cwd = Path(cwd).resolve() if cwd is not None else Path.cwd()
    genv = guest_env(env, scratch, channel, factor)
    run_sh = ["#!/bin/sh", f"cd {shlex.quote(str(cwd))} || exit 125",
              "exec /usr/bin/env -i " + " ".join(shlex.quote(f"{k}={v}") for k, v in genv.items())
              + " " + " ".join(shlex.quote(str(a)) for a in argv)]
    (jd / "run.sh").write_text("\n".join(run_sh) + "\n")
    root_cache = os.environ.get("CANTRACK_VM_ROOT_CACHE", "loose")
    (jd / "job").write_text(f"SCRATCH={shlex.quote(str(scratch))}\nCHANNEL={channel}\n"
                            f"ROOT_CACHE={shlex.quote(root_cache)}\n"
                            f"TIMEOUT={max(1, round(timeout_s))}\n")
    cmd = qemu_command(qemu, image, initrd, scratch, memory_mb=memory_mb, smp=smp)
    console_path = jd / "console.log"
    m0 = time.monotonic()
    starts: list[float] = []

    def start(attempt: int) -> subprocess.Popen:
        for name in _BOOT_FILES:
            (jd / name).unlink(missing_ok=True)
        if attempt > 1:   # (the hung boot's console kept beside the new one)
            console_path.replace(jd / f"console-{attempt - 1}.log")
        starts.append(time.time())
        with open(console_path, "wb") as console_f:
            return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=console_f,
                                    stderr=subprocess.STDOUT, start_new_session=True)

    boot = boot_until_ready(start, jd / "ready", console_path, limit_s=ready_timeout_s,
                            factor=factor)
    proc = boot.proc
    t0 = starts[-1]
    whole = timeout_s + boot_timeout_s
    try:
        proc.wait(timeout=max(0.0, whole - (time.monotonic() - boot.started)))
    except subprocess.TimeoutExpired:
        _kill(proc)
        raise VmTimeoutError(
            f"VM still running after {whole:.0f} s (command limit {timeout_s:.0f} s + boot "
            f"{boot_timeout_s:.0f} s): qemu killed; scratch "
            f"{scratch}\n--- stdout (tail) ---\n{_read(jd / 'stdout')[-2000:]}\n"
            f"--- stderr (tail) ---\n{_read(jd / 'stderr')[-2000:]}",
            console=_read(console_path), scratch_dir=scratch) from None
    finally:
        _kill(proc)   # KeyboardInterrupt etc.: never leave a VM behind
    wall = time.monotonic() - m0
    console = _read(console_path)
    rc_file = jd / "rc"
    if not rc_file.is_file():
        err = _read(jd / "init-error").strip()
        raise VmError(f"VM powered off without an exit code (qemu exit {proc.returncode}"
                      f"{'; init: ' + err if err else ''}; scratch {scratch})",
                      console=console, scratch_dir=scratch)
    boot_s = command_s = None
    ready = jd / "ready"
    if ready.is_file():
        boot_s = max(0.0, ready.stat().st_mtime - t0)
        command_s = max(0.0, rc_file.stat().st_mtime - ready.stat().st_mtime)
    return VmResult(returncode=int(_read(rc_file).strip() or 255), stdout=_read(jd / "stdout"),
                    stderr=_read(jd / "stderr"), scratch_dir=scratch, mode="vm",
                    boot_s=boot_s, command_s=command_s, wall_s=wall, console=console,
                    channel=channel, timed_out=(jd / "timed-out").is_file(),
                    speed_factor=factor, boot_attempts=boot.attempt, boot_notes=boot.notes)


def qemu_command(qemu: Path, image: Path, initrd: Path, scratch: Path, *, memory_mb: int = 1024,
                 smp: int = 2) -> list[str]:
    """The qemu command line (TCG; ``CANTRACK_VM_ACCEL``, ``CANTRACK_VM_CPU``,
    ``CANTRACK_VM_BIOS``, ``CANTRACK_VM_APPEND`` override accelerator, CPU, firmware and
    kernel command line)."""
    accel = os.environ.get("CANTRACK_VM_ACCEL", "tcg,thread=multi")
    bios = os.environ.get("CANTRACK_VM_BIOS")
    return [str(qemu), "-accel", accel, "-cpu", os.environ.get("CANTRACK_VM_CPU", "max"),
            "-m", str(memory_mb), "-smp", str(smp), "-nographic", "-no-reboot",
            "-no-user-config", *(["-bios", bios] if bios else []),
            "-kernel", str(image), "-initrd", str(initrd),
            "-append", os.environ.get("CANTRACK_VM_APPEND", KERNEL_CMDLINE),
            "-virtfs", ("local,path=/,mount_tag=hostroot,security_model=passthrough,"
                        "readonly=on,multidevs=remap"),
            "-virtfs", (f"local,path={scratch},mount_tag=scratch,security_model=none,"
                        "multidevs=remap"),
            "-nic", "none"]


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""
