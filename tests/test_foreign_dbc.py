"""DBCs and CAN logs no one here wrote: public DBCs (tests/data/dbc, cantools' and opendbc's) through
the frame decoder of ``cosim monitor --dbc``, the codec's refusals and ``cosim import``, with logs
written by python-can's own writers (candump, BLF, ASC, TRC, MF4)."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import can
import cantools
import pytest
from cantools.j1939 import frame_id_unpack
from mcap.reader import make_reader

from cosim.analysis import bus_layout, names
from cosim.analysis.export import export
from cosim.analysis.layout import paths
from cosim.bus.codec import Codec
from cosim.bus.foreign import FrameDecoder, read_dbc
from cosim.errors import CodecError, CosimError
from cosim.log.can_import import import_log
from cosim.log.metadata import DBC_ATTACHMENT, IMPORT
from cosim.log.reader import LogReader
from cosim.run.replay import play
from tests.monitor_process import start_monitor, stop_monitor

ROOT = Path(__file__).resolve().parent.parent
CORPUS = sorted((ROOT / "tests" / "data" / "dbc").glob("*/*.dbc"))
REFUSED = {"issue_199.dbc", "mazda_2017.dbc"}  # cantools refuses them (see tests/data/dbc/README.md)
READABLE = [path for path in CORPUS if path.name not in REFUSED]
START = 1_718_000_000.25  # 2024-06-10, the logs' first frame (s since the epoch)


def _id(path: Path) -> str:
    return f"{path.parent.name}/{path.stem}"


def frames_of(database: cantools.database.can.Database, per_message: int, seed: int = 0) -> list[can.Message]:
    """Frames of every message of a database: random payloads its message decodes (a multiplexed
    one: with a multiplexer value it lists), each on the message's id with its own flags."""
    rng = random.Random(seed)
    frames = []
    for message in database.messages:
        found = 0
        for _ in range(50 * per_message):
            data = bytes(rng.getrandbits(8) for _ in range(message.length))
            try:
                message.decode(data, decode_choices=False)
            except Exception:  # noqa: BLE001 - a multiplexer value the message does not list
                continue
            frames.append(
                can.Message(
                    arbitration_id=message.frame_id,
                    is_extended_id=message.is_extended_frame,
                    is_fd=message.is_fd or message.length > 8,
                    bitrate_switch=message.is_fd,
                    data=data,
                )
            )
            found += 1
            if found == per_message:
                break
    rng.shuffle(frames)
    for i, frame in enumerate(frames):
        frame.timestamp = START + 0.001 * i
    return frames


@pytest.mark.parametrize("path", CORPUS, ids=_id)
def test_every_public_dbc_is_read_or_refused_in_one_line(path):
    if path.name in REFUSED:
        with pytest.raises(CodecError) as refused:
            read_dbc(path)
        text = str(refused.value)
        assert "\n" not in text and text.startswith(f"{path}: cantools cannot read it as a DBC: ")
    else:
        assert read_dbc(path).messages


@pytest.mark.parametrize("path", READABLE, ids=_id)
def test_the_codec_compiles_a_dbc_or_names_the_message_and_signal(path):
    """Every problem is a CodecError naming the message (and the signal); what compiles decodes
    every frame as cantools does."""
    text = path.read_bytes().decode("cp1252")
    try:
        codec = Codec.from_dbc(text)
    except CodecError as error:
        assert str(error).startswith("DBC message ") or "cantools cannot read" in str(error), error
        assert "\n" not in str(error)
        return
    database = cantools.database.load_string(text, strict=False)
    for frame in frames_of(database, 20):
        message = database.get_message_by_frame_id(frame.arbitration_id)
        expected = message.decode(bytes(frame.data), decode_choices=False)
        decoded = codec.decode(frame)
        assert decoded is not None
        got = {**decoded.values, "tick": decoded.tick} if "tick" in expected else decoded.values
        assert got == pytest.approx(expected, rel=1e-12)


def test_the_codec_takes_a_negative_factor_and_no_range_and_names_an_empty_one():
    dbc = 'VERSION ""\n\nBU_: X\n\nBO_ 256 M: 8 X\n'
    dbc += ' SG_ a : 0|8@1- (-0.5,0) [0|0] "m" X\n SG_ b : 8|8@1+ (1,0) [%s] "" X\n'
    codec = Codec.from_dbc(dbc % "0|10")
    frame = can.Message(arbitration_id=256, is_extended_id=False, data=bytes([4, 3, 0, 0, 0, 0, 0, 0]))
    assert codec.decode(frame).values == {"a": -2.0, "b": 3.0}
    with pytest.raises(CodecError, match=r"^DBC message M, signal b: its range \[10\|0\] holds no value"):
        Codec.from_dbc(dbc % "10|0")


