"""CanTracker.fmu (FMI 2) and CanTracker3.fmu (FMI 3) against importer mistakes: non-finite
master inputs, fixed parameters set after initialisation, a host exiting with a live
instance; units and bounds of the model description; ``cantrack fmu check`` on the FMI 3
FMU; where errors are logged."""

from __future__ import annotations

import logging
import math
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from controller.fmu.engine import POSITIVE_FLOOR, VARIABLES, tracker_params
from controller.fmu.runner import FmuTracker, conveyor_scenario, core_run
from controller.tracking import MotionState

T = 0.001
DEFAULTS = {row[0]: row[4] for row in VARIABLES if row[2] == "parameter"}


@pytest.fixture(params=["fmi2", "fmi3"])
def fmu_path(request):
    return request.getfixturevalue("fmu2_path" if request.param == "fmi2" else "fmu3_path")


def _error_records(caplog):
    return [r for r in caplog.records
            if r.name == "cantrack.fmu" and r.levelno >= logging.WARNING]


# -- gap: non-finite master inputs ------------------------------------------------------------
def test_non_finite_master_refused_state_unchanged_and_repeatable(fmu_path, caplog):
    """Engaged, then master_x = NaN (and master_vc = inf): the step is refused with Discard
    before anything changes, the error names the input and its value; repeating the step with
    finite values continues bit-identically to the core."""
    scenario = conveyor_scenario(T, engage_s=0.02)
    n_before, n_after = 60, 700
    with caplog.at_level(logging.DEBUG, logger="cantrack.fmu"), FmuTracker(
            fmu_path, start_values={"planner": 0}) as fmu:
        first = fmu.run(scenario, n_before, T)
        before = fmu.outputs()
        t_before = fmu.time
        _, e = scenario(n_before)
        for name, value in (("master_x", math.nan), ("master_vc", math.inf),
                            ("master_ay", -math.inf)):
            fmu.slave.setBoolean(fmu._engage_vr, [e])
            fmu.set({name: value})
            with pytest.raises(FMICallException) as exc:
                fmu.slave.doStep(currentCommunicationPoint=fmu.time, communicationStepSize=T)
            assert exc.value.status == 2  # fmi2Discard / fmi3Discard: state as before
            status, category, text = fmu.messages[-1]
            assert status == 2 and category == "logStatusDiscard"  # the call's status
            assert f"{name}={value!r}" in text and "non-finite master input" in text
            assert not text.endswith("\n")
            assert fmu.outputs() == before and fmu.time == t_before
            fmu.set({name: 0.0})
        # nothing was done: the same step with the finite master goes on as if never refused
        rest = fmu.run(scenario, n_after, T, first_step=n_before)
    ref = core_run(tracker_params({**DEFAULTS, "planner": 0}), scenario, n_before + n_after)
    assert first.reals + rest.reals == ref.reals and first.ints + rest.ints == ref.ints
    assert {row[1] for row in rest.ints} >= {2}  # synchronised after the refusals
    assert all(math.isfinite(x) for row in rest.reals for x in row)
    # the Python logger: ERROR in FMI 2 (pythonfmu forwards only with loggingOn), only DEBUG
    # in FMI 3 (pythonfmu3 always forwards errors to logMessage: no second copy on stderr)
    logged = [r for r in caplog.records if "non-finite master input" in r.getMessage()]
    assert len(logged) == 3
    assert {r.levelno for r in logged} == (
        {logging.DEBUG} if fmu_path.name == "CanTracker3.fmu" else {logging.ERROR})


def test_non_finite_master_before_engage_is_refused(fmu_path):
    """master_c = NaN from the start: the first step is refused (not SYNCING with NaN)."""
    with FmuTracker(fmu_path, start_values={"planner": 0}) as fmu:
        fmu.set({"master_c": math.nan, "engage": True})
        with pytest.raises(FMICallException) as exc:
            fmu.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=T)
        assert exc.value.status == 2
        assert "master_c=nan" in fmu.messages[-1][2]
        reals, ints = fmu.outputs()
        assert ints == [0, 0, 0] and reals == [0.0] * 12  # still OFF at the initial setpoint
        fmu.set({"master_c": 10.0})
        fmu.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=T)
        assert fmu.outputs()[1][1] == 1  # SYNCING, finite
        assert all(math.isfinite(x) for x in fmu.outputs()[0])


def test_non_finite_initial_position_fails_initialisation(fmu_path):
    with FmuTracker(fmu_path, start_values={"planner": 0, "y0": math.inf},
                    init_errors=True) as fmu:
        assert fmu.init_error.status == 3  # fmiXError from exitInitializationMode
        assert fmu.messages[-1][2] == ("tracker: exitInitializationMode refused the "
                                       "parameters: y0=inf must be finite")
        with pytest.raises(FMICallException) as exc:
            fmu.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=T)
        assert exc.value.status == 3 and "y0=inf" in fmu.messages[-1][2]


