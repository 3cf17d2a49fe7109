"""Time-optimal REFERENCE approach planner for the tracking benchmark (Ruckig, per-axis limits).

Not a controller planner: it keeps *per-axis* limits, so in 3-D the vector norm of the
velocity/acceleration/jerk can reach sqrt(3) times the limit.  It is the measuring stick of
``benchmarks/tracking.py``: every planner's time to sync is divided by this one's.

Spec: docs/spec/tracking.md#3.10 (the time-optimal reference of the readings' measurements:
Ruckig planned in the master's frame -- relative coordinates, target 0, limits shifted by
the master's velocity/acceleration) and #6.2 (Ruckig needs SI-like magnitudes; with
``Synchronization.TimeIfNecessary`` it did not fail in 600 runs).

One channel (n = 3 translation in mm, or n = 1 rotation in deg), per sample (period T):

1. The planner holds the setpoint (p, v, a) of sample k-1 and gets the master (pm, vm, am) of
   sample k (the time axis of ``controller/tracking/softmc.py``).  The master at k-1 is the
   master at k moved back by T at constant acceleration (the same constant-acceleration
   master model the plan itself uses; exact for the benchmark's masters).
2. Relative coordinates e = robot - master at k-1: e, de/dt, d2e/dt2.  Target e = 0 with
   zero relative velocity and acceleration.
3. Per-axis limits shifted by the master's state at sample k, so that the robot's own
   per-axis velocity/acceleration stay within +-V / +-A at the sample being computed:
   v_e,i in [-V - vm_i, V - vm_i], a_e,i in [-A - am_i, A - am_i], jerk +-J.
4. Ruckig (PyPI ``ruckig``) plans the time-optimal jerk-limited trajectory from e to 0,
   re-planned every cycle; all values are scaled by 1e-3 inside (mm -> m, and deg the same
   way), because Ruckig in mm fails on valid inputs (notes).
5. The plan is sampled at T: setpoint(k) = master(k) + e(T) (and the same for the
   derivatives).  Once the plan's remaining duration is <= T, e has reached 0 within this
   sample: the step returns the master's state exactly and reports "synchronised"; from then
   on the tracker copies the master.

If Ruckig reports an error (not seen in practice) the planner retries without time
synchronisation and then falls back to continuing its own state at constant acceleration for
one sample; ``failures`` counts those samples so the benchmark can report them.
"""

from __future__ import annotations

from ruckig import InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

Vec = tuple[float, ...]

#: mm (or deg) -> the unit Ruckig computes in
SCALE = 1e-3
_OK = (Result.Working, Result.Finished)


