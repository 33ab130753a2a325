"""ROS 2 bags in and out: bags of CAN frames as ros2_socketcan records them (written with rosbags)
imported as a candump of the same frames is, and runs exported as bags that rosbags and the
official ``mcap`` reader's ROS 2 decoder read without the message packages."""

from __future__ import annotations

import math
import shutil
from collections import Counter
from pathlib import Path

import can
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from cosim.analysis.export import export
from cosim.analysis.ros_messages import register, ros_types
from cosim.bus.foreign import read_dbc
from cosim.cli import main
from cosim.errors import CosimError
from cosim.log.can_import import import_log
from cosim.log.metadata import IMPORT
from cosim.log.reader import LogReader
from tests.ros2_socketcan_bags import (
    FD_FRAME,
    FRAME,
    FRAME_MSG,
    LATENCY_NS,
    recorded,
    store,
    write_bag,
    write_old_sqlite_bag,
)
from tests.test_export import run_short
from tests.test_foreign_dbc import ROOT, frames_of, read_mcap, write_log

DBC = ROOT / "tests/data/dbc/cantools/foobar.dbc"  # classic and CAN FD, standard and extended, units, a value table


def bus_frames() -> list[can.Message]:
    """Frames of a DBC with classic and CAN FD messages, and one id it does not describe; the FD
    ones without bit-rate switch (ros2_socketcan's FdFrame records none), 1 ms apart to the µs."""
    frames = frames_of(read_dbc(DBC), 8)
    frames.append(can.Message(arbitration_id=0x7FE, is_extended_id=False, data=b"\x01\x02"))
    for i, frame in enumerate(frames):
        frame.bitrate_switch = False
        frame.timestamp = 1_718_000_000.25 + 0.001 * i
    return frames


def without(topics: dict, *keys: str) -> dict:
    """The topics with the frames' records less ``keys``."""
    return {
        topic: [(t, {k: v for k, v in m.items() if k not in keys}) if topic == "/can/frames" else (t, m) for t, m in ms]
        for topic, ms in topics.items()
    }


# -- in: cosim import BAG ------------------------------------------------------------------------


@pytest.mark.parametrize("bare", [False, True], ids=["folder", "file"])
@pytest.mark.parametrize("version", [8, 9])
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_imports_exactly_as_a_candump_of_the_same_frames(tmp_path, storage, version, bare):
    frames = bus_frames()
    bag = write_bag(tmp_path / "bag", frames, storage, version)
    source = next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")) if bare else bag
    from_bag = import_log(source, DBC, tmp_path / "bag.mcap")
    write_log(frames, tmp_path / "bus.log")
    from_candump = import_log(tmp_path / "bus.log", DBC, tmp_path / "candump.mcap")
    topics, schemas, attachments, metadata = read_mcap(tmp_path / "bag.mcap")
    candump, candump_schemas, candump_attachments, _ = read_mcap(tmp_path / "candump.mcap")

    # the same frames and decoded messages, schemas (units, value tables), DBC and counts; the
    # frames' time since the first ("t") from the bag's exact ns, a candump's float seconds
    assert topics.keys() == candump.keys() and schemas == candump_schemas and attachments == candump_attachments
    for topic in candump:
        ours, theirs = (without(found, "channel", "stamp", "t")[topic] for found in (topics, candump))
        assert [m for _, m in ours] == [m for _, m in theirs], topic
    counts = ("frames", "decoded", "unknown", "undecodable", "skipped")
    assert [getattr(from_bag.record, c) for c in counts] == [getattr(from_candump.record, c) for c in counts]
    assert from_bag.record.unknown == 1 and from_bag.record.decoded == len(frames) - 1
    assert metadata["cosim.import"]["format"] == f"rosbag2 {storage}"

    # the bag's own times to the ns (a candump's are float seconds), each frame's header stamp, its topic
    logged = topics["/can/frames"]
    expected_ns = [round(f.timestamp * 1e6) * 1000 for f in frames]
    assert [t for t, _ in logged] == expected_ns
    assert all(abs(t - c) < 1000 for (t, _), (c, _) in zip(logged, candump["/can/frames"]))
    assert [r["stamp"] for _, r in logged] == [t - LATENCY_NS for t in expected_ns]
    assert [r["channel"] for _, r in logged] == ["/from_can_bus_fd" if f.is_fd else "/from_can_bus" for f in frames]
    fd = sum(f.is_fd for f in frames)
    assert f"{fd} frames of ros2_socketcan_msgs/msg/FdFrame" in from_bag.warnings[0]


