"""Count quantiser (controller/motion/quantize.py): mm -> counts at the drive boundary."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.errors import ParameterError
from controller.limits import Limits
from controller.motion import AxisConfig, CountQuantizer, MotionResult, PointToPoint

PROPERTY = settings(derandomize=True, database=None, deadline=None, max_examples=60,
                    suppress_health_check=[HealthCheck.too_slow])


def test_hand_computed_counts():
    q = CountQuantizer(counts_per_mm=1000.0, sign=-1, offset_counts=5000)
    # -1 * 1000 * 1.2345 = -1234.5 -> halves round up -> -1234; 5000 - 1234 = 3766
    assert q.to_counts(1.2345) == 3766
    assert q.to_counts(0.0) == 5000
    assert q.to_counts(-2.0) == 7000
    assert q.to_mm(7000) == -2.0
    assert q.velocity_to_counts_s(10.0) == -10000.0
    # 500 mm/s at 1 ms with 1000 counts/mm: 500 counts per sample at most
    assert q.max_step_counts(500.0, 0.001) == 500
    assert CountQuantizer(2048.0 / 5.0).max_step_counts(300.0, 0.004) == math.ceil(491.52)


def test_round_trip():
    q = CountQuantizer(counts_per_mm=4096.0 / 10.0, sign=1, offset_counts=-123)
    for c in (-10**6, -1, 0, 1, 77, 10**6):
        assert q.to_counts(q.to_mm(c)) == c
    for x in np.linspace(-100.0, 100.0, 101):
        assert abs(q.to_mm(q.to_counts(x)) - x) <= 0.5 / q.counts_per_mm + 1e-12


def test_int32_range_is_checked():
    q = CountQuantizer(counts_per_mm=1e4)
    lo, hi = q.range_mm()
    assert lo == pytest.approx(-214748.3648) and hi == pytest.approx(214748.3647)
    with pytest.raises(ParameterError, match="607Ah"):
        q.to_counts(300_000.0)


@pytest.mark.parametrize("kwargs, text", [
    ({"counts_per_mm": 0.0}, "counts_per_mm"),
    ({"counts_per_mm": 1.0, "sign": 0}, "sign"),
    ({"counts_per_mm": 1.0, "sign": True}, "sign"),
    ({"counts_per_mm": 1.0, "offset_counts": 1.5}, "offset_counts"),
    ({"counts_per_mm": 1.0, "offset_counts": 2**31}, "INTEGER32"),
])
def test_validation(kwargs, text):
    with pytest.raises(ParameterError, match=text):
        CountQuantizer(**kwargs)


@PROPERTY
@given(st.floats(0.1, 5000.0), st.sampled_from([-1, 1]), st.integers(-10**6, 10**6),
       st.floats(5.0, 1000.0), st.sampled_from([0.001, 0.002, 0.004]),
       st.floats(-300.0, 300.0), st.floats(-1.0, 1.0))
def test_count_stream_never_jumps_more_than_the_velocity_allows(
        cpm, sign, offset, vel, period, start, rel):
    limits = Limits(vel, vel / 0.05, vel / 0.05 / 0.01)
    q = CountQuantizer(cpm, sign, offset)
    axis = PointToPoint(AxisConfig(limits, period), position_mm=start)
    axis.set_target(start + rel * vel)
    positions = [start]
    while True:
        out = axis.update()
        positions.append(out.position_mm)
        if out.result is not MotionResult.WORKING:
            break
    counts = np.array(q.quantize_stream(positions))
    jumps = np.abs(np.diff(counts))
    bound = q.max_step_counts(vel, period)
    assert jumps.max(initial=0) <= bound
    # over any window of n samples the counts never run ahead by more than one count
    for n in (2, 5, 17):
        if len(counts) > n:
            assert np.abs(counts[n:] - counts[:-n]).max() <= math.ceil(n * cpm * vel * period)
    # quantisation error at most half a count, and the last count is the target's
    errors = np.abs(np.array([q.to_mm(c) for c in counts]) - np.array(positions))
    assert errors.max() <= 0.5 / cpm * (1 + 1e-9)
    assert counts[-1] == q.to_counts(positions[-1])