@pytest.mark.parametrize("path", READABLE, ids=_id)
def test_monitor_decodes_every_frame_as_cantools_by_its_own_flag(path):
    """The decoder of ``cosim monitor --dbc``: every frame of every message as cantools decodes it,
    looked up by id and extended flag (an extended id at or below 0x7FF is no standard id)."""
    database = read_dbc(path)
    decoder = FrameDecoder(database)
    keys = {(m.is_extended_frame, m.frame_id) for m in database.messages}
    for frame in frames_of(database, 10):
        found = decoder.decode(frame)
        assert found is not None
        message, values = found
        assert (message.is_extended_frame, message.frame_id) == (frame.is_extended_id, frame.arbitration_id)
        assert values == message.decode(bytes(frame.data), decode_choices=False)
        other = can.Message(
            arbitration_id=frame.arbitration_id, is_extended_id=not frame.is_extended_id, data=frame.data
        )
        if (other.is_extended_id, other.arbitration_id) not in keys:
            assert decoder.decode(other) is None  # the same number with the other flag is another id


def test_names_of_an_attached_dbc_the_codec_cannot_compile():
    """A log carrying a DBC the codec refuses (big-endian) names its topics through cantools."""
    text = (ROOT / "tests/data/dbc/cantools/motohawk.dbc").read_text()
    assert names.prefixes(text)["/truth/state"] == "state"
    assert names.prefixes(b"not a DBC")["/truth/state"] == "state"


def write_log(frames: list[can.Message], path: Path) -> list[can.Message]:
    """Write frames with python-can's writer of the path's format; the frames it holds (TRC: no CAN FD)."""
    if path.suffix == ".mf4":
        from cosim.bus.canlogs import _python_can_mf4

        _python_can_mf4()
        from can.io.mf4 import MF4Writer as writer_class
    else:
        writer_class = {
            ".log": can.CanutilsLogWriter,
            ".blf": can.BLFWriter,
            ".asc": can.ASCWriter,
            ".trc": can.TRCWriter,
            ".csv": can.CSVWriter,
            ".db": can.SqliteWriter,
        }[path.suffix]
    kept = [f for f in frames if not (path.suffix == ".trc" and f.is_fd)]
    with writer_class(path) as writer:
        for frame in kept:
            writer.on_message_received(frame)
    return kept


def read_mcap(path: Path) -> tuple[dict[str, list[tuple[int, dict]]], dict[str, dict], dict[str, bytes], dict]:
    """Topics (log time, message), schemas, attachments and metadata, by the official mcap reader."""
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        topics: dict[str, list[tuple[int, dict]]] = {}
        schemas = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topics.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
            schemas[channel.topic] = json.loads(schema.data)
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return topics, schemas, attachments, metadata


#: The channel python-can's writers record a frame without one on, as the log names it.
CHANNEL_OF = {".log": "vcan0", ".blf": "1", ".asc": "1", ".trc": "1", ".mf4": "0"}
IMPORTED = [
    "cantools/motohawk_fd",
    "cantools/multiplex_choices",
    "cantools/j1939",
    "cantools/floating_point",
    "opendbc/toyota_adas",
]


