"""Where a tick's CPU time goes: the per-tick budget of the runner and of each node, per phase.

An in-process run (``--interface virtual``) of a scenario (default ``masses-bias``) with a timer
around each phase of the runner and of the nodes it drives in its process (the same ``EstimatorNode``
code a node process runs); each call's time is charged to the innermost phase it is in, so the rows
add up to the tick loop. Phases:

- runner: ``sense+faults`` (plant readings, sensor faults, the SYNC), ``encode`` (frames from values),
  ``bus send``, ``log frames`` (the /can records), ``log truth`` (the /truth records), ``mcap write``
  (JSON and the MCAP writer, inside both log phases), ``traffic`` (accounting and ordering of what
  arrived), ``decode``, ``actuate`` (actuator faults, disturbances), ``mj_step``, ``loop`` (the rest:
  waiting, draining the bus, Ctrl-C checks);
- each node: ``bus recv``, ``decode``, ``assemble`` (grouping a tick's frames), ``step`` (the
  estimator's step, its own arithmetic), ``encode``, ``bus send``, ``node`` (the rest).

Then, for a node in a process of its own on ``udp_multicast``, what python-can's transport costs per
frame (send, and receive with unpacking), measured on this host in the same run: with F frames on the
bus per tick and each of P processes receiving all of them (multicast loopback), the transport alone
costs P·F receives and F sends per tick, shared by the cores.

Usage: python bench/tick_budget.py [--json] [--scenario NAME] [--duration S] [--repeat R]
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can  # noqa: E402

import faults  # noqa: E402
from bench.common import bench_parser, print_figures  # noqa: E402
from cosim import scenario  # noqa: E402
from cosim.bus import client as client_module  # noqa: E402
from cosim.bus.codec import Codec  # noqa: E402
from cosim.bus.transport import allocate, open_bus  # noqa: E402
from cosim.log.recorder import RunRecorder  # noqa: E402
from cosim.log.writer import McapLog  # noqa: E402
from cosim.run import Run, loop, node, session, traffic  # noqa: E402
from cosim.scenario import overrides  # noqa: E402
from estimators.base import Estimator  # noqa: E402


class Budget:
    """Exclusive time per (owner, phase): a call's time less the time of the phases inside it."""

    def __init__(self) -> None:
        self.time: Counter[tuple[str, str]] = Counter()
        self.calls: Counter[tuple[str, str]] = Counter()
        self._stack: list[list[Any]] = []  # [owner, phase, time of the phases inside]
        self._undo: list[Callable[[], None]] = []

    def wrap(self, owner: Any, attribute: str, phase: str, who: Callable[[Any], str] | None = None) -> None:
        original = getattr(owner, attribute)
        stack, spent, calls = self._stack, self.time, self.calls

        def timed(*args: Any, **kwargs: Any) -> Any:
            name = who(args[0]) if who is not None else (stack[-1][0] if stack else "runner")
            start = time.perf_counter()
            stack.append([name, phase, 0.0])
            try:
                return original(*args, **kwargs)
            finally:
                name, _, inner = stack.pop()
                elapsed = time.perf_counter() - start
                spent[(name, phase)] += elapsed - inner
                calls[(name, phase)] += 1
                if stack:
                    stack[-1][2] += elapsed

        setattr(owner, attribute, timed)
        self._undo.append(lambda: setattr(owner, attribute, original))

    def undo(self) -> None:
        while self._undo:
            self._undo.pop()()


def instrument(budget: Budget, bus_class: type) -> None:
    w = budget.wrap
    w(loop.PlantSource, "frames", "sense+faults")
    w(loop.PlantSource, "advance", "actuate")
    w(faults.FaultInjector, "actuators", "actuate")
    w(Codec, "encode_decoded", "encode")
    w(Codec, "encode", "encode")
    w(Codec, "sync", "encode")
    w(Codec, "heartbeat", "encode")
    w(Codec, "decode", "decode")
    w(bus_class, "send", "bus send")
    w(bus_class, "recv", "bus recv")
    w(session.Session, "send", "loop")
    w(traffic.Traffic, "on_message_received", "traffic")
    w(traffic.Traffic, "flush", "traffic")
    w(RunRecorder, "frame", "log frames")
    w(RunRecorder, "truth", "log truth")
    w(McapLog, "write", "mcap write")
    w(node._Node, "service", "node", who=lambda n: f"node {n.client.name}")
    w(client_module.TickAssembler, "push", "assemble")
    w(Estimator, "step", "step")
    # the plant's step: whatever class the scenario builds
    from cosim.plant import physics, statespace

    w(physics.Plant, "step", "mj_step")
    w(statespace.StateSpacePlant, "step", "mj_step")


