"""The first real-SocketCAN tier: CANopen over vcan0 (native or in the VM), checked by tshark.

One run of :mod:`controller.testing.bus_selftest` (one VM boot for the whole module): a master
(canopen RemoteNodes) and a device process (canopen LocalNodes from our EDS files: encoder node
1, servo node 2) exchange NMT, SYNC with a counter, PDOs, SDO, heartbeats and an EMCY on a real
SocketCAN ``vcan0`` through python-can's ``socketcan`` interface, while can-utils' ``candump -L``
records the bus.  The capture is converted to pcap (link type 227) and decoded by Wireshark's
CANopen dissector (``tshark -d can.subdissector,canopen``): the tests below check what tshark
saw against what the run was configured to produce.

Timing inside the VM is emulated: the SYNC period is checked loosely (correctness, not speed).
The PDO and EMCY checks are windows of one or two SYNC periods: the period (50 ms on an idle
machine) is stretched by the host's slowness measured before the boot
(:func:`controller.testing.speed.fresh_factor`), so that a device process that answers late
on a busy machine is still within its cycle.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import pytest

from controller.testing.capture import (
    Kind,
    classify_capture,
    kinds_count,
    pdo_order_per_sync,
    problems,
    sync_period_stats,
)

pytestmark = pytest.mark.vcan

#: on an idle machine; x the measured slowness (``Run.period_s``)
SYNC_PERIOD_MS = 50.0
SYNC_OVERFLOW = 10
SYNC_COUNT = 40
ENCODER, SERVO = 1, 2
VENDOR_ID = 0x00CA7AC0
PRODUCT = {ENCODER: 0x04060001, SERVO: 0x04020001}
DEVICE_TYPE = {ENCODER: 0x00020196, SERVO: 0x00020192}
#: emulated time: the median SYNC period within 10 %, the mean within 25 % of the configured one
MEDIAN_TOL, MEAN_TOL = 0.10, 0.25


class Run:
    """The self-test's outputs: result.json, device.json and tshark's classification."""

    def __init__(self, vm, out: Path, frames):
        self.vm = vm
        self.out = out
        self.result = json.loads((out / "result.json").read_text())
        self.device = json.loads((out / "device.json").read_text())
        self.frames = frames
        #: the SYNC period of the run [s] (stretched)
        self.period_s = self.result["sync_period_s"]


@pytest.fixture(scope="module")
def selftest(vcan_runner, tshark_path, tmp_path_factory) -> Run:
    from controller.testing.speed import ENV, fresh_factor, window_factor

    scratch = tmp_path_factory.mktemp("vcan-selftest")
    out = scratch / "selftest"
    f = round(fresh_factor(), 3)
    r = vcan_runner.run([sys.executable, "-m", "controller.testing.bus_selftest", "run",
                         "--out", str(out), "--sync-period-ms",
                         f"{SYNC_PERIOD_MS * window_factor(f):.1f}",
                         "--sync-overflow", str(SYNC_OVERFLOW), "--sync-count", str(SYNC_COUNT)],
                        timeout_s=150, env={ENV: f"{f:.3f}"}, scratch_dir=scratch,
                        cwd=Path(__file__).resolve().parents[1])
    res = out / "result.json"
    detail = res.read_text() if res.is_file() else "(no result.json)"
    dev_out = out / "device.out"
    assert r.returncode == 0 and not r.timed_out, (
        f"self-test failed ({r.mode}, rc {r.returncode}, timed out {r.timed_out})\n"
        f"--- result.json ---\n{detail}\n--- stderr ---\n{r.stderr[-3000:]}\n"
        f"--- device ---\n{dev_out.read_text()[-3000:] if dev_out.is_file() else ''}")
    frames = classify_capture(out / "bus.log", tshark=tshark_path)
    return Run(r, out, frames)


def _of(frames, kind):
    return [f for f in frames if f.kind is kind]


def test_run_completed_and_capture_complete(selftest):
    res = selftest.result
    assert res["ok"] and res["device_returncode"] == 0 and res["candump_returncode"] == 0
    assert res["capture_dropped"] == 0
    assert len(selftest.frames) == res["capture_frames"] > 0
    assert (selftest.out / "bus.pcap").is_file()


def test_every_frame_classified_none_malformed(selftest):
    bad = problems(selftest.frames)
    assert not bad, f"{len(bad)} of {len(selftest.frames)} frames:\n" + "\n".join(bad[:30])


def test_every_service_present(selftest):
    counts = kinds_count(selftest.frames)
    assert set(counts) == {Kind.NMT, Kind.SYNC, Kind.PDO, Kind.SDO, Kind.EMCY, Kind.HEARTBEAT}, \
        counts


def test_nmt_commands_in_order(selftest):
    cmds = [(f.nmt_command, f.nmt_target) for f in _of(selftest.frames, Kind.NMT)]
    assert cmds == [(0x01, 0), (0x02, SERVO), (0x80, 0)]


def test_heartbeat_state_sequence(selftest):
    for node, want in ((ENCODER, [0, 127, 5, 127]), (SERVO, [0, 127, 5, 4, 127])):
        states = [f.nmt_state for f in _of(selftest.frames, Kind.HEARTBEAT) if f.node_id == node]
        changes = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
        assert changes == want, f"node {node}: {states}"
    # the boot-up is the first frame each node sends
    for node in (ENCODER, SERVO):
        first = next(f for f in selftest.frames if f.node_id == node and f.kind in (
            Kind.HEARTBEAT, Kind.PDO, Kind.SDO, Kind.EMCY) and f.direction != "rx")
        assert first.kind is Kind.HEARTBEAT and first.nmt_state == 0, first.describe()


def test_sdo_requests_and_answers(selftest):
    sdo = _of(selftest.frames, Kind.SDO)
    for node in (ENCODER, SERVO):
        req = [(f.sdo_index, f.sdo_subindex) for f in sdo if f.node_id == node
               and f.direction == "rx"]
        resp = [(f.sdo_index, f.sdo_subindex) for f in sdo if f.node_id == node
                and f.direction == "tx"]
        want = [(0x1000, 0)] + [(0x1018, s) for s in (1, 2, 3, 4)]
        if node == SERVO:
            want += [(0x6060, 0), (0x6060, 0)]   # download 8, upload it back
        assert req == want and resp == want, (node, req, resp)
        # expedited upload responses carry the EDS values (decoded by us from tshark's frames)
        values = {(f.sdo_index, f.sdo_subindex): struct.unpack_from("<I", f.data, 4)[0]
                  for f in sdo if f.node_id == node and f.direction == "tx"
                  and f.data[0] & 0xE0 == 0x40}
        assert values[(0x1000, 0)] == DEVICE_TYPE[node]
        assert values[(0x1018, 1)] == VENDOR_ID
        assert values[(0x1018, 2)] == PRODUCT[node]
    assert selftest.result["sdo"][str(SERVO)]["6060_readback"] == 8


def test_sync_period_and_counter(selftest):
    stats = sync_period_stats(selftest.frames, overflow=SYNC_OVERFLOW)
    # every SYNC the master and the device saw is in the capture, and nothing else
    assert stats.count == selftest.result["syncs_seen"] == selftest.device["syncs"], \
        stats.describe()
    assert SYNC_COUNT <= stats.count <= SYNC_COUNT + 3, stats.describe()
    assert stats.counters[0] == 1 and not stats.counter_gaps, stats.describe()
    assert list(stats.counters) == [(i % SYNC_OVERFLOW) + 1 for i in range(stats.count)]
    assert list(stats.counters) == selftest.device["counters"]
    period = selftest.period_s
    from controller.testing.speed import window_factor
    assert period == pytest.approx(SYNC_PERIOD_MS / 1e3 * window_factor(selftest.vm.speed_factor),
                                   abs=1e-4)
    assert abs(stats.period_median_s - period) <= MEDIAN_TOL * period, stats.describe()
    assert abs(stats.period_mean_s - period) <= MEAN_TOL * period, stats.describe()


def test_pdo_order(selftest):
    """TPDO1 (transmission type 1) of the encoder then of the servo after every SYNC; the
    master's RPDO1 to the servo once per SYNC; the k-th of each follows the k-th SYNC."""
    frames = selftest.frames
    n_sync = len(_of(frames, Kind.SYNC))
    pdos = _of(frames, Kind.PDO)
    assert {(f.can_id, f.pdo, f.direction) for f in pdos} == {
        (0x181, 1, "tx"), (0x182, 1, "tx"), (0x202, 1, "rx")}
    device_seq = [f.can_id for f in pdos if f.can_id in (0x181, 0x182)]
    assert device_seq == [0x181, 0x182] * n_sync
    sync_t = [f.time_s for f in _of(frames, Kind.SYNC)]
    for cob in (0x181, 0x182, 0x202):
        times = [f.time_s for f in pdos if f.can_id == cob]
        assert len(times) == n_sync, (hex(cob), len(times), n_sync)
        late = [k for k, t in enumerate(times) if not (
            t > sync_t[k] and (k + 2 >= n_sync or t < sync_t[k + 2]))]
        assert not late, f"0x{cob:X}: PDOs {late} not after their SYNC"
    cycles = pdo_order_per_sync(frames)
    exact = sum(1 for c in cycles if [x for x in c if x != 0x202] == [0x181, 0x182]
                and c.count(0x202) == 1)
    assert exact >= 0.9 * n_sync, f"only {exact} of {n_sync} SYNC cycles hold exactly " \
                                  f"0x181, 0x182 (in this order) and one 0x202: {cycles}"
    assert selftest.result["tpdo1_received"] == {str(ENCODER): n_sync, str(SERVO): n_sync}
    assert selftest.device["rpdo1"] == n_sync


def test_emcy(selftest):
    emcy = [(f.node_id, f.emcy_code, f.emcy_register) for f in _of(selftest.frames, Kind.EMCY)]
    assert emcy == [(SERVO, 0x8611, 0x01), (SERVO, 0x0000, 0x00)]
    assert selftest.result["emcy"] == [{"node": SERVO, "code": 0x8611, "register": 1},
                                       {"node": SERVO, "code": 0, "register": 0}]
    # sent at the servo's 10th and 20th operational SYNC
    syncs = _of(selftest.frames, Kind.SYNC)
    for f, k in zip(_of(selftest.frames, Kind.EMCY), (10, 20)):
        assert syncs[k - 1].time_s < f.time_s < syncs[k + 1].time_s, f.describe()
