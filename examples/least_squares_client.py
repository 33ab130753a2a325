"""A user-written estimator joining a running co-simulation with ``cosim.bus.client``.

It reads the three redundant position sensors of the coupled masses, y = C_p [x1, x2] + noise with
C_p = [[1, 0], [0, 1], [1, -1]], and publishes the static least-squares fix
[x1, x2] = (C_pᵀ C_p)⁻¹ C_pᵀ y = [(2 y1 + y2 + y3) / 3, (y1 + 2 y2 − y3) / 3]
in its own DBC message (CLIENT_lsq), tick by tick, in lockstep with the runner. If a reading is
missing it uses the two that remain.

    terminal 1:  cosim run examples/least-squares-client.toml
    terminal 2:  python examples/least_squares_client.py
"""

import numpy as np

from cosim.bus.client import Client

C_P = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, -1.0]])  # rows: x1, x2, x1 - x2
SENSORS = ("x1", "x2", "x1_minus_x2")


def least_squares(readings: dict[str, float]) -> np.ndarray:
    rows = [i for i, name in enumerate(SENSORS) if name in readings]
    y = np.array([readings[SENSORS[i]] for i in rows])
    fix, *_ = np.linalg.lstsq(C_P[rows], y, rcond=None)
    return fix


with Client.attach("lsq") as client:
    for tick in client.ticks():
        x1, x2 = least_squares(tick.sensors)
        client.publish(tick, {"x1": x1, "x2": x2})
