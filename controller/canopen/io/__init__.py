"""Time and frames: the lowest CANopen layer (no CANopen knowledge above CAN frames).

- :mod:`.clock` — stepped and real-time clocks (integer ns);
- :mod:`.transport` — the stepped world, the real-time transport, the device thread;
- :mod:`.canbus` — opening a real bus like python-can's tools (flags, config, env vars);
- :mod:`.files` — strict JSON written atomically (run reports, readiness files).

Layer ``io``: imports nothing of the CANopen shell (docs/architecture.md).
"""