@pytest.mark.parametrize("suffix", [".log", ".blf", ".asc", ".trc", ".mf4", ".csv", ".db"])
@pytest.mark.parametrize("name", IMPORTED)
def test_import_decodes_a_python_can_log_exactly(tmp_path, name, suffix):
    dbc = ROOT / "tests/data/dbc" / f"{name}.dbc"
    database = read_dbc(dbc)
    frames = frames_of(database, 6)
    frames.append(
        can.Message(timestamp=frames[-1].timestamp + 0.001, arbitration_id=0x7FE, is_extended_id=False, data=b"\x01")
    )
    kept = write_log(frames, tmp_path / f"bus{suffix}")
    result = import_log(tmp_path / f"bus{suffix}", dbc, tmp_path / "bus.mcap")
    topics, schemas, attachments, metadata = read_mcap(tmp_path / "bus.mcap")
    assert attachments[DBC_ATTACHMENT] == dbc.read_bytes()
    assert metadata[IMPORT]["frames"] == str(len(kept)) and metadata[IMPORT]["unknown"] == "1"
    logged = topics["/can/frames"]
    flagged = suffix not in (".csv", ".db")  # python-can's CSV and SQLite keep no FD flag: > 8 bytes is FD
    assert [(r["id"], r["extended"], r["fd"], bytes.fromhex(r["data"])) for _, r in logged] == [
        (f.arbitration_id, f.is_extended_id, f.is_fd if flagged else len(f.data) > 8, bytes(f.data)) for f in kept
    ]
    assert {r["channel"] for _, r in logged} == ({None} if suffix in (".csv", ".db") else {CHANNEL_OF[suffix]})
    # the frames' own timestamps, as precise as the format keeps them (TRC: 1 µs; the others better)
    assert all(abs(t / 1e9 - f.timestamp) < 2e-6 for (t, _), f in zip(logged, kept))
    decoder = FrameDecoder(database)
    expected: dict[str, list[tuple[int, dict]]] = {}
    for (t, _), frame in zip(logged, kept):
        if (found := decoder.decode(frame)) is not None:
            message, values = found
            if message.protocol == "j1939":  # a parameter group keeps the address its frame came from
                values = {**values, "source_address": frame_id_unpack(frame.arbitration_id).source_address}
            expected.setdefault(f"/can/{message.name}", []).append((t, values))
    assert {topic: messages for topic, messages in topics.items() if topic != "/can/frames"} == expected
    assert result.record.decoded == sum(len(m) for m in expected.values())
    for topic in expected:
        message = database.get_message_by_name(topic.removeprefix("/can/"))
        for s in message.signals:
            description = schemas[topic]["properties"][s.name]["description"]
            assert description.endswith(f" [{s.unit}]") if s.unit else "[" not in description


def test_the_whole_corpus_imports(tmp_path):
    """Every readable public DBC, its frames as a candump log, through cosim import."""
    for dbc in READABLE:
        database = read_dbc(dbc)
        frames = frames_of(database, 2, seed=1)
        if not frames:
            continue
        write_log(frames, tmp_path / "bus.log")
        result = import_log(tmp_path / "bus.log", dbc, tmp_path / f"{dbc.stem}.mcap")
        assert (result.record.frames, result.record.decoded, result.record.unknown) == (len(frames), len(frames), 0), (
            dbc
        )


def test_one_channel_of_a_log_of_several_buses_is_imported_and_each_frame_keeps_its_channel(tmp_path, capsys):
    from cosim.cli import main

    dbc = ROOT / "tests/data/dbc/cantools/motohawk.dbc"
    frames = frames_of(read_dbc(dbc), 20)
    for i, frame in enumerate(frames):
        frame.channel = i % 3 // 2  # python-can's 0 and 1: the BLF's channels 1 and 2 (CAN 1, CAN 2 in CANalyzer)
    write_log(frames, tmp_path / "buses.blf")
    whole = import_log(tmp_path / "buses.blf", dbc, tmp_path / "whole.mcap")
    assert whole.warnings == [
        "buses.blf holds frames of 2 channels (1 (14 frames), 2 (6 frames)), all decoded by the one DBC; "
        "--channel CH imports the frames of one channel alone"
    ]
    topics, *_ = read_mcap(tmp_path / "whole.mcap")
    assert [r["channel"] for _, r in topics["/can/frames"]] == [str(f.channel + 1) for f in frames]
    assert main(["import", str(tmp_path / "buses.blf"), "--dbc", str(dbc), "--channel", "2", "-q"]) == 0
    topics, _, _, metadata = read_mcap(tmp_path / "buses.mcap")
    on_two = [f for f in frames if f.channel == 1]
    assert [(r["seq"], r["channel"], bytes.fromhex(r["data"])) for _, r in topics["/can/frames"]] == [
        (i, "2", bytes(f.data)) for i, f in enumerate(on_two)
    ]
    assert (metadata[IMPORT]["channel"], metadata[IMPORT]["other_channels"]) == ("2", "14")
    with LogReader(tmp_path / "buses.mcap") as reader:
        from cosim.log.metadata import LogMetadata

        assert LogMetadata.read(reader.metadata()).imported.channel == "2"
    capsys.readouterr()
    assert (
        main(
            [
                "import",
                str(tmp_path / "buses.blf"),
                "--dbc",
                str(dbc),
                "--channel",
                "3",
                "--out",
                str(tmp_path / "x.mcap"),
            ]
        )
        == 1
    )
    assert capsys.readouterr().err.strip() == (
        f"error: --channel 3: {tmp_path / 'buses.blf'} has no frame on it; its channels: 1 (14 frames), 2 (6 frames)"
    )
    write_log(frames, tmp_path / "bus.csv")
    with pytest.raises(
        CosimError, match=r"--channel can0: .*bus\.csv has no frame on it; its format records no channel"
    ):
        import_log(tmp_path / "bus.csv", dbc, tmp_path / "csv.mcap", channel="can0")
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "csv.mcap").exists()


