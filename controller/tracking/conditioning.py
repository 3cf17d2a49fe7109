"""Master conditioning: raw conveyor-encoder samples in, a physically possible belt motion out.

The controller sees the belt only through an encoder: positions in steps of one count
(``resolution_mm``), taken ``latency_samples`` whole cycles before the cycle that uses them,
at an instant that may be off the nominal cycle time by a known ``time_offset_s`` (the
shell's measured SYNC lateness: the arrival jitter), sometimes missing, sometimes wrong (a
glitch).  :class:`MasterConditioner` turns them into the belt's position, velocity,
acceleration and jerk at the *setpoint's* time (``lead_samples`` cycles after the current
one), as a trajectory that stays within the moving frame's VelocityMax, AccelerationMax and
JerkMax.  Pure and deterministic: samples in, estimate out, no clock.

Two stages (docs/spec/master-conditioning.md#2 to #4):

1. **Estimator** -- a Kalman filter on the constant-jerk model x = (p, v, a, j) [mm, mm/s,
   mm/s^2, mm/s^3] driven by white snap of intensity q, measuring p with variance
   R = resolution^2/12 + noise_mm^2 (eq. 2.1-2.4).  q is the *quiet* model's,
   JerkMax^2 / ``quiet_jerk_change_s`` (or omega^8 R T for omega = 2 pi ``bandwidth_hz``,
   eq. 2.5): it averages where the belt's jerk does not change.  The first
   ``warmup_samples`` run the full (time-varying) filter from a wide prior; after that the
   gains come from a schedule computed once for the nominal period (eq. 2.7): a detector
   of jerk steps (an exponential average of the innovations beyond ``jerk_step_sigma``)
   re-opens the filter as a jerk step of 1 sigma = JerkMax would, and the gain runs down
   along the Riccati recursion to the steady state; the prediction is over the actual time
   between sample instants (jitter, missing samples).  At a detection the step is fitted
   to the samples since the last one (a generalized likelihood ratio: onset and size, the
   jerk after it within JerkMax or back to 0; eq. 2.8) and, confirmed, the belt's motion
   is revised back to the onset; the output takes the revision as one jump (eq. 4.5,
   reported as a ``JERK_STEP`` event) that the tracker closes within the robot's limits.
   *Outliers*: a sample whose innovation exceeds the gate (eq. 3.1)
   ``outlier_mm + JerkMax*dt^3/6`` (dt: time since the last accepted sample) is not
   something the belt can have done: it is rejected, counted, reported as an
   :class:`ConditioningEvent` with its size, and the estimate coasts.  ``max_outliers``
   consecutive outliers: the master is lost (``MasterStatus.LOST``; the shells then start the
   existing MASTER_LOST reaction); the next sample starts the filter again.
2. **Output generator** -- the estimate is predicted to the setpoint time (lag compensation,
   eq. 2.6) and followed by an output trajectory that is integrated sample by sample with a
   constant jerk per sample, so that the output *is* a belt motion: its finite differences
   never exceed the frame's limits.

   - ``ConditionerDesign.KINEMATIC`` (default): a third-order tracking law, jerk
     u = j_e + 3w(a_e - a) + 3w^2(v_e - v) + w^3(p_e - p) (triple pole at -w,
     w = 2 pi ``output_hz``) with feed-forward of the estimated jerk, projected onto the
     kinematic constraints |u| <= JerkMax, |a + uT| <= AccelerationMax and the braking
     distance of the velocity (eq. 4.1-4.3); where it would saturate, its pole is scheduled
     down until it fits (low-gain feedback: no wind-up).  A few multiply-adds per sample.
   - ``ConditionerDesign.OTG``: online trajectory generation with Ruckig: every sample a
     time-optimal plan from the output state to the estimate predicted by the last plan's
     duration, within the frame's limits; the output is its first sample (eq. 4.4).

   The benchmark (benchmarks/tracking.py, encoder table) compares them; KINEMATIC is kept
   (docs/spec/master-conditioning.md#5).

Units: mm, mm/s, mm/s^2, mm/s^3 (or deg... for a rotary frame), s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, NamedTuple, SupportsFloat

import numpy as np

from ..errors import ParameterError
from ..limits import Limits
from .types import MotionState, Vec3
from .values import as_stored, attributes, integer, mypyc_attr, python_class, restore


class ConditionerDesign(IntEnum):
    """How the output trajectory is generated from the estimate."""

    KINEMATIC = 0  #: Kalman estimate + third-order tracking law with kinematic projection
    OTG = 1  #: Kalman estimate + Ruckig online trajectory generation


class MasterStatus(IntEnum):
    """State of the conditioned master."""

    STARTING = 0  #: warming up (fewer than ``warmup_samples`` accepted samples): not usable
    OK = 1  #: the newest sample was accepted
    COASTING = 2  #: the newest sample was missing or an outlier: the estimate is predicted
    LOST = 3  #: ``max_outliers`` consecutive outliers: the master is lost


class EventKind(IntEnum):
    OUTLIER = 1  #: a sample rejected as physically impossible (size: its innovation [mm])
    LOST = 2  #: too many consecutive outliers (size: the last innovation [mm])
    READY = 3  #: the estimator is warmed up (again) and the output valid
    #: a jerk step of the belt detected: the estimate revised, the output jumped with it
    #: (size: the output's position jump [mm]; docs/spec/master-conditioning.md#2.8)
    JERK_STEP = 4


@python_class
@dataclass(frozen=True, slots=True)
class ConditioningEvent:
    """Something the shell should report: at ``sample`` (the conditioner's cycle count)."""

    kind: EventKind
    sample: int
    size_mm: float = 0.0


@python_class
@dataclass(frozen=True, slots=True)
class EncoderModel:
    """What is known about the encoder: count size [mm] and latency [whole cycles].

    ``resolution_mm``: one count in mm (0: an ideal, unquantised position);
    ``latency_samples``: cycles between the encoder's sampling instant and the cycle that gets
    the sample (1: the TPDO sampled at SYNC k arrives for cycle k's computation, which is for
    the setpoint applied at SYNC k+1); ``noise_mm``: extra white position noise [mm, 1 sigma].
    """

    resolution_mm: float = 0.0
    latency_samples: int = 1
    noise_mm: float = 0.0

    def __post_init__(self) -> None:
        s = as_stored(self)  # (the values as passed: values.as_stored)
        if not (math.isfinite(s.resolution_mm) and s.resolution_mm >= 0.0):
            raise ParameterError(f"resolution_mm (={s.resolution_mm!r}) must be >= 0 mm")
        integer(self, "latency_samples", 0, 100)
        if not (math.isfinite(s.noise_mm) and s.noise_mm >= 0.0):
            raise ParameterError(f"noise_mm (={s.noise_mm!r}) must be >= 0 mm")


@python_class
@dataclass(frozen=True, slots=True)
class ConditioningParams:
    """Configuration of one :class:`MasterConditioner` (one belt coordinate).

    ``frame``: the moving frame's VelocityMax/AccelerationMax/JerkMax (mm/s, mm/s^2, mm/s^3):
    the envelope of the output and of the outlier gate.  ``lead_samples``: the setpoint's time
    after the current cycle in cycles (1 + the drives' delay).  ``bandwidth_hz``: the
    estimator's bandwidth (eq. 2.5); ``output_hz``: the KINEMATIC tracking law's pole
    (eq. 4.1).  ``outlier_mm``: the gate's base [mm] (None: max(0.25 mm, 5 counts)).
    """

    sample_time_s: float
    encoder: EncoderModel = EncoderModel()
    frame: Limits = Limits(1000.0, 1000.0, 5000.0)
    lead_samples: float = 1.0
    design: ConditionerDesign = ConditionerDesign.KINEMATIC
    bandwidth_hz: float | None = None
    output_hz: float | None = None
    #: the belt's jerk may change by JerkMax within about this long [s]: sets the snap
    #: intensity q = JerkMax^2 / jerk_change_s of the estimator's model (eq. 2.5)
    jerk_change_s: float = 1.0
    #: between jerk steps the belt's jerk may change by JerkMax only within about this long
    #: [s]: the quiet model's snap intensity q_s = JerkMax^2 / quiet_jerk_change_s (eq. 2.5);
    #: a detected jerk step opens the filter (eq. 2.7)
    quiet_jerk_change_s: float = 100.0
    #: the jerk-step detector's threshold [sigma of its statistic] (eq. 2.7)
    jerk_step_sigma: float = 3.0
    outlier_mm: float | None = None
    max_outliers: int = 10
    #: the output's jerk may exceed JerkMax by this share to catch up the estimator's lag
    #: at a jerk step (eq. 4.2); velocity and acceleration stay within the frame's maxima
    jerk_reserve: float = 3.0
    warmup_samples: int | None = None

    def __post_init__(self) -> None:
        s = as_stored(self)  # (the values as passed: values.as_stored)
        if not (math.isfinite(s.sample_time_s) and 1e-5 <= s.sample_time_s <= 0.1):
            raise ParameterError(
                f"sample_time_s (={s.sample_time_s!r}) must be in [1e-05...0.1] s")
        try:
            object.__setattr__(self, "design", ConditionerDesign(s.design))
        except ValueError:
            raise ParameterError(f"design (={s.design!r}) must be one of "
                                 f"{', '.join(d.name.lower() for d in ConditionerDesign)}"
                                 ) from None
        if not (math.isfinite(s.lead_samples) and 0.0 <= s.lead_samples <= 100.0):
            raise ParameterError(f"lead_samples (={s.lead_samples!r}) must be in [0...100]")
        for name in ("jerk_change_s", "quiet_jerk_change_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise ParameterError(f"{name} (={v!r}) must be > 0 s")
        if not (isinstance(s.jerk_step_sigma, (int, float))
                and math.isfinite(s.jerk_step_sigma) and s.jerk_step_sigma > 0.0):
            raise ParameterError(f"jerk_step_sigma (={s.jerk_step_sigma!r}) must be > 0")
        for name in ("bandwidth_hz", "output_hz"):
            v = getattr(self, name)
            if v is None:
                continue
            if not (math.isfinite(v) and 0.0 < v <= 0.1 / s.sample_time_s):
                raise ParameterError(f"{name} (={v!r}) must be in (0...{0.1 / s.sample_time_s:g}]"
                                     f" Hz (a tenth of the sample rate)")
        if s.outlier_mm is not None and not (math.isfinite(s.outlier_mm)
                                                and s.outlier_mm > 0.0):
            raise ParameterError(f"outlier_mm (={s.outlier_mm!r}) must be > 0 mm")
        if not (math.isfinite(s.jerk_reserve) and 0.0 <= s.jerk_reserve <= 100.0):
            raise ParameterError(f"jerk_reserve (={s.jerk_reserve!r}) must be in [0...100]")
        integer(self, "max_outliers", 1)
        if s.warmup_samples is not None:
            integer(self, "warmup_samples", 3)

    @property
    def gate_mm(self) -> float:
        """Base of the outlier gate [mm]."""
        if self.outlier_mm is not None:
            return self.outlier_mm
        return max(0.25, 5.0 * self.encoder.resolution_mm)

    @property
    def measurement_var_mm2(self) -> float:
        """R [mm^2]: quantisation (one count uniform) plus the extra noise (eq. 2.2)."""
        enc = self.encoder
        return max(enc.resolution_mm ** 2 / 12.0 + enc.noise_mm ** 2, 1e-12)

    @property
    def estimator_hz(self) -> float:
        """The estimator's bandwidth [Hz]: given, or from q and R (eq. 2.5), at most a
        tenth of the sample rate."""
        if self.bandwidth_hz is not None:
            return self.bandwidth_hz
        q = self.frame.jerk ** 2 / self.jerk_change_s
        w = (q / (self.measurement_var_mm2 * self.sample_time_s)) ** 0.125
        return min(w / (2.0 * math.pi), 0.1 / self.sample_time_s)

    @property
    def quiet_q(self) -> float:
        """The quiet model's snap intensity q_s [mm^2/s^7] (eq. 2.5): JerkMax^2 /
        ``quiet_jerk_change_s``, or from ``bandwidth_hz`` if given."""
        if self.bandwidth_hz is not None:
            w = 2.0 * math.pi * self.bandwidth_hz
            return w ** 8 * self.measurement_var_mm2 * self.sample_time_s
        return self.frame.jerk ** 2 / self.quiet_jerk_change_s

    @property
    def generator_hz(self) -> float:
        """The KINEMATIC law's pole [Hz]: given, or 1.5 x the estimator's (a tenth of the
        sample rate at most)."""
        if self.output_hz is not None:
            return self.output_hz
        return min(1.5 * self.estimator_hz, 0.1 / self.sample_time_s)

    @property
    def warmup(self) -> int:
        """Accepted samples before the output is valid: 5 estimator time constants."""
        if self.warmup_samples is not None:
            return int(self.warmup_samples)
        return max(10, math.ceil(5.0 / (2.0 * math.pi * self.estimator_hz * self.sample_time_s)))


class ConditionedMaster(NamedTuple):
    """The conditioned belt at the setpoint time: mm, mm/s, mm/s^2, mm/s^3 (or deg...).

    A named tuple (immutable; made once per cycle, so cheap to make)."""

    pos: float
    vel: float
    acc: float
    jerk: float
    status: MasterStatus
    event: ConditioningEvent | None = None

    @property
    def valid(self) -> bool:
        """Usable by a tracker (warmed up, not lost)."""
        return self.status == MasterStatus.OK or self.status == MasterStatus.COASTING

    def along(self, direction: Vec3, origin: Vec3 = (0.0, 0.0, 0.0)) -> MotionState:
        """The 3-D master of a linear frame: origin + direction * s (``direction`` a unit
        vector), with all four derivatives."""
        d0, d1, d2 = direction
        p, v, a, j = self.pos, self.vel, self.acc, self.jerk
        return MotionState((origin[0] + d0 * p, origin[1] + d1 * p, origin[2] + d2 * p),
                           (d0 * v, d1 * v, d2 * v), (d0 * a, d1 * a, d2 * a),
                           jerk=(d0 * j, d1 * j, d2 * j))


def _q_matrix(q: float, dt: float) -> np.ndarray:
    """Process noise of the constant-jerk model over dt for white snap q (eq. 2.3)."""
    Q = np.empty((4, 4))
    for i in range(4):
        for k in range(4):
            e = 7 - i - k
            Q[i, k] = q * dt ** e / (e * math.factorial(3 - i) * math.factorial(3 - k))
    return Q


def _f_matrix(dt: float) -> np.ndarray:
    return np.array([[1.0, dt, dt * dt / 2.0, dt ** 3 / 6.0], [0.0, 1.0, dt, dt * dt / 2.0],
                     [0.0, 0.0, 1.0, dt], [0.0, 0.0, 0.0, 1.0]])


def steady_state(q: float, r: float, dt: float) -> tuple[tuple[float, float, float, float],
                                                         np.ndarray]:
    """Steady-state Kalman gain (p, v, a, j rows) of the constant-jerk model (eq. 2.4) and
    the covariance after the update, by iterating the Riccati recursion to convergence."""
    F = _f_matrix(dt)
    Q = _q_matrix(q, dt)
    P = np.diag([r, 1e6 * r / dt ** 2, 1e6 * r / dt ** 4, 1e6 * r / dt ** 6])
    K = np.zeros(4)
    for _ in range(20000):
        Pp = F @ P @ F.T + Q
        Kn = Pp[:, 0] / (Pp[0, 0] + r)
        P = Pp - np.outer(Kn, Pp[0, :])
        if np.allclose(Kn, K, rtol=1e-12, atol=0.0):
            K = Kn
            break
        K = Kn
    return (float(K[0]), float(K[1]), float(K[2]), float(K[3])), P


#: a jerk step is assumed to have happened within this long before its detection [s]: the
#: covariance a detection adds is the model's process noise over it (eq. 2.7)
JERK_STEP_WINDOW_S = 0.04
#: the detector's memory [s]: time constant of its exponential average of innovations
JERK_STEP_MEMORY_S = 0.005
#: after a detection the next one is not before this long [s] (the gains run down first)
JERK_STEP_HOLD_S = 0.06
#: the jerk-step fit's window [s] (eq. 2.8): longer than the detector's delay (40-55 ms
#: at 50 um / 4 ms), shorter than a belt's S-curve phases
GLR_WINDOW_S = 0.1
#: the fit's candidate onsets are this far apart [s] (half a sample at longer cycles)
GLR_ONSET_S = 0.001
#: a detection is confirmed when the fit's log-likelihood ratio (twice: chi^2 units) is at
#: least this (eq. 2.8); below it, the filter is re-opened as in eq. 2.7
GLR_CONFIRM = 12.0
#: the hypothesis "the jerk returned to 0" is taken unless the free step fits better by more
#: than this (chi^2 units; eq. 2.8)
GLR_ZERO_PENALTY = 4.0
#: the warm-up's gate: base + this many standard deviations of the innovation (eq. 3.1)
WARMUP_GATE_SIGMA = 6.0
#: the KINEMATIC law's pole is at most this / T [rad/s] (eq. 4.2): a discrete law with a
#: faster pole rings when it saturates after a detected jerk step
OUTPUT_POLE_T = 0.25


def jerk_step_schedule(q: float, r: float, dt: float, P: np.ndarray, jerk_mm_s3: float,
                       window_s: float = JERK_STEP_WINDOW_S, rtol: float = 1e-3,
                       max_samples: int = 100_000) -> tuple[list, list, list]:
    """Gains after a detected jerk step (eq. 2.7): the Riccati recursion of the quiet model
    (snap q, measurement variance r [mm^2], period dt [s]) from its steady-state covariance
    P plus the process noise of a jerk change of 1 sigma = ``jerk_mm_s3`` spread over
    ``window_s``, until the gain is within ``rtol`` of the steady state.  Returns the gains
    (p, v, a, j rows), the innovation standard deviations [mm] and the covariances after
    each update (the GLR's prior, eq. 2.8), one per sample; the last entry is the steady
    state."""
    K_ss, _ = steady_state(q, r, dt)
    F = _f_matrix(dt)
    Q = _q_matrix(q, dt)
    P = P + _q_matrix(jerk_mm_s3 ** 2 / window_s, window_s)
    Ks: list = []
    Ss: list = []
    Ps: list = []
    for _ in range(max_samples):
        Pp = F @ P @ F.T + Q
        S = float(Pp[0, 0] + r)
        K = Pp[:, 0] / S
        P = Pp - np.outer(K, Pp[0, :])
        Ks.append((float(K[0]), float(K[1]), float(K[2]), float(K[3])))
        Ss.append(math.sqrt(S))
        Ps.append(P)
        if all(abs(k - ks) <= rtol * abs(ks) for k, ks in zip(Ks[-1], K_ss)):
            break
    Ks.append(K_ss)
    Ss.append(Ss[-1])
    Ps.append(Ps[-1])
    return Ks, Ss, Ps


def jerk_step_fit(tau_s: np.ndarray, res_mm: np.ndarray, P_w: np.ndarray, r: float,
                  onsets_s: np.ndarray, j0: float, jerk_max: float
                  ) -> tuple[float, float, float, np.ndarray]:
    """Eq. 2.8: the generalized likelihood ratio of one jerk step in a window of samples.

    ``tau_s``: the samples' instants after the window's start state x_w [s]; ``res_mm``: the
    samples minus x_w's constant-jerk prediction [mm]; ``P_w``: the covariance of x_w's
    error (the prior of its correction delta); ``r``: the measurement variance [mm^2];
    ``onsets_s``: the candidate onsets theta [s]; ``j0``: x_w's jerk; ``jerk_max``: the
    frame's JerkMax (the jerk after the step stays within it).  Two hypotheses per onset,
    fitted by least squares with the prior on delta: the jerk steps by a free dj (limited
    so that |j0 + delta_j + dj| <= jerk_max), or it returns to 0 (an S-curve's phases end
    at jerk 0), taken unless the free step fits better by ``GLR_ZERO_PENALTY``.  Returns
    (the best onset's statistic [chi^2, twice the log-likelihood ratio against no step],
    theta [s], dj [mm/s^3], delta (4,))."""
    A = np.stack([np.ones_like(tau_s), tau_s, tau_s * tau_s / 2.0, tau_s ** 3 / 6.0], axis=1)
    M0 = A.T @ A / r + np.linalg.inv(P_w)
    M0i = np.linalg.inv(M0)
    b0 = A.T @ res_mm / r
    g = M0i @ b0  # delta without a step
    d = np.maximum(tau_s[None, :] - onsets_s[:, None], 0.0)
    S = d * d * d / 6.0  # the step's signature per onset, per unit dj
    W = S @ A / r
    numer = S @ res_mm / r - W @ g
    denom = np.maximum((S * S).sum(axis=1) / r - np.einsum("ij,jk,ik->i", W, M0i, W),
                       1e-300)
    jb = j0 + g[3]
    djs = np.clip(numer / denom, -jerk_max - jb, jerk_max - jb)
    stat = 2.0 * djs * numer - djs * djs * denom
    b = int(np.argmax(stat))
    dj = float(djs[b])
    best = (float(stat[b]), float(onsets_s[b]), dj, M0i @ (b0 - W[b] * dj))
    if j0 == 0.0:
        return best
    # back to jerk 0 at theta: res = A_z delta - j0 s with A_z = A - s e3^T (s = S_theta):
    # its normal equations are M0's and b0's updated by rank two from W, u and ss (no sum
    # over the samples per onset), one 4 x 4 solve per onset
    u = S @ res_mm / r
    ss = (S * S).sum(axis=1) / r
    Mz = np.broadcast_to(M0, (len(onsets_s), 4, 4)).copy()
    Mz[:, :, 3] -= W
    Mz[:, 3, :] -= W
    Mz[:, 3, 3] += ss
    bz = b0[None, :] + j0 * W
    bz[:, 3] -= u + j0 * ss
    dz = np.linalg.solve(Mz, bz[:, :, None])[:, :, 0]
    statz = (res_mm @ res_mm / r - b0 @ g) - ((res_mm @ res_mm) / r + 2.0 * j0 * u
                                               + j0 * j0 * ss
                                               - np.einsum("ti,ti->t", bz, dz))
    bz_ = int(np.argmax(statz))
    if statz[bz_] >= best[0] - GLR_ZERO_PENALTY:
        return (float(statz[bz_]), float(onsets_s[bz_]), -(j0 + float(dz[bz_, 3])),
                dz[bz_])
    return best


def _low_gain(j: float, ea: float, ev: float, ep: float, w: float, lo: float,
              hi: float) -> float:
    """Eq. 4.3: the tracking law u = j + 3w'e_a + 3w'^2 e_v + w'^3 e_p with the largest
    pole w' <= w [rad/s] for which u lies in [lo, hi] [mm/s^3] (bisection; j itself is
    taken into [lo, hi] first).  Scheduling the gain down while the error is large keeps
    the saturated triple integrator linear, so it cannot wind up (low-gain feedback)."""
    base = max(lo, min(hi, j))
    a, b = 0.0, w
    for _ in range(24):
        m = 0.5 * (a + b)
        u = base + m * (3.0 * ea + m * (3.0 * ev + m * ep))
        if lo <= u <= hi:
            a = m
        else:
            b = m
    return max(lo, min(hi, base + a * (3.0 * ea + a * (3.0 * ev + a * ep))))


def output_pole(P: np.ndarray, w_max: float, authority: float) -> float:
    """The KINEMATIC law's pole [rad/s] (eq. 4.2): the fastest up to ``w_max`` whose jerk
    driven by the estimate's own error, 3 sigma of g^T P g with g = (w^3, 3w^2, 3w, 1),
    fits in the jerk ``authority`` [mm/s^3] left over the belt's own jerk."""
    def noise(w: float) -> float:
        g = np.array([w ** 3, 3.0 * w * w, 3.0 * w, 1.0])
        return 3.0 * math.sqrt(max(float(g @ P @ g), 0.0))

    if noise(w_max) <= authority:
        return w_max
    lo, hi = 0.0, w_max
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if noise(mid) <= authority:
            lo = mid
        else:
            hi = mid
    return max(lo, 1e-3 * w_max)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class MasterConditioner:
    """Raw belt positions (one per cycle) -> conditioned belt motion at the setpoint time.

    ``update(position_mm, time_offset_s)`` once per cycle: the sample the encoder took
    ``latency_samples`` cycles ago (``None`` if none arrived this cycle), ``time_offset_s``
    [s] how far its sampling instant was after the nominal time (known jitter).
    """

    def __init__(self, params: ConditioningParams) -> None:
        self.params = params
        T = self.T = params.sample_time_s
        enc = params.encoder
        self._r = r = params.measurement_var_mm2
        self._q = q = params.quiet_q
        # the warm-up's model: the belt's jerk changing by JerkMax within jerk_change_s (eq. 2.5)
        w = 2.0 * math.pi * params.estimator_hz
        self._q_warm = w ** 8 * r * T
        self._K, P = steady_state(q, r, T)
        # eq. 2.7: the gains after a detected jerk step, run down to the steady state; the
        # detector's thresholds per step of that schedule
        Ks, sd, self._Ps = jerk_step_schedule(q, r, T, P, params.frame.jerk)
        #: the jerk-step fit's window [samples] (eq. 2.8)
        self._nwin = max(8, round(GLR_WINDOW_S / T))
        #: its candidate onsets' spacing [s]: half a sample, at most 1 ms (eq. 2.8)
        self._onset_s = max(0.5 * T, min(T, GLR_ONSET_S))
        #: jerk steps confirmed by the fit (statistics; n_jerk_steps counts every detection)
        self.n_jerk_fits = 0
        lam = self._lam = math.exp(-T / JERK_STEP_MEMORY_S)
        self._lam1 = 1.0 - lam
        c = params.jerk_step_sigma * math.sqrt((1.0 - lam) / (1.0 + lam))
        hold = max(1, round(JERK_STEP_HOLD_S / T))
        last = len(Ks) - 1
        #: per step i of the schedule: (K_p, K_v, K_a, K_j, the detector's threshold [mm]
        #: (none during the hold after a detection), the next step)
        self._sched = [(*K, c * x if i >= hold else math.inf, min(i + 1, last))
                       for i, (K, x) in enumerate(zip(Ks, sd))]
        #: jerk steps detected (statistics)
        self.n_jerk_steps = 0
        f = params.frame
        # (1 - 1e-9): the output stays under the maxima after rounding (the tracker's master
        # monitoring compares with them exactly)
        self._V, self._A, self._J = f.vel * (1.0 - 1e-9), f.acc * (1.0 - 1e-9), f.jerk
        self._J6 = f.jerk / 6.0  # the gate's growth: J dt^3 / 6 (eq. 3.1)
        self._Jout = f.jerk * (1.0 + params.jerk_reserve)
        #: jerk available for corrections on top of the belt's own (eq. 4.2)
        self._authority = max(self._Jout - f.jerk, 0.25 * f.jerk)
        wo = 2.0 * math.pi * params.generator_hz
        if params.output_hz is None:
            # eq. 4.2: the noise of the quiet estimate, at most OUTPUT_POLE_T / T
            wo = output_pole(P, min(wo, OUTPUT_POLE_T / T), self._authority)
        #: the KINEMATIC law's pole [Hz]
        self.output_hz = wo / (2.0 * math.pi)
        # triple pole at -wo as a cascade: kp*kv*ka = wo^3, kv*ka = 3 wo^2, ka = 3 wo
        self._g = (wo / 3.0, wo, 3.0 * wo)
        self._gains = (3.0 * wo, 3.0 * wo * wo, wo ** 3)  # ka, ka*kv, ka*kv*kp
        self._gate = params.gate_mm
        self._warmup = params.warmup
        self._lead_s = params.lead_samples * T
        self._latency = enc.latency_samples
        self._kinematic_design = params.design == ConditionerDesign.KINEMATIC
        self._otg: Any = None  # (Ruckig, InputParameter, Trajectory), made when first needed
        self._otg_d = 0.0
        #: statistics: accepted samples, outliers, missing samples, lost events
        self.n_accepted = 0
        self.n_outliers = 0
        self.n_missing = 0
        self.n_lost = 0
        self.reset()

    def __getstate__(self):
        d = attributes(self)
        d["_otg"] = None  # Ruckig objects cannot be pickled: rebuilt when needed
        return d

    def __setstate__(self, d) -> None:
        restore(self, d)

    def reset(self) -> None:
        """Forget the belt (the next sample starts the warm-up)."""
        self.k = 0  # cycles since reset
        # times are kept as (cycle, offset [s]) and only their differences computed, so that
        # the results do not depend on where cycle 0 was (shells started at other times
        # give bit-identical outputs)
        self._x: tuple[float, float, float, float] | None = None  # (p, v, a, j) at _tx
        self._tx = (0, 0.0)
        self._P: np.ndarray | None = None
        self._n = 0  # accepted samples since (re)start
        self._bad = 0  # consecutive outliers
        self._t_acc = (0, 0.0)  # instant of the last accepted sample
        self._y: tuple[float, float, float] | None = None  # output at the last setpoint time
        self._yj = 0.0
        # step of the jerk-step gain schedule (eq. 2.7): the steady state once warmed up (the
        # warm-up's faster model has converged; a jerk step re-opens the filter)
        self._i = len(self._sched) - 1
        self._s = 0.0  # the jerk-step detector's statistic [mm]
        self.lost = False
        #: accepted samples since the last detection, at most 2 windows (eq. 2.8): (cycle,
        #: offset [s], z [mm], the state after it, the schedule's step of its gain)
        self._hist: list[tuple[int, float, float, tuple[float, float, float, float], int]] = []

    # -- the estimator ------------------------------------------------------------------
    @staticmethod
    def _predict(x: tuple, dt: float) -> tuple[float, float, float, float]:
        p, v, a, j = x
        h = dt * dt
        return (p + v * dt + a * h * 0.5 + j * h * dt / 6.0, v + a * dt + j * h * 0.5,
                a + j * dt, j)

    def _dt(self, a: tuple[int, float], b: tuple[int, float]) -> float:
        """Time from instant b to instant a [s] (instants: (cycle, offset [s]))."""
        return (a[0] - b[0]) * self.T + (a[1] - b[1])

    def _measure(self, z: float, ts: tuple[int, float]) -> tuple[EventKind | None, float]:
        """Feed the sample z [mm] taken at instant ts; (event kind or None, innovation)."""
        if self._x is None:
            self._x = (z, 0.0, 0.0, 0.0)
            self._tx = ts
            r = self._r
            T = self.T
            self._P = np.diag([r, (1e3 / T) ** 2 * r, (1e3 / T ** 2) ** 2 * r,
                               (1e3 / T ** 3) ** 2 * r])
            self._n = 1
            self._t_acc = ts
            return None, 0.0
        dt = self._dt(ts, self._tx)
        xp = self._predict(self._x, dt)
        innov = z - xp[0]
        if self._n >= self._warmup:
            da = self._dt(ts, self._t_acc)
            gate = self._gate + self._J6 * da * da * da
            if abs(innov) > gate:
                self._bad += 1
                self._x, self._tx = xp, ts
                if self._bad >= self.params.max_outliers:
                    return EventKind.LOST, innov
                return EventKind.OUTLIER, innov
            i = self._i
            K = self._gain(innov)
            if K is None:  # a jerk step (eq. 2.8)
                jump = self._jerk_step(z, ts, xp, innov)
                self._bad = 0
                self._n += 1
                return EventKind.JERK_STEP, jump
            self._x = (xp[0] + K[0] * innov, xp[1] + K[1] * innov, xp[2] + K[2] * innov,
                       xp[3] + K[3] * innov)
            hist = self._hist
            hist.append((ts[0], ts[1], z, self._x, i))
            if len(hist) > 2 * self._nwin:
                del hist[:self._nwin]
        else:  # warm-up: the full filter from the wide prior
            F = _f_matrix(dt)
            P = F @ self._P @ F.T + _q_matrix(self._q_warm, dt)
            S = P[0, 0] + self._r
            # the gate in the warm-up (eq. 3.1): once the cubic is determined, a sample
            # beyond WARMUP_GATE_SIGMA of the innovation's own spread (plus the gate's base)
            # is an outlier too -- one glitch taken in would spoil the estimate for the
            # whole warm-up (and the output started on it)
            if self._n >= 4 and abs(innov) > self._gate + WARMUP_GATE_SIGMA * math.sqrt(S):
                self._bad += 1
                self._x, self._tx, self._P = xp, ts, P
                if self._bad >= self.params.max_outliers:
                    return EventKind.LOST, innov
                return EventKind.OUTLIER, innov
            Kv = P[:, 0] / S
            self._P = P - np.outer(Kv, P[0, :])
            xn = np.asarray(xp) + Kv * innov
            self._x = (float(xn[0]), float(xn[1]), float(xn[2]), float(xn[3]))
        self._tx = ts
        self._bad = 0
        self._n += 1
        self._t_acc = ts
        return None, innov

    def _gain(self, innov: float) -> tuple[float, float, float, float] | None:
        """Eq. 2.7: the gain for an accepted sample of innovation ``innov`` [mm] and the
        schedule moved on; None: a jerk step is detected (``_jerk_step``)."""
        g = self._sched[self._i]
        s = self._lam * self._s + self._lam1 * innov
        if abs(s) > g[4]:
            return None
        self._s = s
        self._i = g[5]
        return g[0], g[1], g[2], g[3]

    def _jerk_step(self, z: float, ts: tuple[int, float],
                   xp: tuple[float, float, float, float], innov: float) -> float:
        """Eq. 2.8: a detected jerk step at the sample z [mm] taken at ``ts`` (prediction
        ``xp``, innovation ``innov``).  The jerk step is fitted in the window since the last
        detection (``jerk_step_fit``); confirmed, the state becomes the fit's (the belt's
        motion revised back to the step's onset), else the filter is re-opened (eq. 2.7).
        Either way the filter's gain schedule starts again and the output (eq. 4.5) takes
        the estimate's jump at once: the revision is handed on, not followed at the belt's
        jerk."""
        self.n_jerk_steps += 1
        self._s = 0.0
        T = self.T
        g = self._sched[0]
        K0, K1, K2, K3 = g[0], g[1], g[2], g[3]
        gi = self._sched[self._i]  # the jump's base: what the current gain would have given
        old = (xp[0] + gi[0] * innov, xp[1] + gi[1] * innov, xp[2] + gi[2] * innov,
               xp[3] + gi[3] * innov)
        new = (xp[0] + K0 * innov, xp[1] + K1 * innov, xp[2] + K2 * innov, xp[3] + K3 * innov)
        h = self._hist
        if len(h) >= 6:
            kw, ow, _, xw, iw = h[-min(len(h), self._nwin)]
            w = h[-min(len(h), self._nwin) + 1:]
            tau = np.array([(e[0] - kw) * T + (e[1] - ow) for e in w]
                           + [(ts[0] - kw) * T + (ts[1] - ow)])
            zs = np.array([e[2] for e in w] + [z])
            pw, vw, aw, jw = xw
            res = zs - (pw + vw * tau + aw * tau * tau / 2.0 + jw * tau ** 3 / 6.0)
            stat, th, dj, dl = jerk_step_fit(tau, res, self._Ps[iw], self._r,
                                             np.arange(0.0, tau[-1], self._onset_s), jw, self._J)
            if stat >= GLR_CONFIRM:
                t = float(tau[-1])
                p, v, a, j = self._predict((pw + dl[0], vw + dl[1], aw + dl[2], jw + dl[3]), t)
                e = t - th
                new = (p + dj * e ** 3 / 6.0, v + dj * e * e / 2.0, a + dj * e, j + dj)
                self.n_jerk_fits += 1
        self._x = new
        self._tx = self._t_acc = ts
        self._i = g[5]
        h.clear()
        h.append((ts[0], ts[1], z, new, 0))
        if self._y is None:
            return 0.0
        # eq. 4.5: the output takes the jump (at its own instant, the step's start), within
        # the frame's velocity and acceleration
        d = self._predict((new[0] - old[0], new[1] - old[1], new[2] - old[2], new[3] - old[3]),
                          self._dt((self.k - 1, self._lead_s), ts) - T)
        yp, yv, ya = self._y
        V, A = self._V, self._A
        self._y = (yp + d[0], max(-V, min(V, yv + d[1])), max(-A, min(A, ya + d[2])))
        return d[0]

    # -- the cyclic call ----------------------------------------------------------------
    def update(self, position_mm: SupportsFloat | None,
               time_offset_s: float = 0.0) -> ConditionedMaster:
        """One cycle.  Returns the conditioned belt at this cycle's setpoint time."""
        # (any real number: numpy's scalars as Python floats, the same in both modes)
        pos_mm = None if position_mm is None else float(position_mm)
        k = self.k
        self.k = k + 1
        T = self.T
        if (pos_mm is not None and self._n >= self._warmup and not self.lost
                and self._y is not None and self._kinematic_design):
            # the steady state, inlined (eq. 2.4, 3.1, 4.1): predict, gate, correct, output
            tx = self._tx
            kx = k - self._latency
            off = float(time_offset_s)
            dt = (kx - tx[0]) * T + (off - tx[1])
            p, v, a, j = self._x  # type: ignore[misc]  # not None: n >= warmup
            h = dt * dt
            p += v * dt + a * h * 0.5 + j * h * dt / 6.0
            v += a * dt + j * h * 0.5
            a += j * dt
            innov = pos_mm - p
            ta = self._t_acc
            da = (kx - ta[0]) * T + (off - ta[1])
            gate = self._gate + self._J6 * da * da * da
            if -gate <= innov <= gate:
                # eq. 2.7, inlined (_gain)
                g = self._sched[self._i]
                s = self._lam * self._s + self._lam1 * innov
                if s > g[4] or -s > g[4]:
                    # a jerk step (eq. 2.8): the revised belt, its jump taken by the output
                    jump = self._jerk_step(pos_mm, (kx, off), (p, v, a, j), innov)
                    self._bad = 0
                    self._n += 1
                    self.n_accepted += 1
                    self._kinematic((k, self._lead_s))
                    p, v, a = self._y
                    return ConditionedMaster(p, v, a, self._yj, MasterStatus.OK,
                                             ConditioningEvent(EventKind.JERK_STEP, k, jump))
                self._s = s
                i = self._i
                K0, K1, K2, K3, _, self._i = g
                self._x = (p + K0 * innov, v + K1 * innov, a + K2 * innov, j + K3 * innov)
                self._tx = self._t_acc = (kx, off)
                self._bad = 0
                self._n += 1
                self.n_accepted += 1
                hist = self._hist
                hist.append((kx, off, pos_mm, self._x, i))
                if len(hist) > 2 * self._nwin:
                    del hist[:self._nwin]
                # the output law (eq. 4.1), from the estimate at the step's start (lead - 1)
                dt = (self._lead_s - off) + (self._latency - 1) * T
                p += K0 * innov
                v += K1 * innov
                a += K2 * innov
                j += K3 * innov
                h = dt * dt
                pe = p + v * dt + a * h * 0.5 + j * h * dt / 6.0
                ve = v + a * dt + j * h * 0.5
                ae = a + j * dt
                yp, yv, ya = self._y
                g1, g2, g3 = self._gains
                u = j + g1 * (ae - ya) + g2 * (ve - yv) + g3 * (pe - yp)
                # inside the envelope with room to spare: no projection needed (eq. 4.3)
                J = self._Jout
                vn = yv + ya * T
                an = ya + u * T
                if (-J < u < J and -self._A < an < self._A
                        and an * an < 2.0 * J * (self._V - abs(vn)) * 0.25):
                    h = T * T
                    yp, yv = (yp + yv * T + ya * h * 0.5 + u * h * T / 6.0,
                              yv + ya * T + u * h * 0.5)
                    self._y = (yp, yv, an)
                    self._yj = u
                    return ConditionedMaster(yp, yv, an, u, MasterStatus.OK, None)
                self._kinematic((k, self._lead_s))
                p, v, a = self._y
                return ConditionedMaster(p, v, a, self._yj, MasterStatus.OK, None)
        event = None
        status = MasterStatus.OK
        if self.lost and pos_mm is not None:
            self._x = None  # start again from this sample
            self._n = 0
            self._i = len(self._sched) - 1
            self._s = 0.0
            self.lost = False
        if pos_mm is None:
            self.n_missing += 1
            status = MasterStatus.COASTING
        elif not self.lost:
            ts = (k - self._latency, float(time_offset_s))
            was_ready = self._n >= self._warmup
            kind, innov = self._measure(float(pos_mm), ts)
            if kind is None or kind == EventKind.JERK_STEP:
                self.n_accepted += 1
                if kind is not None:
                    event = ConditioningEvent(kind, k, innov)
                if not was_ready and self._n >= self._warmup:
                    event = ConditioningEvent(EventKind.READY, k)
            else:
                self.n_outliers += 1
                status = MasterStatus.COASTING
                event = ConditioningEvent(kind, k, innov)
                if kind == EventKind.LOST:
                    self.n_lost += 1
                    self.lost = True
        if self._x is None or self._n < self._warmup:
            return ConditionedMaster(0.0 if self._x is None else self._x[0], 0.0, 0.0, 0.0,
                                     MasterStatus.STARTING, event)
        if self.lost:
            status = MasterStatus.LOST
        t_sp = (k, self._lead_s)  # this cycle's setpoint instant
        if self._y is None:
            # the first valid cycle: the output starts on the estimate (within the limits)
            p, v, a, _ = self._predict(self._x, self._dt(t_sp, self._tx))
            V, A = self._V, self._A
            self._y = (p, max(-V, min(V, v)), max(-A, min(A, a)))
            self._yj = 0.0
        elif self._kinematic_design:
            self._kinematic(t_sp)
        else:
            self._otg_step(t_sp)
        p, v, a = self._y
        return ConditionedMaster(p, v, a, self._yj, status, event)

    # -- output generators ---------------------------------------------------------------
    def _kinematic(self, t_sp: tuple[int, float]) -> None:
        """Eq. 4.1-4.3: the cascade law at the step's start, projected, integrated."""
        T = self.T
        tx = self._tx
        dt = (t_sp[0] - tx[0]) * T + (t_sp[1] - tx[1]) - T
        pe, ve, ae, je = self._x  # type: ignore[misc]  # set once warmed up
        h = dt * dt
        pe += ve * dt + ae * h * 0.5 + je * h * dt / 6.0
        ve += ae * dt + je * h * 0.5
        ae += je * dt
        p, v, a = self._y  # type: ignore[misc]  # set on the first valid cycle
        g1, g2, g3 = self._gains
        V, A, J = self._V, self._A, self._Jout
        # triple pole at -wo on the error to the estimate, with its jerk fed forward
        u = je + g1 * (ae - a) + g2 * (ve - v) + g3 * (pe - p)
        hi = min(J, (A - a) / T)
        lo = max(-J, (-A - a) / T)
        # braking distance (eq. 4.3): after the step the acceleration must still be able to
        # return to 0 at J before |v| reaches V
        vn = v + a * T
        amax = math.sqrt(2.0 * J * (V - vn)) if vn < V else 0.0
        amin = -math.sqrt(2.0 * J * (V + vn)) if vn > -V else 0.0
        hi = min(hi, (amax - a) / T)
        lo = max(lo, (amin - a) / T)
        if lo > hi:  # outside the envelope (cannot come from the output itself): brake
            u = max(-J, min(J, lo if a < 0.0 else hi))
        elif not lo <= u <= hi:
            # the law would saturate: a saturated triple integrator can wind up, so the law's
            # pole is scheduled down until it fits (eq. 4.3: low-gain feedback)
            u = _low_gain(je, ae - a, ve - v, pe - p, self._gains[0] / 3.0, lo, hi)
        h = T * T
        self._y = (p + v * T + a * h * 0.5 + u * h * T / 6.0, v + a * T + u * h * 0.5,
                   a + u * T)
        self._yj = u

    def _otg_step(self, t_sp: tuple[int, float], fallback: bool = True) -> bool:
        """Eq. 4.4: Ruckig in the estimate's frame: from e0 = output - estimate (both at the
        step's start; the estimate moving on at its constant acceleration) to e = 0 in
        minimum time, bounds shifted by the estimate's velocity and acceleration so that
        the output itself stays within the frame's limits; the output is its first sample."""
        from ruckig import InputParameter, Ruckig, Trajectory
        if self._otg is None:
            self._otg = (Ruckig(1), InputParameter(1), Trajectory(1))
            inp = self._otg[1]
            inp.target_position = [0.0]
            inp.target_velocity = [0.0]
            inp.target_acceleration = [0.0]
        rk, inp, traj = self._otg
        s = 1e-3  # Ruckig needs SI-like magnitudes (optimal.py)
        T = self.T
        V, A, J = self._V, self._A, self._Jout
        pe, ve, ae, _ = self._predict(self._x, self._dt(t_sp, self._tx) - T)  # type: ignore[arg-type]
        ae = max(-A, min(A, ae))
        ve = max(-V, min(V, ve))
        p, v, a = self._y  # type: ignore[misc]
        inp.current_position = [(p - pe) * s]
        inp.current_velocity = [(v - ve) * s]
        inp.current_acceleration = [(a - ae) * s]
        inp.min_velocity = [(-V - ve) * s]
        inp.max_velocity = [(V - ve) * s]
        inp.min_acceleration = [(-A - ae) * s]
        inp.max_acceleration = [(A - ae) * s]
        inp.max_jerk = [J * s]
        try:
            ok = int(rk.calculate(inp, traj)) >= 0
        except Exception:  # noqa: BLE001 - the binding raises on unknown result codes
            ok = False
        if not ok:  # not seen; the kinematic law instead
            if fallback:
                self._kinematic(t_sp)
            return False
        (ep,), (ev,), (ea,) = traj.at_time(T)
        h = T * T
        na = ae + ea / s
        self._y = (pe + ve * T + ae * h * 0.5 + ep / s, ve + ae * T + ev / s, na)
        self._yj = (na - a) / T
        return True
