"""The setpoint-source protocol (controller.canopen.master.source): a source is pure (the same
context gives the same output, no controller or bus reachable from what it is handed or
holds), and the cycle uses nothing of a source but ``start`` and ``step``; conveyor
following, the demo's pick and place and the axis jobs are such sources."""

from __future__ import annotations

import copy
import gc
from dataclasses import replace

from controller.canopen.apps import axis_motion as am
from controller.canopen.apps.axis_controller import JobSequence, MotionController, run_jobs
from controller.canopen.apps.axis_jobs import AxisSlot
from controller.canopen.apps.demo import PhotoEye, PickPlace
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.config import load_config
from controller.canopen.config.plc import PlcConfig
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.master.plc_node import attach_plc_node
from controller.canopen.master.source import (
    CycleContext,
    DriveCommand,
    Engage,
    SdoDownload,
    SdoUpload,
    SourceOutput,
    SourceStart,
    SourceStatus,
)
from controller.canopen.slave.encoder import SpeedProfile
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import load, stepped
from controller.cli import demo as cmd_demo
from controller.errors import CanError
from controller.tracking import Mode, TrackState

OFFSET = (420.0, 30.0, 0.0)


class Recording:
    """A source that hands everything to ``inner`` and keeps what went in and out."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.started: SourceStart | None = None
        self.contexts: list[CycleContext] = []
        self.outputs: list[SourceOutput] = []

    def start(self, start: SourceStart) -> SourceStatus:
        self.started = start
        return self.inner.start(start)

    def step(self, ctx: CycleContext) -> SourceOutput:
        out = self.inner.step(ctx)
        self.contexts.append(ctx)
        self.outputs.append(out)
        return out


def _reachable(root, limit: int = 200_000) -> list:
    """Every object reachable from ``root`` (gc referents; classes and modules not followed)."""
    seen, todo, out = set(), [root], []
    while todo and len(out) < limit:
        o = todo.pop()
        if id(o) in seen or isinstance(o, type) or type(o).__name__ == "module":
            continue
        seen.add(id(o))
        out.append(o)
        todo.extend(gc.get_referents(o))
    return out


#: modules of the imperative shell: nothing of them may be reachable from a source or its
#: context (the simulated belt's speed profile, data the demo's photo-eye reads, excepted)
SHELL_MODULES = ("controller.canopen.master.cycle", "controller.canopen.master.axisio",
                 "controller.canopen.master.masterio", "controller.canopen.master.plc_node",
                 "controller.canopen.master.supervision", "controller.canopen.master.sync",
                 "controller.canopen.io.", "controller.canopen.slave.", "can.", "canopen.",
                 "threading", "socket", "_io")


def _shell(o) -> bool:
    t = type(o)
    if t is SpeedProfile:
        return False
    mod = t.__module__ or ""
    return any(mod == m.rstrip(".") or mod.startswith(m) for m in SHELL_MODULES)


def _no_shell_reachable(root) -> None:
    bad = [type(o).__name__ for o in _reachable(root) if _shell(o)]
    assert not bad, f"{type(root).__name__} reaches {sorted(set(bad))}"
    assert not any(isinstance(o, Controller | SimWorld) for o in _reachable(root))


def _follow_run(tmp_path, source, cycles: int = 500, plc: bool = False):
    cfg = load(tmp_path)
    world, ctl = stepped(cfg, source)
    with world:
        node = attach_plc_node(ctl, PlcConfig()) if plc else None
        ctl.boot()
        ctl.run(max_cycles=cycles)
    return ctl, node


def _replay(make, rec: Recording) -> list[SourceOutput]:
    src = make()
    src.start(rec.started)
    return [src.step(ctx) for ctx in rec.contexts]


def test_conveyor_follow_is_pure(tmp_path):
    """Recorded contexts replayed into a fresh ConveyorFollow give the run's outputs
    exactly; a copy of the source stepped with the same context gives the same output;
    neither the contexts nor the source reach the controller, a transport or the bus."""
    def make():
        return ConveyorFollow(20, 320, OFFSET, mode=Mode.RELATIVE, end_cycle=420)
    rec = Recording(make())
    ctl, _ = _follow_run(tmp_path, rec)
    assert ctl.failure is None and len(rec.contexts) == 420 and rec.outputs[-1].done
    states = {o.status.track_state for o in rec.outputs}
    assert {TrackState.SYNCING, TrackState.SYNCED, TrackState.DESYNCING} <= states
    assert _replay(make, rec) == rec.outputs
    # the same context twice (the source copied before) -> the same output
    src = make()
    src.start(rec.started)
    for i, ctx in enumerate(rec.contexts):
        if i in (0, 25, 200, 330):
            twin = copy.deepcopy(src)
            assert twin.step(ctx) == src.step(ctx)
        else:
            src.step(ctx)
    _no_shell_reachable(rec.started)
    for ctx in rec.contexts[::50]:
        _no_shell_reachable(ctx)
    _no_shell_reachable(src)
    hash(rec.contexts[100])  # frozen all the way down


def _demo_run(items: int = 2, max_cycles: int = 6000):
    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    demo = replace(cfg.demo, items=items)
    made = []

    def make():
        app = PickPlace(demo)
        app.eye = PhotoEye(made[0], demo, made[1])
        return app
    app = PickPlace(demo)
    rec = Recording(app)
    with SimWorld(cfg) as world:
        ctl = Controller(cfg, world.transport, rec)
        ctl.boot()
        ctl.start()
        made[:] = [world.device(cfg.tracking.conveyor.node).profile,
                   world.clock.now_ns() * 1e-9]
        app.eye = PhotoEye(made[0], demo, made[1])
        ctl.run(max_cycles=max_cycles)
    return ctl, app, rec, make


def test_pick_place_is_pure():
    """The demo's source: the recorded run replayed gives the same setpoints, statuses,
    events and the same items placed; a copy stepped with the same context agrees."""
    ctl, app, rec, make = _demo_run()
    assert app.placed == 2 and ctl.source_done
    replayed = _replay(make, rec)
    assert replayed == rec.outputs
    src = make()
    src.start(rec.started)
    for i, ctx in enumerate(rec.contexts):
        if i % 400 == 0:
            # (the configuration is immutable: shared, not copied)
            twin = copy.deepcopy(src, {id(rec.started.tracking): rec.started.tracking})
            assert twin.step(ctx) == src.step(ctx)
            assert twin.placed == src.placed and twin.stage == src.stage
        else:
            src.step(ctx)
    assert src.placed == 2
    _no_shell_reachable(src)
    _no_shell_reachable(rec.contexts[-1])


class Strict:
    """A source as a plain class with only the protocol's two methods; any other attribute
    looked up on it (by the cycle, the PLC node, anyone) is recorded and fails."""

    __slots__ = ("_inner", "_asked")

    def __init__(self, inner) -> None:
        object.__setattr__(self, "_inner", inner)
        object.__setattr__(self, "_asked", [])

    def __getattribute__(self, name: str):
        if name in ("start", "step", "__class__"):
            return object.__getattribute__(self, name)
        object.__getattribute__(self, "_asked").append(name)
        raise AttributeError(name)

    def start(self, start: SourceStart) -> SourceStatus:
        return object.__getattribute__(self, "_inner").start(start)

    def step(self, ctx: CycleContext) -> SourceOutput:
        return object.__getattribute__(self, "_inner").step(ctx)


def test_cycle_looks_up_nothing_but_start_and_step(tmp_path):
    """A source that has nothing but ``start`` and ``step`` runs the cycle (with the PLC node
    attached, which reads the status each cycle) exactly like the ConveyorFollow it wraps:
    the same setpoints and states, and no other attribute asked for."""
    plain, _ = _follow_run(tmp_path, ConveyorFollow(20, None, OFFSET, end_cycle=300))
    inner = ConveyorFollow(20, None, OFFSET, end_cycle=300)
    strict = Strict(inner)
    ctl, node = _follow_run(tmp_path, strict, plc=True)
    assert object.__getattribute__(strict, "_asked") == []
    assert ctl.failure is None and ctl.source_done
    assert [r.targets for r in ctl.trace] == [r.targets for r in plain.trace]
    assert [r.state for r in ctl.trace] == [r.state for r in plain.trace]
    assert ctl.status.track_state is TrackState.SYNCED and ctl.tracking


def test_plc_commands_reach_the_source_in_the_next_context(tmp_path):
    """An engage command queued between two cycles is in the next cycle's context (and
    only there), and the source acts on it in that cycle."""
    inner = ConveyorFollow(None, None, OFFSET)
    rec = Recording(inner)
    cfg = load(tmp_path)
    world, ctl = stepped(cfg, rec)
    with world:
        ctl.boot()
        ctl.start()
        while ctl.phase is not Phase.RUNNING:
            ctl.step()
        for _ in range(5):
            ctl.step()
        ctl.command(Engage(Mode.ABSOLUTE))
        k = ctl.k
        ctl.step()
        ctl.step()
    with_cmd = [c for c in rec.contexts if c.commands]
    assert [(c.cycle, c.commands) for c in with_cmd] == [(k, (Engage(Mode.ABSOLUTE),))]
    assert rec.outputs[-2].status.tracker_state is TrackState.SYNCING
    assert rec.outputs[-3].status.tracker_state is TrackState.OFF


# ---------------------------------------------------------------------------------------------
# axis jobs: the JobSequence source (apps.axis_controller)

class RecordingTransfers(Recording):
    """:class:`Recording` that also keeps each cycle's SDO program as it ran: the transfers
    asked for and the answers (or errors) the cycle gave."""

    def __init__(self, inner) -> None:
        super().__init__(inner)
        self.transfers: list[list] = []

    def step(self, ctx: CycleContext) -> SourceOutput:
        out = super().step(ctx)
        log: list = []
        self.transfers.append(log)
        if out.transfers is not None:
            out = out._replace(transfers=self._wrap(out.transfers, log))
        return out

    @staticmethod
    def _wrap(program, log):
        try:
            req = program.send(None)
            while True:
                try:
                    value = yield req
                except CanError as exc:
                    log.append((req, exc))
                    req = program.throw(exc)
                    continue
                log.append((req, value))
                req = program.send(value)
        except StopIteration:
            return


def _run_program(program, log) -> list:
    """Run an SDO program against recorded answers; the transfers it asked for."""
    asked = []
    answers = iter(log)
    try:
        req = program.send(None)
        while True:
            asked.append(req)
            _, answer = next(answers)
            req = program.throw(answer) if isinstance(answer, Exception) \
                else program.send(answer)
    except StopIteration:
        pass
    return asked


def _homing_session(tmp_path, record_source):
    import test_canopen_motion as tm
    homing = tm.GOTOY.replace("}", ", home_offset: 2.5, touch_probe: true}")
    p = tmp_path / "bus.yml"
    p.write_text(tm.yml_text(initial=50000, homing=homing, sim=tm.PROBE_SIM))
    cfg = load_config(p)
    ax = am.axis_config(cfg, "y")

    def jobs():
        return [am.GotoYJob(ax, cfg.period_s), am.MoveJob(ax, cfg.period_s, 3.0),
                am.JogJob(ax, cfg.period_s, -20.0, 0.2)]
    with SimWorld(cfg) as world:
        ctl = MotionController(cfg, world.transport, jobs())
        rec = record_source(ctl.sequence)
        ctl.source = rec  # (the recorder in front of the controller's own sequence)
        reports = run_jobs(ctl)
    return cfg, ctl, rec, reports, jobs


def test_axis_jobs_are_a_pure_source(tmp_path):
    """GotoY with the touch probe (SDO arming and read, the drive's position set in homing
    mode), a move and a jog in one session run as a JobSequence source: replayed into a
    fresh sequence of fresh jobs, the recorded contexts and SDO answers give the same
    setpoints, drive commands, requests and SDO transfers, and the same reports."""
    cfg, ctl, rec, reports, jobs = _homing_session(tmp_path, RecordingTransfers)
    assert [r.result for r in reports] == ["FINISHED"] * 3, [r.message for r in reports]
    assert reports[0].latch_source == "touch probe" and reports[0].probe_source == "SDO"
    asked = [req for log in rec.transfers for req, _ in log]
    assert {(r.index, type(r)) for r in asked} >= {
        (0x60B8, SdoDownload), (0x60B9, SdoUpload), (0x60BA, SdoUpload),
        (0x6060, SdoDownload), (0x607C, SdoDownload), (0x6064, SdoUpload)}
    commands = {c for o in rec.outputs for c in o.setpoint.commands}
    assert DriveCommand.HOMING_START in commands  # (method 37: bit 4 in homing mode)
    slots = [AxisSlot(s.index, s.label, s.scale, s.inputs_mapped, s.probe_mapped)
             for s in ctl.sequence.slots]
    fresh = JobSequence(jobs(), slots, [a.name for a in cfg.tracking.axes])
    fresh.start(rec.started)
    for ctx, out, log in zip(rec.contexts, rec.outputs, rec.transfers):
        again = fresh.step(ctx)
        # (setpoint, commands, status, stop, done; the generators are compared by running)
        assert again._replace(transfers=None) == out._replace(transfers=None)
        assert _run_program(again.transfers, log) == [req for req, _ in log]
    for a, b in zip(fresh.jobs, ctl.jobs):
        assert (a.report.targets, a.report.states, a.report.result, a.report.latched_mm) \
            == (b.report.targets, b.report.states, b.report.result, b.report.latched_mm)
    for ctx in rec.contexts[::100]:
        _no_shell_reachable(ctx)
    _no_shell_reachable(fresh)


def test_motion_controller_is_the_plain_cycle(tmp_path):
    """The axis jobs run through the cycle's source path: MotionController overrides none of
    the cycle (no _run_step, no _supervise of its own), and its jobs hold no I/O."""
    for name in ("_run_step", "_supervise", "_compute", "step"):
        assert getattr(MotionController, name) is getattr(Controller, name), name
    cfg, ctl, rec, reports, _ = _homing_session(tmp_path, Recording)
    assert all(r.ok for r in reports)
    for job in ctl.jobs:
        _no_shell_reachable(job)
