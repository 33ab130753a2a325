"""Vehicle logs through ``cosim import``, ``plot`` and ``export``, as real ones come: a damaged line
in the middle, times to the microsecond, local dates without a zone, DBCs with messages without
signals or with dozens of them, J1939 parameter groups from any source address.

The logs are written by python-can's own writers (candump, ASC, TRC) from frames of public DBCs
(``tests/data/dbc``: cantools' and commaai/opendbc's), then damaged or re-dated as a real one is.
"""

from __future__ import annotations

import time
from pathlib import Path

import can
import cantools
import pytest
from can.io.trc import TRCFileVersion
from cantools.j1939 import frame_id_pack, frame_id_unpack

from cosim import progress
from cosim.analysis import bus_figures, bus_layout
from cosim.analysis.export import export
from cosim.analysis.plot import plot
from cosim.bus.foreign import read_dbc
from cosim.cli import main
from cosim.errors import CosimError
from cosim.log.can_import import import_log
from cosim.log.metadata import IMPORT, ImportRecord
from cosim.log.reader import LogReader
from tests.test_foreign_dbc import frames_of, read_mcap, write_log

ROOT = Path(__file__).resolve().parent.parent
DBCS = ROOT / "tests" / "data" / "dbc"
MOTOHAWK = DBCS / "cantools" / "motohawk.dbc"  # ExampleMessage: 0x1F0, 8 bytes, 3 signals
START_NS = 1_718_000_000_250_000_000  # 2024-06-10 06:13:20.250 UTC
STEP_NS = 200_000  # 0.000200 s, which a float since the epoch does not hold


def motohawk_frames(count: int) -> list[can.Message]:
    """``count`` frames of motohawk's ExampleMessage, 200 µs apart from START_NS."""
    frames = frames_of(read_dbc(MOTOHAWK), count)
    for i, frame in enumerate(frames):
        frame.timestamp = (START_NS + i * STEP_NS) / 1e9
    return frames


def logged_times(path: Path) -> list[int]:
    topics, *_ = read_mcap(path)
    return [t for t, _ in topics["/can/frames"]]


def test_a_bad_line_in_a_candump_log_is_skipped_counted_and_named_and_the_frames_after_it_read(tmp_path):
    write_log(motohawk_frames(20), tmp_path / "drive.log")
    lines = (tmp_path / "drive.log").read_text().splitlines()
    lines[10:10] = ["(1718000000.252000) can0 124#11 22 33"]  # a line a hand or a tool mangled
    lines[16:16] = ["-- logging paused --"]
    (tmp_path / "drive.log").write_text("\n".join(lines) + "\n")
    result = import_log(tmp_path / "drive.log", MOTOHAWK, tmp_path / "drive.mcap")
    assert result.record.frames == 20
    assert result.warnings == [
        "drive.log: skipped 2 lines that are not frames (the first, line 11 '(1718000000.252000) can0 124#11 22 33': "
        "too many values to unpack (expected 3)); the 20 frames around them were read"
    ]
    assert logged_times(tmp_path / "drive.mcap") == [START_NS + i * STEP_NS for i in range(20)]


def test_candump_times_are_exact_where_python_cans_float_seconds_are_not(tmp_path):
    write_log(motohawk_frames(50), tmp_path / "drive.log")
    exact = [START_NS + i * STEP_NS for i in range(50)]
    assert logged_times(import_log(tmp_path / "drive.log", MOTOHAWK, tmp_path / "drive.mcap").path) == exact
    through_float = [round(f.timestamp * 1e9) for f in can.LogReader(tmp_path / "drive.log")]
    assert through_float != exact  # what the import gave before: 0.000200 s came back as 0.000199936


