"""Test infrastructure: real SocketCAN (vcan natively or in a throwaway VM), bus capture and
independent CANopen decoding, and the pytest plugin for the ``vcan`` and ``hil`` tiers.

- :func:`run_with_vcan` / :func:`run_in_vm` / :func:`vcan_available` / :func:`vm_available`
  (:mod:`.vcan`, :mod:`.vm`): run a command on a real ``vcan0``.
- :mod:`.candump`: capture a bus with can-utils' ``candump -L``.
- :mod:`.capture`: candump log → pcap (link type 227) → tshark's CANopen dissector →
  :class:`FrameClass` per frame; SYNC period/counter and PDO order checks; a built-in CiA 301
  decoder (:func:`decode_messages`) for machines without tshark (``decoder="auto"``).
- :mod:`.e2e`: the end-to-end checks of a ``cantrack run`` (capture and report) shared by the
  ``vcan`` controller tier and the ``hil`` tier (``tests/test_hil.py``).
- :mod:`.bus_selftest`: a two-process CANopen exchange (canopen LocalNodes from our EDS files)
  used by the first ``vcan`` tier.
- :mod:`.pytest_plugin`: ``--can-interface``, ``--can-channel``, ``--can-bitrate``,
  ``--bus-config``, ``--vcan-mode``; markers ``vcan`` and ``hil``; fixtures.

See ``docs/hil.md``.
"""

from .capture import (
                      FrameClass,
                      Kind,
                      SyncStats,
                      classify_capture,
                      decode_messages,
                      pdo_order_per_sync,
                      pick_decoder,
                      problems,
                      sync_period_stats,
                      write_pcap,
)
from .vcan import run_with_vcan, vcan_available
from .vm import VmError, VmResult, VmTimeoutError, run_in_vm, vm_available

__all__ = ["FrameClass", "Kind", "SyncStats", "VmError", "VmResult", "VmTimeoutError",
           "classify_capture", "decode_messages", "pdo_order_per_sync", "pick_decoder",
           "problems", "run_in_vm", "run_with_vcan",
           "sync_period_stats", "vcan_available", "vm_available", "write_pcap"]
