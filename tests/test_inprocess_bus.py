"""cosim's in-process bus (``--interface virtual``): every receiver gets each frame in order, a python-can
program its own copy as python-can's virtual bus gives it, cosim's own buses the very frame.
(python-can's own interface tests run against it in tests/test_python_can_interfaces.py.)"""

from __future__ import annotations

import gc
import threading
import time
import weakref

import can
import pytest

from cosim.bus import inprocess
from cosim.bus.inprocess import InProcessBus
from cosim.bus.transport import DRAIN_LIMIT, allocate, drain_silent, open_bus, silent
from tests.test_bench import bench


def frame(identifier: int) -> can.Message:
    return can.Message(arbitration_id=identifier, data=bytes([identifier & 0xFF]), is_extended_id=False)


def taken(bus: can.BusABC) -> list[can.Message]:
    return list(iter(lambda: bus.recv(0.0), None))


def test_cosim_buses_hand_each_other_the_very_frames_in_order():
    with (
        InProcessBus("t-order", share_frames=True) as a,
        InProcessBus("t-order", share_frames=True) as b,
        InProcessBus("t-order", share_frames=True) as c,
        InProcessBus("t-other", share_frames=True) as elsewhere,
    ):
        sent = [frame(i) for i in range(5)]
        for message in sent:
            a.send(message)
        for bus in (b, c):
            assert all(x is y for x, y in zip(taken(bus), sent, strict=True))  # no copies
        assert a.recv(0.0) is None and elsewhere.recv(0.0) is None  # not its own frames; not another channel


def test_a_python_can_program_gets_what_python_cans_virtual_bus_gives_it():
    """Field by field what python-can's virtual bus delivers (but the time stamp), whoever sent it."""
    message = can.Message(
        arbitration_id=0x123456, data=bytes(range(12)), is_fd=True, bitrate_switch=True, error_state_indicator=True
    )
    with (
        can.Bus(interface="virtual", channel="t-copy") as virtual_sender,
        can.Bus(interface="virtual", channel="t-copy") as virtual_receiver,
        InProcessBus("t-copy", share_frames=True) as cosim,
        can.Bus(interface="cosim_virtual", channel="t-copy") as program,
        can.Bus(interface="cosim_virtual", channel="t-copy") as other_program,
    ):
        virtual_sender.send(message)
        expected = virtual_receiver.recv(0.0)
        for sender, receiver in ((cosim, program), (program, cosim), (program, other_program)):
            before = time.time()
            sender.send(message)
            got = receiver.recv(0.0)
            assert got is not message and got.data is not message.data
            assert before <= got.timestamp <= time.time()
            got.timestamp = expected.timestamp
            assert [getattr(got, f) for f in FIELDS] == [getattr(expected, f) for f in FIELDS]
            got.data[0] = 0xFF  # the receiver's own copy
            assert message.data[0] == 0
            for bus in (cosim, program, other_program):
                taken(bus)


FIELDS = [name for name in can.Message.__slots__ if name != "__weakref__"]


def test_the_copy_sets_every_field_of_a_message():
    copy = inprocess.received(frame(1), 1.5, "c", True)
    assert all(hasattr(copy, name) for name in FIELDS)  # a field python-can adds would be missing here


def test_own_frames_come_back_with_receive_own_messages_and_timestamps_are_kept_on_request():
    with (
        can.Bus(interface="cosim_virtual", channel="t-own", receive_own_messages=True, preserve_timestamps=True) as a,
        can.Bus(interface="cosim_virtual", channel="t-own") as b,
    ):
        message = frame(3)
        message.timestamp = 12.5
        a.send(message)
        own, other = a.recv(0.0), b.recv(0.0)
        assert (own.is_rx, other.is_rx) == (False, True) and own.timestamp == other.timestamp == 12.5
        assert own is not other and a.recv(0.0) is None


