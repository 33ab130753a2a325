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
