"""The tracking core: pure, deterministic, no I/O, threads or clocks.

Public API::

    from controller.tracking import Tracker, TrackerParams, MotionState, Limits
    tracker = Tracker(TrackerParams(sample_time_s=0.002, planner="softmc"), MotionState.at(0, 0, 0))
    tracker.engage()
    out = tracker.update(master_state)      # once per sample

``Limits`` is :class:`controller.limits.Limits` (the one limits type of every layer),
exported here too because ``TrackerParams`` takes it.

Compiled core (docs/architecture.md "Compiled core"): the install compiles this package's
modules, and those of ``controller.conveyor`` and ``controller.kinematics``, with mypyc where
it can (setup.py; one group, its shared library in this directory).  This module chooses for
all of them (``controller.conveyor`` and ``controller.kinematics`` import it first):
``NATIVE`` tells whether the compiled modules are the ones running (all of them);
``CANTRACK_PURE`` set to anything but "", "0", "false", "no" or "off" forces the Python
source.  The build records the hash of each compiled source (``_native_manifest.json``, paths
relative to ``controller/``): a source changed or deleted since (an editable checkout edited
after ``pip install -e .``), or a compiled file missing, makes every compiled package run its
Python source, with one warning naming the file, instead of the old (or half a) compiled
build.
"""

import hashlib as _hashlib
import importlib.machinery as _machinery
import importlib.util as _util
import json as _json
import os as _os
import sys as _sys
import warnings as _warnings


#: the values of CANTRACK_PURE (and setup.py's CANTRACK_NO_EXTENSIONS) that mean "off"
_OFF = ("", "0", "false", "no", "off")


def _flag(name: str) -> bool:
    """The environment variable ``name`` as a boolean: unset, "", "0", "false", "no", "off"
    (any case, surrounding blanks ignored) are off, anything else on."""
    return _os.environ.get(name, "").strip().lower() not in _OFF


def _compiled_file(directory: str, stem: str) -> "str | None":
    """The extension module ``stem`` (``tracker``, ``_core__mypyc``) in ``directory``, or None."""
    for suffix in _machinery.EXTENSION_SUFFIXES:
        path = _os.path.join(directory, stem + suffix)
        if _os.path.isfile(path):
            return path
    return None


#: the directory of the ``controller`` package (the manifest's paths are relative to it)
_ROOT = _os.path.dirname(_os.path.dirname(__file__))


class _PureFinder:
    """Meta-path finder: the modules of the compiled packages (``prefixes``, e.g.
    ``controller.tracking.``) from their ``.py`` source (never a compiled extension module
    beside it: a module whose source is missing but whose compiled module is there is an
    ImportError naming both, not the compiled one loaded silently).  Subpackages (their
    ``__init__.py``) are left to the usual finders: they are never compiled."""

    def __init__(self, prefixes: "tuple[str, ...]", root: str) -> None:
        self.prefixes = prefixes
        self.root = root

    def find_spec(self, fullname, path=None, target=None):  # noqa: ANN001 -- importlib's API
        if not fullname.startswith(self.prefixes):
            return None
        # controller.conveyor.frames.linear -> <root>/conveyor/frames/linear.py
        *parts, name = fullname.split(".")[1:]
        directory = _os.path.join(self.root, *parts)
        source = _os.path.join(directory, name + ".py")
        if not _os.path.isfile(source):
            compiled = _compiled_file(directory, name)
            if compiled is not None:
                raise ImportError(
                    f"{source}: missing, and the tracking core runs its Python source: "
                    f"not loading the compiled {compiled} instead (restore the source, or "
                    f"rebuild with pip install -e .)", name=fullname, path=compiled)
            return None
        return _util.spec_from_file_location(
            fullname, source, loader=_machinery.SourceFileLoader(fullname, source))


