"""Independent FMI importers for the test tiers: the Modelica Association's ``fmusim`` (FMI 2
and 3, from the Reference-FMUs sources) and the Modelica tools' FMU Compliance Checker
``fmuCheck`` (FMI 1 and 2, on FMI Library), built from their source archives with
gcc/cmake/make (never part of the product).

The sources are found like the CANopen stack's (:mod:`controller.testing.vendor`): in
``$CANTRACK_VENDOR_DIR`` (default ``../shared/vendor`` relative to the repository), as the
upstream ``git archive`` snapshots

- ``Reference-FMUs-<rev>.tar.gz`` (the last revision that still has ``fmusim/``),
- ``FMUComplianceChecker-<rev>.tar.gz`` and ``fmi-library-<version>.tar.gz``,
- ``zlib-<version>.tar.gz`` (minizip and zlib for fmusim),
- ``sundials-<version>.tar.gz`` (CVODE: fmusim links it even for co-simulation),

plus ``libxml2`` from the system (``libxml2-dev``).  The build (about 2 min of wall time on a
busy 2-core machine, mostly FMI Library) goes to the same cache as the CANopen stack
(``$CANTRACK_VENDOR_CACHE``), one directory per content hash of the archives.

How it is put together (the upstream build systems' quirks with a current gcc/cmake):

- fmusim: its CMake project expects prebuilt dependencies under ``build/``; instead CVODE is
  built with cmake (static, CVODE only) and fmusim's sources, zlib's and minizip's are
  compiled with one gcc command against the system libxml2;
- FMI Library's cmake needs ``CMAKE_POLICY_VERSION_MINIMUM=3.5`` (cmake >= 4), ``-fcommon``
  (gcc >= 10), and loses an ``add_dependencies`` on files (an error since CMP0046); its
  static "merged" library reads the LOCATION property (an error since cmake 4), so it is
  built as a shared library and the checker is linked with the static sub-libraries built
  on the way (``libfmiimport.a`` & co.);
- the Compliance Checker's own cmake clones FMI Library with git: its nine C files are
  compiled with gcc instead (``fmu_checker_version.h`` written by hand).
"""

from __future__ import annotations

import fcntl
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from .vendor import (VENDOR_ENV, VendorError, build_slot, find_archives, run_logged, unpack,
                     vendor_dir)

ARCHIVES = ("Reference-FMUs", "FMUComplianceChecker", "fmi-library", "zlib", "sundials")
TOOLS = ("gcc", "cmake", "make")
LIBXML2_HEADER = Path("/usr/include/libxml2/libxml/parser.h")
#: zlib's own sources (compiled into fmusim with minizip)
_ZLIB_SOURCES = ("adler32", "compress", "crc32", "deflate", "gzclose", "gzlib", "gzread",
                 "gzwrite", "infback", "inffast", "inflate", "inftrees", "trees", "uncompr",
                 "zutil")
#: FMI Library's static sub-libraries the checker links (order matters for the linker)
_FMIL_LIBS = ("libfmiimport.a", "libfmixml.a", "libfmicapi.a", "libfmizip.a",
              "Config.cmake/Minizip/libminizip.a", "zlib/libz.a",
              "ExpatEx/install/lib/libexpat.a", "libjmutils.a",
              "ThirdParty/c99_snprintf/libc99snprintf.a")


@dataclass(frozen=True)
class FmiTools:
    """The built importers (absolute paths)."""

    root: Path
    fmusim: Path
    fmu_check: Path
    #: the archives' names, e.g. ``Reference-FMUs-c8d4e6d90f``
    versions: tuple[str, ...]
    #: wall time of the build [s] (0 when it came from the cache)
    build_s: float = 0.0


def archives(directory: Path | None = None) -> dict[str, Path | None]:
    """The importers' archives."""
    return find_archives(ARCHIVES, directory)


def tools_available(directory: Path | None = None) -> tuple[bool, str]:
    """(True, the archives) or (False, what is missing and how to provide it)."""
    d = directory if directory is not None else vendor_dir()
    missing = [n for n, p in archives(d).items() if p is None]
    if missing:
        names = ", ".join(m + "-*.tar.gz" for m in missing)
        return False, (f"independent FMI importers: no {names} in {d} (set {VENDOR_ENV} to "
                       "the directory with the Reference-FMUs, FMUComplianceChecker, "
                       "fmi-library, zlib and sundials source archives)")
    tools = [t for t in TOOLS if shutil.which(t) is None]
    if tools:
        return False, f"independent FMI importers: {', '.join(tools)} not installed"
    if not LIBXML2_HEADER.is_file():
        return False, ("independent FMI importers: libxml2 headers missing "
                       f"({LIBXML2_HEADER}; apt-get install libxml2-dev)")
    return True, ", ".join(p.name for p in archives(d).values() if p is not None)


def _run(args: list[str], cwd: Path, log: Path, env: dict[str, str] | None = None) -> None:
    run_logged(args, cwd, log, "the independent FMI importers", env)


def _source_root(into: Path) -> Path:
    """The unpacked tree (descending into a single top-level folder if there is one)."""
    entries = list(into.iterdir())
    return entries[0] if len(entries) == 1 and entries[0].is_dir() else into


def _tools(root: Path, versions: tuple[str, ...], build_s: float = 0.0) -> FmiTools:
    return FmiTools(root, root / "bin" / "fmusim", root / "bin" / "fmuCheck.linux64", versions,
                    build_s)


