"""The run's UDP multicast bus, kept to this host and hardened against what arrives on its socket.

python-can's ``udp_multicast`` interface binds the wildcard address on the run's port and raises
on a datagram it cannot unpack. ``HostMulticastBus`` speaks the same wire format (any python-can
program joins the run with ``interface="udp_multicast"``) but:

- binds the socket to the run's multicast group, not to the wildcard address, so that only
  datagrams sent to that group reach it: a datagram sent unicast to the host's addresses on the
  run's port, or to another group on the same port (another run's), never does;
- accepts datagrams from this host's own addresses only (where the group is one a remote host could
  reach, as an IPv4 group can): anything sent from another host is foreign;
- never raises for what it receives: a datagram it cannot unpack (garbage, a truncated or
  oversized packet, or a well-formed message whose fields are not a CAN frame's: an identifier
  that is no integer in range, a payload that is no byte string of a CAN length, a flag that is no
  boolean) or one from another host is a ``ForeignDatagram``, handed to ``on_foreign`` and
  counted, and reception goes on. Fields are checked before a frame is built from them, so a
  datagram cannot make the receiver allocate more than the datagram itself.

It is registered as the python-can interface ``cosim_udp`` (``can.Bus(interface="cosim_udp", ...)``).
"""

from __future__ import annotations

import errno
import select
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

import can
import msgpack
from can.bus import CanProtocol
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus, UdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message

#: Bytes of a foreign datagram's payload that are kept for the log.
KEEP_BYTES = 64
#: The fields python-can's ``pack_message`` writes, with the types a frame's fields have.
_FLAGS = ("is_extended_id", "is_remote_frame", "is_error_frame", "is_fd", "bitrate_switch", "error_state_indicator")
_CAN_LENGTHS = frozenset((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64))


BATCH_TAG = "cosim/1"
"""The first element of a batch datagram: ``[BATCH_TAG, [id, flags, dlc, data], ...]`` (msgpack),
one sender's frames of a tick in one datagram; ``flags`` has bit i set for the i-th of ``_FLAGS``."""
MAX_BATCH = 256
"""Frames per batch datagram at most (256 CAN FD frames of 64 bytes take about 20 kB)."""


def _unpack(data: bytes) -> Any:
    try:
        return msgpack.unpackb(
            data, raw=False, strict_map_key=True, max_bin_len=64, max_str_len=256, max_array_len=MAX_BATCH + 1
        )
    except Exception as error:  # msgpack raises several kinds for bad bytes
        raise ValueError(f"not a msgpack message ({type(error).__name__})") from None


def unpack_datagram(data: bytes, timestamp: float) -> can.Message:
    """The frame a python-can ``udp_multicast`` datagram carries; ValueError naming the first field
    that is not a CAN frame's (checked before the frame is built)."""
    fields = _unpack(data)
    if not isinstance(fields, dict):
        raise ValueError("not a map of a frame's fields")
    flags = [fields.get(flag, False) for flag in _FLAGS]
    dlc = fields.get("dlc")  # absent: the payload's length
    channel = fields.get("channel")
    return _frame(fields.get("arbitration_id"), flags, dlc, fields.get("data"), timestamp, channel)


def unpack_frames(data: bytes, timestamp: float) -> list[can.Message]:
    """The frames a datagram carries: one of python-can's, or a batch (``BATCH_TAG``); ValueError
    naming what is not a frame's (the whole datagram is refused)."""
    fields = _unpack(data)
    if isinstance(fields, dict):
        return [unpack_datagram(data, timestamp)]
    if not isinstance(fields, list) or not fields or fields[0] != BATCH_TAG:
        raise ValueError("neither a frame's map nor a batch of frames")
    frames = []
    for item in fields[1:]:
        if not isinstance(item, list) or len(item) != 4 or type(item[1]) is not int or not 0 <= item[1] < 64:
            raise ValueError("a batch's item is not [id, flags, dlc, data]")
        identifier, bits, dlc, payload = item
        frames.append(_frame(identifier, [bool(bits >> i & 1) for i in range(len(_FLAGS))], dlc, payload, timestamp))
    return frames


def pack_batch(frames: list[can.Message]) -> bytes:
    """One datagram of at most ``MAX_BATCH`` frames (``unpack_frames`` reads it)."""
    items: list[Any] = [BATCH_TAG]
    for frame in frames:
        bits = sum(1 << i for i, flag in enumerate(_FLAGS) if getattr(frame, flag))
        items.append([frame.arbitration_id, bits, frame.dlc, bytes(frame.data)])
    return msgpack.packb(items, use_bin_type=True)


