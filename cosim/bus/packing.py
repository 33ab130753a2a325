"""The run's messages compiled once into packers: bytes in and out without a database lookup per frame.

cantools stays the source of the database (``cosim.bus.codec`` builds it, and reads a DBC with it);
a ``Packer`` takes one cantools message and lays its signals out as integer fields of the frame's
payload read as one little-endian integer (every signal cosim defines is little-endian): a field
of ``length`` bits at bit ``start``, signed or not, scaled by cantools' own conversion of the signal
or, for CAN FD's float64 signals, the IEEE 754 bits of the value.

The packer is compiled: for each message, Python source with one line per signal (its shift, mask,
sign and the conversion's scale and offset folded in as constants) is generated once and compiled,
so encoding or decoding a frame is one function call with no loop and no lookup. The arithmetic is
cantools' own, operation for operation: a linear signal's raw value is ``round((v - offset) /
scale)`` and its physical value ``raw * scale + offset`` (``LinearConversion``), an identity
conversion rounds (integers) or passes the value (floats); a conversion of another kind is called
as cantools would call it. ``tests/test_packing.py`` checks every message of every built-in scenario
and random values at the signals' limits bit for bit against cantools.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from cantools.database.conversion import IdentityConversion, LinearConversion

from cosim.errors import CodecError

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
    """Encode and decode one message's payload (``length`` bytes) by integer arithmetic.

    ``order`` names the signals in the order ``encode`` and ``carried`` take their values (default:
    the message's signal order); ``decode`` returns them in that order too.
    """

    def __init__(self, message: Any, order: Sequence[str] | None = None) -> None:
        self.name = message.name
        self.length = message.length
        by_name = {}
        for signal in message.signals:
            if (problem := uncompiled(signal)) is not None:
                raise CodecError(
                    f"DBC message {message.name}, signal {signal.name}: {problem}, which cosim's bus codec does not "
                    "compile (its own DBCs never have them); 'cosim monitor --dbc' and 'cosim import' decode such "
                    "a bus through cantools"
                )
            by_name[signal.name] = Field(
                signal.name, signal.start, signal.length, signal.is_signed, signal.is_float, signal.conversion
            )
        names = tuple(order) if order is not None else tuple(by_name)
        if sorted(names) != sorted(by_name):
            raise ValueError(f"{message.name}: the order {names} does not name its signals {tuple(by_name)}")
        self.fields = tuple(by_name[name] for name in names)
        self.names = names
        compiled = _compile(self.name, self.fields, self.length)
        self.encode: Callable[[Sequence[float]], bytes] = compiled["encode"]
        """The payload for one value per signal, in ``names`` order."""
        self.encode_carried: Callable[[Sequence[float]], tuple[bytes, list[float]]] = compiled["encode_carried"]
        """The payload, and each value as the frame carries it (what a receiver decodes)."""
        self.decode: Callable[[bytes | bytearray], dict[str, float]] = compiled["decode"]
        """Signal name → physical value, as cantools decodes it (``decode_choices=False``)."""
        self.unpack: Callable[[bytes | bytearray], tuple[float, ...]] = compiled["unpack"]
        """The physical values, in ``names`` order."""

    def encode_rows(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``encode_carried`` of K payloads at once: ``values`` (K, fields) in ``names`` order, each in
        its signal's range; the payloads (K, length) uint8 and the values as the frames carry them
        (K, fields), row by row the bytes and floats ``encode_carried`` gives. None for a message
        it does not pack on arrays (``RowsPacker``); a message without signals has payloads of zeros."""
        if not self.fields:
            return np.zeros((len(values), self.length), dtype=np.uint8), np.empty((len(values), 0))
        if self._rows is None:
            return None
        words, carried = self._rows.encode_rows(values)
        return words.astype("<u8").view(np.uint8).reshape(len(values), 8)[:, : self.length], carried

    @functools.cached_property
    def _rows(self) -> RowsPacker | None:
        """This message's ``RowsPacker`` (None: not packed on arrays), built at first use."""
        return rows_packer((self,))

    @property
    def packs_rows(self) -> bool:
        """Whether ``RowsPacker`` packs this message: at most 8 bytes, one signal or more (each
        message's fields are OR-ed from its first), integer signals of at most 53 bits (a raw value
        of more is not exact in a float), linear or identity conversions."""
        return (
            self.length <= 8
            and bool(self.fields)
            and all(
                not f.is_float and f.length <= 53 and isinstance(f.conversion, (LinearConversion, IdentityConversion))
                for f in self.fields
            )
        )

    def raw(self, field: Field, value: float) -> int | float:
        """The raw value cantools' encoder would put in the frame for ``value``."""
        return field.conversion.numeric_scaled_to_raw(value)

    def carried(self, values: Sequence[float]) -> list[float]:
        """What a receiver decodes from the payload ``encode(values)``: each value as the frame carries it."""
        return self.encode_carried(values)[1]


class _Columns:
    """Integer signals' conversions as arrays, one column per field: the raw values
    ``rint((v - offset) / scale)`` and the values as the frames carry them, ``raw * scale + offset``
    (a linear conversion), or the raw values themselves (an identity conversion, whose scale 1 and
    offset 0 leave v as it is). Element-wise operations give each column the bits they give it
    alone, so every value is cantools' (NumPy's ``rint`` rounds half to even as Python's ``round``
    does, and an integer raw value times the scale is the float's)."""

    def __init__(self, conversions: Sequence[Any]) -> None:
        linear = [isinstance(c, LinearConversion) for c in conversions]
        self.scale = np.array([float(c.scale) if lin else 1.0 for c, lin in zip(conversions, linear)])
        self.offset = np.array([float(c.offset) if lin else 0.0 for c, lin in zip(conversions, linear)])
        self.identity = ~np.array(linear, dtype=bool)

    def raw_and_carried(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The raw values (rounded floats) and the carried values of ``values`` (K, columns)."""
        raw = np.rint((values - self.offset) / self.scale)
        return raw, np.where(self.identity, raw, raw * self.scale + self.offset)


def _integer(conversion: Any) -> bool:
    """Whether a signal's conversion is one ``_Columns`` computes (linear or identity, of integers)."""
    return isinstance(conversion, (LinearConversion, IdentityConversion)) and not conversion.is_float


class RowsPacker:
    """``Packer.encode_carried`` of several messages for K frames each, on arrays, every field of
    every message in one operation per step (``_Columns``): each field's raw bits shifted into
    their place, and each message's fields OR-ed into one 64-bit word (``np.bitwise_or.reduceat``)."""

    def __init__(self, packers: Sequence[Packer]) -> None:
        fields = [f for packer in packers for f in packer.fields]
        self.columns = _Columns([f.conversion for f in fields])
        self.masks = np.array([f.mask for f in fields], dtype=np.uint64)
        self.starts = np.array([f.start for f in fields], dtype=np.uint64)
        #: The column of each message's first field.
        self.first = np.cumsum([0, *(len(packer.fields) for packer in packers[:-1])])

    def encode_rows(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``values`` (K, fields: every message's, in order), each in its signal's range: each
        message's payload as a little-endian 64-bit word (K, messages), and the values as the
        frames carry them (K, fields)."""
        raw, carried = self.columns.raw_and_carried(values)
        bits = (raw.astype(np.int64).astype(np.uint64) & self.masks) << self.starts
        return np.bitwise_or.reduceat(bits, self.first, axis=1), carried


def rows_packer(packers: Sequence[Packer]) -> RowsPacker | None:
    """The ``RowsPacker`` of these messages, or None where one of them is not packed on arrays
    (``Packer.packs_rows``)."""
    return RowsPacker(packers) if packers and all(p.packs_rows for p in packers) else None


class CarriedValues:
    """Values of K frames of some fields, (K, fields), as the frames carry them: ``encode_carried``'s
    second part for each row, bit for bit: integer signals on arrays (``_Columns``), a float
    signal's value as it is, a conversion of another kind by cantools' own methods, value by value."""

    def __init__(self, fields: Sequence[Field]) -> None:
        conversions = [f.conversion for f in fields]
        integer = [_integer(c) for c in conversions]
        self.columns = _Columns([c if i else None for c, i in zip(conversions, integer)])
        self.integer = np.array(integer, dtype=bool)
        self.every = all(integer)
        self.other = [
            (i, c)
            for i, (c, whole) in enumerate(zip(conversions, integer))
            if not whole and not isinstance(c, IdentityConversion)
        ]

    def __call__(self, values: np.ndarray) -> np.ndarray:
        if self.every:
            return self.columns.raw_and_carried(values)[1]
        found = np.where(self.integer, self.columns.raw_and_carried(np.where(self.integer, values, 0.0))[1], values)
        for i, conversion in self.other:  # another kind: cantools' own methods, value by value
            found[:, i] = [conversion.raw_to_scaled(conversion.numeric_scaled_to_raw(x), False) for x in values[:, i]]
        return found


def uncompiled(signal: Any) -> str | None:
    """Why a cantools signal cannot be compiled into a packer (None: it can): big-endian, a float
    of other than 64 bits, or one of a multiplexed message's signals (present in some frames only)."""
    if signal.byte_order != "little_endian":
        return "it is big-endian (Motorola byte order)"
    if signal.is_float and signal.length != 64:
        return f"it is a {signal.length}-bit float"
    if signal.is_multiplexer or signal.multiplexer_ids:
        return "its message is multiplexed"
    return None


def _compile(name: str, fields: tuple[Field, ...], length: int) -> dict[str, Any]:
    """Source for the message's four functions, compiled. Constants go in as names of the namespace
    (never as printed floats), so nothing is lost in a repr."""
    namespace: dict[str, Any] = {
        "_pack_double": _DOUBLE.pack,
        "_unpack_double": _DOUBLE.unpack,
        "_from": int.from_bytes,
    }
    values = [f"v{i}" for i in range(len(fields))]
    unpacked = ", ".join(values) + ("," if len(values) == 1 else "")
    raw_lines, carried, word = _encoder_source(fields, namespace)
    decode_lines, results = _decoder_source(fields, namespace)
    source = "\n".join(
        [
            "def encode(values):",
            f"    {unpacked} = values" if values else "    () = values",
            *raw_lines,
            f"    return ({word}).to_bytes({length}, 'little')",
            "def encode_carried(values):",
            f"    {unpacked} = values" if values else "    () = values",
            *raw_lines,
            f"    return ({word}).to_bytes({length}, 'little'), [{', '.join(carried)}]",
            "def unpack(data):",
            *decode_lines,
            f"    return ({', '.join(results)}{',' if len(results) == 1 else ''})",
            "def decode(data):",
            *decode_lines,
            "    return {" + ", ".join(f"{f.name!r}: {r}" for f, r in zip(fields, results)) + "}",
        ]
    )
    exec(compile(source, f"<packer {name}>", "exec"), namespace)  # noqa: S102 - our own generated source
    return namespace


def _encoder_source(fields: tuple[Field, ...], namespace: dict[str, Any]) -> tuple[list[str], list[str], str]:
    """The lines that turn each value v_i into its raw value r_i, the expressions of the values as
    the frame carries them, and the expression of the payload word."""
    raw_lines, carried, bits = [], [], []
    for i, field in enumerate(fields):
        conversion = field.conversion
        namespace[f"c{i}"] = conversion
        v, r = f"v{i}", f"r{i}"
        if isinstance(conversion, LinearConversion) and not conversion.is_float:
            namespace[f"s{i}"], namespace[f"o{i}"] = conversion.scale, conversion.offset
            raw_lines.append(f"    {r} = round(({v} - o{i}) / s{i})")
            carried.append(f"{r} * s{i} + o{i}")
        elif isinstance(conversion, IdentityConversion):
            raw_lines.append(f"    {r} = {v}" if conversion.is_float else f"    {r} = round({v})")
            carried.append(r)
        else:  # another kind: cantools' own methods
            raw_lines.append(f"    {r} = c{i}.numeric_scaled_to_raw({v})")
            carried.append(f"c{i}.raw_to_scaled({r}, False)")
        if field.is_float:
            bits.append(f"(_from(_pack_double({r}), 'little') << {field.start})")
        else:
            bits.append(f"((int({r}) & {field.mask}) << {field.start})")
    return raw_lines, carried, " | ".join(bits) if bits else "0"


def _decoder_source(fields: tuple[Field, ...], namespace: dict[str, Any]) -> tuple[list[str], list[str]]:
    """The lines that cut the payload word w into raw values b_i, and the expressions of their
    physical values."""
    decode_lines, results = ["    w = _from(data, 'little')"], []
    for i, field in enumerate(fields):
        b = f"b{i}"
        decode_lines.append(f"    {b} = (w >> {field.start}) & {field.mask}")
        if field.is_float:
            decode_lines.append(f"    {b} = _unpack_double({b}.to_bytes(8, 'little'))[0]")
        elif field.signed:
            decode_lines.append(f"    if {b} >> {field.length - 1}: {b} -= {1 << field.length}")
        conversion = field.conversion
        if isinstance(conversion, LinearConversion):
            results.append(f"{b} * s{i} + o{i}")
            namespace[f"s{i}"], namespace[f"o{i}"] = conversion.scale, conversion.offset
        elif isinstance(conversion, IdentityConversion):
            results.append(b)
        else:
            results.append(f"c{i}.raw_to_scaled({b}, False)")
    return decode_lines, results
