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


def _state_calls(fmu):
    return fmu.get_state, fmu.set_state, fmu.free_state


def test_inputs_reach_the_engine_from_every_path(fmu_path):
    """The inputs reach the engine whichever way they were set after initialisation: kept
    by the front (moved into the engine's value list at doStep), a set that mixes inputs and
    a tunable (passed through to Python, copied into the front's inputs), a set of only some
    inputs (the others keep their values), and FMU states (restored inputs read back by the
    front).  Each path alone delivers the scenario's values, so the outputs are the core's,
    bit for bit; a stale value in the front's copy would change them."""
    from controller.fmu.engine import VARIABLES
    from controller.fmu.runner import core_run, master_values
    from tests.test_fmu import params_for

    scenario = conveyor_scenario(T, engage_s=0.02, release_s=0.25)
    n = 320
    vel_sync = next(row[4] for row in VARIABLES if row[0] == "vel_sync")
    with FmuTracker(fmu_path, start_values={"planner": 0}, logging_on=False) as fmu:
        s, vr = fmu.slave, fmu.vr
        ins, eng = fmu._in_vrs, fmu._engage_vr
        get_state, set_state, free_state = _state_calls(fmu)
        reals, ints = [], []
        for k in range(n):
            master, engage = scenario(k)
            vals = master_values(master)
            path = k % 4
            if path == 0:  # the cache
                fmu._set_real(ins, vals)
            elif path == 1:  # one set with a tunable: passed through
                fmu._set_real(ins + [vr["vel_sync"]], vals + [vel_sync])
            elif path == 2:  # half cached, half passed through
                fmu._set_real(ins[:6], vals[:6])
                fmu._set_real([vr["vel_sync"]] + ins[6:], [vel_sync] + vals[6:])
            else:  # a state with these inputs restored over other values
                fmu._set_real(ins, vals)
                state = get_state()
                fmu._set_real(ins, [1e6 + x for x in vals])
                set_state(state)
                free_state(state)
            s.setBoolean(eng, [engage])  # kept by the front
            s.doStep(currentCommunicationPoint=k * T, communicationStepSize=T)
            r, i = fmu.outputs()
            reals.append(r)
            ints.append(i)
        assert fmu._get_real(ins) == master_values(scenario(n - 1)[0])
    ref = core_run(params_for(planner=0), scenario, n)
    assert reals == ref.reals and ints == ref.ints
    assert {row[1] for row in ints} == {0, 1, 3}  # off, approaching, de-syncing


def test_private_value_references_are_refused(fmu_path):
    """The front's private value references (from PRIVATE_BASE on: the engine's value
    list's address) are not the importer's: a set or get of one is an error naming it,
    never reaches Python, and the instance goes on."""
    from controller.fmu.engine import PRIVATE_BASE, VALUE_LIST_VR

    with FmuTracker(fmu_path, start_values={"planner": 0}, logging_on=False) as fmu:
        fmu.run(conveyor_scenario(T), 3, T)
        for call, args in ((fmu._get_real, ([VALUE_LIST_VR],)),
                           (fmu._set_real, ([fmu.vr["master_x"], PRIVATE_BASE], [1.0, 2.0])),
                           (fmu._set_real, ([VALUE_LIST_VR], [123.0]))):
            with pytest.raises(FMICallException):
                call(*args)
        assert [m[0] for m in fmu.messages] == [3, 3, 3]
        assert f"valueReference {VALUE_LIST_VR} is not a variable of" in fmu.messages[0][2]
        assert f"valueReference {PRIVATE_BASE} is not a variable of" in fmu.messages[1][2]
        got = fmu.run(conveyor_scenario(T), 5, T, first_step=3)
    assert len(got.reals) == 5