def test_a_signal_with_a_value_table_is_its_number_and_its_schema_names_the_values(tmp_path):
    """Numbers, as every signal (plots and exports need them; a value outside the table stays
    exact); the names are in the schema (16 at most: a DTC table may have hundreds) and the DBC."""
    dbc = ROOT / "tests/data/dbc/cantools/choices.dbc"  # Foo: signed 8 bits, values -5 and 0 to 6 named
    frames = [
        can.Message(timestamp=START + i, arbitration_id=0, is_extended_id=False, data=[v & 0xFF] + [0] * 7)
        for i, v in enumerate([0, -5, 6, 7, -1])
    ]
    write_log(frames, tmp_path / "bus.log")
    import_log(tmp_path / "bus.log", dbc, tmp_path / "bus.mcap")
    topics, schemas, *_ = read_mcap(tmp_path / "bus.mcap")
    assert [m["Foo"] for _, m in topics["/can/Foo"]] == [0, -5, 6, 7, -1]
    described = schemas["/can/Foo"]["properties"]["Foo"]
    assert described["type"] == "number" and described["description"].startswith("Foo (6: reserved, 5: reserved,")
    assert described["description"].endswith(", 0: With space, -5: A negative value)")
    many = tmp_path / "many.dbc"
    table = " ".join(f'{v} "state {v}"' for v in range(20))
    many.write_text(
        'VERSION ""\n\nBU_: ECU\n\nBO_ 1 Status: 1 ECU\n SG_ State : 0|8@1+ (1,0) [0|255] "" Vector__XXX\n\n'
        f"VAL_ 1 State {table} ;\n"
    )
    write_log([can.Message(timestamp=START, arbitration_id=1, is_extended_id=False, data=[19])], tmp_path / "s.log")
    import_log(tmp_path / "s.log", many, tmp_path / "s.mcap")
    topics, schemas, *_ = read_mcap(tmp_path / "s.mcap")
    assert topics["/can/Status"][0][1] == {"State": 19}
    description = schemas["/can/Status"]["properties"]["State"]["description"]
    assert description.endswith("15: state 15, ...)") and "16: state 16" not in description


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("imported")
    dbc = ROOT / "tests/data/dbc/cantools/motohawk_fd.dbc"
    write_log(frames_of(read_dbc(dbc), 50) + frames_of(read_dbc(dbc), 50, seed=3), folder / "bus.blf")
    return import_log(folder / "bus.blf", dbc, folder / "bus.mcap").path


def test_an_imported_log_exports_as_a_table_and_as_frames(imported, tmp_path):
    import pandas as pd

    table = pd.read_csv(export(imported, "csv", tmp_path / "bus.csv").path)
    with LogReader(imported) as reader:
        decoded = [(t, m) for _, t, m in reader.messages(["/can/ExampleMessage"])]
    assert list(table.columns[:2]) == ["time [ns]", "t [s]"] and "ExampleMessage.Temperature [degK]" in table.columns
    assert list(table["time [ns]"]) == [t for t, _ in decoded]
    assert list(table["ExampleMessage.Temperature [degK]"]) == [m["Temperature"] for _, m in decoded]
    for fmt, suffix in (("blf", ".blf"), ("candump", ".log"), ("asc", ".asc")):
        out = export(imported, fmt, tmp_path / f"again{suffix}").path
        again = list(can.LogReader(out, **({"relative_timestamp": False} if fmt == "asc" else {})))
        assert len(again) == 100 and abs(again[0].timestamp - START) < 1e-3  # stamped when recorded, not at 1970


def test_an_imported_log_gets_a_layout_and_figures(imported, tmp_path):
    with LogReader(imported) as reader:
        schemas = reader.schemas()
        found = bus_layout.messages(reader)
    layout = bus_layout.build(found)
    for path in paths(layout):
        topic, _, field = path.rpartition(".")
        assert field in schemas[topic]["properties"]
    assert [m.sender for m in found] == ["PCM1"]
    from cosim.analysis.plot import plot

    written = plot(imported, tmp_path / "plots")
    assert [p.name for p in written] == ["ExampleMessage.png"]


