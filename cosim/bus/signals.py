"""A bus signal: a named scalar with its unit, its range on the bus and its classic-CAN resolution.

Plant modules describe their sensors, actuators and states as ``Channel`` values (``mjcf/``), and
the codec lays them out in frames; this module is the one both import, and imports nothing itself.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Channel:
    """A named scalar signal of a plant: a sensor reading, an actuator input or a state component.

    ``minimum``/``maximum`` bound the values the signal may take on the bus and ``resolution`` is
    its quantum in a classic-CAN frame (scaled integer); CAN FD frames carry it as float64.
    A sensor channel may read another MuJoCo sensor (``source``) minus a ``zero``: a transmitter
    calibrated to read the deviation from an operating point, as the papers' linearized outputs do.
    ``component`` picks one component of a vector sensor (a velocimeter's surge velocity is 0).
    """

    name: str
    unit: str
    description: str
    minimum: float
    maximum: float
    resolution: float
    source: str = ""
    zero: float = 0.0
    component: int | None = None

    def __post_init__(self) -> None:
        if not self.minimum < self.maximum:
            raise ValueError(f"channel {self.name}: minimum must be below maximum")
        if not self.resolution > 0:
            raise ValueError(f"channel {self.name}: resolution must be positive")
