"""Getting frames on and off the bus, in stepped or real time, with the same interface.

Every participant (the controller, the rack of simulated devices, the bus logger) owns one
python-can bus.  A :class:`Port` sends frames stamped with the clock's message time and
dispatches received frames to per-COB-ID subscribers ``callback(can_id, data, t_ns)``.

The controller talks to a *transport*: ``send``, ``subscribe``, ``clock`` and
``run_until(deadline_ns, done)``, which processes incoming frames until ``done()`` is true
or the deadline has passed.  That one call is the only way the controller waits, so the same
cycle code runs on

- :class:`SteppedTransport` in a :class:`SteppedWorld`: everything on one python-can
  ``virtual`` channel in one thread; ``run_until`` drains every participant's queue until the
  bus is quiet (a device's answer is sent while the request is handled), fires the timers
  that fall due (heartbeats, fault injection) in time order, and advances the stepped clock.
  No sleeping and hoping: the order of events is fixed, a run is reproducible;
- :class:`RealtimeTransport`: blocks in ``bus.recv(timeout)``; for a ``precise`` deadline
  (the SYNC) only until ``SPIN_NS`` before it, then polls (``recv(0)``) up to it, on
  ``time.perf_counter_ns`` (absolute deadlines, python-can's own ``due_ns += period_ns``).

Simulated devices in real time run in a :class:`DeviceThread`.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable
from typing import Protocol

import can

from ...errors import CanError
from .clock import Clock, RealtimeClock, SteppedClock
from .vbus import FastVirtualBus

Callback = Callable[[int, bytes, int], None]

#: real-time waits poll (instead of blocking) this long before a deadline [ns]
SPIN_NS = 300_000


def virtual_bus(channel: str) -> can.BusABC:
    """A python-can ``virtual`` bus that keeps the sender's timestamps (without the
    per-receiver deepcopy: :class:`~.vbus.FastVirtualBus`)."""
    return FastVirtualBus(channel=channel, preserve_timestamps=True, receive_own_messages=False)


class Port:
    """A participant's access to its bus: stamped sends and dispatch by COB-ID.

    Receivers get the controller time of the frame: when it is handled (default), or with
    ``frame_time`` when it was sent, from its message time (a simulated bus whose senders
    stamp their frames with the same clock: :func:`virtual_bus` keeps the senders' stamps);
    a host that serves frames late (a device thread waiting for the interpreter) then still
    knows when each was on the bus.  A stamp outside the last :data:`FRAME_TIME_MAX_NS`
    (none, another time base) falls back to the handling time."""

    #: how far back a frame's own time is believed [ns]
    FRAME_TIME_MAX_NS = 1_000_000_000

    def __init__(self, bus: can.BusABC, clock: Clock, frame_time: bool = False) -> None:
        self.bus = bus
        self.clock = clock
        self.frame_time = frame_time
        self.subscribers: dict[int, list[Callback]] = {}
        #: receivers of error frames (python-can ``is_error_frame``: SocketCAN's CAN_ERR_*)
        self.error_subscribers: list[Callable[[can.Message], None]] = []
        self.sent = 0
        self.received = 0
        #: the message each COB-ID is sent with (:meth:`send`)
        self._out: dict[int, can.Message] = {}
        #: :meth:`FastVirtualBus.send_frame` of our virtual bus (None: any other bus)
        self._send_frame = bus.send_frame if isinstance(bus, FastVirtualBus) else None

    def subscribe(self, can_id: int, callback: Callback) -> None:
        lst = self.subscribers.setdefault(can_id, [])
        if callback not in lst:
            lst.append(callback)

    def unsubscribe(self, can_id: int, callback: Callback | None = None) -> None:
        if callback is None:
            self.subscribers.pop(can_id, None)
        elif can_id in self.subscribers and callback in self.subscribers[can_id]:
            self.subscribers[can_id].remove(callback)

    def send(self, can_id: int, data: bytes | bytearray) -> None:
        send_frame = self._send_frame
        if send_frame is not None:  # our virtual bus: no sender's message at all
            try:
                send_frame(can_id, data, self.clock.stamp())
            except can.CanError as exc:
                raise CanError(f"cannot send 0x{can_id:03X}: {exc}") from exc
            self.sent += 1
            return
        # One can.Message per COB-ID, refilled for every frame instead of a new one (its
        # constructor is a third of a frame's cost in the cycle).  python-can's buses take
        # what they send out of the message inside send() -- SocketCAN packs a kernel frame,
        # the virtual bus gives every receiver its own copy -- and keep no reference to it.
        msg = self._out.get(can_id)
        if msg is None:
            msg = self._out[can_id] = can.Message(arbitration_id=can_id, is_extended_id=False)
        # (data as the constructor keeps it: a bytearray, the caller's own if it is one)
        msg.data = data if data.__class__ is bytearray else bytearray(data)
        msg.dlc = len(data)
        msg.timestamp = self.clock.stamp()
        try:
            self.bus.send(msg)
        except can.CanError as exc:
            raise CanError(f"cannot send 0x{can_id:03X}: {exc}") from exc
        self.sent += 1

    def subscribe_errors(self, callback: Callable[[can.Message], None]) -> None:
        if callback not in self.error_subscribers:
            self.error_subscribers.append(callback)

    def handle(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            for ecb in tuple(self.error_subscribers):
                ecb(msg)
            return
        if msg.is_remote_frame or msg.is_extended_id:
            return
        self.received += 1
        can_id = msg.arbitration_id
        callbacks = self.subscribers.get(can_id)
        if callbacks:
            t = self.clock.now_ns()
            if self.frame_time:
                sent = round((msg.timestamp - self.clock.epoch_s) * 1e9)
                if 0 <= t - sent <= self.FRAME_TIME_MAX_NS:
                    t = sent
            data = bytes(msg.data)  # (immutable: one copy for every subscriber)
            if len(callbacks) == 1:
                callbacks[0](can_id, data, t)
            else:
                for cb in tuple(callbacks):
                    cb(can_id, data, t)

    # a Port has no timers of its own
    def next_timer_ns(self) -> int | None:
        return None

    def on_timer(self, now_ns: int) -> None:
        pass


class Endpoint(Protocol):
    """A participant of a :class:`SteppedWorld`."""

    bus: can.BusABC

    def handle(self, msg: can.Message) -> None: ...

    def next_timer_ns(self) -> int | None: ...

    def on_timer(self, now_ns: int) -> None: ...


class Transport(Protocol):
    # read-only for the user of a transport, so a transport may keep a more precise clock
    # type (RealtimeTransport's RealtimeClock) than the protocol's
    @property
    def clock(self) -> Clock: ...

    def send(self, can_id: int, data: bytes | bytearray) -> None: ...

    def subscribe(self, can_id: int, callback: Callback) -> None: ...

    def unsubscribe(self, can_id: int, callback: Callback | None = None) -> None: ...

    def subscribe_errors(self, callback: Callable[[can.Message], None]) -> None: ...

    def run_until(self, deadline_ns: int, done: Callable[[], bool] | None = None,
                  precise: bool = False) -> bool: ...


class GuardedTransport:
    """A transport whose receive callbacks run guarded (:meth:`FrameHygiene.guard`): an
    exception inside one is queued for the cycle, never raised into the receive loop.
    ``send`` and ``run_until`` are the inner transport's own (bound: no extra call)."""

    def __init__(self, inner: Transport, hygiene) -> None:
        self.inner = inner
        self.hygiene = hygiene
        self.clock = inner.clock
        self.send = inner.send
        self.run_until = inner.run_until
        self._guarded: dict[tuple[int, Callback], Callback] = {}

    def subscribe(self, can_id: int, callback: Callback) -> None:
        g = self._guarded.get((can_id, callback))
        if g is None:
            g = self._guarded[(can_id, callback)] = self.hygiene.guard(callback)
        self.inner.subscribe(can_id, g)

    def unsubscribe(self, can_id: int, callback: Callback | None = None) -> None:
        if callback is None:
            for key in [key for key in self._guarded if key[0] == can_id]:
                del self._guarded[key]
            self.inner.unsubscribe(can_id)
            return
        g = self._guarded.pop((can_id, callback), None)
        if g is not None:
            self.inner.unsubscribe(can_id, g)

    def subscribe_errors(self, callback: Callable[[can.Message], None]) -> None:
        def guarded(msg: can.Message) -> None:
            self.hygiene.guard(lambda _c, _d, _t: callback(msg))(msg.arbitration_id,
                                                               bytes(msg.data), 0)
        self.inner.subscribe_errors(guarded)


class SteppedWorld:
    """Every participant on one virtual channel, advanced deterministically in one thread.

    With a :class:`SteppedClock` time jumps from event to event; with a
    :class:`RealtimeClock` the same world is *paced*: it waits for each event in wall-clock
    time (sleep, then poll the last ``spin_ns``), the participants still being served in
    this thread (no thread hand-over; used by the cycle benchmark).
    """

    #: guard against a timer that never moves on (a bug): events at one instant
    MAX_EVENTS_AT_ONCE = 10_000

    def __init__(self, channel: str, clock: SteppedClock | RealtimeClock | None = None,
                 spin_ns: int = SPIN_NS) -> None:
        self.channel = channel
        self.clock = clock if clock is not None else SteppedClock()
        self.spin_ns = spin_ns
        self.endpoints: list[Endpoint] = []
        self._actions: list[tuple[int, int, Callable[[], None]]] = []
        self._seq = itertools.count()

    def new_bus(self) -> can.BusABC:
        return virtual_bus(self.channel)

    def add(self, endpoint: Endpoint) -> Endpoint:
        self.endpoints.append(endpoint)
        return endpoint

    def at(self, t_ns: int, action: Callable[[], None]) -> None:
        """Run ``action`` when the stepped clock reaches ``t_ns`` (fault injection)."""
        heapq.heappush(self._actions, (int(t_ns), next(self._seq), action))

    def drain(self) -> int:
        """Deliver queued frames until every participant's queue is empty."""
        delivered = 0
        progress = True
        while progress:
            progress = False
            for ep in self.endpoints:
                bus = ep.bus
                while True:
                    msg = bus.recv(0)
                    if msg is None:
                        break
                    ep.handle(msg)
                    delivered += 1
                    progress = True
        return delivered

    def _next_due(self) -> int | None:
        due = [t for ep in self.endpoints if (t := ep.next_timer_ns()) is not None]
        if self._actions:
            due.append(self._actions[0][0])
        return min(due) if due else None

    def run_until(self, deadline_ns: int, done: Callable[[], bool] | None = None) -> bool:
        """Process frames and timers up to ``deadline_ns``; stop early once ``done()``."""
        clock = self.clock
        same, last = 0, -1
        while True:
            self.drain()
            if done is not None and done():
                return True
            due = self._next_due()
            if due is None or due > deadline_ns:
                break
            self._advance(max(due, clock.now_ns()))
            now = clock.now_ns()
            same = same + 1 if now == last else 0
            last = now
            if same > self.MAX_EVENTS_AT_ONCE:  # pragma: no cover - a bug in a participant
                stuck = [type(ep).__name__ for ep in self.endpoints
                         if (t := ep.next_timer_ns()) is not None and t <= now]
                raise RuntimeError(f"stepped world: timers of {stuck} do not advance")
            while self._actions and self._actions[0][0] <= now:
                heapq.heappop(self._actions)[2]()
            for ep in self.endpoints:
                t = ep.next_timer_ns()
                if t is not None and t <= now:
                    ep.on_timer(now)
        if deadline_ns > clock.now_ns():
            self._advance(deadline_ns)
        self.drain()
        return done() if done is not None else True

    def _advance(self, t_ns: int) -> None:
        clock = self.clock
        if isinstance(clock, SteppedClock):
            clock.advance_to(t_ns)
            return
        while True:  # paced: wait in real time
            rest = t_ns - clock.now_ns()
            if rest <= 0:
                return
            if rest > self.spin_ns:
                time.sleep((rest - self.spin_ns) * 1e-9)

    def close(self) -> None:
        for ep in self.endpoints:
            try:
                ep.bus.shutdown()
            except Exception:  # pragma: no cover - best effort
                pass
        self.endpoints.clear()


class PortTransport:
    """What the stepped and the real-time transport share: frames go out and in through one
    :class:`Port`; they differ only in how time passes (``run_until``)."""

    port: Port

    def send(self, can_id: int, data: bytes | bytearray) -> None:
        self.port.send(can_id, data)

    def subscribe(self, can_id: int, callback: Callback) -> None:
        self.port.subscribe(can_id, callback)

    def unsubscribe(self, can_id: int, callback: Callback | None = None) -> None:
        self.port.unsubscribe(can_id, callback)

    def subscribe_errors(self, callback: Callable[[can.Message], None]) -> None:
        self.port.subscribe_errors(callback)


class SteppedTransport(PortTransport):
    """The controller's transport inside a :class:`SteppedWorld`."""

    def __init__(self, world: SteppedWorld) -> None:
        self.world = world
        self.clock = world.clock
        self.port = Port(world.new_bus(), world.clock)
        world.add(self.port)
        self.send = self.port.send  # type: ignore[method-assign]  # (no extra call per frame)

    def run_until(self, deadline_ns: int, done: Callable[[], bool] | None = None,
                  precise: bool = False) -> bool:
        return self.world.run_until(deadline_ns, done)

    def close(self) -> None:
        pass  # the world closes the bus


class RealtimeTransport(PortTransport):
    """The controller's transport on a real bus (or a virtual one shared with threads)."""

    #: frames handled at most by a wait whose deadline has passed (bounded: a flood must
    #: not hold the late cycle up further)
    LATE_FRAMES = 256

    def __init__(self, bus: can.BusABC, clock: RealtimeClock | None = None,
                 spin_ns: int = SPIN_NS) -> None:
        self.clock = clock if clock is not None else RealtimeClock()
        self.port = Port(bus, self.clock)
        self.spin_ns = spin_ns
        self.send = self.port.send  # type: ignore[method-assign]  # (no extra call per frame)

    def run_until(self, deadline_ns: int, done: Callable[[], bool] | None = None,
                  precise: bool = False) -> bool:
        """``precise``: poll the last ``spin_ns`` before the deadline (the SYNC); otherwise
        block until a frame or the deadline (waiting for other nodes' answers: a poll would
        only take the CPU from them).

        Called when the deadline has passed already (a late cycle), it still handles the
        frames received meanwhile (at most :data:`LATE_FRAMES`), as the stepped world does:
        they arrived before the deadline and belong to the cycle before it, not to the
        next SYNC's (whose index the caller sets after this wait).

        The frames queued when a receive returns are handled together before ``done()`` is
        asked again (one test per wake-up, not per frame: the devices answer a SYNC in a
        burst), each batch cut at the deadline."""
        now_ns = self.clock.now_ns
        recv = self.port.bus.recv
        handle = self.port.handle
        spin = self.spin_ns if precise else 0
        while True:
            if done is not None and done():
                return True
            rest = deadline_ns - now_ns()
            if rest <= 0:
                for _ in range(self.LATE_FRAMES):
                    msg = recv(0)
                    if msg is None:
                        break
                    handle(msg)
                return done() if done is not None else True
            msg = recv((rest - spin) * 1e-9) if rest > spin else recv(0)
            # (a blocking recv(timeout) may return a little after the deadline: the
            #  next loop pass sees rest <= 0)
            while msg is not None:
                handle(msg)
                if now_ns() >= deadline_ns:
                    break  # (the rest, at most LATE_FRAMES, in the next pass)
                msg = recv(0)

    def close(self) -> None:
        self.port.bus.shutdown()


class DeviceThread:
    """Runs an endpoint (e.g. the device rack) in real time in a background thread."""

    def __init__(self, endpoint: Endpoint, clock: RealtimeClock, name: str = "devices",
                 max_block_s: float = 0.005) -> None:
        self.endpoint = endpoint
        self.clock = clock
        self.max_block_s = max_block_s
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> DeviceThread:
        self._thread.start()
        return self

    def _run(self) -> None:
        ep = self.endpoint
        clock = self.clock
        bus = ep.bus
        recv = bus.recv
        # on our virtual bus the batch's answers go out together, just before the wait
        # (FastVirtualBus.hold_sends: the controller is woken once per burst, not by its
        # first frame while this thread still holds the GIL)
        fast = bus if isinstance(bus, FastVirtualBus) else None
        deliver = None
        if fast is not None:
            fast.hold_sends()
            deliver = fast.deliver_held
        timeout = 0.0
        try:
            while not self._stop.is_set():
                if deliver is not None:
                    deliver()
                msg = recv(timeout)
                while msg is not None:  # the whole batch before looking at the timers
                    ep.handle(msg)
                    msg = recv(0)
                now = clock.now_ns()
                due = ep.next_timer_ns()
                if due is not None and due <= now:
                    ep.on_timer(now)
                    due = ep.next_timer_ns()
                timeout = self.max_block_s if due is None else \
                    max(0.0, min(self.max_block_s, (due - now) * 1e-9))
        except BaseException as exc:  # reported by stop()
            self.error = exc
        finally:
            if fast is not None:
                fast.release_sends()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        if self.error is not None:
            raise CanError(f"simulated devices stopped: {self.error}") from self.error
