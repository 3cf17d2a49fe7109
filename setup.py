"""Build of the compiled tracking core (docs/architecture.md "Compiled core").

``pip install .`` and ``pip install -e .`` compile the modules of ``controller/tracking`` (all
but ``PURE_ONLY``; and of the other ``PACKAGES``, and the single ``MODULES``) with mypyc: the
same source, checked by mypy and turned into C extension modules, about 1.6x faster in the
cycle's hot path.  Everything else (metadata, packages,
package data) is in pyproject.toml.

- ``CANTRACK_NO_EXTENSIONS=1`` (a boolean: unset, "", "0", "false", "no", "off" are off)
  skips the compile: the pure package is installed (and, for an editable install, the
  in-place build an earlier one left is removed, so that it cannot run instead).
- A compile that fails (no C compiler or Python headers, mypyc missing or refusing the
  source) is not a failed install: the pure package is installed and a warning says why.
  (mypy itself is a [build-system] requirement, installed before this file runs: offline
  without it an isolated build fails whatever CANTRACK_NO_EXTENSIONS says; use
  ``pip install --no-build-isolation``, docs/architecture.md "Compiled core".)
- The build records the SHA-256 of each compiled source in ``controller/tracking/
  _native_manifest.json``; at import the package runs the compiled modules only while every
  source still has its recorded hash (controller/tracking/__init__.py: the stale build guard).
- An editable install whose in-place build is up to date is not compiled again (``pip install
  -e .`` twice: the second is not another compile): the manifest also records what else the
  compile depends on, and ``_in_place_build_stale`` compares it all (see there).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import sysconfig
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext

HERE = Path(__file__).resolve().parent
CONTROLLER = HERE / "controller"
TRACKING = CONTROLLER / "tracking"
#: the compiled packages (directories of ``controller/``): the cycle's per-sample path
#: (tracking core, conveyor model, kinematics) and the simulated devices' per-SYNC path
#: (the slave-node engine, the drive, the encoder, the rack), one group so that their calls
#: stay native
PACKAGES = ("tracking", "conveyor", "conveyor/frames", "kinematics", "canopen/slave")
#: single compiled modules of packages that otherwise stay Python (docs/architecture.md
#: "Compiled core"): the demo's setpoint source, the encoder's and the drives' cycle I/O
MODULES = ("canopen/apps/demo.py", "canopen/master/masterio.py", "canopen/master/axisio.py")
MANIFEST = "_native_manifest.json"
#: the mypyc group: one shared library ``controller/tracking/_core__mypyc.*.so`` beside the
#: modules' small import shims
GROUP = "controller.tracking._core"
#: mypy's settings for the compile (not pyproject's [tool.mypy]: its warn_unused_configs makes
#: mypyc exit 1 over the sections of the modules that are not compiled).  numpy and ruckig
#: are never read (``Any`` to mypyc): the same C code whether or not the build environment
#: can see them (pip's isolated build may or may not; with numpy's stubs missing mypy would
#: refuse the source)
MYPYC_INI = """\
[mypy]
no_implicit_optional = True
[mypy-numpy,numpy.*,ruckig,ruckig.*,can,can.*,canopen,canopen.*]
follow_imports = skip
ignore_missing_imports = True
[mypy-controller.canopen,controller.canopen.*]
follow_imports = skip
"""
# (the last section: what MODULES import from the CANopen shell is Any to the C code, which so
#  depends on none of those modules: _read_modules has none of them)


def _warn(message: str) -> None:
    bar = "*" * 78
    print(f"\n{bar}\ncantrack: {message}\n"
          f"cantrack: installing the pure-Python tracking core (same results, slower)\n{bar}\n",
          file=sys.stderr)


#: not compiled (besides the packages' ``__init__.py``: tracking's chooses compiled or pure):
#: the two numpy-array modules off the per-sample path (batch stepping, trace metrics), where
#: mypyc gains nothing, and the conveyor's exceptions (mypyc cannot subclass builtins)
#: Of the simulated devices what is not on their per-SYNC path: the controller's own PLC
#: node, the simulated bus's wiring (its logger and recorder endpoints) and the SDO server
#: (it subclasses python canopen's classes, which the compile does not read).
PURE_ONLY = {"tracking/batch.py", "tracking/metrics.py", "conveyor/errors.py",
             "canopen/slave/plc.py", "canopen/slave/sdo_server.py", "canopen/slave/world.py"}


def _sources() -> list[Path]:
    return sorted([p for package in PACKAGES for p in (CONTROLLER / package).glob("*.py")
                   if p.name != "__init__.py" and _name(p) not in PURE_ONLY]
                  + [CONTROLLER / m for m in MODULES])


def _name(path: Path) -> str:
    """A module's path relative to ``controller/`` (``conveyor/frames/linear.py``): its name
    in ``PURE_ONLY`` and the manifest."""
    return path.relative_to(CONTROLLER).as_posix()


def _remove_build(root: Path = CONTROLLER) -> None:
    """The compiled files and the manifest a build left under ``root`` (the ``controller``
    directory; by default the checkout's, which an earlier in-place (editable) build left)."""
    for package in PACKAGES:
        directory = root / package
        for path in list(directory.glob("*.so")) + list(directory.glob("*.pyd")) + \
                [directory / MANIFEST]:
            if path.exists():
                path.unlink()
    for module in MODULES:  # (only the module's own: its package's others are Python)
        stem = root / module[:-3]
        for path in list(stem.parent.glob(stem.name + ".*.so")) + \
                list(stem.parent.glob(stem.name + ".*.pyd")):
            path.unlink()


def _write_manifest(directory: Path, record: dict | None = None) -> None:
    """The manifest of a build from the checkout as it is now (``record``: by default
    :func:`_build_record`): what the stale build guard at import and the next editable
    install's up-to-date check read."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / MANIFEST).write_text(json.dumps(
        _build_record() if record is None else record, indent=1, sort_keys=True) + "\n")


#: mypycify's options for the compile (recorded: another value is another build)
MYPYC_OPTIONS = {"opt_level": "3", "debug_level": "0", "group_name": GROUP}
#: the environment variables that change the C compile and link (setuptools' compiler reads
#: CC, CFLAGS & co.; mypyc's MYPYC_NO_EXTRA_FLAGS drops its own flags)
COMPILE_ENV = ("CC", "CXX", "CFLAGS", "CPPFLAGS", "LDFLAGS", "LDSHARED", "ARCHFLAGS",
               "MYPYC_NO_EXTRA_FLAGS")


def _read_modules() -> list[Path]:
    """The modules mypy reads beside the compiled ones (the C code builds in their types):
    the compiled packages' pure modules and the base layer, the only other one they import
    (docs/architecture.md "Layers": ``controller/*.py``)."""
    compiled = set(_sources())
    # (not the simulated devices' pure modules: mypy does not read controller.canopen)
    return sorted({p for package in PACKAGES for p in (CONTROLLER / package).glob("*.py")
                   if p not in compiled and not package.startswith("canopen/")}
                  | set(CONTROLLER.glob("*.py")))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _mypy_version() -> str | None:
    """The version of the mypy (mypyc) that compiles, None without one."""
    try:
        from mypy.version import __version__
    except ImportError:
        return None
    return str(__version__)


def _build_record(mypy_version: str | None = None) -> dict:
    """What a compile of the checkout as it is now depends on, as the manifest records it:
    ``sources`` (compiled module -> SHA-256 of its source; the stale build guard at import
    reads these) and ``build``: the Python (``sys.version``: version and build, and the
    extension suffix: the C API and ABI compiled against), the mypy version (by default the
    one this build imports), the compile flags (mypycify's options, the mypy settings
    ``MYPYC_INI``, the ``COMPILE_ENV`` variables) and the SHA-256 of the modules mypy reads
    beside the compiled ones (``_read_modules``)."""
    return {
        "group": GROUP,
        "sources": {_name(p): _sha256(p) for p in _sources()},
        "build": {
            "python": sys.version,
            "ext_suffix": sysconfig.get_config_var("EXT_SUFFIX"),
            "mypy": _mypy_version() if mypy_version is None else mypy_version,
            "flags": {"mypycify": MYPYC_OPTIONS, "mypy_ini": MYPYC_INI,
                      "env": {k: os.environ.get(k) for k in COMPILE_ENV}},
            "read": {p.relative_to(HERE).as_posix(): _sha256(p) for p in _read_modules()},
        },
    }


def _in_place_build_stale(directory: Path, record: dict) -> str | None:
    """Why the compiled build in ``directory`` (an editable install's, in place) is not the
    build ``record`` (:func:`_build_record`) describes, or None when it is: skip the compile.

    Compared: the manifest's group, every compiled source's SHA-256 (the same modules, none
    added or removed), the Python version and build and its extension suffix, the mypy
    version, the compile flags, the SHA-256 of the modules mypy reads beside them, and that
    the group's shared library and every module's extension file (with the recorded suffix)
    exist.  A manifest of an older setup.py, without the ``build`` part, is stale."""
    try:
        built = json.loads((directory / MANIFEST).read_text())
    except (OSError, ValueError) as exc:
        return f"no usable {MANIFEST} ({type(exc).__name__})"
    if not isinstance(built, dict):
        return f"{MANIFEST} is not a build record"
    if built.get("group") != record["group"]:
        return f"the mypyc group differs ({built.get('group')!r})"
    then, now = built.get("sources") or {}, record["sources"]
    for name in sorted(set(then) | set(now)):
        if name not in then:
            return f"{name}: not compiled in the last build"
        if name not in now:
            return f"{name}: compiled in the last build, not a compiled module now"
        if then[name] != now[name]:
            return f"{name}: changed since the last build"
    build = built.get("build")
    if not isinstance(build, dict):
        return f"{MANIFEST} records no build (written by an older setup.py)"
    for key, what in (("python", "the Python"), ("ext_suffix", "the extension suffix"),
                      ("mypy", "the mypy version"), ("flags", "the compile flags")):
        if build.get(key) != record["build"][key]:
            return f"{what} changed (last build {build.get(key)!r}, now {record['build'][key]!r})"
    then, now = build.get("read") or {}, record["build"]["read"]
    for name in sorted(set(then) | set(now)):
        if then.get(name) != now.get(name):
            return f"{name}: changed since the last build (mypy reads its types)"
    suffix = record["build"]["ext_suffix"]
    # (the sources' names are relative to controller/, the manifest's directory's parent)
    for stem in ["tracking/_core__mypyc"] + sorted(name[:-3] for name in record["sources"]):
        if not (directory.parent / (stem + suffix)).is_file():
            return f"{stem}{suffix}: missing"
    return None


class BuildExt(build_ext):
    """build_ext that falls back to the pure package when the compile fails, and writes the
    source manifest beside the compiled modules when it succeeds."""

    #: the build record (:func:`_build_record`) taken before mypyc translated the sources
    record: dict | None = None

    def run(self) -> None:
        if not self.extensions:
            return
        try:
            super().run()
        except Exception as exc:  # noqa: BLE001 -- any compile failure: install pure
            _warn(f"compiling the tracking core failed ({type(exc).__name__}: {exc})")
            self._drop_outputs()
            return
        for target in self._output_dirs():
            _write_manifest(target / "tracking", self.record)

    def _output_dirs(self) -> set[Path]:
        """Where this build puts the compiled modules (their ``controller`` directory): the
        build tree, and the checkout for an in-place (editable) build."""
        directories = {Path(self.build_lib) / "controller"}
        if self.inplace or getattr(self, "editable_mode", False):
            directories.add(CONTROLLER)
        return directories

    def _drop_outputs(self) -> None:
        """No half build: a shim without its shared library would fail at import."""
        self.extensions = []
        for directory in self._output_dirs():
            _remove_build(directory)

    def get_outputs(self) -> list[str]:
        return super().get_outputs() if self.extensions else []


#: the values of CANTRACK_NO_EXTENSIONS that mean "off" (any case)
OFF = ("", "0", "false", "no", "off")

#: the setup.py commands that build (pip's metadata steps, egg_info and dist_info, do not:
#: mypyc's translation, some 20 s, runs once per install)
BUILDS = {"build", "build_ext", "bdist_wheel", "editable_wheel", "develop", "install"}


def _extensions() -> list:
    if not BUILDS & set(sys.argv[1:]):
        return []
    editable = "editable_wheel" in sys.argv or "develop" in sys.argv
    # (a boolean as controller/tracking/__init__.py reads CANTRACK_PURE)
    if os.environ.get("CANTRACK_NO_EXTENSIONS", "").strip().lower() not in OFF:
        print("cantrack: CANTRACK_NO_EXTENSIONS set: the tracking core is not compiled",
              file=sys.stderr)
        if editable:
            _remove_build()  # (a regular build leaves the checkout's alone)
        return []
    record = _build_record()
    # pip install -e . again: no second compile of an in-place build that is up to date (not
    # for editable_mode=strict: its link tree has only the files this build lists)
    if editable and "strict" not in sys.argv:
        stale = _in_place_build_stale(TRACKING, record)
        if stale is None:
            print("cantrack: the in-place compiled tracking core is up to date (sources, "
                  "Python, mypy, compile flags): not compiled again", file=sys.stderr)
            return []
        print(f"cantrack: compiling the tracking core ({stale})", file=sys.stderr)
    BuildExt.record = record
    extensions = _mypycify()
    if not extensions and editable:
        _remove_build()  # (an older in-place build must not run instead)
    return extensions


def _mypycify() -> list:
    try:
        from mypyc.build import mypycify
    except ImportError as exc:
        _warn(f"mypyc is not available ({exc})")
        return []
    with tempfile.NamedTemporaryFile("w", suffix=".ini", delete=False) as ini:
        ini.write(MYPYC_INI)
    cwd = os.getcwd()
    try:
        os.chdir(HERE)  # mypyc names the modules from the paths relative to the checkout
        return mypycify(
            ["--config-file", ini.name] + [str(p.relative_to(HERE)) for p in _sources()],
            opt_level=MYPYC_OPTIONS["opt_level"], debug_level=MYPYC_OPTIONS["debug_level"],
            group_name=MYPYC_OPTIONS["group_name"])
    except BaseException as exc:  # noqa: BLE001 -- mypyc exits (SystemExit) on a type error
        if isinstance(exc, KeyboardInterrupt):
            raise
        _warn(f"mypyc could not translate the tracking core ({type(exc).__name__}: {exc})")
        return []
    finally:
        os.chdir(cwd)
        os.unlink(ini.name)


if __name__ == "__main__":  # (setuptools runs this file as __main__; tests import it)
    setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
