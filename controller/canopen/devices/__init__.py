"""Simulated CANopen devices: python canopen ``LocalNode``s built from the EDS files in eds/.

- :mod:`.base` — :class:`SimNode`: NMT slave, heartbeat, PDOs from the OD, EMCY, fault
  injection (what ``LocalNode`` lacks);
- :mod:`.encoder` — :class:`SimEncoder`, a CiA 406 conveyor encoder;
- :mod:`.drive` — :class:`SimDrive`, a CiA 402 servo drive (state machine, CSP, servo model);
- :mod:`.rack` — :class:`DeviceRack`: all simulated devices of a bus.yml on one bus;
- :mod:`.simconfig` — the ``.simulation:`` section of bus.yml.
"""

from .base import SimNode
from .drive import DriveParams, SimDrive
from .encoder import EncoderParams, SimEncoder
from .rack import DeviceRack

__all__ = ["DeviceRack", "DriveParams", "EncoderParams", "SimDrive", "SimEncoder", "SimNode"]
