"""How close can any estimator follow a belt's jerk step through a quantised encoder?

Run from the repository root::

    python benchmarks/detection_bound.py            # the encoder benchmark's 9 cells
    python benchmarks/detection_bound.py --alpha 1e-5

docs/spec/master-conditioning.md#5.1.  A belt at a known state (the most favourable case:
any estimator facing the real problem, whose state before the step is itself uncertain,
does no better) steps its jerk by J = the frame's JerkMax at an unknown instant theta.
The samples after it differ from the no-step belt by s_i = J (t_i - theta)^3 / 6, seen in
the count's quantisation noise sigma = q / sqrt(12) (white: the arrival jitter dithers it).
n samples after the step the two hypotheses are d(n) = sqrt(sum s_i^2) / sigma apart
(their Mahalanobis distance); the setpoint is ``lead`` samples after the newest sample
(latency + lead of the benchmark: 2), where the two belts are
Delta(n) = J ((n + lead) T)^3 / 6 apart.  Two bounds per cell:

- *any causal estimator* (two-point, Le Cam): while d(n) <= 2 z_{0.99} = 4.65 the two
  hypotheses' laws overlap by more than 2 %, so no estimator can be within Delta/2 of the
  truth with probability 0.99 under both: the p99 error at that sample is >= Delta(n*)/2,
  n* the last n with d(n) <= 4.65, under the step or under the belt that did not step.
- *detect, then correct* (what the conditioner does, eq. 2.7-2.8): a test that signals a
  jerk step with a false-alarm probability ``alpha`` per sample needs, even knowing the
  onset (a matched filter; a test over unknown onsets needs more), d(n) >= z_alpha + z_beta
  to detect it with probability beta; until then the estimate is the no-step belt's, off
  by Delta(n) at the setpoint.  Printed for beta = 0.5 and 0.9.

Onsets are taken half a sample before a sample (the mean case).  Pure arithmetic.
"""

from __future__ import annotations

import argparse
import math
from statistics import NormalDist

COUNTS_MM = (0.001, 0.01, 0.05)
CYCLES_S = (0.001, 0.002, 0.004)
JERK = 5000.0  # the benchmark frame's JerkMax [mm/s^3]
LEAD = 2  # samples from the newest sample's instant to the setpoint's (latency 1 + lead 1)


def distance(n: int, T: float, count_mm: float, jerk: float = JERK) -> float:
    """d(n): the no-step and step belts n samples after the step, in noise sigmas."""
    sigma = count_mm / math.sqrt(12.0)
    return math.sqrt(sum((jerk * ((i - 0.5) * T) ** 3 / 6.0) ** 2
                         for i in range(1, n + 1))) / sigma


def gap(n: int, T: float, jerk: float = JERK, lead: int = LEAD) -> float:
    """Delta(n) [mm]: the two belts at the setpoint time, n samples after the step."""
    return jerk * ((n - 0.5 + lead) * T) ** 3 / 6.0


def first_n(T: float, count_mm: float, d_min: float) -> int:
    n = 1
    while distance(n, T, count_mm) < d_min:
        n += 1
    return n


def bounds(T: float, count_mm: float, alpha: float) -> dict:
    z = NormalDist().inv_cdf
    d2 = 2.0 * z(0.99)
    n2 = first_n(T, count_mm, d2) - 1  # the last n with d(n) <= 4.65
    out = {"two_point_mm": gap(max(n2, 0), T) / 2.0, "two_point_n": n2}
    for beta in (0.5, 0.9):
        n = first_n(T, count_mm, z(1.0 - alpha) + z(beta))
        out[f"delay_{beta}_s"] = (n - 0.5) * T
        out[f"detect_{beta}_mm"] = gap(n, T)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--alpha", type=float, default=1e-4,
                    help="false alarms per sample of the detect-then-correct test")
    args = ap.parse_args(argv)
    print(f"jerk step {JERK:g} mm/s^3, setpoint {LEAD} samples after the newest sample, "
          f"false alarms {args.alpha:g} per sample\n")
    print("| count | cycle | any estimator: p99 error >= [mm] | detection delay, beta 0.5 / 0.9 "
          "[ms] | detect-then-correct: error at detection, beta 0.5 / 0.9 [mm] |")
    print("|---|---|---|---|---|")
    for count in COUNTS_MM:
        for T in CYCLES_S:
            b = bounds(T, count, args.alpha)
            print(f"| {count * 1e3:g} µm | {T * 1e3:g} ms | {b['two_point_mm']:.3f} | "
                  f"{b['delay_0.5_s'] * 1e3:.0f} / {b['delay_0.9_s'] * 1e3:.0f} | "
                  f"{b['detect_0.5_mm']:.3f} / {b['detect_0.9_mm']:.3f} |")


if __name__ == "__main__":
    main()
