"""A simulated CANopen slave: the slave-node engine (:mod:`.engine`) plus fault injection.

The engine gives NMT, heartbeat producer and consumer, the SDO server, PDOs and EMCY on the
rack's clock (no python-can periodic thread: a stepped simulation cannot use one).
:class:`SimNode` adds what a test of the controller needs of a misbehaving node: heartbeat
stop, silence (nothing sent at all), PDOs muted, SDO server mute, an SDO abort on one
object, identity changes, a refused NMT start (an EMCY instead), power off.

Subclasses (the drive, the encoder) implement the engine's hooks: ``on_sync`` (before the
TPDOs are sent), ``on_reset``, ``on_write``, ``on_rpdo``, ``on_heartbeat_lost``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ...tracking.values import mypyc_attr
from ..protocol.sdo import (
    ABORT_DEVICE_STATE,
    ABORT_GENERAL,
    ABORT_PARAM_INCOMPATIBLE,
    ABORT_PDO_LENGTH,
    ABORT_PDO_MAPPING,
    ABORT_VALUE_RANGE,
    SdoAbortError,
)
from .engine import EMCY_SYNC_LENGTH, Nmt, SlaveBus, SlaveEngine

NMT_INITIALISING = Nmt.INITIALISING
NMT_STOPPED = Nmt.STOPPED
NMT_OPERATIONAL = Nmt.OPERATIONAL
NMT_PRE_OPERATIONAL = Nmt.PRE_OPERATIONAL

__all__ = ["ABORT_DEVICE_STATE", "EMCY_SYNC_LENGTH", "ABORT_PARAM_INCOMPATIBLE", "ABORT_PDO_LENGTH",
           "ABORT_PDO_MAPPING", "ABORT_VALUE_RANGE", "NMT_INITIALISING", "NMT_OPERATIONAL",
           "NMT_PRE_OPERATIONAL", "NMT_STOPPED", "SimNode"]


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable; subclassed in Python)
class SimNode(SlaveEngine):
    """Base of the simulated devices (one node on the rack's port).

    Its timers are cached (:attr:`SlaveEngine.cache_timers`): what ``listening`` and
    ``may_send`` read that a timer depends on (:attr:`powered`, :attr:`silent`,
    :attr:`pdos_muted`) are properties that retime the node when set; a subclass with a
    ``device_timer_ns`` calls ``_retime`` where its inputs change outside the engine's
    entry points."""

    kind = "node"
    cache_timers = True

    def __init__(self, name: str, eds: str | Path, node_id: int, bus: SlaveBus,
                 boot_delay_ns: int = 5_000_000) -> None:
        self._powered = True
        self._silent = False
        self._pdos_muted = False
        self.sdo_muted = False
        self.heartbeat_enabled = True
        self._sdo_rejects: dict[tuple[int, int], int] = {}
        self._identity_override: dict[int, int] = {}
        #: an EMCY code sent instead of obeying NMT start (a device that refuses to start,
        #: like a CANopenNode device without its storage files: 5000h)
        self.refuse_start: int | None = None
        super().__init__(name, eds, node_id, bus, boot_delay_ns=boot_delay_ns)

    # -- fault injection -----------------------------------------------------------------
    @property
    def powered(self) -> bool:
        return self._powered

    @powered.setter
    def powered(self, on: bool) -> None:
        self._powered = on
        self._retime()  # (after the change: a timer computed meanwhile is not kept)

    @property
    def silent(self) -> bool:
        return self._silent

    @silent.setter
    def silent(self, on: bool) -> None:
        self._silent = on
        self._retime()

    @property
    def pdos_muted(self) -> bool:
        return self._pdos_muted

    @pdos_muted.setter
    def pdos_muted(self, on: bool) -> None:
        self._pdos_muted = on
        self._retime()

    def listening(self) -> bool:
        return self._powered

    def may_send(self, kind: str) -> bool:
        if not self._powered or self._silent:
            return False
        if kind == "pdo":
            return not self._pdos_muted
        if kind == "hb":
            return self.heartbeat_enabled
        if kind == "sdo":
            return not self.sdo_muted
        return True

    def accept_start(self) -> bool:
        if self.refuse_start is not None:
            self.send_emcy(self.refuse_start)  # (as CANopenNode without its storage files)
            return False
        return True

    def reject_sdo(self, index: int, sub: int, code: int) -> None:
        """Abort every SDO write to ``index:sub`` with ``code``."""
        self._sdo_rejects[(index, sub)] = code

    def check_access(self, index: int, sub: int) -> None:
        if not self.powered:
            raise SdoAbortError(ABORT_GENERAL)
        code = self._sdo_rejects.get((index, sub))
        if code is not None:
            raise SdoAbortError(code)

    def set_identity(self, vendor: int | None = None, product: int | None = None,
                     revision: int | None = None, serial: int | None = None) -> None:
        for sub, value in ((1, vendor), (2, product), (3, revision), (4, serial)):
            if value is not None:
                self.store(0x1018, sub, value)
                self._identity_override[sub] = value

    def on_comm_reset(self) -> None:
        for sub, value in self._identity_override.items():
            self.store(0x1018, sub, value)

    def mute_pdos(self, on: bool = True) -> None:
        """Stop (or resume) sending PDOs; heartbeat, EMCY and SDO go on."""
        self.pdos_muted = on

    def mute_sdo(self, on: bool = True) -> None:
        """Stop (or resume) answering SDO requests (a hung SDO server)."""
        self.sdo_muted = on

    def silence(self, on: bool = True) -> None:
        """Stop (or resume) sending anything (the node still listens)."""
        self.silent = on

    def stop_heartbeat(self) -> None:
        self.heartbeat_enabled = False

    def resume_heartbeat(self) -> None:
        self.heartbeat_enabled = True
        self._schedule_heartbeat(self.clock.now_ns())

    def reset_itself(self) -> None:
        """The node resets on its own (a watchdog, a supply glitch): reset application, then
        its boot-up after ``boot_delay_ns``, in pre-operational with its EDS defaults."""
        self.reset(application=True)

    def power_off(self) -> None:
        """The node disappears: it neither answers nor sends."""
        self.powered = False

    def _on_sdo_frame(self, can_id: int, data: bytes, t: Any) -> None:
        if not self.sdo_muted and not self._silent:
            super()._on_sdo_frame(can_id, data, t)