def in_process(name: str, duration: float | None, repeat: int) -> dict[str, Any]:
    loaded = scenario.load(name)
    if duration is not None:
        loaded = overrides.apply(loaded, [("duration", duration)])
    best: dict[str, Any] | None = None
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            budget = Budget()
            probe = open_bus(allocate("virtual"))
            bus_class = type(probe)
            probe.shutdown()
            instrument(budget, bus_class)
            try:
                result = Run(loaded, Path(tmp) / "budget.mcap", interface="virtual").execute()
            finally:
                budget.undo()
            if best is None or result.loop_time < best["loop_s"]:
                ticks = result.ticks
                phases: dict[str, dict[str, float]] = {}
                for (owner, phase), spent in budget.time.items():
                    phases.setdefault(owner, {})[phase] = 1e6 * spent / ticks
                rest = 1e6 * result.loop_time / ticks - sum(sum(p.values()) for p in phases.values())
                phases["runner"]["loop"] = phases["runner"].get("loop", 0.0) + rest
                best = {
                    "scenario": name,
                    "ticks": ticks,
                    "frames_per_tick": result.frames / ticks,
                    "loop_s": result.loop_time,
                    "loop_us_per_tick": 1e6 * result.loop_time / ticks,
                    "realtime_factor": result.sim_time / result.loop_time,
                    "us_per_tick": phases,
                }
    assert best is not None
    return best


def udp_costs(frames: int = 20_000) -> dict[str, float]:
    """µs per frame of python-can's udp_multicast (cosim's host-bound bus): send, and receive with unpacking."""
    config = allocate("udp_multicast")
    sender, receiver = open_bus(config), open_bus(config)
    message = can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False)
    try:
        best_send = best_recv = float("inf")
        for _ in range(3):
            batch = 500
            send = recv = 0.0
            for _ in range(frames // batch):
                start = time.perf_counter()
                for _ in range(batch):
                    sender.send(message)
                send += time.perf_counter() - start
                start = time.perf_counter()
                got = 0
                while got < 2 * batch:  # the receiver's and the sender's own copy (loopback)
                    bus = receiver if got < batch else sender
                    if bus.recv(1.0) is None:
                        raise RuntimeError("udp frames lost in the budget's transport measurement")
                    got += 1
                recv += time.perf_counter() - start
            best_send = min(best_send, 1e6 * send / frames)
            best_recv = min(best_recv, 1e6 * recv / (2 * frames))
    finally:
        sender.shutdown()
        receiver.shutdown()
    return {"udp_send_us_per_frame": best_send, "udp_recv_us_per_frame": best_recv}


def receivers(figures: dict[str, Any]) -> int:
    """The processes that receive every frame on UDP: the runner and each estimator node."""
    return 1 + sum(1 for owner in figures["us_per_tick"] if owner.startswith("node "))


def print_table(figures: dict[str, Any]) -> None:
    """The table: where a tick's time goes, per process and phase, and the UDP transport's share."""
    per_tick = figures["frames_per_tick"]
    print(
        f"{figures['scenario']}: {figures['ticks']} ticks in-process, {per_tick:.1f} frames per tick, "
        f"tick loop {figures['loop_us_per_tick']:.0f} µs per tick (real-time factor {figures['realtime_factor']:.1f})"
    )
    for owner, phases in sorted(figures["us_per_tick"].items(), key=lambda item: item[0] != "runner"):
        total = sum(phases.values())
        print(f"  {owner:<20} {total:8.1f} µs/tick")
        for phase, spent in sorted(phases.items(), key=lambda item: -item[1]):
            print(f"    {phase:<18} {spent:8.1f}")
    print(
        f"udp_multicast per frame: send {figures['udp_send_us_per_frame']:.1f} µs, receive "
        f"{figures['udp_recv_us_per_frame']:.1f} µs; {receivers(figures)} processes x {per_tick:.1f} frames: "
        f"{figures['udp_transport_us_per_tick']:.0f} µs of transport per tick"
    )


def main() -> None:
    parser = bench_parser(__doc__, repeat=3)
    parser.add_argument("--scenario", default="masses-bias")
    parser.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    parser.add_argument("--udp-frames", type=int, default=20_000, help="frames of the transport measurement")
    args = parser.parse_args()
    figures = in_process(args.scenario, args.duration, args.repeat)
    figures |= udp_costs(args.udp_frames)
    per_frame = figures["udp_send_us_per_frame"] + receivers(figures) * figures["udp_recv_us_per_frame"]
    figures["udp_transport_us_per_tick"] = figures["frames_per_tick"] * per_frame
    print_figures(figures, args.json, print_table)


if __name__ == "__main__":
    main()
