"""What the runner hears, accounted for: forged control frames change no count."""

from __future__ import annotations

import can

from cosim import scenario
from cosim.bus.codec import OPERATIONAL, RUNNER, Decoded
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
