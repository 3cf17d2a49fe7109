"""``cantrack demo`` runs on the softMC conveyor model (:mod:`controller.conveyor`).

The demo's application (:class:`controller.canopen.apps.demo.PickPlace`) is a RobotGroup on a
linear MovingFrame fed by the controller's belt estimate: photo-eye edges are TRIGGERs in the
robot's trigger buffer, the frame's window decides when tracking starts and reports missed
items (30238), NEXTITEM after each pick, and the robot's setpoint is what goes to the drives.
"""

from __future__ import annotations

import json
from dataclasses import replace

from controller.canopen.apps.demo import PhotoEye, PickPlace, Step

from controller.canopen.config import load_config
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.slave.world import SimWorld
from controller.cli import demo as cmd_demo
from controller.conveyor import ITEM_MISSED_CODE, LINEAR, ItemStatus, MovingFrame, RobotGroup


def _run(demo, extra_trigger=False, max_cycles=8000, watch=None, on_world=None):
    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    demo = replace(cfg.demo, **demo)
    app = PickPlace(demo)
    with SimWorld(cfg) as world:
        if on_world is not None:
            on_world(world)
        ctl = Controller(cfg, world.transport, app)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, demo,
                           world.clock.now_ns() * 1e-9)
        triggered = False
        while ctl.k < max_cycles:
            ctl.step()
            if ctl.phase is Phase.ENABLING:
                continue
            if watch is not None:
                watch(ctl, app)
            if ctl.source_done:
                break
            if extra_trigger and not triggered and app.eye.detected == 1:
                triggered = True  # a second item right behind the first (a PLC trigger)
                app.eye.trigger(ctl.clock.now_ns())
    return ctl, app


def test_demo_runs_on_the_conveyor_model():
    seen = {"setpoint_ok": 0, "steps": set(), "buffer_max": 0}

    def watch(ctl, app):
        seen["steps"].add(app.stage)
        r = app.robot
        if r is None or r.last_output is None or ctl.last_output is None:
            return
        seen["buffer_max"] = max(seen["buffer_max"], len(r.buffer))
        # the controller's setpoint is the robot group's (the tracker passes it through)
        if ctl.source.tracker.state.name == "SYNCED":
            d = max(abs(a - b) for a, b in zip(ctl.last_output.setpoint.pos,
                                               r.last_output.setpoint.pos))
            assert d < 1e-9
            seen["setpoint_ok"] += 1

    ctl, app = _run({"items": 3}, watch=watch)
    items = app.items()
    assert [i.outcome for i in items] == ["placed"] * 3
    assert isinstance(app.robot, RobotGroup) and isinstance(app.frame, MovingFrame)
    assert app.frame.type == LINEAR and app.robot.slave == 0
    w0, w1 = ctl.cfg.tracking.window
    assert app.frame.window.upstream[0] == w0 - app.demo.photo_eye
    assert app.frame.window.downstream[0] == w1 - app.demo.photo_eye
    assert seen["setpoint_ok"] > 1000
    assert seen["steps"] == {Step.WAIT, Step.APPROACH, Step.FOLLOW, Step.PLACE}
    # every photo-eye edge went through the trigger buffer; NEXTITEM emptied it
    assert seen["buffer_max"] >= 1 and len(app.robot.buffer) == 0
    assert sorted(app.robot.records) == [i.entry_id for i in items]
    assert all(app.robot.records[i.entry_id].status == ItemStatus.CAUGHT for i in items)
    # IMFS: wait (0) -> synchronised (1) -> de-sync (-1) -> ... , once per item
    imfs = app.imfs_log
    runs = [v for k, v in enumerate(imfs) if k == 0 or imfs[k - 1] != v]
    assert runs[:4] == [0, 1, -1, 0] and runs.count(1) == 3 and runs.count(-1) == 3
    # the cycle records carry the robot group's IMFS
    rec_imfs = [r.imfs for r in ctl.trace if r.phase == "running"]
    assert set(rec_imfs) == {0, 1, -1}
    # the summary's figures come from the model: engaged (window entry) -> synchronised
    for it in items:
        m = it.model
        assert m["status"] == "caught" and m["time_to_sync_s"] is not None
        assert abs((it.synced_cycle - it.engage_cycle) * ctl.cfg.period_s
                   - m["time_to_sync_s"]) < 1e-9
        assert w0 <= it.u_pick < w1


def test_item_passing_the_window_while_the_robot_is_busy_is_missed_30238():
    ctl, app = _run({"items": 1, "place_dwell_s": 2.0}, extra_trigger=True)
    items = app.items()
    assert [i.outcome for i in items] == ["placed", "missed"]
    missed = items[1]
    assert str(ITEM_MISSED_CODE) in missed.reason and ITEM_MISSED_CODE == 30238
    rec = app.robot.records[missed.entry_id]
    assert rec.status == ItemStatus.MISSED and rec.error == "Item missed (30238)"
    assert missed.model["status"] == "missed"
    ev = [e for e in ctl.events if e.kind == "item_missed"]
    assert len(ev) == 1 and "30238" in ev[0].detail
    assert len(app.robot.buffer) == 0


