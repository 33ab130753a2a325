"""The CAN frames of a ROS 2 bag, read with rosbags (the pure-Python rosbag2 library; no ROS needed).

A bag is a rosbag2 folder (``metadata.yaml`` and its storage files, MCAP or SQLite, of any bag
version rosbag2 has written, 1 to 9; split bags read file after file), or one storage file of
one (``.mcap``, ``.db3``). Its CAN topics are those of the two types ros2_socketcan publishes
(``cosim.bus.ros_can``: ``can_msgs/msg/Frame``, ``ros2_socketcan_msgs/msg/FdFrame``), whatever
their names (``/from_can_bus``, ``/to_can_bus``, a namespace's): their frames come in the bag's
order, each with the bag's time (when rosbag2 recorded it), its header stamp (when ros2_socketcan
received it, or the publisher's) and its topic. Every time is integer ns since the Unix epoch.

A bag whose CAN topics carry another definition of their type than the package's, or a bag
without CAN topics, is one line naming what it holds; a bag damaged part way is read up to the
damage, with a warning (as ``cosim.bus.canlogs`` reads other tools' logs).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from cosim.bus.ros_can import DEFINITIONS, FD_FRAME, frame_of, stamp_ns, typestore
from cosim.errors import CosimError
from cosim.extras import require

#: A storage file's suffix → rosbag2's storage identifier.
STORAGES = {".mcap": "mcap", ".db3": "sqlite3"}
FEATURE = "reading a ROS 2 bag"
#: Topics a line names, at most.
TOPICS_SHOWN = 8


@dataclass(frozen=True)
class BagFrame:
    """One frame of a bag: the frame, its topic, the bag's time and the header's stamp (ns)."""

    frame: can.Message
    topic: str
    time_ns: int
    stamp_ns: int


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` names a bag rather than another tool's CAN log: a folder, or a storage file."""
    path = Path(path)
    return path.is_dir() or path.suffix.lower() in STORAGES


def bag_format(path: str | Path) -> str:
    """How ``cosim import`` names a bag's format: ``rosbag2 mcap`` or ``rosbag2 sqlite3``."""
    path = Path(path)
    files = path.iterdir() if path.is_dir() else [path]
    storages = {STORAGES[s] for f in files for s in f.suffixes if s in STORAGES}
    return "rosbag2 " + ("/".join(sorted(storages)) or "(no storage file)")


def read_bag(path: str | Path, warnings: list[str], topic: str | None = None) -> Iterator[BagFrame]:
    """The frames of a bag's CAN topics in the bag's order (``topic``: the one whose frames are
    kept, which the warnings speak of). Damage part way ends them with a warning in ``warnings``;
    a bag that cannot be read, or holds no CAN topic, is one CosimError line."""
    require("rosbags", FEATURE)
    from rosbags.rosbag2 import Reader

    path = Path(path)
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise CosimError(f"{path}: not a ROS 2 bag (a rosbag2 folder holds a metadata.yaml)")
    if not path.exists():
        raise CosimError(f"{path}: no such bag")
    reader = Reader(path)
    try:
        reader.open()
    except Exception as error:  # noqa: BLE001 - rosbags, sqlite and YAML raise their own kinds
        raise CosimError(f"{path}: cannot read it as a ROS 2 bag ({_reason(error)})") from None
    try:
        yield from _frames(path, reader, warnings, topic)
    finally:
        reader.close()


def _frames(path: Path, reader: Any, warnings: list[str], topic: str | None) -> Iterator[BagFrame]:
    connections = [c for c in reader.connections if c.msgtype in DEFINITIONS]
    if not connections:
        raise CosimError(
            f"{path}: no CAN frames to import: no topic of {' or '.join(DEFINITIONS)}; {_found(reader.connections)}"
        )
    for connection in connections:
        _check_definition(path, connection)
    store = typestore()
    count = fd = 0
    try:
        for connection, time_ns, data in reader.messages(connections):
            message: Any = store.deserialize_cdr(data, connection.msgtype)
            try:
                frame = frame_of(message, connection.msgtype)
            except ValueError as error:
                raise CosimError(f"{path}: message {count} on {connection.topic} holds no CAN frame: {error}") from None
            frame.timestamp = time_ns / 1e9
            fd += connection.msgtype == FD_FRAME and topic in (None, connection.topic)
            count += 1
            yield BagFrame(frame, connection.topic, time_ns, stamp_ns(message.header))
    except CosimError:
        raise
    except Exception as error:  # noqa: BLE001 - a damaged chunk or page: rosbags, zstd, lz4, sqlite errors
        if count == 0:
            raise CosimError(f"{path}: cannot read its CAN frames ({_reason(error)})") from None
        warnings.append(f"{path}: damaged after {count} frames ({_reason(error)}); the frames before it were read")
    if fd:
        warnings.append(
            f"{fd} frames of {FD_FRAME}, which records neither the FD flag nor the bit-rate switch: taken as CAN FD "
            "without bit-rate switch (ros2_socketcan publishes every frame of an FD socket as one)"
        )


def _check_definition(path: Path, connection: Any) -> None:
    """A bag's definition of a CAN type (where it carries one: bags since rosbag2 version 8, and
    every MCAP bag) must be the package's: a fork's or an old one's would be misread."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_msg

    definition = connection.msgdef
    if definition.format != MessageDefinitionFormat.MSG or not definition.data.strip():
        return  # none, or IDL (rosbag2 writes a .msg type's as .msg): the package's own is used
    try:
        theirs = get_types_from_msg(definition.data, connection.msgtype)
    except Exception as error:  # noqa: BLE001 - rosbags' parser raises its own kinds
        raise CosimError(
            f"{path}: {connection.topic}: its definition of {connection.msgtype} cannot be read ({_reason(error)})"
        ) from None
    ours = typestore().fielddefs
    differ = sorted(name for name, fields in theirs.items() if name in ours and ours[name] != fields)
    if differ:
        fields = ", ".join(name for name, _ in theirs[connection.msgtype][1])
        raise CosimError(
            f"{path}: {connection.topic} is a {connection.msgtype} of another definition than its package's "
            f"(differs in {', '.join(differ)}; its fields: {fields}); cosim reads {' and '.join(DEFINITIONS)} "
            "as can_msgs and ros2_socketcan_msgs define them"
        )


def _found(connections: list[Any]) -> str:
    """A bag's topics, as a line names them: each with its type and messages."""
    if not connections:
        return "it holds no topic"
    listed = [f"{c.topic} ({c.msgtype}, {c.msgcount} messages)" for c in connections[:TOPICS_SHOWN]]
    more = f" and {len(connections) - TOPICS_SHOWN} more" if len(connections) > TOPICS_SHOWN else ""
    return f"its topics: {', '.join(listed)}{more}"


def _reason(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__
