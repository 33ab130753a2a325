"""Authenticated control frames: only the run's participants can stop, advance or close a tick.

NMT, SYNC and heartbeats steer a run: an NMT stop ends a node, a SYNC starts a tick, a heartbeat
closes one. Each carries a MAC in its last bytes (``mac`` in the DBC, ``cosim.bus.dbc``), in every
bus mode, with or without SecOC on the data frames::

    NMT        | command | node | MAC (48 bits)                          |
    SYNC       | tick (32 bits) | frames | MAC (24 bits)                 |
    HEARTBEAT  | state | tick mod 2¹⁶ | frames | lost mod 2⁸ | MAC (24)  |

- the MAC is AES-128-CMAC over ``id (2 bytes, big-endian) | the bytes before the MAC | the full
  tick (4 bytes, big-endian)``, truncated to the MAC's length; a SYNC carries its tick, a heartbeat
  the tick it closes mod 2¹⁶ (a receiver takes the tick nearest its own with those bits), an NMT
  none (0): its freshness is the run (a frame of another run fails under this run's keys);
- each sender has its own key, derived (HKDF-SHA256) from the run's secret and its name
  (``cosim.bus.keys``, purpose ``control``): the runner's signs NMT and SYNC, each
  node's its heartbeats. A node holds its own key and those of the senders it hears (the runner,
  an upstream node); the runner holds all of them.

A control frame whose MAC does not verify is dropped by every receiver and reported as a
rejection (``bad_mac``), as SecOC reports a data frame's. A replayed SYNC or heartbeat carries a
genuine MAC for a tick that is over: the protocol already ignores those (a SYNC must take the run
forward, a node closes a tick once). With 24 bits, a forger needs 2²³ tries on average to pass one
frame, each of which the runner counts; the one that passes is a second copy of a genuine frame,
which marks its tick contested.

Signing happens where the frame is sent, after the simulated wire has timed it with the MAC's bytes
at 0: a run's timing does not depend on its (random) key.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from functools import lru_cache

import can

from cosim.bus.codec import Codec, nearest_tick
from cosim.bus.dbc import ControlFields
from cosim.bus.keys import derive_key
from cosim.bus.secoc import BAD_MAC, Rejection

PURPOSE = "control"
"""The key derivation's purpose for control frames (data frames' SecOC keys are ``secoc``'s)."""


def control_keys(secret: bytes, senders: list[str]) -> dict[str, str]:
    """The senders' control keys (hex), for a node's spec or the run registry."""
    return {sender: derive_key(secret, sender, PURPOSE).hex() for sender in senders}


class ShortCmac:
    """AES-CMAC (RFC 4493) under one key, for messages shorter than a block (16 bytes), as a control
    frame's MAC input always is (at most 13 bytes): the padded message XOR the subkey K2, one AES
    block encrypted. The same bytes as ``cryptography``'s CMAC (tested), at a fifth of its cost: a
    CMAC object copied and finalized per frame costs more than the one block it encrypts."""

    def __init__(self, key: bytes) -> None:
        from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

        # ECB on one whole block at a time keeps no state between calls: the encryptor is reused
        self._encrypt = Cipher(algorithms.AES(key), modes.ECB()).encryptor().update  # noqa: S305
        self._k2 = _double(_double(int.from_bytes(self._encrypt(bytes(16)), "big")))
        self._recent: dict[bytes, bytes] = {}  # message -> MAC, of the last few (``_RECENT``)

    def __call__(self, message: bytes) -> bytes:
        found = self._recent.get(message)
        if found is not None:
            return found
        if len(message) >= 16:
            raise ValueError(f"ShortCmac takes messages shorter than 16 bytes, not {len(message)}")
        padded = int.from_bytes(message + b"\x80" + bytes(15 - len(message)), "big") ^ self._k2
        if len(self._recent) >= _RECENT:
            self._recent.clear()
        found = self._recent[message] = self._encrypt(padded.to_bytes(16, "big"))
        return found


