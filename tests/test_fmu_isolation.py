"""The FMUs in hosts that are not cantrack's own test process, each in a subprocess with fmpy:
a host that imported its own package called ``controller`` first, a Python without numpy, a
Python without ruckig.  No crash (the process ends normally), a clear FMI message at
instantiation naming what is missing and how to install it, and where the FMU can run, the
same numbers as the core."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from controller.fmu.engine import VARIABLES, tracker_params
from controller.fmu.runner import conveyor_scenario, core_run

T = 0.001
N_STEPS = 300
DEFAULTS = {row[0]: row[4] for row in VARIABLES if row[2] == "parameter"}

#: The host program: fmpy driving the FMU through its FMI 2 or FMI 3 API.  It prints one JSON
#: line with what happened; every failure of the FMU is caught as fmpy reports it.
_HOST = """
import json, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

fmu, planner, n_steps, prepare = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
md = read_model_description(fmu)
d = extract(fmu)
# -- the host's own state, set up after fmpy was imported
if prepare == "numpy-missing":
    for k in [k for k in sys.modules if k == "numpy" or k.startswith("numpy.")]:
        sys.modules[k] = None  # 'import numpy' now fails, as in a Python without numpy
elif prepare == "ruckig-missing":
    sys.modules["ruckig"] = None
elif prepare == "host-controller":
    sys.path.insert(0, sys.argv[5])
    import controller  # the host's own package of that name
    assert controller.__version__ == "host-0.0"
vr = {v.name: v.valueReference for v in md.modelVariables}
fmi3 = md.fmiVersion.startswith("3")
messages = []
result = {"messages": messages, "instantiated": False, "initialised": False, "rows": []}
cls = FMU3Slave if fmi3 else FMU2Slave
s = cls(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="host")
def log(status, message):
    messages.append([int(status), message.decode(errors="replace")])
try:
    if fmi3:
        s.instantiate(loggingOn=True, logMessage=lambda env, st, cat, msg: log(st, msg))
    else:
        from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
        from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
        from fmpy import calloc, free
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, st, cat, msg: log(st, msg))
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        s.instantiate(callbacks=cb, loggingOn=True)
    result["instantiated"] = True
except Exception as exc:
    result["instantiate_error"] = str(exc)
if result["instantiated"]:
    if fmi3:
        s.enterInitializationMode(startTime=0.0)
        s.setInt32([vr["planner"]], [planner])
    else:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setInteger([vr["planner"]], [planner])
    try:
        s.exitInitializationMode()
        result["initialised"] = True
    except Exception as exc:
        result["init_error"] = str(exc)
    set_r, get_r = (s.setFloat64, s.getFloat64) if fmi3 else (s.setReal, s.getReal)
    get_i = s.getInt32 if fmi3 else s.getInteger
    ins = ["master_x", "master_y", "master_z", "master_c", "master_vx", "master_vy",
           "master_vz", "master_vc", "master_ax", "master_ay", "master_az", "master_ac"]
    outs = ["x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac"]
    for k in range(n_steps):  # the runner's conveyor_scenario(T)
        t = k * 0.001
        set_r([vr[n] for n in ins], [100.0 + 300.0 * t, 50.0, 0.0, 10.0 + 20.0 * t, 300.0,
                                     0.0, 0.0, 20.0, 0.0, 0.0, 0.0, 0.0])
        s.setBoolean([vr["engage"]], [0.1 <= t < 1.0])
        try:
            s.doStep(t, 0.001)
        except Exception as exc:
            result["step_error"] = str(exc)
            break
        result["rows"].append([repr(x) for x in get_r([vr[n] for n in outs])]
                              + get_i([vr[n] for n in ("imfs", "state", "error")]))
    s.terminate()
    s.freeInstance()
if prepare == "host-controller":
    import controller
    result["host_controller_kept"] = controller.__version__ == "host-0.0"
    result["private"] = sorted({m.split(".")[0] for m in sys.modules if m.startswith("_can")})
