"""``cantrack check-bus CONFIG``: scan the bus and compare every node with the configuration.

Reads each configured node's (and, with ``--scan 1-127``, every answering node's) identity
(1000h, 1018h) and NMT state (heartbeat), compares them with the bus.yml and the EDS files,
reads back the PDO communication and mapping objects (1400h/1600h, 1800h/1A00h) and prints
what differs (:mod:`controller.canopen.master.checkbus`).  Listens and reads only: no NMT command, no
SDO write.  Exit code 0 when everything matches, 1 when something differs or a node is
missing, 2 on an error (configuration, bus).
"""

from __future__ import annotations

import argparse
import json

from ..canopen.config import load_config
from ..canopen.io import canbus
from ..canopen.io.transport import RealtimeTransport
from ..canopen.master.checkbus import check_bus, parse_scan
from ..errors import ConfigError
from .common import add_bus_arguments


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="bus.yml (slaves, EDS files, PDOs)")
    add_bus_arguments(p)
    p.add_argument("--scan", metavar="A-B", help="also look for nodes in this node-ID range "
                   "(e.g. 1-127): an answering node that is not configured is reported")
    p.add_argument("--listen", type=float, metavar="S",
                   help="listen this long for heartbeats (default 1.5 x the longest "
                        "configured heartbeat period, at least 0.5 s)")
    p.add_argument("--sdo-timeout", type=float, metavar="S", help="SDO time-out [s]")
    p.add_argument("--no-pdos", action="store_true", help="do not read the PDO objects")
    p.add_argument("--json", metavar="FILE", help="also write the result as JSON")
    return p


def main(argv: list[str] | None = None, prog: str = "cantrack check-bus") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_config(args.config)
    try:
        scan = parse_scan(args.scan) if args.scan else None
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    transport = RealtimeTransport(canbus.open_bus(args, cfg.bitrate))
    try:
        result = check_bus(cfg, transport, scan=scan, listen_s=args.listen,
                           sdo_timeout_s=args.sdo_timeout, pdos=not args.no_pdos)
    finally:
        transport.close()
    print(result.format())
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"ok": result.ok, "nodes": [
                {"node_id": n.node_id, "name": n.name, "answered": n.answered,
                 "nmt_state": n.nmt_state, "identity": n.identity, "names": n.names,
                 "differences": [vars(d) for d in n.differences]} for n in result.nodes]},
                f, indent=1)
    return 0 if result.ok else 1
