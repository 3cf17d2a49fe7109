"""``cantrack simulate SCENARIO.yaml [-o OUT.csv] [--plot [PNG]] [--quiet] [--record PREFIX]``.

Runs the scenario, writes the CSV trace (default: ``<scenario stem>_trace.csv`` in the current
directory), prints the summary and, with ``--plot``, writes a PNG (default: the trace path
with ``.png``).  Errors (invalid scenario, unreadable files) are raised as
``CantrackError``/``OSError``; ``controller.cli`` prints them as one line, exit code 2.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Sequence

from ..errors import ConfigError

log = logging.getLogger(__name__)


def build_parser(prog: str = "cantrack simulate") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Run a conveyor-tracking scenario offline through the tracking core: "
                    "CSV trace, summary, optional PNG plot.",
        epilog="The scenario schema is documented in examples/README.md and in "
               "controller.simulate.scenario.")
    parser.add_argument("scenario", type=Path, metavar="SCENARIO.yaml",
                        help="the scenario file")
    parser.add_argument("-o", "--output", type=Path, metavar="OUT.csv",
                        help="CSV trace (default: ./<scenario stem>_trace.csv)")
    parser.add_argument("--plot", nargs="?", const="", default=None, metavar="PNG",
                        help="also write a PNG plot (default: the trace path with .png); "
                             "put it after SCENARIO.yaml or give PNG")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="print nothing (errors still go to stderr)")
    parser.add_argument("--record", type=Path, metavar="PREFIX",
                        help="conveyor scenarios: also write PREFIX_triggers.csv (and, with an "
                             "encoder, PREFIX_encoder.csv) for a deterministic replay")
    return parser


def main(argv: Sequence[str] | None = None, prog: str = "cantrack simulate") -> int:
    args = build_parser(prog).parse_args(argv)
    from .runner import run_scenario
    from .summary import format_summary
    from .trace import write_trace

    result = run_scenario(args.scenario)
    out = args.output or Path.cwd() / f"{args.scenario.stem}_trace.csv"
    write_trace(result, out)
    log.info("trace written to %s", out)
    png = None
    if args.plot is not None:
        from .plot import plot_result

        png = Path(args.plot) if args.plot else out.with_suffix(".png")
        plot_result(result, png)
        log.info("plot written to %s", png)
    logs = ()
    if args.record is not None:
        from .conveyor import ConveyorResult, write_logs

        if not isinstance(result, ConveyorResult):
            raise ConfigError("--record applies to conveyor scenarios only (a 'conveyor' "
                              "section)", file=str(args.scenario))
        logs = tuple(p for p in write_logs(result, args.record) if p is not None)
    if not args.quiet:
        print(format_summary(result))
        print()
        print(f"Trace      {out}")
        if png is not None:
            print(f"Plot       {png}")
        for p in logs:
            print(f"Log        {p}")
    return 0
