"""``cantrack capacity`` (issue 16, point 7): the capacity map of the shipped linear example
agrees with full simulations at points on both sides of its boundary; the limiting reasons;
the command's output and errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller.cli import main as cli_main
from controller.errors import ConfigError, ParameterError
from controller.simulate.capacity import (REASONS, capacity, full_simulation, pick_cycle)
from controller.simulate.scenario import load_scenario

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "conveyor_linear.yaml"
SPEEDS = (150.0, 250.0, 350.0, 450.0, 550.0, 650.0)
SPACINGS = (250.0, 450.0, 650.0, 850.0)


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(EXAMPLE)


@pytest.fixture(scope="module")
def cap(scenario):
    return capacity(scenario, SPEEDS, SPACINGS, workers=2)


def test_the_map_agrees_with_full_simulations_on_both_sides_of_the_boundary(scenario, cap):
    points = []   # (speed, spacing, predicted good)
    for j, s in enumerate(SPACINGS):
        b = cap.boundary[0][j]
        assert b is not None and b < SPEEDS[-1], f"spacing {s}: the boundary must be inside"
        k = SPEEDS.index(b)
        points += [(b, s, True), (SPEEDS[k + 1], s, False)]
    # one more on each side, further from the boundary
    k = SPEEDS.index(cap.boundary[0][-1])
    points += [(SPEEDS[k - 1], SPACINGS[-1], True), (SPEEDS[-1], SPACINGS[0], False)]
    assert sum(1 for p in points if p[2]) >= 5 and sum(1 for p in points if not p[2]) >= 5
    assert len(set(points)) >= 10
    for v, s, good in points:
        ok, reason, before_loss = cap.point(v, s)
        assert ok == good
        # enough items for the predicted loss to happen (near the boundary the backlog grows
        # slowly: the index of the first loss is a rough figure, its occurrence is not)
        picked, n, why = full_simulation(scenario, v, s, 8 if good else 2 * before_loss + 5)
        if good:
            assert picked == n == 8, (v, s, why)
        else:
            assert reason in REASONS
            assert picked < n, (v, s, "the map says an item is lost, the simulation "
                                      "picked all")


def test_boundary_rises_with_the_spacing_and_pick_time_limits_this_cell(cap):
    b = list(cap.boundary[0])
    assert b == sorted(b)                  # wider spacing: a faster belt is fine
    assert set(cap.limit[0]) == {"pick time"}
    assert cap.cycles > 0 and cap.elapsed_s > 0


def test_single_cycle_reasons(scenario):
    assert pick_cycle(scenario, 250.0, 0.0).ok
    assert pick_cycle(scenario, 250.0, 1050.0).reason == "approach time"
    # the item reached late in the window: synchronised, but the grip does not end in it
    late = [pick_cycle(scenario, 600.0, x) for x in (400.0, 500.0)]
    assert all(c.reason == "window length" for c in late)
    # faster than the frame's VelocityMaxTrans (1000 mm/s)
    assert pick_cycle(scenario, 1100.0, 0.0).reason == "limits"


def test_the_command_prints_the_boundary_and_writes_map_and_json(tmp_path, capsys):
    out = tmp_path / "c.json"
    png = tmp_path / "c.png"
    code = cli_main(["capacity", str(EXAMPLE), "--speeds", "400:400:1", "--spacings",
                     "400,800", "--workers", "1", "--plot", str(png), "--json", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "fastest 100 % belt speed" in text and "pick cycles simulated" in text
    data = json.loads(out.read_text())
    assert data["speeds"] == [400.0] and data["spacings"] == [400.0, 800.0]
    assert data["boundary"][0] == [None, 400.0]   # 800 mm apart 400 mm/s is fine, 400 not
    assert data["limit"][0][0] == "pick time" and data["ok"] == [[[False], [True]]]
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_command_errors(tmp_path, capsys):
    assert cli_main(["capacity", str(EXAMPLE), "--speeds", "5:1:3"]) == 2
    assert "--speeds" in capsys.readouterr().err
    other = EXAMPLE.parent / "linear_absolute.yaml"
    assert cli_main(["capacity", str(other)]) == 2
    assert "needs a conveyor scenario" in capsys.readouterr().err
    with pytest.raises(ParameterError, match="spacings"):
        capacity(load_scenario(EXAMPLE), [100.0], [0.0])
    with pytest.raises(ConfigError):
        capacity(load_scenario(other), [100.0], [100.0])


def test_window_placement_is_a_sweep_dimension(scenario):
    """Shifting the window 500 mm downstream (further from the robot's place position):
    longer cycles, so 450 mm/s at 800 mm spacing no longer picks every item."""
    r = capacity(scenario, [450.0], [800.0], [0.0, 500.0], workers=2)
    assert r.ok.shape == (2, 1, 1)
    assert r.point(450.0, 800.0, 0.0)[:2] == (True, "")
    assert r.point(450.0, 800.0, 500.0)[:2] == (False, "pick time")
    assert r.boundary == [[450.0], [None]]
