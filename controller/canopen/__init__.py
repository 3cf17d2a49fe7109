"""The CANopen shell of cantrack, in layers (docs/architecture.md; each imports only those
below it, checked by tests/test_architecture.py):

- :mod:`.io` — clocks, transports (stepped / real time), opening a real bus, atomic files;
- :mod:`.protocol` — CiA 301/402: object dictionaries, PDO codec, SDO client, 402 state machine;
- :mod:`.config` — bus.yml (Lely dcfgen format + ``.tracking``/``.simulation``/``.demo``),
  the concise DCF, the bus load;
- :mod:`.slave` — the slave-node engine and the simulated encoder and drives, the simulated bus;
- :mod:`.master` — boot, the cyclic controller, SYNC, supervision, events, axis and master
  I/O, check-bus, the controller's own (PLC) node;
- :mod:`.apps` — what is tracked or moved: conveyor pick-and-place, axis jobs, record and
  replay, run reports;
- :mod:`.testing` — test support (stepped worlds for the test suite).

The ``cantrack`` commands that use them are in :mod:`controller.cli`.

Unit legend: mm, mm/s, mm/s^2 (deg for the tool angle c) at the core; counts only in
:mod:`controller.kinematics.counts`; time in integer ns of the controller clock (``_ns``), s
in configuration and reports (``_s``), us in timing figures (``_us``).
"""
