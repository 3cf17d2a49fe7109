"""The three mutant families of :mod:`controller.testing.mutants`, with their loaders and
the short run that checks an accepted mutant.

- ``bus``: examples/bus/demo.yml; loaded by ``load_config``; an accepted one runs the
  stepped demo for ``run_s`` of machine time (boot, enable, the first item);
- ``scenario``: examples/*.yaml; ``load_scenario``, an accepted one is simulated in full;
- ``eds``: eds/cantrack-servo.eds and cantrack-encoder.eds, named by a copy of demo.yml;
  judged like ``bus``, and an accepted mutant whose change CiA 306 forbids
  (:func:`cia306_forbids`) is *wrong*.
"""

from __future__ import annotations

import random
import re
from dataclasses import replace
from pathlib import Path

from ..resources import data_path
from . import mutants as mu

EXAMPLES = Path(data_path("examples"))
EDS_DIR = Path(data_path("eds"))

#: CiA 306 / CiA 301 facts the EDS oracle needs (independent of the validator in the shell)
_ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}
_OBJECT_TYPES = {0x2, 0x5, 0x6, 0x7, 0x8, 0x9}
_DATA_TYPES = set(range(0x01, 0x1C)) - {0x0E, 0x17}  # (0x0E, 0x17 unused in CiA 301)
_BOOL_KEYS = {"pdomapping", "simplebootupmaster", "simplebootupslave",
              "dynamicchannelssupported", "groupmessaging", "lss_supported"}
_UNSIGNED_KEYS = {"vendornumber", "productnumber", "revisionnumber", "nrofrxpdo",
                  "nroftxpdo", "subnumber", "granularity", "supportedobjects"}


def _int(text: str) -> int | None:
    t = text.strip()
    try:
        return int(t, 0)
    except ValueError:
        return None


def _base_type(base: str, section: str) -> int | None:
    """The DataType of ``[section]`` in the unmutated file."""
    for name, _head, entries in mu.eds_sections(base):
        if name.lower() == section.lower():
            lines = base.splitlines()
            for i in entries:
                k, _, v = lines[i].partition("=")
                if k.strip().lower() == "datatype":
                    return _int(v)
    return None


def cia306_forbids(mutant: mu.Mutant, base: str) -> str | None:
    """Why CiA 306 forbids this EDS mutant, or None if it may be valid (then accepting it
    is not judged wrong here)."""
    if mutant.path is None:
        return None
    section = mutant.path[0]
    sec = section.lower()
    if mutant.label == "deleted" and len(mutant.path) == 1:
        if re.fullmatch(r"[0-9a-f]{4}(sub[0-9a-f]+)?", sec):
            return f"[{section}] deleted while listed or counted elsewhere"
        if sec in ("deviceinfo", "mandatoryobjects", "fileinfo"):
            return f"mandatory section [{section}] deleted"
        return None
    key = mutant.path[1].lower()
    value = mutant.label
    if mutant.label == "deleted":
        if re.fullmatch(r"[0-9a-f]{4}(sub[0-9a-f]+)?", sec) and key in (
                "parametername", "datatype", "accesstype", "subnumber"):
            # DataType/AccessType are mandatory for VAR, SubNumber for ARRAY/RECORD
            return f"mandatory entry {mutant.path[1]} of [{section}] deleted"
        if sec in ("mandatoryobjects", "optionalobjects", "manufacturerobjects"):
            return f"object list [{section}] entry deleted (count or object mismatch)"
        return None
    if mutant.label == "range":
        if _base_type(base, section) in (0x09, 0x0A, 0x0B, 0x0F):
            return None  # (a string has no range)
        return f"[{section}] DefaultValue outside its DataType's range"
    if re.fullmatch(r"[0-9a-f]{4}(sub[0-9a-f]+)?", sec):
        if key == "accesstype" and value.strip().lower() not in _ACCESS:
            return f"AccessType={value}"
        if key == "objecttype" and _int(value) not in _OBJECT_TYPES:
            return f"ObjectType={value}"
        if key == "datatype" and _int(value) not in _DATA_TYPES:
            return f"DataType={value}"
        if key == "pdomapping" and _int(value) not in (0, 1):
            return f"PDOMapping={value}"
        if key == "subnumber" and _int(value) is None:
            return f"SubNumber={value}"
        if key in ("defaultvalue", "lowlimit", "highlimit"):
            if _base_type(base, section) in (0x09, 0x0A, 0x0B, 0x0F):
                return None  # (any text is a string's value)
            v = value.strip()
            if v.lower() in ("nan", "xx", "rw ro", "$nodeid+x") or v == "1e300" \
                    or ((iv := _int(v)) is not None and not -(1 << 63) <= iv < (1 << 64)):
                return f"{mutant.path[1]}={value}"
        return None
    if key in _BOOL_KEYS or key.startswith("baudrate_"):
        return None if _int(value) in (0, 1) else f"{mutant.path[1]}={value} (0 or 1)"
    if key in _UNSIGNED_KEYS:
        u = _int(value)
        return None if u is not None and u >= 0 else f"{mutant.path[1]}={value}"
    if sec in ("mandatoryobjects", "optionalobjects", "manufacturerobjects") and key != \
            "supportedobjects":
        u = _int(value)
        return None if u is not None and 0 <= u <= 0xFFFF else f"{mutant.path[1]}={value}"
    return None