def test_a_file_that_is_mostly_not_a_log_is_refused_in_one_line(tmp_path):
    (tmp_path / "notes.log").write_text("".join(f"lap {i}: all fine\n" for i in range(200)))
    with pytest.raises(CosimError) as refused:
        import_log(tmp_path / "notes.log", MOTOHAWK, tmp_path / "notes.mcap")
    assert str(refused.value) == (
        f"{tmp_path / 'notes.log'}: its first 50 lines hold no candump frame (line 1 'lap 0: all fine': too many "
        "values to unpack (expected 3)): not a candump log cosim can read (its frames read like "
        "'(1718000000.000200) can0 123#DEADBEEF')"
    )
    write_log(motohawk_frames(3), tmp_path / "few.log")
    (tmp_path / "few.log").write_text((tmp_path / "few.log").read_text() + "junk\n" * 4)
    with pytest.raises(
        CosimError,
        match=r"few\.log: 4 of its lines are not candump frames, against 3 that are \(the first, line 4 'junk'",
    ):
        import_log(tmp_path / "few.log", MOTOHAWK, tmp_path / "few.mcap")
    assert not (tmp_path / "notes.mcap").exists() and not (tmp_path / "few.mcap").exists()


@pytest.fixture
def new_york(monkeypatch):
    """The process's local zone is New York's (python-can's ASC writer dates its log in local time)."""
    monkeypatch.setenv("TZ", "America/New_York")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def test_an_asc_log_is_local_time_of_unknown_zone_unless_the_zone_is_given(tmp_path, new_york, capsys):
    write_log(motohawk_frames(30), tmp_path / "drive.asc")
    assert "\nBegin Triggerblock Mon Jun 10 02:13:20.250 2024\n" in (tmp_path / "drive.asc").read_text()
    local = import_log(tmp_path / "drive.asc", MOTOHAWK, tmp_path / "local.mcap")
    assert local.record.time_zone == "unknown"
    four_hours = 4 * 3600 * 10**9  # EDT, UTC-4, in June
    assert logged_times(tmp_path / "local.mcap") == [START_NS - four_hours + i * STEP_NS for i in range(30)]
    utc = import_log(tmp_path / "drive.asc", MOTOHAWK, tmp_path / "utc.mcap", timezone="America/New_York")
    assert utc.record.time_zone == "America/New_York"
    assert logged_times(tmp_path / "utc.mcap") == [START_NS + i * STEP_NS for i in range(30)]
    assert main(["import", str(tmp_path / "drive.asc"), "--dbc", str(MOTOHAWK), "--out", str(tmp_path / "x.mcap")]) == 0
    assert "of asc from 2024-06-10 02:13:20.250 local time, zone unknown)" in capsys.readouterr().err
    figures = plot(tmp_path / "local.mcap", tmp_path / "figures", fmt="svg")
    assert "2024-06-10 02:13:20.250 local time, zone unknown" in figures[0].read_text()
    figures = plot(tmp_path / "utc.mcap", tmp_path / "utc-figures", fmt="svg")
    assert "2024-06-10 02:13:20.250 EDT (America/New_York)" in figures[0].read_text()
    result = export(tmp_path / "local.mcap", "csv", tmp_path / "local.csv")
    assert any("local time of its recording, zone unknown" in w for w in result.warnings)


def test_a_peak_trace_keeps_its_offsets_exact_its_bad_lines_counted_and_takes_a_zone(tmp_path):
    write_log(motohawk_frames(30), tmp_path / "trace.trc")
    lines = (tmp_path / "trace.trc").read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if not line.startswith(";"))
    lines[first + 5] = lines[first + 5][:40]  # cut short: python-can logs it and drops it
    lines[first + 9 : first + 9] = ["     99      12.345 DT 1  ZZZZ Rx -  8    00 00 00 00 00 00 00 00"]
    (tmp_path / "trace.trc").write_text("\n".join(lines) + "\n")
    result = import_log(tmp_path / "trace.trc", MOTOHAWK, tmp_path / "trace.mcap")
    assert result.record.frames == 29 and result.record.time_zone == "unknown"
    assert result.warnings[0].startswith(
        f"trace.trc: skipped 2 lines that are not frames (the first, line {first + 6} "
    )
    times = logged_times(tmp_path / "trace.mcap")
    kept = [i for i in range(30) if i != 5]
    # python-can writes $STARTTIME as float days (about 1 µs); the offsets, in µs, are exact from it
    assert [t - times[0] for t in times] == [i * STEP_NS for i in kept]
    assert abs(times[0] - START_NS) < 2_000
    berlin = import_log(tmp_path / "trace.trc", MOTOHAWK, tmp_path / "berlin.mcap", timezone="Europe/Berlin")
    assert berlin.record.time_zone == "Europe/Berlin"
    assert logged_times(tmp_path / "berlin.mcap") == [t - 2 * 3600 * 10**9 for t in times]  # CEST, UTC+2


