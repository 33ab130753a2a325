"""cosim export: every format read back by an independent library and compared with the log."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import tracemalloc
from collections import defaultdict
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from cosim.analysis import export as exporting
from cosim.analysis.export import export, parse_start_time, table_columns
from cosim.analysis.metrics import compute_metrics
from cosim.bus.codec import Codec
from cosim.cli import main
from cosim.errors import CosimError
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader
from cosim.log.recorder import FRAMES, RunRecorder
from cosim.log.writer import McapLog
from cosim.run import Run
from cosim.scenario import LoadedScenario, apply, builtin_names, load, parse_setting

FORMATS = ("csv", "parquet", "blf", "mf4", "candump")


def run_short(name: str, duration: float, out: Path, *settings: str) -> Path:
    loaded = apply(load(name), [parse_setting(text) for text in settings]) if settings else load(name)
    scenario = loaded.scenario.model_copy(update={"duration": duration})
    Run(LoadedScenario(scenario, f"{name} ({duration:g} s)", ""), out, interface="virtual").execute()
    return out


@pytest.fixture(scope="module")
def classic_log(tmp_path_factory) -> Path:
    """The default scenario (classic CAN) through its fault onset at 5 s."""
    return run_short("masses-bias", 6.0, tmp_path_factory.mktemp("classic") / "masses-bias.mcap")


@pytest.fixture(scope="module")
def fd_log(tmp_path_factory) -> Path:
    """CAN FD with dropped frames (from 10 s), outliers, a stuck sensor and an actuator fault."""
    return run_short("masses-faults-fd", 10.5, tmp_path_factory.mktemp("fd") / "masses-faults-fd.mcap")


def logged_frames(log: Path) -> list[tuple[int, dict]]:
    with LogReader(log) as reader:
        return [(t, frame) for _, t, frame in reader.messages([FRAMES])]


def logged_start(log: Path) -> float:
    """When the run started, in s since the epoch, to the millisecond: what frame exports stamp tick 0 with."""
    with LogReader(log) as reader:
        start = json.loads(reader.metadata()["cosim.run"]["start_time_ns"])
    assert 1.7e18 < start < 4e18  # a date of this century, in ns
    return start // 1_000_000 / 1000


def node_names(log: Path) -> dict[str, str]:
    """Decoded topic name (EST_kalman_0) → the node it belongs to, from the run's metadata (not the DBC,
    which the exporter reads)."""
    with LogReader(log) as reader:
        run = LogMetadata.read(reader.metadata()).run
    assert run is not None
    found = {m: name for name, e in run.estimators.items() for m in e.messages}
    found.update({m: name for name, c in run.clients.items() for m in c["messages"]})
    if run.controller is not None:
        found.update(dict.fromkeys(run.controller.status_messages, "controller"))
    return found


def logged_dbc(log: Path) -> str:
    with LogReader(log) as reader:
        return reader.attachments()["cosim.dbc"].decode()


def logged_signals(log: Path) -> dict[str, list[tuple[int, dict]]]:
    """Decoded messages per DBC message name: (log time, values) in log order."""
    out: dict[str, list[tuple[int, dict]]] = defaultdict(list)
    with LogReader(log) as reader:
        for topic, t, message in reader.messages():
            if topic.startswith("/can/") and topic != FRAMES:
                out[topic.removeprefix("/can/")].append((t, message))
    return out


def same(a, b) -> bool:
    """Equal, with NaN equal to NaN and to a missing (None) value."""

    def missing(v):
        return v is None or v == "" or (isinstance(v, float) and math.isnan(v))

    return (missing(a) and missing(b)) or a == b


# -- tidy tables ----------------------------------------------------------------------------------


def expected_table(log: Path) -> dict[int, dict[str, object]]:
    """tick → {column: value} built straight from the log messages (not with the exporter's code):
    a node's signals are named after the node (kalman.xhat_x1), whichever frame carried them."""
    rows: dict[int, dict[str, object]] = defaultdict(dict)
    nodes = node_names(log)
    with LogReader(log) as reader:
        for topic, t, message in reader.messages():
            if topic.startswith("/truth/"):
                k = message["tick"]
                rows[k]["t"] = t / 1e9
                for key, value in message.items():
                    if isinstance(value, dict):
                        for inner, v in value.items():
                            rows[k][f"{topic[7:]}.{key}.{inner}"] = v
                    elif isinstance(value, list):
                        rows[k][f"{topic[7:]}.{key}"] = ",".join(value)
                    elif key not in ("tick", "t"):
                        rows[k][f"{topic[7:]}.{key}"] = value
            elif (
                topic.startswith("/can/")
                and topic != FRAMES
                and not topic.startswith(("/can/SYNC", "/can/NMT", "/can/HEARTBEAT"))
            ):
                k = t // 10_000_000  # τ = 10 ms; lockstep logs a frame at the tick it carries
                assert message["tick"] == k % 2**16 or message["tick"] == k
                for key, value in message.items():
                    if key != "tick":
                        rows[k][f"{nodes.get(topic[5:], topic[5:])}.{key}"] = value
    return rows


def bare(name: str) -> str:
    return name.split(" [")[0]


def check_table(records: list[dict], log: Path) -> None:
    expected = expected_table(log)
    assert [r["tick"] for r in records] == sorted(expected)
    for record in records:
        want = expected[record["tick"]]
        assert record["t [s]"] == want["t"]
        got = {bare(name): value for name, value in record.items() if name not in ("tick", "t [s]")}
        assert set(got) >= set(want) - {"t"}
        for name, value in got.items():
            assert same(value, want.get(name)), (record["tick"], name, value, want.get(name))


@pytest.mark.parametrize("which", ["classic_log", "fd_log"])
def test_csv_reads_back_in_pandas_with_every_value_of_the_log(which, request, tmp_path):
    import pandas as pd

    log = request.getfixturevalue(which)
    result = export(log, "csv", tmp_path / "out.csv")
    frame = pd.read_csv(result.path, keep_default_na=False, na_values=[""])  # pandas >= 3 parses floats exactly
    assert result.count == len(frame) and result.warnings == []
    assert frame.columns[:4].tolist() == ["tick", "t [s]", "state.x1 [m]", "state.x2 [m]"]
    assert "kalman.xhat_x1 [m]" in frame.columns and "uniform.xhat_v2 [m/s]" in frame.columns
    assert not any(c.startswith("EST_") for c in frame.columns)
    check_table(frame.to_dict("records"), log)


def test_parquet_reads_back_in_pyarrow_with_units_and_every_value(fd_log, tmp_path):
    import pyarrow.parquet as pq

    result = export(fd_log, "parquet", tmp_path / "out.parquet")
    table = pq.read_table(result.path)
    assert table.num_rows == result.count == 1050
    assert table.schema.field("state.v1 [m/s]").metadata[b"unit"] == b"m/s"
    assert table.schema.field("inputs.effective.force [N]").metadata[b"source"] == b"/truth/inputs.effective.force"
    assert json.loads(table.schema.metadata[b"cosim.run"])["scenario"] == "masses-faults-fd"
    records = table.to_pylist()
    check_table(records, fd_log)
    dropped = [r for r in records if r["faults.dropped"]]
    assert dropped and all(
        r["SENSOR_x2_minus_x1.x2_minus_x1 [m]"] is None for r in dropped
    )  # a frame not sent is empty


def test_table_columns_are_named_after_topic_and_field_with_units(classic_log):
    with LogReader(classic_log) as reader:
        names = [c.name for c in table_columns(reader.schemas(), reader.attachments()["cosim.dbc"])]
    assert {
        "inputs.commanded.force [N]",
        "faults.noise.x1 [m]",
        "faults.effectiveness.force",
        "faults.active",
        "SENSOR_x1_minus_x2.x1_minus_x2 [m]",
        "uniform.xhat_v2 [m/s]",
        "COMMAND_force.force [N]",
    } <= set(names)
    assert not any(n.startswith(("SYNC", "HEARTBEAT", "NMT", "EST_")) for n in names) and len(names) == len(set(names))


def test_an_estimator_has_the_same_columns_on_classic_can_and_can_fd(classic_log, tmp_path):
    """The default scenario on CAN FD packs each estimator into one frame, on classic CAN into two:
    the tables have the same columns, and the same estimates (up to the classic scaling)."""
    fd = run_short("masses-bias", 6.0, tmp_path / "fd.mcap", "bus.fd=true")
    columns = {}
    for name, log in (("classic", classic_log), ("fd", fd)):
        with LogReader(log) as reader:
            columns[name] = [c.name for c in table_columns(reader.schemas(), reader.attachments()["cosim.dbc"])]
    assert columns["classic"] == columns["fd"]
    assert [c for c in columns["fd"] if c.startswith("kalman.")] == [
        "kalman.xhat_x1 [m]",
        "kalman.xhat_x2 [m]",
        "kalman.xhat_v1 [m/s]",
        "kalman.xhat_v2 [m/s]",
    ]


# -- frame logs -----------------------------------------------------------------------------------


def check_frames(read: list[can.Message], log: Path, time_resolution: float, start: float = 0.0) -> None:
    """The frames read back are the log's, in order, each at ``start`` plus its simulated time."""
    frames = logged_frames(log)
    assert len(read) == len(frames)
    for message, (t, frame) in zip(read, frames):
        assert message.arbitration_id == frame["id"] and message.is_extended_id == frame["extended"]
        assert message.is_fd == frame["fd"] and message.bitrate_switch == frame["brs"]
        assert bytes(message.data) == bytes.fromhex(frame["data"])
        assert abs(message.timestamp - (start + t / 1e9)) <= time_resolution


def check_decoded(decoded: dict[str, list[tuple[float, dict]]], log: Path, start: float = 0.0) -> None:
    """Values decoded by another library with the log's DBC equal the log's decoded messages."""
    logged = logged_signals(log)
    assert set(decoded) == set(logged)
    for name, entries in logged.items():
        assert len(decoded[name]) == len(entries), name
        for (t, values), (t_read, read) in zip(entries, decoded[name]):
            assert abs(t_read - (start + t / 1e9)) < 1e-6
            assert {k: float(v) for k, v in read.items() if k in values} == {k: float(v) for k, v in values.items()}, (
                name
            )


@pytest.mark.parametrize("which", ["classic_log", "fd_log"])
def test_blf_reads_back_with_python_can(which, request, tmp_path):
    log = request.getfixturevalue(which)
    result = export(log, "blf", tmp_path / "out.blf")
    reader = can.BLFReader(result.path)
    read = list(reader)
    # the header holds the start to the millisecond, the frames ns after it (through floats: ~0.3 µs)
    assert reader.start_timestamp == logged_start(log)
    check_frames(read, log, 1e-6, logged_start(log))
    assert {m.channel for m in read} == {0}  # BLF channel 1 (python-can counts from 0)


@pytest.mark.parametrize("which", ["classic_log", "fd_log"])
def test_candump_reads_back_with_python_can_and_decodes_with_cantools(which, request, tmp_path):
    from cantools.logreader import Parser

    log = request.getfixturevalue(which)
    result = export(log, "candump", tmp_path / "out.log")
    start = logged_start(log)
    assert result.start_ns == round(start * 1000) * 1_000_000 and result.warnings == []
    check_frames(list(can.LogReader(result.path)), log, 1e-6, start)
    database = cantools.database.load_string(logged_dbc(log), database_format="dbc")
    decoded: dict[str, list] = defaultdict(list)
    with open(result.path) as stream:
        lines = 0
        for entry in Parser(stream):
            lines += 1
            message = database.get_message_by_frame_id(entry.frame_id)
            decoded[message.name].append(
                (entry.timestamp.timestamp(), message.decode(entry.data, decode_choices=False))
            )
    assert lines == result.count
    check_decoded(decoded, log, start)


@pytest.mark.parametrize("which", ["classic_log", "fd_log"])
def test_asc_reads_back_with_python_can_and_is_dated_at_the_runs_start(which, request, tmp_path):
    """Vector's ASC: the header's date is the run's (not the export's), the frames relative to it."""
    from datetime import datetime

    log = request.getfixturevalue(which)
    result = export(log, "asc", tmp_path / "out.asc")
    start = logged_start(log)
    header = result.path.read_text().splitlines()
    when = datetime.fromtimestamp(start)
    assert header[0] == "date " + when.strftime(f"%a %b %d %H:%M:%S.{when.microsecond // 1000:03d} %Y")
    block = header[3].removeprefix("Begin Triggerblock ").split()  # python-can writes its ms unpadded here
    clock, milliseconds = block[3].split(".")
    assert header[3].startswith("Begin Triggerblock ") and block[:3] + block[4:] == header[0].split()[1:4] + [
        header[0].split()[5]
    ]
    assert clock == when.strftime("%H:%M:%S") and int(milliseconds) == when.microsecond // 1000
    check_frames(list(can.ASCReader(result.path)), log, 1e-6)  # relative to the trigger block's start
    assert result.count == len(logged_frames(log))


def test_trc_reads_back_with_python_can_at_the_runs_date(classic_log, tmp_path):
    """PEAK's TRC 2.1: absolute times from its $STARTTIME, the header naming the file written."""
    result = export(classic_log, "trc", tmp_path / "bus.trc")
    text = result.path.read_text()
    assert ";$FILEVERSION=2.1" in text and ";   bus.trc\n" in text and ".part" not in text
    check_frames(list(can.TRCReader(result.path)), classic_log, 1e-5, logged_start(classic_log))  # 0.1 µs


def test_trc_refuses_can_fd_frames_rather_than_leaving_them_out(fd_log, tmp_path):
    with pytest.raises(CosimError, match=r"--to trc: the log has CAN FD frames.*--to asc, blf, candump or mf4"):
        export(fd_log, "trc", tmp_path / "bus.trc")
    assert list(tmp_path.iterdir()) == []  # no file, not even a part


def test_candump_has_the_run_s_date_for_can_utils_and_start_time_overrides_it(classic_log, tmp_path):
    """can-utils' log2asc writes one header with the run's date (not one per line from 1970);
    --start-time 0 gives times from the epoch, an ISO date and time its own."""
    from datetime import UTC, datetime

    result = export(classic_log, "candump", tmp_path / "run.log")
    start = logged_start(classic_log)
    first = result.path.read_text().splitlines()[0]
    assert first.startswith(f"({start:.6f}) can0 ") and first.endswith(" R")
    epoch = export(classic_log, "candump", tmp_path / "epoch.log", start_ns=0)
    assert epoch.path.read_text().splitlines()[0].startswith("(0.000000) can0 ")
    noon = parse_start_time("2025-06-01T12:00:00Z")
    assert noon == parse_start_time("2025-06-01T14:00:00+02:00") == parse_start_time("1748779200") == 1748779200 * 10**9
    assert list(can.LogReader(export(classic_log, "candump", tmp_path / "noon.log", start_ns=noon).path))[
        -1
    ].timestamp == pytest.approx(1748779200 + 6.0, abs=1e-6)
    with pytest.raises(CosimError, match="--start-time 'yesterday': give an ISO 8601 date"):
        parse_start_time("yesterday")
    with pytest.raises(CosimError, match="--start-time stamps the frame logs"):
        export(classic_log, "csv", tmp_path / "x.csv", start_ns=0)
    log2asc = shutil.which("log2asc")
    if log2asc is None:
        pytest.skip("can-utils' log2asc is not installed (apt-get install can-utils)")
    asc = subprocess.run([log2asc, "-I", str(result.path), "can0"], capture_output=True, text=True, check=True).stdout
    dates = [line for line in asc.splitlines() if line.startswith("date ")]
    when = datetime.fromtimestamp(start, UTC)
    assert dates == [f"date {when.strftime('%a %b')} {when.day:2d} {when.strftime('%H:%M:%S %Y')}"]
    assert len(asc.splitlines()) == 3 + result.count  # date, base, internal events, then a line per frame


@pytest.mark.parametrize("which", ["classic_log", "fd_log"])
def test_mf4_is_a_bus_log_that_asammdf_decodes_with_the_attached_dbc(which, request, tmp_path):
    from asammdf import MDF

    log = request.getfixturevalue(which)
    result = export(log, "mf4", tmp_path / "out.mf4")
    with MDF(result.path) as mdf:
        assert mdf.version == "4.10"
        assert mdf.start_time.timestamp() == logged_start(log)  # the run's date; timestamps after it
        data, name, _ = mdf.extract_attachment(0)
        assert name.name == "cosim.dbc" and data.decode() == logged_dbc(log)
        ids, lengths, payload, edl, brs = (
            mdf.get(f"CAN_DataFrame.{c}") for c in ("ID", "DataLength", "DataBytes", "EDL", "BRS")
        )
        read = [
            can.Message(
                timestamp=t,
                arbitration_id=int(i) & 0x1FFFFFFF,
                is_extended_id=bool(int(i) >> 31),
                is_fd=bool(e),
                bitrate_switch=bool(b),
                data=bytes(d[:n]),
            )
            for t, i, n, d, e, b in zip(
                ids.timestamps, ids.samples, lengths.samples, payload.samples, edl.samples, brs.samples
            )
        ]
        check_frames(read, log, 1e-9)
        dbc = tmp_path / name.name
        dbc.write_bytes(data)
        extracted = mdf.extract_bus_logging({"CAN": [(str(dbc), 0)]})
    database = cantools.database.load_string(data.decode(), database_format="dbc")
    decoded = {}
    for message in database.messages:
        signals = {s.name: extracted.get(f"CAN1.{message.name}.{s.name}") for s in message.signals}
        times = next(iter(signals.values())).timestamps
        decoded[message.name] = [(t, {s: sig.samples[i] for s, sig in signals.items()}) for i, t in enumerate(times)]
    decoded = {name: entries for name, entries in decoded.items() if entries}
    check_decoded(decoded, log)


def test_exports_are_deterministic(classic_log, tmp_path):
    """The same bytes whenever and wherever they are written (TRC's header names the file)."""
    for n in "ab":
        (tmp_path / n).mkdir()
    for fmt in FORMATS:
        a, b = (export(classic_log, fmt, tmp_path / n / f"out.{fmt}").path.read_bytes() for n in "ab")
        assert a == b, fmt


@pytest.mark.slow
@pytest.mark.parametrize("name", builtin_names())
def test_every_builtin_scenario_log_inspects_and_exports_to_every_format(name, tmp_path):
    log = run_short(name, 0.5 if name != "three-tank-reconciliation" else 3.0, tmp_path / f"{name}.mcap")
    metrics = compute_metrics(log)
    assert metrics["status"] == "completed" and metrics["warnings"] == [] and metrics["missing"] == [], metrics[
        "missing"
    ]
    assert set(metrics["estimators"]) == {e.name for e in load(name).scenario.estimators}
    with LogReader(log) as reader:
        frames = sum(1 for _ in reader.messages([FRAMES]))
        ticks = int(reader.metadata()["cosim.result"]["ticks"])
    start = logged_start(log)
    fd = load(name).scenario.bus.fd
    for fmt in FORMATS:
        if fmt == "trc" and fd:  # classic CAN only (test_trc_refuses_can_fd_frames_rather_than_leaving_them_out)
            continue
        result = export(log, fmt, tmp_path / f"out.{fmt}")
        assert result.count == (ticks if fmt in ("csv", "parquet") else frames) and result.warnings == [], fmt
        if fmt in ("candump", "mf4", "blf"):
            assert result.start_ns == round(start * 1000) * 1_000_000, fmt  # the run's date
    assert (tmp_path / "out.candump").read_text().startswith(f"({start:.6f}) ")
    # a ROS 2 bag of every topic, each message decoded by the definition in the file (mcap_ros2)
    bag = export(log, "rosbag2", tmp_path / "bag")
    with open(tmp_path / "bag" / "bag.mcap", "rb") as stream, LogReader(log) as reader:
        decoded = make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
        assert sum(1 for _ in decoded) == bag.count == sum(1 for _ in reader.messages()) and bag.warnings == []

    # the same scenario on the other bus (classic CAN for CAN FD, and back): the same table columns
    other = run_short(
        name, 2 * load(name).scenario.sample_time, tmp_path / "other.mcap", f"bus.fd={str(not fd).lower()}"
    )
    names = []
    for path in (log, other):
        with LogReader(path) as reader:
            names.append([c.name for c in table_columns(reader.schemas(), reader.attachments()["cosim.dbc"])])
    assert names[0] == names[1]


# -- bad input ------------------------------------------------------------------------------------


def test_bad_input_gives_one_message_naming_the_fix(classic_log, tmp_path, capsys):
    with pytest.raises(CosimError, match="unknown export format 'xlsx': choose one of csv, parquet, blf, mf4, candump"):
        export(classic_log, "xlsx")
    with pytest.raises(CosimError, match="no such file"):
        export(tmp_path / "missing.mcap", "csv")
    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    with pytest.raises(CosimError, match="not a readable MCAP file"):
        export(text, "blf")
    with pytest.raises(CosimError, match="--dbc is used by the mf4 export only"):
        export(classic_log, "csv", dbc=tmp_path / "x.dbc")
    with pytest.raises(CosimError, match="overwrite the log"):
        export(classic_log, "csv", classic_log)

    foreign = tmp_path / "foreign.mcap"  # /can/frames but no DBC and no cosim metadata: another program's log
    with McapLog(foreign) as other:
        channel = other.channel(FRAMES, {"type": "object"})
        other.write(
            channel,
            0,
            {"id": 0x123, "extended": False, "fd": False, "brs": False, "dlc": 2, "length": 2, "data": "abcd"},
        )
    with pytest.raises(CosimError, match=r"no DBC attached .* pass --dbc FILE.dbc \(write it with 'cosim dbc SCENARIO"):
        export(foreign, "mf4")
    with pytest.raises(CosimError, match="no cosim.run metadata"):
        export(foreign, "csv")
    result = export(foreign, "candump", tmp_path / "foreign.log")
    assert result.path.read_text() == "(0.000000) can0 123#ABCD R\n"
    assert any("does not record when the run started" in w and "--start-time" in w for w in result.warnings)
    dbc = tmp_path / "bus.dbc"
    dbc.write_text(logged_dbc(classic_log))
    assert export(foreign, "mf4", tmp_path / "foreign.mf4", dbc=dbc).count == 1
    assert not list(tmp_path.glob("*.part*"))  # failed exports leave nothing behind

    assert main(["export", str(foreign), "--to", "mf4", "--out", str(tmp_path / "f.mf4")]) == 1
    err = capsys.readouterr().err
    assert "--dbc FILE.dbc" in err and "Traceback" not in err and len(err.strip().splitlines()) <= 2


def test_a_cut_log_exports_what_it_holds_with_a_warning(classic_log, tmp_path):
    cut = tmp_path / "cut.mcap"
    data = classic_log.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    result = export(cut, "candump", tmp_path / "cut.log")
    assert 0 < result.count < len(logged_frames(classic_log))
    assert any("cut" in w or "summary" in w for w in result.warnings)


def test_cli_export_writes_next_to_the_log_by_default(classic_log, tmp_path, capsys):
    log = tmp_path / "run.mcap"
    log.write_bytes(classic_log.read_bytes())
    assert main(["export", str(log), "--to", "parquet"]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "run.parquet")
    assert (tmp_path / "run.parquet").stat().st_size > 10_000
    with pytest.raises(SystemExit):
        main(["export", str(log), "--to", "xlsx"])


# -- bounded memory -------------------------------------------------------------------------------


def long_log(path: Path, ticks: int) -> Path:
    """A log with the default scenario's traffic and truth, written with the real codec and recorder
    (no simulation: values are sines, which is all an exporter sees)."""
    loaded = load()
    scenario = loaded.scenario
    codec: Codec = scenario.codec()
    states, sensors, actuators = ("x1", "x2", "v1", "v2"), tuple(scenario.sensors), tuple(scenario.actuators)
    units = {
        "states": dict.fromkeys(states, "m"),
        "sensors": dict.fromkeys(sensors, "m"),
        "actuators": dict.fromkeys(actuators, "N"),
    }
    estimates = codec.messages(role="estimate")
    with McapLog(path) as log:
        log.metadata("cosim.run", {"scenario": scenario.name, "sample_time": "0.01", "bus": json.dumps({"fd": False})})
        log.attach("cosim.dbc", "text/plain", codec.dbc.encode())
        recorder = RunRecorder(log, codec, states=states, sensors=sensors, actuators=actuators, units=units)
        for k in range(ticks):
            t, t_ns = k * 0.01, k * 10_000_000
            y = [0.1 * math.sin(0.01 * k + i) for i in range(len(sensors))]
            frames = [(codec.sync(k, len(sensors)), None)]
            frames += [codec.encode_decoded(f"SENSOR_{s}", k, (v,)) for s, v in zip(sensors, y)]
            frames += [codec.encode_decoded(m.name, k, [0.05] * len(m.signals)) for m in estimates]
            for frame, decoded in frames:
                recorder.frame(k, t, t_ns, frame, decoded if decoded is not None else codec.decode(frame))
            x = np.array([y[0], y[1], 0.0, 0.0])
            recorder.truth(
                k,
                t,
                t_ns,
                x=x,
                y_true=np.array(y),
                noise=np.zeros(len(y)),
                fault=np.zeros(len(y)),
                measured=np.array(y),
                active=(),
                u_cmd=np.zeros(1),
                u_eff=np.zeros(1),
                delta=np.ones(1),
            )
    return path


@pytest.mark.slow
def test_exports_stream_in_bounded_memory(tmp_path, monkeypatch):
    """Peak Python memory of each export does not grow with the log: a log 4x longer (and well past
    every buffer, shrunk here to keep the test short) peaks at about the same."""
    monkeypatch.setattr(exporting, "PARQUET_BATCH_ROWS", 128)
    monkeypatch.setattr(exporting, "MF4_BATCH_FRAMES", 1024)
    monkeypatch.setattr(exporting, "MF4_FRAGMENT_BYTES", 64 * 1024)
    monkeypatch.setattr(exporting, "ROW_WINDOW", 64)
    logs = {ticks: long_log(tmp_path / f"{ticks}.mcap", ticks) for ticks in (500, 2000)}
    for fmt in FORMATS:
        peaks = []
        for ticks, log in logs.items():
            tracemalloc.start()
            result = export(log, fmt, tmp_path / f"out.{fmt}")
            peaks.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
            per_tick = 1 if fmt in ("csv", "parquet") else 8  # SYNC, 3 sensors, 2 estimators x 2 frames
            assert result.count == per_tick * ticks, (fmt, result.count)
        assert peaks[1] < 1.25 * peaks[0] + 512 * 1024, (fmt, peaks)


def test_the_command_line_offers_every_export_format():
    from cosim.analysis.export import FORMATS
    from cosim.cli.export import EXPORT_FORMATS

    assert sorted(EXPORT_FORMATS) == sorted(FORMATS)
