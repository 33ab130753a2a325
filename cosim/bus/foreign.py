"""Any DBC, read and decoded through cantools: a vehicle's, a bench's, or one ``cosim dbc`` wrote.

The run's own codec (``cosim.bus.codec``) compiles cosim's DBCs into fast packers and refuses
what they never hold (big-endian, 32-bit float or multiplexed signals, extended ids). A DBC from
elsewhere is read here instead, as cantools reads it (``strict=False``: vehicle DBCs often have
overlapping signals), and its frames are decoded by cantools, every signal as cantools decodes
it (numbers, not choice names).

A frame is looked up by its own identifier *and* its own flag: a DBC may hold a standard message
on 0x123 and an extended one on 0x123 (a J1939 or a UDS id), and an extended frame whose id is at
most 0x7FF is still an extended frame (cantools' ``get_message_by_frame_id`` takes the number alone).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can
import cantools
from cantools.database.can import Database, Message

from cosim.bus.dbc import refusal
from cosim.errors import CodecError


def read_dbc(path: str | Path) -> Database:
    """The CAN database of a DBC file, as cantools reads it; one CodecError line naming the file
    and cantools' reason for a file it cannot read or refuses."""
    try:
        database = cantools.database.load_file(str(path), database_format="dbc", strict=False)
    except OSError as error:
        raise CodecError(f"{path}: cannot read the DBC ({error.strerror or error})") from None
    except Exception as error:  # noqa: BLE001 - cantools raises several parse error types
        raise CodecError(f"{path}: cantools cannot read it as a DBC: {refusal(error)}") from None
    if not isinstance(database, Database):  # never from the DBC format
        raise CodecError(f"{path}: not a CAN database")
    return database


class FrameDecoder:
    """The messages of a database by (extended, id), and frames decoded by them."""

    def __init__(self, database: Database) -> None:
        self.database = database
        self._messages = {(m.is_extended_frame, m.frame_id): m for m in database.messages}

    def message(self, frame: can.Message) -> Message | None:
        """The DBC message of a frame, by its id and its own extended flag (None: not in the DBC)."""
        return self._messages.get((bool(frame.is_extended_id), frame.arbitration_id))

    def decode(self, frame: can.Message) -> tuple[Message, dict[str, Any]] | None:
        """The frame's message and its signals as cantools decodes them (numbers; a multiplexed
        message's present signals only); None for a frame the DBC does not describe, or one that
        is not a frame of its message (too short, an unknown multiplexer value, a remote frame)."""
        message = self.message(frame)
        if message is None or frame.is_remote_frame or frame.is_error_frame:
            return None
        try:
            values = message.decode(bytes(frame.data), decode_choices=False)
        except (cantools.database.DecodeError, ValueError, KeyError, IndexError):
            return None
        return (message, values) if isinstance(values, dict) else None  # a container message: not in a DBC
