"""CiA 301/402 protocol pieces, no configuration, no threads: the lowest CANopen layer but
``io``.

- :mod:`.od` — EDS object dictionaries (python canopen's) and their data types;
- :mod:`.pdo` — PDO parameters, a configured PDO (:class:`~.pdo.PdoSpec`), packing
  (:class:`~.pdo.PdoCodec`);
- :mod:`.sdo` — the SDO client (expedited and segmented) on a :class:`~..io.transport.Transport`;
- :mod:`.cia402` — the CiA 402 drive state machine (shared by the master and the simulated drive).

Layer ``protocol``: imports only ``io`` (docs/architecture.md).
"""
