"""cosim's in-process bus (``--interface virtual``): every other receiver gets each frame, uncopied, in order."""

from __future__ import annotations

import threading

import can

from cosim.bus.inprocess import InProcessBus
from cosim.bus.transport import allocate, open_bus


def frame(identifier: int) -> can.Message:
    return can.Message(arbitration_id=identifier, data=bytes([identifier & 0xFF]), is_extended_id=False)


def test_every_other_bus_on_the_channel_gets_the_same_frame_in_order():
    with (
        can.Bus(interface="cosim_virtual", channel="t-order") as a,
        can.Bus(interface="cosim_virtual", channel="t-order") as b,
        can.Bus(interface="cosim_virtual", channel="t-order") as c,
        can.Bus(interface="cosim_virtual", channel="t-other") as elsewhere,
    ):
        assert isinstance(a, InProcessBus)
        sent = [frame(i) for i in range(5)]
        for message in sent:
            a.send(message)
        for bus in (b, c):
            got = list(iter(lambda bus=bus: bus.recv(0.0), None))
            assert all(x is y for x, y in zip(got, sent, strict=True))  # the very frames: no copies
        assert a.recv(0.0) is None and elsewhere.recv(0.0) is None  # not its own frames; not another channel


def test_a_closed_bus_gets_nothing_more_and_a_new_one_only_what_follows():
    with can.Bus(interface="cosim_virtual", channel="t-close") as a:
        b = can.Bus(interface="cosim_virtual", channel="t-close")
        a.send(frame(1))
        b.shutdown()
        a.send(frame(2))
        with can.Bus(interface="cosim_virtual", channel="t-close") as c:
            a.send(frame(3))
            assert c.recv(0.0).arbitration_id == 3 and c.recv(0.0) is None


def test_a_receiver_waiting_in_another_thread_is_woken_by_a_send():
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


def test_filters_are_applied():
    with (
        can.Bus(interface="cosim_virtual", channel="t-filter") as a,
        can.Bus(interface="cosim_virtual", channel="t-filter", can_filters=[{"can_id": 0x100, "can_mask": 0x7FF}]) as b,
    ):
        a.send(frame(0x101))
        a.send(frame(0x100))
        assert b.recv(1.0).arbitration_id == 0x100 and b.recv(0.0) is None


def test_a_virtual_run_bus_is_the_in_process_bus():
    config = allocate("virtual")
    assert config.kwargs()["interface"] == "cosim_virtual"
    assert "interface='cosim_virtual'" in config.python_can()
    bus = open_bus(config)
    try:
        assert isinstance(bus, InProcessBus)
    finally:
        bus.shutdown()
