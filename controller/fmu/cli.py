"""The ``cantrack fmu`` sub-commands (registered by ``controller/cli/__init__.py``).

Registration in the main parser::

    from controller.fmu.cli import add_parser
    add_parser(subparsers)          # adds "fmu" with build / check / crosscheck / cosim
    ...
    args = parser.parse_args()
    return args.func(args)          # "fmu" sets func=main_fmu; main_fmu returns the exit code

Also runnable on its own: ``python -m controller.fmu build -o DIR``.

Exit codes: 0 success; 1 the check or comparison found problems; 2 usage or build error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``fmu`` command (with its sub-commands) to an ``add_subparsers()`` object."""
    fmu = subparsers.add_parser(
        "fmu", help="build and check the CanTracker FMU (FMI 2.0 Co-Simulation)",
        description="Build and check CanTracker.fmu, the tracker as an FMI 2.0 Co-Simulation "
                    "FMU (pythonfmu).")
    _add_subcommands(fmu)
    fmu.set_defaults(func=main_fmu)
    return fmu


def _add_subcommands(fmu: argparse.ArgumentParser) -> None:
    sub = fmu.add_subparsers(dest="fmu_command",
                             metavar="{build,check,crosscheck,cosim,doctor}")
    sub.required = True
    b = sub.add_parser("build", help="write DIR/CanTracker.fmu",
                       description="Write DIR/CanTracker.fmu (and with --system the conveyor "
                                   "FMU and OspSystemStructure.xml).")
    b.add_argument("-o", "--output", "--dest", dest="output", default=".", metavar="DIR",
                   help="output folder (default: the current folder)")
    b.add_argument("--system", action="store_true",
                   help="also write CanConveyor.fmu and OspSystemStructure.xml (libcosim)")
    b.add_argument("--fmi3", action="store_true",
                   help="also write CanTracker3.fmu (FMI 3.0, needs pythonfmu3)")
    c = sub.add_parser("check", help="validate an FMU and run a smoke co-simulation",
                       description="Validate FILE.fmu (fmpy validate, fmutool -check) and, for "
                                   "a CanTracker FMU (FMI 2.0 or 3.0), run a smoke "
                                   "co-simulation in fmpy "
                                   "(sync, bit-identity with the core, step refusal, state).")
    c.add_argument("file", metavar="FILE.fmu")
    c.add_argument("--planner", type=int, choices=(0, 1), default=None,
                   help="planner for the smoke run (default: the FMU's start value)")
    c.add_argument("--no-smoke", action="store_true", help="only validate")
    c.add_argument("--no-fmutool", action="store_true", help="skip fmutool -check")
    x = sub.add_parser("crosscheck", help="write the FMI cross-check files",
                       description="Write CanTracker_in.csv, CanTracker_ref.csv and "
                                   "CanTracker_ref.opt (reference from the core) into DIR; "
                                   "with --fmu also simulate that FMU with them and compare.")
    x.add_argument("-o", "--output", dest="output", default=".", metavar="DIR")
    x.add_argument("--fmu", default=None, metavar="FILE.fmu",
                   help="simulate this FMU with the inputs and compare with the reference")
    s = sub.add_parser("cosim", help="run conveyor -> tracker in libcosim and compare offline",
                       description="Run OspSystemStructure.xml with libcosimpy and compare the "
                                   "tracker's outputs with the core run offline.")
    s.add_argument("system", metavar="OspSystemStructure.xml")
    sub.add_parser("doctor", help="what this machine gives a host of the FMUs",
                   description="Check this Python as the FMUs' Python (numpy, ruckig, shared "
                               "libpython for hosts without Python) and print what a host "
                               "must set.  Exit 1 if something needed is missing.")


def main_fmu(args: argparse.Namespace) -> int:
    """Run an ``fmu`` sub-command; returns the exit code."""
    from ..errors import CantrackError

    try:
        return _COMMANDS[args.fmu_command](args)
    except CantrackError as exc:
        print(f"cantrack fmu {args.fmu_command}: {exc}", file=sys.stderr)
        return 2


def _build(args) -> int:
    from .build import build_conveyor_fmu, build_tracker_fmu

    out = Path(args.output)
    print(build_tracker_fmu(out))
    if args.system:
        from .osp import write_system_structure
        print(build_conveyor_fmu(out))
        print(write_system_structure(out))
    if args.fmi3:
        from .build import build_tracker_fmu3
        print(build_tracker_fmu3(out))
    return 0


def _check(args) -> int:
    from .check import check_fmu

    report = check_fmu(args.file, smoke=not args.no_smoke, planner=args.planner,
                       fmutool=not args.no_fmutool)
    print(report.format())
    return 0 if report.passed else 1


def _crosscheck(args) -> int:
    from .crosscheck import compare_fmu, write_crosscheck

    paths = write_crosscheck(args.output)
    for p in paths:
        print(p)
    if args.fmu:
        problems = compare_fmu(args.fmu, args.output)
        print("\n".join(problems) if problems else
              f"{args.fmu}: outputs bit-identical to {paths[1].name}")
        return 1 if problems else 0
    return 0


def _cosim(args) -> int:
    from .osp import compare_with_offline

    problems, summary = compare_with_offline(args.system)
    print(summary)
    print("\n".join(problems) if problems else "libcosim run bit-identical to the offline run")
    return 1 if problems else 0


def _doctor(args) -> int:
    from .doctor import diagnose

    report = diagnose()
    print(report.format())
    return 0 if report.ok else 1


_COMMANDS = {"build": _build, "check": _check, "crosscheck": _crosscheck, "cosim": _cosim,
             "doctor": _doctor}


def main(argv: list[str] | None = None, prog: str = "python -m controller.fmu") -> int:
    """``cantrack fmu ...`` / ``python -m controller.fmu ...``: build and check the FMU."""
    parser = argparse.ArgumentParser(prog=prog,
                                     description="Build and check the CanTracker FMU.")
    _add_subcommands(parser)
    args = parser.parse_args(argv)
    return main_fmu(args)