def test_replay_live_plays_any_python_can_log_at_its_pace(tmp_path):
    from cosim.bus.transport import allocate, drain, open_bus

    frames = frames_of(read_dbc(ROOT / "tests/data/dbc/cantools/j1939.dbc"), 10)
    write_log(frames, tmp_path / "bus.blf")
    bus = allocate("virtual", f"foreign-{os.getpid()}")
    with open_bus(bus) as listener:
        result = play(tmp_path / "bus.blf", "virtual", bus.channel, 0, speed=0.5)
        heard = list(drain(listener, 0.2))
    assert [(f.arbitration_id, f.is_extended_id, bytes(f.data)) for f in heard] == [
        (f.arbitration_id, f.is_extended_id, bytes(f.data)) for f in frames
    ]
    span = frames[-1].timestamp - frames[0].timestamp
    assert result.sim_time == pytest.approx(span, abs=1e-6) and result.wall_time >= span / 0.5 * 0.95


def test_an_unknown_log_format_is_one_line(tmp_path):
    (tmp_path / "bus.xyz").write_text("")
    with pytest.raises(CosimError, match=r"not a CAN log cosim reads \(by its suffix '.xyz'\); it reads candump"):
        import_log(tmp_path / "bus.xyz", READABLE[0], tmp_path / "bus.mcap")
    (tmp_path / "bus.blf").write_bytes(b"garbage")
    with pytest.raises(CosimError, match="cannot read it as a blf log"):
        import_log(tmp_path / "bus.blf", READABLE[0], tmp_path / "bus.mcap")
    assert not (tmp_path / "bus.mcap").exists()


@pytest.mark.slow
def test_import_of_an_mf4_log_and_inspect_on_the_command_line(tmp_path):
    """In a fresh process (which imports python-can without its MF4 support)."""
    dbc = ROOT / "tests/data/dbc/cantools/multiplex_choices.dbc"
    write_log(frames_of(read_dbc(dbc), 5), tmp_path / "bus.mf4")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "import", str(tmp_path / "bus.mf4"), "--dbc", str(dbc)],
        capture_output=True,
        text=True,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(tmp_path / "bus.mcap") and "decoded into" in done.stderr
    inspected = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "inspect", str(tmp_path / "bus.mcap"), "--json"],
        capture_output=True,
        text=True,
        env=env,
    )
    assert inspected.returncode == 0, inspected.stderr
    summary = json.loads(inspected.stdout)
    assert summary["channels"]["/can/frames"] == 15 and summary["status"] == "imported"
    assert summary["source"] == "cosim import of bus.mf4 (mf4) by multiplex_choices.dbc" and not summary["warnings"]
    refused = subprocess.run(
        [
            sys.executable,
            "-m",
            "cosim.cli",
            "import",
            str(tmp_path / "bus.mf4"),
            "--dbc",
            str(ROOT / "tests/data/dbc/opendbc/mazda_2017.dbc"),
            "--out",
            str(tmp_path / "other.mcap"),
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert (
        refused.returncode == 1 and refused.stderr.count("\n") == 1 and "Invalid syntax at line 273" in refused.stderr
    )


@pytest.mark.slow
def test_monitor_decodes_extended_frames_by_their_flag_on_a_bus(tmp_path):
    """motohawk_fd's ExampleMessage is extended id 0x1F0: a standard frame on 0x1F0 is not it."""
    from cosim.bus.transport import allocate, open_bus

    dbc = ROOT / "tests/data/dbc/cantools/motohawk_fd.dbc"
    message = read_dbc(dbc).get_message_by_name("ExampleMessage")
    config = allocate("udp_multicast")
    monitor = start_monitor(dbc, config)
    time.sleep(3.0)  # it starts and its socket joins the group
    data = message.encode({"Enable": 1, "AverageRadius": 1.5, "Temperature": 250.5})
    bus = open_bus(config)
    try:
        for _ in range(40):
            bus.send(can.Message(arbitration_id=0x1F0, is_extended_id=True, is_fd=True, data=data))
            bus.send(can.Message(arbitration_id=0x1F0, is_extended_id=False, data=b"\x00" * 8))
            time.sleep(0.05)
    finally:
        bus.shutdown()
    out, err = stop_monitor(monitor)
    assert (
        "ExampleMessage" in out
        and "000001F0" in out
        and "AverageRadius=1.5 m" in out
        and "Temperature=250.5 degK" in out
    )
    assert "unknown)" in out + err  # the standard frames on 0x1F0
