"""A log as a ROS 2 bag (``cosim export --to rosbag2``), written with rosbags: no ROS installation.

The bag is a rosbag2 folder of bag version 9 (what rosbag2 writes since Jazzy): ``metadata.yaml``
(its topics, types, counts, start and duration, as ``ros2 bag info`` shows them) and one MCAP
storage file, zstd-compressed chunks, every message CDR-serialized and every channel's schema the
message definition in rosbag2's ``ros2msg`` form, so that readers without the packages (rosbags,
the ``mcap`` reader's ROS 2 decoder, Foxglove) decode it. Its topics, in the log's order:

- ``/can/frames``: every frame of the log's ``/can/frames``, byte for byte, as ros2_socketcan
  publishes them (``cosim.bus.ros_can``): a classic frame as ``can_msgs/msg/Frame``, a CAN FD frame
  as ``ros2_socketcan_msgs/msg/FdFrame`` on ``/can/frames_fd`` (a ROS topic has one type; this is
  ros2_socketcan's ``from_can_bus_fd`` beside ``from_can_bus``). The header's ``frame_id`` is the
  frame's channel where the log names one, ``can`` (ros2_socketcan's) otherwise; its stamp the
  frame's own (an imported bag's header stamp) or its time. FdFrame has no bit-rate switch flag:
  that flag is not in the bag.
- every other topic of the log (the truth, the decoded signals and estimates on ``/can/<Message>``,
  the runner's events, ...) under its own name, as a ``cosim_msgs`` message whose fields are the
  topic's (``cosim.analysis.ros_messages``: units in the definitions' comments).

Each message's bag time, and its header stamp, is the log's start plus its log time, as the frame
exports stamp theirs (``cosim.analysis.export``): a run's wall-clock start to the millisecond and
simulated time after it, an imported log's own times. Times stay integer ns throughout. The bag is
written in a temporary folder beside the output and renamed into place once complete.
"""

from __future__ import annotations

import shutil
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any, Final, Literal

from cosim.analysis.ros_messages import RosType, definition, register, ros_types
from cosim.bus.ros_can import DEFINITIONS, FD_FRAME, FRAME_ID, header, new_typestore, ros_frame
from cosim.errors import CosimError
from cosim.extras import require
from cosim.log.reader import LogReader
from cosim.log.topics import FRAMES

FD_FRAMES = FRAMES + "_fd"
VERSION: Final[Literal[9]] = 9  # the bag version rosbag2 writes since Jazzy


def write_bag(reader: LogReader, out: Path, start_ns: int, base_ns: int) -> Counter[str]:
    """Write the log of ``reader`` as the bag folder ``out`` (replacing a bag folder there, nothing
    else), each message at ``start_ns + log time - base_ns``; the messages written per topic."""
    require("rosbags", "cosim export --to rosbag2")
    if out.exists() and not (out.is_dir() and (out / "metadata.yaml").is_file()):
        raise CosimError(f"{out} exists and is no ROS 2 bag folder: choose another --out (only a bag is replaced)")
    work = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        written = _write(reader, work / out.name, start_ns - base_ns)
        if out.exists():
            out.rename(work / "replaced")
        (work / out.name).rename(out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return written


def _write(reader: LogReader, path: Path, offset_ns: int) -> Counter[str]:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    store = new_typestore()
    schemas = reader.schemas()
    types = ros_types({topic: schema for topic, schema in schemas.items() if topic != FRAMES})
    register(store, list(types.values()))
    texts = {**DEFINITIONS, **{t.name: t.text for top in types.values() for t in top.every()}}
    writer = Writer(path, version=VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    connections: dict[tuple[str, str], Any] = {}
    written: Counter[str] = Counter()

    def connection(topic: str, msgtype: str) -> Any:
        found = connections.get((topic, msgtype))
        if found is None:
            found = connections[topic, msgtype] = writer.add_connection(
                topic, msgtype, msgdef=definition(store, msgtype, texts), rihs01=store.hash_rihs01(msgtype)
            )
        return found

    with writer:
        for topic, log_time, payload in reader.messages():
            time_ns = log_time + offset_ns
            if topic == FRAMES:
                stamp = payload.get("stamp")
                frame_id = payload.get("channel") or FRAME_ID
                msgtype, message = ros_frame(store, payload, time_ns if stamp is None else stamp + offset_ns, frame_id)
                topic = FD_FRAMES if msgtype == FD_FRAME else FRAMES
            else:
                kind: RosType = types[topic]
                msgtype, message = kind.name, kind.message(store, payload, header(store, time_ns, ""))
            writer.write(connection(topic, msgtype), time_ns, store.serialize_cdr(message, msgtype))
            written[topic] += 1
    return written
