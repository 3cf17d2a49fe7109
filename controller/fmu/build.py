"""Build the FMUs (pythonfmu) from the installed ``controller`` package.

The sources are located through the *installed* package (``controller.__file__`` and this
package's own files), never through a repository checkout, so ``cantrack fmu build`` works from
a regular (non-editable) install as well as from an editable one.

What goes into ``CanTracker.fmu`` (FMI 2.0 Co-Simulation):

- ``resources/cantracker_<hash>.py``: the slave script ``controller/fmu/tracker_slave.py``
  under a content-hashed module name.  Python caches imported modules by name, so two FMUs
  whose scripts share a name cannot be used in one process; the hash (of the script and the
  bundled core) makes the name unique per content.
- ``resources/_<prefix>_<hash>/``: the FMU's private package, everything the script imports:
  the tracker core (``__init__``, ``errors``, ``limits``, ``tracking/``; it needs numpy, and
  ruckig for planner 1), ``fmu/engine.py`` (variables, stepping, errors, FMU state) and
  ``fmu/runtime.py`` (the dependency checks at instantiation) with a stub
  ``fmu/__init__.py`` (the build/check code is not bundled), and pythonfmu's Python part
  (``pythonfmu/``).  The build rewrites the script's ``from controller...`` and
  ``from pythonfmu...`` imports to this package (``_privatise``); the bundled modules import
  each other relatively.  The name carries the hash, so no host package can shadow it.
- ``binaries/linux64/CanTracker.so``: the front library (``front.c``, compiled by the build:
  it needs a C compiler): loads libpython in hosts without Python, returns the status the
  FMU logged during a call (Error from exitInitializationMode / doStep, which pythonfmu cannot
  return), refuses Model Exchange and FMI 3 event mode, passes the FMI 3 start time, and
  forwards every other call to ``binaries/linux64/CanTracker_pythonfmu.so``: pythonfmu's FMI
  wrapper, which runs the slave in the process's Python (it does not link libpython).
  ``binaries/win64/CanTracker.dll``: pythonfmu's wrapper alone.
- ``documentation/index.html``: variables, semantics and what the importing tool needs.

The only binary of ours is the front library, compiled from source at build time.
"""

from __future__ import annotations

import contextlib
import hashlib
import html
import importlib
import os
import re
import shutil
import subprocess
import sys
import sysconfig
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
default "optimal" planner; planner=0 "softmc" needs numpy only).  Instantiation fails with a
message naming the Python and the pip command when numpy is missing, and warns when ruckig
is (planner=1 is then refused at exitInitializationMode).  The tracker core and pythonfmu's
Python part are bundled in resources/ under a private package name (_cantracker_<hash>):
packages of the host, also one called `controller`, do not interfere.

