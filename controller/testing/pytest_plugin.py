"""pytest plugin: the ``vcan`` (real SocketCAN, native or VM) and ``hil`` (real bus) test tiers.

Registered for the project's tests in ``tests/conftest.py``::

    pytest_plugins = ["controller.testing.pytest_plugin"]

(or ``-p controller.testing.pytest_plugin`` on the command line).

Options (group "cantrack CAN bus")::

    --can-interface NAME   python-can interface of a real bus (socketcan, pcan, kvaser, ...)
    --can-channel NAME     its channel (can0, PCAN_USBBUS1, ...)
    --can-bitrate BIT/S    its bitrate (for interfaces that set it; socketcan: set by `ip link`)
    --bus-config PATH      the rig's cantrack bus configuration (nodes, EDS files, PDOs)
    --hil-duration S       hil end-to-end run: `cantrack run --duration` (default 5)
    --hil-engage-at S      ... `--engage-at` (default 1)
    --hil-disengage-at S   ... `--disengage-at` (default 3)
    --hil-wait-nodes S     wait up to S s for every configured node's heartbeat first (default 0)
    --hil-decoder NAME     decode the hil capture with tshark, builtin or auto (default: tshark
                           when installed, else the built-in CiA 301 decoder)
    --vcan-mode MODE       auto (default; $CANTRACK_VCAN_MODE), native or vm
    --vcan-required        a vcan test that cannot run fails instead of being skipped
                           (default from $CANTRACK_VCAN_REQUIRED=1; CI sets it)

Markers: ``vcan`` — needs a real SocketCAN ``vcan0``; skipped only when neither native vcan nor
the VM is possible, with a message that says what to install.  ``hil`` — needs a real bus;
skipped unless ``--can-interface`` and ``--can-channel`` are given.

Fixtures: ``vcan_runner`` (session; :class:`VcanRunner`: ``.run(argv, timeout_s, env=...)``
→ :class:`~controller.testing.vm.VmResult`), ``hil_bus_config`` (session; :class:`HilBus`),
``tshark_path`` (session; path of tshark, skip/fail with the install hint when missing),
``hil_rig`` (session; the :class:`HilBus` with its loaded bus configuration: fails when no
``--bus-config`` was given).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import pytest

from .capture import tshark_available
from .vcan import MODES, pick_mode, resolve_mode, run_with_vcan, vcan_available
from .vm import DEFAULT_CHANNEL, VmResult

_AVAIL_KEY = pytest.StashKey[tuple]()
_RUNNER_KEY = pytest.StashKey["VcanRunner"]()

HIL_HINT = ("hil: needs a real CAN bus: run with --can-interface socketcan --can-channel can0 "
            "[--can-bitrate 500000] [--bus-config rig.yaml] (see docs/hil.md)")


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("cantrack CAN bus", "real SocketCAN (vcan) and hardware-in-the-loop")
    g.addoption("--can-interface", default=None, metavar="NAME",
                help="python-can interface of a real bus for hil tests (socketcan, pcan, ...)")
    g.addoption("--can-channel", default=None, metavar="NAME",
                help="channel of the real bus for hil tests (can0, ...)")
    g.addoption("--can-bitrate", default=None, type=int, metavar="BIT/S",
                help="bitrate of the real bus (for interfaces that set it)")
    g.addoption("--bus-config", default=None, metavar="PATH",
                help="the rig's cantrack bus configuration file for hil tests")
    g.addoption("--hil-duration", default=5.0, type=float, metavar="S",
                help="hil end-to-end run: cantrack run --duration (default 5 s)")
    g.addoption("--hil-engage-at", default=1.0, type=float, metavar="S",
                help="hil end-to-end run: cantrack run --engage-at (default 1 s)")
    g.addoption("--hil-disengage-at", default=3.0, type=float, metavar="S",
                help="hil end-to-end run: cantrack run --disengage-at (default 3 s)")
    g.addoption("--hil-wait-nodes", default=0.0, type=float, metavar="S",
                help="hil: before check-bus, wait up to S s for a heartbeat of every "
                     "configured node (a rig that is still powering up; default 0: no wait)")
    g.addoption("--hil-decoder", default="auto", choices=("auto", "tshark", "builtin"),
                help="hil: how to decode the bus capture: tshark's CANopen dissector, the "
                     "built-in CiA 301 decoder, or auto (tshark when installed; default)")
    g.addoption("--vcan-mode", default=None, choices=MODES,
                help="how vcan tests get a real SocketCAN vcan0: auto (native, else VM; "
                     "default, or $CANTRACK_VCAN_MODE), native, vm")
    g.addoption("--vcan-required", action="store_true",
                default=os.environ.get("CANTRACK_VCAN_REQUIRED", "") not in ("", "0"),
                help="fail vcan tests that cannot run instead of skipping them "
                     "(default: $CANTRACK_VCAN_REQUIRED=1)")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "vcan: needs a real SocketCAN vcan0 (native or in the VM harness)")
    config.addinivalue_line("markers", "hil: needs a real CAN bus (hardware in the loop)")
    if config.getoption("--bus-config") and not config.getoption("--can-channel"):
        raise pytest.UsageError("--bus-config needs --can-interface and --can-channel")
    if bool(config.getoption("--can-interface")) != bool(config.getoption("--can-channel")):
        raise pytest.UsageError("--can-interface and --can-channel go together: "
                                "e.g. --can-interface socketcan --can-channel can0")
    bc = config.getoption("--bus-config")
    if bc and not Path(bc).is_file():
        raise pytest.UsageError(f"--bus-config {bc}: no such file")


def _vcan_availability(config: pytest.Config) -> tuple[bool, str]:
    if _AVAIL_KEY not in config.stash:
        config.stash[_AVAIL_KEY] = vcan_available(config.getoption("--vcan-mode"),
                                                  DEFAULT_CHANNEL)
    return config.stash[_AVAIL_KEY]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    hil_on = bool(config.getoption("--can-interface") and config.getoption("--can-channel"))
    required = config.getoption("--vcan-required")
    for item in items:
        if item.get_closest_marker("hil") and not hil_on:
            item.add_marker(pytest.mark.skip(reason=HIL_HINT))
        if item.get_closest_marker("vcan"):
            ok, why = _vcan_availability(config)
            if not ok and not required:
                item.add_marker(pytest.mark.skip(reason="vcan: " + why))


@dataclasses.dataclass
class VcanRunner:
    """Runs commands on a real SocketCAN ``vcan0`` (native or VM); keeps every result."""

    mode: str
    channel: str = DEFAULT_CHANNEL
    results: list = dataclasses.field(default_factory=list)
    tmp_factory: pytest.TempPathFactory | None = None

    def run(self, argv: Sequence[str], timeout_s: float = 120.0,
            env: Mapping[str, str] | None = None, *, cwd: str | Path | None = None,
            scratch_dir: str | Path | None = None) -> VmResult:
        """:func:`controller.testing.vcan.run_with_vcan` in this runner's mode (scratch
        directory: a new pytest temporary directory unless given)."""
        if scratch_dir is None and self.tmp_factory is not None:
            scratch_dir = self.tmp_factory.mktemp("vcan-run")
        r = run_with_vcan(argv, timeout_s, env, mode=self.mode, cwd=cwd,
                          scratch_dir=scratch_dir, channel=self.channel)
        self.results.append(r)
        return r


@pytest.fixture(scope="session")
def vcan_runner(pytestconfig: pytest.Config,
                tmp_path_factory: pytest.TempPathFactory) -> VcanRunner:
    """A :class:`VcanRunner`; skips (fails with --vcan-required) when no vcan is possible.

    Each ``run`` in VM mode is one VM boot (~4 s idle, more on a loaded machine, plus the
    command): put everything a test module needs into one command.
    """
    ok, why = _vcan_availability(pytestconfig)
    if not ok:
        if pytestconfig.getoption("--vcan-required"):
            pytest.fail("vcan required but not possible: " + why, pytrace=False)
        pytest.skip("vcan: " + why)
    mode = pick_mode(pytestconfig.getoption("--vcan-mode"), DEFAULT_CHANNEL)
    runner = VcanRunner(mode=mode, tmp_factory=tmp_path_factory)
    pytestconfig.stash[_RUNNER_KEY] = runner
    return runner


@pytest.fixture(scope="session")
def tshark_path(pytestconfig: pytest.Config) -> str:
    """Path of ``tshark`` (the independent CANopen decoder); skip (or fail with
    --vcan-required) with the install hint when it is missing."""
    ok, found = tshark_available()
    if not ok:
        if pytestconfig.getoption("--vcan-required"):
            pytest.fail(found, pytrace=False)
        pytest.skip(found)
    return found


@dataclasses.dataclass(frozen=True)
class HilBus:
    """The real bus of a hil run: python-can interface, channel, bitrate, bus configuration."""

    interface: str
    channel: str
    bitrate: int | None = None
    bus_config: Path | None = None
    run_duration_s: float = 5.0
    engage_at_s: float = 1.0
    disengage_at_s: float = 3.0
    decoder: str = "auto"
    wait_nodes_s: float = 0.0

    def bus_kwargs(self) -> dict:
        """Keyword arguments for ``can.Bus(**kw)`` / ``canopen.Network().connect(**kw)``."""
        kw: dict[str, object] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            kw["bitrate"] = self.bitrate
        return kw

    def bus_args(self) -> list[str]:
        """The bus arguments of a ``cantrack`` command: ``-i IF -c CH [-b BIT/S]``."""
        args = ["-i", self.interface, "-c", self.channel]
        if self.bitrate is not None:
            args += ["-b", str(self.bitrate)]
        return args

    def load_config(self):
        """The rig's :class:`~controller.canopen.config.ControllerConfig` (``--bus-config``)."""
        from ..canopen.config import load_config

        if self.bus_config is None:
            raise ValueError("no --bus-config given")
        return load_config(self.bus_config)

    def wait_for_heartbeats(self, node_ids, timeout_s: float) -> set[int]:
        """Listen until every node of ``node_ids`` has sent a heartbeat, at most
        ``timeout_s``; return the nodes not heard (empty: all there).  Sends nothing."""
        import time

        import can

        from .speed import scaled

        missing = set(node_ids)
        t_end = time.monotonic() + scaled(timeout_s)  # (a limit: follows the load)
        with can.Bus(**self.bus_kwargs()) as bus:
            while missing and time.monotonic() < t_end:
                msg = bus.recv(min(0.2, max(0.0, t_end - time.monotonic())))
                if (msg is not None and not msg.is_extended_id
                        and 0x701 <= msg.arbitration_id <= 0x77F):
                    missing.discard(msg.arbitration_id - 0x700)
        return missing

    def describe(self) -> str:
        s = f"{self.interface} {self.channel}"
        if self.bitrate is not None:
            s += f" @ {self.bitrate} bit/s"
        if self.interface == "virtual":
            s += (" (python-can's in-process virtual bus: another process - a cantrack command,"
                  " a rig - is never on it)")
        return s


