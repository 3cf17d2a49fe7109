"""The cycle's real-time supervision, deterministically: the start-up budget check, the
reaction to deadlines missed in a row, and a late cycle's wait.

The cycle's timing figures are taken only on a real-time clock; here a stepped world's clock
says it is one (``realtime = True``) so that the figures are taken on stepped time, and a
source that "computes" too long advances that clock itself: every number is exact.  The
budget check's compute time is the thread's CPU time (``time.thread_time_ns``), so there the
source burns CPU; CPU time does not depend on how busy the machine is.
"""

from __future__ import annotations

import time

from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.io.transport import RealtimeTransport, virtual_bus
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.master.source import CycleContext, SourceOutput, SourceStart
from controller.canopen.testing import load


class _Slow:
    """A source that takes ``compute_ns`` of stepped time (``clock``) or, with ``burn``, of
    this thread's CPU time in each of its cycles ``first`` ... ``first + cycles - 1``."""

    def __init__(self, clock, compute_ns: int, first: int = 0, cycles: int = 10**9,
                 burn: bool = False) -> None:
        self.inner = ConveyorFollow(10, None, (420.0, 30.0, 0.0))
        self.clock = clock
        self.compute_ns = compute_ns
        self.first, self.last = first, first + cycles
        self.burn = burn
        self.n = 0
        self.cycles: list[int] = []  # the controller's cycle of each step

    def start(self, start: SourceStart):
        return self.inner.start(start)

    def step(self, ctx: CycleContext) -> SourceOutput:
        out = self.inner.step(ctx)
        self.cycles.append(ctx.cycle)
        if self.first <= self.n < self.last:
            if self.burn:
                t = time.thread_time_ns() + self.compute_ns
                while time.thread_time_ns() < t:
                    pass
            else:
                self.clock.advance_to(self.clock.now_ns() + self.compute_ns)
        self.n += 1
        return out


def _controller(stepped_controller, tmp_path, source_of, cls=Controller, **kw):
    """A booted, started ``cls`` on a stepped world whose clock counts as real time (the
    timing figures are taken, on stepped time); its source ``source_of(clock, cfg)``."""
    cfg = load(tmp_path)
    world, _ = stepped_controller(cfg)
    world.clock.realtime = True
    ctl = cls(cfg, world.transport, source_of(world.clock, cfg), keep_trace=False, **kw)
    ctl.boot()
    ctl.start()
    return world, ctl


def test_deadlines_missed_in_a_row_quick_stop_the_drives(stepped_controller, tmp_path):
    """Every cycle's compute takes 1.2 periods from the 50th tracking cycle on: the RPDOs go
    out after the next SYNC's deadline; at ``max_missed_in_row`` (25) the controller
    quick-stops, saying why, and ends with exit 3 (a fault handled)."""
    world, ctl = _controller(stepped_controller, tmp_path,
                             lambda clock, cfg: _Slow(clock, round(1.2 * cfg.period_ns), 50))
    ctl.run(max_cycles=1000, realtime_gc=False)
    ev = [e for e in ctl.events if e.kind == "deadlines_missed"]
    assert len(ev) == 1
    assert ev[0].detail.startswith("25 SYNC deadlines missed in a row")
    assert ev[0].reaction == "quick stop of all drives"
    assert ctl.timing.missed == ctl.timing.missed_run.longest >= 25
    assert ctl.phase is Phase.STOPPED and ctl.exit_code() == 3
    # the quick stop came with the 25th miss: the source's cycles 50 ... 74 were slow
    assert ev[0].cycle == ctl.source.cycles[74]


def test_a_streak_shorter_than_the_limit_is_counted_not_stopped(stepped_controller,
                                                                tmp_path):
    """24 slow cycles, then the compute fits again: the streak ends one short of the
    limit; the misses are counted, nothing stops."""
    world, ctl = _controller(
        stepped_controller, tmp_path,
        lambda clock, cfg: _Slow(clock, round(1.2 * cfg.period_ns), 50, cycles=24))
    ctl.run(max_cycles=400, realtime_gc=False)
    assert not [e for e in ctl.events if e.kind == "deadlines_missed"]
    assert ctl.timing.missed == 24 and ctl.timing.missed_run.longest == 24
    assert ctl.failure is None and ctl.exit_code() == 0


class _ShortCheck(Controller):
    BUDGET_CHECK_S = 0.1  # 50 cycles at 2 ms