def test_reset_reattaches_the_value_list(fmu_path):
    """fmiXReset makes a new Python instance: the front takes its value list, so the run
    after the reset is the first one again (FMI 2 and FMI 3)."""
    scenario = conveyor_scenario(T, engage_s=0.02, release_s=0.15)
    with FmuTracker(fmu_path, start_values={"planner": 0}, logging_on=False) as fmu:
        first = fmu.run(scenario, 200, T)
        fmu.reset()  # (planner 0 again, time 0)
        again = fmu.run(scenario, 200, T)
    assert again.reals == first.reals and again.ints == first.ints
    assert {row[1] for row in first.ints} == {0, 1, 3}


def test_fmi2_step_exception_outside_the_engine_guard_is_an_error(fmu2_path, monkeypatch):
    """FMI 2: the front calls the engine's step directly; an exception that escapes it
    (here from the refusal after terminate) is Error with a message, its traceback on
    stderr, the host goes on, and the front refuses later steps until a reset."""
    from controller.fmu.runner import bundled_module

    with FmuTracker(fmu2_path, start_values={"planner": 0}, logging_on=False) as fmu:
        fmu.run(conveyor_scenario(T), 3, T)
        fmu.slave.terminate()
        engine = bundled_module(fmu2_path, "fmu.engine").TrackerEngine

        def broken(self, current_time):
            raise RuntimeError("refusal broke")

        monkeypatch.setattr(engine, "_refuse_dead", broken)
        unraisable = []  # the front hands the exception to sys.unraisablehook (stderr)
        monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
        with pytest.raises(FMICallException):
            fmu.slave.doStep(fmu.time, T)
        assert [m[0] for m in fmu.messages] == [3]
        assert "the engine raised an exception" in fmu.messages[0][2]
        assert [(u.exc_type, str(u.exc_value)) for u in unraisable] == [
            (RuntimeError, "refusal broke")]
        monkeypatch.undo()
        with pytest.raises(FMICallException):  # refused by the front now
            fmu.slave.doStep(fmu.time, T)
        assert "refused: an earlier step raised an exception" in fmu.messages[-1][2]
        fmu.reset()  # (planner 0 again, time 0)
        fmu.run(conveyor_scenario(T), 3, T)


def _softmc_params():
    """The TrackerParams of the FMU's default parameters with planner 0 (softmc)."""
    from controller.fmu.engine import VARIABLES, tracker_params

    return tracker_params({**{row[0]: row[4] for row in VARIABLES if row[2] == "parameter"},
                           "planner": 0})


# run in a subprocess: a crash of the host (or an exit) is then seen, not suffered
_PROBE = r"""
import gc, json, sys
from controller.fmu.runner import FmuTracker, bundled_module, conveyor_scenario

path, mode = sys.argv[1], sys.argv[2]
T = 0.001
out = {}


def engine_of(fmu):
    cls = bundled_module(path, "fmu.engine").TrackerEngine
    gc.collect()  # an engine of an earlier Python instance (reset) may still be garbage
    [engine] = [o for o in gc.get_objects() if isinstance(o, cls)]
    return engine


def attached(fmu):
    # with the front attached a set input waits in the front until the next step
    engine, vr = engine_of(fmu), fmu.vr["master_x"]
    before = engine.v[vr]
    fmu.set({"master_x": before + 12.5})
    held = engine.v[vr] == before
    fmu.set({"master_x": before})
    return held


with FmuTracker(path, start_values={"planner": 0}, logging_on=False) as fmu:
    scenario = conveyor_scenario(T, engage_s=0.02, release_s=0.15)
    if mode == "attach":
        out["warnings"] = [m[2] for m in fmu.messages if m[0] == 1]
        out["attached"] = attached(fmu)
        out["reals"] = fmu.run(scenario, 200, T).reals
        fmu.reset()
        out["attached_after_reset"] = attached(fmu)
        out["again"] = fmu.run(scenario, 200, T).reals
    else:
        fmu.run(scenario, 3, T)
        engine = type(engine_of(fmu))
        step = engine._step

        def broken(self, *args):
            raise (SystemExit(7) if mode == "exit" else KeyboardInterrupt())

        engine._step = broken
        statuses = []
        for _ in range(2):
            try:
                fmu.slave.doStep(fmu.time, T)
                statuses.append("ok")
            except Exception as exc:
                statuses.append(type(exc).__name__ + ": " + str(exc))
        engine._step = step
        out["statuses"] = statuses
        out["messages"] = [[m[0], m[2]] for m in fmu.messages]
        try:
            fmu.reset()
        except Exception as exc:  # FMI 3: the wrapper made the step Fatal (fmi3Reset fails)
            out["reset"] = str(exc)
            fmu.slave = None  # after Fatal only free (the front does not call the wrapper's)
        else:
            out["after_reset"] = fmu.run(scenario, 200, T).reals
print("RESULT " + json.dumps(out))
"""