@pytest.fixture(scope="session")
def hil_bus_config(pytestconfig: pytest.Config) -> HilBus:
    """The :class:`HilBus` from the command line; skips when no real bus was given."""
    iface = pytestconfig.getoption("--can-interface")
    chan = pytestconfig.getoption("--can-channel")
    if not (iface and chan):
        pytest.skip(HIL_HINT)
    bc = pytestconfig.getoption("--bus-config")
    return HilBus(interface=iface, channel=chan, bitrate=pytestconfig.getoption("--can-bitrate"),
                  bus_config=Path(bc).resolve() if bc else None,
                  run_duration_s=pytestconfig.getoption("--hil-duration"),
                  engage_at_s=pytestconfig.getoption("--hil-engage-at"),
                  disengage_at_s=pytestconfig.getoption("--hil-disengage-at"),
                  decoder=pytestconfig.getoption("--hil-decoder"),
                  wait_nodes_s=pytestconfig.getoption("--hil-wait-nodes"))


@pytest.fixture(scope="session")
def hil_rig(hil_bus_config: HilBus) -> HilBus:
    """:class:`HilBus` of a rig with its bus configuration: skips without a real bus (as
    ``hil_bus_config``); *fails* when the bus is given but ``--bus-config`` is not (an
    end-to-end test cannot know the rig's nodes, SYNC period and axes without it)."""
    if hil_bus_config.bus_config is None:
        pytest.fail("hil end-to-end tests need the rig's configuration: add --bus-config "
                    "rig.yml (see docs/hil.md)", pytrace=False)
    return hil_bus_config


