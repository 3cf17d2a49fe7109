"""The scenario getters of controller.yamlmarks.Section (the one reader of bus.yml and the
scenario files): each error names the file, the line of the value and the dotted key."""

from __future__ import annotations

import pytest

from controller.errors import ConfigError
from controller.yamlmarks import Section, load_marked

TEXT = """\
tracker:
  sample_time_s: 0.002
  window: {upstream: 50, downstream: 1500}
robot:
  start: [0, 0, 1.0e7]
  slave:
items:
  - {time_s: 0.5}
  - {time_s: -1}
"""


def _top() -> Section:
    return Section(load_marked(TEXT, "cell.yml"), "cell.yml", line=1, root="the scenario")


def _err(call) -> tuple[int | None, str | None, str]:
    with pytest.raises(ConfigError) as e:
        call()
    return e.value.line, e.value.key, str(e.value)


def test_numbers_with_units_and_open_bounds():
    t = _top().section("tracker")
    assert t.number("sample_time_s", lo=0.0, lo_open=True, unit="s") == 0.002
    line, key, msg = _err(lambda: t.number("sample_time_s", lo=0.002, lo_open=True, unit="s"))
    assert (line, key) == (2, "tracker.sample_time_s")
    assert "must be > 0.002 s" in msg
    w = t.section("window")
    assert w.number("downstream", hi=1500, unit="mm") == 1500.0
    line, key, msg = _err(lambda: w.number("downstream", hi=1500, hi_open=True, unit="mm"))
    assert (line, key) == (3, "tracker.window.downstream") and "< 1500 mm" in msg


def test_a_position_beyond_a_kilometre_and_an_empty_value_are_named():
    r = _top().section("robot")
    line, key, msg = _err(lambda: r.xyz("start", unit="mm"))
    assert (line, key) == (5, "robot.start") and "item 2" in msg and "out of range" in msg
    line, key, msg = _err(lambda: r.number("slave", 5))
    assert (line, key) == (6, "robot.slave") and "has no value" in msg
    # from Python, None is "not given": the default
    assert Section({"slave": None}, "<scenario>").number("slave", 5) == 5


def test_check_keys_lists_the_valid_keys_and_the_closest():
    line, key, msg = _err(lambda: _top().check_keys(("tracker", "robot", "itens")))
    assert (line, key) == (7, "items")
    assert "unknown key in the scenario; did you mean 'itens'?" in msg
    assert "(valid keys: tracker, robot, itens)" in msg


def test_list_items_are_sections_of_the_same_file_at_their_lines():
    top = _top()
    items = [top.child(v, path, line) for v, line, path in top.list("items")]
    assert items[0].number("time_s", lo=0.0) == 0.5
    line, key, msg = _err(lambda: items[1].number("time_s", lo=0.0, unit="s"))
    assert (line, key) == (9, "items[1].time_s") and ">= 0 s" in msg
    assert items[1].file == "cell.yml" and items[1].root == "the scenario"
    e = items[1].fail("a trigger before the start", items[1].head, items[1].path)
    assert str(e).startswith("cell.yml:9, key 'items[1]'")


def test_required_and_optional_sections():
    top = _top()
    assert top.optional_section("conveyor") is None
    line, key, msg = _err(lambda: top.section("conveyor"))
    assert key == "conveyor" and "required key is missing" in msg
    assert top.optional_section("robot").head == 4
