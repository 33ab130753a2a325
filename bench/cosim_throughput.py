"""Throughput of the co-simulation against the ceiling of its CAN transport, measured in one run.

- raw: frames/s between two processes on the chosen python-can interface (send → receive): one
  process sends classic 8-byte frames in windows of ``--window`` frames, the other receives them
  and acknowledges each window (flow control, so that no frame is lost to a full socket buffer);
  the figure is frames received per second. This is the ceiling of the transport for Python.
- pipeline: a full lockstep co-simulation of the default scenario (plant, faults, two estimator
  processes, MCAP logging) on the same interface: frames on the bus per second of its tick loop
  (the nodes' start-up, about a second, is reported apart), ticks per second, real-time factor,
  frames lost.

- node start-up: from a node process's spawn to its first (boot-up) heartbeat on the bus, the slowest
  node of the pipeline run (``node_startup_s``, per node in ``node_startup``).
- in-process: ``cosim run --interface virtual`` of the default scenario (the runner drives the
  estimator nodes in its own process, over cosim's in-process bus): real-time factor over the tick
  loop (``inprocess_realtime_factor``) and over the whole run, start-up included
  (``inprocess_run_realtime_factor``).
- arithmetic floor: the same scenario's physics (``Plant.step`` and the sensor readout) and its
  estimators' steps alone, tick after tick, with no bus, codec, faults or log: µs per tick
  (``arithmetic_tick_us``), the real-time factor no orchestration can beat
  (``arithmetic_realtime_factor``), and the in-process loop's tick over it (``inprocess_over_arithmetic``).

Each is repeated and the best kept: the machine's other load only ever slows a measurement down.
- ratio: pipeline frames/s over raw frames/s.
- floor: the same wire with three processes in lockstep doing no work (the runner's tick in one
  datagram, each node's answer in one): µs per tick, and the pipeline's ticks/s over the floor's.

Usage: python bench/cosim_throughput.py [--json] [--interface udp_multicast] [--frames N]
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can  # noqa: E402
import numpy as np  # noqa: E402

from bench.common import bench_parser, best_run, print_figures  # noqa: E402
from cosim import scenario  # noqa: E402
from cosim.bus.transport import BusConfig, allocate, open_bus, send_all  # noqa: E402
from cosim.run import Run, launcher, traffic  # noqa: E402
from cosim.run.loop import PlantSource  # noqa: E402
from cosim.run.plan import RunPlan  # noqa: E402

ACK_ID = 0x7FF


def _receiver(config: dict, frames: int, window: int, ready, result) -> None:
    bus = open_bus(BusConfig.from_dict(config))
    ready.set()
    received, start = 0, None
    while received < frames:
        frame = bus.recv(5.0)
        if frame is None:
            break
        if frame.arbitration_id == ACK_ID:
            continue  # our own acknowledgement, looped back
        if start is None:
            start = time.perf_counter()
        received += 1
        if received % window == 0 or received == frames:
            bus.send(can.Message(arbitration_id=ACK_ID, data=received.to_bytes(4, "little"), is_extended_id=False))
    elapsed = time.perf_counter() - start if start else float("nan")
    result.put((received, elapsed))
    bus.shutdown()


def raw_rate(config: BusConfig, frames: int, window: int) -> dict[str, float]:
    context = multiprocessing.get_context("spawn")
    ready, result = context.Event(), context.Queue()
    receiver = context.Process(target=_receiver, args=(config.to_dict(), frames, window, ready, result))
    receiver.start()
    ready.wait(30)
    bus = open_bus(config)
    time.sleep(0.2)
    message = can.Message(arbitration_id=0x100, data=bytes(range(8)), is_extended_id=False)
    sent = 0
    while sent < frames:
        for _ in range(min(window, frames - sent)):
            bus.send(message)
            sent += 1
        acknowledged = 0
        while acknowledged < sent:
            frame = bus.recv(5.0)
            if frame is None:
                raise RuntimeError(f"no acknowledgement after {sent} frames: frames were lost")
            if frame.arbitration_id == ACK_ID:
                acknowledged = int.from_bytes(frame.data, "little")
    received, elapsed = result.get(timeout=30)
    receiver.join(10)
    bus.shutdown()
    return {"raw_frames": received, "raw_lost_frames": frames - received, "raw_frames_per_s": received / elapsed}


def _floor_node(config: dict, node: int, ticks: int, ready, done) -> None:  # type: ignore[no-untyped-def]
    """A node doing nothing: each tick's batch from the runner in, one batch of three frames out."""
    bus = open_bus(BusConfig.from_dict(config))
    answer = [
        can.Message(arbitration_id=0x200 + 0x20 * node + i, data=bytes(8), is_extended_id=False) for i in range(3)
    ]
    ready.set()
    answered = 0
    while answered < ticks:
        frame = bus.recv(5.0)
        if frame is None:
            break
        if frame.arbitration_id == 0x080:  # a tick: answer it
            send_all(bus, answer)
            answered += 1
    done.put(answered)
    bus.shutdown()