@pytest.mark.parametrize("version", [4, 5])
def test_a_bag_of_the_older_sqlite_layouts_imports_with_the_packages_definitions(tmp_path, version):
    """Foxy (bag version 4) and Humble (5) wrote SQLite bags without message definitions."""
    frames = bus_frames()
    bag = write_old_sqlite_bag(tmp_path / "old", frames, version)
    import_log(bag, DBC, tmp_path / "old.mcap")
    write_bag(tmp_path / "new", frames, "sqlite3", 9)
    import_log(tmp_path / "new", DBC, tmp_path / "new.mcap")
    old, *_ = read_mcap(tmp_path / "old.mcap")
    new, *_ = read_mcap(tmp_path / "new.mcap")
    assert old == new


def test_one_topic_of_a_bag_is_imported_with_topic(tmp_path, capsys):
    """ros2_socketcan's receiver on /from_can_bus, and what nodes sent to its sender on /to_can_bus."""
    received = [f for f in bus_frames() if not f.is_fd]
    sent = [can.Message(timestamp=f.timestamp + 0.0005, arbitration_id=0x7FD, data=b"\x05") for f in received[:3]]
    frames = sorted(received + sent, key=lambda f: f.timestamp)
    bag = write_bag(
        tmp_path / "bag", frames, topic_of=lambda f: "/to_can_bus" if f.arbitration_id == 0x7FD else "/from_can_bus"
    )
    whole = import_log(bag, DBC, tmp_path / "whole.mcap")
    assert (
        f"bag holds frames of 2 topics (/from_can_bus ({len(received)} frames), /to_can_bus (3 frames)), all decoded "
        "by the one DBC; --topic TOPIC imports the frames of one topic alone"
    ) in whole.warnings
    assert main(["import", str(bag), "--dbc", str(DBC), "--topic", "/to_can_bus", "-q"]) == 0
    topics, _, _, metadata = read_mcap(tmp_path / "bag.mcap")
    assert [(r["channel"], r["id"]) for _, r in topics["/can/frames"]] == [("/to_can_bus", 0x7FD)] * 3
    assert (metadata[IMPORT]["channel"], metadata[IMPORT]["other_channels"]) == ("/to_can_bus", str(len(received)))
    capsys.readouterr()
    out = str(tmp_path / "x.mcap")
    assert main(["import", str(bag), "--dbc", str(DBC), "--topic", "/nope", "-o", out]) == 1
    assert capsys.readouterr().err.strip() == (
        f"error: --topic /nope: {bag} has no frame on it; its topics: /from_can_bus ({len(received)} frames), "
        "/to_can_bus (3 frames)"
    )
    assert main(["import", str(bag), "--dbc", str(DBC), "--channel", "can0", "-o", out]) == 1
    assert "the buses of a ROS 2 bag are its topics; pick one with --topic" in capsys.readouterr().err
    write_log(frames, tmp_path / "bus.log")
    assert main(["import", str(tmp_path / "bus.log"), "--dbc", str(DBC), "--topic", "/a", "-o", out]) == 1
    assert "--topic picks a topic of a ROS 2 bag" in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists()


