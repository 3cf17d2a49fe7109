"""Independent CANopen implementations for the test tiers: CANopenNode, CANopenLinux and
CANopenDemo, built from their source archives with gcc/make (never part of the product).

The sources are found through ``$CANTRACK_VENDOR_DIR`` (default: ``../shared/vendor``
relative to the repository).  That directory holds the upstream ``git archive`` snapshots:

- ``CANopenNode-<rev>.tar.gz`` (the stack, CiA 301 slave and simple master),
- ``CANopenLinux-<rev>.tar.gz`` (``canopend``: a Linux CANopen device on SocketCAN, and
  ``cocomm``: a command-line SDO/NMT client talking to canopend's command socket),
- ``CANopenDemo-<rev>.tar.gz`` (``demoLinuxDevice``: a CiA 401 style I/O device with 1008h
  and objects long enough for segmented SDO).

The build (a few seconds) goes to ``$CANTRACK_VENDOR_CACHE`` (default
``$XDG_CACHE_HOME/cantrack-vendor`` or ``~/.cache/cantrack-vendor``), one directory per
content hash of the three archives, so a second run reuses it and a new snapshot rebuilds.
How the build is put together (the upstream Makefiles' quirks):

- CANopenNode is a git submodule of CANopenLinux: it is unpacked into
  ``CANopenLinux/CANopenNode``;  ``make`` there builds ``canopend``, ``make -C cocomm``
  builds ``cocomm``;
- ``CANopenDemo/demo`` expects ``CANopenLinux`` beside it (a symbolic link), wants
  ``GIT_VERSION=...`` on the command line (it is no git checkout), and its ``all: clean``
  target removes CANopenLinux's object files: so it is built after canopend, without ``-j``.

:func:`stack_available` says whether the sources are there (and why not); :func:`build_stack`
builds (or finds in the cache) and returns the :class:`CanopenStack`.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

#: environment variable naming the directory with the source archives
VENDOR_ENV = "CANTRACK_VENDOR_DIR"
#: environment variable naming the build cache
CACHE_ENV = "CANTRACK_VENDOR_CACHE"
REPO_ROOT = Path(__file__).resolve().parents[2]
ARCHIVES = ("CANopenNode", "CANopenLinux", "CANopenDemo")
TOOLS = ("gcc", "make")


class VendorError(RuntimeError):
    """The sources are missing or the build failed (the message has the build log's tail)."""


@dataclass(frozen=True)
class CanopenStack:
    """The built programs (absolute paths) and the demo device's EDS."""

    root: Path
    canopend: Path
    cocomm: Path
    demo_device: Path
    demo_eds: Path
    #: the archives' names, e.g. ``CANopenNode-ef9ac3a``
    versions: tuple[str, ...]

    #: the demo device's node-ID when none is given (CO_NODE_ID_INITIAL of CANopenDemo)
    DEMO_NODE_ID = 4


def vendor_dir() -> Path:
    """``$CANTRACK_VENDOR_DIR``, else ``../shared/vendor`` relative to the repository (or to
    the nearest parent directory that has one: a git worktree lives deeper than its main
    checkout)."""
    env = os.environ.get(VENDOR_ENV)
    if env:
        return Path(env).expanduser().resolve()
    default = (REPO_ROOT.parent / "shared" / "vendor").resolve()
    for parent in REPO_ROOT.parents:
        candidate = parent / "shared" / "vendor"
        if candidate.is_dir():
            return candidate.resolve()
    return default


def cache_dir() -> Path:
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "cantrack-vendor"


def find_archive(directory: Path, name: str) -> Path | None:
    """The newest ``<name>-*.tar.gz`` in ``directory`` (by name), or None."""
    found = sorted(directory.glob(f"{name}-*.tar.gz"))
    return found[-1] if found else None


def find_archives(names: tuple[str, ...], directory: Path | None = None) -> dict[str, Path | None]:
    """Each of ``names`` to its archive in ``directory`` (default :func:`vendor_dir`)."""
    d = directory if directory is not None else vendor_dir()
    return {n: find_archive(d, n) for n in names}


def archives(directory: Path | None = None) -> dict[str, Path | None]:
    """The CANopen stack's archives."""
    return find_archives(ARCHIVES, directory)


def stack_available(directory: Path | None = None) -> tuple[bool, str]:
    """(True, the archives) or (False, what is missing and how to provide it)."""
    d = directory if directory is not None else vendor_dir()
    missing = [n for n, p in archives(d).items() if p is None]
    if missing:
        return False, (f"independent CANopen stack: no {', '.join(m + '-*.tar.gz' for m in missing)}"
                       f" in {d} (set {VENDOR_ENV} to the directory with the CANopenNode, "
                       "CANopenLinux and CANopenDemo source archives)")
    tools = [t for t in TOOLS if shutil.which(t) is None]
    if tools:
        return False, f"independent CANopen stack: {', '.join(tools)} not installed"
    return True, ", ".join(p.name for p in archives(d).values() if p is not None)


def content_key(paths: list[Path]) -> str:
    """Content hash of the archives (the name of their build's cache directory)."""
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:16]