def _frame(
    identifier: Any, flags: list[Any], dlc: Any, payload: Any, timestamp: float, channel: Any = None
) -> can.Message:
    """A frame from its fields, each checked before it is built (ValueError naming the first that is wrong)."""
    if type(identifier) is not int:
        raise ValueError("arbitration_id is not an integer")
    for flag, value in zip(_FLAGS, flags):
        if type(value) is not bool:
            raise ValueError(f"{flag} is not a boolean")
    extended, fd = flags[0], flags[3]
    if not 0 <= identifier < (1 << 29 if extended else 1 << 11):
        raise ValueError(f"arbitration_id {identifier} is out of range")
    if not isinstance(payload, bytes) or len(payload) not in _CAN_LENGTHS:
        raise ValueError("data is not a CAN payload (bytes of a CAN or CAN FD length)")
    if len(payload) > 8 and not fd:
        raise ValueError("data longer than 8 bytes in a classic frame")
    if dlc is None:
        dlc = len(payload)
    if type(dlc) is not int or not 0 <= dlc <= (64 if fd else 8):  # a remote frame asks for dlc bytes, carries none
        raise ValueError("dlc is not a CAN data length")
    return can.Message(
        timestamp=timestamp,
        arbitration_id=identifier,
        data=payload,
        dlc=dlc,
        channel=channel if isinstance(channel, (str, int)) else None,
        **dict(zip(_FLAGS, flags)),
        check=True,
    )


@dataclass(frozen=True)
class ForeignDatagram:
    """Something that arrived on the run's socket and is not a frame of the run's bus."""

    reason: str
    """``garbage`` (cannot be unpacked as a python-can frame) or ``remote`` (sent from another host)."""
    source: str
    length: int
    data: bytes
    """The first ``KEEP_BYTES`` bytes."""


@cache
def is_local_address(address: str, scope: int = 0) -> bool:
    """Whether ``address`` is one of this host's own (a socket can bind it)."""
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.bind((address, 0, 0, scope) if family == socket.AF_INET6 else (address, 0))
        return True
    except OSError:
        return False


@cache
def multicast_scope(group: str) -> int:
    """The interface index through which this host sends to an IPv6 multicast ``group`` by default
    (what a socket bound to the group must name as its scope). Found by a probe on a spare port."""
    candidates = [index for index, _ in socket.if_nameindex()]
    sockets: dict[int, socket.socket] = {}
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as sender:
            sender.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sender.bind(("::", 0))
            port = sender.getsockname()[1]  # a port nobody else uses: the probe disturbs no listener
            request = socket.inet_pton(socket.AF_INET6, group)
            for index in candidates:
                candidate = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
                try:
                    candidate.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    candidate.bind((group, port, 0, index))
                    membership = request + struct.pack("@I", index)
                    candidate.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP, membership)
                    candidate.setblocking(False)
                    sockets[index] = candidate
                except OSError:
                    candidate.close()
            sender.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, struct.pack("@i", 1))
            sender.sendto(b"cosim scope probe", (group, port))
            import select

            ready, _, _ = select.select(list(sockets.values()), [], [], 0.5)
            for index, candidate in sockets.items():
                if candidate in ready:
                    return index
    except OSError:
        pass
    finally:
        for candidate in sockets.values():
            candidate.close()
    return 0


#: Linux's socket options for receive timestamps and for the count of datagrams the kernel dropped
#: because the socket's receive buffer was full (sent with every datagram once one was dropped).
SO_TIMESTAMPNS, SO_RXQ_OVFL = 35, 40
#: Linux's option for a receive buffer past ``net.core.rmem_max`` (Python's socket module lacks it).
SO_RCVBUFFORCE = 33
_TIMESPEC, _DROPS = struct.Struct("@ll"), struct.Struct("@I")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) + socket.CMSG_SPACE(_DROPS.size)


RECEIVE_BUFFER = 8 * 1024 * 1024
"""Bytes the run's socket asks the kernel to hold for it: the default (about 200 kB) holds only a few
hundred small datagrams (each takes about 800 bytes of the buffer), which a burst overflows."""


def _enlarge_receive_buffer(sock: socket.socket) -> None:
    """Room for bursts: ``RECEIVE_BUFFER``, where the system allows it (SO_RCVBUFFORCE, which may
    pass ``net.core.rmem_max``, takes a privileged process; SO_RCVBUF is capped at that limit).
    Whatever still overflows is counted (``kernel_dropped``)."""
    for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, RECEIVE_BUFFER)
            return
        except OSError:
            continue


