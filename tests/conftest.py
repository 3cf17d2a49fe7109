"""Shared test configuration: a derandomised hypothesis profile."""

import pytest
from hypothesis import settings

# (the hil/vcan plugin, controller.testing.pytest_plugin, is registered by the installed
# package's pytest11 entry point)

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.load_profile("ci")


@pytest.fixture
def stepped_controller():
    """``stepped_controller(cfg, **kw)`` -> (SimWorld, Controller) on a stepped virtual bus
    (``controller.canopen.testing.stepped``); the worlds are closed after the test."""
    from controller.canopen.testing import stepped
    worlds = []

    def _make(cfg, **kw):
        world, ctl = stepped(cfg, **kw)
        worlds.append(world)
        return world, ctl
    yield _make
    for w in worlds:
        w.close()


#: the belt point the supervision and bus-fault tests follow [mm]
FOLLOW_OFFSET = (420.0, 30.0, 0.0)


@pytest.fixture
def booted_follow(tmp_path, stepped_controller):
    """``booted_follow(text=None, end_cycle=600, **kw)`` -> (SimWorld, Controller): the
    two-drive bus (``text``, else the default bus.yml) booted in stepped time, following
    the belt point at ``FOLLOW_OFFSET`` from cycle 10."""
    from controller.canopen.config import load_config
    from controller.canopen.apps.follow import ConveyorFollow
    from controller.canopen.testing import bus_yml, load

    def _make(text: str | None = None, end_cycle: int = 600, **kw):
        cfg = load_config(bus_yml(tmp_path, text=text)) if text else load(tmp_path)
        app = ConveyorFollow(10, None, FOLLOW_OFFSET, end_cycle=end_cycle)
        world, ctl = stepped_controller(cfg, source=app, **kw)
        ctl.boot()
        return world, ctl
    return _make


def _vendor_build(pytestconfig, available, build):
    """A vendor build for a test tier: ``available()`` -> (ok, why) first; skipped where the
    sources are absent, a failure in CI (``--vcan-required`` or CI=true), a failed build a
    failure (one :class:`~controller.testing.vendor.VendorError` for every vendor build)."""
    import os

    from controller.testing.vendor import VendorError

    ok, why = available()
    required = pytestconfig.getoption("--vcan-required") or os.environ.get("CI") == "true"
    if not ok:
        if required:
            pytest.fail(why, pytrace=False)
        pytest.skip(why)
    try:
        return build()
    except VendorError as exc:
        pytest.fail(str(exc), pytrace=False)


@pytest.fixture(scope="module")
def canopen_stack(pytestconfig):
    """The independent CANopen stack (CANopenNode's canopend, cocomm, the demo device) built
    from the vendor sources: skipped where they are absent, a failure in CI."""
    from controller.testing.vendor import build_stack, stack_available
    return _vendor_build(pytestconfig, stack_available, build_stack)


@pytest.fixture(scope="module")
def fmi_tools(pytestconfig):
    """The independent FMI importers (the Reference-FMUs' fmusim, the FMU Compliance Checker)
    built from the vendor sources: skipped where they are absent, a failure in CI."""
    from controller.testing.fmi_tools import build_tools, tools_available
    return _vendor_build(pytestconfig, tools_available, build_tools)


def _conveyor_example(name: str):
    from pathlib import Path

    from controller.simulate import run_scenario
    return run_scenario(Path(__file__).resolve().parents[1] / "examples" / name)


@pytest.fixture(scope="session")
def linear():
    """The ConveyorResult of examples/conveyor_linear.yaml (simulated once per session)."""
    return _conveyor_example("conveyor_linear.yaml")


@pytest.fixture(scope="session")
def rotary():
    """The ConveyorResult of examples/conveyor_rotary.yaml (simulated once per session)."""
    return _conveyor_example("conveyor_rotary.yaml")


@pytest.fixture(scope="session")
def fmu2_path(tmp_path_factory):
    """The session's CanTracker.fmu (the folder test_fmu.py and test_fmu_cosim.py use too)."""
    pytest.importorskip("pythonfmu")
    from controller.fmu import build_conveyor_fmu, build_tracker_fmu

    d = tmp_path_factory.getbasetemp() / "fmu-build"
    if not (d / "CanConveyor.fmu").is_file():
        build_tracker_fmu(d)
        build_conveyor_fmu(d)
    return d / "CanTracker.fmu"


@pytest.fixture(scope="session")
def fmu3_path(tmp_path_factory):
    """The session's CanTracker3.fmu (the folder test_fmu3.py uses too)."""
    pytest.importorskip("pythonfmu3")
    from controller.fmu import build_tracker_fmu3

    d = tmp_path_factory.getbasetemp() / "fmu3-build"
    if not (d / "CanTracker3.fmu").is_file():
        build_tracker_fmu3(d)
    return d / "CanTracker3.fmu"