def _read_manifest(directory: str) -> "dict[str, str] | None":
    """The build's manifest (compiled source, relative to ``controller/`` -> SHA-256), or None
    without a build."""
    try:
        with open(_os.path.join(directory, "_native_manifest.json"), encoding="utf-8") as f:
            recorded = _json.load(f)["sources"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return recorded if isinstance(recorded, dict) else None


def _module(entry: str, directory: str) -> "tuple[str, str, str]":
    """(module name, its directory, stem) of the entry of the manifest in ``directory``
    (this package's): a path relative to ``controller/`` (``conveyor/frames/linear.py``), or
    a bare name (``tracker.py``, as builds of this package alone wrote) in ``directory``."""
    path = str(entry)[:-3] if str(entry).endswith(".py") else str(entry)
    if "/" not in path:
        return f"{__name__}.{path}", directory, path
    folder, stem = _os.path.split(_os.path.join(_os.path.dirname(directory), *path.split("/")))
    return __name__.rpartition(".")[0] + "." + path.replace("/", "."), folder, stem


def _prefixes(recorded: "dict[str, str] | None") -> "tuple[str, ...]":
    """The compiled packages' module prefixes: this package's and those of the build's
    manifest (``controller.conveyor.``, ...)."""
    top = __name__.rpartition(".")[0]
    names = {__name__} | {f"{top}.{e.split('/')[0]}" for e in (recorded or {}) if "/" in e}
    return tuple(sorted(n + "." for n in names))


def _stale_source(directory: str) -> "str | None":
    """Why the build cannot run, as a file and what is wrong with it: a compiled module's
    source that differs from the build's manifest or is missing, the group's shared library
    or a module's compiled file missing; None when the build matches the sources; "" without a
    build."""
    recorded = _read_manifest(directory)
    if recorded is None:
        return ""
    if _compiled_file(directory, "_core__mypyc") is None:
        return (f"{_os.path.join(directory, '_core__mypyc')}.*.so: missing (the compiled "
                f"modules' shared library)")
    for name, digest in sorted(recorded.items()):
        _, folder, stem = _module(name, directory)
        source = _os.path.join(folder, stem + ".py")
        if _compiled_file(folder, stem) is None:
            return (f"{_os.path.join(folder, stem)}.*.so: missing (compiled from "
                    f"{stem}.py)")
        try:
            with open(source, "rb") as f:
                if _hashlib.sha256(f.read()).hexdigest() != digest:
                    return f"{source}: changed since the tracking core was compiled"
        except OSError:
            return f"{source}: missing (deleted since the tracking core was compiled)"
    return None


def _choose() -> str:
    """"pure" (forced), "stale" (a changed source: pure) or "auto" (the finders' choice)."""
    if _flag("CANTRACK_PURE"):
        return "pure"
    directory = _os.path.dirname(__file__)
    stale = _stale_source(directory)
    if stale:
        _warnings.warn(
            f"{stale}: running the Python source instead (rebuild with pip install -e .)",
            RuntimeWarning, stacklevel=3)
        return "stale"
    return "auto"


_MODE = _choose()
if _MODE != "auto" and not any(isinstance(f, _PureFinder) and f.root == _ROOT
                               for f in _sys.meta_path):
    _sys.meta_path.insert(0, _PureFinder(_prefixes(_read_manifest(_os.path.dirname(__file__))),
                                         _ROOT))

from .estimator import MasterEstimate, MasterEstimator, unwrap_counts  # noqa: E402
from .planner import PLANNER_CODES, PLANNERS, planner_factory  # noqa: E402
from .tracker import Tracker  # noqa: E402
from ..limits import Limits  # noqa: E402
from .types import (Imfs, Mode, MotionState, Rates, SoftMcOptions, TrackError,  # noqa: E402
                    TrackerOutput, TrackerParams, TrackState)


def _native() -> bool:
    """Whether every module the build compiled runs compiled (its loaded or would-be-loaded
    file is not its ``.py``); False without a build or in pure mode."""
    directory = _os.path.dirname(__file__)
    recorded = _read_manifest(directory)
    if _MODE != "auto" or not recorded:
        return False
    for name in recorded:
        fullname, folder, _ = _module(name, directory)
        module = _sys.modules.get(fullname)
        if module is not None:
            origin = getattr(module, "__file__", None)
        else:  # (the finder the import would use, without importing the package first)
            spec = _machinery.PathFinder.find_spec(fullname, [folder])
            origin = spec.origin if spec is not None else None
        if not origin or str(origin).endswith(".py"):
            return False
    return True


#: True when the compiled (mypyc) modules run (all of them), False for the Python source
NATIVE: bool = _native()

__all__ = [
    "Imfs", "Limits", "MasterEstimate", "MasterEstimator", "Mode", "MotionState", "NATIVE",
    "PLANNERS", "PLANNER_CODES", "Rates", "SoftMcOptions", "TrackError", "Tracker",
    "TrackerOutput", "TrackerParams", "TrackState", "planner_factory", "unwrap_counts",
]
