"""Helpers shared by the tracking tests (import as `from helpers import ...`)."""

from __future__ import annotations

import math

import numpy as np

from controller.tracking import MotionState, Tracker


def conveyor(direction=(1.0, 0.0, 0.0), v=300.0, a=0.0, ang_v=0.0):
    """A master moving along ``direction`` [unit] at v mm/s + a mm/s^2 * t, starting at 0."""
    n = math.sqrt(sum(x * x for x in direction))
    d = tuple(x / n for x in direction)

    def at(t: float) -> MotionState:
        s = v * t + 0.5 * a * t * t
        vv = v + a * t
        return MotionState(tuple(x * s for x in d), tuple(x * vv for x in d),
                           tuple(x * a for x in d), ang_v * t, ang_v, 0.0)
    return at


def run_tracker(tracker: Tracker, master, seconds: float, engage_at: int = 0,
                disengage_at: int | None = None):
    """Run ``tracker`` against ``master(t)``; return arrays including row 0 (before engage)."""
    T = tracker.T
    n = int(round(seconds / T))
    sp = [tracker.setpoint]
    ms = [master(0.0)]
    st = [int(tracker.state)]
    outs = []
    for k in range(1, n + 1):
        if k - 1 == engage_at:
            tracker.engage()
        if disengage_at is not None and k - 1 == disengage_at:
            tracker.disengage()
        m = master(k * T)
        o = tracker.update(m)
        outs.append(o)
        sp.append(o.setpoint)
        ms.append(m)
        st.append(int(o.state))
    return {
        "pos": np.array([s.pos for s in sp]),
        "vel": np.array([s.vel for s in sp]),
        "acc": np.array([s.acc for s in sp]),
        "ang": np.array([s.ang for s in sp]),
        "mpos": np.array([m.pos for m in ms]),
        "mang": np.array([m.ang for m in ms]),
        "state": np.array(st),
        "outs": outs,
    }