def test_a_log_without_a_date_says_so_and_a_zone_is_refused_where_it_means_nothing(tmp_path, capsys):
    with can.TRCWriter(tmp_path / "old.trc") as writer:
        writer.file_version = TRCFileVersion.V1_0  # PEAK's first format: offsets in ms, no start time
        for frame in motohawk_frames(5):
            writer.on_message_received(frame)
    result = import_log(tmp_path / "old.trc", MOTOHAWK, tmp_path / "old.mcap")
    assert result.record.time_zone == "none" and result.record.start_time_ns == 0
    figure = plot(tmp_path / "old.mcap", tmp_path / "figures", fmt="svg")[0]
    assert "time since the log's first frame [s] (the log records no date)" in figure.read_text()
    with pytest.raises(CosimError, match=r"--timezone: .*old\.trc records no date"):
        import_log(tmp_path / "old.trc", MOTOHAWK, tmp_path / "x.mcap", timezone="Europe/Berlin")
    write_log(motohawk_frames(5), tmp_path / "drive.log")
    arguments = ["import", str(tmp_path / "drive.log"), "--dbc", str(MOTOHAWK), "--out", str(tmp_path / "x.mcap")]
    capsys.readouterr()
    assert main([*arguments, "--timezone", "Europe/Berlin"]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: --timezone: a candump log's times are seconds since the Unix epoch (UTC) already; the option is for "
        "the local times of ASC, TRC and BLF logs"
    )
    assert main([*arguments, "--timezone", "Europe/Berln"]) == 1
    assert "not a time zone; give an IANA name (Europe/Berlin, America/Detroit) or UTC" in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists()


def test_an_import_made_before_its_zone_was_recorded_reads_as_its_format_says():
    for fmt, zone in (("asc", "unknown"), ("trc", "unknown"), ("candump", "UTC"), ("mf4", "UTC")):
        record = ImportRecord("a.x", fmt, "car.dbc", 1, 1, start_time_ns=5)
        old = {k: v for k, v in record.to_metadata().items() if k != "time_zone"}
        assert ImportRecord.from_metadata(old, []).time_zone == zone


def import_public(tmp_path: Path, dbc: Path, per_message: int, only: str | None = None) -> Path:
    """A candump log of frames of every message of a public DBC (or of the one named), imported."""
    database = read_dbc(dbc)
    frames = frames_of(database, per_message)
    if only is not None:
        frames = [f for f in frames if f.arbitration_id == database.get_message_by_name(only).frame_id]
    write_log(frames, tmp_path / f"{dbc.stem}.log")
    return import_log(tmp_path / f"{dbc.stem}.log", dbc, tmp_path / f"{dbc.stem}.mcap").path


