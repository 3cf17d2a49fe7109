"""Bus load of a configuration: worst-case bits per SYNC cycle over the bit time of a cycle.

A CAN 2.0A data frame with n data bytes takes at most, with worst-case bit stuffing and the
interframe space (canopen-notes.md, "Bus capacity")::

    bits(n) = 8n + 47 + floor((33 + 8n) / 4)      # n = 0: 55, 4: 95, 6: 115, 8: 135

Counted per cycle (frames per cycle x bits):

- the SYNC (1 byte with a counter, 1019h/``sync_overflow`` > 0, else 0 bytes): 1;
- every enabled TPDO of a slave: transmission 0 or 1: 1, n = 2...240: 1/n; event-driven
  (254/255) with an event timer: cycle / event timer; purely on change: not counted (its rate
  depends on the process; listed with 0 frames);
- the RPDO the controller sends every cycle to each drive axis (6040h + 607Ah);
- heartbeats (1 byte) of the master and of every slave: cycle / producer time.

``load = bits per cycle / (bitrate * cycle)``.  Above :data:`WARN_LOAD` (60 %) the
controller warns, above :data:`MAX_LOAD` (90 %) it refuses the configuration: the frames of
a cycle would not reliably fit before the next SYNC, and SYNC jitter grows with the load.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ...errors import ConfigError
from .concise import effective_pdos

if TYPE_CHECKING:
    from .bus import ControllerConfig

log = logging.getLogger(__name__)

WARN_LOAD = 0.60
MAX_LOAD = 0.90


def frame_bits(n_bytes: int) -> int:
    """Worst-case bits on the wire of a standard-ID data frame with ``n_bytes`` bytes."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"n_bytes (={n_bytes}) must be in [0...8]")
    return 8 * n_bytes + 47 + (33 + 8 * n_bytes) // 4


@dataclass(frozen=True, slots=True)
class LoadItem:
    what: str
    frames_per_cycle: float
    data_bytes: int

    @property
    def bits_per_cycle(self) -> float:
        return self.frames_per_cycle * frame_bits(self.data_bytes)


@dataclass(frozen=True)
class BusLoad:
    items: tuple[LoadItem, ...]
    cycle_s: float
    bitrate: int

    @property
    def bits_per_cycle(self) -> float:
        return sum(i.bits_per_cycle for i in self.items)

    @property
    def load(self) -> float:
        """Fraction of the bus time of one cycle (0.55 = 55 %)."""
        return self.bits_per_cycle / (self.bitrate * self.cycle_s)

    @property
    def busy_s(self) -> float:
        """Time the frames of one cycle occupy the bus [s]."""
        return self.bits_per_cycle / self.bitrate

    def table(self) -> str:
        rows = [f"{'frame':<34} {'frames/cycle':>12} {'bytes':>5} {'bits/cycle':>10}"]
        for i in self.items:
            rows.append(f"{i.what:<34} {i.frames_per_cycle:>12.4g} {i.data_bytes:>5} "
                        f"{i.bits_per_cycle:>10.1f}")
        rows.append(f"{'total':<34} {'':>12} {'':>5} {self.bits_per_cycle:>10.1f}")
        rows.append(f"bus load {100 * self.load:.1f} % of {self.bitrate / 1000:g} kbit/s x "
                    f"{self.cycle_s * 1e3:g} ms")
        return "\n".join(rows)


def bus_load(cfg: ControllerConfig) -> BusLoad:
    """The worst-case load of ``cfg``'s cyclic traffic (see the module docstring)."""
    cycle_s = cfg.period_s
    items = [LoadItem("SYNC", 1.0, 1 if cfg.master.sync_overflow else 0)]
    pdos = effective_pdos(cfg)
    drive_nodes = set(cfg.tracking.drive_nodes) if cfg.tracking is not None else set()
    for name, node in pdos.items():
        for p in node.tpdo.values():
            if not p.enabled:
                continue
            t = p.transmission
            if t <= 1:
                rate = 1.0
            elif t <= 240:
                rate = 1.0 / t
            elif t >= 254 and p.event_timer:
                rate = cycle_s / (p.event_timer * 1e-3)
            else:
                rate = 0.0
            items.append(LoadItem(f"{name} TPDO{p.number} (type {t})", rate, p.size))
        if name in drive_nodes:
            rp = node.find("rpdo", [(0x6040, 0), (0x607A, 0)])
            if rp is not None:
                items.append(LoadItem(f"{name} RPDO{rp.number} (controller)", 1.0, rp.size))
        hb = cfg.slaves[name].heartbeat_producer_ms
        if hb is None:
            from ..protocol import od as odm
            var = odm.variable(cfg.ods[name], 0x1017)
            hb = int(odm.default_value(var) or 0) if var is not None else 0
        if hb:
            items.append(LoadItem(f"{name} heartbeat", cycle_s / (hb * 1e-3), 1))
    if cfg.master.heartbeat_producer_ms:
        items.append(LoadItem("master heartbeat",
                              cycle_s / (cfg.master.heartbeat_producer_ms * 1e-3), 1))
    return BusLoad(tuple(items), cycle_s, cfg.bitrate)


def check_bus_load(cfg: ControllerConfig) -> BusLoad:
    """The load of ``cfg``; warns above 60 %, raises ConfigError above 90 %."""
    load = bus_load(cfg)
    pct = 100.0 * load.load
    where = f"{cfg.master.sync_period_us} us cycle at {cfg.master.baudrate_kbit} kbit/s"
    if load.load > MAX_LOAD:
        raise ConfigError(
            f"bus load {pct:.1f} % ({load.bits_per_cycle:.0f} bit per {where}) is above "
            f"{100 * MAX_LOAD:.0f} %: lengthen master.sync_period, raise master.baudrate or "
            "map fewer bytes", file=cfg.file, line=cfg.master.sync_period_line,
            key="master.sync_period")
    if load.load > WARN_LOAD:
        log.warning("%s: bus load %.1f %% (%.0f bit per %s) is above %.0f %%", cfg.file, pct,
                    load.bits_per_cycle, where, 100 * WARN_LOAD)
    return load
