"""Build the FMUs (pythonfmu) from the installed ``controller`` package.

The sources are located through the *installed* package (``controller.__file__`` and this
package's own files), never through a repository checkout, so ``cantrack fmu build`` works from
a regular (non-editable) install as well as from an editable one.

What goes into ``CanTracker.fmu`` (FMI 2.0 Co-Simulation):

- ``resources/cantracker_<hash>.py``: the slave script ``controller/fmu/tracker_slave.py``
  under a content-hashed module name.  Python caches imported modules by name, so two FMUs
  whose scripts share a name cannot be used in one process; the hash (of the script and the
  bundled core) makes the name unique per content.
- ``resources/controller/{__init__,errors}.py`` and ``resources/controller/tracking/*.py``:
  the tracker core (pure Python; it needs numpy, and ruckig for planner 1), and
  ``resources/controller/fmu/engine.py`` (variables, stepping, errors, FMU state) with a stub
  ``controller/fmu/__init__.py`` (the build/check code is not bundled).
- ``resources/pythonfmu/*.py``: pythonfmu's Python runtime (added by pythonfmu's builder) and
  ``binaries/{linux64,win64}/CanTracker.{so,dll}``: pythonfmu's FMI wrapper, which runs the
  slave in the importing process's Python (it does not link libpython).
- ``documentation/index.html``: variables, semantics and what the importing tool needs.

Nothing binary of ours is bundled.
"""

from __future__ import annotations

import contextlib
import hashlib
import html
import importlib
import sys
import tempfile
import zipfile
from pathlib import Path

import controller

from ..errors import CantrackError

#: model names (= file stems) of the FMUs built here
TRACKER_MODEL = "CanTracker"
TRACKER3_MODEL = "CanTracker3"
CONVEYOR_MODEL = "CanConveyor"

_HERE = Path(__file__).resolve().parent

#: What the importing tool needs (also written into the FMU's documentation).
HOST_REQUIREMENTS = """\
The FMU runs Python code inside the importing process (pythonfmu, needsExecutionTool=true).
Binaries: linux64 and win64 (pythonfmu's wrapper; nothing binary of cantrack is bundled).

Python hosts (fmpy, libcosimpy, ...): the interpreter of the host process is used (tested:
CPython 3.11).  numpy >= 1.24 must be importable, and ruckig >= 0.12 for planner=1 (the
default "optimal" planner; planner=0 "softmc" needs numpy only).  pythonfmu's Python part and
the tracker core (package `controller`: tracking, errors, fmu/engine) are bundled in
resources/ and need not be installed.  Python caches modules by name: if a package called
`controller` is already imported in the host (e.g. an installed cantrack), the FMU runs that
one, not its bundled copy -- keep one cantrack version per process.

Non-Python hosts on Linux (a C/C++ master, OMSimulator, ...): the wrapper does not link
libpython, so loading it fails with "undefined symbol: _Py_NoneStruct" (pythonfmu #202).
Preload the shared Python library and point Python at its home and packages:
    LD_PRELOAD=/path/to/libpython3.X.so      # e.g. <prefix>/lib/libpython3.11.so
    PYTHONHOME=/path/to/prefix               # needed unless Python lives in /usr
                                             # (else: No module named 'math')
    PYTHONPATH=/path/to/site-packages        # the folder(s) holding numpy (and ruckig)
fmu/c_host/fmi2_host.c is a complete example (tested).
Windows (not tested): the folder of python3X.dll on PATH, PYTHONHOME/PYTHONPATH as above.

Logging: pythonfmu forwards the FMU's messages to the importer's logger only when the
instance is created with loggingOn=true; errors also go to Python's `cantrack.fmu` logger.
"""


class FmuBuildError(CantrackError):
    """Building an FMU failed (the message names the step and the file)."""


def _require_pythonfmu():
    try:
        from pythonfmu import FmuBuilder
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise FmuBuildError("building FMUs needs pythonfmu >= 0.7 (pip install pythonfmu, or "
                            "pip install 'cantrack[fmu]')") from exc
    return FmuBuilder


def core_files() -> list[tuple[Path, str]]:
    """The tracker core bundled into the FMU: (source file, path relative to resources/)."""
    root = Path(controller.__file__).resolve().parent
    files = [(root / "__init__.py", "controller/__init__.py"),
             (root / "errors.py", "controller/errors.py")]
    tracking = root / "tracking"
    if not (tracking / "__init__.py").is_file():
        raise FmuBuildError(f"{tracking}: the tracker core (controller.tracking) is missing")
    files += [(p, f"controller/tracking/{p.name}") for p in sorted(tracking.glob("*.py"))]
    files.append((_HERE / "engine.py", "controller/fmu/engine.py"))
    for src, _ in files:
        if not src.is_file():
            raise FmuBuildError(f"{src}: missing file of the tracker core")
    return files


#: ``controller/fmu/__init__.py`` inside the FMU: only the engine is bundled, not the build
#: and check code (which would need pythonfmu and fmpy in the importing tool)
_FMU_PACKAGE_STUB = (b'"""The FMU runtime subset of controller.fmu (bundled by '
                     b'cantrack fmu build): the engine."""\n')


def _bundle() -> list[tuple[str, bytes]]:
    """(path relative to resources/, content) of everything bundled next to the script."""
    files = [(arc, src.read_bytes()) for src, arc in core_files()]
    files.append(("controller/fmu/__init__.py", _FMU_PACKAGE_STUB))
    return sorted(files)


def _require_pythonfmu3():
    try:
        from pythonfmu3 import FmuBuilder
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise FmuBuildError("building the FMI 3.0 FMU needs pythonfmu3 >= 0.3 "
                            "(pip install pythonfmu3)") from exc
    return FmuBuilder


