"""Datagrams crafted against the receive path: well-formed msgpack whose fields are not a CAN
frame's is counted as foreign, never raises, and never makes the receiver allocate more than the
datagram itself."""

from __future__ import annotations

import math
import socket
import tracemalloc

import can
import msgpack
import pytest
from can.interfaces.udp_multicast.utils import pack_message

from cosim.bus.transport import allocate, open_bus
from cosim.bus.udp import BATCH_TAG, MAX_BATCH, pack_batch, unpack_datagram, unpack_frames

GOOD = {
    "timestamp": 0.0,
    "arbitration_id": 0x100,
    "is_extended_id": False,
    "is_remote_frame": False,
    "is_error_frame": False,
    "channel": None,
    "dlc": 2,
    "data": b"\x01\x02",
    "is_fd": False,
    "bitrate_switch": False,
    "error_state_indicator": False,
}

CRAFTED = {
    "a float identifier": {"arbitration_id": 256.0},
    "a NaN identifier": {"arbitration_id": math.nan},
    "a negative identifier": {"arbitration_id": -1},
    "an identifier past 11 bits": {"arbitration_id": 0x800},
    "an identifier past 29 bits": {"arbitration_id": 1 << 29, "is_extended_id": True},
    "a huge integer identifier": {"arbitration_id": 2**63},
    "an integer payload (would allocate that many bytes)": {"data": 500_000_000},
    "a string payload": {"data": "abc"},
    "a list payload": {"data": [1, 2, 3]},
    "a 9-byte classic payload": {"data": bytes(9)},
    "a 10-byte FD payload (no CAN FD length)": {"data": bytes(10), "is_fd": True},
    "a flag that is a string": {"is_fd": "yes"},
    "a flag that is a number": {"is_extended_id": 1},
}


def crafted(change: dict) -> bytes:
    return msgpack.packb(GOOD | change, use_bin_type=True)


def test_a_python_can_datagram_unpacks_to_its_frame():
    frame = can.Message(arbitration_id=0x123, data=bytes(range(12)), is_extended_id=False, is_fd=True)
    got = unpack_datagram(pack_message(frame), 5.0)
    assert got.arbitration_id == 0x123 and got.data == frame.data and got.is_fd and got.timestamp == 5.0
    assert unpack_datagram(crafted({}), 0.0).data == b"\x01\x02"


@pytest.mark.parametrize("change", CRAFTED.values(), ids=CRAFTED.keys())
def test_fields_that_are_not_a_frames_are_refused_in_one_line(change):
    with pytest.raises(ValueError) as refused:
        unpack_datagram(crafted(change), 0.0)
    assert "\n" not in str(refused.value)


@pytest.mark.parametrize("data", [b"", b"\xc1", msgpack.packb([1, 2]), msgpack.packb({}), b"\x92" * 100])
def test_what_is_no_map_of_fields_is_refused(data):
    with pytest.raises(ValueError):
        unpack_datagram(data, 0.0)


def test_a_batch_unpacks_to_its_frames_in_order():
    frames = [
        can.Message(arbitration_id=0x100, data=b"\x01\x02", is_extended_id=False),
        can.Message(arbitration_id=0x1FFFFFFF, data=bytes(range(64)), is_fd=True, bitrate_switch=True),
        can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=3, is_extended_id=False),
    ]
    got = unpack_frames(pack_batch(frames), 7.0)
    assert [g.equals(f, timestamp_delta=None) for g, f in zip(got, frames, strict=True)] == [True] * 3
    assert {g.timestamp for g in got} == {7.0}
    assert [g.arbitration_id for g in unpack_frames(pack_message(frames[0]), 0.0)] == [0x100]  # python-can's own