def test_messages_without_signals_get_no_figure_and_a_warning_and_rows_in_the_table(tmp_path, capsys):
    dbc = DBCS / "opendbc" / "mazda_radar.dbc"  # CRZ_CTRL, CRZ_INFO, RADAR_499: no signals
    log = import_public(tmp_path, dbc, 4)
    warnings: list[str] = []
    written = plot(log, tmp_path / "figures", warnings=warnings)
    bare = {m.name for m in read_dbc(dbc).messages if not m.signals}
    assert {p.stem for p in written} == {m.name for m in read_dbc(dbc).messages} - bare
    head, _, named = warnings[0].partition(": ")
    assert len(warnings) == 1 and head == "3 messages carry no signals and have no figure"
    assert sorted(named.split(", ")) == sorted(f"{name} (4 frames)" for name in bare)
    with LogReader(log) as reader:
        layout = bus_layout.build(bus_layout.messages(reader))
    assert not [key for key in layout["configById"] if key.split("!")[-1] in bare]
    import pandas as pd

    assert main(["export", str(log), "--to", "csv", "--out", str(tmp_path / "radar.csv")]) == 0
    assert f"wrote {4 * len(read_dbc(dbc).messages)} rows (decoded frames) as csv" in capsys.readouterr().err
    table = pd.read_csv(tmp_path / "radar.csv")
    assert list(table.columns[:3]) == ["time [ns]", "t [s]", "message"]
    assert (table["message"].value_counts() == 4).all() and bare <= set(table["message"])
    topics, *_ = read_mcap(log)
    assert list(table["time [ns]"]) == sorted(t for topic, m in topics.items() if topic != "/can/frames" for t, _ in m)


def test_a_message_of_many_signals_is_drawn_on_pages_a_screen_shows_and_says_its_progress(tmp_path):
    import matplotlib.image

    dbc = DBCS / "opendbc" / "tesla_powertrain.dbc"  # STW_ACTN_RQ: 31 signals, most without a unit
    log = import_public(tmp_path, dbc, 20, only="STW_ACTN_RQ")
    steps: list[tuple[str, ...]] = []
    with progress.listening(steps.append):
        written = plot(log, tmp_path / "figures")
    pages = sorted(p.name for p in written)
    assert len(pages) > 1 and pages[0] == "STW_ACTN_RQ-1.png" and all(p.startswith("STW_ACTN_RQ-") for p in pages)
    for page in written:
        height, width, _ = matplotlib.image.imread(page).shape
        assert height <= 2000 and width <= 1500, (page.name, width, height)
    with LogReader(log) as reader:
        found = {m.name: m for m in bus_layout.messages(reader)}
        tracks = bus_figures._tracks(reader, list(found.values()), 0)
    message = found["STW_ACTN_RQ"]
    drawn = [name for page in bus_figures._pages(message, tracks[message.topic]) for _, names in page for name in names]
    assert sorted(drawn) == sorted(message.units)  # every signal once
    said = [s[0] for s in steps if s]
    assert said[0].startswith("reading the ") and "figure of STW_ACTN_RQ, " in " ".join(said)


def test_a_plot_that_fails_part_way_leaves_no_folder(tmp_path, monkeypatch):
    log = import_public(tmp_path, DBCS / "opendbc" / "tesla_powertrain.dbc", 3, only="STW_ACTN_RQ")
    drawn = []

    def failing(*args, **kwargs):
        if drawn:
            raise RuntimeError("disk full")
        drawn.append(1)
        return real(*args, **kwargs)

    real = bus_figures._figure
    monkeypatch.setattr(bus_figures, "_figure", failing)
    with pytest.raises(RuntimeError):
        plot(log, tmp_path / "figures")
    assert not (tmp_path / "figures").exists() and not list(tmp_path.glob(".figures*"))


def test_the_envelope_of_a_long_curve_keeps_its_extremes_and_its_ends():
    import numpy as np

    t = np.arange(100_000) * 0.001
    v = np.sin(t) + (t == 50.0) * 5.0  # one spike
    v[70_000:70_010] = np.nan
    kept_t, kept_v = bus_figures.envelope(list(t), list(v), 1000)
    assert len(kept_t) <= 4000 and kept_t[0] == t[0] and kept_t[-1] == t[-1]
    assert np.nanmax(kept_v) == np.nanmax(v) and np.nanmin(kept_v) == np.nanmin(v)
    assert np.all(np.diff(kept_t) > 0)
    short_t, short_v = bus_figures.envelope([0.0, 1.0], [3.0, 4.0], 1000)
    assert list(short_t) == [0.0, 1.0] and list(short_v) == [3.0, 4.0]


