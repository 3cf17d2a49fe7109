"""FMI conformance details of CanTracker (FMI 2), CanTracker3 (FMI 3) and CanConveyor in fmpy:
the communication time grid (an OMSimulator-style accumulated time runs to the end), jumps
and calls after terminate refused, declared ranges = accepted ranges, the model description
(output dependencies, fixedInternalStepSize, stopTime)."""

from __future__ import annotations

import math
import zipfile
from xml.etree import ElementTree

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from controller.fmu.engine import ENUMERATIONS, VARIABLES, tracker_params
from controller.fmu.runner import (FmuRunError, FmuTracker, conveyor_scenario, core_run,
                                   master_values)

T = 0.001
DEFAULTS = {row[0]: row[4] for row in VARIABLES if row[2] == "parameter"}


@pytest.fixture(params=["fmi2", "fmi3"])
def fmu_path(request):
    return request.getfixturevalue("fmu2_path" if request.param == "fmi2" else "fmu3_path")


# -- the communication time grid ---------------------------------------------------------
@pytest.mark.parametrize("stop", [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 5.0, 10.0])
def test_accumulated_time_runs_to_the_end(fmu_path, stop):
    """OMSimulator's loop: time += step, the last step min(step, stop - time).  Accumulated
    rounding leaves a last step of ~1e-13 s for 1.5, 2, 2.5, 3 and 10 s: a no-op, not an
    error; every other step gives the core's numbers."""
    scenario = conveyor_scenario(T, engage_s=0.1, release_s=0.8 * stop)
    n = round(stop / T)
    ref = core_run(tracker_params({**DEFAULTS, "planner": 0}), scenario, n)
    rows, remainders = [], []
    last = None
    with FmuTracker(fmu_path, start_values={"planner": 0}) as fmu:
        t, k = 0.0, 0
        while t < stop:
            h = min(T, stop - t)
            m, e = scenario(k)
            fmu._set_real(fmu._in_vrs, master_values(m))
            fmu.slave.setBoolean(fmu._engage_vr, [e])
            fmu.slave.doStep(t, h)  # raises on any status but OK/warning
            if h < 0.5 * T:
                remainders.append(h)
                assert fmu.outputs() == last  # the remainder changed nothing
            else:
                last = fmu.outputs()
                rows.append(last)
                k += 1
            t += h
        assert [m for m in fmu.messages if m[0] >= 2] == []
    assert bool(remainders) == (stop in (1.5, 2.0, 2.5, 3.0, 10.0))
    assert all(0 < h < 1e-12 for h in remainders)
    assert [r for r, _ in rows] == ref.reals and [i for _, i in rows] == ref.ints


def test_steps_off_the_grid_and_jumps_are_refused(fmu_path):
    """A step that ends off the grid t0 + k*T, or starts elsewhere than where the last one
    ended, is refused with Discard; nothing changes and the run goes on as the core's."""
    scenario = conveyor_scenario(T, engage_s=0.02)
    ref = core_run(tracker_params({**DEFAULTS, "planner": 0}), scenario, 120)
    with FmuTracker(fmu_path, start_values={"planner": 0}) as fmu:
        first = fmu.run(scenario, 60, T)
        before = fmu.outputs()
        for t, h, what in ((fmu.time + T, T, "previous step ended at"),
                           (fmu.time - T, T, "previous step ended at"),
                           (fmu.time, 0.4 * T, "must end on the sample grid"),
                           (fmu.time, 1.5 * T, "must end on the sample grid")):
            with pytest.raises(FMICallException) as exc:
                fmu.slave.doStep(t, h)
            assert exc.value.status == 2, what
            assert what in fmu.messages[-1][2] and fmu.messages[-1][0] == 2
            assert fmu.outputs() == before
        rest = fmu.run(scenario, 60, T, first_step=60)
    assert first.reals + rest.reals == ref.reals and first.ints + rest.ints == ref.ints