print("RESULT " + json.dumps(result))
"""


def _host_package(tmp_path):
    """A host package called ``controller`` (not cantrack's) with a broken ``tracking``."""
    pkg = tmp_path / "host" / "controller"
    (pkg / "tracking").mkdir(parents=True)
    (pkg / "__init__.py").write_text('__version__ = "host-0.0"\n')
    (pkg / "tracking" / "__init__.py").write_text(
        'raise ImportError("the host\'s own controller.tracking must not be used")\n')
    return tmp_path / "host"


def run_host(fmu, prepare: str, planner: int, tmp_path) -> dict:
    script = tmp_path / "host.py"
    script.write_text(textwrap.dedent(_HOST))
    extra = [str(_host_package(tmp_path))] if prepare == "host-controller" else []
    proc = subprocess.run([sys.executable, str(script), str(fmu), str(planner), str(N_STEPS),
                           prepare, *extra], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    # no crash: the host process ends normally whatever the FMU met
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    (line,) = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    return json.loads(line[len("RESULT "):])


def _reference(planner: int) -> list[list]:
    ref = core_run(tracker_params({**DEFAULTS, "planner": planner}), conveyor_scenario(T),
                   N_STEPS)
    return [[repr(x) for x in r] + i for r, i in zip(ref.reals, ref.ints)]


@pytest.fixture(params=["fmi2", "fmi3"])
def fmu_path(request):
    return request.getfixturevalue("fmu2_path" if request.param == "fmi2" else "fmu3_path")


def test_host_with_its_own_controller_package(fmu_path, tmp_path):
    """The host imported an unrelated package ``controller``: the FMU runs its private copy
    (bit-identical to the core) and leaves the host's package alone."""
    res = run_host(fmu_path, "host-controller", 0, tmp_path)
    assert res["instantiated"] and res["initialised"], res
    assert res["rows"] == _reference(0)
    assert res["host_controller_kept"] is True
    assert len(res["private"]) == 1 and res["private"][0].startswith("_cantracker")


def test_numpy_missing_is_an_instantiation_error(fmu_path, tmp_path):
    res = run_host(fmu_path, "numpy-missing", 0, tmp_path)
    assert not res["instantiated"]
    text = "\n".join(m for _, m in res["messages"])
    model = "CanTracker3" if fmu_path.name == "CanTracker3.fmu" else "CanTracker"
    assert f"{model}: numpy cannot be imported in the Python {sys.version.split()[0]} at " \
           f"{sys.prefix} that runs this FMU" in text
    assert "-m pip install 'numpy>=1.24'" in text
    assert "Traceback" not in text


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="needs valgrind")
@pytest.mark.parametrize("prepare", ["numpy-missing", "none"])
def test_no_use_after_free_at_exit(fmu_path, tmp_path, prepare):
    """pythonfmu's wrapper (0.7.0; pythonfmu3 0.3.4 the same) stays loaded until the host
    exits (it has GNU unique symbols: dlclose keeps it); there the static destructor of its
    Python state's shared_ptr runs first and its destructor function then resets the
    destroyed shared_ptr: a write into the freed block at every exit (valgrind: an invalid
    read in finalizePythonInterpreter), which aborted the numpy-missing host once ("corrupted
    double-linked list", exit -6).  The front resets the state first (front.c,
    release_wrapper_state).  Under valgrind, with Python's allocator off (PYTHONMALLOC=malloc:
    every block valgrind's)."""
    script = tmp_path / "host.py"
    script.write_text(textwrap.dedent(_HOST))
    log = tmp_path / "valgrind.txt"
    proc = subprocess.run(["valgrind", f"--log-file={log}", sys.executable, str(script),
                           str(fmu_path), "0", "5", prepare], capture_output=True, text=True,
                          timeout=600, cwd=tmp_path, env={**os.environ, "PYTHONMALLOC": "malloc"})
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    text = log.read_text()
    assert "ERROR SUMMARY" in text  # (valgrind ran the host to its end)
    assert "finalizePythonInterpreter" not in text, text[text.index("finalizePython") - 800:][:2500]


@pytest.mark.parametrize("planner", [0, 1])
def test_ruckig_missing(fmu_path, tmp_path, planner):
    """Said once, at instantiation (a warning); planner=1 is then refused at
    exitInitializationMode in one line; planner=0 (softmc, numpy only) runs as the core."""
    res = run_host(fmu_path, "ruckig-missing", planner, tmp_path)
    assert res["instantiated"], res
    warnings = [m for st, m in res["messages"] if st == 1]
    assert len(warnings) == 1 and "ruckig cannot be imported" in warnings[0]
    assert "pip install 'ruckig>=0.12'" in warnings[0] and "planner=0" in warnings[0]
    if planner == 0:
        assert res["initialised"] and res["rows"] == _reference(0)
        assert [m for st, m in res["messages"] if st >= 2] == []
        return
    errors = [m for st, m in res["messages"] if st >= 2]
    assert errors[0] == ("host: exitInitializationMode refused the parameters: planner=1 "
                         "(optimal) needs ruckig, which cannot be imported (ModuleNotFoundError:"
                         " import of ruckig halted; None in sys.modules): install ruckig for "
                         "the Python running this FMU or set planner=0 (softmc)")
    assert res["rows"] == [] and "step_error" in res
