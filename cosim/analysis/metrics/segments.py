"""Fault segments: the stretch of a run in which a fault's effects are looked for.

The onsets of all faults cut the run into segments: a fault's segment runs from its onset to the
next onset of any fault, or to the end of the log; faults starting at the same tick share one
(docs/metrics.md).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Segment:
    """From one fault onset (one or more faults starting at tick ``start``) to the next."""

    start: int
    labels: list[str]

    def since(self, k: int | None, dt: float) -> float | None:
        """Seconds from the segment's start to tick ``k`` (None for no tick)."""
        return None if k is None else round((k - self.start) * dt, 9)