def test_start_time_grid(fmu_path):
    """Started at 0.25 s, the grid is 0.25 + k*T: steps from there are accepted."""
    scenario = conveyor_scenario(T, engage_s=0.01)
    ref = core_run(tracker_params({**DEFAULTS, "planner": 0}), scenario, 50)
    with FmuTracker(fmu_path, start_values={"planner": 0}, start_time=0.25) as fmu:
        got = fmu.run(scenario, 50, T)
        assert math.isclose(fmu.time, 0.3, abs_tol=1e-12)
    assert got.reals == ref.reals and got.ints == ref.ints


def test_calls_after_terminate_are_refused(fmu_path):
    """After terminate: steps and setters refused (Error), getters still answer; reset
    makes the instance usable again."""
    with FmuTracker(fmu_path, start_values={"planner": 0}) as fmu:
        fmu.run(conveyor_scenario(T), 5, T)
        before = fmu.outputs()
        fmu.slave.terminate()
        with pytest.raises(FMICallException) as exc:
            fmu.slave.doStep(fmu.time, T)
        assert "refused: the instance is terminated" in fmu.messages[-1][2]
        assert fmu.messages[-1][0] == 3 and exc.value.status == 3
        for name, value in (("master_x", 1.0), ("engage", True), ("vel_sync", 100.0)):
            with pytest.raises(FMICallException) as exc:
                fmu.set({name: value})
            assert exc.value.status == 3
            assert "refused: the instance is terminated" in fmu.messages[-1][2]
        assert fmu.outputs() == before
        fmu.reset()  # (planner 0 again, time 0)
        fmu.run(conveyor_scenario(T), 5, T)


# -- declared ranges = accepted ranges ----------------------------------------------------
def _ranges():
    """(name, accepted values, refused values) from the declared min/max/enumeration."""
    out = []
    for name, typ, causality, _v, _start, _u, _d, extra in VARIABLES:
        if causality != "parameter":
            continue
        if "enumeration" in extra:
            items = [v for _, v in ENUMERATIONS[extra["enumeration"]]]
            gaps = [v for v in range(min(items) - 1, max(items) + 2) if v not in items]
            out.append((name, items, gaps))
        elif "min" in extra or "max" in extra:
            ok, bad = [], []
            for key, direction in (("min", -math.inf), ("max", math.inf)):
                if key in extra:
                    bound = float(extra[key])
                    ok.append(int(bound) if typ == "Integer" else bound)
                    bad.append(int(bound) + (1 if key == "max" else -1) if typ == "Integer"
                               else math.nextafter(bound, direction))
            out.append((name, ok, bad))
    return out


