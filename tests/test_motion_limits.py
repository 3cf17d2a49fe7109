"""Axis limits and axis configuration validation (controller/motion/limits.py, ptp.py)."""

from __future__ import annotations

import math

import pytest

from controller.errors import CantrackError, ParameterError
from controller.motion import AxisConfig, AxisLimits, PointToPoint


def test_limits_accept_positive_values():
    limits = AxisLimits(500, 5000.0, 1e5)
    assert limits.jerk_bound_velocity == 250.0
    assert limits.with_max_vel(5.0) == AxisLimits(5.0, 5000.0, 1e5)


@pytest.mark.parametrize("field, value", [
    ("max_vel", 0.0), ("max_vel", -1.0), ("max_acc", math.nan), ("max_jerk", math.inf),
    ("max_acc", "10"), ("max_jerk", True),
])
def test_limits_reject_bad_values_with_clear_message(field, value):
    kwargs = {"max_vel": 1.0, "max_acc": 1.0, "max_jerk": 1.0}
    kwargs[field] = value
    with pytest.raises(ParameterError) as err:
        AxisLimits(**kwargs)
    message = str(err.value)
    assert f"AxisLimits.{field}" in message and "> 0" in message and repr(value) in message
    assert isinstance(err.value, CantrackError) and isinstance(err.value, ValueError)


def test_limits_are_frozen():
    limits = AxisLimits(1.0, 1.0, 1.0)
    with pytest.raises(AttributeError):
        limits.max_vel = 2.0  # type: ignore[misc]


@pytest.mark.parametrize("kwargs, text", [
    ({"sample_period_s": 0.0}, "sample_period_s"),
    ({"sample_period_s": 0.001, "brake_release_s": -0.1}, "brake_release_s"),
    ({"sample_period_s": 0.001, "brake_engage_s": math.nan}, "brake_engage_s"),
    ({"sample_period_s": 0.001, "stop_time_s": -1}, "stop_time_s"),
])
def test_axis_config_validation(kwargs, text):
    with pytest.raises(ParameterError, match=text):
        AxisConfig(AxisLimits(1.0, 1.0, 1.0), **kwargs)


def test_axis_config_sample_counts_round_up():
    cfg = AxisConfig(AxisLimits(1.0, 1.0, 1.0), 0.004, brake_release_s=0.01,
                     brake_engage_s=0.012, stop_time_s=0.0)
    assert (cfg.release_samples, cfg.engage_samples, cfg.stop_samples) == (3, 3, 0)


def test_axis_rejects_wrong_types():
    with pytest.raises(ParameterError, match="AxisLimits"):
        AxisConfig((1.0, 1.0, 1.0), 0.001)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="position_mm"):
        PointToPoint(AxisConfig(AxisLimits(1.0, 1.0, 1.0), 0.001), position_mm=math.nan)


def test_numpy_numbers_are_accepted():
    np = pytest.importorskip("numpy")
    limits = AxisLimits(np.float64(2.0), np.int64(3), 4.0)
    assert limits.max_acc == 3
