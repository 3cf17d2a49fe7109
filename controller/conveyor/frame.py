"""The moving frame object (docs/spec/conveyor.md#3: the frame, its types, limits).

A :class:`MovingFrame` is a softMC moving-frame variable: a named object with a type, NOF
master sources, a geometry, a window and limits.  It is updated once per sample
(:meth:`MovingFrame.update` reads its sources) and linked to robots by
``<robot>.MasterFrame = <MF>`` (:class:`controller.conveyor.robot.RobotGroup`).

Types (``<MF>.type``, :class:`FrameType`, default 0):

- 0 linear: NOF sources, each along a direction (:mod:`.frames.linear`);
- 1 rotary: the arc through UpStream[1], ArcPoint, DownStream[1] (:mod:`.frames.rotary`);
- 2 rotary decoupled: as 1, but the orientation does not change with the master source;
- 3 group: another robot group's TCP, 4 DOFs (x, y, z, angle about an axis), the item's
  location taken at TRIGGER (:mod:`.frames.group`; the softMC overview only plans it as
  "phase 3"); made by :meth:`MovingFrame.group`.

Errors where softMC puts them (docs/spec/conveyor.md#3.1, #3.4.1):

- setting ``type`` while the frame is engaged (linked to a robot): :class:`StateError`;
- ``type`` 1 (and 2, "same as rotary") only with NOF = 1: :class:`ParameterError`
  (softMC's range says 0-1 but lists 2; we accept 0...2);
- collinear arc points (:class:`ArcGeometryError`): when ``center`` is queried while the frame
  is not linked to any robot, and when the frame is assigned to a robot's MasterFrame (the
  "circle pre-calculation").  While linked, the pre-calculated geometry is used.

Limits (docs/spec/conveyor.md#3.5, :data:`FRAME_LIMITS`, :func:`frame_limits` by softMC's
names; defaults): VelocityMaxTrans 1000 mm/s,
AccelerationMaxTrans 1000 mm/s^2, JerkMaxTrans 1000 mm/s^3, VelocityMaxRot 100 deg/s,
AccelerationMaxRot 100 deg/s^2, JerkMaxRot 100 deg/s^3.  A master above the velocity or
acceleration maxima is an error (the tracker's MASTER_VELOCITY / MASTER_ACCELERATION, which
starts the de-sync); jerk is not monitored (softMC monitors "velocities & accelerations").
"""

from __future__ import annotations

import math
import numbers
from enum import IntEnum
from typing import TYPE_CHECKING, Sequence

from ..errors import ParameterError, StateError
from ..limits import CartesianLimits, Limits
from ..tracking import TrackError
from ..tracking.values import as_stored, mypyc_attr
from .frames import FramePoint, GroupGeometry, LinearGeometry, RotaryGeometry
from .kinematics import Kinematics
from .location import Location, Vec3, as_location, v_norm, vec3
from .sources import GroupSource, MasterSource, SourceState
from .triggers import TriggerEntry
from .window import Window, WindowPosition

if TYPE_CHECKING:
    from .robot import RobotGroup


class FrameType(IntEnum):
    """``<MF>.type``, softMC's numbers (see the module docstring)."""

    LINEAR = 0
    ROTARY = 1
    ROTARY_DECOUPLED = 2
    GROUP = 3


#: the types by their softMC names, for code that reads like a softMC program
LINEAR, ROTARY, ROTARY_DECOUPLED, GROUP = (FrameType.LINEAR, FrameType.ROTARY,
                                           FrameType.ROTARY_DECOUPLED, FrameType.GROUP)
TYPE_NAMES = {LINEAR: "linear", ROTARY: "rotary", ROTARY_DECOUPLED: "rotary decoupled",
              GROUP: "group (robot TCP)"}


def _direction(frame: str, i: int, d: Sequence[float]) -> Vec3:
    """Direction ``i`` of a linear frame as a 3-tuple (a ParameterError otherwise)."""
    t = tuple(d)
    if len(t) != 3:
        raise ParameterError(f"frame {frame!r}: directions[{i}] (={t!r}) must have 3 "
                             "components (x, y, z)")
    return t


