"""Scenario snippets shared by the tests: one place for the TOML the tests run."""

from __future__ import annotations


def masses(name: str = "t", duration: float = 1.0, *, forced: bool = False, bus: str = "", kalman: bool = False) -> str:
    """A short masses scenario (three sensors, 10 ms ticks), the base that tests add tables to:
    ``forced`` drives the force with a 0.5 Hz sine, ``bus`` is the body of its [bus] table,
    ``kalman`` adds a Kalman filter."""
    text = f"""
name = "{name}"
duration = {duration}
sample_time = 0.01
[plant]
model = "masses"
sensors = ["x1", "x2", "x1_minus_x2"]
"""
    if forced:
        text += """[[inputs]]
actuator = "force"
signal = { kind = "sine", amplitude = 1.0, frequency = 0.5 }
"""
    if bus:
        text += f"[bus]\n{bus.strip()}\n"
    if kalman:
        text += """[[estimators]]
name = "kalman"
kind = "kalman"
params = { measurement_std = 1e-3, process_std = 1e-4 }
"""
    return text


#: The masses scenario without inputs or estimators (``masses()``).
MASSES = masses()

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