def _probe(fmu, mode, tmp_path, env=None):
    import json

    res = subprocess.run([sys.executable, "-c", _PROBE, str(fmu), mode], capture_output=True,
                         text=True, timeout=300, env=env)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
    assert res.returncode == 0 and lines, (res.returncode, res.stdout[-2000:],
                                          res.stderr[-4000:])
    return json.loads(lines[-1][len("RESULT "):]), res.stderr


def test_front_attaches_when_ruckig_is_missing(fmu_path, tmp_path):
    """Without ruckig the slave warns at instantiation, and that warning reaches the front
    during its own get of the engine's references: the front still attaches (set inputs wait
    in it until the step, also after a reset), and the outputs are the fallback planner's,
    bit for bit."""
    import os

    from controller.fmu.runner import core_run

    fake = tmp_path / "no-ruckig" / "ruckig"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('ruckig is not installed here')\n")
    env = {**os.environ,
           "PYTHONPATH": os.pathsep.join([str(fake.parent), os.environ.get("PYTHONPATH", "")])}
    got, _ = _probe(fmu_path, "attach", tmp_path, env)
    assert any("ruckig cannot be imported" in w for w in got["warnings"]), got["warnings"]
    assert got["attached"] and got["attached_after_reset"]
    scenario = conveyor_scenario(T, engage_s=0.02, release_s=0.15)
    ref = core_run(_softmc_params(), scenario, 200).reals
    assert got["reals"] == ref and got["again"] == ref


@pytest.mark.parametrize("mode", ["exit", "interrupt"])
def test_step_base_exception_is_an_error_and_later_steps_are_refused(fmu_path, mode,
                                                                     tmp_path):
    """A SystemExit or KeyboardInterrupt out of the engine's step: the host goes on.  FMI 2
    (the front calls the engine's step): the step is Error, the next one is refused (the
    tracker may be half updated), and after a reset the instance steps again.  FMI 3 (the
    wrapper calls the slave's do_step): pythonfmu3 makes it Fatal, after which the front
    refuses every call but free."""
    from controller.fmu.runner import core_run

    got, err = _probe(fmu_path, mode, tmp_path)
    name = "SystemExit" if mode == "exit" else "KeyboardInterrupt"
    first, second = got["statuses"]
    assert "failed with status 3 (error)" in second, got
    if "fmi3" in fmu_path.name or fmu_path.name.endswith("3.fmu"):
        assert "failed with status 4 (fatal)" in first, got
        assert [m[0] for m in got["messages"]] == [4] and name in got["messages"][0][1]
        assert "fmi3Reset failed with status 3" in got["reset"]
        return
    assert "fmi2DoStep failed with status 3 (error)" in first, got
    texts = [t for s, t in got["messages"] if s >= 3]
    assert len(texts) == 2, got["messages"]
    assert "the engine raised an exception" in texts[0]
    assert "refused: an earlier step raised an exception" in texts[1]
    assert name in err
    scenario = conveyor_scenario(T, engage_s=0.02, release_s=0.15)
    assert got["after_reset"] == core_run(_softmc_params(), scenario, 200).reals
