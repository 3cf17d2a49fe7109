"""The master input under real-time conditions, deterministically: SYNCs sent late (the
lateness known) and encoder samples missing, as a loaded machine gives them.

Each sample is the belt's count at the time its SYNC went out (a real encoder latches at
the SYNC), the cycle hands the input the lateness; no bus, no clock: the input's update is
called as the cycle calls it.  Before, the lateness correction took the velocity from the
estimate it feeds (a loop with a gain up to 3.5 during the warm-up) and a missing sample
was the fit's quadratic prediction (pushed among real ones it bent the fit further each
time): with half the samples missing at 1 ms the estimate diverged (1e32 mm in a
real-time run), and every item was missed.
"""

from __future__ import annotations

import math
import random

import pytest

from controller.canopen.config import load_config
from controller.canopen.master.masterio import MasterInput
from controller.canopen.testing import bus_yml


class _Bus:
    def subscribe(self, can_id, callback):
        pass


@pytest.mark.parametrize("period_us", [1000, 2000])
def test_late_and_missing_samples_keep_the_estimate_on_the_belt(tmp_path, period_us):
    cfg = load_config(bus_yml(tmp_path, period_us=period_us))
    mi = MasterInput(cfg, _Bus())
    conv = cfg.tracking.conveyor
    T = cfg.period_s
    v_belt = 300.0  # mm/s
    rng = random.Random(1)
    worst_pos = worst_acc = worst_vel = 0.0
    ready = 0  # cycles in a row with a full window (5 missing in a row: lost, warm-up again)
    t_first = None
    compared = 0
    for k in range(3000):
        late = rng.uniform(0.0, 2e-3) if rng.random() < 0.3 else rng.uniform(0.0, 50e-6)
        if rng.random() < 0.5:  # this SYNC's sample came
            counts = math.floor(v_belt * (k * T + late) * conv.counts_per_mm)
            mi.snapshot = (counts, 0, k)
            if t_first is None:  # (the belt travel counts from the first sample)
                t_first = math.floor(v_belt * (k * T + late) * conv.counts_per_mm) \
                    / conv.counts_per_mm / v_belt
        _, est = mi.update(k, late)
        ready = ready + 1 if mi.ready else 0
        if ready > 16 and est is not None:  # the estimate for SYNC k + lead, warmed up
            true = v_belt * ((k + mi.lead) * T - t_first)
            compared += 1
            worst_pos = max(worst_pos, abs(est.pos - true))
            worst_vel = max(worst_vel, abs(est.vel - v_belt))
            worst_acc = max(worst_acc, abs(est.acc))
    assert compared > 1000
    # within a few counts (1 count = 0.024 mm) and well inside the frame's limits
    # (AccelerationMax 1000 mm/s^2: the tracker de-syncs above it)
    assert worst_pos < 0.1, worst_pos
    assert worst_vel < 30.0, worst_vel
    assert worst_acc < 1000.0, worst_acc