#: ``<Moving Frame>.{Velocity|Acceleration|Jerk}Max{Trans|Rot}`` with softMC's defaults
#: (docs/spec/conveyor.md#3.5): 1000 mm/s, 1000 mm/s^2, 1000 mm/s^3; 100 deg/s, 100 deg/s^2,
#: 100 deg/s^3
FRAME_LIMITS = CartesianLimits(Limits(1000.0, 1000.0, 1000.0), Limits(100.0, 100.0, 100.0))

#: softMC's names of a frame's limits -> (channel, bound) of :class:`CartesianLimits`
SOFTMC_LIMIT_NAMES: dict[str, tuple[str, str]] = {
    "VelocityMaxTrans": ("trans", "vel"), "AccelerationMaxTrans": ("trans", "acc"),
    "JerkMaxTrans": ("trans", "jerk"), "VelocityMaxRot": ("rot", "vel"),
    "AccelerationMaxRot": ("rot", "acc"), "JerkMaxRot": ("rot", "jerk"),
}


def frame_limits(base: CartesianLimits = FRAME_LIMITS, **softmc: float | int) -> CartesianLimits:
    """``base`` (softMC's defaults) with the bounds given by their softMC names, e.g.
    ``frame_limits(VelocityMaxTrans=500.0)`` [mm/s, mm/s^2, mm/s^3; deg/s, ...].

    Raises:
        ParameterError: an unknown name, or a bound that is not a finite number > 0 (the
            message names ``<Moving Frame>.<name>``).
    """
    bounds = {"trans": {"vel": base.trans.vel, "acc": base.trans.acc, "jerk": base.trans.jerk},
              "rot": {"vel": base.rot.vel, "acc": base.rot.acc, "jerk": base.rot.jerk}}
    for name, value in softmc.items():
        if name not in SOFTMC_LIMIT_NAMES:
            raise ParameterError(f"<Moving Frame>.{name}: unknown limit (known: "
                                 + ", ".join(SOFTMC_LIMIT_NAMES) + ")")
        if not (isinstance(value, numbers.Real) and not isinstance(value, bool)
                and math.isfinite(value) and value > 0):
            raise ParameterError(f"<Moving Frame>.{name} (={value!r}) must be a finite "
                                 "number > 0")
        channel, bound = SOFTMC_LIMIT_NAMES[name]
        bounds[channel][bound] = value
    return CartesianLimits(Limits(**bounds["trans"]), Limits(**bounds["rot"]))


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class MovingFrame:
    """A moving frame.  Units: mm, deg, s; source values in source units.

    Linear parameters: ``origin`` (MF.zero, the trigger point's location), ``directions``
    (one per DOF), ``scales`` [mm per source unit].  Rotary parameters: ``upstream``
    (UpStream[1], a Location), ``arc_point``, ``downstream`` (positions), ``up_master`` /
    ``down_master`` (UpMaster[1] / DownMaster[1], source units) or ``deg_per_unit``.
    ``window``: :class:`Window` in frame units (default: unlimited).  ``world``: the
    kinematics of the frame's world frame (robot type and dimension), checked at MasterFrame
    assignment (None: the robot's own).
    """

    def __init__(self, name: str, sources: Sequence[MasterSource] = (), *, type: int = LINEAR,
                 nof: int | None = None, directions: Sequence[Sequence[float]] | None = None,
                 scales: Sequence[float] | None = None,
                 origin: Location | Sequence[float] = Location(),
                 upstream: Location | Sequence[float] | None = None,
                 arc_point: Sequence[float] | None = None,
                 downstream: Sequence[float] | None = None, up_master: float = 0.0,
                 down_master: float | None = None, deg_per_unit: float | None = None,
                 limits: CartesianLimits = FRAME_LIMITS, window: Window | None = None,
                 trigger_delay_s: float = 0.0, world: "Kinematics | None" = None) -> None:
        self.name = str(name)
        #: the kinematics of the world frame the frame's object is given in (None: the
        #: robot's own; :func:`controller.conveyor.kinematics.check_compatible`)
        if world is not None and not isinstance(world, Kinematics):
            raise ParameterError(f"frame {name!r}: world (={world!r}) must be a Kinematics")
        self.world = world
        self.sources = tuple(sources)
        n = as_stored(nof) if nof is not None else (len(self.sources) or 1)
        if int(n) != n or n < 1:
            raise ParameterError(f"frame {name!r}: NOF (={nof!r}) must be an integer >= 1")
        if self.sources and len(self.sources) != n:
            raise ParameterError(f"frame {name!r}: NOF (={n}) must equal the number of master "
                                 f"sources ({len(self.sources)})")
        self.nof = int(n)
        self.directions: tuple[Vec3, ...] = tuple(
            _direction(name, i, d) for i, d in enumerate(directions)) if directions is not None \
            else tuple(vec3(1.0 if j == i else 0.0 for j in range(3)) for i in range(self.nof))
        self.scales = tuple(scales) if scales is not None else (1.0,) * self.nof
        self.origin = as_location(origin)
        self.upstream = as_location(upstream) if upstream is not None else None
        self.arc_point = tuple(arc_point) if arc_point is not None else None
        self.downstream = tuple(downstream) if downstream is not None else None
        self.up_master = float(up_master)
        self.down_master = down_master
        self.deg_per_unit = deg_per_unit
        if not isinstance(limits, CartesianLimits):
            raise ParameterError(f"frame {name!r}: limits (={limits!r}) must be a "
                                 "CartesianLimits (see frame_limits)")
        self.limits = limits
        if not (isinstance(trigger_delay_s, (int, float)) and math.isfinite(trigger_delay_s)
                and trigger_delay_s >= 0.0):
            raise ParameterError(f"frame {name!r}: trigger delay (={trigger_delay_s!r}) must "
                                 "be >= 0 s")
        #: the delay from the sensor edge to the TRIGGER [s] (docs/spec/conveyor.md#5.2: the
        #: 1-2 sample delay "causes a gap in the position"; corrected at TRIGGER)
        self.trigger_delay_s = float(trigger_delay_s)
        self.window = window if window is not None else Window.unlimited(self.nof)
        if self.window.nof != self.nof:
            raise ParameterError(f"frame {name!r}: the window has {self.window.nof} DOF(s), "
                                 f"the frame NOF = {self.nof}")
        self._type: FrameType = LINEAR
        #: type 3: the robot TCP source (set by :meth:`group`)
        self.group_source: GroupSource | None = None
        self.group_axis: Vec3 = (0.0, 0.0, 1.0)
        #: the robot that has this frame as its (syncing/synced) MasterFrame, or None
        self.engaged_by: str | None = None
        #: robots de-syncing from this frame (it cannot be engaged until the set is empty)
        self.desyncing_by: set[str] = set()
        self._linked_geometry: LinearGeometry | RotaryGeometry | GroupGeometry | None = None
        #: the source states of the last update (one per DOF), None before the first
        self.master: tuple[SourceState, ...] | None = None
        self.sample = 0
        self.type = type

    @classmethod
    def group(cls, name: str, master: "RobotGroup", *, transform: Location | None = None,
              axis: Sequence[float] = (0.0, 0.0, 1.0), window: Window | None = None,
              limits: CartesianLimits = FRAME_LIMITS, world: Kinematics | None = None
              ) -> "MovingFrame":
        """A group frame (type 3): the TCP of robot group ``master`` as the master source,
        in this frame's world (``transform : TCP``; the transformation between the tracked and
        the tracking kinematics), with its rotation about ``axis`` (world).  The window is over
        the 4 coordinates (Δx, Δy, Δz [mm], Δθ [deg] since the trigger; default unlimited);
        ``world`` defaults to the master robot's kinematics (a robot of another system cannot
        track it).  Items get their full location at TRIGGER (``RobotGroup.trigger`` with
        ``offset=`` relative to the TCP, or ``location=``).
        """
        src = GroupSource(master, transform, axis)
        f = cls(name, src.axes(), window=window if window is not None else Window.unlimited(4),
                limits=limits, world=world if world is not None else master.kinematics)
        f.group_source = src
        f.group_axis = src.axis
        f._type = GROUP
        return f

    # -- type -------------------------------------------------------------------------------
    @property
    def type(self) -> FrameType:
        return self._type

    @type.setter
    def type(self, value: FrameType | int) -> None:
        if isinstance(value, bool) or value not in (LINEAR, ROTARY, ROTARY_DECOUPLED, GROUP):
            raise ParameterError(f"<{self.name}>.type (={value!r}) must be 0 (linear), "
                                 "1 (rotary), 2 (rotary decoupled) or 3 (group)")
        if (value == GROUP) != (self.group_source is not None):
            raise ParameterError(f"<{self.name}>.type 3 (group) is made by MovingFrame.group() "
                                 "(a robot's TCP as the master) and cannot be changed")
        if self.linked:
            raise StateError(f"<{self.name}>.type cannot be set while the moving frame is "
                             f"engaged (linked to robot(s) {self._linked_names()})")
        if value in (ROTARY, ROTARY_DECOUPLED) and self.nof != 1:
            raise ParameterError(f"<{self.name}>.type (={value}) rotary needs NOF = 1 "
                                 f"(this frame has NOF = {self.nof})")
        self._type = FrameType(int(value))

    @property
    def type_name(self) -> str:
        return TYPE_NAMES[self._type]

    # -- linking (called by RobotGroup) -------------------------------------------------------
    @property
    def linked(self) -> bool:
        return self.engaged_by is not None or bool(self.desyncing_by)

    def _linked_names(self) -> str:
        names = ([self.engaged_by] if self.engaged_by else []) + sorted(self.desyncing_by)
        return ", ".join(repr(n) for n in names)

    def _link(self) -> None:
        """Circle pre-calculation at assignment (raises ArcGeometryError for a bad arc)."""
        if not self.linked:
            self._linked_geometry = self._build_geometry()

    def _unlink_if_free(self) -> None:
        if not self.linked:
            self._linked_geometry = None

    # -- geometry ---------------------------------------------------------------------------
    def _build_geometry(self) -> LinearGeometry | RotaryGeometry | GroupGeometry:
        if self._type == GROUP:
            src = self.group_source
            if src is None:
                raise ParameterError(f"group frame {self.name!r}: no master robot (group source)")
            return GroupGeometry(self.group_axis, src.robot.kinematics.dimension)
        if self._type == LINEAR:
            if len(self.directions) != self.nof or len(self.scales) != self.nof:
                raise ParameterError(f"frame {self.name!r}: give one direction and one scale "
                                     f"per DOF (NOF = {self.nof})")
            return LinearGeometry(self.origin, self.directions, self.scales)
        up, arc, down = self.upstream, self.arc_point, self.downstream
        if up is None or arc is None or down is None:
            missing = [n for n, v in (("UpStream[1]", up), ("ArcPoint", arc),
                                      ("DownStream[1]", down)) if v is None]
            raise ParameterError(f"rotary frame {self.name!r}: {', '.join(missing)} not given")
        return RotaryGeometry.from_points(
            up, arc, down, up_master=self.up_master,
            down_master=self.down_master, deg_per_unit=self.deg_per_unit,
            decoupled=self._type == ROTARY_DECOUPLED)

    def geometry(self) -> LinearGeometry | RotaryGeometry | GroupGeometry:
        """The pre-calculated geometry while linked, else computed from the current values."""
        if self._linked_geometry is not None:
            return self._linked_geometry
        return self._build_geometry()

    def _rotary(self) -> RotaryGeometry:
        if self._type in (LINEAR, GROUP):
            raise StateError(f"<{self.name}>: center/start/normal/radius/alpha exist for "
                             "rotary frames (type 1 or 2) only")
        geo = self.geometry()
        assert isinstance(geo, RotaryGeometry)  # type 1 or 2
        return geo

    @property
    def center(self) -> Vec3:
        """``<MF>.center`` [mm] (rotary).  Unlinked: computed now (ArcGeometryError if the
        three points are collinear)."""
        return self._rotary().center

    @property
    def start(self) -> Vec3:
        """<MF>.start (unit vector)"""
        return self._rotary().start

    @property
    def normal(self) -> Vec3:
        """<MF>.normal (unit vector)"""
        return self._rotary().normal

    @property
    def radius(self) -> float:
        """<MF>.radius [mm]"""
        return self._rotary().radius

    @property
    def alpha(self) -> float:
        """arc angle alpha [deg]"""
        return self._rotary().alpha_deg

    # -- cyclic -----------------------------------------------------------------------------
    def update(self, k: int, t_s: float) -> tuple[SourceState, ...]:
        """Read every master source for sample k (time t_s)."""
        if not self.sources:
            raise StateError(f"frame {self.name!r} has no master source")
        self.master = tuple(s.read(k, t_s) for s in self.sources)
        self.sample = k
        return self.master

    def set_master(self, states: Sequence[SourceState], k: int | None = None) -> None:
        """Set the source states directly (shells and tests without source objects)."""
        if len(states) != self.nof:
            raise ParameterError(f"frame {self.name!r}: {len(states)} source state(s) given, "
                                 f"NOF = {self.nof}")
        self.master = tuple(states)
        if k is not None:
            self.sample = k

    def _require_master(self) -> tuple[SourceState, ...]:
        if self.master is None:
            raise StateError(f"frame {self.name!r} has not been updated yet (no master values)")
        return self.master

    def source_values(self, age_s: float = 0.0) -> tuple[float, ...]:
        """The master source values ``age_s`` before the last update (what TRIGGER latches).

        ``age_s`` > 0 is softMC's correction term for the delay between the sensor edge and the
        TRIGGER (docs/spec/conveyor.md#5.2): each source is taken back along its motion,
        pos - vel*d + acc*d^2/2 (exact for a constant-acceleration source), so the latched value
        is where the item was at the edge, not ``vel*d`` further on.
        """
        if age_s == 0.0:
            return tuple(s.pos for s in self._require_master())
        return tuple(s.extrapolated(-age_s, with_acceleration=True).pos
                     for s in self._require_master())

    # -- items ------------------------------------------------------------------------------
    def coords(self, item: TriggerEntry, master: Sequence[SourceState] | None = None
               ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """The item's DOF coordinates and rates [frame units] (from ``master`` or the last
        update)."""
        m = self._require_master() if master is None else master
        geo = self.geometry()
        return (geo.coords([s.pos for s in m], item.values), geo.rates([s.vel for s in m]),
                geo.rates([s.acc for s in m]))

    def point(self, item: TriggerEntry, master: Sequence[SourceState] | None = None
              ) -> FramePoint:
        """``<MF>.here`` for ``item``, with its rates."""
        c, cd, cdd = self.coords(item, master)
        return self.geometry().point(c, cd, cdd, item.dr_mm, item)

    def here(self, item: TriggerEntry) -> Location:
        return self.point(item).here

    def zero(self, item: TriggerEntry | None = None) -> Location:
        """``<MF>.zero`` (MF(0)): the item's location at its trigger."""
        return self.geometry().zero(item.dr_mm if item is not None else 0.0, item)

    def window_position(self, item: TriggerEntry,
                        master: Sequence[SourceState] | None = None) -> WindowPosition:
        return self.window.classify(self.coords(item, master)[0], item.inverse)

    # -- monitoring -------------------------------------------------------------------------
    def check_limits(self, point: FramePoint) -> TrackError:
        """MASTER_VELOCITY / MASTER_ACCELERATION if ``point`` exceeds the frame's maxima."""
        trans, rot = self.limits.trans, self.limits.rot
        if v_norm(point.vel) > trans.vel or abs(point.ang_vel) > rot.vel:
            return TrackError.MASTER_VELOCITY
        if v_norm(point.acc) > trans.acc or abs(point.ang_acc) > rot.acc:
            return TrackError.MASTER_ACCELERATION
        return TrackError.NONE

    def __repr__(self) -> str:
        return f"MovingFrame({self.name!r}, type={self._type} ({self.type_name}), NOF={self.nof})"
