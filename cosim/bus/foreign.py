"""Any DBC, read and decoded through cantools: a vehicle's, a bench's, or one ``cosim dbc`` wrote.

The run's own codec (``cosim.bus.codec``) compiles cosim's DBCs into fast packers and refuses
what they never hold (big-endian, 32-bit float or multiplexed signals, extended ids). A DBC from
elsewhere is read here instead, as cantools reads it (``strict=False``: vehicle DBCs often have
overlapping signals), and its frames are decoded by cantools, every signal as cantools decodes
it (numbers, not choice names).

A frame is looked up by its own identifier *and* its own flag: a DBC may hold a standard message
on 0x123 and an extended one on 0x123 (a J1939 or a UDS id), and an extended frame whose id is at
most 0x7FF is still an extended frame (cantools' ``get_message_by_frame_id`` takes the number alone).

A J1939 DBC's messages are parameter groups (``VFrameFormat`` ``J1939PG``, cantools' protocol
``j1939``): their ids carry a priority and the address of the ECU that sent them, which a bus's
frames need not share with the DBC. As J1939 tools do, a frame that no message's id matches is
decoded by the message of its parameter group number (cantools' ``j1939.pgn_from_frame_id``: the
priority, the source address and a PDU1 group's destination left out), and its source address is
kept (``source_address``). A PGN that several of the DBC's messages share (one per sender) is
matched by the PGN and the source address: a frame of it from another address is not the DBC's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can
import cantools
from cantools.database.can import Database, Message
from cantools.j1939 import frame_id_unpack, pgn_from_frame_id

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


#: Ids looked up by their parameter group number that a decoder remembers (a fuzzed log has many).
PGN_LOOKUPS_KEPT = 65536


def is_j1939(message: Message) -> bool:
    """Whether a DBC message is a J1939 parameter group (an extended id with a source address)."""
    return message.protocol == "j1939" and message.is_extended_frame


def source_address(frame_id: int) -> int:
    """The address of the ECU that sends a J1939 frame of this id (its low byte)."""
    return int(frame_id_unpack(frame_id).source_address)


class FrameDecoder:
    """The messages of a database by (extended, id), J1939 ones also by their parameter group
    number, and frames decoded by them."""

    def __init__(self, database: Database) -> None:
        self.database = database
        self._messages = {(m.is_extended_frame, m.frame_id): m for m in database.messages}
        groups: dict[int, list[Message]] = {}
        for message in filter(is_j1939, database.messages):
            groups.setdefault(pgn_from_frame_id(message.frame_id), []).append(message)
        self._by_pgn = {pgn: found[0] for pgn, found in groups.items() if len(found) == 1}
        self._by_sender = {(pgn, source_address(m.frame_id)): m for pgn, found in groups.items() for m in found}
        self._by_id: dict[int, Message | None] = {}

    def message(self, frame: can.Message) -> Message | None:
        """The DBC message of a frame, by its id and its own extended flag, or a J1939 frame's by
        its parameter group number (None: not in the DBC)."""
        found = self._messages.get((bool(frame.is_extended_id), frame.arbitration_id))
        if found is not None or not frame.is_extended_id or not self._by_sender:
            return found
        frame_id = frame.arbitration_id
        if frame_id not in self._by_id:
            if len(self._by_id) >= PGN_LOOKUPS_KEPT:
                self._by_id.clear()
            pgn = pgn_from_frame_id(frame_id)
            self._by_id[frame_id] = self._by_sender.get((pgn, source_address(frame_id)), self._by_pgn.get(pgn))
        return self._by_id[frame_id]

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
