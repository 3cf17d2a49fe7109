"""Mutated bus.yml, scenario and EDS files: does cantrack answer each with a clear error, or
accept it and do the right thing?  (The larger run of tests/test_mutants.py.)

    python benchmarks/mutants.py                        # 400 bus, 300 scenario, 150 EDS mutants
    python benchmarks/mutants.py --bus 1000 --scenario 1000 --eds 300 --seed 2 --json out.json
    python benchmarks/mutants.py --no-run               # loading only (no short run per mutant)

Families (``controller.testing.mutants``): ``bus`` (examples/bus/demo.yml), ``scenario``
(every examples/*.yaml in turn), ``eds`` (eds/cantrack-servo.eds and cantrack-encoder.eds,
loaded through a bus.yml that names them).  Each accepted mutant is also run briefly (the demo
for 0.3 s of machine time, the scenario in full) so that a value that loads but breaks the run
is found.  Prints the count per verdict and family and every mutant that is not an error or
accepted (traceback, unclear, wrong); exit code 1 if there is one.
"""

from __future__ import annotations

import argparse
import collections
import json
import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller.testing import mutants as mu
from controller.testing.mutant_runs import FAMILIES


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bus", type=int, default=400, help="bus.yml mutants (default 400)")
    p.add_argument("--scenario", type=int, default=300, help="scenario mutants (default 300)")
    p.add_argument("--eds", type=int, default=150, help="EDS mutants (default 150)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-run", action="store_true", help="judge loading only")
    p.add_argument("--json", metavar="FILE", help="every answer as JSON")
    p.add_argument("--show", type=int, default=60, help="findings printed (default 60)")
    args = p.parse_args(argv)
    rng = random.Random(args.seed)
    counts: dict[str, collections.Counter] = {}
    findings: list[mu.Answer] = []
    answers = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for family, n in (("bus", args.bus), ("scenario", args.scenario), ("eds", args.eds)):
            fam = FAMILIES[family](Path(tmp), run=not args.no_run)
            c = counts.setdefault(family, collections.Counter())
            for _ in range(n):
                a = fam.judge(fam.mutant(rng))
                c[a.verdict.value] += 1
                answers.append({"family": family, "what": a.mutant.what,
                                "verdict": a.verdict.value, "detail": a.detail})
                if not a.verdict.ok:
                    findings.append(a)
    wall = time.perf_counter() - t0
    print(f"seed {args.seed}, {sum(sum(c.values()) for c in counts.values())} mutants in "
          f"{wall:.0f} s" + (" (loading only)" if args.no_run else ""))
    verdicts = [v.value for v in mu.Verdict]
    print(f"{'family':<10}" + "".join(f"{v:>11}" for v in verdicts))
    for family, c in counts.items():
        print(f"{family:<10}" + "".join(f"{c[v]:>11}" for v in verdicts))
    for a in findings[:args.show]:
        print(a)
    if len(findings) > args.show:
        print(f"... and {len(findings) - args.show} more")
    if args.json:
        Path(args.json).write_text(json.dumps(answers, indent=1))
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
