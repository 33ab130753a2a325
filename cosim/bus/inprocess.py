"""The in-process bus of ``--interface virtual``: python-can's ``virtual`` bus, without its deep copies.

Every bus of the process opened on the same ``channel`` gets every frame another one sends, in send
order, reliably, and its own frames too with ``receive_own_messages``. Receivers may be in other
threads of the process: one waiting in ``recv`` is woken by the next send.

What a receiver gets is what python-can's ``virtual`` bus gives it: its own copy of the frame (its
own ``data``), stamped with the send time (the sender's ``timestamp`` with ``preserve_timestamps``),
the bus's ``channel`` and ``is_rx`` (False on a bus's own frame). python-can's ``deepcopy`` of a
``can.Message`` costs about 5 µs; the copy here sets its fields directly, about 0.3 µs.

cosim's own participants (the runner and the nodes it drives in its process, as
``cosim.bus.transport.open_bus`` opens their buses) never change a frame they sent or received, and
they read neither the receive timestamp nor ``channel`` or ``is_rx``: their buses are opened with
``share_frames=True``, and a frame from one such bus to another is handed over as the very object,
unstamped. Any other delivery is a copy, so a python-can program on the channel sees python-can's
behaviour whoever sent the frame, and cosim never holds a frame a python-can program may still change.

It is registered as the python-can interface ``cosim_virtual`` (``can.Bus(interface="cosim_virtual",
channel=...)``). A bus that is dropped without ``shutdown()`` leaves its channel when it is collected,
as python-can's buses do.
"""

from __future__ import annotations

import threading
import time
import weakref
from collections import deque
from typing import Any

import can
from can.bus import BusABC, CanProtocol


class Pending:
    """The frames a bus received and has not taken yet, counted as python-can's virtual bus's ``queue``."""

    def __init__(self, frames: deque[can.Message]) -> None:
        self._frames = frames

    def empty(self) -> bool:
        return not self._frames

    def qsize(self) -> int:
        return len(self._frames)


class Receiver:
    """What the channel holds of a bus: its queue and how to wake it. The bus itself only weakly, so
    that a bus nobody shuts down is still collected (and leaves the channel)."""

    __slots__ = ("queue", "ready", "waiting", "shares", "bus")

    def __init__(self, bus: InProcessBus, shares: bool) -> None:
        self.queue: deque[can.Message] = deque()
        self.ready = threading.Condition(threading.Lock())
        self.waiting = False
        self.shares = shares
        self.bus = weakref.ref(bus)

    def put(self, msg: can.Message) -> None:
        self.queue.append(msg)
        if self.waiting:
            self.wake()

    def wake(self) -> None:
        with self.ready:
            self.ready.notify()


#: channel -> the receivers of the buses open on it
_channels: dict[Any, list[Receiver]] = {}
#: Reentrant: a bus collected (and so shut down) while this thread holds the lock leaves its channel at once.
_lock = threading.RLock()


def _route_all(members: list[Receiver]) -> None:
    """Every bus's fan-out from its channel's members (once more if a bus left meanwhile)."""
    while True:
        snapshot = tuple(members)
        for receiver in snapshot:
            if (bus := receiver.bus()) is not None:
                bus._route(snapshot)
        if tuple(members) == snapshot:
            return


def received(msg: can.Message, timestamp: float, channel: Any, is_rx: bool) -> can.Message:
    """A receiver's copy of ``msg``, as python-can's virtual bus makes it (without ``deepcopy``).
    Every field of ``can.Message`` (its ``__slots__``; ``tests/test_inprocess_bus.py`` checks the list)."""
    copy = can.Message.__new__(can.Message)
    copy.timestamp = timestamp
    copy.arbitration_id = msg.arbitration_id
    copy.is_extended_id = msg.is_extended_id
    copy.is_remote_frame = msg.is_remote_frame
    copy.is_error_frame = msg.is_error_frame
    copy.channel = channel
    copy.dlc = msg.dlc
    copy.data = bytearray(msg.data)
    copy.is_fd = msg.is_fd
    copy.is_rx = is_rx
    copy.bitrate_switch = msg.bitrate_switch
    copy.error_state_indicator = msg.error_state_indicator
    return copy


class InProcessBus(BusABC):
    """A bus shared by every ``InProcessBus`` of the process opened on the same ``channel``.

    ``receive_own_messages``, ``preserve_timestamps``: as python-can's ``virtual`` bus. ``share_frames``:
    frames between two buses that both set it pass as the very objects (see the module's documentation).
    ``queue``: how many frames it received and has not taken yet."""

    _share_to: tuple[Receiver, ...] = ()
    """The receivers that get this bus's frames as they are."""
    _copy_to: tuple[Receiver, ...] = ()
    """The receivers that get a copy of each."""

    def __init__(
        self,
        channel: Any = "cosim",
        fd: bool = True,
        receive_own_messages: bool = False,
        preserve_timestamps: bool = False,
        share_frames: bool = False,
        **kwargs: Any,
    ) -> None:
        super().__init__(channel=channel, **kwargs)
        self.channel_id = channel
        self.channel_info = f"cosim in-process bus channel {channel}"
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        self.receive_own_messages = receive_own_messages
        self.preserve_timestamps = preserve_timestamps
        self._receiver = Receiver(self, share_frames)
        self._queue = self._receiver.queue
        self.queue = Pending(self._queue)
        self._open = True
        with _lock:
            self._members = _channels.setdefault(channel, [])
            self._members.append(self._receiver)
            _route_all(self._members)

    def _route(self, members: tuple[Receiver, ...]) -> None:
        me = self._receiver
        self._share_to = tuple(r for r in members if r is not me and me.shares and r.shares)
        self._copy_to = tuple(
            r for r in members if r not in self._share_to and (r is not me or self.receive_own_messages)
        )

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        for receiver in self._share_to:
            receiver.queue.append(msg)
            if receiver.waiting:
                receiver.wake()
        if self._copy_to:
            timestamp = msg.timestamp if self.preserve_timestamps else time.time()
            for receiver in self._copy_to:
                receiver.put(received(msg, timestamp, self.channel_id, receiver is not self._receiver))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is None:  # the common cases: no filters, a frame waiting or none to wait for
            if self._queue:
                return self._queue.popleft()
            if timeout is not None and timeout <= 0 and self._open:
                return None
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        receiver = self._receiver
        if receiver.queue:
            return receiver.queue.popleft(), False
        if timeout is not None and timeout <= 0:
            return None, False
        with receiver.ready:
            receiver.waiting = True
            try:
                if not receiver.queue:
                    receiver.ready.wait(timeout)
            finally:
                receiver.waiting = False
        return (receiver.queue.popleft(), False) if receiver.queue else (None, False)

    def waiting(self) -> list[can.Message]:
        """The frames received and not taken yet, in order, left where they are."""
        return list(self._queue)

    def discard(self) -> None:
        """Drop every frame received and not taken yet (a receiver that knows what they would do)."""
        self._queue.clear()

    @property
    def alone(self) -> bool:
        """No other bus is open on this channel: nothing can arrive but what is queued already."""
        with _lock:
            return self._members == [self._receiver]

    def shutdown(self) -> None:
        super().shutdown()
        if not self._open:
            return
        self._open = False
        self._queue = deque()  # what still arrives (a sender mid-send) is never received
        with _lock:
            self._members.remove(self._receiver)
            _route_all(self._members)
            if not self._members:
                del _channels[self.channel_id]
        self._receiver.wake()  # a recv waiting in another thread raises now
