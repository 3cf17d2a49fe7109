"""cantrack: conveyor tracking for CANopen CiA 402 drives.

Unit legend (used in every module, Klipper-style):
    ``*_mm``  position in mm          ``*_deg`` angle in degrees
    ``vel``   mm/s or deg/s           ``acc``   mm/s^2 or deg/s^2
    ``jerk``  mm/s^3 or deg/s^3       ``*_s``   time in seconds
Drive counts exist only at the drive boundary (``controller.kinematics``).

Time domains: the core counts *samples* (integer k, time k*T); the shells
(CAN controller, FMU, simulator) own clocks and convert.
"""

__version__ = "0.1.0"
