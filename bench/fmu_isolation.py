"""Cost per tick of running an FMU plant in the runner's process or in a process of its own.

A tick of an FMU plant is one step of the FMU (the inputs held over the sample time) and the read of
its states and sensors. Variants, each on the same FMU, each ``--ticks`` ticks, best of ``--repeat``
(interleaved), in µs per tick of wall time and of CPU time (both processes for ``process``):

- ``runner``: ``FmuPlant`` in this process (``[plant.fmu] isolation = "none"``): the floor;
- ``runner+fd``: the same with file descriptors 1 and 2 sent to a pipe around each tick and the
  pipe read after it: what capturing the FMU's prints costs in the runner's process;
- ``runner+thread``: the tick run by a worker thread the main thread waits for in slices of 50 ms
  (so that Ctrl-C is seen while the FMU hangs): what a watchdog in the runner's process costs;
- ``process``: ``IsolatedFmuPlant``: the FMU in its host process (``cosim.plant.fmu_host``), one
  request and one answer per tick (raw float64s), its prints read from its pipes.

Then a whole run of ``tests/data/fmus/vanderpol-bias.toml`` (a Kalman filter on the bus, in process)
with ``isolation = "none"`` and ``"process"``: the tick loop's time per tick
(``RunResult.loop_time / ticks``), best of ``--repeat``; and the host process's start (the first
plant of an FMU in a process that has no host for it yet).

The machine's load average is printed with the figures: a process switch per tick costs its
scheduling delay, which grows with the load of the machine (other processes on its cores).

Usage: python bench/fmu_isolation.py [--json] [--ticks N] [--repeat R]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser  # noqa: E402
from cosim import scenario  # noqa: E402
from cosim.plant import fmu_model  # noqa: E402
from cosim.plant.fmu import FmuPlant  # noqa: E402
from cosim.plant.fmu_process import IsolatedFmuPlant  # noqa: E402
from cosim.run import Run  # noqa: E402
from cosim.scenario.spec import FmuSpec  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FMUS = ROOT / "tests" / "data" / "fmus"
CASES = [
    ("VanDerPol FMI 3 CS", "fmi3/VanDerPol.fmu", "co-simulation"),
    ("VanDerPol FMI 3 ME", "fmi3/VanDerPol.fmu", "model-exchange"),
    ("StateSpace FMI 3 CS (3 inputs)", "fmi3/StateSpace.fmu", "co-simulation"),
]


def model(path: str, interface: str) -> fmu_model.FmuModel:
    return fmu_model.read(FMUS / path, FmuSpec.model_validate({"interface": interface}))


def host_cpu(plant: IsolatedFmuPlant) -> float:
    """CPU seconds the plant's host process has used (Linux /proc)."""
    assert plant._host is not None
    fields = Path(f"/proc/{plant._host.process.pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class FdCapture:
    """File descriptors 1 and 2 sent to a pipe around a call, the pipe read after it."""

    def __init__(self) -> None:
        self.read_end, self.write_end = os.pipe()
        os.set_blocking(self.read_end, False)

    def __call__(self, tick) -> None:
        saved = os.dup(1), os.dup(2)
        os.dup2(self.write_end, 1)
        os.dup2(self.write_end, 2)
        try:
            tick()
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
        try:
            os.read(self.read_end, 1 << 16)
        except BlockingIOError:
            pass


class Watchdog:
    """A worker thread runs each tick; the caller waits for it in slices of 50 ms."""

    def __init__(self) -> None:
        self.go, self.done = threading.Event(), threading.Event()
        self.work = None
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            self.go.wait()
            self.go.clear()
            self.work()
            self.done.set()

    def __call__(self, tick) -> None:
        self.work = tick
        self.go.set()
        while not self.done.wait(0.05):
            pass
        self.done.clear()


def per_tick(path: str, interface: str, ticks: int, repeat: int) -> dict[str, dict[str, float]]:
    m = model(path, interface)
    u = np.array([0.1] * len(m.actuators))
    plants = {
        "runner": FmuPlant(m, 0.01, 1e6),
        "runner+fd": FmuPlant(m, 0.01, 1e6),
        "runner+thread": FmuPlant(m, 0.01, 1e6),
        "process": IsolatedFmuPlant(m, 0.01, 1e6),
    }
    wrappers = {"runner+fd": FdCapture(), "runner+thread": Watchdog()}
    best = {name: {"wall_us": float("inf"), "cpu_us": float("inf")} for name in plants}
    for _ in range(repeat):
        for name, plant in plants.items():
            plant.reset()

            def tick(plant=plant) -> None:
                plant.step(u)
                plant.state()
                plant.sensors()

            run = wrappers.get(name)
            child = host_cpu(plant) if isinstance(plant, IsolatedFmuPlant) else 0.0
            wall, cpu = time.perf_counter(), time.process_time()
            for _ in range(ticks):
                if run is None:
                    tick()
                else:
                    run(tick)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            if isinstance(plant, IsolatedFmuPlant):
                cpu += host_cpu(plant) - child
            best[name]["wall_us"] = min(best[name]["wall_us"], wall / ticks * 1e6)
            best[name]["cpu_us"] = min(best[name]["cpu_us"], cpu / ticks * 1e6)
    for plant in plants.values():
        plant.close()
    return best


def whole_run(repeat: int) -> dict[str, float]:
    """µs per tick of the vanderpol-bias run's tick loop, by isolation."""
    loaded = scenario.load(FMUS / "vanderpol-bias.toml")
    found: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            for isolation in ("none", "process"):
                changed = scenario.apply(loaded, [("plant.fmu.isolation", isolation)])
                result = Run(changed, Path(tmp) / "run.mcap", interface="virtual").execute()
                found[isolation] = min(found.get(isolation, float("inf")), result.loop_time / result.ticks * 1e6)
    return found


def host_start(repeat: int) -> float:
    """Seconds to the first answer of a new host process (its start, FMPy's import, the FMU's instance)."""
    from cosim.plant import fmu_process

    m = model("fmi3/VanDerPol.fmu", "co-simulation")
    times = []
    for _ in range(repeat):
        fmu_process._HOSTS.close_all()
        start = time.perf_counter()
        IsolatedFmuPlant(m, 0.01, 1.0).close()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = bench_parser(__doc__, repeat=5)
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per measurement (2000)")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    figures = {
        "per_tick": {label: per_tick(path, interface, args.ticks, args.repeat) for label, path, interface in CASES},
        "run_loop_us_per_tick": whole_run(args.repeat),
        "host_start_s": round(host_start(args.repeat), 3),
        "load_average": round(max(load_before, os.getloadavg()[0]), 2),
        "cores": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(figures, indent=2))
        return
    print(f"load average {figures['load_average']} on {figures['cores']} cores; µs per tick, wall / CPU")
    for label, variants in figures["per_tick"].items():
        row = "  ".join(f"{name} {v['wall_us']:7.1f} / {v['cpu_us']:6.1f}" for name, v in variants.items())
        print(f"{label:32s} {row}")
    loop = figures["run_loop_us_per_tick"]
    print(f"vanderpol-bias tick loop: runner {loop['none']:.1f} µs, process {loop['process']:.1f} µs per tick")
    print(f"a new host process answers in {figures['host_start_s']:.2f} s")


if __name__ == "__main__":
    main()
