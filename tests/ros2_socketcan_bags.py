"""ROS 2 bags of CAN frames as ros2_socketcan records them, written with rosbags' own writer (bag
versions 8 and 9, MCAP or SQLite), and SQLite bags of the older layouts rosbag2 wrote before
(Foxy's version 4, Humble's version 5), which rosbags reads but does not write.

The message definitions are the packages' .msg files as published (ros_canopen's can_msgs,
ros2_socketcan's ros2_socketcan_msgs), kept here apart from cosim's copy so that a test catches a
wrong one. The receiver node stamps each header (``use_bus_time``: the socket's time) before
rosbag2 records the message: a bag's time is a little after its stamp.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from pathlib import Path

import can
import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

FRAME_MSG = (
    "std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\nuint8 dlc\nuint8[8] data\n"
)
FD_FRAME_MSG = "std_msgs/Header header\nuint32 id\nbool is_extended\nbool is_error\nuint8 len\nuint8[<=64] data\n"
FRAME, FD_FRAME = "can_msgs/msg/Frame", "ros2_socketcan_msgs/msg/FdFrame"
LATENCY_NS = 123_457  # from the socket's stamp to rosbag2's record
STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}


def store():
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    typestore.register(get_types_from_msg(FRAME_MSG, FRAME))
    typestore.register(get_types_from_msg(FD_FRAME_MSG, FD_FRAME))
    return typestore


def socketcan_message(typestore, frame: can.Message, stamp_ns: int) -> tuple[str, bytes]:
    """(type, CDR bytes) of a frame as ros2_socketcan's receiver publishes it."""
    types = typestore.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec, nanosec), frame_id="can")
    data = bytes(frame.data)
    if frame.is_fd:
        message = types[FD_FRAME](
            header, frame.arbitration_id, frame.is_extended_id, False, len(data), np.frombuffer(data, np.uint8)
        )
        return FD_FRAME, typestore.serialize_cdr(message, FD_FRAME)
    padded = np.frombuffer(data.ljust(8, b"\0"), np.uint8)
    message = types[FRAME](
        header,
        frame.arbitration_id,
        frame.is_remote_frame,
        frame.is_extended_id,
        frame.is_error_frame,
        len(data),
        padded,
    )
    return FRAME, typestore.serialize_cdr(message, FRAME)


def received(frame: can.Message) -> str:
    """The receiver's topic of a frame: a classic one's, or an FD socket's."""
    return "/from_can_bus_fd" if frame.is_fd else "/from_can_bus"


def recorded(
    frames: list[can.Message], topic_of: Callable[[can.Message], str] = received
) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, bag time, CDR) of each frame; the bag's time is the frame's timestamp to the
    microsecond (what a candump log keeps) in integer ns, its stamp LATENCY_NS before."""
    typestore = store()
    out = []
    for frame in frames:
        time_ns = round(frame.timestamp * 1e6) * 1000
        msgtype, data = socketcan_message(typestore, frame, time_ns - LATENCY_NS)
        out.append((topic_of(frame), msgtype, time_ns, data))
    return out


def write_bag(
    path: Path,
    frames: list[can.Message],
    storage: str = "mcap",
    version: int = 9,
    topic_of: Callable[[can.Message], str] = received,
) -> Path:
    """A rosbag2 folder of ``frames`` written by rosbags, as ros2_socketcan's receiver and
    ``ros2 bag record`` would."""
    typestore = store()
    with Writer(path, version=version, storage_plugin=STORAGES[storage]) as writer:
        connections = {}
        for topic, msgtype, time_ns, data in recorded(frames, topic_of):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
            writer.write(connections[topic], time_ns, data)
    return path


def write_old_sqlite_bag(path: Path, frames: list[can.Message], version: int) -> Path:
    """A rosbag2 folder of SQLite storage in the layout of bag version 4 (Foxy: tables topics and
    messages, QoS profiles as YAML text) or 5 (Humble: also the schema and metadata tables, and a
    ``files`` list in metadata.yaml); neither carries message definitions."""
    path.mkdir()
    rows = recorded(frames)
    topics = {topic: msgtype for topic, msgtype, _, _ in rows}
    ids = {topic: i + 1 for i, topic in enumerate(topics)}
    db = sqlite3.connect(path / f"{path.name}_0.db3")
    db.execute(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
        "serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL)"
    )
    db.execute(
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, "
        "data BLOB NOT NULL)"
    )
    db.execute("CREATE INDEX timestamp_idx ON messages (timestamp ASC)")
    if version >= 5:
        db.execute("CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL)")
        db.execute("INSERT INTO schema VALUES(3, 'humble')")
        db.execute(
            "CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, metadata TEXT NOT NULL)"
        )
    db.executemany("INSERT INTO topics VALUES(?, ?, ?, 'cdr', '')", [(ids[t], t, m) for t, m in topics.items()])
    db.executemany(
        "INSERT INTO messages(topic_id, timestamp, data) VALUES(?, ?, ?)", [(ids[t], n, d) for t, _, n, d in rows]
    )
    db.commit()
    db.close()
    start, end = rows[0][2], rows[-1][2]
    counts = {t: sum(1 for r in rows if r[0] == t) for t in topics}
    listed = "".join(
        f"    - topic_metadata:\n        name: {t}\n        type: {m}\n        serialization_format: cdr\n"
        f"        offered_qos_profiles: ''\n      message_count: {counts[t]}\n"
        for t, m in topics.items()
    )
    files = (
        f"  files:\n    - path: {path.name}_0.db3\n      starting_time:\n        nanoseconds_since_epoch: {start}\n"
        f"      duration:\n        nanoseconds: {end - start}\n      message_count: {len(rows)}\n"
        if version >= 5
        else ""
    )
    (path / "metadata.yaml").write_text(
        f"rosbag2_bagfile_information:\n  version: {version}\n  storage_identifier: sqlite3\n"
        f"  duration:\n    nanoseconds: {end - start}\n  starting_time:\n    nanoseconds_since_epoch: {start}\n"
        f"  message_count: {len(rows)}\n  topics_with_message_count:\n{listed}"
        f"  compression_format: ''\n  compression_mode: ''\n  relative_file_paths:\n    - {path.name}_0.db3\n{files}"
    )
    return path