def test_frames_the_dbc_cannot_decode_and_remote_frames_are_named_by_their_ids(tmp_path):
    write_log(motohawk_frames(3), tmp_path / "drive.log")
    extra = "(1718000000.300000) vcan0 1F0#0102\n(1718000000.300100) vcan0 1F0#R\n(1718000000.300200) vcan0 7FF#00\n"
    (tmp_path / "drive.log").write_text((tmp_path / "drive.log").read_text() + extra)
    result = import_log(tmp_path / "drive.log", MOTOHAWK, tmp_path / "drive.mcap")
    assert result.warnings == [
        "1 frames on 1 ids the DBC does not describe (0x7FF (1)): in /can/frames only",
        "1 frames on the DBC's ids are not frames of their message (too short, or a multiplexer value it does not "
        "list: 0x1F0 (1)): in /can/frames only",
        "left out 1 remote frames (0x1F0 (1)): they carry no signals",
    ]


def j1939_frame(dbc_id: int, data: bytes, priority: int, source: int, destination: int | None = None) -> can.Message:
    """A frame of the parameter group of ``dbc_id`` as another ECU sends it (cantools' J1939 helpers)."""
    parts = frame_id_unpack(dbc_id)
    specific = parts.pdu_specific if destination is None else destination
    frame_id = frame_id_pack(priority, parts.reserved, parts.data_page, parts.pdu_format, specific, source)
    return can.Message(arbitration_id=frame_id, is_extended_id=True, data=data)


def test_j1939_frames_of_any_source_address_decode_by_their_pgn_with_the_address_kept(tmp_path):
    dbc = DBCS / "cantools" / "j1939.dbc"  # Message1: PGN 0x13400 (PDU1) from 0x01; Message2: 0x1F010 from 0x02
    database = cantools.database.load_file(dbc)
    one, two = database.get_message_by_name("Message1"), database.get_message_by_name("Message2")
    frames = [
        j1939_frame(two.frame_id, bytes([0x10] * 8), 3, 0x02),
        j1939_frame(two.frame_id, bytes([0xF0] * 8), 6, 0x05),
        j1939_frame(one.frame_id, bytes([0x7F] * 8), 7, 0x21, destination=0xFF),
        j1939_frame(two.frame_id ^ 0x100, bytes(8), 6, 0x05),  # another PGN: not the DBC's
    ]
    for i, frame in enumerate(frames):
        frame.timestamp = (START_NS + i * STEP_NS) / 1e9
    write_log(frames, tmp_path / "truck.log")
    result = import_log(tmp_path / "truck.log", dbc, tmp_path / "truck.mcap")
    topics, schemas, *_ = read_mcap(tmp_path / "truck.mcap")
    assert [m for _, m in topics["/can/Message2"]] == [
        {**two.decode(frames[0].data), "source_address": 0x02},
        {**two.decode(frames[1].data), "source_address": 0x05},
    ]
    assert [m for _, m in topics["/can/Message1"]] == [{**one.decode(frames[2].data), "source_address": 0x21}]
    assert schemas["/can/Message2"]["properties"]["source_address"]["type"] == "integer"
    assert result.record.unknown == 1
    figures = plot(tmp_path / "truck.mcap", tmp_path / "figures", fmt="svg")
    drawing = next(p for p in figures if p.stem == "Message2").read_text()
    assert "Signal2, SA 0x02" in drawing and "Signal2, SA 0x05" in drawing and "source_address" not in drawing


def test_a_pgn_several_messages_share_is_told_apart_by_the_source_address(tmp_path):
    dbc = DBCS / "cantools" / "multiplex_choices.dbc"  # Message1..3: one PGN, source addresses 0x56..0x58
    database = cantools.database.load_file(dbc)
    two = database.get_message_by_name("Message2")
    data = next(f.data for f in frames_of(database, 5) if f.arbitration_id == two.frame_id)
    frames = [j1939_frame(two.frame_id, bytes(data), 2, 0x57), j1939_frame(two.frame_id, bytes(data), 6, 0x99)]
    for i, frame in enumerate(frames):
        frame.timestamp = (START_NS + i * STEP_NS) / 1e9
    write_log(frames, tmp_path / "bus.log")
    result = import_log(tmp_path / "bus.log", dbc, tmp_path / "bus.mcap")
    topics, *_ = read_mcap(tmp_path / "bus.mcap")
    assert [m["source_address"] for _, m in topics["/can/Message2"]] == [0x57]
    assert result.record.unknown == 1 and f"0x{frames[1].arbitration_id:08X} (1)" in result.warnings[0]


