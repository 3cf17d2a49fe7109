"""Configuration: ``bus.yml`` = Lely dcfgen's bus description + cantrack's dot sections.

- :mod:`.bus` — the dcfgen part (``options``, ``master``, slaves; strict);
- :mod:`.concise` — what dcfgen would write to each slave (SDOs, the PDOs after boot);
- :mod:`.busload` — the worst-case bus load of the configured PDOs;
- :mod:`.tracking` — ``.tracking`` (conveyor, axes, kinematics, tracker, timeouts);
- :mod:`.simulation` — ``.simulation`` (simulated encoder and drives);
- :mod:`.demo` — ``.demo`` (the pick-and-place demo's items and stations);
- :mod:`.load` — :func:`load_config`, all of it in order.

Layer ``config``: imports ``protocol`` and ``io`` (and the pure core), never the master, the
slaves or the applications (docs/architecture.md).
"""

from .bus import (
    ControllerConfig,
    MasterConfig,
    Options,
    PdoEntry,
    PdoSetting,
    SdoWrite,
    SlaveConfig,
)
from .load import load_config, parse_config

__all__ = ["ControllerConfig", "MasterConfig", "Options", "PdoEntry", "PdoSetting", "SdoWrite",
           "SlaveConfig", "load_config", "parse_config"]
