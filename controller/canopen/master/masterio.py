"""The conveyor (master axis) input: encoder TPDO -> belt travel -> estimate for the setpoint.

Time axis: the encoder samples 6004h at SYNC k (time t_k) and its TPDO arrives in cycle k;
the setpoint computed in cycle k is applied by the drives at SYNC k+1 and reached
``drive_delay_cycles`` (d) later.  So the estimator
(:class:`controller.tracking.MasterEstimator`, quadratic least squares over ``window``
samples) predicts ``lead_samples = 1 + d`` samples past the newest one: the master state for
time t_{k+1+d}.

Staleness: the raw value is stored with the cycle in which it arrived (a snapshot taken in
the receive callback).  In a cycle without a fresh sample the estimator gets its own
prediction as a virtual sample (so its samples stay one period apart) and ``silent`` counts
up; after ``silent_cycles`` the cycle de-syncs on that extrapolated master
(:mod:`controller.canopen.master.cycle`).  When samples come back the estimator restarts from them.

With ``conveyor.conditioning`` the belt goes through a :class:`MasterConditioner` instead
(docs/spec/master-conditioning.md): counts of 1/counts_per_mm, the sample taken at this
cycle's SYNC (latency 0, its lateness ``sync_late_s`` the known jitter), predicted
``lead`` cycles ahead, within the frame's VelocityMax/AccelerationMax (the tracker's
``master_max_trans``) and ``jerk_max``; a missing sample coasts; an outlier is reported
("outlier") and coasted over; ``max_outliers`` in a row are "lost" (the controller de-syncs
with MASTER_LOST), and the conditioner starts again from the next sample.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from ...kinematics import EncoderScale
from ...limits import Limits
from ...tracking import MasterEstimate, MasterEstimator
from ...tracking.conditioning import (ConditionedMaster, ConditioningParams, EncoderModel,
                                      EventKind, MasterConditioner)
from ..config.concise import effective_pdos
from ..io.transport import Transport
from ..protocol.frames import FrameHygiene
from ..protocol.pdo import PdoCodec

if TYPE_CHECKING:
    from ..config import ControllerConfig
    from ..config.tracking import ConveyorConfig


class MasterInput:
    """One master encoder's input: its TPDO, counts -> mm, the estimator or conditioner.

    ``encoder``: which one (a cell has several, ``.tracking.cell.encoders``; one input each,
    on the same transport); default ``.tracking.conveyor``."""

    def __init__(self, cfg: ControllerConfig, transport: Transport,
                 hygiene: FrameHygiene | None = None,
                 encoder: ConveyorConfig | None = None) -> None:
        assert cfg.tracking is not None  # a controller runs only with a .tracking section
        c = encoder if encoder is not None else cfg.tracking.conveyor
        self.conf = c
        self.label = cfg.label(c.node)
        pdo = effective_pdos(cfg)[c.node].find("tpdo", [(c.index, c.sub_index)])
        assert pdo is not None  # checked by the configuration loader
        self.codec = PdoCodec(pdo, cfg.ods[c.node])
        self._pos = self.codec.position(c.index, c.sub_index)
        self.scale = EncoderScale(c.counts_per_mm, c.modulus, c.sign)
        self.lead = 1 + cfg.tracking.drive_delay_cycles
        self.period_s = cfg.period_s
        #: the frame's VelocityMax [mm/s]: the fastest belt the lateness correction believes
        self.max_vel = cfg.tracking.tracker.master_max_trans.vel
        #: this cycle's SYNC on the nominal time axis [s] (periods counted, slips included)
        self._t_nominal_s = 0.0
        #: the fresh samples as measured: (when taken [s, nominal + lateness], belt [mm])
        self._measured: deque[tuple[float, float]] = deque(maxlen=max(3, c.window))
        self.estimator: MasterEstimator | None = None
        self.conditioner: MasterConditioner | None = None
        if c.conditioning is None:
            self.estimator = MasterEstimator(cfg.period_s, c.window,
                                             lead_samples=float(self.lead), degree=c.degree)
        else:
            cc = c.conditioning
            tc = cfg.tracking
            assert tc is not None  # a controller runs only with a .tracking section
            mt = tc.tracker.master_max_trans
            self.conditioner = MasterConditioner(ConditioningParams(
                cfg.period_s, EncoderModel(1.0 / c.counts_per_mm, 0),
                Limits(mt.vel, mt.acc, cc.jerk_max), lead_samples=float(self.lead),
                design=cc.design, jerk_reserve=cc.jerk_reserve, outlier_mm=cc.outlier_mm,
                max_outliers=cc.max_outliers))
        #: the conditioner's output of the last update (None with the estimator)
        self.conditioned: ConditionedMaster | None = None
        self.snapshot: tuple[int, int, int] | None = None  # (raw, t_ns, cycle)
        self.cycle = -1
        self.silent = 0
        self.lost = False
        self.belt_mm: float | None = None  # newest measured belt travel
        self.raw: int | None = None
        self.last_estimate: MasterEstimate | None = None  # of the last update
        self.hygiene = hygiene if hygiene is not None else FrameHygiene()
        self._size = self.codec.struct.size
        self._what = f"TPDO{pdo.number} of {self.label}"
        #: size [mm] of the last outlier (conditioner)
        self.outlier_mm = 0.0
        transport.subscribe(pdo.cob_id, self._on_tpdo)

    def _on_tpdo(self, can_id: int, data: bytes, t_ns: int) -> None:
        """The sample (a frame shorter than the mapping: dropped, counted, never unpacked)."""
        if len(data) != self._size and not self.hygiene.check_length(
                can_id, data, self._size, self._what, t_ns):
            return
        self.snapshot = (self.codec.unpack(data)[self._pos], t_ns, self.cycle)

    def fresh(self, cycle: int) -> bool:
        s = self.snapshot
        return s is not None and s[2] == cycle

    @property
    def ready(self) -> bool:
        """Enough samples for a full estimator window (the conditioner: warmed up) and not
        lost."""
        if self.conditioner is not None:
            return not self.lost and self.conditioned is not None and self.conditioned.valid
        est = self.estimator
        assert est is not None  # one of the two
        return not self.lost and est.samples >= est.window

    @property
    def velocity_known(self) -> bool:
        """The estimate's velocity means something (for the trace)."""
        if self.conditioner is not None:
            return self.conditioned is not None and self.conditioned.valid
        return self.estimator is not None and self.estimator.samples >= 3

    def skip(self, periods: int) -> None:
        """The time base slipped by ``periods`` (an overrun, no SYNC was sent): the estimator
        gets its own prediction for each of them, so that its samples stay one period
        apart (else the next real sample looks like a velocity jump)."""
        if self.conditioner is not None:
            self._t_nominal_s += periods * self.period_s
            for _ in range(periods):
                self.conditioner.update(None)  # coasts
            return
        est = self.estimator
        assert est is not None  # one of the two
        for _ in range(periods):
            t_nom = self._t_nominal_s
            self._t_nominal_s = t_nom + self.period_s
            if est.samples:
                est.push(self._coast(t_nom))

    def _coast(self, t_nom: float) -> float:
        """A virtual sample [mm] for a SYNC without one (missing, or skipped by an
        overrun): the belt at ``t_nom`` on the chord of the measured samples of the window
        (their velocity, within VelocityMax), else, before two, the estimator's own
        prediction.  Not the fit's quadratic prediction: pushed among real samples it fed
        its acceleration back (each real sample after a coast bent the fit, the next coast
        went further off: half the samples missing at 1 ms, a real-time run, 8 m/s² and
        then 1e25 mm within seconds).  A belt accelerating at 1000 mm/s² moves 12 um off
        the chord in 5 missing ms."""
        m = self._measured
        if len(m) >= 2:
            (t0, x0), (t1, x1) = m[0], m[-1]
            if t1 > t0:
                v = (x1 - x0) / (t1 - t0)
                v = self.max_vel if v > self.max_vel else -self.max_vel \
                    if v < -self.max_vel else v
                return x1 + v * (t_nom - t1)
        est = self.estimator
        assert est is not None  # (the estimator's path)
        return est.estimate(1.0 - est.lead).pos

    def update(self, cycle: int, sync_late_s: float = 0.0
               ) -> tuple[str | None, MasterEstimate | None]:
        """Take this cycle's sample; returns (event, estimate at the next SYNC).

        ``sync_late_s``: how late this cycle's SYNC went out [s].  The encoder samples when
        the SYNC arrives, so the sample is moved back to the nominal SYNC time with the
        estimated velocity (s - v * late): SYNC jitter would otherwise enter the estimate
        as position noise (0.3 mm for 1 ms late at 300 mm/s, and in a 1 ms quadratic fit
        an acceleration spike above the frame's AccelerationMax).  The velocity is the
        slope of the measured samples over the window against the times they were taken
        (nominal + lateness), not the estimate's: the estimate is fed by this very
        correction, a loop with a gain of (the fit's weight of the newest sample in the
        velocity) x lateness, 3.5 for 3 samples at 1 ms and 1 ms late, which diverged (a
        real-time run at 1 ms reached 1e32 mm and missed every item).  Within the frame's
        VelocityMax; the first late sample after a start is only timed, not fitted.
        event: None, "silent" (first cycle over the limit) or "back"; with the conditioner
        also "outlier" (``outlier_mm`` holds its size) and "lost".
        """
        if self.conditioner is not None:
            return self._update_conditioned(cycle, sync_late_s)
        event = None
        est = self.estimator
        assert est is not None  # one of the two
        t_nom = self._t_nominal_s
        self._t_nominal_s = t_nom + self.period_s
        snap = self.snapshot
        if snap is not None and snap[2] == cycle:  # (fresh() written out)
            raw = snap[0]
            if self.lost:
                self.lost = False
                est.reset()
                self._measured.clear()
                event = "back"
            self.raw = raw
            self.belt_mm = self.scale.belt_mm(raw)
            sample = self.belt_mm
            measured = self._measured
            measured.append((t_nom + sync_late_s, sample))
            fit = True
            if sync_late_s:
                if len(measured) < 2:
                    fit = False  # (the first after a start: only timed, not fitted)
                else:
                    (t0, x0), (t1, x1) = measured[0], measured[-1]
                    v = (x1 - x0) / (t1 - t0) if t1 > t0 else 0.0
                    v = self.max_vel if v > self.max_vel else -self.max_vel \
                        if v < -self.max_vel else v
                    sample -= v * sync_late_s
            if fit:
                est.push(sample)
            self.silent = 0
        else:
            self.raw = None
            self.silent += 1
            if est.samples:
                est.push(self._coast(t_nom))  # the position at t_k
            if self.silent >= self.conf.silent_cycles and not self.lost:
                self.lost = True
                event = "silent"
        self.last_estimate = est.estimate() if est.samples else None
        return event, self.last_estimate

    def _update_conditioned(self, cycle: int, sync_late_s: float
                            ) -> tuple[str | None, MasterEstimate | None]:
        event = None
        x = None
        snap = self.snapshot
        if snap is not None and snap[2] == cycle:  # fresh
            raw = snap[0]
            if self.lost and self.silent:
                event = "back"
            if self.silent:
                self.lost = False
            self.raw = raw
            self.belt_mm = x = self.scale.belt_mm(raw)
            self.silent = 0
        else:
            self.raw = None
            self.silent += 1
            if self.silent >= self.conf.silent_cycles and not self.lost:
                self.lost = True
                event = "silent"
        assert self.conditioner is not None  # the caller checked
        o = self.conditioner.update(x, sync_late_s)
        self.conditioned = o
        ev = o.event
        if ev is not None and event is None:
            if ev.kind == EventKind.OUTLIER:
                event = "outlier"
                self.outlier_mm = ev.size_mm
            elif ev.kind == EventKind.LOST:
                event = "lost"
                self.outlier_mm = ev.size_mm
                self.lost = True
            elif ev.kind == EventKind.READY and self.lost:
                self.lost = False
                event = "back"
        self.last_estimate = (MasterEstimate(o.pos, o.vel, o.acc, o.jerk)
                              if o.valid or o.status == o.status.LOST else None)
        return event, self.last_estimate
