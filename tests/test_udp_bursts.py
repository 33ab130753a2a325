"""``cosim_udp`` opened the way any python-can program opens it (``can.Bus(interface="cosim_udp")``,
python-can's ``ThreadSafeBus``) keeps every frame of a burst: its socket asks for a receive buffer
that holds one (the kernel's default, about 200 kB, held a few hundred datagrams, and python-can's
own concurrent-writes test then lost frames and waited forever for them about one run in three)."""

from __future__ import annotations

import socket
import time
from multiprocessing.pool import ThreadPool

import can
import pytest

from cosim.bus.transport import allocate
from cosim.bus.udp import RECEIVE_BUFFER, SO_RCVBUFFORCE

FRAME = can.Message(arbitration_id=0x123, is_extended_id=True, data=[254, 255, 1, 2])


def python_can_bus(config, thread_safe: bool = False) -> can.BusABC:
    kind = can.ThreadSafeBus if thread_safe else can.Bus
    return kind(interface="cosim_udp", channel=config.channel, port=config.port, fd=True)


def privileged() -> bool:
    """Whether this process may pass the system's limit on receive buffers (SO_RCVBUFFORCE)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RECEIVE_BUFFER)
            return True
        except OSError:
            return False


def test_the_socket_asks_for_room_for_bursts_however_the_bus_is_opened():
    config = allocate("udp_multicast")
    with python_can_bus(config) as bus:
        room = bus._multicast._socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    limit = int(open("/proc/sys/net/core/rmem_max").read()) if not privileged() else RECEIVE_BUFFER
    assert room >= min(RECEIVE_BUFFER, limit)  # Linux reports twice what was granted


def receive(bus: can.BusABC, count: int, seconds: float) -> list[can.Message]:
    deadline, got = time.monotonic() + seconds, []
    while len(got) < count and time.monotonic() < deadline:
        frame = bus.recv(0.05)
        if frame is not None:
            got.append(frame)
    return got


@pytest.mark.skipif(not privileged(), reason="the system caps receive buffers below a burst's size")
def test_a_burst_sent_before_the_receiver_reads_arrives_whole():
    config = allocate("udp_multicast")
    with python_can_bus(config) as receiver, python_can_bus(config) as sender:
        for _ in range(2000):
            sender.send(FRAME)
        got = receive(receiver, 2000, 10.0)
        assert len(got) == 2000 and receiver.kernel_dropped == 0
        assert all(FRAME.equals(frame, timestamp_delta=None) for frame in got)


@pytest.mark.skipif(not privileged(), reason="the system caps receive buffers below a burst's size")
def test_concurrent_writes_from_a_hundred_threads_all_arrive():
    """python-can's ThreadSafeBus test: 1000 identical frames sent from 100 threads while 100 threads
    receive, here each receiver with a deadline instead of waiting forever."""
    config = allocate("udp_multicast")
    sender, receiver = python_can_bus(config, True), python_can_bus(config, True)
    senders, receivers = ThreadPool(100), ThreadPool(100)
    try:
        deadline = time.monotonic() + 20.0

        def one(_: None) -> can.Message | None:
            while time.monotonic() < deadline:
                if (frame := receiver.recv(0.05)) is not None:
                    return frame
            return None

        senders.map_async(sender.send, 1000 * [FRAME])
        got = receivers.map(one, 1000 * [None])
        assert sum(frame is None for frame in got) == 0, f"lost; the kernel dropped {receiver.kernel_dropped}"
        assert all(FRAME.equals(frame, timestamp_delta=None) for frame in got)
        assert receiver.recv(0.2) is None  # and no frame twice
    finally:
        senders.close()
        receivers.close()
        senders.join()
        receivers.join()
        sender.shutdown()
        receiver.shutdown()
