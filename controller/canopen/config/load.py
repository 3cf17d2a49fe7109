"""Reading a whole bus.yml: the dcfgen part (:mod:`.bus`), the PDO COB-ID checks
(:mod:`.concise`) and cantrack's dot sections (:mod:`.tracking`, :mod:`.simulation`,
:mod:`.demo`, :mod:`.plc`), in this order: each part is read with what the parts before it give."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ...errors import ConfigError
from ...yamlmarks import Section, load_marked, read_text
from .bus import ControllerConfig, parse_bus
from .concise import check_cob_ids
from .demo import parse_demo
from .plc import parse_plc
from .simulation import parse_simulation
from .tracking import parse_tracking


def load_config(path: str | Path, *, sections: bool = True) -> ControllerConfig:
    """Read and validate a bus.yml.  ``sections=False`` skips the dot sections."""
    p = Path(path)
    text = read_text(p)
    return parse_config(text, str(p), base_dir=p.parent, sections=sections)


def parse_config(text: str, file: str, base_dir: Path | None = None, *,
                 sections: bool = True) -> ControllerConfig:
    """:func:`load_config` of the text ``text`` of the file ``file`` (relative ``dcf``
    paths from ``base_dir``, default: the file's directory)."""
    base_dir = Path(base_dir) if base_dir is not None else Path(file).parent
    data = load_marked(text, file)
    if data is None:
        raise ConfigError("the file is empty", file=file)
    top = Section(data, file, line=1)
    cfg, dot = parse_bus(top, base_dir)
    check_cob_ids(cfg)
    if sections:
        tracking = parse_tracking(top.section(".tracking"), cfg) if ".tracking" in dot \
            else None
        simulation = parse_simulation(top.section(".simulation"), cfg) \
            if ".simulation" in dot else None
        demo = parse_demo(top.section(".demo"), cfg, tracking) if ".demo" in dot else None
        plc = parse_plc(top.section(".plc"), cfg) if ".plc" in dot else None
        cfg = replace(cfg, tracking=tracking, simulation=simulation, demo=demo, plc=plc)
    return cfg
