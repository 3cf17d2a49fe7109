"""The softMC multi-dimensional tracking algorithm (approach phase), one channel.

Spec: docs/spec/tracking.md#3 (the approach, section by section; the readings chosen where
the published algorithm is wrong are named switches of ``SoftMcOptions``, table #3.10).
The same code runs the 3-D translation channel (mm) and the 1-D rotation channel (deg).

Per sample (period T) the planner gets the master's state at this sample (pm, vm, am) and
holds the robot setpoint of the previous sample (p, v, a).  It computes:

1. Time to reach (docs/spec/tracking.md#3.2):  D = sqrt(K*|vm - v| / J) + sqrt(4*|pm - p| / A),
   published: K = 4 if |vm| > |v| else 2.  Our reading (option ``time_to_reach_k``, default
   (16, 16)): the published comment says the time doubles because the robot must pass the
   master's speed and come back; a jerk-limited speed change takes sqrt(4*|dv|/J), twice that
   is sqrt(16*|dv|/J).  With the published K the fixed algorithm limit-cycles whenever the
   velocity error dominates (relative mode, robot already at the master);
   D *= DampingFactor;  D = T*int(D/T + 1)  (floor + 1: always >= T).
2. Rendezvous prediction (docs/spec/tracking.md#3.3) with t = D - T: the quintic starts at
   the previous sample (k-1)T and ends at (k-1)T + D = kT + t, so the master is predicted t
   ahead of its sample (this "- T" is a time-origin shift, not a typo: #2.2).
   pred_pos = pm + t*vm + t^2*am/2,  pred_vel = vm + t*am,
   pred_acc = am  (the published "pred_acc = 0" is option ``pred_acc_from_master=False``).
3. Quintic coefficients a3, a4, a5 in the published nested form (they are the standard
   quintic, docs/spec/tracking.md#3.4) and the increment
   dp = a5*T^5 + a4*T^4 + a3*T^3 + a*T^2/2 + v*T  (#3.5).
4. Filter (docs/spec/tracking.md#3.6): |dp| <= V*T, |ddp| = |dp - dp0| <= A*T^2,
   |dddp| = |ddp - ddp0| <= J*T^3, each clamp along the vector's own direction, later clamps
   re-deriving dp.  Option ``braking_distance_velocity`` lowers the velocity cap to
   V - a_t^2/(2J), a_t the acceleration along the motion, so that the jerk clamp cannot carry
   the velocity over V.
5. New state (docs/spec/tracking.md#3.7): p += dp; if a clamp acted, v and a come from the
   increments.  The published algorithm feeds back dp/T and ddp/T^2 (mid-sample averages, the
   key defect that makes the jerk clamp flip every cycle).  We use the end-of-sample values
   of the constant-jerk sample, v = (dp + ddp/2 + dddp/3)/T, a = (ddp + dddp)/T^2 (option
   ``end_of_sample_feedback``).  Without a clamp, v and a are the quintic's derivatives at T.
6. Synchronised (docs/spec/tracking.md#3.8) when |vm - v| <= g*A*T and |pm - p| <= g*A*T^2
   (g = FilterFactor).  Then "take the middle": p = (p + pm)/2, v = (v + vm)/2, and from the
   next sample on the tracker copies the master.  The middle step makes the jerk spike of
   about g*A/T that softMC's algorithm always has (7-37 x J); it is kept (option
   ``take_the_middle``) because it is part of the algorithm being reproduced.
Initial increments (docs/spec/tracking.md#3.9): dp0 = v0*T, ddp0 = a0*T^2 (literal: 0).
"""

from __future__ import annotations

import math

from ..limits import Limits
from .types import SoftMcOptions
from .values import mypyc_attr
from .vec import Vec


