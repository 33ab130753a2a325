"""The compiled packers encode and decode every message of every built-in scenario bit for bit as cantools does."""

from __future__ import annotations

import random

import pytest

from cosim import scenario
from cosim.bus.packing import Packer


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
