"""``cantrack fmu doctor``: what this machine gives a host of the cantrack FMUs.

The FMUs run their Python part in the Python of the host process, or -- in a host without
Python (fmusim, OMSimulator, a C/C++ master) -- in the Python whose shared library the FMU's
front library loads (``front.c``: ``$CANTRACK_LIBPYTHON``, else the Python that built the
FMU, else ``libpython3.X.so.1.0`` from the loader's search path).  That Python needs numpy,
and ruckig for planner 1.  The doctor checks this for the Python it runs in and prints what
a host must set, if anything.
"""

from __future__ import annotations

import ctypes
import importlib
import os
import sys
from dataclasses import dataclass, field

from .build import build_libpython
from .runtime import NUMPY_REQUIREMENT, RUCKIG_REQUIREMENT, pip_hint


@dataclass
class DoctorReport:
    """Findings (name, ok, detail) and what a non-Python host needs to set."""

    findings: list[tuple[str, bool, str]] = field(default_factory=list)
    host_env: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return all(ok for _, ok, _ in self.findings)

    def format(self) -> str:
        lines = [f"{'ok  ' if ok else 'FAIL'} {name}: {detail}"
                 for name, ok, detail in self.findings]
        if self.host_env:
            lines.append("a host without Python needs in its environment:")
            lines += [f"    {k}={v}" for k, v in self.host_env.items()]
        else:
            lines.append("a host without Python needs nothing set (the FMU's front library "
                         "loads this Python)")
        return "\n".join(lines)


def _module(name: str) -> tuple[bool, str]:
    try:
        mod = importlib.import_module(name)
    except Exception as exc:
        return False, f"{type(exc).__name__}: {exc}"
    return True, f"{getattr(mod, '__version__', '?')} ({os.path.dirname(mod.__file__ or '')})"


def diagnose() -> DoctorReport:
    """Check the Python this runs in as the FMUs' Python."""
    r = DoctorReport()
    py = f"{sys.version.split()[0]} at {sys.prefix}"
    r.findings.append(("Python", sys.version_info >= (3, 10), py + " (needs >= 3.10)"))
    ok, detail = _module("numpy")
    r.findings.append(("numpy", ok, detail if ok else
                       f"{detail}; install: {pip_hint(NUMPY_REQUIREMENT)}"))
    ok, detail = _module("ruckig")
    r.findings.append(("ruckig (planner 1)", ok, detail if ok else
                       f"{detail}; install: {pip_hint(RUCKIG_REQUIREMENT)} or use planner=0"))
    lib = build_libpython()
    minor = sys.version_info.minor
    if not lib:
        r.findings.append(("shared libpython", False,
                           "this Python has none (built without --enable-shared): a host "
                           "without Python cannot load it; use a Python with "
                           f"libpython3.{minor}.so (e.g. the distribution's python3)"))
        return r
    try:
        ctypes.CDLL(lib)
        r.findings.append(("shared libpython", True, lib))
    except OSError as exc:
        r.findings.append(("shared libpython", False, f"{lib}: {exc}"))
    # what the front library would find by itself, in order
    env = os.environ.get("CANTRACK_LIBPYTHON")
    if env and os.path.realpath(env) != os.path.realpath(lib):
        r.findings.append(("CANTRACK_LIBPYTHON", os.path.isfile(env),
                           f"{env} is set and is loaded instead of {lib}"))
    r.host_env = {}
    if sys.prefix != sys.base_prefix:  # a virtual environment: its packages are not the base's
        site = [p for p in sys.path if p.startswith(sys.prefix) and p.endswith("site-packages")]
        r.host_env["PYTHONPATH"] = os.pathsep.join(site)
    r.findings.append(("FMUs built here", True,
                       f"load {lib} in hosts without Python (or $CANTRACK_LIBPYTHON)"))
    return r