def time_to_reach(pos_diff: float, vel_diff: float, master_speed: float, robot_speed: float,
                  acc: float, jerk: float, sample_time_s: float,
                  damping_factor: float = 1.0, k_faster: float = 4.0,
                  k_slower: float = 2.0) -> float:
    """Time-to-reach estimate D [s] (docs/spec/tracking.md#3.2), rounded up to whole samples.

    D = sqrt(K*|dv|/J) + sqrt(4*|dp|/A), K = k_faster if |vm| > |v| else k_slower (published:
    4 and 2, the defaults here; the planner passes SoftMcOptions.time_to_reach_k); D *= DampingFactor;
    D = T*int(D/T + 1).  ``pos_diff`` [mm], ``vel_diff`` [mm/s] are norms; speeds [mm/s].
    """
    K = k_faster if master_speed > robot_speed else k_slower
    D = math.sqrt(K * vel_diff / jerk) + math.sqrt(4.0 * pos_diff / acc)
    D *= damping_factor
    return sample_time_s * int(D / sample_time_s + 1.0)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class SoftMcPlanner:
    """One channel of the softMC approach.  ``reset()`` at engage, ``step()`` every sample."""

    name = "softmc"

    def __init__(self, limits: Limits, sample_time_s: float, *, filter_factor: float = 1.0,
                 damping_factor: float = 1.0, options: SoftMcOptions | None = None) -> None:
        self.limits = limits
        self.T = float(sample_time_s)
        self.filter_factor = float(filter_factor)
        self.damping_factor = float(damping_factor)
        self.options = options if options is not None else SoftMcOptions()
        self.p: Vec = ()
        self.v: Vec = ()
        self.a: Vec = ()
        self.dp0: Vec = ()
        self.ddp0: Vec = ()
        #: which clamps acted in the last step (softMC's sat* flags, never set there)
        self.sat_vel = self.sat_acc = self.sat_jerk = False

    # -- thresholds -----------------------------------------------------------------
    @property
    def sync_vel_threshold(self) -> float:
        """|dv| threshold g*A*T [mm/s or deg/s]."""
        return self.filter_factor * self.limits.acc * self.T

    @property
    def sync_pos_threshold(self) -> float:
        """|dp| threshold g*A*T^2 (or softMC's overview's A*T^2/2) [mm or deg]; #3.8."""
        if self.options.unit_consistent_thresholds:
            return self.filter_factor * self.limits.acc * self.T * self.T
        return 0.5 * self.limits.acc * self.T * self.T

    def reset(self, p: Vec, v: Vec, a: Vec) -> None:
        """Start an approach from the robot setpoint (p, v, a) of the previous sample."""
        T = self.T
        self.p, self.v, self.a = tuple(p), tuple(v), tuple(a)
        if self.options.init_increments_from_state:
            self.dp0 = tuple([x * T for x in v])
            self.ddp0 = tuple([x * T * T for x in a])
        else:
            self.dp0 = tuple([0.0] * len(p))
            self.ddp0 = tuple([0.0] * len(p))

    def step(self, mp: Vec, mv: Vec, ma: Vec,
             mj: Vec | None = None) -> tuple[Vec, Vec, Vec, bool]:
        """Advance one sample towards the master state (mp, mv, ma) of this sample.

        Returns the new setpoint (p, v, a) and whether the approach is complete.
        """
        T = self.T
        lim = self.limits
        opts = self.options
        p, v, a = self.p, self.v, self.a
        n = len(p)
        rng = range(n)

        # differences (#3.1); time to reach (#3.2)
        pdn = 0.0
        vdn = 0.0
        mvn = 0.0
        vn = 0.0
        closing = 0.0
        for i in rng:
            d = mp[i] - p[i]
            pdn += d * d
            dv = mv[i] - v[i]
            vdn += dv * dv
            closing += d * dv
            mvn += mv[i] * mv[i]
            vn += v[i] * v[i]
        if opts.directional_k:
            # overshoot needed (position and velocity errors point the same way): "faster" K
            faster, slower = (1.0, 0.0) if closing > 0.0 else (0.0, 1.0)
        else:
            faster, slower = math.sqrt(mvn), math.sqrt(vn)
        D = time_to_reach(math.sqrt(pdn), math.sqrt(vdn), faster, slower,
                          lim.acc, lim.jerk, T, self.damping_factor, *opts.time_to_reach_k)

        # rendezvous prediction (#3.3), t = D - T (time-origin shift)
        t = D - T
        half_t2 = 0.5 * t * t
        pred_diff = [mp[i] + t * mv[i] + half_t2 * ma[i] - p[i] for i in rng]
        pred_vel = [mv[i] + t * ma[i] for i in rng]
        pred_acc = list(ma) if opts.pred_acc_from_master else [0.0] * n

        # quintic coefficients (#3.4, the nested form) and next-sample increment (#3.5)
        T2 = T * T
        T3 = T2 * T
        T4 = T3 * T
        T5 = T4 * T
        a3 = []
        a4 = []
        a5 = []
        dp = []
        for i in rng:
            c3 = (0.5 * (pred_acc[i] - 3.0 * a[i])
                  + (10.0 * pred_diff[i] / D - 6.0 * v[i] - 4.0 * pred_vel[i]) / D) / D
            c4 = (((5.0 * pred_diff[i] / D - (pred_vel[i] + 4.0 * v[i])) / D
                   - 1.5 * a[i]) / D - 2.0 * c3) / D
            c5 = ((((pred_diff[i] / D - v[i]) / D - 0.5 * a[i]) / D - c3) / D - c4) / D
            a3.append(c3)
            a4.append(c4)
            a5.append(c5)
            dp.append(c5 * T5 + c4 * T4 + c3 * T3 + 0.5 * a[i] * T2 + v[i] * T)

        # velocity, acceleration and jerk filter (#3.6, vector norms)
        dp0, ddp0 = self.dp0, self.ddp0
        sat_v = sat_a = sat_j = False
        vel_cap = lim.vel * T
        if opts.braking_distance_velocity:
            dpn = math.sqrt(sum(x * x for x in dp))
            if dpn > 0.0:
                a_t = sum(a[i] * dp[i] for i in rng) / dpn
                if a_t > 0.0:
                    vel_cap = max(0.0, lim.vel - a_t * a_t / (2.0 * lim.jerk)) * T
        dpn = math.sqrt(sum(x * x for x in dp))
        if dpn > vel_cap:
            k = vel_cap / dpn
            dp = [x * k for x in dp]
            sat_v = True
        ddp = [dp[i] - dp0[i] for i in rng]
        acc_cap = lim.acc * T2
        ddpn = math.sqrt(sum(x * x for x in ddp))
        if ddpn > acc_cap:
            k = acc_cap / ddpn
            ddp = [x * k for x in ddp]
            dp = [ddp[i] + dp0[i] for i in rng]
            sat_a = True
        dddp = [ddp[i] - ddp0[i] for i in rng]
        jerk_cap = lim.jerk * T3
        dddpn = math.sqrt(sum(x * x for x in dddp))
        if dddpn > jerk_cap:
            k = jerk_cap / dddpn
            dddp = [x * k for x in dddp]
            ddp = [dddp[i] + ddp0[i] for i in rng]
            dp = [ddp[i] + dp0[i] for i in rng]
            sat_j = True
        self.sat_vel, self.sat_acc, self.sat_jerk = sat_v, sat_a, sat_j

        # new position; velocity and acceleration
        new_p = tuple([p[i] + dp[i] for i in rng])
        if sat_v or sat_a or sat_j:
            if opts.end_of_sample_feedback:
                new_v = tuple([(dp[i] + 0.5 * ddp[i] + dddp[i] / 3.0) / T for i in rng])
                new_a = tuple([(ddp[i] + dddp[i]) / T2 for i in rng])
            else:
                new_v = tuple([dp[i] / T for i in rng])
                new_a = tuple([ddp[i] / T2 for i in rng])
        else:
            new_v = tuple([5.0 * a5[i] * T4 + 4.0 * a4[i] * T3 + 3.0 * a3[i] * T2 + a[i] * T
                           + v[i] for i in rng])
            new_a = tuple([20.0 * a5[i] * T3 + 12.0 * a4[i] * T2 + 6.0 * a3[i] * T + a[i]
                           for i in rng])
        self.dp0 = tuple(dp)
        self.ddp0 = tuple(ddp)

        # synchronised? (#3.8)
        dvn = math.sqrt(sum((mv[i] - new_v[i]) ** 2 for i in rng))
        epn = math.sqrt(sum((mp[i] - new_p[i]) ** 2 for i in rng))
        synced = dvn <= self.sync_vel_threshold and epn <= self.sync_pos_threshold
        if synced and opts.take_the_middle:
            new_p = tuple([0.5 * (new_p[i] + mp[i]) for i in rng])
            new_v = tuple([0.5 * (new_v[i] + mv[i]) for i in rng])
        self.p, self.v, self.a = new_p, new_v, new_a
        return new_p, new_v, new_a, synced


def create(limits: Limits, params) -> SoftMcPlanner:
    """Planner-registry factory: a softMC channel planner for ``limits`` and ``params``."""
    return SoftMcPlanner(limits, params.sample_time_s, filter_factor=params.filter_factor,
                         damping_factor=params.damping_factor, options=params.softmc)
