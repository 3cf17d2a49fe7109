"""The FMUs' front library (controller/fmu/front.c, Linux): statuses, refusals before Python,
the FMI 3 start time, errors reaching the importer whatever loggingOn, and `fmpy simulate`'s
exit code.  (Loading libpython in a host without Python: test_fmu.py::test_non_python_host,
tests/test_fmu_importers.py with fmusim.)"""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave

from controller.fmu.runner import FmuTracker, conveyor_scenario

T = 0.001
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="the front library is built for Linux only")


@pytest.fixture(params=["fmi2", "fmi3"])
def fmu_path(request):
    return request.getfixturevalue("fmu2_path" if request.param == "fmi2" else "fmu3_path")


def _fmpy_simulate(fmu, *args, env=None):
    return subprocess.run([sys.executable, "-m", "fmpy.cli", "simulate", str(fmu),
                           *args], capture_output=True, text=True, timeout=120, env=env)


def test_fmpy_simulate_exit_code(fmu_path, tmp_path):
    """A run whose every step is refused does not exit 0; a good run does."""
    ok = _fmpy_simulate(fmu_path, "--start-values", "planner", "0",
                        "--output-file", str(tmp_path / "ok.csv"))
    assert ok.returncode == 0, ok.stderr
    bad = _fmpy_simulate(fmu_path, "--start-values", "sample_time", "0.5",
                         "--output-file", str(tmp_path / "bad.csv"))
    assert bad.returncode != 0
    assert "ExitInitializationMode failed with status 3 (error)" in bad.stderr + bad.stdout
    assert "sample_time=0.5 s is outside its declared range" in bad.stderr + bad.stdout


def test_fmpy_simulate_without_ruckig_fails_at_initialisation(fmu_path, tmp_path):
    """In a Python without ruckig the default planner is refused at exitInitializationMode:
    `fmpy simulate` exits non-zero saying why (not a 2-row result with exit 0)."""
    import os

    fake = tmp_path / "no-ruckig" / "ruckig"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('ruckig is not installed here')\n")
    env = {**os.environ,
           "PYTHONPATH": os.pathsep.join([str(fake.parent), os.environ.get("PYTHONPATH", "")])}
    res = _fmpy_simulate(fmu_path, "--output-file", str(tmp_path / "r.csv"), env=env)
    out = res.stdout + res.stderr
    assert res.returncode != 0, out
    assert "ruckig cannot be imported" in out and "planner=1 (optimal) needs ruckig" in out


def test_fmi3_time_after_initialisation(fmu3_path):
    """`time` is the start time right after initialisation (pythonfmu3 does not pass it to
    Python: the front library sets it), and t0 + k*T after k steps."""
    with FmuTracker(fmu3_path, start_values={"planner": 0}, start_time=0.25) as fmu:
        vr_time = fmu.vr["time"]
        assert fmu.slave.getFloat64([vr_time]) == [0.25]
        fmu.run(conveyor_scenario(T), 10, T)
        assert fmu.slave.getFloat64([vr_time])[0] == pytest.approx(0.26, abs=1e-12)


def test_fmi3_event_mode_and_model_exchange_refused(fmu3_path):
    md = read_model_description(str(fmu3_path))
    d = extract(str(fmu3_path))
    messages = []
    s = FMU3Slave(guid=md.guid, unzipDirectory=d, modelIdentifier="CanTracker3",
                  instanceName="ev")
    with pytest.raises(Exception, match="instantiate"):
        s.instantiate(eventModeUsed=True, logMessage=lambda env, st, cat, msg: messages.append(
            (st, msg.decode())))
    assert messages == [(3, "CanTracker3: eventModeUsed=true refused: the FMU has no event "
                            "mode (hasEventMode=false); instantiate it with "
                            "eventModeUsed=false")]
    assert md.coSimulation.hasEventMode in (None, False)
    s.freeLibrary()


def test_errors_reach_the_importer_with_logging_off(fmu_path):
    """loggingOn=false: errors and warnings are still logged (FMI), the rest is not."""
    with FmuTracker(fmu_path, start_values={"planner": 0}, logging_on=False) as fmu:
        fmu.run(conveyor_scenario(T), 3, T)
        with pytest.raises(FMICallException):
            fmu.slave.doStep(fmu.time, 1.5 * T)
        assert [m[0] for m in fmu.messages] == [2]
        assert "must end on the sample grid" in fmu.messages[0][2]


def test_doctor(tmp_path):
    """`cantrack fmu doctor`: this Python as the FMUs' Python; exit 1 naming what is missing."""
    import os

    from controller.fmu.build import build_libpython

    cmd = [sys.executable, "-m", "controller.fmu", "doctor"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"ok   shared libpython: {build_libpython()}" in res.stdout
    assert "ok   numpy: " in res.stdout
    fake = tmp_path / "no-ruckig" / "ruckig"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('ruckig is not installed here')\n")
    env = {**os.environ,
           "PYTHONPATH": os.pathsep.join([str(fake.parent), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 1
    assert "FAIL ruckig (planner 1): ImportError: ruckig is not installed here; install: " \
           in res.stdout and "pip install 'ruckig>=0.12'" in res.stdout
