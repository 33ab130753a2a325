"""The generated DBC and the frames: round trips, range checks, layout, and external decoding."""

from __future__ import annotations

import numpy as np
import pytest

import mjcf
from cosim.bus.codec import SYNC_ID, Codec, load_dbc, signal_bits
from cosim.bus.signals import Channel
from cosim.errors import CodecError

INFO = mjcf.get("masses")
SENSORS = INFO.sensors[:3]


def codec(fd: bool) -> Codec:
    return Codec(SENSORS, INFO.actuators, {"uniform": INFO.states, "kalman": INFO.states}, fd=fd, cycle_time=0.01)


def test_signal_bits_cover_the_range_at_the_resolution():
    assert signal_bits(Channel("p", "m", "", -8.0, 8.0, 1e-6)) == 24  # 8e6 < 2^23
    assert signal_bits(Channel("f", "N", "", -100.0, 100.0, 1e-4)) == 21
    assert signal_bits(Channel("h", "m", "", 0.0, 1.0, 2**-10)) == 12


def random_values(c: Codec, seed: int, count: int = 1):
    """(message, values) drawn uniformly within every signal's range, ``count`` per data message
    (NMT, SYNC and heartbeats have their own constructors)."""
    rng = np.random.default_rng(seed)
    for spec in c.messages():
        for _ in range(count if spec.channels else 0):
            yield spec, [rng.uniform(ch.minimum, ch.maximum) for ch in spec.channels]


@pytest.mark.parametrize("fd", [False, True])
def test_round_trip(fd):
    c = codec(fd)
    for spec, values in random_values(c, 1):
        frame = c.encode(spec.name, 123456, values)
        decoded = c.decode(frame)
        assert decoded.spec is spec and frame.is_fd == fd and not frame.is_extended_id
        assert decoded.tick == (123456 if fd else 123456 % 65536)
        for ch, signal, value in zip(spec.channels, spec.signals, values):
            if fd:
                assert decoded.values[signal] == value  # float64: exact
            else:
                assert abs(decoded.values[signal] - value) <= ch.resolution / 2 * (1 + 1e-9)


@pytest.mark.parametrize("fd", [False, True])
def test_range_limits_are_inclusive_and_errors_name_the_signal(fd):
    c = codec(fd)
    for value in (-8.0, 8.0):
        assert c.decode(c.encode("SENSOR_x1", 0, [value])).values["x1"] == pytest.approx(value, abs=1e-6)
    with pytest.raises(
        CodecError,
        match=r"SENSOR_x1\.x1 at tick 7 = 8\.5 m is outside its declared range \[-8, 8\] m.*\[bus\.sensors\.x1\]",
    ):
        c.encode("SENSOR_x1", 7, [8.5])
    with pytest.raises(CodecError, match=r"EST_kalman.*xhat_v2 at tick 0 = -9 m/s.*\[bus\.states\.v2\]"):
        last = c.data_messages("kalman")[-1]
        c.encode(last.name, 0, [0.0] * (len(last.channels) - 1) + [-9.0])
    with pytest.raises(CodecError, match=r"COMMAND_force\.force at tick 0 is not a number"):
        c.encode("COMMAND_force", 0, [float("nan")])


def test_classic_layout_packs_estimates_into_8_byte_frames():
    c = codec(False)
    est = c.data_messages("uniform")
    assert [s.signals for s in est] == [("xhat_x1", "xhat_x2"), ("xhat_v1", "xhat_v2")]
    assert [s.frame_id for s in est] == [0x200, 0x201]
    assert [s.frame_id for s in c.data_messages("kalman")] == [0x220, 0x221]
    assert [s.frame_id for s in c.messages(role="heartbeat")] == [0x701, 0x702]
    for message in c.database.messages:
        assert message.length <= 8 and not message.is_fd
    assert c.messages(role="sensor")[0].frame_id == 0x100 and c.messages(role="command")[0].frame_id == 0x180


def test_fd_layout_is_one_float64_frame_per_estimator():
    c = codec(True)
    (est,) = c.data_messages("uniform")
    assert est.signals == ("xhat_x1", "xhat_x2", "xhat_v1", "xhat_v2")
    assert c.database.get_message_by_name(est.name).length == 48  # 4 + 32 bytes, next FD length


def test_a_signal_too_wide_for_classic_can_is_refused_with_the_fix():
    fine = Channel("x", "m", "", -1e3, 1e3, 1e-12)
    with pytest.raises(
        CodecError,
        match=r"needs 51 bits.*set a coarser resolution or a narrower range with \[bus\.sensors\.x\], or use CAN FD",
    ):
        Codec([fine], [], {})
    Codec([fine], [], {}, fd=True)  # float64 in FD has no such limit


