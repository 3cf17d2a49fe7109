"""Build of the compiled tracking core (docs/architecture.md "Compiled core").

``pip install .`` and ``pip install -e .`` compile the modules of ``controller/tracking`` (all
but ``PURE_ONLY``) with mypyc: the same source, checked by mypy and turned into C extension
modules, about 1.6x faster in the cycle's hot path.  Everything else (metadata, packages,
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
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext

HERE = Path(__file__).resolve().parent
TRACKING = HERE / "controller" / "tracking"
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
[mypy-numpy,numpy.*,ruckig,ruckig.*]
follow_imports = skip
ignore_missing_imports = True
"""


def _warn(message: str) -> None:
    bar = "*" * 78
    print(f"\n{bar}\ncantrack: {message}\n"
          f"cantrack: installing the pure-Python tracking core (same results, slower)\n{bar}\n",
          file=sys.stderr)


#: not compiled: the package (it chooses compiled or pure) and the two numpy-array modules
#: off the per-sample path (batch stepping, trace metrics), where mypyc gains nothing
PURE_ONLY = {"__init__.py", "batch.py", "metrics.py"}


def _sources() -> list[Path]:
    return sorted(p for p in TRACKING.glob("*.py") if p.name not in PURE_ONLY)


def _remove_build(directory: Path = TRACKING) -> None:
    """The compiled files and the manifest a build left in ``directory`` (by default the
    checkout's, which an earlier in-place (editable) build left)."""
    for path in list(directory.glob("*.so")) + list(directory.glob("*.pyd")) + \
            [directory / MANIFEST]:
        if path.exists():
            path.unlink()


def _write_manifest(directory: Path) -> None:
    entries = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in _sources()}
    directory.mkdir(parents=True, exist_ok=True)
    (directory / MANIFEST).write_text(
        json.dumps({"group": GROUP, "sources": entries}, indent=1, sort_keys=True) + "\n")


class BuildExt(build_ext):
    """build_ext that falls back to the pure package when the compile fails, and writes the
    source manifest beside the compiled modules when it succeeds."""

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
            _write_manifest(target)

    def _output_dirs(self) -> set[Path]:
        """Where this build puts the compiled modules: the build tree, and the checkout for
        an in-place (editable) build."""
        directories = {Path(self.build_lib) / "controller" / "tracking"}
        if self.inplace or getattr(self, "editable_mode", False):
            directories.add(TRACKING)
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
            opt_level="3", debug_level="0", group_name=GROUP)
    except BaseException as exc:  # noqa: BLE001 -- mypyc exits (SystemExit) on a type error
        if isinstance(exc, KeyboardInterrupt):
            raise
        _warn(f"mypyc could not translate the tracking core ({type(exc).__name__}: {exc})")
        return []
    finally:
        os.chdir(cwd)
        os.unlink(ini.name)


setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