Non-Python hosts on Linux (a C/C++ master, fmusim, OMSimulator, ...): nothing to set.  The
FMU's front library (binaries/<platform>/<model>.so, controller/fmu/front.c) loads
libpython itself when the host has none: $CANTRACK_LIBPYTHON if set, else the Python that
built the FMU (its path is recorded), else libpython3.X.so.1.0 from the loader's search path
(a distribution's Python).  That Python needs numpy (and ruckig for planner=1) in its own
site-packages, or PYTHONPATH pointing at them (a virtual environment's).  When no Python can
be loaded, instantiation fails naming what was tried.  `cantrack fmu doctor` prints what
this machine provides.  fmu/c_host/fmi2_host.c is a complete C host (tested).
Windows (not tested): pythonfmu's own wrapper (no front library): the folder of python3X.dll
on PATH, PYTHONHOME/PYTHONPATH as needed.

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
    """The tracker core bundled into the FMU: (source file, path inside the private package).

    All of it uses relative imports only, so it runs under the FMU's private package name.
    """
    root = Path(controller.__file__).resolve().parent
    files = [(root / "__init__.py", "__init__.py"), (root / "errors.py", "errors.py"),
             (root / "limits.py", "limits.py")]
    tracking = root / "tracking"
    if not (tracking / "__init__.py").is_file():
        raise FmuBuildError(f"{tracking}: the tracker core (controller.tracking) is missing")
    files += [(p, f"tracking/{p.name}") for p in sorted(tracking.glob("*.py"))]
    files += [(_HERE / "engine.py", "fmu/engine.py"), (_HERE / "runtime.py", "fmu/runtime.py")]
    for src, _ in files:
        if not src.is_file():
            raise FmuBuildError(f"{src}: missing file of the tracker core")
    return files


#: ``fmu/__init__.py`` of the private package: only the engine and the runtime checks are
#: bundled, not the build and check code (which would need pythonfmu and fmpy in the host)
_FMU_PACKAGE_STUB = (b'"""The FMU runtime subset of controller.fmu (bundled by '
                     b'cantrack fmu build): engine and runtime checks."""\n')
_PACKAGE_STUB = b'"""Private package of a cantrack FMU (bundled by cantrack fmu build)."""\n'

#: a line of a slave script importing the installed packages that the build points at the
#: FMU's private package instead
_ABSOLUTE_IMPORT = re.compile(r"^from (controller|pythonfmu3?)\b", re.M)


def _python_part(package: str) -> list[tuple[str, bytes]]:
    """pythonfmu's (or pythonfmu3's) Python part: (path inside the private package, content).

    Bundled privately so that a host which imported another pythonfmu version first still
    gets the one matching the FMU's binary.  Its modules import each other relatively."""
    mod = importlib.import_module(package)
    root = Path(str(mod.__file__)).resolve().parent
    return [(f"{package}/{p.name}", p.read_bytes()) for p in sorted(root.glob("*.py"))]


def _bundle(with_core: bool, fmi: str) -> list[tuple[str, bytes]]:
    """(path inside the private package, content) of everything bundled next to the script."""
    if with_core:
        files = [(arc, src.read_bytes()) for src, arc in core_files()]
        files.append(("fmu/__init__.py", _FMU_PACKAGE_STUB))
    else:
        files = [("__init__.py", _PACKAGE_STUB)]
    files += _python_part(fmi)
    return sorted(files)


def _privatise(source: bytes, private: str, path: Path) -> bytes:
    """The slave script with its absolute imports of ``controller`` and pythonfmu pointed at
    the private package (``from controller.fmu.runtime`` -> ``from _x.fmu.runtime``,
    ``from pythonfmu`` -> ``from _x.pythonfmu``)."""
    text = source.decode()
    if re.search(r"^import (controller|pythonfmu)", text, re.M):
        raise FmuBuildError(f"{path}: use 'from ... import' for controller/pythonfmu (the "
                            f"build rewrites those to the FMU's private package)")
    text = _ABSOLUTE_IMPORT.sub(
        lambda m: f"from {private}" if m[1] == "controller" else f"from {private}.{m[1]}", text)
    return text.encode()


#: the C source of the FMUs' front library (see its header comment)
FRONT_SOURCE = _HERE / "front.c"


def _c_compiler() -> str:
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        raise FmuBuildError("building the FMU's front library (controller/fmu/front.c) needs a "
                            "C compiler: install gcc (apt-get install gcc) or set CC")
    return cc


def build_libpython() -> str:
    """The shared library of the Python running the build ('' if it has none): the front
    library loads it in hosts without Python unless CANTRACK_LIBPYTHON says otherwise."""
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    for name in (sysconfig.get_config_var("INSTSONAME"), sysconfig.get_config_var("LDLIBRARY")):
        if name and name.endswith((".so", ".so.1.0")) and (Path(libdir) / name).is_file():
            return str(Path(libdir) / name)
    return ""


def _front_library(model: str, fmi3: bool, vr_time: int, out: Path,
                   cached: bool = False) -> None:
    """Compile the front library of ``model`` into ``out`` (Linux x86_64); ``cached``: with
    the variable cache of the tracker's inputs and outputs (``engine.CACHED_INPUTS``)."""
    defines = {"FMI_VERSION": "3" if fmi3 else "2", "MODEL": f'"{model}"',
               "REAL_LIBRARY": f'"{model}_pythonfmu.so"',
               "LIBPYTHON_BUILD": f'"{build_libpython()}"',
               "PY_MINOR": str(sys.version_info.minor), "VR_TIME": str(vr_time)}
    if cached:
        from .engine import CACHED_INPUTS, CACHED_OUTPUTS, PRIVATE_BASE, VALUE_LIST_VR, VARIABLES

        for prefix, table in (("IN", CACHED_INPUTS), ("OUT", CACHED_OUTPUTS)):
            defines[f"N_{prefix}"] = str(len(table))
            defines[f"{prefix}_VRS"] = "{" + ",".join(str(vr) for vr, _ in table) + "}"
            defines[f"{prefix}_TYPES"] = '"' + "".join(t for _, t in table) + '"'
        defines["PRIVATE_BASE"] = f"{PRIVATE_BASE}u"
        defines["VALUE_LIST_VR"] = f"{VALUE_LIST_VR}u"
        defines["N_VARIABLES"] = str(len(VARIABLES))
    cmd = [_c_compiler(), "-shared", "-fPIC", "-O2", "-fvisibility=hidden",
           *[f"-D{k}={v}" for k, v in defines.items()], "-o", str(out), str(FRONT_SOURCE),
           "-ldl", "-lpthread"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    except OSError as exc:
        raise FmuBuildError(f"{cmd[0]}: cannot run the C compiler: {exc}") from exc
    if proc.returncode != 0:
        raise FmuBuildError(f"{FRONT_SOURCE}: compiling the front library failed:\n"
                            f"{proc.stderr[-2000:]}")


def _install_front(fmu: Path, model: str, fmi3: bool, vr_time: int, cached: bool) -> None:
    """Put the front library in as binaries/<platform>/<model>.so and pythonfmu's wrapper
    beside it as <model>_pythonfmu.so (the front loads it).  Windows keeps pythonfmu's."""
    platform = "x86_64-linux" if fmi3 else "linux64"
    lib, wrapper = f"binaries/{platform}/{model}.so", f"binaries/{platform}/{model}_pythonfmu.so"
    with tempfile.TemporaryDirectory(prefix="cantrack_front_") as tmp:
        front = Path(tmp) / f"{model}.so"
        _front_library(model, fmi3, vr_time, front, cached)
        rewritten = Path(tmp) / fmu.name
        with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(rewritten, "w",
                                                          zipfile.ZIP_DEFLATED) as dst:
            for info in src.infolist():
                data = src.read(info)
                if info.filename == lib:
                    dst.writestr(wrapper, data)
                    dst.writestr(lib, front.read_bytes())
                else:
                    dst.writestr(info, data)
        shutil.move(rewritten, fmu)


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
def _clean_import_state(module_name: str):
    """pythonfmu's builder imports the script (``module_name``) and its private package
    (``_<module_name>``) and leaves them in sys.modules / sys.path.  An instance of an FMU
    with the same content may have imported them already (its own copy): those are set
    aside during the build and put back afterwards."""
    saved_path = list(sys.path)
    private = f"_{module_name}"

    def ours(name: str) -> bool:
        return name in (module_name, private) or name.startswith(private + ".")

    aside = {n: m for n, m in sys.modules.items() if ours(n)}
    for name in aside:
        del sys.modules[name]
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for name in [n for n in sys.modules if ours(n)]:
            del sys.modules[name]
        sys.modules.update(aside)
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
    bundle = _bundle(bundle_core, "pythonfmu3" if fmi3 else "pythonfmu")
    digest = _digest([(f"{slave_module}.py", source)] + bundle)
    module_name = f"{prefix}_{digest}"
    # the private package: resources/_<prefix>_<hash>/ (pythonfmu puts resources/ on sys.path;
    # the name is unique per content: no host package can shadow it, two builds never share it)
    private = f"_{module_name}"
    target = dest_dir / f"{model}.fmu"
    slave_doc = importlib.import_module(f"controller.fmu.{slave_module}").__doc__ or ""
    if bundle_core:  # the tracker: variables and semantics are the engine's
        from . import engine
        variables = engine.VARIABLES
        summary = slave_doc + "\n" + (engine.__doc__ or "")
    else:
        slave = importlib.import_module(f"controller.fmu.{slave_module}")
        variables, summary = slave.VARIABLES, slave_doc
    with tempfile.TemporaryDirectory(prefix="cantrack_fmu_") as tmpdir, \
            _clean_import_state(module_name):
        tmp = Path(tmpdir)
        script_dir = tmp / "script"
        script_dir.mkdir()
        script = script_dir / f"{module_name}.py"
        script.write_bytes(_privatise(source, private, _HERE / f"{slave_module}.py"))
        for arc, data in bundle:
            dst = tmp / "core" / private / arc
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.write_bytes(data)
        project_files = [tmp / "core" / private]
        doc = tmp / "documentation"
        doc.mkdir()
        (doc / "index.html").write_text(
            _documentation_html(doc_title, summary, variables), encoding="utf-8")
        # the builder imports the script: its private package must be importable meanwhile,
        # with the private pythonfmu being the builder's own (it looks for subclasses of its
        # Fmi2Slave / Fmi3Slave); inside the FMU the private copy is used
        sys.path.insert(0, str(tmp / "core"))
        fmi = "pythonfmu3" if fmi3 else "pythonfmu"
        for name, mod in list(sys.modules.items()):
            if name == fmi or name.startswith(f"{fmi}."):
                sys.modules[f"{private}.{name}"] = mod
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
    _install_front(built, model, fmi3, len(variables), cached=bundle_core)
    with zipfile.ZipFile(built) as zf:
        names = set(zf.namelist())
    platform = "x86_64-linux" if fmi3 else "linux64"
    expected = {"modelDescription.xml", f"resources/{module_name}.py",
                f"binaries/{platform}/{model}.so", f"binaries/{platform}/{model}_pythonfmu.so"} | {
        f"resources/{private}/{arc}" for arc, _ in bundle}
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