def test_startup_check_warns_when_compute_p99_is_over_half_the_period(stepped_controller,
                                                                      tmp_path, caplog):
    """Compute CPU of 1.2 ms in each 2 ms cycle (60 %) over the first 0.1 s of tracking:
    one warning "cycle_budget" naming the p99 and the share; the run goes on."""
    _, ctl = _controller(stepped_controller, tmp_path,
                         lambda clock, _cfg: _Slow(clock, 1_200_000, burn=True), cls=_ShortCheck)
    ctl.run(max_cycles=120, realtime_gc=False)
    ev = [e for e in ctl.events if e.kind == "cycle_budget"]
    assert len(ev) == 1, [str(e) for e in ctl.events]
    share = int(ev[0].detail.split(" us = ")[1].split(" %")[0])
    # (at least the burn's 60 %; the check's p99 of 50 cycles is their largest, and one cycle
    #  on a loaded machine took 181 %: the upper bound only catches a unit error, 1000 x)
    assert 60 <= share < 1000 and "over the first 0.1 s (> 50 %)" in ev[0].detail
    assert ev[0].reaction == ""  # a warning (logged at WARNING), no reaction
    assert [r.levelname for r in caplog.records if "cycle_budget" in r.getMessage()] \
        == ["WARNING"]
    # after the first 0.1 s of tracking (50 cycles, from the one that started the source,
    # the cycle before its first step), and never again
    assert ev[0].cycle == ctl.source.cycles[0] - 1 + 49
    assert ctl.failure is None and ctl.timing.startup is None  # checked once


def test_startup_check_is_silent_with_headroom(stepped_controller, tmp_path):
    """The plain source's compute (tens of us of CPU) in the same 2 ms cycle: no warning."""
    _, ctl = _controller(stepped_controller, tmp_path,
                         lambda clock, _cfg: _Slow(clock, 0, burn=True), cls=_ShortCheck)
    ctl.run(max_cycles=120, realtime_gc=False)
    assert not [e for e in ctl.events if e.kind == "cycle_budget"]
    assert ctl.timing.startup is None  # the check ran


def test_a_late_wait_still_handles_the_frames_received_before_its_deadline():
    """A cycle that starts after its deadline (the controller was held up) must still take
    the frames that came in meanwhile, before it sets the next SYNC's index: else a TPDO
    answering the last SYNC was taken for the next one's.  Cue: the frame is in the receive
    queue before the wait (a virtual bus delivers on send)."""
    channel = f"late-wait-{time.perf_counter_ns()}"
    transport = RealtimeTransport(virtual_bus(channel))
    peer = virtual_bus(channel)
    got = []
    try:
        transport.subscribe(0x18A, lambda can_id, data, t: got.append(bytes(data)))
        import can
        peer.send(can.Message(arbitration_id=0x18A, data=b"\x01\x02\x03\x04",
                              is_extended_id=False))
        past = transport.clock.now_ns() - 1_000_000
        assert transport.run_until(past, precise=True) is True
        assert got == [b"\x01\x02\x03\x04"]
        # with a completion test: the frame is handled, then the test is asked again
        peer.send(can.Message(arbitration_id=0x18A, data=b"\x05", is_extended_id=False))
        assert transport.run_until(past, lambda: len(got) == 2) is True
        assert got[-1] == b"\x05"
    finally:
        peer.shutdown()
        transport.close()


def test_a_wait_handles_the_queued_frames_together_before_asking_again():
    """The frames queued when a receive returns (the devices' answers to a SYNC come in a
    burst) are handled together, then the completion test is asked once: not once per
    frame."""
    channel = f"batch-wait-{time.perf_counter_ns()}"
    transport = RealtimeTransport(virtual_bus(channel))
    peer = virtual_bus(channel)
    got, asked = [], []

    def done() -> bool:
        asked.append(len(got))
        return len(got) >= 1

    try:
        transport.subscribe(0x18A, lambda can_id, data, t: got.append(bytes(data)))
        import can
        for i in range(3):
            peer.send(can.Message(arbitration_id=0x18A, data=bytes((i,)),
                                  is_extended_id=False))
        deadline = transport.clock.now_ns() + 1_000_000_000
        assert transport.run_until(deadline, done) is True
        assert got == [b"\x00", b"\x01", b"\x02"]
        assert asked == [0, 3]
    finally:
        peer.shutdown()
        transport.close()


def test_the_cycles_cpu_outside_the_compute_is_its_own_figure(stepped_controller, tmp_path):
    """cpu_wait: the SYNC's send and the input wait, per cycle, beside the compute; with a
    source burning 1 ms of CPU in each of its cycles the compute holds it, the wait does
    not, and the two make up the cycle's CPU."""
    _, ctl = _controller(stepped_controller, tmp_path,
                         lambda clock, _cfg: _Slow(clock, 1_000_000, burn=True))
    ctl.run(max_cycles=120, realtime_gc=False)
    tm = ctl.timing
    assert tm.cpu_wait.n == tm.cpu_cycle.n == tm.cpu_compute.n == 120
    assert tm.cpu_wait.total + tm.cpu_compute.total == tm.cpu_cycle.total
    assert ctl.source.n > 60  # (most cycles ran the source)
    assert tm.cpu_compute.percentile(50) >= 1_000_000 > tm.cpu_wait.percentile(50)
