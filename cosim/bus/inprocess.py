"""The in-process bus of ``--interface virtual``: frames handed to the other receivers as they are.

python-can's ``virtual`` interface deep-copies every ``can.Message`` once per receiver (about 20 µs
a frame with three participants, the largest cost of an in-process run after the log). Here a
frame is immutable once sent (nothing in cosim changes a frame it sent or received), so every
receiver on the channel gets the same object: a send appends it to each other receiver's queue.
Order is the send order, delivery is reliable and a bus never receives its own frames, as on
python-can's ``virtual`` bus. Receivers may be in other threads of the process: one waiting in
``recv`` is woken by the next send.

It is registered as the python-can interface ``cosim_virtual`` (``can.Bus(interface="cosim_virtual",
channel=...)``); ``cosim.bus.transport.open_bus`` opens it for a run whose interface is ``virtual``.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

import can
from can.bus import BusABC, CanProtocol

#: channel -> the receive queues of the buses open on it
_channels: dict[Any, list[InProcessBus]] = {}
_lock = threading.Lock()


class InProcessBus(BusABC):
    """A bus shared by every ``InProcessBus`` of the process opened on the same ``channel``."""

    def __init__(self, channel: Any = "cosim", fd: bool = True, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        self.channel_id = channel
        self.channel_info = f"cosim in-process bus channel {channel}"
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        self._queue: deque[can.Message] = deque()
        self._ready = threading.Condition(threading.Lock())
        self._waiting = False
        self._open = True
        with _lock:
            self._peers = _channels.setdefault(channel, [])
            self._peers.append(self)
            self._others: tuple[InProcessBus, ...] = ()
            for bus in self._peers:
                bus._others = tuple(b for b in bus._peers if b is not bus)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        for bus in self._others:
            bus._queue.append(msg)
            if bus._waiting:
                with bus._ready:
                    bus._ready.notify()

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is None:  # the common cases: no filters, a frame waiting or none to wait for
            if self._queue:
                return self._queue.popleft()
            if timeout is not None and timeout <= 0:
                return None
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        if self._queue:
            return self._queue.popleft(), False
        if timeout is not None and timeout <= 0:
            return None, False
        with self._ready:
            self._waiting = True
            try:
                if not self._queue:
                    self._ready.wait(timeout)
            finally:
                self._waiting = False
        return (self._queue.popleft(), False) if self._queue else (None, False)

    def shutdown(self) -> None:
        super().shutdown()
        if not self._open:
            return
        self._open = False
        with _lock:
            self._peers.remove(self)
            for bus in self._peers:
                bus._others = tuple(b for b in bus._peers if b is not bus)
            if not self._peers:
                del _channels[self.channel_id]
