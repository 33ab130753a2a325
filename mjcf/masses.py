"""Two coupled mass-spring-dampers (TAC 2024, Sec. VII, Fig. 2, Table I).

The MJCF model ``masses.xml`` holds the physics. This module names its signals and parameters and
gives the paper's own continuous-time model (A0, B0), which the tests compare MuJoCo against.
"""

from __future__ import annotations

import numpy as np

from mjcf._plant import Channel, Parameter, PlantInfo

_TABLE_I = "Cristofaro & Zaccarian, IEEE TAC 2024, Table I"

PARAMETERS = {
    "m1": Parameter(1.5, "kg", _TABLE_I),
    "m2": Parameter(1.0, "kg", _TABLE_I),
    "k1": Parameter(1.2, "N/m", _TABLE_I),
    "k2": Parameter(1.0, "N/m", _TABLE_I),
    "d1": Parameter(5e-3, "N s/m", _TABLE_I),
    "d2": Parameter(9e-3, "N s/m", _TABLE_I),
    "tau": Parameter(1e-2, "s", _TABLE_I + " (sample time)"),
}


def _position(name: str, description: str) -> Channel:
    # 1 µm quantum over ±8 m: a 24-bit signed integer in a classic-CAN frame.
    return Channel(name, "m", description, -8.0, 8.0, 1e-6)


def _velocity(name: str, description: str) -> Channel:
    return Channel(name, "m/s", description, -8.0, 8.0, 1e-6)


INFO = PlantInfo(
    name="masses",
    description="Two coupled mass-spring-dampers, force on mass 2 (TAC 2024, Sec. VII)",
    model_file="masses.xml",
    states=(
        _position("x1", "displacement of mass 1"),
        _position("x2", "displacement of mass 2"),
        _velocity("v1", "velocity of mass 1 (the paper's x3)"),
        _velocity("v2", "velocity of mass 2 (the paper's x4)"),
    ),
    sensors=(
        _position("x1", "position of mass 1"),
        _position("x2", "position of mass 2"),
        _position("x1_minus_x2", "range from mass 1 to mass 2, x1 - x2"),
        _position("x2_minus_x1", "range from mass 2 to mass 1, x2 - x1"),
    ),
    actuators=(Channel("force", "N", "force on mass 2 (the paper's u)", -100.0, 100.0, 1e-4),),
    parameters=PARAMETERS,
)

#: Rows of the paper's output matrix for each sensor (Sec. VII-A and VII-B).
SENSOR_ROWS = {
    "x1": (1.0, 0.0, 0.0, 0.0),
    "x2": (0.0, 1.0, 0.0, 0.0),
    "x1_minus_x2": (1.0, -1.0, 0.0, 0.0),
    "x2_minus_x1": (-1.0, 1.0, 0.0, 0.0),
}


def continuous_model(
    m1: float = 1.5, m2: float = 1.0, k1: float = 1.2, k2: float = 1.0, d1: float = 5e-3, d2: float = 9e-3
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's continuous-time model x_dot = A0 x + B0 u (TAC 2024, Sec. VII).

    Returns A0 with shape (4, 4) and B0 with shape (4, 1), for x = [x1, x2, x1_dot, x2_dot].
    """
    a0 = np.array(
        [
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [-(k1 + k2) / m1, k2 / m1, -(d1 + d2) / m1, d2 / m1],
            [k2 / m2, -k2 / m2, d2 / m2, -d2 / m2],
        ]
    )
    b0 = np.array([[0.0], [0.0], [0.0], [1.0 / m2]])
    return a0, b0


def output_matrix(sensors: list[str] | tuple[str, ...]) -> np.ndarray:
    """The paper's output matrix C for a suite of sensors, shape (len(sensors), 4)."""
    return np.array([SENSOR_ROWS[name] for name in sensors])