def _build_fmusim(src: dict[str, Path], work: Path, log: Path) -> Path:
    cvode_build, cvode = work / "cvode-build", work / "cvode-install"
    _run(["cmake", "-S", str(src["sundials"]), "-B", str(cvode_build),
          "-DCMAKE_BUILD_TYPE=Release", "-DBUILD_SHARED_LIBS=OFF", "-DBUILD_STATIC_LIBS=ON",
          "-DBUILD_TESTING=OFF", "-DEXAMPLES_INSTALL=OFF", "-DEXAMPLES_ENABLE_C=OFF",
          "-DBUILD_ARKODE=OFF", "-DBUILD_CVODES=OFF", "-DBUILD_IDA=OFF", "-DBUILD_IDAS=OFF",
          "-DBUILD_KINSOL=OFF", "-DSUNDIALS_ENABLE_ERROR_CHECKS=OFF",
          f"-DCMAKE_INSTALL_PREFIX={cvode}"], work, log)
    _run(["cmake", "--build", str(cvode_build), "-j2", "--target", "install"], work, log)
    ref, zlib = src["Reference-FMUs"], src["zlib"]
    minizip = zlib / "contrib" / "minizip"
    out = work / "bin" / "fmusim"
    out.parent.mkdir(parents=True, exist_ok=True)
    sources = sorted(str(p) for p in (ref / "fmusim").glob("*.c"))
    sources += [str(ref / "src" / f) for f in ("FMI.c", "FMI1.c", "FMI2.c", "FMI3.c",
                                              "structured_variable_name.yy.c",
                                              "structured_variable_name.tab.c")]
    sources += [str(minizip / "ioapi.c"), str(minizip / "unzip.c")]
    sources += [str(zlib / f"{n}.c") for n in _ZLIB_SOURCES]
    _run(["gcc", "-O1", "-w", "-o", str(out), '-DFMUSIM_VERSION="vendor"', "-DLIBXML_STATIC",
          f"-I{ref / 'fmusim'}", f"-I{ref / 'include'}", "-I/usr/include/libxml2",
          f"-I{zlib}", f"-I{minizip}", f"-I{cvode / 'include'}", *sources,
          str(cvode / "lib" / "libsundials_cvode.a"), str(cvode / "lib" / "libsundials_core.a"),
          "-lxml2", "-ldl", "-lm"], work, log)
    return out


def _build_checker(src: dict[str, Path], work: Path, log: Path) -> Path:
    fmil_src = src["fmi-library"]
    xml = fmil_src / "Config.cmake" / "fmixml.cmake"
    text = xml.read_text()
    xml.write_text("\n".join(line for line in text.splitlines()
                             if not line.startswith("add_dependencies(expatex ${CMAKE_BINARY_DIR}"))
                   + "\n")
    build, install = work / "fmil-build", work / "fmil-install"
    env = {"CMAKE_POLICY_VERSION_MINIMUM": "3.5", "CFLAGS": "-fcommon"}
    _run(["cmake", "-S", str(fmil_src), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release",
          f"-DFMILIB_INSTALL_PREFIX={install}", "-DFMILIB_BUILD_STATIC_LIB=OFF",
          "-DFMILIB_BUILD_SHARED_LIB=ON", "-DFMILIB_BUILD_TESTS=OFF",
          "-DFMILIB_GENERATE_DOXYGEN_DOC=OFF",
          f"-DFMILIB_FMI_STANDARD_HEADERS={fmil_src / 'ThirdParty' / 'FMI' / 'default'}"],
         work, log, env)
    _run(["cmake", "--build", str(build), "-j2", "--target", "install"], work, log, env)
    checker = src["FMUComplianceChecker"]
    generated = work / "checker-generated"
    generated.mkdir()
    (generated / "fmu_checker_version.h").write_text(
        f'#define FMUCHK_VERSION "{checker.name}"\n#define FMIL_VERSION "{fmil_src.name}"\n')
    out = work / "bin" / "fmuCheck.linux64"
    sources = [str(checker / "src" / "Common" / "fmuChecker.c")]
    sources += sorted(str(p) for d in ("FMI1", "FMI2") for p in (checker / "src" / d).glob("*.c"))
    _run(["gcc", "-O1", "-w", "-fcommon", f"-I{install / 'include'}", f"-I{checker / 'include'}",
          f"-I{generated}", "-o", str(out), *sources, *[str(build / lib) for lib in _FMIL_LIBS],
          "-ldl"], work, log)
    return out


def build_tools(directory: Path | None = None, cache: Path | None = None) -> FmiTools:
    """Build fmusim and fmuCheck (or reuse the cached build)."""
    d = directory if directory is not None else vendor_dir()
    ok, why = tools_available(d)
    if not ok:
        raise VendorError(why)
    found = archives(d)
    base, root, versions = build_slot(found, "fmi", cache)
    with (base / ".lock-fmi").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one build at a time (parallel test sessions)
        if (root / "done").is_file():
            return _tools(root, versions)
        t0 = time.monotonic()
        work = Path(tempfile.mkdtemp(prefix="build-fmi-", dir=base))
        try:
            log = work / "build.log"
            src = {}
            for name in ARCHIVES:
                archive = found[name]
                assert archive is not None
                unpack(archive, work / "src" / name)
                src[name] = _source_root(work / "src" / name)
            _build_fmusim(src, work, log)
            _build_checker(src, work, log)
            built = _tools(work, versions)
            for p in (built.fmusim, built.fmu_check):
                if not p.is_file():
                    raise VendorError(f"building the independent FMI importers: {p} missing "
                                      "after the build")
            build_s = time.monotonic() - t0
            (work / "done").write_text("\n".join(versions) + f"\nbuild {build_s:.1f} s\n")
            shutil.rmtree(work / "src", ignore_errors=True)
            for tmp in ("cvode-build", "fmil-build"):  # the programs are linked statically
                shutil.rmtree(work / tmp, ignore_errors=True)
            if root.exists():
                shutil.rmtree(root)
            work.rename(root)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    return _tools(root, versions, build_s)
