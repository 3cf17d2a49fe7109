"""What the CanTracker FMUs' Python part needs before the core can run (standard library only).

Bundled into the FMUs with the core (``cantrack fmu build``, see ``build.py``) under the
FMU's private package name; the slave scripts import this module at their top level and the
engine (which needs numpy) only when an instance is created.  So importing the slave script
never fails -- an import error there crashes the FMI 3 host (pythonfmu3 0.3.4 goes on with a
NULL module) -- and a missing compiled dependency is reported by ``fmiXInstantiate`` with one
clear message instead:

- numpy (needed by the core): instantiation fails, the message names the Python that runs the
  FMU and the pip command for it;
- ruckig (needed by ``planner=1``, the default planner): instantiation succeeds with a
  warning saying so; ``exitInitializationMode`` with ``planner=1`` is an error (no silent
  switch to another planner: its numbers differ from what the parameters ask for), with
  ``planner=0`` (softmc, numpy only) the FMU runs.

Instances the host never frees: a host may exit with live instances (a Python script that
instantiates, steps and ends without fmiXTerminate/fmiXFreeInstance; a C host that calls
exit()).  pythonfmu's wrapper then still holds the slave objects while the interpreter
finalises (a Python host's own exit, or the wrapper's Py_Finalize at unload in a host the
wrapper started Python in), and the trackers' ruckig objects would be torn down after
ruckig's binding module (nanobind reports them as leaked; once seen to abort there).  So
every engine registers itself here (``track_instance``, a weak reference: a freed instance
is gone) and an ``atexit`` hook -- run at the start of the interpreter's finalisation, while
everything still works -- releases the compiled objects of the engines still alive
(``TrackerEngine.release``).
"""

from __future__ import annotations

import atexit
import importlib
import sys
import weakref
from types import ModuleType
from typing import Any

#: pip requirement of the compiled dependencies (keep in step with pyproject.toml)
NUMPY_REQUIREMENT = "numpy>=1.24"
RUCKIG_REQUIREMENT = "ruckig>=0.12"


#: the engines of the live instances (weak: an instance the host freed drops out)
_LIVE: weakref.WeakSet[Any] = weakref.WeakSet()


def track_instance(engine: Any) -> None:
    """Register an engine (anything with ``release()``) for the exit hook."""
    _LIVE.add(engine)


def release_live_instances() -> int:
    """Release every registered engine still alive (``atexit``); returns how many."""
    live = list(_LIVE)
    for engine in live:
        engine.release()
    _LIVE.clear()
    return len(live)


atexit.register(release_live_instances)


class FmuDependencyError(ImportError):
    """A compiled dependency of the FMU cannot be imported in the Python that runs it."""


def python_description() -> str:
    """The Python that runs the FMU: version and prefix (the host may be any program)."""
    return f"Python {sys.version.split()[0]} at {sys.prefix}"


def pip_hint(requirement: str) -> str:
    """The command installing ``requirement`` for the Python that runs the FMU."""
    major, minor = sys.version_info[:2]
    return f"{sys.prefix}/bin/python{major}.{minor} -m pip install '{requirement}'"


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def load_engine(model: str) -> ModuleType:
    """Import the engine of this package (``<core>.fmu.engine``).

    Raises ``FmuDependencyError`` with a one-line message naming the model, what is missing,
    the Python that runs the FMU and how to install it (pythonfmu reports the exception's
    text in the failing ``fmiXInstantiate``).
    """
    try:
        importlib.import_module("numpy")
    except Exception as exc:  # ImportError, or a numpy built for another Python
        raise FmuDependencyError(
            f"{model}: numpy cannot be imported in the {python_description()} that runs this "
            f"FMU ({_one_line(exc)}); install it for that Python: "
            f"{pip_hint(NUMPY_REQUIREMENT)}") from None
    try:
        return importlib.import_module(".engine", __package__)
    except Exception as exc:
        raise FmuDependencyError(
            f"{model}: its bundled Python core cannot be imported in the "
            f"{python_description()} that runs this FMU: {_one_line(exc)}") from None


def ruckig_warning(model: str, import_error: str | None) -> str | None:
    """The instantiation warning when the optimal planner (ruckig) cannot be loaded."""
    if import_error is None:
        return None
    return (f"{model}: ruckig cannot be imported in the {python_description()} that runs this "
            f"FMU ({import_error}): planner=1 (optimal, the start value) will be refused at "
            f"exitInitializationMode; install it ({pip_hint(RUCKIG_REQUIREMENT)}) or set "
            f"planner=0 (softmc, needs numpy only)")


class EngineStateMixin:
    """FMU state and variable access of a slave class whose ``self._engine`` is a
    ``TrackerEngine``: get/set and (de)serialisation delegate to the engine (all internal
    state).  Shared by the FMI 2 and FMI 3 slaves; list it before the pythonfmu base class."""

    _engine: Any  # a TrackerEngine (not imported here: runtime needs no numpy)

    def _get_fmu_state(self) -> dict:
        return self._engine.get_state()

    def _set_fmu_state(self, state: dict) -> None:
        self._engine.set_state(state)

    @staticmethod
    def _fmu_state_to_bytes(state: dict) -> bytes:
        import pickle

        return pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict:
        import pickle

        try:
            return pickle.loads(state)
        except Exception as exc:
            return {"format": None, "error": f"cannot deserialize: {exc!r}"}

    # -- variable access shared by both FMI versions (the slaves bind them to their API's
    #    names: get_integer / get_int32, set_real / set_float64, ...).  The fast path reads
    #    and writes ``self._v`` directly (these run several times per step); anything else
    #    (unknown, read-only or frozen variables) goes through the engine's checks.
    def _get_integers(self, vrs):
        if not self._int.issuperset(vrs):
            self._engine.check("Integer", vrs)
        if self._engine.tracker is None:  # before initialisation: the InitialUnknowns
            self._engine.refresh_initial()
        v = self._v
        return [v[vr] for vr in vrs]

    def _get_booleans(self, vrs):
        if not self._bool.issuperset(vrs):
            self._engine.check("Boolean", vrs)
        v = self._v
        return [v[vr] for vr in vrs]

    def _set_reals(self, vrs, values):
        if not self._settable["Real"].issuperset(vrs):
            return self._engine.set_values("Real", vrs, values, float)
        v = self._v
        for vr, value in zip(vrs, values):
            v[vr] = value

    def _set_integers(self, vrs, values):
        if not self._settable["Integer"].issuperset(vrs):
            return self._engine.set_values("Integer", vrs, values, int)
        v = self._v
        for vr, value in zip(vrs, values):
            v[vr] = int(value)

    def _set_booleans(self, vrs, values):
        if not self._settable["Boolean"].issuperset(vrs):
            return self._engine.set_values("Boolean", vrs, values, bool)
        v = self._v
        for vr, value in zip(vrs, values):
            v[vr] = bool(value)
