"""Authenticated frames in the spirit of AUTOSAR SecOC (``[bus] authentication = "secoc"``, CAN FD).

Every data frame (sensors, commands, control status, estimates, clients: the CAN FD messages that
carry a ``tick``) becomes a *secured PDU*: the authentic PDU (the message's signals as before),
then a 4-byte trailer, then the padding to the next CAN FD length::

    | authentic PDU (n bytes: tick, signals) | FV (1 byte) | MAC (3 bytes) | padding |
      byte 0 .. n-1                            n             n+1 .. n+3

as SecOC profile 1 ("24Bit-CMAC-8Bit-FV") has it:

- the freshness value (FV) is the tick counter k of the frame (32 bits in full, a time-based FV
  every receiver knows from SYNC); the frame carries its 8 least significant bits (``secoc_fv``);
- the MAC (``secoc_mac``) is AES-128-CMAC over ``id (2 bytes, big-endian) | authentic PDU | full FV
  (4 bytes, big-endian)``, truncated to its 24 most significant bits;
- each sender has its own key, derived (HKDF-SHA256) from the run secret and the sender's name
  (``cosim.bus.keys``).

A receiver rebuilds the full FV as the latest tick ≤ its current tick (the last SYNC) with those 8
bits, verifies the MAC, and accepts the frame only if its FV is newer than the last it accepted on
that id and at most ``WINDOW`` ticks old. What fails is dropped and reported with a reason:
``bad_mac`` (the MAC does not match: forged or altered, or more than 255 ticks late), ``replayed``
(a genuine MAC, but the FV is not newer than the last one accepted on the id) or ``stale`` (a
genuine, newer FV, but older than the window).

The DBC describes the trailer: the two signals are appended to each secured message, whose length
grows to hold them. ``Codec.from_dbc`` takes them out again (``cosim.bus.dbc.strip_secoc_trailer``),
so the codec encodes and decodes the authentic PDU of a frame of the secured length, and this
module fills and checks the trailer.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from dataclasses import dataclass

import can
import cantools
from cantools.database.can import Database, Signal

from cosim.bus.dbc import SECOC_SIGNALS, DatabaseView, fd_length

FV_SIGNAL, MAC_SIGNAL = SECOC_SIGNALS
FV_BYTES, MAC_BYTES = 1, 3
TRAILER = FV_BYTES + MAC_BYTES
WINDOW = 8
"""Ticks a frame may be late and still be accepted (a delayed or arbitrated frame arrives after its tick)."""
BAD_MAC, REPLAYED, STALE = "bad_mac", "replayed", "stale"
REASONS = (BAD_MAC, REPLAYED, STALE)
_FV_MODULUS = 2**32


def _secured(message: cantools.database.can.Message) -> bool:
    names = {signal.name for signal in message.signals}
    return bool(message.is_fd) and "tick" in names


def secure_dbc(text: str) -> str:
    """The DBC with the SecOC trailer appended to every CAN FD data message."""
    database = cantools.database.load_string(text, database_format="dbc")
    assert isinstance(database, Database)
    for message in database.messages:
        if not _secured(message):
            continue
        used = (max(signal.start + signal.length for signal in message.signals) + 7) // 8
        length = fd_length(used + TRAILER)  # the codec's frames hold at most 60 bytes of signals
        message.signals.append(
            Signal(FV_SIGNAL, 8 * used, 8 * FV_BYTES, comment="SecOC: the 8 least significant bits of the freshness")
        )
        message.signals.append(
            Signal(MAC_SIGNAL, 8 * (used + FV_BYTES), 8 * MAC_BYTES, comment="SecOC: AES-CMAC truncated to 24 bits")
        )
        message.length = length
        message.refresh()
    database.refresh()
    return database.as_dbc_string()


@dataclass(frozen=True)
class Rejection:
    """A frame a receiver dropped: its id, who it claims to come from, why, and its full FV as rebuilt."""

    frame_id: int
    sender: str
    reason: str
    freshness: int


class SecOC:
    """Authentication of one participant: ``keys`` are the senders' keys it holds (its own to sign,
    the others' to verify), ``trailers`` where each secured id's trailer starts, ``senders`` each
    secured id's sender (its DBC node)."""

    def __init__(self, keys: Mapping[str, bytes], trailers: Mapping[int, int], senders: Mapping[int, str]) -> None:
        from cryptography.hazmat.primitives.ciphers import algorithms
        from cryptography.hazmat.primitives.cmac import CMAC

        # one CMAC per key, copied per frame: the key schedule is computed once
        self._cmacs = {sender: CMAC(algorithms.AES(key)) for sender, key in keys.items()}
        self.trailers = dict(trailers)
        self.senders = {frame_id: senders[frame_id] for frame_id in self.trailers}
        self._last: dict[int, int] = {}  # id -> full FV of the last frame accepted

    @classmethod
    def from_codec(cls, codec: DatabaseView, keys: Mapping[str, bytes]) -> SecOC | None:
        """The participant's SecOC for a codec from a secured DBC (None: the DBC is not secured)."""
        if not codec.secoc_trailers:
            return None
        return cls(keys, codec.secoc_trailers, {spec.frame_id: spec.sender for spec in codec.specs.values()})

    def _mac(self, sender: str, frame_id: int, pdu: bytes | bytearray, freshness: int) -> bytes:
        cmac = self._cmacs[sender].copy()
        cmac.update(frame_id.to_bytes(2, "big") + bytes(pdu) + (freshness % _FV_MODULUS).to_bytes(4, "big"))
        return cmac.finalize()[:MAC_BYTES]

    def sign(self, frame: can.Message, tick: int) -> None:
        """Write the trailer of a frame of tick ``tick`` (in place); frames of unsecured ids are left as they are."""
        at = self.trailers.get(frame.arbitration_id)
        if at is None or frame.is_extended_id:
            return
        data = frame.data
        mac = self._mac(self.senders[frame.arbitration_id], frame.arbitration_id, data[:at], tick)
        data[at] = tick & 0xFF
        data[at + FV_BYTES : at + TRAILER] = mac

    def verify(self, frame: can.Message, current: int) -> Rejection | None:
        """Check a received frame against the receiver's current tick (its last SYNC): None if it
        is accepted (or not secured), else why it is dropped. An accepted frame's FV becomes the
        id's latest."""
        at = self.trailers.get(frame.arbitration_id)
        if at is None or frame.is_extended_id:
            return None
        frame_id, data = frame.arbitration_id, frame.data
        sender = self.senders[frame_id]
        if len(data) < at + TRAILER or sender not in self._cmacs:
            return Rejection(frame_id, sender, BAD_MAC, -1)
        current %= _FV_MODULUS
        freshness = current - ((current - data[at]) % 256)  # the latest tick <= current with those 8 bits
        expected = self._mac(sender, frame_id, data[:at], freshness)
        if freshness < 0 or not hmac.compare_digest(expected, bytes(data[at + FV_BYTES : at + TRAILER])):
            return Rejection(frame_id, sender, BAD_MAC, freshness)
        if freshness <= self._last.get(frame_id, -1):
            return Rejection(frame_id, sender, REPLAYED, freshness)
        if current - freshness > WINDOW:
            return Rejection(frame_id, sender, STALE, freshness)
        self.accept(frame_id, freshness)
        return None

    def accept(self, frame_id: int, freshness: int) -> None:
        """A frame of ``frame_id`` with ``freshness`` accepted: the id's latest (``verify``'s last
        step; a batch, ``cosim.campaign.batch_bus``, says so of the genuine frames it does not build)."""
        self._last[frame_id] = freshness
