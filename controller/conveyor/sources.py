"""Master sources of a moving frame (docs/spec/conveyor.md#3.2; softMC: "The input position (master
source) is usually taken as an external source (external encoder), simulated axis or even
another moving frame position").

A source is read once per sample: ``read(k, t_s)`` returns :class:`SourceState` (position,
velocity, acceleration in *source units*, e.g. encoder counts; the frame scales them to mm or
deg).  Sources are deterministic: the same calls give the same values.

- :class:`SimulatedAxis` - a function of time (exact position, velocity, acceleration).
- :class:`EncoderSource` - raw counts (pushed by the shell, or from a callable/log), unwrapped
  with :func:`controller.tracking.unwrap_counts` (counter modulus), velocity and acceleration
  estimated with :class:`controller.tracking.MasterEstimator`; keeps the raw counts it was
  given (:attr:`EncoderSource.log`) for a deterministic replay.
- :class:`FrameSource` - another moving frame's DOF coordinate [mm or deg] (read after that
  frame was updated in the same sample).
- :class:`GroupSource` - another robot group's TCP ("group as a master source",
  docs/spec/conveyor-extensions.md#4):
  its position and its rotation about an axis, in the tracking robot's world
  (``transform : TCP``), as the four sources of a group frame (type 3); read after that
  robot's update in the same sample (:class:`controller.conveyor.cell.ConveyorCell` orders
  it so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Protocol, Sequence

from ..tracking.values import as_stored, fast_init, mypyc_attr
from ..errors import ParameterError, StateError
from ..tracking import MasterEstimator, unwrap_counts
from .location import vec3

if TYPE_CHECKING:
    from .frame import MovingFrame
    from .location import Location
    from .robot import RobotGroup


@fast_init
@dataclass(frozen=True, slots=True)
class SourceState:
    """A master source value [source unit] and its rates [unit/s, unit/s^2]."""

    pos: float
    vel: float = 0.0
    acc: float = 0.0

    def extrapolated(self, dt_s: float, with_acceleration: bool = False) -> "SourceState":
        """Moved on by ``dt_s`` at constant velocity (or constant acceleration)."""
        if with_acceleration:
            return SourceState(self.pos + self.vel * dt_s + 0.5 * self.acc * dt_s * dt_s,
                               self.vel + self.acc * dt_s, self.acc)
        return SourceState(self.pos + self.vel * dt_s, self.vel, 0.0)


class MasterSource(Protocol):
    name: str

    def read(self, k: int, t_s: float) -> SourceState:
        """The source at sample k (time t_s = k*T) [source units]."""
        ...


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class SimulatedAxis:
    """A simulated master axis: ``fn(t_s) -> (pos, vel, acc)`` [unit, unit/s, unit/s^2]."""

    def __init__(self, fn: Callable[[float], tuple[float, float, float]],
                 name: str = "axis") -> None:
        self.fn = fn
        self.name = name

    @classmethod
    def constant_speed(cls, speed: float, start: float = 0.0, name: str = "axis"
                       ) -> "SimulatedAxis":
        """pos = start + speed*t [unit, unit/s]."""
        return cls(lambda t: (start + speed * t, speed, 0.0), name)

    @classmethod
    def from_profile(cls, profile, name: str = "axis") -> "SimulatedAxis":
        """From an object with ``state(t) -> MotionState`` (its x component), e.g.
        :class:`controller.simulate.master.SegmentProfile`."""
        def fn(t: float) -> tuple[float, float, float]:
            s = profile.state(t)
            return s.pos[0], s.vel[0], s.acc[0]
        return cls(fn, name)

    def read(self, k: int, t_s: float) -> SourceState:
        p, v, a = self.fn(t_s)
        return SourceState(float(p), float(v), float(a))


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class EncoderSource:
    """An incremental/absolute encoder in counts, wrapping at ``modulus`` (0: no wrap).

    Each sample's raw count comes from :meth:`push` (the shell) or, if nothing was pushed,
    from ``counts(k)`` (a callable, e.g. a recorded log).  The counts are unwrapped against
    the previous one (``unwrap_counts``: the step between two samples must stay below half
    the modulus) and fed to a :class:`MasterEstimator` (``window`` samples, quadratic fit,
    ``lead_samples`` ahead) for velocity and acceleration [counts/s, counts/s^2].
    """

    def __init__(self, sample_time_s: float, *, modulus: int = 0,
                 counts: Callable[[int], int] | Sequence[int] | None = None, window: int = 8,
                 lead_samples: float = 0.0, name: str = "encoder") -> None:
        if int(as_stored(modulus)) != as_stored(modulus) or modulus < 0:
            raise ParameterError(f"encoder modulus (={modulus!r}) must be an integer >= 0")
        self.modulus = int(modulus)
        self.name = name
        if counts is not None and not callable(counts):
            seq = list(counts)

            def from_log(k: int, seq=seq) -> int:
                if not 0 <= k < len(seq):
                    raise StateError(f"encoder {name!r}: the log has no sample {k} "
                                     f"(it holds samples 0...{len(seq) - 1})")
                return seq[k]
            counts = from_log
        self._counts = counts
        self._pending: int | None = None
        self._last: int | None = None
        self._est = MasterEstimator(sample_time_s, window=window, lead_samples=lead_samples)
        #: the raw counts read so far, one per sample (for recording and replay)
        self.log: list[int] = []

    def push(self, raw_counts: int) -> None:
        """The raw count of the next sample (overrides ``counts`` for that sample)."""
        self._pending = int(raw_counts)

    def read(self, k: int, t_s: float) -> SourceState:
        if self._pending is not None:
            raw, self._pending = self._pending, None
        elif self._counts is not None:
            raw = int(self._counts(k))
        else:
            raise StateError(f"encoder {self.name!r}: no count pushed for sample {k}")
        self.log.append(raw)
        if self._last is None:
            unwrapped = raw
        else:
            unwrapped = unwrap_counts(self._last, raw, self.modulus)
        self._last = unwrapped
        self._est.push(float(unwrapped))
        e = self._est.estimate()
        return SourceState(e.pos, e.vel, e.acc)


def quantise_counts(value_units: float, counts_per_unit: float, modulus: int = 0) -> int:
    """A raw encoder count for a position (rounded, wrapped at ``modulus``)."""
    c = int(math.floor(value_units * counts_per_unit + 0.5))
    return c % modulus if modulus else c


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class FrameSource:
    """Another moving frame's DOF coordinate as a master source [mm or deg].

    The coordinate is the other frame's scaled master relative to ``reference`` (its source
    value at coordinate 0, default 0): ``scale_i * (m_i - reference)``.
    """

    def __init__(self, frame: "MovingFrame", dof: int = 0, reference: float = 0.0,
                 name: str | None = None) -> None:
        if not 0 <= dof < frame.nof:
            raise ParameterError(f"dof (={dof!r}) must be in [0...{frame.nof - 1}] for frame "
                                 f"{frame.name!r}")
        self.frame = frame
        self.dof = dof
        self.reference = float(reference)
        self.name = name or f"{frame.name}[{dof}]"

    def read(self, k: int, t_s: float) -> SourceState:
        m = self.frame.master
        if m is None:
            raise StateError(f"frame {self.frame.name!r} must be updated before the frame that "
                             f"uses it as a master source")
        geo = self.frame.geometry()
        trig = [0.0] * geo.nof
        vals = [x.pos for x in m]
        trig[self.dof] = self.reference
        c = geo.coords(vals, trig)[self.dof]
        cd = geo.rates([x.vel for x in m])[self.dof]
        cdd = geo.rates([x.acc for x in m])[self.dof]
        return SourceState(c, cd, cdd)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class GroupSource:
    """Another robot group's TCP as a master: ``transform : robot.setpoint`` [mm, quaternion].

    The four DOFs (:meth:`axes`): x, y, z [mm] of the TCP and its rotation angle about
    ``axis`` [deg] (the twist of its orientation, unwrapped: continuous over turns).  Rates:
    the TCP velocity of the robot's output (exact), the angle rate and both accelerations by
    backward differences over one sample ``T`` (an estimate, like an encoder's).
    """

    def __init__(self, robot: "RobotGroup", transform: "Location | None" = None,
                 axis: Sequence[float] = (0.0, 0.0, 1.0), name: str | None = None) -> None:
        from .location import Location, v_unit

        self.robot = robot
        self.transform = transform if transform is not None else Location()
        self.axis = v_unit(axis, "group source axis")
        self.name = name or f"{robot.name}.TCP"
        self._k: int | None = None
        self._state: tuple[SourceState, ...] = ()
        self._prev: tuple[tuple[float, ...], float, tuple[float, ...]] | None = None
        self._theta: float | None = None

    def location(self) -> "Location":
        """The master TCP now, in the tracking robot's world."""
        return self.transform.compound(self.robot.setpoint)

    def _sample(self, k: int) -> tuple[SourceState, ...]:
        if self._k == k:
            return self._state
        from .location import q_rotate, q_twist_angle

        loc = self.location()
        vel = q_rotate(self.transform.ori, self.robot.velocity)
        twist = q_twist_angle(loc.ori, self.axis)
        if self._theta is None:
            theta = twist
        else:   # unwrap: the step between two samples is below 180 deg
            d = (twist - self._theta) % 360.0
            theta = self._theta + (d - 360.0 if d > 180.0 else d)
        T = self.robot.T
        if self._prev is None or self._k is None or k != self._k + 1:
            acc = (0.0, 0.0, 0.0)
            w = wd = 0.0
        else:
            pv, pth, pw = self._prev
            acc = vec3((a - b) / T for a, b in zip(vel, pv))
            w = (theta - pth) / T
            wd = (w - pw[0]) / T
        self._prev = (vel, theta, (w,))
        self._theta = theta
        self._k = k
        self._state = tuple(SourceState(p, v, a) for p, v, a in zip(loc.pos, vel, acc)) + \
            (SourceState(theta, w, wd),)
        return self._state

    def axes(self) -> tuple["GroupAxis", ...]:
        """The four sources (x, y, z, angle) of a group frame."""
        return tuple(GroupAxis(self, i) for i in range(4))


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class GroupAxis:
    """DOF ``index`` (0-2: x, y, z [mm]; 3: angle [deg]) of a :class:`GroupSource`."""

    def __init__(self, group: GroupSource, index: int) -> None:
        self.group = group
        self.index = index
        self.name = f"{group.name}[{'xyzθ'[index]}]"

    def read(self, k: int, t_s: float) -> SourceState:
        return self.group._sample(k)[self.index]