def _digest(parts: list[tuple[str, bytes]]) -> str:
    h = hashlib.sha256()
    for name, data in parts:
        h.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
    return h.hexdigest()[:12]


def _slave_source(module: str) -> bytes:
    path = _HERE / f"{module}.py"
    if not path.is_file():
        raise FmuBuildError(f"{path}: slave script missing from the installed package")
    return path.read_bytes()


@contextlib.contextmanager
def _clean_import_state():
    """pythonfmu's builder imports the script and leaves it in sys.modules / sys.path."""
    saved_path = list(sys.path)
    saved_modules = set(sys.modules)
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for name in set(sys.modules) - saved_modules:
            if name.startswith(("cantracker_", "cantracker3_", "canconveyor_")):
                del sys.modules[name]
        importlib.invalidate_caches()


def _documentation_html(title: str, summary: str, variables: list[tuple]) -> str:
    rows = "\n".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (
            name, typ, causality, variability, "" if start is None else start, unit or "",
            desc)) + "</tr>"
        for name, typ, causality, variability, start, unit, desc, *_ in variables)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title></head>
<body><h1>{html.escape(title)}</h1>
<pre>{html.escape(summary)}</pre>
<h2>Variables</h2>
<table border="1" cellspacing="0" cellpadding="3">
<tr><th>name</th><th>type</th><th>causality</th><th>variability</th><th>start</th>
<th>unit</th><th>description</th></tr>
{rows}
</table>
<h2>What the importing tool needs</h2>
<pre>{html.escape(HOST_REQUIREMENTS)}</pre>
</body></html>
"""


def _build(model: str, slave_module: str, prefix: str, dest_dir: str | Path,
           bundle_core: bool, doc_title: str, fmi3: bool = False) -> Path:
    FmuBuilder = _require_pythonfmu3() if fmi3 else _require_pythonfmu()
    dest_dir = Path(dest_dir)
    dest_dir.mkdir(parents=True, exist_ok=True)
    source = _slave_source(slave_module)
    core = _bundle() if bundle_core else []
    digest = _digest([(f"{slave_module}.py", source)] + core)
    module_name = f"{prefix}_{digest}"
    target = dest_dir / f"{model}.fmu"
    slave = importlib.import_module(f"controller.fmu.{slave_module}")
    with tempfile.TemporaryDirectory(prefix="cantrack_fmu_") as tmp, _clean_import_state():
        tmp = Path(tmp)
        script_dir = tmp / "script"
        script_dir.mkdir()
        script = script_dir / f"{module_name}.py"
        script.write_bytes(source)
        project_files = []
        if core:
            pkg = tmp / "core" / "controller"
            for arc, data in core:
                dst = tmp / "core" / arc
                dst.parent.mkdir(parents=True, exist_ok=True)
                dst.write_bytes(data)
            project_files.append(pkg)
        doc = tmp / "documentation"
        doc.mkdir()
        summary = slave.__doc__ or ""
        if bundle_core:  # the tracker: its semantics are documented in the engine
            from . import engine
            summary += "\n" + (engine.__doc__ or "")
        (doc / "index.html").write_text(
            _documentation_html(doc_title, summary, slave.VARIABLES), encoding="utf-8")
        try:
            if fmi3:  # pythonfmu3 names the file after the class, in the folder dest
                built = FmuBuilder.build_FMU(
                    script, dest=dest_dir, project_files=project_files,
                    documentation_folder=doc, canGetAndSetFMUState=True,
                    canSerializeFMUState=True,
                    # pythonfmu3 0.3.4 writes "false" here unless it is given explicitly
                    canHandleVariableCommunicationStepSize=True)
            else:
                built = FmuBuilder.build_FMU(
                    script, dest=target, project_files=project_files,
                    documentation_folder=doc, canGetAndSetFMUstate=True,
                    canSerializeFMUstate=True)
        except Exception as exc:
            raise FmuBuildError(f"building {target} from {script.name} failed: {exc}") from exc
    built = Path(built)
    with zipfile.ZipFile(built) as zf:
        names = set(zf.namelist())
    expected = {"modelDescription.xml", f"resources/{module_name}.py",
                f"binaries/{'x86_64-linux' if fmi3 else 'linux64'}/{model}.so"} | {
        f"resources/{arc}" for arc, _ in core}
    missing = sorted(expected - names)
    if missing:
        raise FmuBuildError(f"{built}: incomplete FMU, missing {', '.join(missing)}")
    return built


def build_tracker_fmu(dest_dir: str | Path = ".") -> Path:
    """Build ``DEST_DIR/CanTracker.fmu`` (FMI 2.0 CS) and return its path."""
    return _build(TRACKER_MODEL, "tracker_slave", "cantracker", dest_dir, True,
                  "CanTracker: cantrack conveyor tracker (FMI 2.0 Co-Simulation)")


def build_tracker_fmu3(dest_dir: str | Path = ".") -> Path:
    """Build ``DEST_DIR/CanTracker3.fmu`` (FMI 3.0 CS, pythonfmu3) and return its path."""
    return _build(TRACKER3_MODEL, "tracker3_slave", "cantracker3", dest_dir, True,
                  "CanTracker3: cantrack conveyor tracker (FMI 3.0 Co-Simulation)", fmi3=True)


def build_conveyor_fmu(dest_dir: str | Path = ".") -> Path:
    """Build ``DEST_DIR/CanConveyor.fmu``: a master axis with a speed profile (test master)."""
    return _build(CONVEYOR_MODEL, "conveyor_slave", "canconveyor", dest_dir, False,
                  "CanConveyor: conveyor master axis with a trapezoidal speed profile")
