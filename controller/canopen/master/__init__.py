"""The controller (the CANopen master): boot, the cyclic controller, SYNC, supervision.

- :mod:`.boot` — NMT and SDO configuration of each slave (the concise DCF), the boot report;
- :mod:`.cycle` — :class:`~.cycle.Controller`: one SYNC period after the other;
- :mod:`.sync` — the SYNC producer (with counter);
- :mod:`.supervision` — heartbeat and EMCY consumers;
- :mod:`.events` — the event log;
- :mod:`.axisio`, :mod:`.masterio` — one drive's PDOs; the encoder input and its estimator;
- :mod:`.source` — the setpoint-source protocol: the frozen context the cycle hands a source
  each SYNC, the setpoints, typed status and requests it returns;
- :mod:`.checkbus` — compare a bus with its configuration;
- :mod:`.plc_node` — the controller's own CANopen node (for a PLC).

Layer ``master``: imports ``slave``, ``config``, ``protocol``, ``io`` (docs/architecture.md).
"""

from ... import tracking as _tracking  # noqa: F401 -- first: chooses compiled or pure