BAD_BATCHES = {
    "another tag": ["cosim/2", [0x100, 0, 1, b"\x01"]],
    "an item of three": [BATCH_TAG, [0x100, 0, b"\x01"]],
    "flags out of range": [BATCH_TAG, [0x100, 64, 1, b"\x01"]],
    "a float identifier": [BATCH_TAG, [256.0, 0, 1, b"\x01"]],
    "an integer payload": [BATCH_TAG, [0x100, 0, 1, 500_000_000]],
    "a 9-byte classic payload": [BATCH_TAG, [0x100, 0, 9, bytes(9)]],
    "one bad frame among good ones": [BATCH_TAG, [0x100, 0, 1, b"\x01"], [0x800, 0, 1, b"\x01"]],
    "more frames than a batch holds": [BATCH_TAG, *([[0x100, 0, 1, b"\x01"]] * (MAX_BATCH + 1))],
}


@pytest.mark.parametrize("batch", BAD_BATCHES.values(), ids=BAD_BATCHES.keys())
def test_a_batch_with_anything_that_is_not_a_frame_is_refused_whole(batch):
    with pytest.raises(ValueError) as refused:
        unpack_frames(msgpack.packb(batch, use_bin_type=True), 0.0)
    assert "\n" not in str(refused.value)


def test_a_batch_goes_out_in_one_datagram_and_comes_in_frame_by_frame():
    config = allocate("udp_multicast")
    frames = [
        can.Message(arbitration_id=0x100 + i, data=i.to_bytes(2, "little"), is_extended_id=False) for i in range(300)
    ]
    with open_bus(config) as sender, open_bus(config) as receiver:
        sender.send_batch(frames)  # MAX_BATCH + 44: two datagrams
        got = [receiver.recv(1.0) for _ in frames]
        assert [g.arbitration_id for g in got] == [f.arbitration_id for f in frames] and receiver.recv(0.1) is None
        assert receiver.kernel_dropped == 0 and receiver.foreign == 0


@pytest.mark.slow
def test_the_runs_socket_counts_each_crafted_datagram_and_allocates_nothing_for_it():
    config = allocate("udp_multicast")
    with open_bus(config) as bus:
        family = socket.AF_INET6 if ":" in config.channel else socket.AF_INET
        with socket.socket(family, socket.SOCK_DGRAM) as sender:
            tracemalloc.start()
            for change in CRAFTED.values():
                sender.sendto(crafted(change), (config.channel, config.port))
                assert bus.recv(1.0) is None
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        assert bus.foreign == len(CRAFTED)
        assert peak < 1_000_000  # the integer payload would have been 500 MB
        sender_bus = can.Bus(**config.kwargs())
        with sender_bus:  # and the bus still receives frames
            sender_bus.send(can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False))
            assert bus.recv(1.0).data == b"\x01"


def test_the_datagrams_the_kernel_drops_in_a_flood_are_counted():
    """20 000 frames sent before the receiver reads any overflow its socket's buffer (cut to 256 kB
    here: the run's asks for room for bursts): what it reads and what the kernel says it dropped
    (SO_RXQ_OVFL, told with the next datagram) add up to what was sent."""
    config = allocate("udp_multicast")
    with open_bus(config) as receiver, open_bus(config) as sender:
        receiver._multicast._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 256 * 1024)
        frame = can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False)
        for _ in range(20_000):
            sender.send(frame)
        received = 0
        while receiver.recv(0.2) is not None:
            received += 1
        sender.send(frame)  # the next datagram carries the count
        received += receiver.recv(2.0) is not None
        assert receiver.kernel_dropped > 0, "the flood did not overflow the buffer"
        assert received + receiver.kernel_dropped == 20_001


def test_a_flood_is_named_as_the_cause_of_a_failure_and_a_trickle_is_not():
    from cosim.run.outcome import flood_report

    last = "0x7F0 (id 0x7F0, data 00)"
    assert flood_report(50, 10.0, 0, last) is None  # 5 per second: not a flood
    named = flood_report(30_000, 2.0, 0, last)
    assert named is not None and "15000/s" in named and "0x7F0" in named and "not the participant" in named
    assert flood_report(10, 10.0, 3, last) is not None  # the kernel dropped datagrams: a flood whatever the rate
