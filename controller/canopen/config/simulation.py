"""The ``.simulation:`` section of bus.yml: parameters of the simulated devices.

Device units (counts) for the drives, mm and s for the belt.  Every key is optional::

    .simulation:
      boot_delay_s: 0.005          # power-on / NMT reset -> boot-up message [s]
      <encoder slave>:             # a slave whose EDS is a CiA 406 encoder
        counts_per_mm: 40.96       # default: .tracking.conveyor.counts_per_mm (a cell: its
        sign: 1                    #   encoder of this node); default: .tracking.conveyor.sign
        profile: [[0, 300]]        # belt speed [t_s, v_mm_s] points, piecewise linear
        initial_counts: 0          # 6004h at t = 0 (before the wrap at 6002h)
        noise_counts: 0            # standard deviation of Gaussian noise [counts]
        seed: 1
      <drive slave>:               # a CiA 402 drive
        initial_counts: 0          # 6064h at power-on
        tau_s: 0.0005              # servo time constant [s]
        max_velocity: 1.0e8        # [counts/s]
        negative_limit: -100000    # limit switch (60FDh bit0) active at x <= this [counts]
        positive_limit: 9000000    # bit1 active at x >= this
        home_switch: [0, 5000]     # bit2 active in [lo, hi] [counts]
        slow_down: [8000000, 9000000]   # bit16 active in [lo, hi]
        probe_input: home          # touch-probe-1 input wired to the home switch (its level
                                   #   follows bit2; 60BAh latches the exact edge position,
                                   #   interpolated within the servo step); needs home_switch.
                                   #   none (default): only SimDrive.set_probe_input sets it
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING

from ...yamlmarks import Section, suggest
from ..protocol import od as odm

if TYPE_CHECKING:
    from .bus import ControllerConfig


@dataclass(frozen=True)
class DriveParams:
    """Simulation parameters of one drive (all positions in counts, device units)."""

    initial_counts: int = 0
    tau_s: float = 0.0005
    max_velocity: float = 1.0e8  # counts/s
    negative_limit: int | None = None  # limit switch active at x <= this
    positive_limit: int | None = None  # active at x >= this
    home_switch: tuple[int, int] | None = None  # active for lo <= x <= hi
    slow_down: tuple[int, int] | None = None
    #: what drives the touch-probe-1 input: None (only set_probe_input) or "home" (wired to
    #: the home switch: the level follows it, the latch is at the exact edge crossing)
    probe_input: str | None = None

    PROBE_INPUTS = (None, "home")

    def __post_init__(self) -> None:
        if self.probe_input not in self.PROBE_INPUTS:
            raise ValueError(f"DriveParams.probe_input (={self.probe_input!r}) must be one of "
                             f"{self.PROBE_INPUTS}")


@dataclass(frozen=True)
class EncoderParams:
    counts_per_mm: float = 40.96
    #: (t [s], v [mm/s]) points of the speed profile
    profile: tuple[tuple[float, float], ...] = ((0.0, 300.0),)
    initial_counts: int = 0
    sign: int = 1
    noise_counts: float = 0.0
    seed: int = 1


@dataclass(frozen=True)
class SimulationConfig:
    boot_delay_s: float = 0.005
    #: the simulated devices by slave name (a read-only mapping)
    devices: Mapping[str, EncoderParams | DriveParams] = field(
        default_factory=lambda: MappingProxyType({}))


def _range(s: Section, key: str) -> tuple[int, int] | None:
    if not s.has(key):
        s.raw(key, None)
        return None
    value = s.raw(key)
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
            and value[0] <= value[1]):
        raise s.error(key, "must be a list [lo, hi] of two integers (counts) with lo <= hi")
    return int(value[0]), int(value[1])


def parse_simulation(s: Section, cfg: ControllerConfig) -> SimulationConfig:
    boot = s.float("boot_delay_s", 0.005, min=0.0, max=10.0)
    devices: dict[str, EncoderParams | DriveParams] = {}
    for name, _ in list(s.items()):
        if name == "boot_delay_s":
            continue
        if name not in cfg.slaves:
            raise s.error(name, "is not a slave of this bus"
                          + suggest(str(name), list(cfg.slaves) + ["boot_delay_s"]),
                          at_value=False)
        d = s.section(name)
        prof = odm.profile(cfg.ods[name])
        if prof == odm.PROFILE_ENCODER:
            devices[name] = _encoder(d, cfg, str(name))
        elif prof == odm.PROFILE_DRIVE:
            devices[name] = _drive(d)
        else:
            raise s.error(name, f"'{name}' is neither a CiA 402 drive nor a CiA 406 encoder: "
                                "nothing to set", at_value=False)
    return SimulationConfig(boot, MappingProxyType(devices))


#: the fastest simulated belt [mm/s] (10 m/s) and the last time point of its profile [s]
MAX_BELT_SPEED = 10_000.0
MAX_PROFILE_S = 1e9


def _encoder(s: Section, cfg: ControllerConfig, node: str) -> EncoderParams:
    encoders = cfg.tracking.encoders if cfg.tracking is not None else ()
    # the encoder of this node (a cell has several), else the first one's scale
    conv = next((e for e in encoders if e.node == node),
                encoders[0] if encoders else None)
    profile = []
    for item, line, path in s.list("profile", [[0.0, 300.0]]):
        if not (isinstance(item, list) and len(item) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in item)):
            from ...errors import ConfigError
            raise ConfigError("must be a pair [t_s, v_mm_s]", file=s.file, line=line, key=path)
        if not (math.isfinite(item[0]) and 0.0 <= item[0] <= MAX_PROFILE_S
                and math.isfinite(item[1]) and abs(item[1]) <= MAX_BELT_SPEED):
            from ...errors import ConfigError
            raise ConfigError(f"(={list(item)}) must be [t_s, v_mm_s] with 0 <= t_s <= "
                              f"{MAX_PROFILE_S:g} s and |v_mm_s| <= {MAX_BELT_SPEED:g} mm/s",
                              file=s.file, line=line, key=path)
        profile.append((float(item[0]), float(item[1])))
    times = [p[0] for p in profile]
    if times != sorted(times) or len(set(times)) != len(times):
        raise s.error("profile", "the times must increase strictly")
    p = EncoderParams(
        counts_per_mm=s.float("counts_per_mm", conv.counts_per_mm if conv else 40.96,
                              above=0.0),
        profile=tuple(profile),
        initial_counts=s.int("initial_counts", 0, min=0, max=0xFFFFFFFF),
        sign=s.int("sign", conv.sign if conv else 1, allowed=(1, -1)),
        noise_counts=s.float("noise_counts", 0.0, min=0.0),
        seed=s.int("seed", 1))
    s.finish()
    return p


def _drive(s: Section) -> DriveParams:
    p = DriveParams(
        initial_counts=s.int("initial_counts", 0, min=-0x80000000, max=0x7FFFFFFF),
        tau_s=s.float("tau_s", 0.0005, min=0.0, max=1.0),
        max_velocity=s.float("max_velocity", 1.0e8, above=0.0),
        negative_limit=s.int("negative_limit", None),
        positive_limit=s.int("positive_limit", None),
        home_switch=_range(s, "home_switch"),
        slow_down=_range(s, "slow_down"),
        probe_input=_probe_input(s))
    s.finish()
    return p


def _probe_input(s: Section) -> str | None:
    value = s.str("probe_input", "none", choices=("none", "home"))
    if value == "home" and s.raw("home_switch", None) is None:
        raise s.error("probe_input", "(=home) needs a home_switch: [lo, hi] on this drive")
    return None if value == "none" else value
