"""The run's messages compiled once into packers: bytes in and out without a database lookup per frame.

cantools stays the source of the database (``cosim.bus.codec`` builds it, and reads a DBC with it);
a ``Packer`` takes one cantools message and lays its signals out as integer fields of the frame's
payload read as one little-endian integer (every signal cosim defines is little-endian): a field
of ``length`` bits at bit ``start``, signed or not, scaled by cantools' own conversion of the signal
(the same rounding as cantools' encoder) or, for CAN FD's float64 signals, the IEEE 754 bits of the
value. ``tests/test_packing.py`` checks every message of every built-in scenario and random values
at the signals' limits bit for bit against cantools.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

_DOUBLE = struct.Struct("<d")


@dataclass(frozen=True)
class Field:
    """One signal's place in the payload, and how its value becomes those bits."""

    name: str
    start: int
    length: int
    signed: bool
    is_float: bool
    conversion: Any  # cantools.database.conversion.BaseConversion

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1


class Packer:
    """Encode and decode one message's payload (``length`` bytes) by integer arithmetic."""

    def __init__(self, message: Any) -> None:
        self.name = message.name
        self.length = message.length
        fields = []
        for signal in message.signals:
            if signal.byte_order != "little_endian":
                raise ValueError(f"{message.name}.{signal.name}: only little-endian signals are compiled")
            if signal.is_float and signal.length != 64:
                raise ValueError(f"{message.name}.{signal.name}: only 64-bit float signals are compiled")
            fields.append(
                Field(signal.name, signal.start, signal.length, signal.is_signed, signal.is_float, signal.conversion)
            )
        self.fields = tuple(fields)
        self.names = tuple(f.name for f in fields)
        self._layout = [(f.start, f.mask, f.signed, f.is_float, f.length, f.conversion) for f in fields]

    def raw(self, field: Field, value: float) -> int | float:
        """The raw value cantools' encoder would put in the frame for ``value``."""
        return field.conversion.numeric_scaled_to_raw(value)

    def encode(self, values: Sequence[float]) -> bytes:
        """The payload for one value per signal, in the message's signal order."""
        word = 0
        for (start, mask, _, is_float, _, conversion), value in zip(self._layout, values, strict=True):
            raw = conversion.numeric_scaled_to_raw(value)
            bits = int.from_bytes(_DOUBLE.pack(raw), "little") if is_float else int(raw) & mask
            word |= bits << start
        return word.to_bytes(self.length, "little")

    def decode(self, data: bytes) -> dict[str, float]:
        """Signal name → physical value, as cantools decodes it (``decode_choices=False``)."""
        word = int.from_bytes(data, "little")
        out: dict[str, float] = {}
        for (start, mask, signed, is_float, length, conversion), name in zip(self._layout, self.names):
            bits = (word >> start) & mask
            if is_float:
                out[name] = conversion.raw_to_scaled(_DOUBLE.unpack(bits.to_bytes(8, "little"))[0], False)
                continue
            if signed and bits >> (length - 1):
                bits -= 1 << length
            out[name] = conversion.raw_to_scaled(bits, False)
        return out

    def carried(self, values: Sequence[float]) -> list[float]:
        """What a receiver decodes from the payload ``encode(values)``: each value as the frame carries it."""
        return [
            conversion.raw_to_scaled(conversion.numeric_scaled_to_raw(value), False)
            for (_, _, _, _, _, conversion), value in zip(self._layout, values, strict=True)
        ]
