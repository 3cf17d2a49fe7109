"""The ``.demo:`` section of bus.yml: items on the belt, the pick and the place.

Positions along the belt are coordinates u [mm] along ``.tracking.conveyor.direction``
measured from ``.tracking.conveyor.origin`` (the window uses the same u).  Keys::

    .demo:
      items: 4                     # items the photo-eye sees
      first_item_s: 0.3            # photo-eye trigger of the first item, after enable [s]
      pitch_mm: [300, 450]         # belt travel between two items [mm] (seeded uniform)
      seed: 1
      photo_eye: 0.0               # u of the photo-eye [mm]
      lateral: [-40, 40]           # item offset across the belt [mm] (seeded uniform)
      angle: [-30, 30]             # item angle about z [deg] (seeded uniform)
      item_types: [1, 2]           # the items' types in turn (0...255; default: all 0)
      pick: {height: 20, dwell_s: 0.15}      # z of the pick [mm]; follow time once SYNCED
      place: {position: [600, 300, 80], angle: 0, dwell_s: 0.05}
      duration_s: 30               # the demo stops at the latest after this [s]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ...errors import ConfigError
from ...yamlmarks import Section

if TYPE_CHECKING:
    from .bus import ControllerConfig
    from .tracking import TrackingConfig


@dataclass(frozen=True)
class DemoConfig:
    items: int = 4
    first_item_s: float = 0.3
    pitch_mm: tuple[float, float] = (300.0, 450.0)
    seed: int = 1
    photo_eye: float = 0.0
    lateral: tuple[float, float] = (-40.0, 40.0)
    angle: tuple[float, float] = (-30.0, 30.0)
    pick_height: float = 20.0
    pick_dwell_s: float = 0.15
    place_position: tuple[float, float, float] = (600.0, 300.0, 80.0)
    place_angle: float = 0.0
    place_dwell_s: float = 0.05
    duration_s: float = 30.0
    #: the photo-eye's items get these types in turn (empty: all type 0)
    item_types: tuple[int, ...] = ()


def _pair(s: Section, key: str, default: tuple[float, float]) -> tuple[float, float]:
    lo, hi = s.vector(key, 2, default)
    if lo > hi:
        raise s.error(key, f"must be [lo, hi] with lo <= hi, not [{lo}, {hi}]")
    return lo, hi


def _types(s: Section) -> tuple[int, ...]:
    out = []
    for v, line, path in s.list("item_types", None):
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
            raise ConfigError(f"(={v!r}) must be an item type, an integer in [0...255]",
                              file=s.file, line=line, key=path)
        out.append(v)
    return tuple(out)


def parse_demo(s: Section, cfg: ControllerConfig, tracking: TrackingConfig | None) -> DemoConfig:
    if tracking is not None and tracking.cell is not None:
        # the photo-eye items and the pick-and-place of one belt and one robot
        raise ConfigError("is the pick-and-place demo of one belt and one robot: a cell's "
                          "items come from .tracking.cell.sensors, and a cell is not run on "
                          "the bus yet (run its scenario with cantrack simulate)",
                          file=s.file, line=s.head, key=s.path)
    d = DemoConfig()
    pick = s.section("pick", {})
    place = s.section("place", {})
    out = DemoConfig(
        items=s.int("items", d.items, min=1, max=100_000),
        first_item_s=s.float("first_item_s", d.first_item_s, min=0.0),
        pitch_mm=_pair(s, "pitch_mm", d.pitch_mm),
        seed=s.int("seed", d.seed),
        photo_eye=s.float("photo_eye", d.photo_eye),
        lateral=_pair(s, "lateral", d.lateral),
        angle=_pair(s, "angle", d.angle),
        pick_height=pick.float("height", d.pick_height),
        pick_dwell_s=pick.float("dwell_s", d.pick_dwell_s, min=0.0),
        place_position=place.vector("position", 3, d.place_position),
        place_angle=place.float("angle", d.place_angle),
        place_dwell_s=place.float("dwell_s", d.place_dwell_s, min=0.0),
        duration_s=s.float("duration_s", d.duration_s, above=0.0),
        item_types=_types(s))
    pick.finish()
    place.finish()
    if out.pitch_mm[0] <= 0:
        raise s.error("pitch_mm", f"(={list(out.pitch_mm)}) must be > 0")
    s.finish()
    if tracking is not None:
        start = tracking.window[0]
        if not out.photo_eye < start:
            raise s.error("photo_eye", f"(={out.photo_eye}) must be upstream of the window "
                                       f"(.tracking.window.start = {start})")
    return out
