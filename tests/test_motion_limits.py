"""The one limits type (controller/limits.py) and axis configuration validation (ptp.py)."""

from __future__ import annotations

import math

import pytest

from controller.errors import CantrackError, ParameterError
from controller.limits import Limits
from controller.motion import AxisConfig, PointToPoint


def test_limits_accept_positive_values():
    limits = Limits(500, 5000.0, 1e5)
    assert limits.jerk_bound_velocity == 250.0
    assert limits.with_vel(5.0) == Limits(5.0, 5000.0, 1e5)


@pytest.mark.parametrize("field, value", [
    ("vel", 0.0), ("vel", -1.0), ("acc", math.nan), ("jerk", math.inf),
    ("acc", "10"), ("jerk", True), ("vel", None),
])
def test_limits_reject_bad_values_with_clear_message(field, value):
    kwargs = {"vel": 1.0, "acc": 1.0, "jerk": 1.0}
    kwargs[field] = value
    with pytest.raises(ParameterError) as err:
        Limits(**kwargs)
    message = str(err.value)
    assert f"Limits.{field} (={value!r} mm/s" in message and "must be a finite number > 0" \
        in message
    assert isinstance(err.value, CantrackError) and isinstance(err.value, ValueError)


def test_limits_are_frozen():
    limits = Limits(1.0, 1.0, 1.0)
    with pytest.raises(AttributeError):
        limits.vel = 2.0  # type: ignore[misc]


@pytest.mark.parametrize("kwargs, text", [
    ({"sample_period_s": 0.0}, "sample_period_s"),
    ({"sample_period_s": 0.001, "brake_release_s": -0.1}, "brake_release_s"),
    ({"sample_period_s": 0.001, "brake_engage_s": math.nan}, "brake_engage_s"),
    ({"sample_period_s": 0.001, "stop_time_s": -1}, "stop_time_s"),
])
def test_axis_config_validation(kwargs, text):
    with pytest.raises(ParameterError, match=text):
        AxisConfig(Limits(1.0, 1.0, 1.0), **kwargs)


def test_axis_config_sample_counts_round_up():
    cfg = AxisConfig(Limits(1.0, 1.0, 1.0), 0.004, brake_release_s=0.01,
                     brake_engage_s=0.012, stop_time_s=0.0)
    assert (cfg.release_samples, cfg.engage_samples, cfg.stop_samples) == (3, 3, 0)


def test_axis_rejects_wrong_types():
    with pytest.raises(ParameterError, match="Limits"):
        AxisConfig((1.0, 1.0, 1.0), 0.001)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="position_mm"):
        PointToPoint(AxisConfig(Limits(1.0, 1.0, 1.0), 0.001), position_mm=math.nan)


def test_numpy_numbers_are_accepted():
    np = pytest.importorskip("numpy")
    limits = Limits(np.float64(2.0), np.int64(3), 4.0)
    assert limits.acc == 3