# -- gap: fixed parameters after initialisation -------------------------------------------
def test_fixed_parameters_after_initialisation_are_refused(fmu_path, caplog):
    """sample_time, mode, planner, x0 set after exitInitializationMode: each logged as an error
    naming it and ignored; the run equals the core with the initial values; re-setting the
    current value is silent; tunables stay settable."""
    scenario = conveyor_scenario(T, engage_s=0.05)
    with caplog.at_level(logging.DEBUG, logger="cantrack.fmu"), FmuTracker(
            fmu_path, start_values={"planner": 0, "x0": 1.0}) as fmu:
        n_msgs = len(fmu.messages)
        changes = {"sample_time": 0.002, "mode": 4, "planner": 1, "x0": 7.0}
        for name, value in changes.items():
            with pytest.raises(FMICallException) as exc:
                fmu.set({name: value})
            assert exc.value.status == 3  # fmiXError (the front library: the logged status)
            status, category, text = fmu.messages[-1]
            assert status == 3 and category == "logStatusError"
            assert f"{name}={value!r} refused and ignored" in text and "fixed parameter" in text
        assert len(fmu.messages) == n_msgs + len(changes)
        fmu.set({"sample_time": T, "planner": 0, "x0": 1.0})  # unchanged values: accepted
        assert len(fmu.messages) == n_msgs + len(changes)
        got = fmu.run(scenario, 500, T)
        # the refused values were not stored either: a saved state replays the same
        state = fmu.get_state()
        blob = fmu.serialize_state(state)
        fmu.free_state(state)
        restored = fmu.deserialize_state(blob)
        fmu.set_state(restored)
        fmu.free_state(restored)
        with pytest.raises(FMICallException):
            fmu.set({"mode": 5})  # still refused after restoring a state
        assert "mode=5 refused" in fmu.messages[-1][2]
    ref = core_run(tracker_params({**DEFAULTS, "planner": 0, "x0": 1.0}), scenario, 500,
                   initial=MotionState.at(1.0))
    assert got.reals == ref.reals and got.ints == ref.ints
    assert {row[1] for row in got.ints} >= {1, 2} and {row[2] for row in got.ints} == {0}
    assert not any("tunable parameter is invalid" in m for _, _, m in fmu.messages)
    refused = [r for r in caplog.records if "refused and ignored" in r.getMessage()]
    assert len(refused) == 5


# -- gap: units and bounds -----------------------------------------------------------------
def test_dimensionless_units_and_positive_minima(fmu_path):
    md = read_model_description(str(fmu_path))
    v = {x.name: x for x in md.modelVariables}
    units = {u.name: u for u in md.unitDefinitions}
    one = units["1"].baseUnit
    assert (one.kg, one.m, one.s, one.A, one.K, one.mol, one.cd, one.rad) == (0,) * 8
    assert one.factor == 1.0 and one.offset == 0.0
    for name in ("filter_factor", "damping_factor"):
        assert v[name].unit == "1", name
    positive = [row[0] for row in VARIABLES if row[2] == "parameter" and row[3] == "tunable"
                and row[1] == "Real"]
    assert len(positive) == 16
    for name in positive:  # > 0: declared as the floor the FMU accepts (bounds are inclusive)
        assert v[name].min is not None and float(v[name].min) == POSITIVE_FLOOR, name
        assert float(v[name].start) > 0, name
    assert float(v["max_flops"].min) == 1
    # every Real carries a unit the model description defines
    for x in md.modelVariables:
        if x.type in ("Real", "Float64") and x.name != "time":
            assert x.unit in units, x.name


# -- gap: cantrack fmu check on the FMI 3 FMU ----------------------------------------------
def test_check_runs_smoke_cosimulation_on_fmi3(fmu3_path):
    from controller.fmu.check import check_fmu

    report = check_fmu(fmu3_path, fmutool=False, planner=0)
    items = {i.name: i for i in report.items}
    for name in ("fmpy validate", "smoke co-simulation", "core identity", "step-size refusal",
                 "FMU state"):
        assert items[name].ok is True, report.format()
    assert "fmi3Discard" in items["step-size refusal"].detail
    assert report.summary.startswith("FMI 3.0 Co-Simulation") and report.passed


# -- a host that exits with a live instance ------------------------------------------------
#: what the process's stderr must not contain when it ends (nanobind's report of objects
#: alive at its module's teardown, glibc's and CPython's abort messages)
EXIT_TROUBLE = ("nanobind", "leaked", "Abort", "abort", "corrupted", "Segmentation",
                "Fatal Python error", "double free")


def _optimal_available() -> bool:
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:
        return False
    return True


@pytest.mark.parametrize("master_input", [0, 1])
def test_host_exiting_with_a_live_instance_ends_cleanly(fmu_path, tmp_path, master_input):
    """A Python host (fmpy) that instantiates, steps through the approach into SYNCED (the
    optimal planner's ruckig objects alive; with master_input=1 the conditioners too) and
    exits without terminate/freeInstance: exit status 0, nothing on stderr about leaked
    objects or an abort (the runtime's exit hook releases the live engines while the
    interpreter still works)."""
    if not _optimal_available():
        pytest.skip("needs ruckig: the live objects at exit are the optimal planner's")
    script = textwrap.dedent(f"""
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave
        fmu = {str(fmu_path)!r}
        md = read_model_description(fmu)
        vr = {{v.name: v.valueReference for v in md.modelVariables}}
        fmi3 = md.fmiVersion.startswith("3")
        s = (FMU3Slave if fmi3 else FMU2Slave)(
            guid=md.guid, unzipDirectory=extract(fmu),
            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="live")
        s.instantiate()
        if fmi3:
            s.enterInitializationMode(startTime=0.0)
            s.setInt64([vr["master_input"]], [{master_input}])
        else:
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            s.setInteger([vr["master_input"]], [{master_input}])
        s.exitInitializationMode()
        set_real = s.setFloat64 if fmi3 else s.setReal
        get_int = s.getInt32 if fmi3 else s.getInteger
        for k in range(400):
            t = k * 0.001
            set_real([vr["master_x"], vr["master_vx"]], [100.0 + 300.0 * t, 300.0])
            s.setBoolean([vr["engage"]], [t >= 0.05])
            s.doStep(t, 0.001)
        print("state", get_int([vr["state"]])[0], flush=True)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "state 2" in proc.stdout, proc.stdout  # SYNCED: the planner's objects were made
    trouble = [w for w in EXIT_TROUBLE if w in proc.stderr]
    assert trouble == [], proc.stderr[-3000:]
