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


@pytest.fixture(scope="session")
def conveyor_example_run():
    """``conveyor_example_run(name)`` -> the ConveyorResult of ``examples/<name>`` (each example
    simulated once per session, shared by the conveyor tests)."""
    from pathlib import Path

    from controller.simulate import run_scenario
    examples = Path(__file__).resolve().parents[1] / "examples"
    cache: dict = {}

    def _run(name: str):
        if name not in cache:
            cache[name] = run_scenario(examples / name)
        return cache[name]
    return _run
