"""What the runner hears, accounted for: forged control frames change no count."""

from __future__ import annotations

import can
import pytest

from cosim import scenario
from cosim.bus.codec import OPERATIONAL, RUNNER, Decoded
from cosim.bus.control_frames import _RECENT, ControlAuth, ShortCmac, shared_cmac
from cosim.bus.secoc import Rejection
from cosim.run.traffic import Traffic


class Delivered:
    """Where the traffic puts a tick's frames (the log's recorder in a run)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, can.Message, Decoded | None]] = []

    def frame(self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None) -> None:
        self.frames.append((tick, frame, decoded))


def test_a_second_heartbeat_for_a_tick_is_foreign_and_counts_no_frame_as_lost():
    codec = scenario.load().scenario.codec()
    foreign: list[str] = []
    delivered = Delivered()
    traffic = Traffic(codec, delivered, (RUNNER,), on_foreign=lambda frame, why: foreign.append(why))  # type: ignore[arg-type]
    estimates = codec.data_messages("kalman")
    traffic.current = 3
    for spec in estimates:
        traffic.on_message_received(codec.encode(spec.name, 3, [0.0] * len(spec.channels)))
    traffic.on_message_received(codec.heartbeat("kalman", OPERATIONAL, 3, frames=len(estimates)))
    traffic.on_message_received(codec.heartbeat("kalman", OPERATIONAL, 3, frames=len(estimates)))  # forged
    traffic.flush(3, 0.03, 30_000_000)
    assert traffic.lost["kalman"] == 0 and traffic.closed["kalman"] == 3
    assert foreign == ["a second heartbeat of kalman closing tick 3"]
    assert len(delivered.frames) == len(estimates) + 2  # both heartbeats logged, the forged one undecoded
    assert sum(decoded is None for _, _, decoded in delivered.frames) == 1


def test_a_heartbeat_without_the_nodes_mac_is_rejected_and_closes_nothing():
    codec = scenario.load().scenario.codec()
    keys = ControlAuth.from_secret(codec, bytes(32), [RUNNER, "kalman"])
    rejected: list[Rejection] = []
    traffic = Traffic(codec, Delivered(), (RUNNER,), control=keys, on_rejected=lambda f, r: rejected.append(r))  # type: ignore[arg-type]
    traffic.current = 3
    forged = codec.heartbeat("kalman", OPERATIONAL, 3, frames=255)  # would count 255 frames as lost
    traffic.on_message_received(forged)
    genuine = codec.heartbeat("kalman", OPERATIONAL, 3, frames=0)
    keys.sign(genuine, 3)
    traffic.on_message_received(genuine)
    traffic.flush(3, 0.03, 30_000_000)
    assert [(r.frame_id, r.reason, r.freshness) for r in rejected] == [(forged.arbitration_id, "bad_mac", 3)]
    assert traffic.lost["kalman"] == 0 and traffic.closed["kalman"] == 3


def test_the_frames_a_node_found_missing_add_up_past_the_heartbeats_256():
    codec = scenario.load().scenario.codec()
    traffic = Traffic(codec, Delivered(), (RUNNER,))  # type: ignore[arg-type]
    for k, missing in enumerate([0, 100, 250, 300, 520, 601]):  # at most 255 a tick (what a SYNC announces)
        traffic.current = k
        traffic.on_message_received(codec.heartbeat("kalman", OPERATIONAL, k, lost=missing))
        traffic.flush(k, 0.01 * k, 10_000_000 * k)
    assert traffic.missed_by["kalman"] == 601


@pytest.mark.parametrize("length", range(16))
def test_the_control_frames_cmac_is_rfc_4493s(length):
    """Bit for bit the CMAC of ``cryptography`` (RFC 4493), for every message length a block holds,
    and RFC 4493's own example 1 (the empty message)."""
    from cryptography.hazmat.primitives.ciphers import algorithms
    from cryptography.hazmat.primitives.cmac import CMAC

    key = bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c")
    message = bytes(range(length))
    reference = CMAC(algorithms.AES(key))
    reference.update(message)
    expected = reference.finalize()
    assert ShortCmac(key)(message) == expected
    if length == 0:
        assert ShortCmac(key)(b"").hex() == "bb1d6929e95937287fa37d129b756746"
    # the participants of one process share a key's CMAC, which remembers what it computed last
    shared = shared_cmac(key)
    assert shared is shared_cmac(bytes.fromhex(key.hex()))
    assert [shared(message), shared(message), shared(b"\xff" * length)[:0], shared(message)] == [
        expected,
        expected,
        b"",
        expected,
    ]


def test_a_cmac_forgets_beyond_its_recent_messages():
    cmac, plain = ShortCmac(bytes(16)), ShortCmac(bytes(16))
    messages = [i.to_bytes(3, "big") for i in range(3 * _RECENT)]
    assert [cmac(m) for m in messages + messages[::-1]] == [plain(m) for m in messages + messages[::-1]]
    assert len(cmac._recent) <= _RECENT