def test_sync_frame_is_canopen_style():
    c = codec(False)
    frame = c.sync(70000, 4)
    assert frame.arbitration_id == SYNC_ID == 0x80 and frame.dlc == 8  # tick, frames, then its MAC
    decoded = c.decode(frame)
    assert decoded.tick == 70000 and decoded.values == {"frames": 4}  # the MAC is no value


@pytest.mark.parametrize("fd", [False, True])
def test_syncs_for_several_runs_are_each_the_sync_in_a_buffer_of_its_own(fd):
    """``Codec.syncs`` (a batch's runs' SYNC of one tick): each frame is ``sync``'s, field for field,
    and each its own data buffer, which a run's signing writes into."""
    c = codec(fd)
    frames = c.syncs(70000, 4, 3)
    theirs = c.sync(70000, 4)
    fields = ("arbitration_id", "is_extended_id", "is_fd", "bitrate_switch", "dlc", "is_remote_frame", "channel")
    for frame in frames:
        assert [getattr(frame, f) for f in fields] == [getattr(theirs, f) for f in fields]
        assert frame.data == theirs.data and frame.equals(theirs, timestamp_delta=None)
    frames[0].data[-1] ^= 0xFF
    assert frames[1].data == frames[2].data == theirs.data != frames[0].data
    assert c.syncs(70000, 4, 1)[0].data == theirs.data and c.syncs(70000, 4, 0) == []


@pytest.mark.parametrize("fd", [False, True])
def test_a_heartbeat_encoded_again_is_a_frame_of_its_own_equal_to_the_first(fd):
    """``Codec.heartbeat`` encodes a node's heartbeat of given values once (the runs of a batch
    send it alike): each call gives a frame equal to the first, field for field, in a buffer of
    its own (signed in place under each run's key); other values give their own payload."""
    c = codec(fd)
    first = c.heartbeat("kalman", 5, 70000, frames=3, lost=300)
    again = c.heartbeat("kalman", 5, 70000, frames=3, lost=300)
    fields = ("arbitration_id", "is_extended_id", "is_fd", "bitrate_switch", "dlc", "is_remote_frame", "channel")
    assert [getattr(again, f) for f in fields] == [getattr(first, f) for f in fields] and again.data == first.data
    assert again.data is not first.data
    again.data[-1] ^= 0xFF
    assert c.heartbeat("kalman", 5, 70000, frames=3, lost=300).data == first.data != again.data
    assert c.decode(c.heartbeat("kalman", 5, 70000, frames=3, lost=301)).values["lost"] == 301 % 256
    assert c.decode(c.heartbeat("kalman", 5, 70001, frames=3, lost=300)).tick == 70001 % 65536


def test_a_heartbeat_carries_its_tick_mod_65536_and_the_receiver_unwraps_it():
    c = codec(True)
    decoded = c.decode(c.heartbeat("kalman", 5, 70000, frames=3, lost=300))
    assert decoded.tick == 70000 % 65536 and decoded.values == {"state": 5, "frames": 3, "lost": 300 % 256}
    assert c.with_full_tick(decoded, 70001).tick == 70000
    assert c.with_full_tick(decoded, 70000 + 30000).tick == 70000
    assert c.with_full_tick(decoded, 70000 - 30000).tick == 70000  # a tick ahead of the receiver stays ahead
    sync = c.decode(c.sync(70000, 4))
    assert c.with_full_tick(sync, 5) is sync


@pytest.mark.parametrize("fd", [False, True])
def test_the_dbc_text_decodes_frames_like_the_codec(fd):
    """An external tool loading the DBC text decodes every frame to the same values."""
    c = codec(fd)
    db = load_dbc(c.dbc)
    assert {m.name for m in db.messages} == set(c.specs)
    for spec in c.messages():
        message = db.get_message_by_frame_id(spec.frame_id)
        assert message.is_fd == (fd and bool(spec.channels))
        assert message.senders == [spec.sender]
        if spec.role == "sync":
            frame = c.sync(9, 3)
        elif spec.role == "nmt":
            frame = c.nmt(2)
        elif spec.role == "heartbeat":
            frame = c.heartbeat(spec.sender, 5, 9, 2, 1)
        else:
            frame = c.encode(spec.name, 9, [0.125] * len(spec.channels))
        external = db.decode_message(frame.arbitration_id, bytes(frame.data))
        ours = c.decode(frame)
        assert external.pop("mac", 0) == 0  # a control frame's MAC, unsigned here
        assert external.pop("tick", 0) == ours.tick
        assert external == pytest.approx(ours.values)
    if fd:
        assert 'BA_ "BusType" "CAN FD";' in c.dbc


