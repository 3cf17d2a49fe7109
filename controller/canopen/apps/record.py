"""Record a bus session and replay a recorded encoder stream into the controller.

Recording (``cantrack record``): every frame of a bus into one of python-can's log formats,
chosen by the file's extension through ``can.Logger`` (candump ``.log``, ``.asc``, ``.blf``,
``.csv``, ``.trc``, ...).  Any such file (and a ``candump -L`` capture) is read back with
``can.LogReader``.

Replay (``cantrack replay``): the frames of a session give, per SYNC k (the k-th SYNC frame of
the recording, counted from the controller's first), the master sample the encoder sent after
it (:func:`encoder_stream`; ``None`` when it sent none) and the RPDO each drive got after it
(:func:`drive_setpoints`: controlword, 607Ah).  :func:`replay` runs the same controller cycle
in stepped time on a simulated bus whose encoder sends the recorded samples, SYNC by SYNC, and
whose drives are the simulated ones of the configuration; the setpoints it sends are then
compared with the recorded ones (:func:`compare`).  For a session recorded in stepped time
(``cantrack demo``, tests) with the same configuration and application, the replay reproduces
every 607Ah bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import can

from ...errors import CanError
from ..config.concise import effective_pdos
from ..protocol.pdo import PdoCodec

if TYPE_CHECKING:
    from ..config import ControllerConfig
    from ..master.source import SetpointSource
    from ..master.cycle import Controller

SYNC_COB = 0x80

Frame = tuple[int, bytes]  # (COB-ID, data)


#: the log formats read and written (python-can's ``LogReader``/``Logger`` by extension)
LOG_FORMATS = ".log (candump), .asc, .blf, .csv, .trc"


def read_frames(path: str | Path) -> list[Frame]:
    """The standard data frames of a python-can log (any format ``can.LogReader`` reads).

    A file python-can cannot read (unknown extension, corrupt or not a log) is a CanError
    naming the file and the frame it stopped at; OSError (no such file) propagates.
    """
    out: list[Frame] = []
    try:
        for msg in can.LogReader(str(path)):
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            out.append((msg.arbitration_id, bytes(msg.data)))
    except OSError:
        raise
    except Exception as exc:  # noqa: BLE001 -- python-can's readers raise many kinds
        where = f" after {len(out)} frames" if out else ""
        raise CanError(f"{path}: cannot read it as a CAN log{where} ({type(exc).__name__}: "
                       f"{exc}); formats: {LOG_FORMATS}") from None
    return out


def _per_sync(frames: Iterable[Frame], cob: int) -> list[bytes | None]:
    """Per SYNC, the data of the first frame with ``cob`` before the next SYNC (or None)."""
    out: list[bytes | None] = []
    for can_id, data in frames:
        if can_id == SYNC_COB:
            out.append(None)
        elif can_id == cob and out and out[-1] is None:
            out[-1] = data
    return out


def encoder_stream(cfg: ControllerConfig, frames: Iterable[Frame]) -> list[int | None]:
    """The conveyor encoder's raw sample after each SYNC of ``frames`` (None: none sent)."""
    c = cfg.tracking.conveyor
    pdo = effective_pdos(cfg)[c.node].find("tpdo", [(c.index, c.sub_index)])
    codec = PdoCodec(pdo, cfg.ods[c.node])
    pos = codec.position(c.index, c.sub_index)
    return [None if d is None else int(codec.unpack(d)[pos])
            for d in _per_sync(frames, pdo.cob_id)]


def drive_setpoints(cfg: ControllerConfig, frames: Sequence[Frame]) -> dict[str, list]:
    """Per tracking axis: per SYNC, (controlword, 607Ah) of the RPDO sent after it, or None."""
    out = {}
    pdos = effective_pdos(cfg)
    for a in cfg.tracking.axes:
        rp = pdos[a.node].find("rpdo", [(0x6040, 0), (0x607A, 0)])
        codec = PdoCodec(rp, cfg.ods[a.node])
        i_cw, i_t = codec.position(0x6040), codec.position(0x607A)
        out[a.name] = [None if d is None else (int(v[i_cw]), int(v[i_t]))
                       for d in _per_sync(frames, rp.cob_id)
                       for v in [codec.unpack(d) if d is not None else None]]
    return out


