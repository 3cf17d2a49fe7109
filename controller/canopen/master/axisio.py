"""One drive axis as the cycle sees it: its RPDO out, its TPDO in, its 402 bookkeeping.

The TPDO (6041h statusword + 6064h position actual) is unpacked in the receive callback and
kept as one tuple ``(statusword, actual_counts, t_ns, cycle)``: a snapshot taken inside the
callback, so two values of different frames are never mixed.  A TPDO shorter than its
mapping is dropped and counted (:mod:`.frames`), never unpacked.  Where the drive maps them,
the digital inputs 60FDh (a TPDO of transmission 1: limit, home and slow-down switches) and
touch probe 1 (60B9h + 60BAh in one TPDO, event-driven) are kept too (the axis jobs read
them in the source's context).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from ..config.concise import effective_pdos
from ..io.transport import Transport
from ..protocol import cia402
from ..protocol.cia402 import State
from ..protocol.frames import FrameHygiene
from ..protocol.pdo import PdoCodec

if TYPE_CHECKING:
    from ...kinematics import AxisScale
    from ..config import ControllerConfig


class DriveInput(NamedTuple):
    """One TPDO's snapshot: 6041h, 6064h [counts], when it came [ns], in which cycle, and the
    402 state the statusword shows (decoded once, here; None: an invalid pattern)."""

    statusword: int
    actual: int
    t_ns: int
    cycle: int
    state: State | None


#: the 402 state of the statusword's bits 0-3, 5, 6 (``cia402.decode_statusword`` inlined)
_STATE_OF = cia402.STATE_OF_BITS.__getitem__
#: a DriveInput from its 5 values (the named tuple's own __new__ without its extra call)
_new_input = tuple.__new__


def _configured(cfg: ControllerConfig, node: str, index: int, sub: int) -> float:
    """The value the boot leaves in ``index:sub`` (bus.yml sdo list, else EDS default)."""
    from ..protocol import od as odm
    for w in cfg.slaves[node].sdo:
        if (w.index, w.sub_index) == (index, sub):
            return float(w.value)
    var = odm.variable(cfg.ods[node], index, sub)
    value = odm.default_value(var) if var is not None else None
    return float(value or 0.0)


class AxisIO:
    def __init__(self, cfg: ControllerConfig, axis_name: str, node: str, scale: AxisScale,
                 transport: Transport, hygiene: FrameHygiene | None = None) -> None:
        self.axis = axis_name
        self.node = node
        self.scale = scale
        self.node_id = cfg.slaves[node].node_id
        self.label = cfg.label(node)
        pdos = effective_pdos(cfg)[node]
        od = cfg.ods[node]
        rp = pdos.find("rpdo", [(0x6040, 0), (0x607A, 0)])
        tp = pdos.find("tpdo", [(0x6041, 0), (0x6064, 0)])
        assert rp is not None and tp is not None  # checked by the configuration loader
        self.rpdo = PdoCodec(rp, od)
        self.tpdo = PdoCodec(tp, od)
        self._cw_pos = self.rpdo.position(0x6040)
        self._target_pos = self.rpdo.position(0x607A)
        self._sw_pos = self.tpdo.position(0x6041)
        self._act_pos = self.tpdo.position(0x6064)
        self._out = [0] * len(self.rpdo.objects)
        self._cw_target = (self._cw_pos, self._target_pos) == (0, 1) and len(self._out) == 2
        self.transport = transport
        self._send = transport.send
        self._pack = self.rpdo.struct.pack
        self._unpack = self.tpdo.struct.unpack_from
        #: the drive's quick-stop deceleration 6085h [mm/s^2 | deg/s^2] (as configured)
        self.quick_stop_decel = _configured(cfg, node, 0x6085, 0) / scale.counts_per_unit
        self.input: DriveInput | None = None
        self.cycle = -1  # set by the controller before each cycle's inputs arrive
        self.controlword = 0
        self.target = 0
        self.hold: int | None = None  # counts held while the other drives enable
        self.fault_resets = 0
        self.hygiene = hygiene if hygiene is not None else FrameHygiene()
        self._tp_size = self.tpdo.struct.size
        self._tp_what = f"TPDO{tp.number} of {self.label}"
        transport.subscribe(tp.cob_id, self._on_tpdo)
        self.rpdo_cob = rp.cob_id
        #: 60FDh digital inputs of the last TPDO (None: no TPDO of transmission 1 maps them)
        self.inputs: int | None = None
        di = pdos.find("tpdo", [(0x60FD, 0)])
        self.inputs_mapped = di is not None and di.transmission == 1
        if di is not None and self.inputs_mapped:
            self._di = PdoCodec(di, od)
            self._di_pos = self._di.position(0x60FD)
            transport.subscribe(di.cob_id, self._on_inputs)
        #: (60B9h, 60BAh) of the last touch-probe TPDO since the last arming (None: none)
        self.probe: tuple[int, int] | None = None
        pr = pdos.find("tpdo", [(0x60B9, 0), (0x60BA, 0)])
        self.probe_mapped = pr is not None
        if pr is not None:
            self._pr = PdoCodec(pr, od)
            self._pr_pos = (self._pr.position(0x60B9), self._pr.position(0x60BA))
            transport.subscribe(pr.cob_id, self._on_probe)

    def _on_tpdo(self, can_id: int, data: bytes, t_ns: int) -> None:
        if len(data) != self._tp_size and not self.hygiene.check_length(
                can_id, data, self._tp_size, self._tp_what, t_ns):
            return
        v = self._unpack(data)
        sw = v[self._sw_pos]
        self.input = _new_input(DriveInput, (sw, v[self._act_pos], t_ns, self.cycle,
                                             _STATE_OF(sw & 0x6F)))

    def _on_inputs(self, can_id: int, data: bytes, t_ns: int) -> None:
        self.inputs = int(self._di.unpack(data)[self._di_pos])

    def _on_probe(self, can_id: int, data: bytes, t_ns: int) -> None:
        v = self._pr.unpack(data)
        self.probe = (int(v[self._pr_pos[0]]), int(v[self._pr_pos[1]]))

    def fresh(self, cycle: int) -> bool:
        return self.input is not None and self.input.cycle == cycle

    def send(self, controlword: int, target: int) -> None:
        if self._cw_target:  # the RPDO maps 6040h, 607Ah and nothing else
            self._send(self.rpdo_cob, self._pack(controlword, target))
        else:
            out = self._out
            out[self._cw_pos] = controlword
            out[self._target_pos] = target
            self._send(self.rpdo_cob, self._pack(*out))
        self.controlword = controlword
        self.target = target