def write_temperature_bag(path: Path) -> Path:
    """A bag of a thermometer (sensor_msgs/msg/Temperature): no CAN topic."""
    typestore = store()
    types = typestore.types
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        topic = writer.add_connection("/imu/temperature", "sensor_msgs/msg/Temperature", typestore=typestore)
        header = types["std_msgs/msg/Header"](types["builtin_interfaces/msg/Time"](1, 0), "imu")
        message = types["sensor_msgs/msg/Temperature"](header, 21.5, 0.1)
        writer.write(topic, 1_000_000_000, typestore.serialize_cdr(message, "sensor_msgs/msg/Temperature"))
    return path


def test_a_bag_without_can_topics_or_of_another_definition_is_one_line(tmp_path):
    bag = write_temperature_bag(tmp_path / "imu")
    with pytest.raises(CosimError) as error:
        import_log(bag, DBC, tmp_path / "x.mcap")
    assert str(error.value) == (
        f"{bag}: no CAN frames to import: no topic of can_msgs/msg/Frame or ros2_socketcan_msgs/msg/FdFrame; "
        "its topics: /imu/temperature (sensor_msgs/msg/Temperature, 1 messages)"
    )
    # a fork's can_msgs/msg/Frame of 64 data bytes: read as can_msgs', its frames would be garbage
    fork = FRAME_MSG.replace("uint8[8] data", "uint8[64] data")
    separator = "=" * 80 + "\n"
    definition = separator.join(
        (
            fork,
            "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
            "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
        )
    )
    with Writer(tmp_path / "fork", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.add_connection("/from_can_bus", FRAME, msgdef=definition, rihs01="RIHS01_" + "0" * 64)
    with pytest.raises(CosimError) as error:
        import_log(tmp_path / "fork", DBC, tmp_path / "x.mcap")
    assert str(error.value).startswith(
        f"{tmp_path / 'fork'}: /from_can_bus is a can_msgs/msg/Frame of another definition than its package's "
        "(differs in can_msgs/msg/Frame; its fields: header, id, is_rtr, is_extended, is_error, dlc, data)"
    )
    (tmp_path / "plain").mkdir()
    with pytest.raises(CosimError, match=r"plain: not a ROS 2 bag \(a rosbag2 folder holds a metadata.yaml\)$"):
        import_log(tmp_path / "plain", DBC, tmp_path / "x.mcap")
    with pytest.raises(CosimError, match=r"nothing\.db3: no such bag$"):
        import_log(tmp_path / "nothing.db3", DBC, tmp_path / "x.mcap")
    shutil.copy(ROOT / "tests/data/dbc/cantools/motohawk.dbc", tmp_path / "cosim.mcap")  # not an MCAP file at all
    with pytest.raises(CosimError, match=r"cosim\.mcap: cannot read it as a ROS 2 bag \(.+\)$"):
        import_log(tmp_path / "cosim.mcap", DBC, tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_cut_short_is_one_line_and_writes_nothing(tmp_path, storage):
    """A recording killed part way: rosbags reads neither an MCAP file without its end nor a
    malformed SQLite database (rosbag2's reindex, or mcap recover, mends them first)."""
    frames = bus_frames()
    bag = write_bag(tmp_path / "bag", frames, storage, 9)
    data = next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    data.write_bytes(data.read_bytes()[: data.stat().st_size * 2 // 3])
    with pytest.raises(CosimError) as error:
        import_log(bag, DBC, tmp_path / "cut.mcap")
    assert str(error.value).startswith(f"{bag}: cannot read it as a ROS 2 bag (") and "\n" not in str(error.value)
    assert not (tmp_path / "cut.mcap").exists()


def test_a_message_that_holds_no_frame_ends_the_import_with_a_warning(tmp_path):
    """A message cut short (its CDR ends inside the frame): the frames before it are imported, as
    a damaged log's are, and the warning says where it stopped."""
    frames = [f for f in bus_frames() if not f.is_fd]
    typestore = store()
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        topic = writer.add_connection("/from_can_bus", FRAME, typestore=typestore)
        for i, (_, _, time_ns, data) in enumerate(recorded(frames)):
            writer.write(topic, time_ns, data if i != 5 else data[:20])
    result = import_log(tmp_path / "bag", DBC, tmp_path / "bag.mcap")
    assert result.record.frames == 5
    assert any(w.startswith(f"{tmp_path / 'bag'}: damaged after 5 frames (") for w in result.warnings)


# -- out: cosim export LOG --to rosbag2 -----------------------------------------------------------


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> Path:
    """CAN FD and classic frames, a reading not sent (null in /truth/faults), faults active."""
    settings = ("faults[3].start=0.5", "faults[0].start=0.3", "faults[2].start=0.7")
    return run_short("masses-faults-fd", 1.5, tmp_path_factory.mktemp("run") / "fd.mcap", *settings)


def logged(log: Path) -> tuple[list[tuple[str, int, dict]], int]:
    """The log's messages (topic, log time, payload) and the ns its frames are stamped from."""
    with LogReader(log) as reader:
        messages = list(reader.messages())
        start = int(reader.metadata()["cosim.run"]["start_time_ns"])
    return messages, start - start % 1_000_000


def same_value(ros, value) -> bool:
    """A decoded ROS field equal to the logged JSON value: NaN for a null number, an optional
    (T[<=1]) empty for null, nested messages field by field (an empty object is no field)."""
    if isinstance(value, dict):
        return all(same_value(getattr(ros, key), inner) for key, inner in value.items())
    if value is None:
        return (isinstance(ros, float) and math.isnan(ros)) or len(ros) == 0
    if isinstance(ros, np.ndarray) or (isinstance(ros, list) and not isinstance(value, list)):
        return list(ros) == [value]
    return list(ros) == value if isinstance(value, list) else ros == value


def test_a_run_exports_as_a_bag_that_rosbags_and_the_mcap_reader_decode_without_the_packages(run_log, tmp_path):
    result = export(run_log, "rosbag2", tmp_path / "bag")
    messages, start = logged(run_log)
    assert result.count == len(messages) and result.start_ns == start and result.warnings == []

    # rosbags, with nothing but the bag's own definitions (no typestore of ours)
    with AnyReader([tmp_path / "bag"]) as reader:
        read = [(c.topic, c.msgtype, t, reader.deserialize(d, c.msgtype)) for c, t, d in reader.messages()]
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert (reader.start_time, reader.end_time) == (start + messages[0][1], start + messages[-1][1] + 1)
    assert len(read) == len(messages)
    per_topic = Counter(
        ("/can/frames_fd" if m["fd"] else topic) if topic == "/can/frames" else topic for topic, _, m in messages
    )
    assert counts == dict(per_topic)  # metadata.yaml's counts, as ros2 bag info shows them

    frames = [(t, m) for topic, t, m in messages if topic == "/can/frames"]
    bag_frames = [(topic, msgtype, t, m) for topic, msgtype, t, m in read if msgtype in (FRAME, FD_FRAME)]
    assert len(bag_frames) == len(frames) and {f["fd"] for _, f in frames} == {True, False}
    for (log_time, frame), (topic, msgtype, time_ns, ros) in zip(frames, bag_frames):
        data = bytes(ros.data)[: ros.len] if msgtype == FD_FRAME else bytes(ros.data)[: ros.dlc]
        assert (topic, msgtype) == (("/can/frames_fd", FD_FRAME) if frame["fd"] else ("/can/frames", FRAME))
        assert (ros.id, ros.is_extended, data) == (frame["id"], frame["extended"], bytes.fromhex(frame["data"]))
        assert time_ns == start + log_time == ros.header.stamp.sec * 10**9 + ros.header.stamp.nanosec
        assert ros.header.frame_id == "can" and (msgtype == FD_FRAME or len(ros.data) == 8)

    others = [(topic, t, m) for topic, t, m in messages if topic != "/can/frames"]
    bag_others = [(topic, t, m) for topic, msgtype, t, m in read if msgtype not in (FRAME, FD_FRAME)]
    assert [(topic, start + t) for topic, t, _ in others] == [(topic, t) for topic, t, _ in bag_others]
    nulls = 0
    for (topic, _, payload), (_, time_ns, ros) in zip(others, bag_others):
        assert ros.header.stamp.sec * 10**9 + ros.header.stamp.nanosec == time_ns
        assert all(value == {} or same_value(getattr(ros, key), value) for key, value in payload.items()), topic
        nulls += topic == "/truth/faults" and None in payload["measured"].values()
    assert nulls > 0  # readings not sent: NaN in the bag

    # the official MCAP reader, decoding CDR by the schemas in the file; units in the definitions
    with open(tmp_path / "bag" / "bag.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [(channel.topic, schema) for schema, channel, _, _ in reader.iter_decoded_messages()]
    assert [topic for topic, _ in decoded] == [topic for topic, *_ in read]
    definitions = {topic: schema.data.decode() for topic, schema in decoded}
    assert "float64 xhat_v1  # velocity of mass 1 (the paper's x3) [m/s]\n" in definitions["/can/EST_kalman"]
    assert (
        "cosim_msgs/TruthFaultsMeasured measured  # reading sent on the bus (null: not sent)"
        in definitions["/truth/faults"]
    )
    assert definitions["/can/frames"].startswith(FRAME_MSG) and "\nMSG: std_msgs/Header\n" in definitions["/can/frames"]


def test_a_run_exported_as_a_bag_imports_back_to_the_same_frames(run_log, tmp_path):
    export(run_log, "rosbag2", tmp_path / "bag")
    assert main(["dbc", "masses-faults-fd", "--out", str(tmp_path / "bus.dbc")]) == 0
    result = import_log(tmp_path / "bag", tmp_path / "bus.dbc", tmp_path / "back.mcap")
    messages, start = logged(run_log)
    frames = [(t, m) for topic, t, m in messages if topic == "/can/frames"]
    topics, *_ = read_mcap(tmp_path / "back.mcap")
    back = topics["/can/frames"]
    assert [(start + t, f["id"], f["extended"], f["fd"], f["data"]) for t, f in frames] == [
        (t, f["id"], f["extended"], f["fd"], f["data"]) for t, f in back
    ]
    # FdFrame has no bit-rate switch: said, not guessed
    assert any(f["brs"] for _, f in frames) and not any(f["brs"] for _, f in back)
    assert any("records neither the FD flag nor the bit-rate switch" in w for w in result.warnings)
    assert result.record.decoded == len(frames) and result.record.unknown == 0
    for topic, decoded in topics.items():
        if topic != "/can/frames":
            run = [m for t, _, m in messages if t == topic]
            assert len(decoded) == len(run), topic
            for (_, found), want in zip(decoded, run):  # cantools' arithmetic, the run's codec's (no MACs)
                assert {k: found[k] for k in want} == pytest.approx(want, rel=1e-12), topic


def test_an_imported_bag_exports_back_with_its_stamps_topics_and_signals(tmp_path):
    frames = bus_frames()
    write_bag(tmp_path / "bag", frames)
    import_log(tmp_path / "bag", DBC, tmp_path / "imported.mcap")
    export(tmp_path / "imported.mcap", "rosbag2", tmp_path / "again")
    with AnyReader([tmp_path / "bag"]) as reader:
        original = [(c.topic, t, reader.deserialize(d, c.msgtype)) for c, t, d in reader.messages()]
    with AnyReader([tmp_path / "again"]) as reader:
        again = [(c.topic, c.msgtype, t, reader.deserialize(d, c.msgtype)) for c, t, d in reader.messages()]
        definitions = {c.topic: c.msgdef.data for c in reader.connections}
    frames_again = [(t, m) for _, msgtype, t, m in again if msgtype in (FRAME, FD_FRAME)]
    assert [(t, m.header.stamp, m.id, bytes(m.data)) for _, t, m in original] == [
        (t, m.header.stamp, m.id, bytes(m.data)) for t, m in frames_again
    ]
    assert [m.header.frame_id for _, m in frames_again] == [topic for topic, _, _ in original]
    # the DBC's signals: ROS field names, with the DBC's names, units and values in the comments
    foo = next(m for topic, _, _, m in again if topic == "/can/Foo")
    assert isinstance(foo.foo, float) and isinstance(foo.bar, float)
    assert "float64 foo  # Foo: Foo [degK]\n" in definitions["/can/Foo"]
    assert "float64 fam  # Fam: Fam (" in definitions["/can/Fum"]
    # and in again: the same frames as the first import
    import_log(tmp_path / "again", DBC, tmp_path / "twice.mcap")
    first, *_ = read_mcap(tmp_path / "imported.mcap")
    twice, *_ = read_mcap(tmp_path / "twice.mcap")
    assert without(first, "channel") == without(twice, "channel")


def test_a_bag_export_is_deterministic_and_replaces_only_a_bag(run_log, tmp_path, capsys):
    for name in "ab":
        (tmp_path / name).mkdir()
        export(run_log, "rosbag2", tmp_path / name / "bag")
    for file in ("metadata.yaml", "bag.mcap"):
        assert (tmp_path / "a" / "bag" / file).read_bytes() == (tmp_path / "b" / "bag" / file).read_bytes()
    out = str(tmp_path / "a" / "bag")
    assert main(["export", str(run_log), "--to", "rosbag2", "--out", out]) == 1
    assert (
        capsys.readouterr().err.strip() == f"error: {out} exists: choose another --out, or pass --force to replace it"
    )
    assert main(["export", str(run_log), "--to", "rosbag2", "--out", out, "--start-time", "0", "-f"]) == 0
    with Reader(out) as again:
        assert again.start_time == 0  # tick 0 at the epoch
    (tmp_path / "folder").mkdir()
    capsys.readouterr()
    assert main(["export", str(run_log), "--to", "rosbag2", "--out", str(tmp_path / "folder"), "-f"]) == 1
    assert "exists and is no ROS 2 bag folder" in capsys.readouterr().err
    assert list((tmp_path / "folder").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "folder"]  # no temporary folder left


def test_topics_and_signals_get_ros_names_that_never_collide():
    """ROS 2's rules (a type: CamelCase; a field: lower case, single underscores, a letter first),
    each name once: two topics or two keys that would share one are numbered, never merged."""
    number = {"type": "number", "description": "speed [m/s]"}
    schema = {
        "type": "object",
        "properties": {"Speed": number, "speed": number, "header": number, "ABSActive": {"type": "boolean"}},
        "required": ["Speed"],
        "description": "a message",
    }
    nested = {"type": "object", "properties": {"o": {"type": "object", "properties": {"x": {"type": "integer"}}}}}
    types = ros_types({"/can/ESP_21": schema, "/can/ESP21": schema, "/can/ESP_21_o": nested, "/can/ESP21O": nested})
    assert [[t.name.removeprefix("cosim_msgs/msg/") for t in types[topic].every()] for topic in types] == [
        ["CanESP21"],
        ["CanESP212"],
        ["CanESP21O", "CanESP21OO"],
        ["CanESP21O2", "CanESP21O2O"],
    ]
    text = types["/can/ESP_21"].text
    fields = ("float64 speed  # Speed: speed [m/s]", "float64 speed_2  # speed: speed [m/s]", "float64 header_2  #")
    assert "\n".join(fields) in text
    assert "\nbool[<=1] abs_active  # ABSActive\n" in text  # not required: ROS 2's optional
    typestore = store()
    register(typestore, list(types.values()))
    header = typestore.types["std_msgs/msg/Header"](typestore.types["builtin_interfaces/msg/Time"](0, 5), "")
    message = types["/can/ESP_21"].message(typestore, {"Speed": 1.5, "speed": None}, header)
    assert (message.speed, math.isnan(message.speed_2), list(message.abs_active)) == (1.5, True, [])
    msgtype = "cosim_msgs/msg/CanESP21"
    again = typestore.deserialize_cdr(typestore.serialize_cdr(message, msgtype), msgtype)
    assert again.speed == 1.5 and again.header.stamp.nanosec == 5
