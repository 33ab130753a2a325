"""ROS 2's CAN frame messages, as ros2_socketcan publishes them, and their frames as python-can's.

- ``can_msgs/msg/Frame`` (the ``can_msgs`` package of ros_canopen): a classic CAN frame; its
  ``data`` is always 8 bytes, of which the first ``dlc`` are the payload. ros2_socketcan publishes
  the frames it receives on ``from_can_bus`` and sends those of ``to_can_bus``.
- ``ros2_socketcan_msgs/msg/FdFrame`` (ros2_socketcan's own package): a CAN FD frame of ``len``
  bytes (``from_can_bus_fd``, ``to_can_bus_fd``). It has no flag for the bit-rate switch, and
  ros2_socketcan with ``enable_can_fd`` publishes every frame of its socket as one, classic frames
  too: a frame read from it is taken as CAN FD without bit-rate switch.

The definitions are the packages' .msg text. A bag cosim writes carries them, so that readers
without the packages decode its frames; a bag read here is checked against them first.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any

import can

from cosim.errors import CosimError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

FRAME = "can_msgs/msg/Frame"
FD_FRAME = "ros2_socketcan_msgs/msg/FdFrame"
#: Message type → its .msg text, as its package defines it.
DEFINITIONS = {
    FRAME: """\
std_msgs/Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
""",
    FD_FRAME: """\
std_msgs/Header header
uint32 id
bool is_extended
bool is_error
uint8 len
uint8[<=64] data
""",
}
#: The standard types the frames use (builtin_interfaces', std_msgs'), as their packages define them.
STANDARD = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
}
#: ros2_socketcan's ``header.frame_id``, for a frame whose log names no channel.
FRAME_ID = "can"
#: The last instant a ROS 2 time (int32 seconds since the epoch) holds, in ns.
LAST_STAMP_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999


def new_typestore() -> Typestore:
    """A store of rosbags' with the two CAN frames and the standard types they use, to which a
    bag's writer adds its own types (the store of a whole distribution takes seconds to build)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    for msgtype, text in {**STANDARD, **DEFINITIONS}.items():
        store.register(get_types_from_msg(text, msgtype))
    return store


@cache
def typestore() -> Typestore:
    """The store that reads bags: ``new_typestore``'s types, never added to."""
    return new_typestore()


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in ns since the epoch, exactly."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def ros_time(store: Typestore, time_ns: int) -> Any:
    """``builtin_interfaces/msg/Time`` of ns since the epoch; one line for a time it cannot hold."""
    if not 0 <= time_ns <= LAST_STAMP_NS:
        raise CosimError(
            f"time {time_ns} ns since the Unix epoch does not fit a ROS 2 time (int32 seconds: 1970 to 2038-01-19)"
        )
    seconds, nanoseconds = divmod(time_ns, 1_000_000_000)
    return store.types["builtin_interfaces/msg/Time"](sec=seconds, nanosec=nanoseconds)


def header(store: Typestore, time_ns: int, frame_id: str) -> Any:
    """A ``std_msgs/msg/Header`` stamped ``time_ns``."""
    return store.types["std_msgs/msg/Header"](stamp=ros_time(store, time_ns), frame_id=frame_id)


def frame_of(message: Any, msgtype: str) -> can.Message:
    """The python-can frame of a deserialized ``can_msgs/msg/Frame`` or ``FdFrame`` (its flags
    kept: an error or remote frame is one); ValueError naming the field of one that holds no frame."""
    data = bytes(message.data)
    if msgtype == FD_FRAME:
        length = int(message.len)
        if length > len(data):
            raise ValueError(f"len {length} but {len(data)} data bytes")
        fd, remote = True, False
    else:
        length = min(int(message.dlc), 8)  # a classic DLC of 9 to 15 still means 8 bytes
        fd, remote = False, bool(message.is_rtr)
    return can.Message(
        arbitration_id=int(message.id),
        is_extended_id=bool(message.is_extended),
        is_error_frame=bool(message.is_error),
        is_remote_frame=remote,
        is_fd=fd,
        data=data[:length],
    )


def ros_frame(store: Typestore, frame: dict[str, Any], time_ns: int, frame_id: str) -> tuple[str, Any]:
    """(message type, message) of a ``/can/frames`` record: a classic frame as ``can_msgs/msg/Frame``
    (its data padded to 8 bytes), a CAN FD frame as ``ros2_socketcan_msgs/msg/FdFrame``."""
    import numpy as np

    data = bytes.fromhex(frame["data"])
    types = store.types
    stamped = header(store, time_ns, frame_id)
    if frame["fd"]:
        payload = np.frombuffer(data, dtype=np.uint8)
        return FD_FRAME, types[FD_FRAME](
            header=stamped, id=frame["id"], is_extended=frame["extended"], is_error=False, len=len(data), data=payload
        )
    padded = np.frombuffer(data.ljust(8, b"\0"), dtype=np.uint8)
    return FRAME, types[FRAME](
        header=stamped,
        id=frame["id"],
        is_rtr=False,
        is_extended=frame["extended"],
        is_error=False,
        dlc=len(data),
        data=padded,
    )
