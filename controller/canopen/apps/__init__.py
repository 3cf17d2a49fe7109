"""Applications of the controller: what is tracked or moved, and the reports of a run.

- :mod:`.demo` — the pick-and-place sequence (conveyor cell with items);
- :mod:`.axis_motion` — axis jobs (GotoY and drive homing, point-to-point, jog) and their API;
- :mod:`.record` — recording and replaying an encoder stream through the controller;
- :mod:`.report` — status line, summary, telemetry, plot of a run.

Layer ``apps``: the top CANopen layer, imports all below (docs/architecture.md).
"""
