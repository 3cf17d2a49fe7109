"""The CANopen shell of cantrack: configuration, boot, cycle, supervision, simulated devices.

Modules (one concept each):

- configuration: :mod:`.config` (bus.yml = Lely dcfgen format + dot sections, strict),
  :mod:`.tracking_config` (``.tracking``), :mod:`.demo_config` (``.demo``),
  :mod:`.yamlmarks` (YAML with line marks, key-by-key validation), :mod:`.od` (EDS object
  dictionaries), :mod:`.concise` (the SDO writes dcfgen would generate), :mod:`.pdo`
  (configured PDOs, packing), :mod:`.busload` (worst-case bus load);
- protocol pieces: :mod:`.cia402` (drive state machine, shared with the simulated drive),
  :mod:`.sdo` (expedited SDO client), :mod:`.sync` (SYNC producer with counter),
  :mod:`.supervision` (heartbeat and EMCY consumers), :mod:`.events`;
- time and frames: :mod:`.clock` (stepped / real-time), :mod:`.transport` (stepped world,
  real-time transport, device thread), :mod:`.canbus` (opening a real bus like python-can's
  tools), :mod:`.world` (a simulated bus: devices + transport + bus log);
- the controller: :mod:`.boot`, :mod:`.axisio` (one drive's PDOs), :mod:`.masterio` (the
  encoder input and estimator), :mod:`.app` (what is tracked), :mod:`.cycle` (the cyclic
  controller), :mod:`.report` (status line, summary, telemetry, plot);
- :mod:`.devices` — simulated encoder and drives (python canopen LocalNodes);
- :mod:`.demo` — the pick-and-place sequence; ``cmd_demo``, ``cmd_run``, ``cmd_sim`` — the
  ``cantrack demo``/``run``/``sim-devices`` commands; :mod:`.testing` — test support.

Unit legend: mm, mm/s, mm/s^2 (deg for the tool angle c) at the core; counts only in
:mod:`controller.kinematics.counts`; time in integer ns of the controller clock (``_ns``), s
in configuration and reports (``_s``), us in timing figures (``_us``).
"""
