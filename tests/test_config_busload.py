"""Bus load from the configuration: worst-case bits per cycle, warn > 60 %, refuse > 90 %."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from controller.canopen.config import load_config
from controller.canopen.config.busload import (
    MAX_LOAD,
    WARN_LOAD,
    bus_load,
    check_bus_load,
    frame_bits,
)
from controller.canopen.testing import bus_yml, stepped
from controller.errors import ConfigError

DEMO = Path(__file__).resolve().parents[1] / "examples" / "bus" / "demo.yml"


def test_frame_bits_worst_case_stuffing():
    # 8n + 47 + floor((33 + 8n)/4)   (canopen-notes.md)
    assert [frame_bits(n) for n in (0, 1, 4, 6, 8)] == [55, 65, 95, 115, 135]
    with pytest.raises(ValueError):
        frame_bits(9)


def test_demo_bus_load():
    load = bus_load(load_config(DEMO))
    # SYNC(1 byte) 65 + encoder 95 + 4 x (RPDO 115 + TPDO 115) = 1080 bit per cycle, plus
    # 6 heartbeats every 50 ms (65 bit x 2/50) and 4 TPDO3 every 100 ms (125 bit x 2/100)
    expected = 65 + 95 + 4 * 230 + 6 * 65 * 2 / 50 + 4 * 125 * 2 / 100
    assert load.bits_per_cycle == pytest.approx(expected)
    assert load.load == pytest.approx(expected / 2000)
    assert 0.5 < load.load < WARN_LOAD
    assert "bus load 55.3 %" in load.table()


def test_warns_above_60_percent(tmp_path, caplog):
    cfg = load_config(bus_yml(tmp_path, axes=("x", "y", "z", "c"), period_us=1500))
    with caplog.at_level(logging.WARNING):
        load = check_bus_load(cfg)
    assert WARN_LOAD < load.load <= MAX_LOAD
    assert "bus load 73." in caplog.text and "above 60 %" in caplog.text


@pytest.mark.parametrize("period_us, baudrate", [(1100, 1000), (2000, 500)])
def test_refuses_above_90_percent(tmp_path, period_us, baudrate):
    cfg = load_config(bus_yml(tmp_path, axes=("x", "y", "z", "c"), period_us=period_us,
                                  baudrate=baudrate))
    assert bus_load(cfg).load > MAX_LOAD
    with pytest.raises(ConfigError, match=r"bus load (9\d|1\d\d)\.\d % .* is above 90 %") as info:
        check_bus_load(cfg)
    assert info.value.key == "master.sync_period" and info.value.line == 7
    with pytest.raises(ConfigError, match="above 90 %"):
        stepped(cfg)  # the controller refuses to start on it
