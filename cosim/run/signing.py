"""The runner signs the control frames it sends (SYNC; a replay's runner also the replayed nodes'
heartbeats), and never an intruder's: it holds every sender's key, and a forged frame it signed
would pass every receiver's check (``cosim.bus.control_frames``)."""

from __future__ import annotations

from collections.abc import Collection, Iterable

import can

from cosim.bus.codec import Decoded
from cosim.bus.control_frames import ControlAuth
from cosim.run.busfaults import Applied


def forged(applied: Applied | None, late: Iterable[int] = ()) -> set[int]:
    """A tick's frames that are an intruder's, by ``id()``: its bus faults' (``applied``), and on an
    arbitrated wire those of earlier ticks it delivers now (``Step.forged``)."""
    return set(applied.intruders if applied is not None else ()) | set(late)


def sign_control(
    control: ControlAuth | None, k: int, frames: list[tuple[can.Message, Decoded | None]], forged: Collection[int]
) -> None:
    """Sign the control frames among the runner's frames of tick k but those in ``forged`` (by
    ``id()``), which go as their intruder forged them."""
    if control is None:
        return
    for item in frames:
        if id(item) not in forged:
            control.sign(item[0], k)