#: MACs a ``ShortCmac`` remembers: a control frame is signed by its sender and verified by each
#: receiver, which in one process (a batch, an in-process run) share the key's ``ShortCmac``.
_RECENT = 256


@lru_cache(maxsize=1024)
def shared_cmac(key: bytes) -> ShortCmac:
    """The ``ShortCmac`` of ``key``, one for every participant of this process that holds the key."""
    return ShortCmac(key)


def _double(block: int) -> int:
    """Multiplication by x in GF(2^128) (RFC 4493's subkey step): shift left, reduce by 0x87."""
    shifted = (block << 1) & ((1 << 128) - 1)
    return shifted ^ 0x87 if block >> 127 else shifted


class ControlAuth:
    """Signs and verifies one participant's control frames: ``keys`` are the senders' control keys
    it holds (its own to sign, the others' to verify); ``codec`` says where each id's MAC is."""

    def __init__(self, codec: Codec, keys: Mapping[str, bytes]) -> None:
        self._cmacs = {sender: shared_cmac(key) for sender, key in keys.items()}
        self._macs = {
            frame_id: (spec, fields)
            for frame_id, (spec, fields) in codec.control_macs.items()
            if 2 + fields.mac[0] + 4 < 16  # a control frame of another layout is no control frame of ours
        }

    @classmethod
    def from_hex(cls, codec: Codec, keys: Mapping[str, str]) -> ControlAuth:
        return cls(codec, {sender: bytes.fromhex(key) for sender, key in keys.items()})

    @classmethod
    def from_secret(cls, codec: Codec, secret: bytes, senders: list[str]) -> ControlAuth:
        return cls(codec, {sender: derive_key(secret, sender, PURPOSE) for sender in senders})

    def _tick(self, fields: ControlFields, data: bytes | bytearray, near: int) -> int:
        if fields.tick is None:  # NMT
            return 0
        at, size = fields.tick
        counter = int.from_bytes(data[at : at + size], "little")
        return counter if size >= 4 else nearest_tick(counter, near, 8 * size)

    def _mac(self, sender: str, frame_id: int, data: bytes | bytearray, fields: ControlFields, near: int) -> bytes:
        at, size = fields.mac
        tick = self._tick(fields, data, near) % 2**32
        return self._cmacs[sender](frame_id.to_bytes(2, "big") + bytes(data[:at]) + tick.to_bytes(4, "big"))[:size]

    def key_of(self, frame: can.Message) -> ShortCmac | None:
        """The key this participant signs or verifies ``frame`` under (None: no control frame, or
        its sender's key is not held)."""
        found = None if frame.is_extended_id else self._macs.get(frame.arbitration_id)
        return None if found is None else self._cmacs.get(found[0].sender)

    def sign(self, frame: can.Message, near: int) -> None:
        """Write the MAC of a control frame sent at tick ``near`` (in place); other frames are left
        as they are, and so are frames of senders whose key this participant does not hold."""
        found = None if frame.is_extended_id else self._macs.get(frame.arbitration_id)
        if found is None or found[0].sender not in self._cmacs:
            return
        spec, fields = found
        at, size = fields.mac
        frame.data[at : at + size] = self._mac(spec.sender, frame.arbitration_id, frame.data, fields, near)

    def verify(self, frame: can.Message, near: int) -> Rejection | None:
        """None if the frame is no control frame, or its MAC verifies at the receiver's tick ``near``;
        else the rejection (``bad_mac``, with the tick the MAC was checked for)."""
        found = None if frame.is_extended_id else self._macs.get(frame.arbitration_id)
        if found is None:
            return None
        spec, fields = found
        at, size = fields.mac
        data = frame.data
        if len(data) != at + size or spec.sender not in self._cmacs:
            return Rejection(frame.arbitration_id, spec.sender, BAD_MAC, -1)
        expected = self._mac(spec.sender, frame.arbitration_id, data, fields, near)
        if not hmac.compare_digest(expected, bytes(data[at:])):
            return Rejection(frame.arbitration_id, spec.sender, BAD_MAC, self._tick(fields, data, near))
        return None
