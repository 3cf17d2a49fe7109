"""The setpoint sources of the controller (what is tracked or moved) and the reports of a run.

- :mod:`.follow` — conveyor following (:class:`~.follow.ConveyorFollow`);
- :mod:`.demo` — the pick-and-place sequence (conveyor cell with items);
- :mod:`.axis_jobs` — axis jobs (GotoY and drive homing, point-to-point, jog);
- :mod:`.axis_controller` — the jobs of a session as one setpoint source
  (:class:`~.axis_controller.JobSequence`) and the cycle running it
  (:class:`~.axis_controller.MotionController`, :func:`~.axis_controller.run_jobs`);
- :mod:`.axis_motion` — the Python API: ``home``, ``move``, ``jog``;
- :mod:`.record` — recording and replaying an encoder stream through the controller;
- :mod:`.report` — status line, summary, telemetry, plot of a run.

Layer ``apps``: the top CANopen layer, imports all below (docs/architecture.md).
"""

from ... import tracking as _tracking  # noqa: F401 -- first: chooses compiled or pure