def test_an_item_the_robot_leaves_on_a_tracker_error_is_missed_and_the_next_ones_placed():
    """One encoder sample a period stale while the robot synchronises with item 0 (what a
    late TPDO taken for the next SYNC's did in real time): the estimate's acceleration
    exceeds the frame's AccelerationMax, the link leaves the item (tracker error).  Before,
    the sequence waited in APPROACH for a synchronisation that never came: items 0, 1 and 2
    pending for 8000 cycles.  Now item 0 is missed, saying why, and 1 and 2 are placed."""
    enc = []
    glitch = {"cycle": None}

    def watch(ctl, app):
        r = app.robot
        if glitch["cycle"] is None and app.stage is Step.APPROACH and r.links \
                and r.links[0].tracker.state.name == "SYNCING":
            glitch["cycle"] = ctl.k
            # the next SYNC's sample reads the belt one period back (300 mm/s x 2 ms)
            enc[0]._offset -= round(300.0 * ctl.cfg.period_s * 40.96)
        elif glitch["cycle"] == ctl.k - 1:
            enc[0]._offset += round(300.0 * ctl.cfg.period_s * 40.96)

    ctl, app = _run({"items": 3}, watch=watch,
                    on_world=lambda w: enc.append(w.device(w.cfg.tracking.conveyor.node)))
    items = app.items()
    assert glitch["cycle"] is not None
    assert [i.outcome for i in items] == ["missed", "placed", "placed"]
    assert items[0].reason == "tracker error MASTER_ACCELERATION"
    assert app.robot.records[items[0].entry_id].error == "MASTER_ACCELERATION"
    ev = [e for e in ctl.events if e.kind == "item_missed"]
    assert len(ev) == 1 and "item 0" in ev[0].detail and "MASTER_ACCELERATION" in ev[0].detail
    assert ctl.source_done and ctl.k < 8000


def test_demo_telemetry_has_the_model_item_records(tmp_path, capsys):
    assert cmd_demo.main(["-q", "--no-plot", "--items", "2", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "items placed 2, missed 0, of 2" in out
    lines = [json.loads(x) for x in (tmp_path / "telemetry.jsonl").read_text().splitlines()]
    items = [d for d in lines if d["type"] == "item"]
    assert [d["model"]["status"] for d in items] == ["caught", "caught"]
    assert all(d["model"]["frame"] == "belt" and d["model"]["robot"] == "robot"
               for d in items)
    imfs = {d["imfs"] for d in lines if d["type"] == "cycle" and d["phase"] == "running"}
    assert imfs == {0, 1, -1}


def test_item_types_from_bus_yml_the_robot_picks_only_its_types(tmp_path):
    """.demo.item_types gives the photo-eye's items types in turn, .tracking.items.track_types
    the types the robot tracks: it places the type-2 items only; the type-1 items are ignored
    (never engaged, never missed, 30238)."""
    src = cmd_demo.DEFAULT_CONFIG.read_text(encoding="utf-8")
    assert "\n.demo:\n" in src and "  window:" in src
    assert "\n  items: 5\n" in src
    text = src.replace("\n  items: 5\n", "\n  items: 6\n  item_types: [1, 2]\n", 1)
    text = text.replace("  window:", "  items: {track_types: [2]}\n  window:", 1)
    from controller.canopen.config import parse_config

    cfg = parse_config(text, str(tmp_path / "bus.yml"),
                           base_dir=cmd_demo.DEFAULT_CONFIG.parent)
    assert cfg.tracking.track_types == frozenset({2}) and cfg.demo.item_types == (1, 2)
    app = PickPlace(cfg.demo)
    with SimWorld(cfg) as world:
        ctl = Controller(cfg, world.transport, app)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, cfg.demo,
                           world.clock.now_ns() * 1e-9)
        while ctl.k < 20000 and not ctl.source_done:
            ctl.step()
    items = app.items()
    assert [i.item_type for i in items] == [1, 2, 1, 2, 1, 2]
    assert {i.outcome for i in items if i.item_type == 2} == {"placed"}
    assert {i.outcome for i in items if i.item_type == 1} == {"ignored"}
    assert all(i.engage_cycle is None for i in items if i.item_type == 1)
    assert not any(i.outcome == "missed" for i in items)
    recs = {rec.item_id: rec for rec in app.robot.records.values()}
    assert all(recs[i.entry_id].status != ItemStatus.MISSED for i in items)


def test_item_type_errors_in_bus_yml_name_the_key():
    import pytest

    from controller.canopen.config import parse_config
    from controller.errors import ConfigError

    src = cmd_demo.DEFAULT_CONFIG.read_text(encoding="utf-8")
    for old, new, key in (
            ("  window:", "  items: {track_types: [2, 300]}\n  window:", "track_types[1]"),
            ("  window:", "  items: {track_types: []}\n  window:", "track_types"),
            ("  window:", "  items: {track_type: [1]}\n  window:", "track_type"),
            ("\n  items: 5\n", "\n  items: 5\n  item_types: [1, -1]\n", "item_types[1]")):
        with pytest.raises(ConfigError) as exc:
            parse_config(src.replace(old, new, 1), "bus.yml",
                             base_dir=cmd_demo.DEFAULT_CONFIG.parent)
        assert exc.value.key.endswith(key) and exc.value.line, (new, exc.value)
