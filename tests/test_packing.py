"""The compiled packers encode and decode every message of every built-in scenario bit for bit as cantools does."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from cosim import scenario
from cosim.bus.packing import Packer, rows_packer


def _values(message, rng: random.Random, extreme: bool) -> list[float]:
    values = []
    for signal in message.signals:
        if signal.minimum is None or signal.maximum is None:  # the integer control fields
            top = (1 << signal.length) - 1
            values.append(rng.choice([0, top]) if extreme else rng.randrange(top + 1))
            continue
        if extreme:
            values.append(rng.choice([signal.minimum, signal.maximum, 0.0]))
        else:
            values.append(rng.uniform(signal.minimum, signal.maximum))
    return values


@pytest.mark.parametrize("name", scenario.builtin_names())
def test_every_message_packs_and_unpacks_as_cantools_does(name):
    codec = scenario.load(name).scenario.codec()
    rng = random.Random(name)
    for message in codec.database.messages:
        packer = Packer(message)
        for trial in range(60):
            values = _values(message, rng, extreme=trial % 3 == 0)
            ours = packer.encode(values)
            theirs = message.encode(dict(zip(packer.names, values)), strict=False)
            assert ours == bytes(theirs), (message.name, values)
            decoded = packer.decode(ours)
            assert decoded == message.decode_simple(bytes(theirs), decode_choices=False), message.name
            assert list(decoded.values()) == packer.carried(values), message.name


@pytest.mark.parametrize("name", scenario.builtin_names())
def test_the_codec_encodes_and_decodes_through_its_packers_as_cantools_does(name):
    codec = scenario.load(name).scenario.codec()
    rng = random.Random(name + "/codec")
    for spec in codec.specs.values():
        message = codec.database.get_message_by_name(spec.name)
        for trial in range(20):
            if spec.channels:
                extreme = trial % 2 == 0
                values = [
                    rng.choice([c.minimum, c.maximum, 0.0]) if extreme else rng.uniform(c.minimum, c.maximum)
                    for c in spec.channels
                ]
                tick = rng.randrange(2**32)
                frame, carried = codec.encode_decoded(spec.name, tick, values)
                payload = {"tick": tick % codec.tick_modulus, **dict(zip(spec.signals, values))}
            else:  # NMT, SYNC, heartbeats: integer fields
                payload = {s.name: rng.randrange(1 << s.length) for s in message.signals}
                frame = codec._classic(spec.name, payload)
                carried = None
            theirs = message.decode_simple(message.encode(payload, strict=False), decode_choices=False)
            assert bytes(frame.data) == message.encode(payload, strict=False), (spec.name, payload)
            decoded = codec.decode(frame)
            assert decoded is not None and decoded.tick == int(theirs.pop("tick", 0)), spec.name
            theirs.pop("mac", None)  # a control frame's MAC: in the DBC, no value of the codec's
            assert list(decoded.values.items()) == list(theirs.items()), spec.name  # same values, same order
            if carried is not None:  # what a receiver decodes, to the bit, in the same order (a batch hands it on)
                assert carried.tick == decoded.tick and carried.values == decoded.values, spec.name
                assert [(name, type(v), repr(v)) for name, v in carried.values.items()] == [
                    (name, type(v), repr(v)) for name, v in decoded.values.items()
                ], spec.name


@pytest.mark.parametrize("name", scenario.builtin_names())
def test_frames_encoded_on_arrays_are_encode_decodeds_row_by_row(name):
    """``Codec.encode_rows`` (a batch's runs' frames of one message at once) against
    ``encode_decoded`` frame by frame: the same bytes, ids and flags, and the same decoded tick,
    values, their order and types (an identity conversion's integers), at the ranges' bounds, at
    zero and between; None only for a message it does not pack on arrays (CAN FD, float signals)."""
    codec = scenario.load(name).scenario.codec()
    rng = random.Random(name + "/rows")
    packed = 0
    for spec in codec.specs.values():
        if not spec.channels:
            continue
        tick = rng.randrange(2**32)
        values = [
            [
                rng.choice([c.minimum, c.maximum, 0.0 if c.minimum <= 0 <= c.maximum else c.minimum])
                for c in spec.channels
            ]
            if trial % 3 == 0
            else [rng.uniform(c.minimum, c.maximum) for c in spec.channels]
            for trial in range(30)
        ]
        rows = codec.encode_rows([spec.name], tick, np.array(values, dtype=float))
        if rows is None:
            assert codec.fd or spec.name in {m.name for m in codec.database.messages if m.length > 8}
            continue
        packed += 1
        for found, row in zip(rows, values, strict=True):
            assert found is not None and len(found) == 1
            frame, decoded = found[0]
            theirs, carried = codec.encode_decoded(spec.name, tick, row)
            assert (
                frame.arbitration_id,
                frame.is_extended_id,
                frame.is_fd,
                frame.bitrate_switch,
                bytes(frame.data),
            ) == (
                theirs.arbitration_id,
                theirs.is_extended_id,
                theirs.is_fd,
                theirs.bitrate_switch,
                bytes(theirs.data),
            ), (spec.name, row)
            assert decoded.spec is carried.spec and decoded.tick == carried.tick and type(decoded.tick) is int
            assert [(k, type(v), repr(v)) for k, v in decoded.values.items()] == [
                (k, type(v), repr(v)) for k, v in carried.values.items()
            ], (spec.name, row)
    assert packed > 0 or codec.fd


@pytest.mark.parametrize("name", ["masses-pid-can", "three-tank-reconciliation", "vessel-nominal"])
def test_several_messages_encoded_on_arrays_at_once_are_each_rows_frames_or_none_where_one_does_not_fit(name):
    """``Codec.encode_rows`` of every data message packed on arrays at once (a node's messages, the
    runner's sensors), some frames not sent and some values out of range or NaN: each row's frames
    are those ``encode_decoded`` gives of the messages it sends, in order, and a row is None
    exactly where one of the values it sends is one ``encode`` refuses (a value it does not send
    never matters)."""
    from cosim.errors import CodecError

    codec = scenario.apply(scenario.load(name), [("bus.fd", False)]).scenario.codec()
    lows = {spec.name: np.array([[c.minimum for c in spec.channels]]) for spec in codec.specs.values()}
    specs = [
        spec for spec in codec.specs.values() if spec.channels and codec.encode_rows([spec.name], 0, lows[spec.name])
    ]
    assert len(specs) >= 5
    rng = random.Random(name + "/group")
    for _ in range(8):
        tick, chosen = rng.randrange(2**32), rng.sample(specs, min(len(specs), rng.randint(2, 7)))
        rows, sent = [], []
        for _ in range(40):
            row = []
            for spec in chosen:
                for c in spec.channels:
                    wild = rng.random()
                    row.append(
                        math.nan
                        if wild < 0.02
                        else c.maximum * 1.5 + 1.0
                        if wild < 0.04
                        else rng.uniform(c.minimum, c.maximum)
                    )
            rows.append(row)
            sent.append([rng.random() < 0.8 for _ in chosen])
        found = codec.encode_rows([spec.name for spec in chosen], tick, np.array(rows), np.array(sent))
        assert found is not None and len(found) == len(rows)
        for frames, row, on in zip(found, rows, sent):
            expected, refused, at = [], False, 0
            for spec, built in zip(chosen, on):
                values, at = row[at : at + len(spec.channels)], at + len(spec.channels)
                if not built:
                    continue
                try:
                    expected.append(codec.encode_decoded(spec.name, tick, values))
                except CodecError:
                    refused = True
            if refused:
                assert frames is None
                continue
            assert frames is not None and len(frames) == len(expected)
            for (frame, decoded), (theirs, carried) in zip(frames, expected):
                assert (frame.arbitration_id, bytes(frame.data), frame.is_fd) == (
                    theirs.arbitration_id,
                    bytes(theirs.data),
                    theirs.is_fd,
                )
                assert decoded.spec is carried.spec and decoded.tick == carried.tick
                assert [(k, repr(v)) for k, v in decoded.values.items()] == [
                    (k, repr(v)) for k, v in carried.values.items()
                ]


def test_frames_encoded_on_arrays_equal_cantools_on_the_public_dbcs_of_its_tests():
    """``Packer.encode_rows`` on cantools' own test databases (tests/data/dbc/cantools): every message
    it packs on arrays, at its signals' bounds and between, gives the payload cantools encodes (and
    the compiled packer's), and all of a file's messages in one ``RowsPacker`` give each its own; a
    signal over 53 bits, a float or a conversion of another kind is not packed on arrays (None),
    never packed wrong."""
    from pathlib import Path

    import cantools

    from cosim.errors import CodecError

    packed, grouped = 0, 0
    for path in sorted((Path(__file__).parent / "data" / "dbc" / "cantools").glob("*.dbc")):
        try:
            database = cantools.database.load_file(path, strict=False)
        except cantools.database.UnsupportedDatabaseFormatError:
            continue
        together = []
        for message in database.messages:
            try:
                packer = Packer(message)
            except CodecError:  # big-endian, multiplexed: not compiled at all
                continue
            rng = random.Random(f"{path.name}/{message.name}")
            rows = []
            for _ in range(40):
                row = []
                for field in packer.fields:
                    signal, lowest = message.get_signal_by_name(field.name), 0
                    highest = (1 << field.length) - 1
                    if field.signed:
                        lowest, highest = -(1 << (field.length - 1)), (1 << (field.length - 1)) - 1
                    low = (
                        signal.minimum if signal.minimum is not None else signal.conversion.raw_to_scaled(lowest, False)
                    )
                    high = (
                        signal.maximum
                        if signal.maximum is not None
                        else signal.conversion.raw_to_scaled(highest, False)
                    )
                    row.append(rng.choice([low, high, rng.uniform(low, high)]))
                rows.append(row)
            found = packer.encode_rows(np.array(rows, dtype=float))
            if found is None:
                assert message.length > 8 or any(
                    f.is_float
                    or f.length > 53
                    or type(f.conversion).__name__ not in ("LinearConversion", "IdentityConversion")
                    for f in packer.fields
                ), message.name
                continue
            packed += 1
            for payload, row in zip(found[0], rows):
                theirs = bytes(message.encode(dict(zip(packer.names, row)), strict=False))
                assert bytes(payload) == theirs == packer.encode(row), (path.name, message.name, row)
            together.append((packer, np.array(rows, dtype=float), found[0]))
        if len(together) >= 2:  # every message the file packs, in one RowsPacker: each its own bytes
            words, _ = rows_packer([packer for packer, _, _ in together]).encode_rows(
                np.concatenate([rows for _, rows, _ in together], axis=1)
            )
            payloads = words.astype("<u8").view(np.uint8).reshape(len(words), -1, 8)
            for j, (packer, _, alone) in enumerate(together):
                assert (payloads[:, j, : packer.length] == alone).all(), (path.name, packer.name)
            grouped += 1
    assert packed >= 20 and grouped >= 5


def test_a_message_without_signals_is_packed_on_arrays_as_zeros_and_joins_no_group():
    """``Packer.encode_rows`` of a message without signals gives its payloads, all zeros (what
    ``encode`` gives); ``RowsPacker``, which OR-s each message's fields from its first, takes none."""
    from cantools.database.can import Message

    packer = Packer(Message(frame_id=0x123, name="EMPTY", length=2, signals=[]))
    payloads, carried = packer.encode_rows(np.zeros((3, 0)))
    assert payloads.tolist() == [list(packer.encode([]))] * 3 == [[0, 0]] * 3 and carried.shape == (3, 0)
    assert not packer.packs_rows and rows_packer([packer]) is None
