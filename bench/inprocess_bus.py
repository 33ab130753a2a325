"""Throughput of cosim's in-process bus against python-can's ``virtual`` bus, side by side.

One sender and ``--receivers`` receivers on one channel: the sender sends a batch of classic 8-byte
frames, then every receiver takes them (``recv(0.0)`` until the bus is empty); frames/s is frames
sent per second, each delivered to every receiver. Three buses:

- ``virtual``: python-can's, which deep-copies every frame for every receiver;
- ``cosim_virtual``: cosim's, as any python-can program opens it (``can.Bus(interface="cosim_virtual")``):
  each receiver gets its own copy, stamped like python-can's;
- ``cosim_virtual, cosim's own buses``: as ``open_bus`` opens it for a run's runner and nodes, whose
  frames pass between them as they are (``share_frames``).

Usage: python bench/inprocess_bus.py [--json] [--frames N] [--receivers R] [--repeat R]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import best_of  # noqa: E402
from cosim.bus.transport import allocate, open_bus  # noqa: E402

BATCH = 100


def rate(open_one: Callable[[str], can.BusABC], channel: str, frames: int, receivers: int, repeat: int) -> float:
    """Frames sent per second, each taken by every receiver."""
    sender = open_one(channel)
    listeners = [open_one(channel) for _ in range(receivers)]
    message = can.Message(arbitration_id=0x100, data=bytes(range(8)), is_extended_id=False)

    def run() -> None:
        for _ in range(frames // BATCH):
            for _ in range(BATCH):
                sender.send(message)
            for bus in listeners:
                got = 0
                while bus.recv(0.0) is not None:
                    got += 1
                if got != BATCH:
                    raise RuntimeError(f"a receiver got {got} of {BATCH} frames")

    try:
        return (frames // BATCH * BATCH) / best_of(repeat, run)
    finally:
        for bus in (sender, *listeners):
            bus.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--frames", type=int, default=200_000, help="frames per measurement")
    parser.add_argument("--receivers", type=int, default=1, help="receivers of every frame")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions; the best is kept")
    args = parser.parse_args()
    n, r, repeat = args.frames, args.receivers, args.repeat
    own_channel = allocate("virtual").channel
    figures = {
        "receivers": r,
        "virtual_frames_per_s": rate(lambda c: can.Bus(interface="virtual", channel=c), "bench", n, r, repeat),
        "cosim_virtual_frames_per_s": rate(
            lambda c: can.Bus(interface="cosim_virtual", channel=c), "bench", n, r, repeat
        ),
        "cosim_own_frames_per_s": rate(lambda c: open_bus(allocate("virtual", c)), own_channel, n, r, repeat),
    }
    figures["cosim_virtual_over_virtual"] = figures["cosim_virtual_frames_per_s"] / figures["virtual_frames_per_s"]
    figures["cosim_own_over_virtual"] = figures["cosim_own_frames_per_s"] / figures["virtual_frames_per_s"]
    if args.json:
        print(json.dumps(figures))
        return
    rows = [
        (f"python-can virtual, 1 sender -> {r} receiver(s)", figures["virtual_frames_per_s"], "frames/s"),
        ("cosim_virtual, opened by a python-can program", figures["cosim_virtual_frames_per_s"], "frames/s"),
        ("  over virtual", figures["cosim_virtual_over_virtual"], "x"),
        ("cosim_virtual, cosim's own buses (a run's)", figures["cosim_own_frames_per_s"], "frames/s"),
        ("  over virtual", figures["cosim_own_over_virtual"], "x"),
    ]
    width = max(len(label) for label, _, _ in rows)
    for label, value, unit in rows:
        print(f"{label:<{width}}  {value:>14,.1f} {unit}")


if __name__ == "__main__":
    main()
