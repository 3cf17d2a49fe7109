"""The controller's SDO client (controller.canopen.protocol.sdo): expedited and segmented transfers
against python canopen's SDO server (the simulated devices are canopen LocalNodes), on the
stepped virtual bus; the frames on the bus checked against CiA 301."""

from __future__ import annotations

import struct

import pytest
from canopen.objectdictionary import VISIBLE_STRING, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from controller.canopen.io.transport import SteppedTransport
from controller.canopen.protocol.sdo import (
    ABORT_GENERAL,
    ABORT_TOGGLE,
    ABORT_VALUE_RANGE,
    SdoAbortError,
    SdoClient,
)
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import load
from controller.errors import CanError

SERVO = 11


@pytest.fixture
def world(tmp_path):
    w = SimWorld(load(tmp_path), record=True)
    w.transport.run_until(w.clock.now_ns() + 10_000_000)  # the devices' power-on boot-up
    yield w
    w.close()


def _frames(world, cob):
    """The data of every frame with this COB-ID on the bus so far (the world's recorder)."""
    return [bytes(d) for _, cid, d in world.recorder.frames if cid == cob]


def test_segmented_upload_of_the_device_name(world):
    sdo = SdoClient(world.transport, SERVO, "node 11 (x)", 0.05)
    assert sdo.upload(0x1008, 0) == b"cantrack servo"        # 14 bytes: 2 segments
    requests, responses = _frames(world, 0x600 + SERVO), _frames(world, 0x580 + SERVO)
    assert requests[0][:4] == bytes([0x40, 0x08, 0x10, 0x00])
    assert responses[0][0] == 0x41 and struct.unpack_from("<I", responses[0], 4)[0] == 14
    assert [r[0] for r in requests[1:]] == [0x60, 0x70]     # upload segment, toggle 0, 1
    assert responses[1][0] == 0x00 and responses[2][0] == 0x10 | ((7 - 7) << 1) | 1
    assert sdo.upload(0x100A, 0) == b"0.1.0"                # 5 bytes: segmented too
    assert sdo.upload_uint(0x1018, 1) == 0x00CA7AC0          # expedited unchanged


def test_segmented_download_round_trip(world):
    node = world.device("x").node
    var = ODVariable("test string", 0x2F00, 0)
    var.data_type, var.access_type = VISIBLE_STRING, "rw"
    node.object_dictionary.add_object(var)
    sdo = SdoClient(world.transport, SERVO, "node 11 (x)", 0.05)
    text = b"twenty bytes exactly"
    sdo.download(0x2F00, 0, text)
    requests = _frames(world, 0x600 + SERVO)
    assert requests[0][0] == 0x21 and struct.unpack_from("<I", requests[0], 4)[0] == 20
    # 3 segments (7 + 7 + 6 bytes): toggles 0, 1, 0; the last says 1 unused byte and c = 1
    assert [r[0] for r in requests[1:]] == [0x00, 0x10, 0x00 | (1 << 1) | 1]
    assert b"".join(r[1:8] for r in requests[1:])[:20] == text
    assert sdo.upload(0x2F00, 0) == text


def test_a_server_that_does_not_alternate_the_toggle_is_aborted(world):
    """A fake node 99 answers every upload segment with toggle 0: the client aborts with
    05030000h (CiA 301) and names the object."""
    server = SteppedTransport(world.world)   # another participant on the bus
    sent = []

    def fake_server(can_id, data, t_ns):
        sent.append(bytes(data))
        if data[0] == 0x40:
            server.send(0x580 + 99, bytes([0x41]) + data[1:4] + struct.pack("<I", 20))
        elif data[0] & 0xE0 == 0x60:
            server.send(0x580 + 99, bytes([0x00]) + b"abcdefg")   # always toggle 0, not last
    server.subscribe(0x600 + 99, fake_server)
    t = world.transport
    sdo = SdoClient(t, 99, "node 99", 0.05)
    with pytest.raises(CanError, match=r"node 99: SDO toggle bit not alternated reading "
                                       r"1008h:00 \(aborted: 05030000h\)"):
        sdo.upload(0x1008, 0)
    t.run_until(world.clock.now_ns() + 1_000_000)
    abort = sent[-1]
    assert abort[0] == 0x80 and abort[1:4] == bytes([0x08, 0x10, 0x00])
    assert struct.unpack_from("<I", abort, 4)[0] == ABORT_TOGGLE


def test_one_sdo_abort_type_for_the_client_and_the_slaves():
    """SdoAbortError is cantrack's CanError and python canopen's SdoAbortedError (what its
    LocalNode SDO server answers with the code): one type on both sides."""
    e = SdoAbortError(ABORT_VALUE_RANGE, "node 11 (x)", 0x60C2, 2, "writing")
    assert isinstance(e, CanError) and isinstance(e, SdoAbortedError)
    assert e.code == 0x06090030
    assert str(e) == ("node 11 (x): SDO abort 06090030h (Value range of parameter exceeded) "
                      "writing 60C2h:02")
    assert str(SdoAbortError(ABORT_GENERAL)) == "SDO abort 08000000h (General error)"


def test_a_simulated_device_refuses_with_the_same_abort_the_client_raises(world):
    """A mode the simulated drive does not support written to 6060h (its on_write raises
    SdoAbortError) comes back to the client as SdoAbortError with that code."""
    sdo = SdoClient(world.transport, SERVO, "node 11 (x)", 0.05)
    with pytest.raises(SdoAbortError) as info:
        sdo.download(0x6060, 0, (99).to_bytes(1, "little", signed=True))
    assert info.value.code == ABORT_VALUE_RANGE
    assert info.value.index == 0x6060