def lockstep_floor(config: BusConfig, ticks: int) -> dict[str, float]:
    """The same wire's floor: a runner and two node processes in lockstep doing no work, the
    runner's SYNC and four frames in one datagram, each node's three frames in one."""
    context = multiprocessing.get_context("spawn")
    done = context.Queue()
    events = [context.Event() for _ in range(2)]
    nodes = [context.Process(target=_floor_node, args=(config.to_dict(), n, ticks, events[n], done)) for n in range(2)]
    for node in nodes:
        node.start()
    for event in events:
        event.wait(30)
    bus = open_bus(config)
    time.sleep(0.2)
    frames = [can.Message(arbitration_id=0x080 if i == 0 else 0x100 + i, data=bytes(8)) for i in range(5)]
    start = time.perf_counter()
    for _ in range(ticks):
        send_all(bus, frames)
        answers = 0
        while answers < 2:
            frame = bus.recv(5.0)
            if frame is None:
                raise RuntimeError("a node of the floor measurement stopped answering")
            answers += frame.arbitration_id in (0x202, 0x222)  # each node's last frame closes its tick
    elapsed = time.perf_counter() - start
    for node in nodes:
        node.join(10)
    bus.shutdown()
    return {"floor_ticks_per_s": ticks / elapsed, "floor_tick_us": 1e6 * elapsed / ticks}


class StartupClock:
    """Spawn time of each node process and arrival of its first heartbeat (the runner's view)."""

    def __init__(self) -> None:
        self.spawned: dict[str, float] = {}
        self.joined: dict[str, float] = {}
        self._originals = (launcher.ProcessNode.__init__, traffic.Traffic.on_message_received)

    def __enter__(self) -> StartupClock:
        spawn, receive = self._originals
        clock = self

        def spawning(node, spec, *args, **kwargs):  # type: ignore[no-untyped-def]
            clock.spawned[spec.name] = time.perf_counter()
            spawn(node, spec, *args, **kwargs)

        def receiving(traffic, msg):  # type: ignore[no-untyped-def]
            before = set(traffic.joined)
            receive(traffic, msg)
            for name in set(traffic.joined) - before:
                clock.joined.setdefault(name, time.perf_counter())

        launcher.ProcessNode.__init__ = spawning  # type: ignore[method-assign]
        traffic.Traffic.on_message_received = receiving  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        launcher.ProcessNode.__init__, traffic.Traffic.on_message_received = self._originals  # type: ignore[method-assign]

    def startup(self) -> dict[str, float]:
        return {name: self.joined[name] - start for name, start in self.spawned.items() if name in self.joined}