def test_a_closed_bus_raises_and_gets_nothing_more_and_a_new_one_only_what_follows():
    with can.Bus(interface="cosim_virtual", channel="t-close") as a:
        b = can.Bus(interface="cosim_virtual", channel="t-close")
        a.send(frame(1))
        b.shutdown()
        with pytest.raises(can.CanOperationError):
            b.recv(0.0)  # even with a frame left in its queue
        with pytest.raises(can.CanOperationError):
            b.send(frame(1))
        a.send(frame(2))
        with can.Bus(interface="cosim_virtual", channel="t-close") as c:
            a.send(frame(3))
            assert [m.arbitration_id for m in taken(c)] == [3]


def test_a_bus_nobody_shuts_down_is_collected_and_leaves_its_channel():
    with InProcessBus("t-dropped", share_frames=True) as a:
        for shares in (True, False):
            dropped = InProcessBus("t-dropped", share_frames=shares)
            gone = weakref.ref(dropped)
            a.send(frame(1))
            del dropped
            gc.collect()
            assert gone() is None and len(inprocess._channels["t-dropped"]) == 1


def test_a_receiver_waiting_in_another_thread_is_woken_by_a_send_and_by_its_shutdown():
    with (
        can.Bus(interface="cosim_virtual", channel="t-wake") as a,
        can.Bus(interface="cosim_virtual", channel="t-wake") as b,
    ):
        got: list[can.Message | None] = []
        waiter = threading.Thread(target=lambda: got.append(b.recv(5.0)))
        waiter.start()
        a.send(frame(7))
        waiter.join(5.0)
        assert got and got[0] is not None and got[0].arbitration_id == 7
        assert b.recv(0.01) is None  # a timeout with nothing sent
        raised: list[Exception] = []

        def wait() -> None:
            try:
                b.recv(30.0)
            except can.CanOperationError as error:
                raised.append(error)

        waiter = threading.Thread(target=wait)
        waiter.start()
        time.sleep(0.05)
        started = time.monotonic()
        b.shutdown()
        waiter.join(5.0)
        assert raised and time.monotonic() - started < 5.0


def test_filters_are_applied():
    with (
        can.Bus(interface="cosim_virtual", channel="t-filter") as a,
        can.Bus(interface="cosim_virtual", channel="t-filter", can_filters=[{"can_id": 0x100, "can_mask": 0x7FF}]) as b,
    ):
        a.send(frame(0x101))
        a.send(frame(0x100))
        assert b.recv(1.0).arbitration_id == 0x100 and b.recv(0.0) is None


def test_a_virtual_run_bus_is_the_in_process_bus_handing_frames_over_as_they_are():
    config = allocate("virtual")
    assert config.kwargs()["interface"] == "cosim_virtual"
    assert "interface='cosim_virtual'" in config.python_can()
    with open_bus(config) as runner, open_bus(config) as node, can.Bus(**config.kwargs()) as program:
        assert isinstance(runner, InProcessBus)
        message = frame(5)
        runner.send(message)
        assert node.recv(0.0) is message and program.recv(0.0) is not message


def test_the_benchmark_measures_the_three_buses_side_by_side():
    figures = bench("inprocess_bus.py", "--frames", "2000", "--receivers", "2", "--repeat", "1")
    assert figures["receivers"] == 2
    for key in ("virtual_frames_per_s", "cosim_virtual_frames_per_s", "cosim_own_frames_per_s"):
        assert figures[key] > 0, key


def test_a_bus_alone_on_its_channel_is_silent_once_the_others_leave():
    """The runner's last drain waits for late frames only while another bus could still send them."""
    with InProcessBus("t-alone", share_frames=True) as runner:
        assert runner.alone and silent(runner)
        node = InProcessBus("t-alone", share_frames=True)
        assert not runner.alone and not silent(runner)
        node.send(frame(1))
        node.shutdown()
        assert runner.alone and silent(runner)
        assert [f.arbitration_id for f in taken(runner)] == [1]  # what was sent before it left is still there
        with InProcessBus("t-alone", share_frames=True) as flood:  # more than one drain takes
            for i in range(DRAIN_LIMIT + 100):
                flood.send(frame(i % 0x7FF))
        assert runner.alone and len(list(drain_silent(runner))) == DRAIN_LIMIT + 100
    with can.Bus(interface="virtual", channel="t-alone-virtual") as other:
        assert not silent(other)  # python-can's: it cannot tell
