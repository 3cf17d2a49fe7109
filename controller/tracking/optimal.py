"""The default approach planner ``optimal``: time-optimal, norm-safe, in the master's frame.

One channel (3-D translation in mm, or the 1-D rotation in deg; the same code for n = 1 and
n = 3); spec: docs/spec/tracking.md#6.  Why: softMC's algorithm (``softmc``,
docs/spec/tracking.md#3) re-plans a fixed-time quintic every sample and clamps it; it is
slow, may oscillate, and its "take the middle" switch makes a jerk spike of 7-37 x J
(docs/spec/tracking.md#3.8).  This planner keeps
every vector-norm limit by construction, reaches the master in near-minimum time, does not
oscillate (one time-optimal plan, re-made only when the master deviates from its prediction
or a better plan exists), and switches to SYNCED with relative position, velocity and
acceleration all zero, so the switch has no spike.

Time axis (as ``softmc``, docs/spec/tracking.md#2.2)
----------------------------------------------------
``step()`` gets the master at sample k, (pm, vm, am); the planner holds the robot setpoint
(p, v, a) of sample k-1.  The master at (k-1)T is the given one extrapolated back by T at
constant acceleration: mb = (pm - vm*T + am*T^2/2, vm - am*T, am).

Relative problem
----------------
e(t) = robot(t) - master(t), the master moving at constant acceleration am (jerk 0).  A plan
starts at (k-1)T from e0 = (p, v, a) - mb and brings e to (0, 0, 0) in minimum time (Ruckig,
jerk-limited; ``Synchronization.TimeIfNecessary`` with zero targets does not synchronise the
axes, so each arrives at its own optimum and then rests at 0).  The setpoint j samples after
the plan's origin is master(k) + e(jT).  Ruckig needs SI-like magnitudes: every length (mm
or deg) is multiplied by 1e-3 inside.

The plan is made in an orthonormal basis R (q = R e) with per-axis bounds from weights
w_i > 0, ||w|| = 1, and the channel's sync limits V, A, J (used at (1 - 1e-9) of their value):

    q_v,i in [-V*w_i - vlo_i, V*w_i - vhi_i]   (vlo_i <= (R v_m(t))_i <= vhi_i on the plan)
    q_a,i in [-A*w_i - (R a_m)_i, A*w_i - (R a_m)_i],   q_j,i in [-J*w_i, J*w_i]

so that the robot's own |(R v)_i| <= V*w_i, |(R a)_i| <= A*w_i, |(R j)_i| <= J*w_i, hence

    ||v|| = ||R v|| <= V*||w|| = V,   ||a|| <= A,   ||j|| <= J

at every instant (a box inside the ball), and the finite differences of the sampled
setpoints -- weighted averages (B-splines) of the continuous derivatives -- obey the same
norms.  The setpoint stream is C2 with bounded jerk: every plan starts from the state the
planner output last (a master with a jerk, which the plan takes as 0, adds its own).

Accelerating master: the velocity bounds
----------------------------------------
With am != 0 the master's velocity changes during the plan.  The bounds start from its
current velocity; then each axis' bound is tightened by the largest excess of the robot's
own velocity (R v_m(t))_i + q_v,i(t) over [-V*w_i, V*w_i] along that axis' profile (exact:
the extremes of the quadratic velocity in every constant-jerk phase of Ruckig's profile),
by a secant iteration over-stepped by 5 % until no axis exceeds.  An axis whose bound closes
is infeasible for that w.  An axis that is done follows the master: if the master's own
component (R v_m(t))_i leaves [-V*w_i, V*w_i] before the whole plan ends, the plan is only
valid until then (see "receding horizon").  Where a velocity bound only gets looser with
time (the master decelerating against the direction the robot cruises at), the plan is made
again every sample until that cruise ends, so the robot uses the bound that grows (what a
per-cycle planner does).  The weight search uses a cheaper, more conservative evaluation:
each axis' bounds hold the master's velocity range over that axis' own duration (per-axis
horizon H_i >= D_i, by iteration, warm-started from the looser grid point).

Choice of the basis R and the weights w
---------------------------------------
For n = 1, R = 1 and w = 1.  For n = 3 two bases are tried -- the world axes, and the
master's frame (u1 along the master's velocity, u2 along the part of its acceleration normal
to u1, else of the position error; u3 = u1 x u2), which keeps an accelerating master's
velocity inside a box that fits it -- and the one whose plan is shorter is kept.  In a basis
each axis' duration t_i(w_i) (Ruckig's ``independent_min_durations``) does not increase with
w_i (its feasible set only grows), so the best w of the family minimises max_i t_i(w_i) on
||w|| = 1 by equalising the durations:

    tau* = min { tau : sum_i w_i(tau)^2 <= 1 },   w_i(tau) = min { w >= f_i : t_i(w) <= tau }

Floors f_i: the master's |velocity| (over the horizon H, see below) / V and |a_m,i| / A, and
the robot's own current |a_i| / A and velocity including the overshoot of stopping its
acceleration at jerk J*w_i, (|v_i| + a_i^2/(2 J f_i)) / V, each * (1 + 1e-6) + 1e-3, so that
the robot's state lies inside the box (no out-of-limit brake).  At engage, if those do not
fit in the unit ball, the robot's are dropped (Ruckig then brakes that axis into its box
first; the only case where a norm can be exceeded, by the robot's own initial state).
Search: every axis is sampled along w_i = f_i + (1 - f_i) u on a grid of 8 values of u (one
Ruckig call per grid point gives all axes), t_i(u) is interpolated log-linearly, tau* is
found by bisection on the interpolants, the normalised solution is evaluated and the tables
refined with probes (bisection where an axis turns infeasible) for up to 6 rounds.  If the
master outgrows a weight before the plan ends, the search is repeated with the floors over
1.2 x the plan's duration (up to twice).  Separate weights for v and a, or more bases, gained
about 1 % in trials and are not used.

Receding horizon: when the plan is made again
---------------------------------------------
Every sample the master is compared with the plan's prediction (constant acceleration from
the plan's origin).  If position, velocity and acceleration match to 1e-11 relative
(rounding only), the stored trajectory is sampled (``Trajectory.at_time``: the cheap path).
Otherwise the planner plans from the setpoint it output last, with the same R and w while
they are feasible, else it searches again.  It also searches again from the current state
(a) when an axis is done before 90 % of the plan (its weight can go to the others) and at
25 % and 50 % of every plan, adopting the new plan if it ends 1 % sooner; (b) from 50 ms
before a plan's box stops holding (an accelerating master outgrowing a done axis' weight)
until it does, every 10 ms, adopting a plan that holds longer.  A search mid-plan keeps the
robot's floors (its state stays inside the new box).

Synchronisation
---------------
When the sample time reaches the plan's duration (jT >= D) the relative state is (0, 0, 0)
to Ruckig's precision (~1e-15 m); the planner returns the master exactly with synced = True
and the tracker copies the master from then on: no jump, no jerk spike.

Fallbacks (``step`` never raises)
---------------------------------
1. The fixed R, w infeasible or a Ruckig error: search R and w again.
2. No feasible plan (e.g. ||v_m|| >= V or ||a_m|| >= A, or a fast master accelerating
   away, see "Limits of the design"): the robot matches the master's velocity as far as it can --
   a Ruckig velocity-control plan in the world frame towards s * v_m, s <= 1 the largest
   factor for which one box w (unit norm) holds the robot's state (floors as above) and the
   target, limits V*w, A*w, J*w -- re-made every sample and never synced (the tracker's
   approach timeout or master-limit check then starts the de-sync); tracking is tried
   again every 10 ms.  All three norms hold: each component moves between its start and
   its target inside the box.
3. If even that fails, the robot keeps its velocity and ramps its acceleration to 0 at jerk
   J (an internal error; never observed).

Limits of the design: the box family gives up some speed in 3-D (measured: median 1.12-1.14x
the per-axis reference, which itself breaks the norm by up to sqrt(3)), and a plan's
velocity bounds are constant in the master's frame.  When a fast master accelerates
towards V while the robot has to catch up along it, the robot's cruise at V needs a
relative bound that shrinks with time; a constant bound covers less distance, so a few
such cases (~0.5 % of a harsher random suite with |v_m| ~ 0.8 V) do not synchronise
(softmc, which clamps the absolute velocity, does in ~2 s).  The remedy would be to plan
in a frame moving at the master's initial velocity (exact, constant bounds) towards the
master's state at the arrival time D, with D found by a fixed-point iteration (Ruckig's
``minimum_duration``); not done.

A master with a jerk (a conditioned encoder, ``step(..., mj)``): plans keep a 2 % reserve of
V and A and the master's jerk (plus 2 %) of J, and are sampled in the actual master's frame
while the master stays within that reserve of the prediction (docs/spec/master-conditioning.md#6.3).

FilterFactor and DampingFactor have their documented meaning for ``softmc`` only; this
planner ignores them (its synchronisation is exact, relative state zero at the plan's end,
and it needs no damping because it does not oscillate).

Compute: the cheap path (sampling) is a few microseconds per channel; a plan with a search
costs about 0.3 ms (constant master) to 1 ms (accelerating master) of pure Python, at engage
and at the few re-searches above.  A master that never moves as predicted (a noisy
estimate) makes the planner re-plan every sample with the same R and w (one to a few Ruckig
calls, tens of microseconds).

State save/restore: Ruckig objects cannot be pickled; ``__getstate__`` keeps only plain
floats (the plan's Ruckig inputs), ``__setstate__`` rebuilds the solver and recalculates the
trajectory from those inputs, so a restored copy continues bit-identically.

``RuckigReference`` (``create_reference``) is a comparison baseline: the same relative-frame
Ruckig plan with plain per-axis limits (w_i = 1, world axes: vector norms up to sqrt(n) over
the limits), shifted by the current master velocity only, made again every sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

from ruckig import ControlInterface, InputParameter, Ruckig, Trajectory

from ..limits import Limits
from .follow import rest_target_solver
from .values import attributes, mypyc_attr, python_class, restore
from .vec import Vec

#: rows (u1, u2, u3) of a rotation R (q = R e); None stands for the world axes
Basis = tuple[Vec, Vec, Vec]
#: velocity and acceleration weights per axis (w_v, w_a): tuples or lists (the search makes
#: lists), read by index only
Weights = tuple[Sequence[float], Sequence[float]]

#: lengths (mm or deg) -> Ruckig units (m or kdeg): Ruckig needs SI-like magnitudes
_S = 1e-3
_INV_S = 1e3
#: limits are used at (1 - _SAFETY) of their value, against rounding
_SAFETY = 1e-9
#: relative tolerance of the master-vs-prediction check (rounding only)
_RTOL = 1e-11
#: A master that deviates from the plan's prediction (an estimated, quantised encoder) makes
#: the planner re-plan every sample and chase the noise; it may never finish a plan.  After
#: such a re-plan the approach finishes at once (snap onto the master) when the plan would end
#: within SNAP_SAMPLES samples, or when the re-plans have stopped making progress (the planned
#: arrival time has slipped later for SNAP_STUCK samples in a row) and the relative state
#: after this sample is within SNAP_JERKS * (J*T^3, J*T^2, J*T) in position, velocity and
#: acceleration: a jump of the order of the estimate's own noise, which the setpoint copies
#: after the switch anyway.  An exactly predicted master never snaps (its plans run to their
#: end), nor does a smooth master with a jerk (its re-plans keep the arrival time).
SNAP_SAMPLES = 3
SNAP_STUCK = 3
SNAP_JERKS = 4.0
#: share of V, A and J a plan keeps in reserve for a master with a jerk (a conditioned
#: encoder) that deviates from the plan's constant-acceleration prediction; the plan is made
#: again when the deviation outgrows it (docs/spec/master-conditioning.md#6.3)
_RESERVE = 0.02
#: the master's jerk now, times this, is reserved too (its jerk changes during the plan)
_JERK_MARGIN = 1.5
#: smallest weight of an axis (an idle axis can still correct small errors)
_W_MIN = 1e-3
#: relative margin of the weight floors
_FLOOR_MARGIN = 1e-6
#: after a failed tracking plan, try again after this long [s] (fallback meanwhile)
_RETRY_S = 0.01
#: a plan whose box ends before the plan does is searched again this long before [s]
_HORIZON_MARGIN_S = 0.05
#: search again when an axis is done before this share of the plan's duration
_EARLY_AXIS = 0.9
#: and at these shares of every plan's duration (each adopted plan schedules its own)
_RESEARCH_SHARES = (0.25, 0.5)
#: a plan found by searching again replaces the current one if it ends this much sooner
_IMPROVE = 0.99
#: grid of the weight search: w_i = f_i + (1 - f_i)*u (f_i: the axis' floor)
_GRID = (0.005, 0.03, 0.1, 0.2, 0.35, 0.55, 0.78, 1.0)
#: refinement rounds of the weight search (each: one candidate and one probe evaluation)
_REFINE_ROUNDS = 6

_TRACK = 0  #: a tracking plan: every axis to e = 0
_FALLBACK = 1  #: world-frame velocity control towards the master's velocity


@python_class  # (its state: __getstate__/__setstate__ of its __dict__/__slots__)
class _Plan:
    """A stored plan: its Ruckig inputs (scaled, plain floats), basis and master model."""

    __slots__ = (
        "basis",
        "basis_mm",
        "duration",
        "reserve",
        "inputs",
        "k",
        "kind",
        "ma0",
        "mp0",
        "mv0",
        "replan_until",
        "research_at",
        "research_times",
        "valid_until",
    )

    def __init__(self, kind: int, inputs: tuple, basis, mp0: Vec, mv0: Vec, ma0: Vec,
                 duration: float) -> None:
        self.kind = kind
        #: (cur_p, cur_v, cur_a, vmin, vmax, amin, amax, jmax, target_v)
        self.inputs = inputs
        #: rows of R (q = R e) or None for the world axes; R * 1e3 (q in m -> e in mm)
        self.basis = basis
        self.basis_mm: tuple[Vec, ...] | None = None if basis is None else tuple(
            tuple([x * _INV_S for x in row]) for row in basis)
        self.mp0, self.mv0, self.ma0 = mp0, mv0, ma0  # master at the plan origin (mm units)
        self.duration = duration  # s
        self.k = 0  # samples of the plan already output
        #: re-plan every sample before this plan time [s] (a loosening velocity bound)
        self.replan_until = 0.0
        #: the box holds until this plan time [s] (inf: to the end); search again before
        self.valid_until = math.inf
        #: search again at this plan time [s] (an axis done early), inf: never
        self.research_at = math.inf
        self.research_times: tuple = ()
        #: (velocity, acceleration, jerk) the master may deviate from the prediction by
        #: (a plan made with the reserve), or None: the master must move as predicted
        self.reserve: tuple | None = None

    def __getstate__(self):
        return tuple(getattr(self, name) for name in self.__slots__)

    def __setstate__(self, s) -> None:
        for name, value in zip(self.__slots__, s):
            setattr(self, name, value)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class _Frame:
    """The relative problem in one basis: e0 (scaled lists; empty in the fallback's frame,
    which never plans from it), master v/a and robot v/a."""

    __slots__ = ("acc", "basis", "e0", "ma", "mv", "ra", "rv")

    def __init__(self, basis: Basis | None, e0: tuple, mv: Vec, ma: Vec, rv: Vec, ra: Vec,
                 acc: bool) -> None:
        self.basis, self.e0, self.mv, self.ma, self.rv, self.ra, self.acc = (
            basis, e0, mv, ma, rv, ra, acc)


def _rot(R, x: Vec) -> Vec:
    """R x (R given by its rows); x itself for the world axes (R None)."""
    if R is None:
        return tuple(x)
    return tuple([r[0] * x[0] + r[1] * x[1] + r[2] * x[2] for r in R])


def _unit(x: Vec) -> Vec | None:
    n = math.sqrt(sum(c * c for c in x))
    return tuple([c / n for c in x]) if n > 0.0 else None


def _master_basis(mv: Vec, ma: Vec, ep: Vec, ev: Vec):
    """Rows (u1, u2, u3): u1 along the master's velocity, u2 along the part of its
    acceleration (else the position error, else the velocity error) normal to u1."""
    u1 = _unit(mv)
    if u1 is None:
        return None
    u2 = None
    for x in (ma, ep, ev):
        d = sum(a * b for a, b in zip(x, u1))
        perp = tuple([a - d * b for a, b in zip(x, u1)])
        nx = math.sqrt(sum(c * c for c in x))
        if nx > 0.0 and math.sqrt(sum(c * c for c in perp)) > 1e-6 * nx:
            u2 = _unit(perp)
            break
    if u2 is None:  # any normal: cross u1 with the world axis least along it
        k = min(range(3), key=lambda i: abs(u1[i]))
        e = [0.0, 0.0, 0.0]
        e[k] = 1.0
        u2 = _unit((u1[1] * e[2] - u1[2] * e[1], u1[2] * e[0] - u1[0] * e[2],
                    u1[0] * e[1] - u1[1] * e[0]))
        assert u2 is not None  # u1 x e_k != 0: e_k is the world axis least along u1
    u3 = (u1[1] * u2[2] - u1[2] * u2[1], u1[2] * u2[0] - u1[0] * u2[2],
          u1[0] * u2[1] - u1[1] * u2[0])
    return (u1, u2, u3)


def _candidate_bases(mbv: Vec, ma: Vec, e0w: tuple) -> list:
    """The bases the search tries: the world axes, and the master's frame unless it is a
    signed permutation of the world axes (which gives the same plans)."""
    out = [None]
    R = _master_basis(mbv, ma, e0w[0], e0w[1])
    if R is not None and not all(max(abs(x) for x in r) > 1.0 - 1e-12 for r in R):
        out.append(R)
    return out


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class OptimalPlanner:
    """Time-optimal, vector-norm-safe approach of one channel (see the module docstring).

    ``limits``: the channel's sync limits (mm/s, mm/s^2, mm/s^3 or deg/...);
    ``sample_time_s``: T.  ``per_axis`` / ``replan_always`` / ``conservative`` select the
    baseline behaviour of :class:`RuckigReference` and are not meant for production.
    """

    name = "optimal"
    #: ``step`` returns tuples of Python floats (Ruckig's samples added to the master's
    #: vectors, or the master's own): the tracker makes its approach setpoints from them
    #: without converting them (``types.motion_state``)
    float_tuples: ClassVar[bool] = True

    #: the Ruckig solver, its input and its trajectory for n DOFs: made by _solver() at the
    #: first reset (None before, and in a pickle; ruckig has no type information)
    _rk: Ruckig
    _inp: InputParameter
    _traj: Trajectory

    def __init__(self, limits: Limits, sample_time_s: float, *, per_axis: bool = False,
                 replan_always: bool = False, conservative: bool = True) -> None:
        self.limits = limits
        self.T = float(sample_time_s)
        self.per_axis = per_axis
        self.replan_always = replan_always
        self.conservative = conservative
        k = 1.0 - _SAFETY
        self._V, self._A, self._J = limits.vel * k, limits.acc * k, limits.jerk * k
        self._retry_samples = max(1, round(_RETRY_S / self.T))
        #: start searching again this long [s] before a plan's box ends
        self._horizon_margin = max(5.0 * self.T, _HORIZON_MARGIN_S)
        self.n = 0
        self.p: Vec = ()
        self.v: Vec = ()
        self.a: Vec = ()
        self.basis: Basis | None = None
        self.w: Weights | None = None
        self.plan: _Plan | None = None
        self.done = False
        self._k = 0  # samples since reset
        self._retry_at = 0
        self._last_D = 0.0
        #: statistics: plans started, weight searches, fallback samples
        self.n_plans = 0
        self.n_searches = 0
        self.n_fallback = 0
        self._rk = self._inp = self._traj = None
        #: the reserve of plans made now (None: an ideal master, the whole limits)
        self._reserve: tuple | None = None
        self._jm = 0.0  # |master jerk| of this sample
        self._continuity()
        self._mprev: tuple | None = None  # the master of the last sample (mp, mv, ma)

    def _continuity(self) -> None:
        T = self.T
        J = self.limits.jerk * _RESERVE
        #: the continuity test of a master with a jerk (eq. 6.3): T, T^2/2, T^3/6 and the
        #: tolerances on position, velocity, acceleration (2 % of J over one sample)
        self._cont = (T, 0.5 * T * T, T * T * T / 6.0, J * T * T * T / 6.0, J * 0.5 * T * T,
                      J * T)

    # -- Ruckig objects (not picklable: rebuilt on restore) ---------------------------
    def _solver(self) -> None:
        self._rk, self._inp, self._traj = rest_target_solver(self.n)

    def __getstate__(self):
        d = attributes(self)
        d["_rk"] = d["_inp"] = d["_traj"] = None
        return d

    def __setstate__(self, d) -> None:
        restore(self, d)
        if "_cont" not in d:  # a state saved before the continuity test (eq. 6.3)
            self._continuity()
            self._mprev = None
        if self.n:
            self._solver()
            if self.plan is not None:
                self._calculate(self.plan.kind, self.plan.inputs)

    # -- the protocol ---------------------------------------------------------------
    def reset(self, p: Vec, v: Vec, a: Vec) -> None:
        """Start an approach from the robot setpoint (p, v, a) of the previous sample."""
        n = len(p)
        if n != self.n or self._rk is None:
            self.n = n
            self._solver()
        self.p, self.v, self.a = tuple(p), tuple(v), tuple(a)
        self.basis = None
        self.w = ((1.0,) * n, (1.0,) * n) if (n == 1 or self.per_axis) else None
        self.plan = None
        self.done = False
        self._k = 0
        self._retry_at = 0
        self._stuck = 0  # re-plans in a row whose arrival slipped later
        self._arrival = math.inf
        k = 1.0 - _SAFETY
        lim = self.limits
        self._V, self._A, self._J = lim.vel * k, lim.acc * k, lim.jerk * k
        self._reserve = None
        self._jm = 0.0
        self._mprev = None

    def step(self, mp: Vec, mv: Vec, ma: Vec,
             mj: Vec | None = None) -> tuple[Vec, Vec, Vec, bool]:
        """The setpoint of this sample from the master (mp, mv, ma) of this sample.

        ``mj``: the master's jerk when known (a conditioned master).  The robot's jerk is the
        master's plus the plan's, so plans made now get J - |mj| (at most half of J given
        away; docs/spec/master-conditioning.md#6.3).  An ideal master (mj zero or None)
        plans with the whole J, exactly as before."""
        self._k += 1
        if mj is None:
            jm = 0.0
        else:
            jm = 0.0
            for x in mj:
                jm += x * x
            jm = math.sqrt(jm)
        self._jm = jm
        prev = self._mprev
        self._mprev = (mp, mv, ma)
        plan = self.plan
        if plan is not None and not self.replan_always:
            j = plan.k + 1
            t = j * self.T
            tol = _RTOL
            if plan.reserve is not None:
                # the plan is sampled in the actual master's frame (master + e): it stays
                # within the limits while the master's velocity and acceleration stay within
                # the reserve of the plan's prediction and its jerk within the jerk reserve
                rv, ra, rj = plan.reserve
                ok = jm <= rj and self._in_tube(mp, mv, ma, mj, t, plan, prev, rv, ra)
            else:
                ok = True
                for x, y, z, p0, v0, a0 in zip(mp, mv, ma, plan.mp0, plan.mv0, plan.ma0):
                    # the master as the plan predicted it (to rounding)?
                    if abs(z - a0) > tol * (1.0 + abs(a0)):
                        ok = False
                        break
                    v = v0 + a0 * t
                    if abs(y - v) > tol * (1.0 + abs(v)):
                        ok = False
                        break
                    v = p0 + (v0 + 0.5 * a0 * t) * t
                    if abs(x - v) > tol * (1.0 + abs(v)):
                        ok = False
                        break
            if ok:
                if t >= plan.duration:
                    return self._finish(mp, mv, ma)
                if t >= plan.replan_until and t <= plan.valid_until:
                    if t >= plan.valid_until - self._horizon_margin:
                        # the box of this plan ends soon: search again (else continue it)
                        if self._k >= self._retry_at:
                            rest = plan.valid_until - (j - 1) * self.T
                            out = self._research(plan, mp, mv, ma, valid_over=rest + self.T)
                            if out is not None:
                                return out
                            self._retry_at = self._k + self._retry_samples
                    elif t >= plan.research_at:
                        # an axis is done well before the others (its weight is free now),
                        # or a share of the plan is over: search again from here
                        plan.research_at = min([x for x in plan.research_times if x > t],
                                               default=math.inf)
                        rest = plan.duration - (j - 1) * self.T
                        out = self._research(plan, mp, mv, ma, shorter_than=_IMPROVE * rest)
                        if out is not None:
                            return out
                    if self.plan is plan:
                        plan.k = j
                        return self._sample(t, mp, mv, ma)
        return self._replan(mp, mv, ma)

    def _in_tube(self, mp: Vec, mv: Vec, ma: Vec, mj: Vec | None, t: float, plan: _Plan,
                 prev: tuple | None, rv: float, ra: float) -> bool:
        """Eq. 6.3: the master within the reserve of the plan's prediction (velocity ``rv``,
        acceleration ``ra``), and moved on from the last sample (``prev``) with its jerk: a
        master that jumped (a conditioned one revised at a jerk step,
        master-conditioning.md#4.5) left the plan, which is made again from the last
        setpoint and so closes the jump within the limits.  Written out for 3 components
        (the loop's operations in its order); other lengths the loop."""
        T, h, h3, tp, tv, ta = self._cont
        if len(mv) == 3:
            v0, v1, v2 = plan.mv0
            a0, a1, a2 = plan.ma0
            y0, y1, y2 = mv
            z0, z1, z2 = ma
            x = (y0 - v0 - a0 * t) ** 2
            x += (y1 - v1 - a1 * t) ** 2
            x += (y2 - v2 - a2 * t) ** 2
            if not x <= rv * rv:
                return False
            x = (z0 - a0) ** 2
            x += (z1 - a1) ** 2
            x += (z2 - a2) ** 2
            if not x <= ra * ra:
                return False
            if prev is None or mj is None:
                return True
            (p0, p1, p2), (u0, u1, u2), (b0, b1, b2) = prev
            j0, j1, j2 = mj
            x0, x1, x2 = mp
            # (norms of the three gaps against tolerances per quantity: the components'
            # squares summed, one test each)
            a0 = z0 - b0 - j0 * T
            a1 = z1 - b1 - j1 * T
            a2 = z2 - b2 - j2 * T
            if a0 * a0 + a1 * a1 + a2 * a2 > ta * ta:
                return False
            a0 = y0 - u0 - (b0 + j0 * 0.5 * T) * T
            a1 = y1 - u1 - (b1 + j1 * 0.5 * T) * T
            a2 = y2 - u2 - (b2 + j2 * 0.5 * T) * T
            if a0 * a0 + a1 * a1 + a2 * a2 > tv * tv:
                return False
            a0 = x0 - p0 - u0 * T - b0 * h - j0 * h3
            a1 = x1 - p1 - u1 * T - b1 * h - j1 * h3
            a2 = x2 - p2 - u2 * T - b2 * h - j2 * h3
            return a0 * a0 + a1 * a1 + a2 * a2 <= tp * tp
        dv2 = da2 = 0.0
        for y, z, v0, a0 in zip(mv, ma, plan.mv0, plan.ma0):
            dv2 += (y - v0 - a0 * t) ** 2
            da2 += (z - a0) ** 2
        if not (dv2 <= rv * rv and da2 <= ra * ra):
            return False
        if prev is None or mj is None:
            return True
        for x, y, z, jx, p1, v1, a1 in zip(mp, mv, ma, mj, *prev):
            if (abs(x - p1 - v1 * T - a1 * h - jx * h3) > tp
                    or abs(y - v1 - a1 * T - jx * h) > tv or abs(z - a1 - jx * T) > ta):
                return False
        return True

    # -- output helpers ---------------------------------------------------------------
    def _finish(self, mp: Vec, mv: Vec, ma: Vec) -> tuple[Vec, Vec, Vec, bool]:
        self.p, self.v, self.a = tuple(mp), tuple(mv), tuple(ma)
        self.plan = None
        self.done = True
        return self.p, self.v, self.a, True

    def _sample(self, t: float, mp: Vec, mv: Vec, ma: Vec) -> tuple[Vec, Vec, Vec, bool]:
        """master + e(t) (plan time t), e = R^T q [mm], q from the Ruckig trajectory."""
        qp, qv, qa = self._traj.at_time(t)
        assert self.plan is not None  # a plan is being sampled
        R = self.plan.basis_mm
        if R is None:
            s = _INV_S
            self.p = p = tuple([m + e * s for m, e in zip(mp, qp)])
            self.v = v = tuple([m + e * s for m, e in zip(mv, qv)])
            self.a = a = tuple([m + e * s for m, e in zip(ma, qa)])
            return p, v, a, False
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R  # rows of R, times 1e3
        q0, q1, q2 = qp
        self.p = p = (mp[0] + r00 * q0 + r10 * q1 + r20 * q2,
                      mp[1] + r01 * q0 + r11 * q1 + r21 * q2,
                      mp[2] + r02 * q0 + r12 * q1 + r22 * q2)
        q0, q1, q2 = qv
        self.v = v = (mv[0] + r00 * q0 + r10 * q1 + r20 * q2,
                      mv[1] + r01 * q0 + r11 * q1 + r21 * q2,
                      mv[2] + r02 * q0 + r12 * q1 + r22 * q2)
        q0, q1, q2 = qa
        self.a = a = (ma[0] + r00 * q0 + r10 * q1 + r20 * q2,
                      ma[1] + r01 * q0 + r11 * q1 + r21 * q2,
                      ma[2] + r02 * q0 + r12 * q1 + r22 * q2)
        return p, v, a, False

    def _start(self, plan: _Plan, mp: Vec, mv: Vec, ma: Vec,
               snap: bool = False) -> tuple[Vec, Vec, Vec, bool]:
        """Make ``plan`` (starting at the last setpoint) current; its first sample.

        ``snap``: the plan replaces one the master did not follow; if it ends within
        ``SNAP_SAMPLES`` samples the approach finishes now.
        """
        self.plan = plan
        self.n_plans += 1
        plan.k = 1
        T = self.T
        if T >= plan.duration or (snap and plan.duration <= SNAP_SAMPLES * T):
            return self._finish(mp, mv, ma)
        out = self._sample(T, mp, mv, ma)
        if snap:
            arrival = self._k * T + plan.duration
            self._stuck = self._stuck + 1 if arrival > self._arrival + 0.5 * T else 0
            self._arrival = arrival
            J = self.limits.jerk * SNAP_JERKS
            p, v, a, _ = out
            if (self._stuck >= SNAP_STUCK and math.dist(p, mp) <= J * T * T * T
                    and math.dist(v, mv) <= J * T * T and math.dist(a, ma) <= J * T):
                return self._finish(mp, mv, ma)
        return out

    # -- planning ---------------------------------------------------------------------
    def _set_reserve(self) -> None:
        """Plans made now keep a reserve when the master has a jerk (eq. 6.3)."""
        jm = self._jm
        if jm > 0.0 and not self.replan_always:
            k = 1.0 - _SAFETY
            lim = self.limits
            self._V = lim.vel * k * (1.0 - _RESERVE)
            self._A = lim.acc * k * (1.0 - _RESERVE)
            J = lim.jerk * k
            self._J = J - min(jm * _JERK_MARGIN + _RESERVE * J, 0.5 * J)
            self._reserve = (_RESERVE * lim.vel * k, _RESERVE * lim.acc * k, J - self._J)

    def _plan_from(self, mp: Vec, mv: Vec, ma: Vec) -> _Plan | None:
        """A tracking plan from the last setpoint, the master given at this sample."""
        self._set_reserve()
        T = self.T
        rng = range(self.n)
        hT2 = 0.5 * T * T
        mbp = tuple([mp[i] - mv[i] * T + ma[i] * hT2 for i in rng])
        mbv = tuple([mv[i] - ma[i] * T for i in rng])
        plan = self._plan_track(mbp, mbv, tuple(ma))
        if plan is None and self._reserve is not None:
            # the robot's state is outside the reserved box (it was moving at a limit
            # before the master's jerk appeared): plan with the whole limits, re-made every
            # sample as for any master that leaves its prediction
            k = 1.0 - _SAFETY
            lim = self.limits
            self._V, self._A = lim.vel * k, lim.acc * k
            self._J = lim.jerk * k - min(self._jm, 0.5 * lim.jerk * k)
            self._reserve = None
            self.w = None
            plan = self._plan_track(mbp, mbv, tuple(ma))
            if plan is None and self._jm > 0.0:
                # not even that: the whole J too (the plan as for a master without jerk;
                # the master's own jerk then adds to the robot's until the next plan)
                self._J = lim.jerk * k
                self.w = None
                plan = self._plan_track(mbp, mbv, tuple(ma))
        return plan

    def _replan(self, mp: Vec, mv: Vec, ma: Vec) -> tuple[Vec, Vec, Vec, bool]:
        """Plan from the last setpoint (same R and w if feasible); else the fallback."""
        plan = None
        if self._k >= self._retry_at:
            plan = self._plan_from(mp, mv, ma)
            if plan is None or plan.valid_until < math.inf:
                self._retry_at = self._k + self._retry_samples
        if plan is not None:
            return self._start(plan, mp, mv, ma, snap=True)
        self.plan = None
        return self._fallback(mv, ma)

    def _research(self, plan: _Plan, mp: Vec, mv: Vec, ma: Vec, valid_over: float = 0.0,
                  shorter_than: float = math.inf) -> tuple[Vec, Vec, Vec, bool] | None:
        """Search R and w again from the last setpoint; start the new plan if its box holds
        longer than ``valid_over`` [s] and (given ``shorter_than``) it holds to its end and
        ends within ``shorter_than`` [s]; else keep ``plan`` (its trajectory calculated
        again) and return None."""
        w, basis = self.w, self.basis
        self.w = None
        new = self._plan_from(mp, mv, ma)
        if (new is not None and new.valid_until > valid_over
                and (shorter_than == math.inf
                     or (new.valid_until == math.inf and new.duration < shorter_than))):
            return self._start(new, mp, mv, ma)
        self.w, self.basis = w, basis
        if self._calculate(plan.kind, plan.inputs) is None:  # not seen: Ruckig repeats
            self.plan = None
            return self._replan(mp, mv, ma)
        return None

    def _calculate(self, kind: int, inputs: tuple) -> float | None:
        """Set the Ruckig inputs and calculate into ``_traj``; the duration or None."""
        inp = self._inp
        cp, cv, ca, vmin, vmax, amin, amax, jmax, tv = inputs
        inp.current_position = cp
        inp.current_velocity = cv
        inp.current_acceleration = ca
        inp.min_velocity = vmin
        inp.max_velocity = vmax
        inp.min_acceleration = amin
        inp.max_acceleration = amax
        inp.max_jerk = jmax
        if kind == _FALLBACK:
            inp.control_interface = ControlInterface.Velocity
            inp.per_dof_control_interface = None
            inp.target_velocity = tv
        else:
            inp.control_interface = ControlInterface.Position
            inp.per_dof_control_interface = None
            inp.target_velocity = [0.0] * self.n
        try:
            res = self._rk.calculate(inp, self._traj)
            if int(res) < 0:
                return None
        except Exception:  # noqa: BLE001 - the binding raises on unknown result codes
            return None
        return self._traj.duration

    def _frame(self, R, e0w: tuple, mbv: Vec, ma: Vec, acc: bool) -> _Frame:
        s = _S
        e0 = tuple([[x * s for x in _rot(R, e)] for e in e0w])
        return _Frame(R, e0, _rot(R, mbv), _rot(R, ma), _rot(R, self.v), _rot(R, self.a), acc)

    def _plan_track(self, mbp: Vec, mbv: Vec, ma: Vec) -> _Plan | None:
        """A tracking plan from the robot's last setpoint, or None if infeasible."""
        rng = range(self.n)
        p, v, a = self.p, self.v, self.a
        e0w = (tuple([p[i] - mbp[i] for i in rng]), tuple([v[i] - mbv[i] for i in rng]),
               tuple([a[i] - ma[i] for i in rng]))
        # a master acceleration below 1e-12 A changes its velocity by less than the limits'
        # rounding margin (1e-9 V) within the approach timeout: constant velocity then
        acc = self.conservative and any(abs(x) > 1e-12 * self._A for x in ma)
        res = None
        w = self.w
        if w is not None:
            fr = self._frame(self.basis, e0w, mbv, ma, acc)
            fv, fa = self._floors(fr, False)
            if self.per_axis or all(w[0][i] > fv[i] and w[1][i] > fa[i] for i in rng):
                r = self._checked(fr, w)
                if r is not None and r[2] > self._horizon_margin + self.T:
                    res = (r[0], r[1], w, r[2], fr)
        if res is None and not self.per_axis and self.n > 1:
            bases = _candidate_bases(mbv, ma, e0w) if self.n == 3 else [None]
            for R in bases:
                fr = self._frame(R, e0w, mbv, ma, acc)
                found = self._search(fr)
                if found is not None and (res is None or _better(found, res)):
                    res = found + (fr,)
            # the Ruckig trajectory must be the kept one
            if res is not None and self._calculate(_TRACK, res[0]) is None:
                res = None
        if res is None:
            return None
        inputs, D, w, valid, fr = res
        self.w = w
        self.basis = fr.basis
        plan = _Plan(_TRACK, inputs, fr.basis, mbp, mbv, ma, D)
        plan.reserve = self._reserve
        plan.valid_until = valid
        if acc and not self.per_axis:
            plan.replan_until = self._loosening_until(fr)
        if self.n > 1 and not self.per_axis:
            times = [d + self.T for d in self._traj.independent_min_durations
                     if 0.0 < d < _EARLY_AXIS * D]
            times += [f * D for f in _RESEARCH_SHARES]
            plan.research_times = tuple(sorted(times))
            if times:
                plan.research_at = plan.research_times[0]
        return plan

    def _loosening_until(self, fr: _Frame) -> float:
        """End time of the last cruise at a velocity bound that loosens with time (the
        master's component decelerating against the cruise direction), 0 if none."""
        until = 0.0
        try:
            profs = self._traj.profiles[0]
        except Exception:  # noqa: BLE001
            return 0.0
        for i in range(self.n):
            am = fr.ma[i]
            if am == 0.0:
                continue
            pr = profs[i]
            t = pr.t
            if t[3] > 0.0 and pr.v[3] * am < 0.0:
                until = max(until, pr.brake.duration + t[0] + t[1] + t[2] + t[3])
        return until

    # -- evaluation of one (basis, w) --------------------------------------------------
    def _inputs(self, fr: _Frame, w: Weights, vlo: list, vhi: list) -> tuple:
        """Ruckig inputs of the relative plan; vlo/vhi: master velocity range per axis."""
        s = _S
        V, A, J = self._V, self._A, self._J
        ma = fr.ma
        wv, wa = w
        rng = range(self.n)
        return (fr.e0[0], fr.e0[1], fr.e0[2],
                [(-V * wv[i] - vlo[i]) * s for i in rng],
                [(V * wv[i] - vhi[i]) * s for i in rng],
                [(-A * wa[i] - ma[i]) * s for i in rng],
                [(A * wa[i] - ma[i]) * s for i in rng],
                [J * wa[i] * s for i in rng],
                None)

    def _floors(self, fr: _Frame, robot: bool, H: float = 0.0) -> tuple[list, list]:
        """Smallest velocity and acceleration weights that hold the master's velocity over
        [0, H] and its acceleration, and (``robot``) the robot's current state: its
        acceleration, and its velocity including the overshoot a^2/(2 J wa) that a
        jerk-limited stop of the current acceleration adds."""
        V, A, J = self._V, self._A, self._J
        mv, ma = fr.mv, fr.ma
        fv = []
        fa = []
        for i in range(self.n):
            v = max(abs(mv[i]), abs(mv[i] + ma[i] * H))
            a = abs(ma[i])
            if robot:
                a = max(a, abs(fr.ra[i]))
            f_a = a / A * (1.0 + _FLOOR_MARGIN) + _W_MIN
            if robot:
                rv, ra = fr.rv[i], fr.ra[i]
                over = ra * ra / (2.0 * J * f_a)
                if rv * ra >= 0.0:
                    v = max(v, abs(rv) + over)
                else:
                    v = max(v, abs(rv), over - abs(rv))
            fv.append(v / V * (1.0 + _FLOOR_MARGIN) + _W_MIN)
            fa.append(f_a)
        return fv, fa

    def _checked(self, fr: _Frame, w: Weights) -> tuple[tuple, float, float] | None:
        """(Ruckig inputs, duration, valid_until) of the plan with w, calculated into
        ``_traj``; None if some axis is infeasible.  valid_until [s] is when the master's
        own velocity component leaves the box V*w_i on an axis that is already done (it
        then follows the master) -- inf if never before the plan ends."""
        r = self._evaluate(fr, w, exact=True)
        if r is None:
            return None
        dur, inputs = r
        D = max(dur)
        self._last_D = max([d for d in dur if d < math.inf], default=0.0)
        if D == math.inf:
            return None
        valid = math.inf
        if fr.acc and not self.per_axis:
            V = self._V
            for i in range(self.n):
                am = fr.ma[i]
                if am == 0.0:
                    continue
                lim = V * w[0][i]
                v0 = fr.mv[i]
                if abs(v0 + am * D) >= lim:
                    t_out = ((lim if am > 0.0 else -lim) - v0) / am
                    valid = min(valid, max(t_out, dur[i]))
        D = self._calculate(_TRACK, inputs)
        if D is None:
            return None
        return inputs, D, valid

    def _evaluate(self, fr: _Frame, w: Weights, exact: bool,
                  H0: list | None = None) -> tuple[list, tuple] | None:
        """Per-axis durations [s] with weights w (inf: infeasible axis) and the Ruckig
        inputs; None on a Ruckig error.  Constant master: exact bounds.  Accelerating
        master: ``exact`` -- tighten by the profile's velocity excess (module docstring);
        else the per-axis horizon (conservative, cheaper; for the search)."""
        mv = fr.mv
        vlo = list(mv)
        vhi = list(mv)
        if not fr.acc:
            inputs = self._inputs(fr, w, vlo, vhi)
            if self._calculate(_TRACK, inputs) is None:
                return None
            return list(self._traj.independent_min_durations), inputs
        if exact:
            return self._evaluate_exact(fr, w, vlo, vhi)
        return self._evaluate_horizon(fr, w, vlo, vhi, H0)

    def _evaluate_exact(self, fr: _Frame, w: Weights, vlo: list,
                        vhi: list) -> tuple[list, tuple] | None:
        n = self.n
        V = self._V
        mv = fr.mv
        dur = [math.inf] * n
        todo = list(range(n))
        prev: dict = {}  # (axis, side) -> (tightening, excess) of the last round
        for _ in range(10):
            inputs = self._inputs(fr, w, vlo, vhi)
            if self._calculate(_TRACK, inputs) is None:
                return None
            d = self._traj.independent_min_durations
            excess = self._velocity_excess(fr, w, todo)
            if excess is None:
                return [math.inf] * n, inputs
            rest = []
            for i in todo:
                hi_x, lo_x = excess[i]
                if hi_x <= 0.0 and lo_x <= 0.0:
                    dur[i] = d[i]
                    continue
                if hi_x > 0.0:
                    vhi[i] = mv[i] + _tighten(prev, (i, 1), vhi[i] - mv[i], hi_x, V)
                if lo_x > 0.0:
                    vlo[i] = mv[i] - _tighten(prev, (i, -1), mv[i] - vlo[i], lo_x, V)
                if V * w[0][i] <= vhi[i] or -V * w[0][i] >= vlo[i]:
                    vlo[i] = vhi[i] = mv[i]  # infeasible: keep valid Ruckig inputs
                else:
                    rest.append(i)
            todo = rest
            if not todo:
                break
        if todo:
            inputs = self._inputs(fr, w, vlo, vhi)
        return dur, inputs

    def _evaluate_horizon(self, fr: _Frame, w: Weights, vlo: list, vhi: list,
                          H0: list | None) -> tuple[list, tuple] | None:
        n = self.n
        V = self._V
        mv, ma = fr.mv, fr.ma
        # warm start: the horizons of a plan with looser bounds (shorter) are a lower bound
        H = [0.0] * n if H0 is None else [h if h < math.inf else 0.0 for h in H0]
        dur = [math.inf] * n
        todo = list(range(n))
        for _ in range(8):
            out = set()
            for i in todo:
                v0 = mv[i]
                v1 = v0 + ma[i] * H[i]
                vlo[i], vhi[i] = (v1, v0) if v1 < v0 else (v0, v1)
                if V * w[0][i] <= vhi[i] or -V * w[0][i] >= vlo[i]:
                    vlo[i] = vhi[i] = v0  # infeasible: keep valid Ruckig inputs
                    out.add(i)
            inputs = self._inputs(fr, w, vlo, vhi)
            if self._calculate(_TRACK, inputs) is None:
                return None
            d = self._traj.independent_min_durations
            rest = []
            for i in todo:
                if i in out:
                    continue  # infeasible
                if ma[i] == 0.0 or d[i] <= H[i]:
                    dur[i] = d[i]
                else:
                    H[i] = d[i] * 1.05 + 1e-3
                    rest.append(i)
            todo = rest
            if not todo:
                break
        return dur, inputs

    def _velocity_excess(self, fr: _Frame, w: Weights, axes: list) -> dict | None:
        """Per axis in ``axes`` (over, under) [mm/s] by which the robot's velocity
        (R v_m(t))_i + q_v,i(t) leaves [-V*w_i, V*w_i] during the calculated plan.
        Excursions that only continue an initial velocity already outside the box are not
        counted.  None if the profile is not understood."""
        s = _S
        V = self._V
        out = {}
        try:
            profs = self._traj.profiles[0]
        except Exception:  # noqa: BLE001
            return None
        ev0 = fr.e0[1]
        for i in axes:
            pr = profs[i]
            if pr.accel.duration > 0.0:
                return None
            vm0 = fr.mv[i] * s
            am = fr.ma[i] * s
            lim = V * w[0][i] * s
            u0 = vm0 + ev0[i]
            top = max(lim, u0)
            bot = min(-lim, u0)
            umax = -math.inf
            umin = math.inf
            t0 = 0.0
            br = pr.brake
            if br.duration > 0.0:
                segs = list(zip(br.t, br.j, br.a, br.v)) + list(zip(pr.t, pr.j, pr.a, pr.v))
            else:
                segs = list(zip(pr.t, pr.j, pr.a, pr.v))
            for dt, j, a0, v0 in segs:
                if dt <= 0.0:
                    continue
                # u(tau) = v0 + vm0 + am*(t0 + tau) + a0*tau + j*tau^2/2
                c0 = v0 + vm0 + am * t0
                c1 = a0 + am
                ue = c0 + (c1 + 0.5 * j * dt) * dt
                umax = max(umax, c0)
                umax = max(umax, ue)
                umin = min(umin, c0)
                umin = min(umin, ue)
                if j != 0.0:
                    tau = -c1 / j
                    if 0.0 < tau < dt:
                        uc = c0 + 0.5 * c1 * tau
                        umax = max(umax, uc)
                        umin = min(umin, uc)
                t0 += dt
            tol = 1e-12 * lim
            hi_x = umax - top if umax > top + tol else 0.0
            lo_x = bot - umin if umin < bot - tol else 0.0
            out[i] = (hi_x * _INV_S, lo_x * _INV_S)
        return out

    # -- the weight search ------------------------------------------------------------
    def _search(self, fr: _Frame) -> tuple[tuple, float, tuple, float] | None:
        """(inputs, duration, w, valid_until) of the best plan in this basis, or None.

        A plan whose box holds to its end is preferred (the floors are widened over the
        plan's horizon up to twice); else the first plan found, whose box ends before the
        plan does (receding horizon: the planner searches again before then)."""
        H = 0.0
        partial = None
        for _ in range(3):
            w = self._choose_w(fr, H)
            if w is None:
                break
            res = self._checked(fr, w)
            if res is not None:
                if res[2] == math.inf:
                    return res[0], res[1], w, res[2]
                if partial is None and res[2] > self._horizon_margin + self.T:
                    partial = (res[0], res[1], w, res[2])
            if not fr.acc:
                break
            # a master velocity component outgrows V*w_i before the plan ends: choose
            # again with the floors over a longer horizon
            H = max(2.0 * H, 1.2 * self._last_D + self.T)
        return partial

    def _choose_w(self, fr: _Frame, H: float) -> tuple | None:
        """The weights of the family that equalise the per-axis durations (module
        docstring) as (wv, wa) (velocity; acceleration and jerk); the floors hold the
        master's velocity over [0, H].  None if none is feasible.  Axis i is searched
        along w_i = f_i + (1 - f_i) u_i, u_i in [0, 1], f_i = max(fv_i, fa_i): one weight
        per axis for v, a and j (separate v and a weights gained ~1 % in trials)."""
        n = self.n
        rng = range(n)
        self.n_searches += 1
        fv, fa = self._floors(fr, True, H)
        if sum(x * x for x in fv) >= 1.0 or sum(x * x for x in fa) >= 1.0:
            if self.plan is not None:
                return None  # mid-plan: the robot's state must stay inside the box
            fv, fa = self._floors(fr, False, H)
            if sum(x * x for x in fv) >= 1.0 or sum(x * x for x in fa) >= 1.0:
                return None
        fv = fa = [max(x, y) for x, y in zip(fv, fa)]
        if sum(x * x for x in fv) >= 1.0:
            return None
        inf = math.inf

        def weights(u):
            return ([fv[i] + (1.0 - fv[i]) * u[i] for i in rng],
                    [fa[i] + (1.0 - fa[i]) * u[i] for i in rng])

        def size(u):
            wv, wa = weights(u)
            return max(sum(x * x for x in wv), sum(x * x for x in wa))

        def ev(u):
            return self._evaluate(fr, weights(u), exact=False)

        # per-axis tables (u ascending, t non-increasing) on a grid
        tabs: list[list] = [[] for _ in rng]
        best = None  # (D, (wv, wa))
        H0 = None
        for g in reversed(_GRID):  # loose to tight: each warm-starts the next horizon
            r = self._evaluate(fr, weights([g] * n), False, H0)
            if r is None:
                continue
            H0 = r[0]
            for i in rng:
                tabs[i].append((g, r[0][i]))
        uu = min(_common_u(fv), _common_u(fa))  # the largest common u that fits
        r = ev([uu] * n)
        if r is not None:
            for i in rng:
                tabs[i].append((uu, r[0][i]))
            D = max(r[0])
            if D < inf:
                best = (D, _normalised(weights([uu] * n)))
        for tab in tabs:
            _monotone(tab)
        if any(not tab or tab[-1][1] == inf for tab in tabs):
            return best[1] if best else None
        for _refine in range(_REFINE_ROUNDS):
            tau = _solve_tau(tabs, size)
            uq = [_w_of(tab, tau) for tab in tabs]
            if not all(x < inf for x in uq):
                break
            wq = _normalised(weights(uq))
            r = self._evaluate(fr, wq, exact=False)
            if r is None:
                break
            D = max(r[0])
            if best is None or D < best[0]:
                best = (D, wq)
            if D <= tau * 1.003 and not any(_at_cliff(tab, tau) for tab in tabs):
                break
            # probe every axis inside its bracket at tau (bisection at a feasibility cliff)
            probe = [_probe(tab, tau) for tab in tabs]
            r = ev(probe)
            if r is None:
                break
            for i in rng:
                tabs[i].append((probe[i], r[0][i]))
                _monotone(tabs[i])
        return best[1] if best else None

    # -- fallbacks --------------------------------------------------------------------
    def _fallback(self, mv: Vec, ma: Vec) -> tuple[Vec, Vec, Vec, bool]:
        """No tracking plan: velocity control (world frame) towards the master's velocity,
        scaled down (factor s <= 1) so that a box w holds both the robot's state (its
        velocity with the overshoot of stopping its acceleration, its acceleration) and
        the target: every component then moves between its start and its target, and the
        vector norms stay within the limits.  One sample of it; never synced."""
        n = self.n
        rng = range(n)
        V, A, J = self._V, self._A, self._J
        self.n_fallback += 1
        mbv = [mv[i] - ma[i] * self.T for i in rng]
        fr = _Frame(None, (), (0.0,) * n, (0.0,) * n, self.v, self.a, False)
        fv, fa = self._floors(fr, True)

        def fit(s):
            return [max(fv[i], abs(s * mbv[i]) / V * (1.0 + _FLOOR_MARGIN) + _W_MIN, fa[i])
                    for i in rng]

        s = 1.0
        if sum(x * x for x in fit(1.0)) > 1.0:
            lo, hi = 0.0, 1.0
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                if sum(x * x for x in fit(mid)) <= 1.0:
                    lo = mid
                else:
                    hi = mid
            s = lo
        f = fit(s)
        nf = math.sqrt(sum(x * x for x in f))
        w = [x / nf for x in f]
        sc = _S
        inputs = ([0.0] * n, [x * sc for x in self.v], [x * sc for x in self.a],
                  [-V * w[i] * sc for i in rng], [V * w[i] * sc for i in rng],
                  [-A * w[i] * sc for i in rng], [A * w[i] * sc for i in rng],
                  [J * w[i] * sc for i in rng], [s * mbv[i] * sc for i in rng])
        if self._calculate(_FALLBACK, inputs) is None:
            return self._emergency()
        ep, ev, ea = self._traj.at_time(self.T)
        si = _INV_S
        rp = self.p
        self.p = tuple([rp[i] + ep[i] * si for i in rng])
        self.v = tuple([ev[i] * si for i in rng])
        self.a = tuple([ea[i] * si for i in rng])
        return self.p, self.v, self.a, False

    def _emergency(self) -> tuple[Vec, Vec, Vec, bool]:
        """Last resort: keep the velocity, ramp the acceleration towards 0 at jerk J."""
        T = self.T
        rng = range(self.n)
        a = self.a
        an = math.sqrt(sum(x * x for x in a))
        k = 0.0 if an <= self._J * T else 1.0 - self._J * T / an
        jerk = [(a[i] * k - a[i]) / T for i in rng]
        p, v = self.p, self.v
        self.p = tuple([p[i] + v[i] * T + 0.5 * a[i] * T * T + jerk[i] * T ** 3 / 6.0
                        for i in rng])
        self.v = tuple([v[i] + a[i] * T + 0.5 * jerk[i] * T * T for i in rng])
        self.a = tuple([a[i] * k for i in rng])
        return self.p, self.v, self.a, False


def _better(a: tuple, b: tuple) -> bool:
    """Is search result a (inputs, D, w, valid_until, ...) better than b?  A plan whose box
    holds to its end beats one that does not; then the shorter one."""
    ca, cb = a[3] == math.inf, b[3] == math.inf
    if ca != cb:
        return ca
    return a[1] < b[1]


def _tighten(prev: dict, key: tuple, delta: float, excess: float, V: float) -> float:
    """Next tightening of one velocity bound [mm/s] given the excess it left.

    The excess x(delta) decreases with slope -(1 - k), 0 <= k < 1 (a tighter bound makes
    the cruise longer, so part of the tightening comes back): secant step on the last two
    rounds, over-stepped by 5 % so that the iteration ends on the safe side.
    """
    last = prev.get(key)
    step = 1.3 * excess
    if last is not None:
        d0, x0 = last
        if delta > d0 and x0 > excess:
            slope = (x0 - excess) / (delta - d0)  # 1 - k
            if slope > 0.05:
                step = min(1.05 * excess / slope, 20.0 * excess)
    prev[key] = (delta, excess)
    return delta + step + 1e-9 * V


def _monotone(tab: list) -> None:
    """Sort (w, t) samples by w and make t non-increasing (t(w) is, up to Ruckig noise)."""
    tab.sort()
    m = math.inf
    for k, (w, t) in enumerate(tab):
        if t > m:
            tab[k] = (w, m)
        else:
            m = t


def _w_of(tab: list, tau: float) -> float:
    """Smallest w of the table's log-linear interpolation with t(w) <= tau (inf if none)."""
    prev = None
    for w, t in tab:
        if t <= tau:
            if prev is None or prev[1] == math.inf or t <= 0.0:
                return w
            wp, tp = prev
            x = math.log(tp / tau) / math.log(tp / t) if tp > t else 1.0
            return wp + (w - wp) * x
        prev = (w, t)
    return math.inf


def _solve_tau(tabs: list, size) -> float:
    """Smallest tau with size(u(tau)) <= 1 on the tables' interpolants (1e-4 relative)."""
    lo = max(tab[-1][1] for tab in tabs)  # every axis at its largest sample

    def fits(tau):
        u = [_w_of(tab, tau) for tab in tabs]
        return all(x < math.inf for x in u) and size(u) <= 1.0

    if fits(lo):
        return lo
    hi = lo * 2.0
    for _ in range(60):
        if fits(hi):
            break
        hi *= 2.0
    while hi > lo * 1.0001:
        mid = math.sqrt(lo * hi)
        if fits(mid):
            hi = mid
        else:
            lo = mid
    return hi


def _common_u(f: list) -> float:
    """The u with sum_i (f_i + (1 - f_i) u)^2 = 1 (sum f_i^2 < 1), in [0, 1]."""
    a = sum((1.0 - x) ** 2 for x in f)
    b = 2.0 * sum(x * (1.0 - x) for x in f)
    c = sum(x * x for x in f) - 1.0
    if a <= 0.0:
        return 1.0
    return min(1.0, max(0.0, (-b + math.sqrt(max(0.0, b * b - 4.0 * a * c))) / (2.0 * a)))


def _normalised(w: tuple) -> tuple:
    """Each weight vector scaled to unit norm (only loosens the bounds)."""
    out = []
    for x in w:
        nx = math.sqrt(sum(y * y for y in x))
        out.append(tuple([y / nx for y in x]))
    return tuple(out)


def _at_cliff(tab: list, tau: float) -> bool:
    """True if w(tau) sits next to an infeasible sample more than 1 % below it."""
    prev = None
    for w, t in tab:
        if t <= tau:
            return prev is not None and prev[1] == math.inf and w > prev[0] * 1.01
        prev = (w, t)
    return False


def _probe(tab: list, tau: float) -> float:
    """A w inside the table's bracket around tau: the interpolated one kept 15 % away from
    the ends, or the geometric mean next to an infeasible sample; the bracket's feasible
    end once it is narrower than 1e-3."""
    prev = None
    for w, t in tab:
        if t <= tau:
            if prev is None or w <= prev[0] * 1.001:
                return w
            wp, tp = prev
            if tp == math.inf or t <= 0.0:
                return math.sqrt(wp * w)
            x = math.log(tp / tau) / math.log(tp / t) if tp > t else 1.0
            x = min(max(x, 0.15), 0.85)
            return wp + (w - wp) * x
        prev = (w, t)
    return tab[-1][0]


class RuckigReference(OptimalPlanner):
    """Baseline: per-axis limits (w_i = 1), current master velocity, re-planned every sample.

    Not vector-norm-safe (up to sqrt(n) over the limits); for benchmarks only.
    """

    name = "ruckig-reference"

    def __init__(self, limits: Limits, sample_time_s: float) -> None:
        super().__init__(limits, sample_time_s, per_axis=True, replan_always=True,
                         conservative=False)


def create(limits: Limits, params) -> OptimalPlanner:
    """Planner-registry factory: the ``optimal`` channel planner for ``limits``."""
    return OptimalPlanner(limits, params.sample_time_s)


def create_reference(limits: Limits, params) -> RuckigReference:
    """Factory of the per-cycle per-axis Ruckig baseline (benchmarks)."""
    return RuckigReference(limits, params.sample_time_s)