def test_declared_ranges_are_the_accepted_ranges(fmu2_path):
    """Every parameter with a declared range: its bounds (enumeration items) are accepted at
    exitInitializationMode, the next value outside is refused in one line naming it."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu2_path))
    declared = {v.name: v for v in md.modelVariables}
    ranges = _ranges()
    assert {r[0] for r in ranges} >= {"sample_time", "mode", "planner", "vel_sync",
                                      "max_flops", "filter_factor"}
    for name, accepted, refused in ranges:
        if declared[name].type != "Enumeration":
            for key in ("min", "max"):
                x = dict(VARIABLES[[r[0] for r in VARIABLES].index(name)][7]).get(key)
                assert (getattr(declared[name], key) is None) == (x is None), name
        for value in accepted:
            with FmuTracker(fmu2_path, start_values={"planner": 0, name: value}) as fmu:
                assert [m for m in fmu.messages if m[0] >= 2] == [], (name, value)
        for value in refused:
            with FmuTracker(fmu2_path, start_values={"planner": 0, name: value},
                            init_errors=True) as fmu:
                assert fmu.init_error is not None and fmu.init_error.status == 3
                errors = [m for m in fmu.messages if m[0] >= 2]
                assert len(errors) == 1 and "\n" not in errors[0][2], (name, value)
                assert f"{name}={value!r}" in errors[0][2], (name, value, errors)


def test_no_hidden_bounds():
    """Parameters without a declared max accept any large finite value (1e300) in the core
    as well; without a declared min, any negative one: nothing refuses what is declared."""
    from controller.fmu.engine import parameter_errors
    from controller.tracking import MotionState, Tracker

    for name, typ, causality, _v, _start, _u, _d, extra in VARIABLES:
        if causality != "parameter" or typ != "Real" or name == "sample_time":
            continue
        probes = ([] if "max" in extra else [1e300]) + ([] if "min" in extra else [-1e300])
        for value in probes:
            values = {**DEFAULTS, "planner": 0, name: value}
            assert parameter_errors(values) == [], (name, value)
            Tracker(tracker_params(values), MotionState.at())  # no ParameterError


def test_mode_is_an_enumeration_of_the_accepted_values(fmu_path):
    md = read_model_description(str(fmu_path))
    (mode,) = [v for v in md.modelVariables if v.name == "mode"]
    assert mode.type == "Enumeration" and mode.declaredType.name == "Mode"
    assert [(i.name, int(i.value)) for i in mode.declaredType.items] == [
        ("absolute", 3), ("relative", 5)]
    with FmuTracker(fmu_path, start_values={"planner": 0, "mode": 5}) as fmu:
        assert [m for m in fmu.messages if m[0] >= 2] == []
    with pytest.raises(FmuRunError, match=r"mode=4 must be one of 3 \(absolute\), 5 "
                                          r"\(relative\)"):
        FmuTracker(fmu_path, start_values={"planner": 0, "mode": 4})


def test_conveyor_parameters_validated_in_one_line(fmu2_path):
    """CanConveyor: an invalid parameter is one error line at exitInitializationMode (not
    Fatal with "unknown error"), steps are refused, the instance can be freed."""
    from fmpy import calloc, extract, free
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE,
                           fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)

    path = fmu2_path.with_name("CanConveyor.fmu")
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    assert float(md.defaultExperiment.stopTime) == 3.0
    assert float([v for v in md.modelVariables if v.name == "speed"][0].min) == 1e-9
    messages = []
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(
        lambda env, name, status, cat, msg: messages.append((status, msg.decode())))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                  modelIdentifier="CanConveyor", instanceName="conv")
    s.instantiate(callbacks=cb, loggingOn=True)
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.setReal([vr["speed"]], [0.0])
    with pytest.raises(FMICallException) as exc:
        s.exitInitializationMode()
    assert exc.value.status == 3  # fmi2Error, not Fatal ("unknown error")
    assert messages[-1] == (3, "conv: exitInitializationMode refused the parameters: "
                               "speed=0.0 mm/s is outside its declared range [1e-09, inf]")
    with pytest.raises(FMICallException) as exc:
        s.doStep(0.0, T)
    assert "refused" in messages[-1][1] and messages[-1][0] == 3 and exc.value.status == 3
    s.terminate()
    s.freeInstance()


# -- model description -----------------------------------------------------------------
def test_fmi3_output_dependencies_and_internal_step(fmu3_path):
    with zipfile.ZipFile(fmu3_path) as zf:
        root = ElementTree.fromstring(zf.read("modelDescription.xml"))
    cs = root.find("CoSimulation")
    assert float(cs.get("fixedInternalStepSize")) == DEFAULTS["sample_time"]
    outputs = root.find("ModelStructure").findall("Output")
    assert len(outputs) == 17 and all(o.get("dependencies") == "" for o in outputs)
    initial = {int(u.get("valueReference")): u.get("dependencies")
               for u in root.find("ModelStructure").findall("InitialUnknown")}
    vr = {row[0]: i for i, row in enumerate(VARIABLES)}
    assert initial[vr["x"]] == str(vr["x0"]) and initial[vr["vx"]] == ""
    assert initial[vr["master_status"]] == str(vr["master_input"])
    md = read_model_description(str(fmu3_path))
    assert float(md.defaultExperiment.stopTime) == 1.0
