"""Scenario snippets shared by the tests: one place for the TOML the tests run."""

from __future__ import annotations

#: A short masses scenario (three sensors, no estimator), the base that tests add tables to.
MASSES = """
name = "t"
duration = 1.0
sample_time = 0.01
[plant]
model = "masses"
sensors = ["x1", "x2", "x1_minus_x2"]
"""

_PID = """
name = "{name}"
duration = {duration}
sample_time = 0.01
seed = {seed}
[plant]
model = "masses"
sensors = ["x1", "x2", "x1_minus_x2"]
[controller]
kind = "pid"
diagnosis = "kf"
[controller.params]
outputs = ["x2"]
inputs = ["force"]
setpoint = [0.5]
kp = [8.0]
ki = [2.0]
kd = [4.0]
lower = [-20.0]
upper = [20.0]
[[estimators]]
name = "kf"
kind = "kalman"
[[faults]]
kind = "bias"
sensors = ["x1"]
value = 0.3
start = {fault_start}
"""


def masses_pid(name: str = "masses-pid", duration: float = 12.0, seed: int = 3, fault_start: float = 6.0) -> str:
    """The masses in closed loop: a PID node holds x2 at 0.5 m, a Kalman filter reads its commands,
    and a 0.3 m bias hits x1 at ``fault_start``."""
    return _PID.format(name=name, duration=duration, seed=seed, fault_start=fault_start)


def plant_only(plant: str, sample_time: float, duration: float = 1.0) -> str:
    """A scenario of a registered plant alone, on the in-process CAN FD bus."""
    return (
        f'name = "conformance"\nduration = {duration}\nsample_time = {sample_time}\n[plant]\nmodel = "{plant}"\n'
        '[bus]\ninterface = "virtual"\nfd = true\n'
    )


def short_scenario(text: str, duration: float) -> str:
    """The scenario text with another duration."""
    lines = [f"duration = {duration}" if line.startswith("duration") else line for line in text.splitlines()]
    return "\n".join(lines) + "\n"
