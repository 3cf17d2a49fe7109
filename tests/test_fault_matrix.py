"""The fault matrix (issue 11): every bus fault, its reaction, the cycles to react, the
drives' final state and the exit code - in stepped time against the simulated devices.

No row may end with a traceback, exit code 0, or a drive left enabled.  The README's table
is this module's output (``python tests/test_fault_matrix.py`` prints it); the test checks
that the README holds exactly these rows.
"""

from __future__ import annotations

import random
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Controller
from controller.canopen.protocol.cia402 import State
from controller.canopen.testing import load, stepped
from controller.errors import CanError

ROOT = Path(__file__).resolve().parents[1]
OFFSET = (420.0, 30.0, 0.0)
T_FAULT = 0.5  # s: tracking (SYNCED) by then; 2 ms cycles


class Intruder:
    """Another actor on the stepped bus (it only sends)."""

    def __init__(self, world) -> None:
        self.clock = world.clock
        self.bus = world.world.new_bus()
        world.world.add(self)

    def send(self, can_id: int, data: bytes, error: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False,
                                  is_error_frame=error, timestamp=self.clock.stamp()))

    def handle(self, msg) -> None:
        pass

    def next_timer_ns(self) -> int | None:
        return None

    def on_timer(self, now_ns: int) -> None:
        pass


class _Boom(ConveyorFollow):
    def step(self, ctx):
        if ctx.t_ns >= T_FAULT * 1e9:
            raise ZeroDivisionError("injected")
        return super().step(ctx)


def _random(world, intruder) -> None:
    rng = random.Random(1)
    for i in range(200):
        cob = rng.choice([0x18A, 0x18B, 0x18C, 0x8A, 0x8B, 0x70A, 0x70B, 0x000, 0x080])
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        world.at(T_FAULT + i * 0.0013, lambda c=cob, d=data: intruder.send(c, d))


def _sync(world, intruder) -> None:
    for i in range(20):
        world.at(T_FAULT + i * 0.002 + 0.0007, lambda: intruder.send(0x080, b"\x05"))


def _at(action: Callable) -> Callable:
    return lambda world, intruder: world.at(T_FAULT, lambda: action(world, intruder))


#: name -> (what is done, at boot?)
FAULTS: dict[str, tuple[Callable, bool]] = {
    "short frame (18Ah#0102)": (_at(lambda w, i: i.send(0x18A, b"\x01\x02")), False),
    "long frame (18Bh, 8 bytes)": (_at(lambda w, i: i.send(0x18B, bytes(8))), False),
    "random frames (200, seed 1)": (_random, False),
    "foreign NMT stop": (_at(lambda w, i: i.send(0x000, b"\x02\x00")), False),
    "foreign NMT pre-operational": (_at(lambda w, i: i.send(0x000, b"\x80\x00")), False),
    "foreign NMT reset communication": (_at(lambda w, i: i.send(0x000, b"\x82\x00")), False),
    "second SYNC producer": (_sync, False),
    "heartbeat loss (y)": (_at(lambda w, i: w.device("y").stop_heartbeat()), False),
    "drive powered off (y)": (_at(lambda w, i: w.device("y").power_off()), False),
    "encoder silence": (_at(lambda w, i: w.device("encoder").mute_pdos(True)), False),
    "drive EMCY 4210h (y)": (_at(lambda w, i: w.device("y").send_emcy(0x4210)), False),
    "drive fault 2310h (x)": (_at(lambda w, i: w.device("x").inject_fault(0x2310)), False),
    "following error (x pushed 20 mm)": (_at(lambda w, i: w.device("x").disturb(200_000)),
                                         False),
    "node reset mid-run (y)": (_at(lambda w, i: w.device("y").reset_itself()), False),
    "bus-off (error frame)": (_at(lambda w, i: i.send(0x040, bytes(8), error=True)), False),
    "error passive (error frame)": (_at(lambda w, i: i.send(0x004, bytes((0, 0x30)) + bytes(6),
                                                            error=True)), False),
    "internal error in the cycle": (lambda w, i: None, False),
    "SDO abort at boot (x 6060h)": (lambda w, i: w.device("x").reject_sdo(0x6060, 0,
                                                                          0x06090030), True),
    "SDO time-out at boot (x)": (lambda w, i: w.device("x").mute_sdo(True), True),
}