def pipeline(interface: str, repeat: int) -> dict[str, float]:
    loaded = scenario.load()
    best, startup = None, {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            with StartupClock() as clock:
                result = Run(loaded, Path(tmp) / "bench.mcap", interface=interface).execute()
            if best is None or result.loop_time < best.loop_time:
                best = result
            times = clock.startup()
            if not startup or max(times.values()) < max(startup.values()):
                startup = times
    return {
        "pipeline_frames": best.frames,
        "pipeline_loop_s": best.loop_time,
        "pipeline_startup_s": best.startup_time,
        "pipeline_frames_per_s": best.frames / best.loop_time,
        "pipeline_ticks_per_s": best.ticks / best.loop_time,
        "realtime_factor": best.sim_time / best.loop_time,
        "lost_frames": best.frames_lost,
        "node_startup_s": max(startup.values()),
        "node_startup": startup,
    }


def in_process(repeat: int) -> dict[str, float]:
    best = best_run(scenario.load(), repeat, lambda r: r.loop_time)
    return {
        "inprocess_frames": best.frames,
        "inprocess_loop_s": best.loop_time,
        "inprocess_realtime_factor": best.sim_time / best.loop_time,
        "inprocess_run_realtime_factor": best.sim_time / best.wall_time,
        "inprocess_lost_frames": best.frames_lost,
    }


def arithmetic_floor(repeat: int) -> dict[str, float]:
    """The default scenario's physics and estimator steps alone, per tick (best of ``repeat``)."""
    loaded = scenario.load()
    best = float("inf")
    for _ in range(repeat):
        plan = RunPlan.build(loaded)
        source = PlantSource(plan)
        plant, s = source.plant, plan.scenario
        readings, inputs = [], []
        start = time.perf_counter()
        for k in range(s.ticks):
            readings.append(plant.sensors())
            u = np.array([w(s.time(k)) for w in source.inputs])
            inputs.append(u)
            plant.step(u)
        elapsed = time.perf_counter() - start
        for estimator in plan.estimators.values():
            start = time.perf_counter()
            for y, u in zip(readings, inputs):
                estimator.step(y, u)
            elapsed += time.perf_counter() - start
        best = min(best, elapsed / s.ticks)
    return {"arithmetic_tick_us": best * 1e6, "arithmetic_realtime_factor": s.sample_time / best}


def print_table(figures: dict[str, Any], args: argparse.Namespace) -> None:
    """The table: the raw bus, the pipeline against it and the same-wire floor, the in-process run
    against the arithmetic floor."""
    rows = [
        (f"raw {args.interface}, two processes, send -> receive", f"{figures['raw_frames_per_s']:,.0f} frames/s"),
        ("  frames lost", f"{figures['raw_lost_frames']}"),
        (
            "pipeline: lockstep co-simulation, 2 estimator processes, logging",
            f"{figures['pipeline_frames_per_s']:,.0f} frames/s",
        ),
        ("  ticks per second", f"{figures['pipeline_ticks_per_s']:,.0f} ticks/s"),
        ("  start-up of the nodes (not in the rates)", f"{figures['pipeline_startup_s']:.2f} s"),
        ("  real-time factor", f"{figures['realtime_factor']:.1f} x"),
        ("  frames lost", f"{figures['lost_frames']}"),
        ("  node start-up, spawn to first heartbeat (slowest node)", f"{figures['node_startup_s']:.2f} s"),
        ("ratio pipeline / raw (target >= 0.5)", f"{figures['ratio']:.2f}"),
        ("same-wire floor: 3 processes in lockstep doing nothing", f"{figures['floor_tick_us']:.0f} us/tick"),
        ("ratio pipeline / floor (ticks per second)", f"{figures['floor_ratio']:.2f}"),
        ("in-process (--interface virtual): real-time factor", f"{figures['inprocess_realtime_factor']:.1f} x"),
        ("  over the whole run, start-up included", f"{figures['inprocess_run_realtime_factor']:.1f} x"),
        ("arithmetic floor: physics + estimator steps alone", f"{figures['arithmetic_tick_us']:.0f} us/tick"),
        ("  its real-time factor (no orchestration can beat it)", f"{figures['arithmetic_realtime_factor']:.1f} x"),
        ("  in-process tick over the floor", f"{figures['inprocess_over_arithmetic']:.2f}"),
    ]
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"{label:<{width}}  {value:>18}")


def main() -> None:
    parser = bench_parser(__doc__, repeat=3)
    parser.add_argument("--interface", default="udp_multicast", choices=("udp_multicast", "socketcan"))
    parser.add_argument("--channel", default="", help="socketcan interface (default vcan0)")
    parser.add_argument("--frames", type=int, default=50_000, help="frames for the raw measurement")
    parser.add_argument("--window", type=int, default=128, help="frames per acknowledged window (raw)")
    args = parser.parse_args()
    config = allocate(args.interface, args.channel)
    raw = max(
        (raw_rate(config, args.frames, args.window) for _ in range(args.repeat)), key=lambda r: r["raw_frames_per_s"]
    )
    floor = max((lockstep_floor(config, 3000) for _ in range(args.repeat)), key=lambda f: f["floor_ticks_per_s"])
    figures = (
        {"interface": args.interface}
        | raw
        | floor
        | pipeline(args.interface, args.repeat)
        | in_process(args.repeat)
        | arithmetic_floor(args.repeat)
    )
    figures["inprocess_over_arithmetic"] = figures["arithmetic_realtime_factor"] / figures["inprocess_realtime_factor"]
    figures["ratio"] = figures["pipeline_frames_per_s"] / figures["raw_frames_per_s"]
    figures["floor_ratio"] = figures["pipeline_ticks_per_s"] / figures["floor_ticks_per_s"]
    print_figures(figures, args.json, lambda figures: print_table(figures, args))


if __name__ == "__main__":
    main()