class StreamPlayer:
    """Makes a simulated encoder send recorded samples: the n-th SYNC it sees -> sample n
    (muted PDOs for a SYNC without one, and after the end of the stream)."""

    def __init__(self, encoder, stream: Sequence[int | None], index: int, sub: int) -> None:
        self.encoder = encoder
        self.stream = list(stream)
        self.index, self.sub = index, sub
        self.n = 0

    def __call__(self, now_ns: int) -> None:
        k = self.n
        self.n += 1
        v = self.stream[k] if k < len(self.stream) else None
        if v is None:
            self.encoder.pdos_muted = True
        else:
            self.encoder.pdos_muted = False
            self.encoder.store(self.index, self.sub, v)


@dataclass
class Comparison:
    cycles: int                       # SYNCs compared (in both)
    recorded: int                     # SYNCs in the recording
    replayed: int                     # SYNCs of the replay
    setpoints: int                    # RPDOs compared (recorded and replayed)
    mismatches: list[tuple[str, int, object, object]] = field(default_factory=list)

    @property
    def exact(self) -> bool:
        return not self.mismatches and self.setpoints > 0

    def format(self, limit: int = 10) -> str:
        head = (f"{self.setpoints} setpoints in {self.cycles} SYNC cycles compared "
                f"(recorded {self.recorded}, replayed {self.replayed}): ")
        if self.exact:
            return head + "all identical (bit-exact 6040h and 607Ah)"
        lines = [head + f"{len(self.mismatches)} differ"]
        for axis, k, rec, rep in self.mismatches[:limit]:
            lines.append(f"  SYNC {k} axis {axis}: recorded {rec}, replayed {rep}")
        return "\n".join(lines)


def compare(recorded: dict[str, list], replayed: dict[str, list]) -> Comparison:
    n_rec = max((len(v) for v in recorded.values()), default=0)
    n_rep = max((len(v) for v in replayed.values()), default=0)
    n = min(n_rec, n_rep)
    c = Comparison(n, n_rec, n_rep, 0)
    for axis, rec in recorded.items():
        rep = replayed.get(axis, [])
        for k in range(n):
            a = rec[k] if k < len(rec) else None
            b = rep[k] if k < len(rep) else None
            if a is None and b is None:
                continue
            c.setpoints += 1
            if a != b:
                c.mismatches.append((axis, k, a, b))
    if n_rec != n_rep:
        c.mismatches.append(("*", n, f"{n_rec} SYNC", f"{n_rep} SYNC"))
    return c


def replay(cfg: ControllerConfig, stream: Sequence[int | None],
           source: SetpointSource | None = None,
           setup: Callable[[Controller, object], None] | None = None,
           max_cycles: int | None = None) -> tuple[Controller, list[Frame]]:
    """Run the controller in stepped time with the encoder sending ``stream`` (one sample per
    SYNC); returns the controller and every frame of the replayed bus.

    ``setup(ctl, world)`` is called after the boot and the cycle start (e.g. the demo's
    photo-eye); ``max_cycles`` defaults to the length of the stream.
    """
    from ..master.cycle import Controller
    from ..slave.world import SimWorld
    from .follow import ConveyorFollow

    c = cfg.tracking.conveyor
    with SimWorld(cfg, record=True) as world:
        enc = world.device(c.node)
        enc.sync_hook = StreamPlayer(enc, stream, c.index, c.sub_index)
        ctl = Controller(cfg, world.transport,
                         source if source is not None else ConveyorFollow())
        ctl.boot()
        ctl.start()
        if setup is not None:
            setup(ctl, world)
        ctl.run(max_cycles=len(stream) if max_cycles is None else max_cycles)
        frames = [(can_id, data) for _, can_id, data in world.recorder.frames]
    return ctl, frames
