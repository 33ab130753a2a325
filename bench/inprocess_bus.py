"""Throughput of cosim's in-process bus against python-can's ``virtual`` bus, side by side.

One sender and ``--receivers`` receivers on one channel: the sender sends a batch of classic 8-byte
frames, then every receiver takes them (``recv(0.0)`` until the bus is empty); frames/s is frames
sent per second, each delivered to every receiver, the best of ``--repeat`` rounds that measure the
three buses in turn:

- ``virtual``: python-can's, which deep-copies every frame for every receiver;
- ``cosim_virtual``: cosim's, as any python-can program opens it (``can.Bus(interface="cosim_virtual")``):
  each receiver gets its own copy, stamped like python-can's;
- ``cosim_virtual, cosim's own buses``: as ``open_bus`` opens it for a run's runner and nodes, whose
  frames pass between them as they are (``share_frames``).

Usage: python bench/inprocess_bus.py [--json] [--frames N] [--receivers R] [--repeat R]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser, print_figures  # noqa: E402
from cosim.bus.transport import allocate, open_bus  # noqa: E402

BATCH = 100


def rate(open_one: Callable[[str], can.BusABC], channel: str, frames: int, receivers: int) -> float:
    """Frames sent per second, each taken by every receiver."""
    sender = open_one(channel)
    listeners = [open_one(channel) for _ in range(receivers)]
    message = can.Message(arbitration_id=0x100, data=bytes(range(8)), is_extended_id=False)
    try:
        start = time.perf_counter()
        for _ in range(frames // BATCH):
            for _ in range(BATCH):
                sender.send(message)
            for bus in listeners:
                got = 0
                while bus.recv(0.0) is not None:
                    got += 1
                if got != BATCH:
                    raise RuntimeError(f"a receiver got {got} of {BATCH} frames")
        return frames // BATCH * BATCH / (time.perf_counter() - start)
    finally:
        for bus in (sender, *listeners):
            bus.shutdown()


BUSES: dict[str, tuple[Callable[[str], can.BusABC], int]] = {
    # name: how to open one on a channel, and the share of --frames it gets (python-can's is slow)
    "virtual": (lambda channel: can.Bus(interface="virtual", channel=channel), 10),
    "cosim_virtual": (lambda channel: can.Bus(interface="cosim_virtual", channel=channel), 1),
    "cosim_own": (lambda channel: open_bus(allocate("virtual", channel)), 1),
}


def rates(frames: int, receivers: int, rounds: int) -> dict[str, float]:
    """Each bus's best rate of ``rounds`` rounds, each round measuring every bus in turn (so that the
    machine's other load weighs on all alike)."""
    best = dict.fromkeys(BUSES, 0.0)
    for _ in range(rounds):
        for name, (open_one, share) in BUSES.items():
            best[name] = max(best[name], rate(open_one, f"bench-{name}", max(frames // share, BATCH), receivers))
    return best


def print_table(figures: dict[str, Any], args: argparse.Namespace) -> None:
    """The table: python-can's virtual bus against cosim_virtual, as a program opens it and as a run does."""
    rows = [
        (f"python-can virtual, 1 sender -> {args.receivers} receiver(s)", figures["virtual_frames_per_s"], "frames/s"),
        ("cosim_virtual, opened by a python-can program", figures["cosim_virtual_frames_per_s"], "frames/s"),
        ("  over virtual", figures["cosim_virtual_over_virtual"], "x"),
        ("cosim_virtual, cosim's own buses (a run's)", figures["cosim_own_frames_per_s"], "frames/s"),
        ("  over virtual", figures["cosim_own_over_virtual"], "x"),
    ]
    width = max(len(label) for label, _, _ in rows)
    for label, value, unit in rows:
        print(f"{label:<{width}}  {value:>14,.1f} {unit}")


def main() -> None:
    parser = bench_parser(__doc__, repeat=5)
    parser.add_argument("--frames", type=int, default=200_000, help="frames per measurement")
    parser.add_argument("--receivers", type=int, default=1, help="receivers of every frame")
    args = parser.parse_args()
    best = rates(args.frames, args.receivers, args.repeat)
    figures = {"receivers": args.receivers} | {f"{name}_frames_per_s": value for name, value in best.items()}
    figures["cosim_virtual_over_virtual"] = figures["cosim_virtual_frames_per_s"] / figures["virtual_frames_per_s"]
    figures["cosim_own_over_virtual"] = figures["cosim_own_frames_per_s"] / figures["virtual_frames_per_s"]
    print_figures(figures, args.json, lambda figures: print_table(figures, args))


if __name__ == "__main__":
    main()