@dataclass
class Row:
    fault: str
    reaction: str
    cycles: str
    final: str
    exit_code: int
    traceback: str = ""

    def line(self) -> str:
        return f"| {self.fault} | {self.reaction} | {self.cycles} | {self.final} | " \
               f"{self.exit_code} |"


def run_fault(name: str, tmp: Path) -> tuple[Row, list[State | None]]:
    setup, at_boot = FAULTS[name]
    cfg = load(tmp)
    app = _Boom(10, None, OFFSET, end_cycle=600) if name.startswith("internal") else \
        ConveyorFollow(10, None, OFFSET, end_cycle=600)
    world, ctl = stepped(cfg, app)
    with world:
        intruder = Intruder(world)
        tb = ""
        code = None
        if at_boot:
            setup(world, intruder)
        try:
            ctl.boot()
            if not at_boot:
                setup(world, intruder)
            ctl.run(max_cycles=4000)
        except CanError as exc:
            code = Controller.exit_code(ctl) if ctl.k else 2
            first_error = str(exc).split(":")[0]
            tb = "" if ctl.k else f"boot error ({first_error})"
        except Exception as exc:  # noqa: BLE001 -- a row with a traceback fails the test
            tb = f"{type(exc).__name__}: {exc}"
        code = ctl.exit_code() if code is None else code
        k0 = -(-(int(T_FAULT * 1e9) - ctl.t0) // ctl.period_ns) if ctl.k else 0
        first = next((e for e in ctl.events if e.reaction), None)
        if at_boot:
            reaction, cycles = tb or "?", "boot"
            tb = ""
        elif first is None:
            reaction, cycles = "none", "-"
        else:
            reaction = f"{first.kind}: {first.reaction}"
            cycles = str(first.cycle - k0)
        # a powered-off drive has no power stage: its simulated state is frozen, not live
        states = [world.device(n).state if world.device(n).powered else None
                  for n in ("x", "y")]
        stops = {s.label.split()[-1].strip("()"): s for s in ctl.stops}
        final = ", ".join(
            f"{n} {st.value if st is not None else 'powered off'}" + ("" if not at_boot and stops[n].begin_cycle is None else
                                 " (confirmed)" if stops[n].confirmed_cycle is not None else
                                 " (unconfirmed)" if not at_boot else "")
            for n, st in zip(("x", "y"), states))
    return Row(name, reaction, cycles, final, code, tb), states


def matrix(tmp: Path) -> list[Row]:
    rows = []
    for i, name in enumerate(FAULTS):
        d = tmp / f"f{i}"
        d.mkdir(parents=True, exist_ok=True)
        rows.append(run_fault(name, d)[0])
    return rows


HEADER = ["| fault | first reaction | cycles to react | drives' final state | exit code |",
          "|---|---|---|---|---|"]


@pytest.mark.parametrize("name", list(FAULTS))
def test_fault_row(tmp_path, name):
    row, states = run_fault(name, tmp_path)
    assert not row.traceback, row
    assert row.exit_code != 0, row
    assert State.OPERATION_ENABLED not in states, row
    assert row.reaction != "none", row


def test_readme_has_the_matrix(tmp_path):
    rows = [r.line() for r in matrix(tmp_path)]
    text = (ROOT / "README.md").read_text()
    m = re.search(r"<!-- fault-matrix -->\n(.*?)<!-- /fault-matrix -->", text, re.S)
    assert m, "README.md: no <!-- fault-matrix --> block"
    assert m.group(1).strip().splitlines() == HEADER + rows, \
        "README's fault matrix differs: run python tests/test_fault_matrix.py"


if __name__ == "__main__":
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        print("\n".join(HEADER + [r.line() for r in matrix(Path(d))]))
