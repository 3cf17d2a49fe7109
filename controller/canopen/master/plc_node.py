"""The controller's own CANopen node bound to a running controller (the PLC interface).

:func:`attach_plc_node` puts a :class:`~controller.canopen.slave.plc.PlcNode` on the
controller's transport and chains it onto ``Controller.on_cycle``: each cycle it gets the
cycle's status (state and IMFS of the cycle record, the tracker's error code, the cycle's
tracking error, the estimated belt velocity, the setpoint source's typed
:class:`~.source.SourceStatus`: items, missed, dropped) and the SYNC the controller just
sent.  Its commands (engage, item trigger) are queued with :meth:`Controller.command
<.cycle.Controller.command>` as :class:`~.source.Engage` / :class:`~.source.Trigger` values:
the source gets them with the next cycle's context.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ... import __version__
from ...tracking import Mode, TrackState
from ..config.concise import effective_pdos
from ..config.plc import PlcConfig
from ..slave.plc import EDS, PlcNode, PlcStatus, reserved_cob_ids
from .events import EventKind
from .source import Engage, TrackTypes, Trigger

if TYPE_CHECKING:
    from .cycle import Controller, CycleRecord


class ControllerHost:
    """:class:`~controller.canopen.slave.plc.PlcHost` for a :class:`Controller`: the
    source's typed status, its commands queued for the source."""

    def __init__(self, ctl: Controller) -> None:
        self.ctl = ctl

    def tracking(self) -> bool:
        return self.ctl.tracking

    def track_state(self) -> TrackState:
        return self.ctl.status.track_state  # (the demo's: its robot group's)

    def engage(self, mode: Mode) -> None:
        self.ctl.command(Engage(mode))

    def trigger(self, t_ns: int, item_type: int) -> None:
        # (a source without item sensor ignores it; the node counts its triggers)
        self.ctl.command(Trigger(t_ns, item_type))

    def track_types(self) -> frozenset[int] | None:
        tc = self.ctl.cfg.tracking
        return tc.track_types if tc is not None else None

    def set_track_types(self, types: frozenset[int] | None) -> None:
        # (a source without items ignores it; 2015h keeps the value)
        self.ctl.command(TrackTypes(types))

    def _t(self) -> tuple[int, float]:
        ctl = self.ctl
        if not ctl.t0:
            return -1, 0.0
        return max(ctl.k - 1, 0), (ctl.clock.now_ns() - ctl.t0) * 1e-9

    def quick_stop(self, kind: str, detail: str) -> None:
        k, t_s = self._t()
        self.ctl.quick_stop(k, t_s, f"node {self.ctl.cfg.master.node_id} (controller)",
                            EventKind(kind), detail)

    def event(self, kind: str, detail: str, reaction: str, level: int) -> None:
        k, t_s = self._t()
        self.ctl.events.add(k, t_s, f"node {self.ctl.cfg.master.node_id} (controller)",
                            EventKind(kind), detail, reaction, level=level)

    def nmt(self, state: int) -> None:
        self.ctl.nmt_state = state

    def status(self, rec: CycleRecord, node: PlcNode) -> PlcStatus:
        app = self.ctl.status
        return PlcStatus(
            state=TrackState(rec.state), imfs=rec.imfs,
            error=int(app.error) if self.ctl.tracking else rec.error,
            items=app.items_detected if app.items_detected is not None else node.triggers,
            missed=app.items_missed, tracking_error_mm=rec.tracking_error,
            belt_vel_mm_s=rec.belt_vel if rec.belt_vel is not None else 0.0,
            triggers_dropped=app.triggers_dropped, items_ignored=app.items_ignored)


def attach_plc_node(ctl: Controller, config: PlcConfig | None = None,
                    eds: str = str(EDS)) -> PlcNode:
    """Make the running controller ``ctl`` the node of ``eds`` (node-ID ``master.node_id``)
    for a PLC; ``config``: the ``.plc`` section (default: the bus configuration's, else no
    commander: every motion command refused)."""
    cfg = ctl.cfg
    if config is None:
        config = cfg.plc or PlcConfig()
    host = ControllerHost(ctl)
    m = cfg.master
    slaves = {s.node_id: cfg.label(name) for name, s in cfg.slaves.items()}
    configured = {p.cob_id: f"{p.kind.upper()}{p.number} of {cfg.label(name)}"
                  for name, pdos in effective_pdos(cfg).items() for p in pdos.all()
                  if p.enabled}
    lim = ctl.tc.tracker.sync_trans  # (the controller checked that .tracking is there)
    assert lim is not None  # (TrackerParams fills it in)
    node = PlcNode(host, ctl.transport, m.node_id, sync_period_us=m.sync_period_us,
                   sync_overflow=m.sync_overflow, heartbeat_ms=m.heartbeat_producer_ms or 0,
                   sync_limits=lim, config=config,
                   reserved=reserved_cob_ids(m.node_id, config.commander, slaves, configured),
                   eds=eds, version=__version__)
    ctl.actors.nmt_slave = True  # (NMT to our node-ID: the node's, not another master's)
    if config.commander is not None:
        ctl.actors.node_known(config.commander)
    chained = ctl.on_cycle

    def on_cycle(c: Controller, rec: CycleRecord) -> None:
        if chained is not None:
            chained(c, rec)
        counter = c.sync.counter if c.cfg.master.sync_overflow else None
        node.cycle(host.status(rec, node), c.last_sync_ns, counter)

    ctl.on_cycle = on_cycle
    return node


def plc_summary(node: PlcNode) -> str:
    """One line for the start of a run: the node's identifiers and its commander."""
    c = node.config
    who = (f"commander node {c.commander} (heartbeat {c.commander_heartbeat_ms} ms, on loss: "
           f"{c.on_commander_lost.value})" if c.commander is not None
           else "no commander: motion commands refused (.plc.commander)")
    rx = ", ".join(f"RPDO{p.number} {p.cob_id:03X}h" for p in node.rpdos.values())
    tx = ", ".join(f"TPDO{p.number} {p.cob_id:03X}h" for p in node.tpdos)
    return (f"plc node: id {node.node_id}, SDO {0x600 + node.node_id:03X}h/"
            f"{0x580 + node.node_id:03X}h, {rx}, {tx}; {who}")