class _GroupSocket(GeneralPurposeUdpMulticastBus):
    """python-can's socket handler, with the socket bound to the group instead of the wildcard
    address, and the kernel's drops counted (``kernel_dropped``: datagrams that never reached it)."""

    kernel_dropped = 0

    def recv(self, timeout: float | None = None) -> tuple[bytes, Any, float] | None:
        try:
            ready, _, _ = select.select([self._socket], [], [], timeout)
        except OSError as error:
            raise can.CanOperationError(f"Failed to wait for IP/UDP socket: {error}") from error
        if not ready:
            return None
        data, ancillary, _, sender = self._socket.recvmsg(self.max_buffer, _ANCILLARY)
        timestamp = None
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
                seconds, nanoseconds = _TIMESPEC.unpack_from(payload)
                timestamp = seconds + nanoseconds * 1e-9
            elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= _DROPS.size:
                self.kernel_dropped = _DROPS.unpack_from(payload)[0]
        return data, sender, time.time() if timestamp is None else timestamp

    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        sock = socket.socket(address_family, socket.SOCK_DGRAM)
        try:
            ttl = struct.pack("@I", self.hop_limit)
            if self.ip_version == 4:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
            else:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, ttl)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            for option in (SO_TIMESTAMPNS, SO_RXQ_OVFL):  # where the system has them
                try:
                    sock.setsockopt(socket.SOL_SOCKET, option, 1)
                except OSError as error:
                    if error.errno not in (errno.ENOPROTOOPT, errno.EINVAL):
                        raise
            self.timestamp_nanosecond = True
            _enlarge_receive_buffer(sock)
            group = socket.inet_pton(address_family, self.group)
            if self.ip_version == 4:
                sock.bind((self.group, self.port))
                membership = group + struct.pack("@I", socket.INADDR_ANY)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            else:
                scope = multicast_scope(self.group)
                sock.bind((self.group, self.port, 0, scope))
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP, group + struct.pack("@I", scope))
            return sock
        except OSError as error:
            sock.close()
            raise can.CanInitializationError(f"could not open the run's multicast socket: {error}") from error


class HostMulticastBus(UdpMulticastBus):
    """A udp_multicast bus that only this host's traffic on this run's group reaches, and that
    reports what it cannot parse instead of raising (see the module's documentation).

    ``send_batch`` puts several frames in one datagram (``pack_batch``): a sender's frames of a
    tick cost one system call and one wake-up of each receiver instead of one per frame; receivers
    still get one ``can.Message`` per frame from ``recv``. ``mirror``: another port, to which every
    frame sent also goes alone (to the same group), in python-can's own format, for programs that
    can only open ``udp_multicast`` (they cannot read a batch)."""

    def __init__(
        self,
        channel: str,
        port: int,
        hop_limit: int = 1,
        fd: bool = True,
        on_foreign: Callable[[ForeignDatagram], None] | None = None,
        mirror: int | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(channel, port, hop_limit, fd=fd, **kwargs)
        self._multicast.shutdown()
        self._multicast = self._group = _GroupSocket(channel, port, hop_limit)
        self.on_foreign = on_foreign
        self.foreign = 0
        self._pending: deque[can.Message] = deque()  # the rest of a batch, handed out one by one
        self._mirror: tuple[Any, ...] | None = None
        if mirror:
            scope = multicast_scope(channel) if ":" in channel else 0
            self._mirror = (channel, mirror, 0, scope) if ":" in channel else (channel, mirror)

    @property
    def kernel_dropped(self) -> int:
        """Datagrams the kernel dropped before this bus could read them (its receive buffer was full)."""
        return self._group.kernel_dropped

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        super().send(msg, timeout)
        self._to_mirror([msg])

    def send_batch(self, frames: list[can.Message]) -> None:
        """Send the frames in as few datagrams as hold them (one up to ``MAX_BATCH``), in order."""
        if len(frames) == 1:
            self.send(frames[0])
            return
        if self._can_protocol is not CanProtocol.CAN_FD and any(frame.is_fd for frame in frames):
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        for start in range(0, len(frames), MAX_BATCH):
            self._multicast.send(pack_batch(frames[start : start + MAX_BATCH]))
        self._to_mirror(frames)

    def _to_mirror(self, frames: list[can.Message]) -> None:
        """Each frame alone, in python-can's own format, to the mirror (if the run has one)."""
        if self._mirror is not None:
            for frame in frames:
                self._group._socket.sendto(pack_message(frame), self._mirror)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        result = self._multicast.recv(timeout)
        if not result:
            return None, False
        data, sender, timestamp = result
        address = str(sender[0])
        if not is_local_address(address, sender[3] if len(sender) > 3 else 0):
            return self._foreign("remote", sender, data)
        try:
            frames = unpack_frames(data, timestamp)
        except (ValueError, TypeError):  # can.Message's own check raises these
            return self._foreign("garbage", sender, data)
        if self._can_protocol is not CanProtocol.CAN_FD:  # a classic CAN bus does not see CAN FD frames
            frames = [frame for frame in frames if not frame.is_fd]
        if not frames:
            return None, False
        self._pending.extend(frames[1:])
        return frames[0], False

    def _foreign(self, reason: str, sender: Any, data: bytes) -> tuple[None, bool]:
        self.foreign += 1
        if self.on_foreign is not None:
            host, port = str(sender[0]), sender[1] if len(sender) > 1 else ""
            source = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
            self.on_foreign(ForeignDatagram(reason, source, len(data), bytes(data[:KEEP_BYTES])))
        return None, False
