"""CANopen slaves: the slave-node engine and the simulated devices (python canopen
``LocalNode``s built from the EDS files in eds/).

- :mod:`.node` — :class:`SimNode`: NMT slave, heartbeat, PDOs from the OD, EMCY, fault
  injection (what ``LocalNode`` lacks);
- :mod:`.encoder` — :class:`SimEncoder`, a CiA 406 conveyor encoder;
- :mod:`.drive` — :class:`SimDrive`, a CiA 402 servo drive (state machine, CSP, servo model);
- :mod:`.rack` — :class:`DeviceRack`: all simulated devices of a bus.yml on one bus;
- :mod:`.world` — :class:`SimWorld`: a simulated bus (devices + transport + bus log).

Their parameters (:class:`DriveParams`, :class:`EncoderParams`) are configuration values, in
:mod:`controller.canopen.config.simulation` (the ``.simulation:`` section of bus.yml).

Layer ``slave``: imports ``config``, ``protocol``, ``io`` (docs/architecture.md).

The per-SYNC modules (``engine``, ``node``, ``drive``, ``encoder``, ``rack``) are compiled
with the tracking core (docs/architecture.md "Compiled core"); ``plc`` and ``world`` stay
Python.
"""

# first: controller.tracking chooses compiled or pure for this package's modules too
# (docs/architecture.md "Compiled core"), before one of them is loaded
from ... import tracking as _tracking  # noqa: F401
from ..config.simulation import DriveParams, EncoderParams
from .drive import SimDrive
from .encoder import SimEncoder
from .node import SimNode
from .rack import DeviceRack

__all__ = ["DeviceRack", "DriveParams", "EncoderParams", "SimDrive", "SimEncoder", "SimNode"]
