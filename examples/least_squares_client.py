"""A user-written estimator joining a running co-simulation with ``cosim.client``.

It reads the three redundant position sensors of the coupled masses, y = C_p [x1, x2] + noise with
C_p = [[1, 0], [0, 1], [1, -1]], and publishes the static least-squares fix
[x1, x2] = (C_pᵀ C_p)⁻¹ C_pᵀ y = [(2 y1 + y2 + y3) / 3, (y1 + 2 y2 − y3) / 3]
in its own DBC message (CLIENT_lsq), tick by tick, in lockstep with the runner. If a reading is
missing it uses the two that remain. It says what it joined, shows its fix once a simulated
second, and sums up at the end.

    terminal 1:  cosim run examples/least-squares-client.toml
    terminal 2:  python examples/least_squares_client.py
(with the virtualenv active; else .venv/bin/cosim and .venv/bin/python)
"""

import time

import numpy as np

from cosim.client import Client

C_P = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, -1.0]])  # rows: x1, x2, x1 - x2
SENSORS = ("x1", "x2", "x1_minus_x2")


def least_squares(readings: dict[str, float]) -> np.ndarray:
    rows = [i for i, name in enumerate(SENSORS) if name in readings]
    y = np.array([readings[SENSORS[i]] for i in rows])
    fix, *_ = np.linalg.lstsq(C_P[rows], y, rcond=None)
    return fix


print("lsq: looking for the running co-simulation (start one with 'cosim run examples/least-squares-client.toml')")
with Client.attach("lsq") as client:
    every = max(1, round(1.0 / client.assembler.sample_time))  # a line per simulated second
    print(
        f"lsq: joined the co-simulation's bus, sample time {client.assembler.sample_time:g} s; publishing "
        f"{', '.join(m.name for m in client.messages)} in lockstep"
    )
    started, ticks, partial = time.monotonic(), 0, 0
    for tick in client.ticks():
        x1, x2 = least_squares(tick.sensors)
        client.publish(tick, {"x1": x1, "x2": x2})
        ticks += 1
        partial += len(tick.sensors) < len(SENSORS)
        if tick.tick % every == 0:
            readings = "  ".join(f"{name}={value:+.4f}" for name, value in tick.sensors.items())
            print(f"lsq: t = {tick.t:6.2f} s  {readings}  ->  x1 = {x1:+.4f} m, x2 = {x2:+.4f} m")
    print(
        f"lsq: the run stopped; {ticks} ticks answered in {time.monotonic() - started:.1f} s"
        + (f", {partial} of them with a reading missing" if partial else "")
    )