def pytest_report_header(config: pytest.Config) -> list[str]:
    iface = config.getoption("--can-interface")
    if not iface:
        return []
    line = f"hil bus: {iface} {config.getoption('--can-channel')}"
    if config.getoption("--can-bitrate"):
        line += f" @ {config.getoption('--can-bitrate')} bit/s"
    if config.getoption("--bus-config"):
        line += f", config {config.getoption('--bus-config')}"
    return [line]


def pytest_terminal_summary(terminalreporter, exitstatus, config: pytest.Config) -> None:
    runner = config.stash.get(_RUNNER_KEY, None)
    if runner is None or not runner.results:
        return
    parts = []
    for r in runner.results:
        boot = f"boot {r.boot_s:.1f} s, " if r.boot_s is not None else ""
        cmd = f"command {r.command_s:.1f} s" if r.command_s is not None else ""
        retry = (f", booted {r.boot_attempts} times ({'; '.join(r.boot_notes)})"
                 if r.boot_attempts > 1 else "")
        parts.append(f"{boot}{cmd}, slowness x {r.speed_factor:.2f}{retry}")
    terminalreporter.write_line(
        f"vcan ({runner.mode}, {resolve_mode(config.getoption('--vcan-mode'))}): "
        f"{len(runner.results)} run(s): " + "; ".join(parts))