class _BusBase:
    """Shared by ``bus`` and ``eds``: write a bus.yml, load it, run the demo briefly."""

    run_s = 0.3

    def __init__(self, tmp: Path, run: bool = True) -> None:
        self.tmp = tmp
        self.run = run
        self.n = 0

    def _load(self, path: Path):
        from ..canopen.config import load_config
        return load_config(path)

    def _run_demo(self, cfg) -> str | None:
        from ..canopen.apps.demo import PhotoEye, PickPlace
        from ..canopen.master.cycle import Controller
        from ..canopen.slave.world import SimWorld
        if cfg.demo is None or cfg.tracking is None:
            return None
        demo = replace(cfg.demo, duration_s=min(cfg.demo.duration_s, self.run_s))
        app = PickPlace(demo)
        with SimWorld(cfg) as world:
            ctl = Controller(cfg, world.transport, app, keep_trace=False)
            ctl.boot()
            ctl.start()
            app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, demo,
                               world.clock.now_ns() * 1e-9)
            try:
                ctl.run(max_cycles=int(self.run_s / cfg.period_s) + 50)
            except Exception as exc:
                from ..errors import CantrackError
                if isinstance(exc, CantrackError):
                    return None  # a clear refusal at run time (the boot, the enable)
                raise
        return None


class BusFamily(_BusBase):
    def __init__(self, tmp: Path, run: bool = True) -> None:
        super().__init__(tmp, run)
        text = (EXAMPLES / "bus" / "demo.yml").read_text()
        text = text.replace("../../eds/", str(EDS_DIR) + "/")
        self.base = mu.load_tree(text)

    def mutant(self, rng: random.Random) -> mu.Mutant:
        return mu.yaml_mutant("bus", self.base, rng)

    def judge(self, m: mu.Mutant) -> mu.Answer:
        self.n += 1
        path = self.tmp / f"bus{self.n}.yml"
        twin = mu.deleted_text(m, self.base)

        def deleted_twin():
            p = self.tmp / f"bus{self.n}-twin.yml"
            p.write_text(twin or "")
            return self._load(p)

        return mu.judge(m, self._load, path, deleted_twin if twin else None,
                        self._run_demo if self.run else None)


class ScenarioFamily:
    def __init__(self, tmp: Path, run: bool = True) -> None:
        self.tmp = tmp
        self.run = run
        self.n = 0
        self.bases = []
        for p in sorted(EXAMPLES.glob("*.yaml")):
            text = p.read_text().replace("csv_master.csv", str(EXAMPLES / "csv_master.csv")) \
                .replace("conveyor_rotary_items.csv", str(EXAMPLES / "conveyor_rotary_items.csv"))
            self.bases.append((p.stem, mu.load_tree(text)))

    def mutant(self, rng: random.Random) -> mu.Mutant:
        name, base = rng.choice(self.bases)
        m = mu.yaml_mutant("scenario", base, rng)
        return replace(m, what=f"{name}: {m.what}")

    def _load(self, path: Path):
        from ..simulate.scenario import load_scenario
        return load_scenario(path)

    def _simulate(self, sc) -> str | None:
        from ..simulate.runner import run_scenario
        run_scenario(sc)
        return None

    def judge(self, m: mu.Mutant) -> mu.Answer:
        self.n += 1
        name = m.what.split(":", 1)[0]
        base = dict(self.bases)[name]
        path = self.tmp / f"scenario{self.n}.yaml"
        twin = mu.deleted_text(m, base)

        def deleted_twin():
            p = self.tmp / f"scenario{self.n}-twin.yaml"
            p.write_text(twin or "")
            return self._load(p)

        return mu.judge(m, self._load, path, deleted_twin if twin else None,
                        self._simulate if self.run else None)


class EdsFamily(_BusBase):
    FILES = ("cantrack-servo.eds", "cantrack-encoder.eds")

    def __init__(self, tmp: Path, run: bool = True) -> None:
        super().__init__(tmp, run)
        self.bases = {f: (EDS_DIR / f).read_text() for f in self.FILES}
        self.bus_text = (EXAMPLES / "bus" / "demo.yml").read_text()

    def mutant(self, rng: random.Random) -> mu.Mutant:
        f = rng.choice(self.FILES)
        m = mu.eds_mutant(self.bases[f], rng)
        return replace(m, what=f"{f} {m.what}", label=m.label)

    def judge(self, m: mu.Mutant) -> mu.Answer:
        self.n += 1
        f = m.what.split(" ", 1)[0]
        d = self.tmp / f"eds{self.n}"
        d.mkdir()
        for other in self.FILES:
            (d / other).write_text(m.text if other == f else self.bases[other])
        bus = d / "bus.yml"
        bus.write_text(self.bus_text.replace("../../eds/", str(d) + "/"))
        eds_path = d / f

        def load(_path: Path):
            return self._load(bus)

        # (judge writes the mutant to eds_path and wants the EDS file named in the error)
        a = mu.judge(m, load, eds_path, check=self._run_demo if self.run else None)
        if a.verdict is mu.Verdict.ACCEPTED:
            why = cia306_forbids(m, self.bases[f])
            if why:
                return mu.Answer(m, mu.Verdict.WRONG, f"accepted although {why}")
        return a


FAMILIES = {"bus": BusFamily, "scenario": ScenarioFamily, "eds": EdsFamily}
