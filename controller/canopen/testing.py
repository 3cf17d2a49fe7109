"""Test support: a small bus.yml and a stepped controller with simulated devices.

``bus_yml()`` writes a configuration with an encoder and drives for the given axes (EDS files
from the repository's eds/), in Lely dcfgen format plus the dot sections; the tests edit
its text to make bad files.  ``stepped(cfg)`` gives a :class:`SimWorld` and a
:class:`Controller` on it.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from ..resources import data_path
from .config import ControllerConfig, load_config
from .apps.follow import ConveyorFollow
from .master.source import SetpointSource
from .master.cycle import Controller
from .slave.world import SimWorld

EDS_DIR = data_path("eds")

_DRIVE = """\
{name}:
  dcf: {eds}/cantrack-servo.eds
  node_id: {node_id}
  heartbeat_producer: 50
  heartbeat_consumer: true
  rpdo:
    1:
      enabled: true
      transmission: 1
      mapping:
        - {{index: 0x6040, sub_index: 0}}
        - {{index: 0x607A, sub_index: 0}}
  tpdo:
    1:
      enabled: true
      transmission: 1
      mapping:
        - {{index: 0x6041, sub_index: 0}}
        - {{index: 0x6064, sub_index: 0}}
  sdo:
    - {{index: 0x6065, sub_index: 0, value: 20000}}
    - {{index: 0x6066, sub_index: 0, value: 10}}
    - {{index: 0x605A, sub_index: 0, value: 2}}
    - {{index: 0x6085, sub_index: 0, value: 200000000}}
"""

_HEAD = """\
options:
  heartbeat_multiplier: 3.0

master:
  node_id: 1
  baudrate: {baudrate}
  sync_period: {period_us}
  sync_overflow: 16
  heartbeat_producer: 50

encoder:
  dcf: {eds}/cantrack-encoder.eds
  node_id: 10
  heartbeat_producer: 50
  tpdo:
    1:
      enabled: true
      transmission: 1
      mapping:
        - {{index: 0x6004, sub_index: 0}}

"""

_TRACKING = """\
.tracking:
  conveyor:
    node: encoder
    index: 0x6004
    counts_per_mm: 40.96
    direction: [1, 0, 0]
    estimator: {{window: 16, degree: 2}}
    silent_cycles: 5
  kinematics:
    type: cartesian
    axes:
{axes}
  tracker:
    planner: softmc
    mode: absolute
  window: {{start: 250, end: 900}}
  timeouts: {{boot_up_s: 0.1, sdo_s: 0.05, enable_s: 0.2, stop_s: 0.1}}

.simulation:
  boot_delay_s: 0.005
  encoder:
    profile: [[0, 300]]
    initial_counts: 16767216
{sim}
"""

_AXIS = "      {name}: {{node: {name}, counts_per_{unit}: {cpu}, zero: 0, min: {lo}, max: {hi}}}"
_INITIAL = {"x": 4_000_000, "y": 1_000_000, "z": 500_000, "c": 0}


def bus_yml_text(axes: Iterable[str] = ("x", "y"), period_us: int = 2000,
                 baudrate: int = 1000, eds_dir: Path = EDS_DIR) -> str:
    axes = list(axes)
    text = _HEAD.format(eds=eds_dir, period_us=period_us, baudrate=baudrate)
    for i, name in enumerate(axes):
        text += _DRIVE.format(name=name, node_id=11 + i, eds=eds_dir) + "\n"
    ax_lines = "\n".join(
        _AXIS.format(name=n, unit="deg" if n == "c" else "mm",
                     cpu=1000 if n == "c" else 10000,
                     lo=-180 if n == "c" else -100, hi=180 if n == "c" else 1500)
        for n in axes)
    sim = "\n".join(f"  {n}: {{initial_counts: {_INITIAL.get(n, 0)}, max_velocity: 3.0e7}}"
                    for n in axes)
    return text + _TRACKING.format(axes=ax_lines, sim=sim)


def bus_yml(directory: Path, axes: Iterable[str] = ("x", "y"), text: str | None = None,
            name: str = "bus.yml", **kw) -> Path:
    p = Path(directory) / name
    p.write_text(text if text is not None else bus_yml_text(axes, **kw))
    return p


def stepped(cfg: ControllerConfig, source: SetpointSource | None = None,
            present: Iterable[str] | None = None, record: bool = False,
            **kw) -> tuple[SimWorld, Controller]:
    """A simulated bus of ``cfg`` and a controller on it with ``source`` (default: a
    :class:`ConveyorFollow` that never engages)."""
    world = SimWorld(cfg, present=present, record=record)
    return world, Controller(cfg, world.transport,
                             source if source is not None else ConveyorFollow(), **kw)


def load(directory: Path, **kw) -> ControllerConfig:
    return load_config(bus_yml(directory, **kw))