def test_unknown_and_malformed_frames():
    import can

    c = codec(False)
    assert c.decode(can.Message(arbitration_id=0x7FF, data=b"\x00", is_extended_id=False)) is None
    assert c.decode(can.Message(arbitration_id=0x100, data=b"\x00" * 5, is_extended_id=True)) is None
    # A frame of another length than its message's is not its frame (a short one would decode as
    # zeros from cantools, a long one with trailing bytes ignored).
    with pytest.raises(CodecError, match=r"frame 0x100 \(SENSOR_x1\) has 1 data bytes; the message has 5"):
        c.decode(can.Message(arbitration_id=0x100, data=b"\x00", is_extended_id=False))
    with pytest.raises(CodecError, match=r"has 8 data bytes; the message has 5"):
        c.decode(can.Message(arbitration_id=0x100, data=b"\x00" * 8, is_extended_id=False))


def test_id_blocks_and_sync_counts_are_bounded():
    with pytest.raises(CodecError, match=r"too many estimators for the bus: at most 32 fit ids 0x200-0x5FF"):
        Codec(SENSORS, INFO.actuators, {f"e{i}": INFO.states for i in range(33)})
    with pytest.raises(CodecError, match=r"too many sensors for the bus: at most 128"):
        Codec([Channel(f"s{i}", "m", "", -1, 1, 1e-3) for i in range(129)], [], {})
    with pytest.raises(CodecError, match="a SYNC can announce at most 255"):
        codec(False).sync(0, 256)


def test_fd_data_bitrate_is_in_the_dbc():
    c = Codec(SENSORS, INFO.actuators, {}, fd=True, data_bitrate=5_000_000)
    assert load_dbc(c.dbc).dbc.attributes["BaudrateCANFD"].value == 5_000_000


@pytest.mark.parametrize("fd", [False, True])
def test_the_codec_rebuilds_exactly_from_its_dbc(fd):
    """Nodes and clients get their codec from the DBC text: same messages, same bytes."""
    c = Codec(
        SENSORS,
        INFO.actuators,
        {"uniform": INFO.states, "kalman": INFO.states},
        clients={"avg": [Channel("z", "m", "average", -8, 8, 1e-6)]},
        fd=fd,
        cycle_time=0.01,
    )
    d = Codec.from_dbc(c.dbc)
    assert d.fd == fd and d.node_ids == c.node_ids == {"uniform": 1, "kalman": 2, "avg": 3}
    assert set(d.specs) == set(c.specs)
    for name, spec in c.specs.items():
        other = d.specs[name]
        assert (other.frame_id, other.sender, other.role, other.signals) == (
            spec.frame_id,
            spec.sender,
            spec.role,
            spec.signals,
        )
        assert [(x.name, x.unit, x.minimum, x.maximum) for x in other.channels] == [
            (x.name, x.unit, x.minimum, x.maximum) for x in spec.channels
        ]
        if spec.channels:
            values = [0.5] * len(spec.channels)
            assert bytes(d.encode(name, 77, values).data) == bytes(c.encode(name, 77, values).data)
    assert bytes(d.heartbeat("avg", 5, 3, 1, 0).data) == bytes(c.heartbeat("avg", 5, 3, 1, 0).data)
    with pytest.raises(CodecError, match="cantools cannot read it as a DBC"):
        Codec.from_dbc("BO_ nonsense")


def test_one_dbc_text_is_one_shared_codec_and_a_bad_one_fails_every_time():
    text = codec(False).dbc
    assert Codec.from_dbc(text) is Codec.from_dbc(text)  # a run's nodes and a worker's runs share it
    assert Codec.from_dbc(text).dbc == text
    for _ in range(2):  # a failure is not remembered as a codec
        with pytest.raises(CodecError, match="cantools cannot read it as a DBC"):
            Codec.from_dbc("BO_ nonsense")


@pytest.mark.parametrize("fd", [False, True])
def test_encode_decoded_gives_exactly_what_a_receiver_decodes(fd):
    c = codec(fd)
    for spec, values in random_values(c, 3, count=300):
        frame, carried = c.encode_decoded(spec.name, 99, values)
        received = c.decode(frame)
        assert carried.values == received.values and carried.tick == received.tick and carried.spec is received.spec


def test_scenarios_with_one_database_share_its_codec_and_others_get_their_own():
    """A campaign's runs differ in faults, noise and seeds, not in their frames: one codec for all;
    a bit rate, a resolution or an estimator changes the database, and so the codec."""
    from cosim import scenario

    base = scenario.load("masses-bias").scenario
    same = base.with_overrides(seed=7, faults=[])
    assert same.codec() is base.codec()
    assert same.codec().dbc == base.codec().dbc
    slower = base.with_overrides(**{"bus": base.bus.model_copy(update={"bitrate": 250_000})})
    assert slower.codec() is not base.codec() and slower.codec().bitrate == 250_000
    fewer = base.with_overrides(estimators=base.estimators[:1])
    assert fewer.codec() is not base.codec() and len(fewer.codec().specs) < len(base.codec().specs)