def stack_at(root: Path, versions: tuple[str, ...]) -> CanopenStack:
    linux = root / "CANopenLinux"
    demo = root / "CANopenDemo" / "demo"
    return CanopenStack(root, linux / "canopend", linux / "cocomm" / "cocomm",
                        demo / "demoLinuxDevice", demo / "demoDevice.eds", versions)


def run_logged(args: list[str], cwd: Path, log: Path, what: str,
               env: dict[str, str] | None = None) -> None:
    """Run one build step with its output appended to ``log``; a failure is a
    :class:`VendorError` naming ``what`` was being built, the command and the log's tail."""
    with log.open("ab") as f:
        f.write(f"\n$ {' '.join(args)}  (in {cwd})\n".encode())
        f.flush()
        r = subprocess.run(args, cwd=cwd, stdout=f, stderr=subprocess.STDOUT, check=False,
                           env={**os.environ, **(env or {})})
    if r.returncode != 0:
        tail = log.read_text(errors="replace")[-3000:]
        raise VendorError(f"building {what} failed: {' '.join(args)} "
                          f"in {cwd} exited with {r.returncode}\n{tail}")


def _make(args: list[str], cwd: Path, log: Path) -> None:
    run_logged(args, cwd, log, "the independent CANopen stack")


def unpack(archive: Path, into: Path, strip_top: bool = False) -> None:
    """Unpack ``archive`` into ``into`` (without its top-level folder if ``strip_top``)."""
    into.mkdir(parents=True, exist_ok=True)
    with tarfile.open(archive) as tf:
        members = tf.getmembers()
        if strip_top:
            for m in members:
                parts = Path(m.name).parts
                m.name = str(Path(*parts[1:])) if len(parts) > 1 else ""
            members = [m for m in members if m.name]
        tf.extractall(into, members=members, filter="tar")


def build_slot(found: dict[str, Path | None], prefix: str,
               cache: Path | None = None) -> tuple[Path, Path, tuple[str, ...]]:
    """Where the build of the ``found`` archives goes: (the cache, ``<prefix>-<content key>``
    in it, the archives' names without ``.tar.gz``); the cache is made if missing."""
    paths = [p for p in found.values() if p is not None]
    versions = tuple(p.name.removesuffix(".tar.gz") for p in paths)
    base = cache if cache is not None else cache_dir()
    base.mkdir(parents=True, exist_ok=True)
    return base, base / f"{prefix}-{content_key(paths)}", versions


def build_stack(directory: Path | None = None, cache: Path | None = None) -> CanopenStack:
    """Build canopend, cocomm and demoLinuxDevice (or reuse the cached build)."""
    d = directory if directory is not None else vendor_dir()
    ok, why = stack_available(d)
    if not ok:
        raise VendorError(why)
    found = archives(d)
    base, root, versions = build_slot(found, "canopen", cache)
    stack = stack_at(root, versions)
    with (base / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one build at a time (parallel test sessions)
        if (root / "done").is_file():
            return stack
        work = Path(tempfile.mkdtemp(prefix="build-", dir=base))
        try:
            log = work / "build.log"
            linux = work / "CANopenLinux"
            for name, target, strip in (("CANopenLinux", work, False),
                                        ("CANopenNode", linux / "CANopenNode", True),
                                        ("CANopenDemo", work, False)):
                archive = found[name]
                assert archive is not None
                unpack(archive, target, strip)
            _make(["make"], linux, log)
            _make(["make", "-C", "cocomm"], linux, log)
            demo = work / "CANopenDemo" / "demo"
            link = work / "CANopenDemo" / "CANopenLinux"
            if not link.exists():
                link.symlink_to("../CANopenLinux")
            _make(["make", f"GIT_VERSION={versions[ARCHIVES.index('CANopenDemo')]}"], demo, log)
            built = stack_at(work, versions)
            for p in (built.canopend, built.cocomm, built.demo_device, built.demo_eds):
                if not p.is_file():
                    raise VendorError(f"building the independent CANopen stack: {p} missing "
                                      "after the build")
            (work / "done").write_text("\n".join(versions) + "\n")
            if root.exists():
                shutil.rmtree(root)
            work.rename(root)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    return stack