class RuckigReference:
    """Per-axis time-optimal approach in the master's frame (a ChannelPlanner)."""

    name = "reference"

    def __init__(self, limits, sample_time_s: float, *,
                 synchronization: Synchronization = Synchronization.TimeIfNecessary) -> None:
        self.limits = limits
        self.T = float(sample_time_s)
        self.synchronization = synchronization
        self.p: Vec = ()
        self.v: Vec = ()
        self.a: Vec = ()
        #: samples on which Ruckig failed with TimeIfNecessary (retried without sync)
        self.retries = 0
        #: samples on which Ruckig failed altogether (constant-acceleration fallback)
        self.failures = 0
        #: remaining duration of the last plan [s] (from sample k-1)
        self.duration_s = 0.0
        self._n = 0
        self._otg = self._inp = self._traj = None

    def __deepcopy__(self, memo):
        # Ruckig objects are re-created on the next reset/step; the plan is stateless between
        # samples (re-planned every cycle from the held setpoint).
        new = RuckigReference(self.limits, self.T, synchronization=self.synchronization)
        new.p, new.v, new.a = self.p, self.v, self.a
        new.retries, new.failures, new.duration_s = self.retries, self.failures, self.duration_s
        memo[id(self)] = new
        return new

    def _setup(self, n: int) -> None:
        if self._n == n and self._otg is not None:
            return
        self._n = n
        self._otg = Ruckig(n, self.T)
        inp = self._inp = InputParameter(n)
        s = SCALE
        inp.max_jerk = [self.limits.jerk * s] * n
        inp.target_position = [0.0] * n
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        inp.synchronization = self.synchronization
        self._traj = Trajectory(n)

    def reset(self, p: Vec, v: Vec, a: Vec) -> None:
        """Start an approach from the robot setpoint (p, v, a) of the previous sample."""
        self.p, self.v, self.a = tuple(p), tuple(v), tuple(a)
        self.duration_s = 0.0
        self._setup(len(self.p))

    def step(self, mp: Vec, mv: Vec, ma: Vec,
             mj: Vec | None = None) -> tuple[Vec, Vec, Vec, bool]:
        """One sample towards the master state (mp, mv, ma) of this sample."""
        T = self.T
        s = SCALE
        n = len(self.p)
        self._setup(n)
        p, v, a = self.p, self.v, self.a
        h = 0.5 * T * T
        # relative state at k-1 (master moved back by T at constant acceleration)
        e = [(p[i] - (mp[i] - mv[i] * T + ma[i] * h)) * s for i in range(n)]
        de = [(v[i] - (mv[i] - ma[i] * T)) * s for i in range(n)]
        dde = [(a[i] - ma[i]) * s for i in range(n)]
        if not any(e) and not any(de) and not any(dde):
            return self._synced(mp, mv, ma)
        V, A = self.limits.vel, self.limits.acc
        inp = self._inp
        inp.current_position = e
        inp.current_velocity = de
        inp.current_acceleration = dde
        inp.max_velocity = [max(0.0, (V - mv[i]) * s) for i in range(n)]
        inp.min_velocity = [min(0.0, (-V - mv[i]) * s) for i in range(n)]
        inp.max_acceleration = [max(0.0, (A - ma[i]) * s) for i in range(n)]
        inp.min_acceleration = [min(0.0, (-A - ma[i]) * s) for i in range(n)]
        traj = self._traj
        if not self._plan(inp, traj):
            self.retries += 1
            inp.synchronization = Synchronization.No
            ok = self._plan(inp, traj)
            inp.synchronization = self.synchronization
            if not ok:
                self.failures += 1
                new_p = tuple([p[i] + v[i] * T + a[i] * h for i in range(n)])
                new_v = tuple([v[i] + a[i] * T for i in range(n)])
                self.p, self.v = new_p, new_v
                return new_p, new_v, a, False
        self.duration_s = traj.duration
        if traj.duration <= T * (1.0 + 1e-9):
            return self._synced(mp, mv, ma)
        ep, ev, ea = traj.at_time(T)[:3]
        inv = 1.0 / s
        new_p = tuple([mp[i] + ep[i] * inv for i in range(n)])
        new_v = tuple([mv[i] + ev[i] * inv for i in range(n)])
        new_a = tuple([ma[i] + ea[i] * inv for i in range(n)])
        self.p, self.v, self.a = new_p, new_v, new_a
        return new_p, new_v, new_a, False

    def _plan(self, inp: InputParameter, traj: Trajectory) -> bool:
        try:
            return self._otg.calculate(inp, traj) in _OK
        except RuckigError:
            return False

    def _synced(self, mp: Vec, mv: Vec, ma: Vec) -> tuple[Vec, Vec, Vec, bool]:
        self.p, self.v, self.a = tuple(mp), tuple(mv), tuple(ma)
        self.duration_s = 0.0
        return self.p, self.v, self.a, True


def create(limits, params) -> RuckigReference:
    """Planner-registry factory (``PLANNERS["reference"] = "benchmarks.reference:create"``)."""
    return RuckigReference(limits, params.sample_time_s)


def plan_duration_s(limits, p: Vec, v: Vec, a: Vec, mv: Vec, ma: Vec) -> float:
    """Duration [s] of the per-axis time-optimal plan from the robot state (p, v, a) onto a
    master at the origin moving with (mv, ma) (limits shifted as in ``step``); inf if Ruckig
    fails.  The benchmark uses it to keep only cases that are feasible within the sync time.
    """
    n = len(p)
    s = SCALE
    otg = Ruckig(n)
    inp = InputParameter(n)
    inp.current_position = [x * s for x in p]
    inp.current_velocity = [(v[i] - mv[i]) * s for i in range(n)]
    inp.current_acceleration = [(a[i] - ma[i]) * s for i in range(n)]
    inp.target_position = inp.target_velocity = inp.target_acceleration = [0.0] * n
    V, A, J = limits.vel, limits.acc, limits.jerk
    inp.max_velocity = [max(0.0, (V - mv[i]) * s) for i in range(n)]
    inp.min_velocity = [min(0.0, (-V - mv[i]) * s) for i in range(n)]
    inp.max_acceleration = [max(0.0, (A - ma[i]) * s) for i in range(n)]
    inp.min_acceleration = [min(0.0, (-A - ma[i]) * s) for i in range(n)]
    inp.max_jerk = [J * s] * n
    inp.synchronization = Synchronization.TimeIfNecessary
    traj = Trajectory(n)
    try:
        ok = otg.calculate(inp, traj) in _OK
    except RuckigError:
        ok = False
    return traj.duration if ok else float("inf")