def test_a_j1939_signal_named_like_the_source_address_field_is_refused_in_one_line(tmp_path):
    text = (DBCS / "cantools" / "j1939.dbc").read_text().replace("Signal2", "source_address")
    (tmp_path / "clash.dbc").write_text(text)
    write_log(motohawk_frames(1), tmp_path / "bus.log")
    with pytest.raises(CosimError, match=r"J1939 message Message2 has a signal named source_address"):
        import_log(tmp_path / "bus.log", tmp_path / "clash.dbc", tmp_path / "bus.mcap")


def test_the_import_metadata_names_the_zone(tmp_path):
    write_log(motohawk_frames(2), tmp_path / "drive.log")
    import_log(tmp_path / "drive.log", MOTOHAWK, tmp_path / "drive.mcap")
    *_, metadata = read_mcap(tmp_path / "drive.mcap")
    assert metadata[IMPORT]["time_zone"] == "UTC"


def test_asc_dates_as_canoe_writes_them_and_times_relative_to_the_previous_event(tmp_path):
    from datetime import datetime

    from cosim.bus.log_lines import asc_date

    assert asc_date("Jun 10 02:13:20.250 pm 2024") == datetime(2024, 6, 10, 14, 13, 20, 250000)
    assert asc_date("Mär 3 09:00:01 2017") == datetime(2017, 3, 3, 9, 0, 1)  # CANoe in German
    assert asc_date("Foo 3 09:00:01 2017") is None
    write_log(motohawk_frames(10), tmp_path / "absolute.asc")
    relative, previous = [], 0.0
    for line in (tmp_path / "absolute.asc").read_text().splitlines():
        head, _, rest = line.strip().partition(" ")
        if head[:1].isdigit():  # Vector's "timestamps relative": each event's time from the one before
            line, previous = f"{float(head) - previous:.6f} {rest}", float(head)
        relative.append(line.replace("timestamps absolute", "timestamps relative"))
    (tmp_path / "relative.asc").write_text("\n".join(relative) + "\n")
    import_log(tmp_path / "absolute.asc", MOTOHAWK, tmp_path / "absolute.mcap")
    import_log(tmp_path / "relative.asc", MOTOHAWK, tmp_path / "relative.mcap")
    assert logged_times(tmp_path / "relative.mcap") == logged_times(tmp_path / "absolute.mcap")


def test_an_asc_date_cosim_cannot_read_is_one_line_naming_it(tmp_path):
    write_log(motohawk_frames(2), tmp_path / "drive.asc")
    text = (tmp_path / "drive.asc").read_text().replace("Begin Triggerblock Mon Jun", "Begin Triggerblock Mon Xyz")
    (tmp_path / "drive.asc").write_text(text)
    with pytest.raises(
        CosimError, match=r"drive\.asc: line 4 'Begin Triggerblock Mon Xyz 10 .*': not a date of an ASC log"
    ):
        import_log(tmp_path / "drive.asc", MOTOHAWK, tmp_path / "drive.mcap")


def test_a_text_log_saved_with_a_byte_order_mark_reads_from_its_first_line(tmp_path):
    write_log(motohawk_frames(3), tmp_path / "drive.log")
    (tmp_path / "drive.log").write_text("\ufeff" + (tmp_path / "drive.log").read_text(), encoding="utf-8")
    result = import_log(tmp_path / "drive.log", MOTOHAWK, tmp_path / "drive.mcap")
    assert result.record.frames == 3 and result.warnings == []
