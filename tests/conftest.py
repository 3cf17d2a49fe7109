"""Shared test configuration: a derandomised hypothesis profile, the shared fixtures."""

import os
import subprocess
import sys
from pathlib import Path

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


def _required_in_ci(pytestconfig) -> bool:
    """Whether a test that cannot run here fails instead of being skipped: in CI, that is
    with ``--vcan-required`` (by default from ``CANTRACK_VCAN_REQUIRED=1``, which .ci/run
    sets) or ``CI=true``."""
    return bool(pytestconfig.getoption("--vcan-required")) or os.environ.get("CI") == "true"


def _skip_or_fail(pytestconfig, why: str) -> None:
    """Skip the test with ``why``; in CI (:func:`_required_in_ci`) fail with it."""
    if _required_in_ci(pytestconfig):
        pytest.fail(why, pytrace=False)
    pytest.skip(why)


@pytest.fixture(scope="session")
def skip_or_fail(pytestconfig):
    """``skip_or_fail(why)``: skip the test with ``why``, or in CI fail with it
    (:func:`_required_in_ci`), for tests that need something this install may lack."""
    return lambda why: _skip_or_fail(pytestconfig, why)


def _vendor_build(pytestconfig, available, build):
    """A vendor build for a test tier: ``available()`` -> (ok, why) first; skipped where the
    sources are absent, a failure in CI (:func:`_required_in_ci`), a failed build a
    failure (one :class:`~controller.testing.vendor.VendorError` for every vendor build)."""
    from controller.testing.vendor import VendorError

    ok, why = available()
    if not ok:
        _skip_or_fail(pytestconfig, why)
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


@pytest.fixture(scope="session")
def pure_wheel(tmp_path_factory) -> Path:
    """The checkout's wheel without the compile (``CANTRACK_NO_EXTENSIONS=1``: pure Python,
    a few seconds), built once per session: ``pip wheel --no-deps --no-build-isolation``
    (setuptools and wheel come with the test extra; nothing from the index).  A test that
    needs a compiled install adds the installed compiled modules to its unpacked copy
    (tests/test_fmu.py::test_build_from_a_compiled_install) instead of compiling again."""
    root = Path(__file__).resolve().parents[1]
    dist = tmp_path_factory.mktemp("pure-wheel")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-q", "-w", str(dist), str(root)],
                       capture_output=True, text=True, timeout=300,
                       env={**os.environ, "CANTRACK_NO_EXTENSIONS": "1"})
    assert r.returncode == 0, f"pip wheel {root} failed:\n{r.stderr[-2000:]}"
    (wheel,) = dist.glob("cantrack-*.whl")
    return wheel


@pytest.fixture(scope="session")
def compiled_tracking(pytestconfig) -> Path:
    """The installed ``controller/tracking`` folder of a compiled install (its extension
    modules and ``_native_manifest.json``, docs/architecture.md "Compiled core").  Where the
    install is pure (no C compiler at ``pip install``, ``CANTRACK_NO_EXTENSIONS=1``) the test
    is skipped; in CI (.ci/run installs gcc and the headers first) it fails."""
    import controller.tracking

    directory = Path(controller.tracking.__file__).resolve().parent
    compiled = [p for p in directory.iterdir() if p.name.endswith((".so", ".pyd"))]
    if not compiled or not (directory / "_native_manifest.json").is_file():
        _skip_or_fail(pytestconfig, f"{directory}: the tracking core is not compiled in this "
                      "install (pip install -e . needs a C compiler and the Python headers; "
                      "CANTRACK_NO_EXTENSIONS unset)")
    return directory
