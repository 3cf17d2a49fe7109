"""A simulated CiA 402 servo drive (cantrack-servo.eds): state machine, CSP, servo model.

Behaves like a real drive where a controller can get it wrong:

- the full state machine (:mod:`controller.canopen.protocol.cia402`): a controlword the transition
  table does not allow in the present state is ignored, so a controller that skips a step
  never reaches OPERATION ENABLED; fault reset needs a rising edge of bit 7;
- CSP (6060h = 8): the target 607Ah received in the synchronous RPDO is applied at the next
  SYNC.  On "enable operation" the drive takes the 607Ah it has at that moment, so a
  controller that enables with a stale 607Ah makes it jump: the following error exceeds
  6065h for 6066h ms and the drive faults (603Fh = 8611h, EMCY 8611h);
- quick stop (605Ah): the drive ramps its velocity to 0 with 6085h, then 605Ah 0-3 ->
  SWITCH ON DISABLED (transition 12), 5-8 -> stays in QUICK STOP ACTIVE; a fault ramps the
  same way in FAULT REACTION ACTIVE, then FAULT (14);
- 6007h abort connection option when the consumed heartbeat (1016h, the controller's) is
  lost: 1 fault, 2 disable voltage, 3 quick stop; EMCY 8130h in each case;
- 60FDh digital inputs from the position: bit0 negative / bit1 positive limit switch, bit2
  home switch, bit16 slow-down sensor; bit17 the touch-probe input level.  Moving into an
  active limit switch is refused (the demand is held) and 6041h bit 11 is set;
- touch probe 1 (60B8h-60BAh): latch 6064h on the rising edge of the probe input.  The
  input is set by :meth:`SimDrive.set_probe_input` (e.g. the demo's item sensor), or, with
  ``probe_input="home"`` (``.simulation``: ``probe_input: home``), it is wired to the home
  switch: its level follows 60FDh bit 2 and the latch is exact, as a drive latching in
  hardware: the position where the servo model's path between the previous and the new
  actual position of a step crosses the switch edge, not the position at the SYNC;
- homing mode (6060h = 6, method 6098h, speed 6099h:01 [counts/s], offset 607Ch): started by
  a rising edge of controlword bit 4 in OPERATION ENABLED; methods 17/18 (negative /
  positive limit switch), 19-30 (home switch: 19, 20, 23-26 search in the positive
  direction, 21, 22, 27-30 in the negative one; the position where the switch becomes
  active is home), 35/37 (the current position).  The search runs at 6099h:01 without a
  ramp; reaching a limit switch in the search direction (home-switch methods) or an
  unsupported method is a homing error (6041h bit 13).  At home the reported position
  becomes 607Ch (the switches stay where they physically are); bit 12 "homing attained"
  and bit 10 "target reached" are then set.

Servo model (one step per SYNC, dt = 60C2h; without SYNC a timer keeps a ramp going): the
actual position x [counts] follows the demand d as a first-order lag with time constant
``tau_s`` and a velocity limit::

    x += clamp((d - x) * (1 - exp(-dt / tau)), -v_max*dt, v_max*dt)

Order at a SYNC: servo step toward the previous demand; controlword -> state machine; take
the new 607Ah; update 6041h/6064h/606Ch/60F4h/60FDh; send the TPDOs.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from ...tracking.values import mypyc_attr
from ..config.simulation import DriveParams
from ..protocol import cia402
from ..protocol.cia402 import State
from ..protocol.sdo import ABORT_VALUE_RANGE, SdoAbortError
from .node import NMT_OPERATIONAL, SimNode

EMCY_FOLLOWING_ERROR = 0x8611
EMCY_HEARTBEAT = 0x8130
EMCY_GENERIC = 0x1000

HM_START = 1 << 4  #: controlword bit 4 in homing mode: homing operation start
HM_ATTAINED = 1 << 12  #: statusword bit 12 in homing mode: homing attained
HM_ERROR = 1 << 13  #: statusword bit 13 in homing mode: homing error

#: the statusword's bits given by the 402 state alone (state bits, remote, voltage enabled)
_SW_STATE: dict[State, int] = {
    st: bits | cia402.SW_REMOTE | (cia402.SW_VOLTAGE_ENABLED if st in (
        State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED,
        State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE) else 0)
    for st, bits in cia402.STATE_BITS.items()}
#: the states whose ramp runs on the drive's own timer without SYNC (device_timer_ns)
_RAMPS = (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)
#: the objects :meth:`SimDrive._publish` writes, in its order
_PUBLISHED = ((0x6041, 0), (0x6064, 0), (0x606C, 0), (0x60F4, 0), (0x60FD, 0))
_UNREAD = object()  #: no raw value read yet (the caches of 6040h and 607Ah)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable; subclassed in Python)
class SimDrive(SimNode):
    kind = "drive"

    def __init__(self, name: str, eds: str, node_id: int, bus: Any,
                 params: DriveParams | None = None, boot_delay_ns: int = 5_000_000) -> None:
        # (the keyword written out: mypyc 2.4 passed a ``**kw`` on as the first optional
        #  positional argument, boot_delay_ns = the dict)
        super().__init__(name, eds, node_id, bus, boot_delay_ns=boot_delay_ns)
        clock = self.clock
        self.params = params or DriveParams()
        #: the probe input wired to the home switch (:meth:`_follow_probe` after each step)
        self._probe_home = self.params.probe_input == "home"
        self.x = float(self.params.initial_counts)  # actual position [counts]
        self.v = 0.0  # actual velocity [counts/s]
        self.demand = self.x
        self.state = State.NOT_READY_TO_SWITCH_ON
        #: the last 1000 402 transitions: (number, from, to) (bounded: sim-devices runs long)
        self.transitions: deque[tuple[int, State, State]] = deque(maxlen=1000)
        self.error_code = 0
        self.enable_input = True
        self._prev_cw = 0
        self._fe_time_s = 0.0
        self._following_error = False
        self._internal_limit = False
        self._probe_level = False
        self._probe_armed = False
        self._probe_toggle = False
        self._last_step_ns = clock.now_ns()
        #: configuration values by (index, sub), until the next SDO write or reset
        self._params: dict[tuple[int, int], Any] = {}
        #: the parameters of every SYNC, read from the OD with ``_params`` (_load_cfg):
        #: 6061h, 605Ah, 6065h, 6066h, the interpolation period 60C2h [s], and what the
        #: servo model makes of it: 1 - exp(-dt/tau), the step limit v_max * dt [counts]
        self._cfg_ok = False
        self._mode = 0
        self._qs_option = 0
        self._fe_window = 0
        self._fe_ms = 0
        self._dt = 0.002
        self._lag = 1.0
        self._step_max = 0.0
        #: no switch or limit configured: 60FDh is the probe level alone
        p = self.params
        self._no_switches = (p.negative_limit is None and p.positive_limit is None
                             and p.home_switch is None and p.slow_down is None)
        #: 6040h and 607Ah as last decoded: (the stored bytes object, its value)
        self._cw_raw: object = _UNREAD
        self._cw = 0
        self._target_raw: object = _UNREAD
        self._target = 0.0
        #: the inputs of the last controlword evaluation that changed nothing and saw no
        #: edge: (state, controlword, 6061h, 605Ah, enable input); the same again is a
        #: no-op (_apply_controlword); None after any state change
        self._cw_idle: tuple[State, int, int, int, bool] | None = None
        self._publish_plan = self.store_plan(_PUBLISHED)
        #: reported position - physical position [counts] (changed by the homing mode)
        self._home_shift = 0.0
        #: homing mode: None (not started), "run", "done" or "error"
        self.homing_status: str | None = None
        if self.params.probe_input == "home":
            self._probe_level = self._on_home_switch(self.x)
        self._enter(State.SWITCH_ON_DISABLED, 1)
        self._publish()

    # -- parameters from the object dictionary -------------------------------------------
    def param(self, index: int, sub: int = 0) -> int:
        """A configuration object's value, cached until the next SDO write or reset."""
        key = (index, sub)
        value = self._params.get(key)
        if value is None:
            value = self._params[key] = int(self.load(index, sub))
        return value

    def _params_changed(self) -> None:
        """An SDO write, a mode change or a reset: the parameters are read again."""
        self._params.clear()
        self._cfg_ok = False

    def _load_cfg(self) -> None:
        self._mode = self.param(0x6061, 0)
        self._qs_option = self.param(0x605A)
        self._fe_window = self.param(0x6065)
        self._fe_ms = self.param(0x6066)
        dt = self.param(0x60C2, 1) * 10.0 ** self.param(0x60C2, 2)
        dt = self._dt = dt if dt > 0 else 0.002
        p = self.params
        a = math.exp(-dt / p.tau_s) if p.tau_s > 0 else 0.0
        self._lag = 1.0 - a
        self._step_max = p.max_velocity * dt
        self._cfg_ok = True

    @property
    def dt_s(self) -> float:
        """The interpolation period 60C2h [s] (cached with the parameters)."""
        if not self._cfg_ok:
            self._load_cfg()
        return self._dt

    @property
    def mode(self) -> int:
        """6061h, the mode of operation the drive runs (cached with the parameters)."""
        if not self._cfg_ok:
            self._load_cfg()
        return self._mode

    # -- fault injection -------------------------------------------------------------------
    def inject_fault(self, code: int = EMCY_GENERIC) -> None:
        """A drive fault (e.g. 2310h over-current): fault reaction, then FAULT."""
        self._fault(code)

    def set_enable_input(self, on: bool) -> None:
        """The drive's hardware enable (STO) input: off, it stays SWITCH ON DISABLED."""
        self.enable_input = bool(on)

    def disturb(self, counts: float) -> None:
        """Push the axis by ``counts`` (an external force): a following error if large."""
        x0 = self.x - self._home_shift
        self.x += counts
        self._follow_probe(x0)
        self._publish()

    def set_probe_input(self, level: bool) -> None:
        """The touch-probe-1 input (60FDh bit 17); a rising edge latches 6064h if armed.

        With ``probe_input="home"`` the input follows the home switch and the next servo
        step sets it again."""
        level = bool(level)
        rising = level and not self._probe_level
        self._probe_level = level
        if rising:
            self._probe_edge(self.x)
        self._publish()
        self.service_event_pdos(self.clock.now_ns())

    def _probe_edge(self, position: float) -> None:
        """A rising edge of the probe input at ``position`` [counts, reported coordinate]."""
        if not self._probe_armed:
            return
        fn = int(self.load(0x60B8, 0))
        if fn & 0x0010 and (fn >> 2) & 0x3 == 0:  # positive edge, source = probe input
            self.store(0x60BA, 0, round(position))
            if fn & 0x0002:  # continuous: bit 7 toggles with every new value
                self._probe_toggle = not self._probe_toggle
            status = 0x0001 | 0x0002 | (0x0080 if self._probe_toggle else 0)
            self.store(0x60B9, 0, status)
            if not fn & 0x0002:  # single shot: ignore further edges until re-armed
                self._probe_armed = False

    def _on_home_switch(self, x: float) -> bool:
        """Home switch active at ``x`` [counts, reported coordinate]?"""
        hs = self.params.home_switch
        return hs is not None and hs[0] <= x - self._home_shift <= hs[1]

    def _follow_probe(self, x0_phys: float) -> None:
        """Probe input wired to the home switch: after a step from ``x0_phys`` (physical
        coordinate, the switches') to the present position, update the level; a rising edge
        latches where the path first enters the switch -- interpolated within the step
        (the path x0 -> x1 is linear in the step; a switch passed over entirely within one
        step is an edge too), as a drive latching in hardware would, not the SYNC sample."""
        if self.params.probe_input != "home":
            return
        hs = self.params.home_switch
        x1_phys = self.x - self._home_shift
        level = self._on_home_switch(self.x)
        if hs is not None and not self._probe_level:
            lo, hi = hs
            a, b = min(x0_phys, x1_phys), max(x0_phys, x1_phys)
            if a <= hi and b >= lo:  # the path touches the switch: it became active
                edge = max(lo, min(x0_phys, hi))  # where the path enters [lo, hi]
                self._probe_edge(edge + self._home_shift)
                self._probe_level = True
        self._probe_level = level

    # -- state machine ---------------------------------------------------------------------
    def _enter(self, state: State, number: int) -> None:
        old = self.state
        self.state = state
        self._cw_idle = None
        self._retime()  # (the ramp timer depends on the state)
        self.transitions.append((number, old, state))
        if state is State.OPERATION_ENABLED:
            # the drive takes the target it has now (a stale 607Ah makes it jump)
            self.demand = float(self.load(0x607A, 0))
            self._fe_time_s = 0.0
        if state is State.SWITCH_ON_DISABLED and old is State.FAULT:
            self.error_code = 0
            self.store(0x603F, 0, 0)
            self.send_emcy(0x0000, 0)

    def _fault(self, code: int) -> None:
        if self.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return
        self.error_code = code
        self.store(0x603F, 0, code)
        self._enter(State.FAULT_REACTION_ACTIVE, cia402.FAULT_TRANSITION)
        self.send_emcy(code)
        self._publish()

    def _apply_controlword(self) -> None:
        d = self.node.data_store.get(0x6040)
        raw = d.get(0) if d is not None else None
        if raw is self._cw_raw:  # (decoded when the stored bytes change)
            cw = self._cw
        else:
            cw = self._cw = int(self.load(0x6040, 0))
            self._cw_raw = raw
        if not self._cfg_ok:
            self._load_cfg()
        state = self.state
        prev = self._prev_cw
        idle = (state, cw, self._mode, self._qs_option, self.enable_input) \
            if cw == prev else None
        if idle is not None and idle == self._cw_idle:
            return  # (the same inputs as last time, when nothing happened: nothing again)
        result = cia402.transition_for(state, cw, prev, self._qs_option)
        if state is State.OPERATION_ENABLED and self._mode == cia402.MODE_HM:
            if cw & HM_START and not prev & HM_START:
                self.homing_status = "run"
            elif not cw & HM_START and self.homing_status == "run":
                self.homing_status = None  # bit 4 low: homing interrupted
        self._prev_cw = cw
        if result is not None:
            if result[0] is State.READY_TO_SWITCH_ON and not self.enable_input:
                self._cw_idle = idle
                return  # no power stage without the enable input
            self._enter(result[0], result[1])
        else:
            self._cw_idle = idle

    # -- servo model -----------------------------------------------------------------------
    def _servo_step(self, dt: float) -> None:
        st = self.state
        if not self._cfg_ok:
            self._load_cfg()
        mode = self._mode if st is State.OPERATION_ENABLED else None
        if mode == cia402.MODE_CSP:
            if self._no_switches:  # (_limited_demand without a limit switch)
                d = self.demand
                self._internal_limit = False
            else:
                d = self._limited_demand()
            if dt == self._dt:  # (the period's factors computed with the parameters)
                lag, lim = self._lag, self._step_max
            else:
                p = self.params
                a = math.exp(-dt / p.tau_s) if p.tau_s > 0 else 0.0
                lag, lim = 1.0 - a, p.max_velocity * dt
            step = (d - self.x) * lag
            step = max(-lim, min(lim, step))
            self.x += step
            self.v = step / dt
            self._check_following_error(dt)
        elif mode == cia402.MODE_HM:
            self._homing_step(dt)
        elif st in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE):
            decel = float(self.param(0x6085))
            speed = max(0.0, abs(self.v) - decel * dt)
            self.v = math.copysign(speed, self.v)
            self.x += self.v * dt
            self._following_error = False
            if speed == 0.0:
                if st is State.FAULT_REACTION_ACTIVE:
                    self._enter(State.FAULT, 14)
                elif self._qs_option in (0, 1, 2, 3):
                    self._enter(State.SWITCH_ON_DISABLED, 12)
        else:
            self.v = 0.0
            self._following_error = False

    def _homing_step(self, dt: float) -> None:
        self.v = 0.0
        self._following_error = False
        if self.homing_status != "run":
            return
        method = self.param(0x6098)
        if method >= 0x80:
            method -= 0x100
        if method in (35, 37):
            self._homed()
            return
        if method in (17, 18):
            direction, bit, stop_bit = (-1, 0x1, 0x1) if method == 17 else (1, 0x2, 0x2)
        elif 19 <= method <= 30:
            direction = 1 if method in (19, 20, 23, 24, 25, 26) else -1
            bit, stop_bit = 0x4, (0x2 if direction > 0 else 0x1)
        else:
            self.homing_status = "error"  # not simulated (index pulse, manufacturer)
            return
        inputs = self._inputs()
        if inputs & bit:
            self._homed()
            return
        if inputs & stop_bit:
            self.homing_status = "error"
            return
        speed = float(self.param(0x6099, 1))
        step = direction * speed * dt
        self.x += step
        self.v = step / dt
        self.demand = self.x
        if self._inputs() & bit:
            self._homed()

    def _homed(self) -> None:
        offset = float(self.param(0x607C))
        self._home_shift += offset - self.x
        self.x = offset
        self.demand = offset
        self.v = 0.0
        self.homing_status = "done"

    def _limited_demand(self) -> float:
        d = self.demand
        self._internal_limit = False
        if self._no_switches:
            return d  # (no limit switch)
        inputs = self._inputs()
        if inputs & 0x1 and d < self.x:
            d, self._internal_limit = self.x, True
        if inputs & 0x2 and d > self.x:
            d, self._internal_limit = self.x, True
        return d

    def _check_following_error(self, dt: float) -> None:
        window = self._fe_window
        error = self.demand - self.x
        if window != 0xFFFFFFFF and abs(error) > window and not self._internal_limit:
            self._following_error = True
            self._fe_time_s += dt
            if self._fe_time_s * 1000.0 >= self._fe_ms - 1e-9:
                self._fault(EMCY_FOLLOWING_ERROR)
        else:
            self._following_error = False
            self._fe_time_s = 0.0

    def _inputs(self) -> int:
        if self._no_switches:
            return 1 << 17 if self._probe_level else 0
        p = self.params
        x = self.x - self._home_shift  # the switches are where they physically are
        bits = 0
        if p.negative_limit is not None and x <= p.negative_limit:
            bits |= 1 << 0
        if p.positive_limit is not None and x >= p.positive_limit:
            bits |= 1 << 1
        if p.home_switch is not None and p.home_switch[0] <= x <= p.home_switch[1]:
            bits |= 1 << 2
        if p.slow_down is not None and p.slow_down[0] <= x <= p.slow_down[1]:
            bits |= 1 << 16
        if self._probe_level:
            bits |= 1 << 17
        return bits

    def statusword(self) -> int:
        st = self.state
        sw = _SW_STATE[st]  # (state bits, remote, voltage enabled)
        if st is State.OPERATION_ENABLED:
            mode = self.mode
            if mode == cia402.MODE_CSP:
                sw |= cia402.SW_FOLLOWS_TARGET
                if self._following_error:
                    sw |= cia402.SW_FOLLOWING_ERROR
            elif mode == cia402.MODE_HM:
                if self.homing_status == "done":
                    sw |= cia402.SW_TARGET_REACHED | HM_ATTAINED
                elif self.homing_status == "error":
                    sw |= cia402.SW_TARGET_REACHED | HM_ERROR
        elif st is State.QUICK_STOP_ACTIVE and self.v == 0.0:
            sw |= cia402.SW_TARGET_REACHED  # CiA 402: in quick stop, bit 10 = halted
        if self._internal_limit:
            sw |= cia402.SW_INTERNAL_LIMIT
        return sw

    def _publish(self) -> None:
        """6041h, 6064h, 606Ch, 60F4h, 60FDh from the model (``store`` of each)."""
        self.store_all(self._publish_plan, (
            self.statusword(), round(self.x), round(self.v), round(self.demand - self.x),
            self._inputs()))

    # -- SimNode hooks ---------------------------------------------------------------------
    def on_sync(self, now_ns: int) -> None:
        x0 = self.x - self._home_shift
        if not self._cfg_ok:
            self._load_cfg()
        self._servo_step(self._dt)
        if self._probe_home:
            self._follow_probe(x0)
        self._last_step_ns = now_ns
        self._apply_controlword()
        st = self.state
        if not self._cfg_ok:  # (a write in _apply_controlword: the mode read again)
            self._load_cfg()
        if st is State.OPERATION_ENABLED and self._mode == cia402.MODE_CSP \
                and self.nmt_state == NMT_OPERATIONAL:
            d = self.node.data_store.get(0x607A)
            raw = d.get(0) if d is not None else None
            if raw is not self._target_raw:  # (decoded when the stored bytes change)
                self._target = float(self.load(0x607A, 0))
                self._target_raw = raw
            self.demand = self._target
        elif st in _RAMPS:
            self._retime()  # (the ramp's timer runs from this step)
        self._publish()

    def on_rpdo(self, number: int, objects: frozenset) -> None:
        # 6060h (mode) and 60B8h (touch probe function) act when received (RPDO2, type 255)
        if (0x6060, 0) in objects:
            self._sync_mode()
        if (0x60B8, 0) in objects:
            self._touch_probe_function()

    def on_write(self, index: int, sub: int, value: Any) -> None:
        self._params_changed()  # (the value is stored after this hook: read again later)
        if index == 0x6060:
            if value != cia402.MODE_HM:
                self.homing_status = None
            supported = int(self.load(0x6502, 0))
            if value <= 0 or not supported >> (value - 1) & 1:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            self.store(0x6061, 0, value)
            self._params_changed()
        elif index == 0x60C2 and sub == 2 and not -6 <= value <= 0:
            raise SdoAbortError(ABORT_VALUE_RANGE)
        elif index == 0x60B8:
            self._arm_probe(value)
        elif index == 0x6040:
            # a controlword by SDO acts at once (as an RPDO of type 254/255 would): also in
            # pre-operational, where no RPDO is processed
            self.store(0x6040, 0, value)
            self._apply_controlword()
            self._publish()

    def _sync_mode(self) -> None:
        mode = int(self.load(0x6060, 0))
        supported = int(self.load(0x6502, 0))
        if mode > 0 and supported >> (mode - 1) & 1:
            self.store(0x6061, 0, mode)
            self._params_changed()

    def _touch_probe_function(self) -> None:
        self._arm_probe(int(self.load(0x60B8, 0)))

    def _arm_probe(self, fn: int) -> None:
        was = self._probe_armed
        self._probe_armed = bool(fn & 0x0001)
        if self._probe_armed and not was:
            self.store(0x60B9, 0, 0x0001)
        elif not self._probe_armed:
            self.store(0x60B9, 0, 0x0000)

    def on_reset(self) -> None:
        # the application restarts; the axis stays where it physically is
        self._params_changed()
        self.state = State.NOT_READY_TO_SWITCH_ON
        self._enter(State.SWITCH_ON_DISABLED, 1)
        self.v = 0.0
        self.demand = self.x
        self._prev_cw = 0
        self._probe_armed = False
        self.error_code = 0
        self._publish()

    def on_heartbeat_lost(self, producer: int) -> None:
        option = self.param(0x6007)
        if option == 1:
            self._fault(EMCY_HEARTBEAT)
            return
        self.send_emcy(EMCY_HEARTBEAT)
        if option == 2 and self.state is not State.FAULT:
            self._enter(State.SWITCH_ON_DISABLED, 9 if self.state is State.OPERATION_ENABLED
                        else 12 if self.state is State.QUICK_STOP_ACTIVE else 7)
        elif option == 3 and self.state is State.OPERATION_ENABLED:
            self._enter(State.QUICK_STOP_ACTIVE, 11)
        self._publish()

    # without SYNC, a ramp (quick stop, fault reaction) still runs on the drive's own timer
    # (its inputs -- the state, v, 605Ah, 60C2h, the last step -- change in on_sync and
    #  device_timer, which retime the node in a ramp, in _enter, and by SDO writes)
    def device_timer_ns(self) -> int | None:
        st = self.state
        if st is State.FAULT_REACTION_ACTIVE or (st is State.QUICK_STOP_ACTIVE and (
                self.v != 0.0 or self.param(0x605A) in (0, 1, 2, 3))):
            return self._last_step_ns + int(2 * self.dt_s * 1e9)
        return None

    def device_timer(self, now_ns: int) -> None:
        due = self.device_timer_ns()
        if due is not None and now_ns >= due:
            x0 = self.x - self._home_shift
            self._servo_step(self.dt_s)
            self._follow_probe(x0)
            self._last_step_ns = now_ns - int(self.dt_s * 1e9)
            self._publish()
            self._retime()
