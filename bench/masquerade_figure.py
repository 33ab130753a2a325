"""The masquerade figure of docs/datasets.md: a masquerade of SENSOR_x2 on masses-pid-can is invisible
to the key-less intrusion detector's period check and visible in the physics.

    .venv/bin/python bench/masquerade_figure.py [--out docs/figures/datasets/masquerade.png] [--seed 0]

It runs masses-pid-can (24 s, in process) with the attack of dataset-attacks ("masquerade": the
genuine SENSOR_x2 suspended from 8 to 16 s, the intruder sending x2 + 0.2 m in its slot at its
period with the next counter) and draws from the log: the inter-arrival times of the frames on
SENSOR_x2's id and the detector's alarms; the true x2, the x2 the controller received, and its set
point; the Kalman filter's residuals y − C x̂. Prints the numbers the figure shows. Needs the
``plot`` extra.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cosim import scenario
from cosim.log.reader import LogReader
from cosim.run import run

ATTACK = '{name = "masquerade", kind = "masquerade", message = "SENSOR_x2", offset = 0.2, start = 8.0, end = 16.0}'
C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [1.0, -1.0, 0.0, 0.0]])  # x1, x2, x1 - x2
SENSORS = ("x1", "x2", "x1_minus_x2")


def read(log: Path) -> dict[str, np.ndarray]:
    arrivals, alarms, truth, readings, estimates = [], [], {}, {}, {}
    with LogReader(log) as reader:
        for topic, t, m in reader.messages(
            [
                "/can/frames",
                "/cosim/ids",
                "/truth/state",
                "/can/SENSOR_x1",
                "/can/SENSOR_x2",
                "/can/SENSOR_x1_minus_x2",
                "/can/EST_kalman_0",
                "/can/EST_kalman_1",
            ]
        ):
            k = t // 10_000_000
            if topic == "/can/frames" and m["message"] == "SENSOR_x2":
                arrivals.append(t / 1e9)
            elif topic == "/cosim/ids":
                alarms.append((m["t"], m["alarm"], m["period"], m["sequence"], m["range"], m["unknown"]))
            elif topic == "/truth/state":
                truth[m["tick"]] = m["x2"]
            elif topic.startswith("/can/SENSOR_"):
                readings.setdefault(m["tick"] if m["tick"] == k else -1, {}).update(m)
            elif topic.startswith("/can/EST_kalman"):
                estimates.setdefault(m["tick"], {}).update(m)
    ticks = sorted(k for k in truth if k in readings and k in estimates)
    y = np.array([[readings[k][s] for s in SENSORS] for k in ticks])
    xhat = np.array([[estimates[k][f"xhat_{s}"] for s in ("x1", "x2", "v1", "v2")] for k in ticks])
    return {
        "arrivals": np.array(arrivals),
        "alarms": np.array(alarms),
        "t": np.array(ticks) * 0.01,
        "x2": np.array([truth[k] for k in ticks]),
        "y": y,
        "residual": y - xhat @ C.T,
    }


def attacked_run(seed: int) -> dict[str, np.ndarray]:
    """masses-pid-can for 24 s with the masquerade, in process, read back from its log."""
    settings = [scenario.parse_setting("duration=24.0"), scenario.parse_setting(f"faults=[{ATTACK}]")]
    loaded = scenario.apply(scenario.load("masses-pid-can"), settings)
    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "masquerade.mcap"
        result = run(loaded, log, seed, interface="virtual")
        assert result.status == "completed", result.error
        return read(log)


def inter_arrivals(data: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The arrival time of each frame on SENSOR_x2's id after the first, and its gap to the one before (ms)."""
    return data["arrivals"][1:], np.diff(data["arrivals"]) * 1e3


def set_point(t: np.ndarray) -> np.ndarray:
    """masses-pid-can's set point for x2."""
    return 0.5 + 0.3 * np.sin(2 * np.pi * 0.1 * t)


def print_numbers(data: dict[str, np.ndarray]) -> None:
    """The numbers the figure shows: the gaps before and during the attack, the detector's alarms,
    how far x2 strays from its set point, the Kalman filter's residuals."""
    t, gaps = inter_arrivals(data)
    window = (t >= 8.0) & (t < 16.0)
    alarms = data["alarms"]
    reference = set_point(data["t"])
    during, before = (data["t"] >= 12) & (data["t"] < 16), (data["t"] >= 4) & (data["t"] < 8)
    print(
        f"SENSOR_x2 inter-arrival, ms: before {gaps[~window].min():.3f}-{gaps[~window].max():.3f}, "
        f"during {gaps[window].min():.3f}-{gaps[window].max():.3f}"
    )
    print(
        f"intrusion detector: {int(alarms[:, 1].sum())} alarm ticks (period {int(alarms[:, 2].sum())}, sequence "
        f"{int(alarms[:, 3].sum())}, range {int(alarms[:, 4].sum())}, unknown {int(alarms[:, 5].sum())})"
    )
    print(
        f"x2 - set point, m: RMS before {np.sqrt(np.mean((data['x2'] - reference)[before] ** 2)):.3f}, "
        f"12-16 s {np.sqrt(np.mean((data['x2'] - reference)[during] ** 2)):.3f}"
    )
    residual = np.abs(data["residual"]).max(axis=1)
    print(
        f"Kalman residual max |y - C x^|, m: 4-8 s {residual[before].max():.4f}, 12-16 s {residual[during].min():.4f}"
        f"-{residual[during].max():.4f}"
    )


def draw(data: dict[str, np.ndarray], out: Path) -> None:
    """The three panels (inter-arrival times, x2, the Kalman residuals), the attack shaded, into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, gaps = inter_arrivals(data)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, constrained_layout=True)
    for ax in axes:
        ax.axvspan(8, 16, color="tab:red", alpha=0.08, lw=0)
    ax = axes[0]
    ax.plot(t, gaps, ".", ms=2, color="tab:blue")
    ax.set_ylabel("SENSOR_x2 inter-arrival [ms]")
    ax.set_ylim(9.0, 11.0)
    ax.set_title(
        f"Masquerade of SENSOR_x2 (8–16 s, shaded): the frames keep their period; intrusion detector alarms: "
        f"{int(data['alarms'][:, 1].sum())}",
        fontsize=10,
    )
    ax = axes[1]
    ax.plot(data["t"], set_point(data["t"]), "--", color="gray", lw=1, label="set point")
    ax.plot(data["t"], data["y"][:, 1], color="tab:orange", lw=1, label="x2 as received (the controller's)")
    ax.plot(data["t"], data["x2"], color="tab:blue", lw=1.2, label="x2, true")
    ax.set_ylabel("x2 [m]")
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    for i, name in enumerate(("x1", "x2", "x1 − x2")):
        ax.plot(data["t"], data["residual"][:, i], lw=1, label=f"{name}")
    ax.set_ylabel("Kalman residual y − C x̂ [m]")
    ax.set_xlabel("t [s]")
    ax.legend(loc="upper right", fontsize=8, title="sensor", title_fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/figures/datasets/masquerade.png")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    data = attacked_run(args.seed)
    print_numbers(data)
    draw(data, Path(args.out))
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
