"""Throughput of the CAN codec and of the MCAP logger, and the run time of the default scenario.

Each figure comes with a baseline measured in the same run on the same data:
- codec: frames/s encoded and decoded through the generated DBC (compiled from cantools into
  packers, with our range checks) against ``struct`` packing and unpacking the same bit layout by
  hand (the ceiling for Python);
- logger: frames/s through the run recorder (the ``/can/frames`` record and the decoded
  ``/can/<Message>`` record, JSON, zstd, indexed) against the bare ``mcap`` writer appending the same
  number of pre-serialized records of the same size;
- run: wall time, ticks/s and real-time factor of the default scenario on the in-process bus
  (``--interface virtual``; ``bench/cosim_throughput.py`` measures the multi-process run).

Usage: python bench/codec_log.py [--json] [--frames N] [--repeat R]
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, IndexType, Writer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser, best_of, best_run, print_figures  # noqa: E402
from cosim import scenario  # noqa: E402
from cosim.bus.codec import signal_bits  # noqa: E402
from cosim.log.recorder import RunRecorder  # noqa: E402
from cosim.log.writer import McapLog, dumps  # noqa: E402
from cosim.run import Run  # noqa: E402


def workload(run: Run, n: int):
    """n (message name, tick, values) triples cycling over the run's sensor, command and estimate messages."""
    specs = [s for s in run.codec.messages() if s.channels]
    rng = np.random.default_rng(0)
    return [
        (s.name, i, [float(rng.uniform(c.minimum, c.maximum) * 0.5) for c in s.channels])
        for i, s in zip(range(n), specs * (n // len(specs) + 1))
    ]


def bench_run(loaded, repeat: int) -> dict[str, float]:
    best = best_run(loaded, repeat, lambda r: r.wall_time)
    return {
        "run_wall_s": best.wall_time,
        "run_ticks_per_s": best.ticks / best.wall_time,
        "run_frames_per_s": best.frames / best.wall_time,
        "run_realtime_factor": best.realtime_factor,
    }


def bench_codec(run: Run, items, repeat: int) -> dict[str, float]:
    codec = run.codec

    def ours() -> None:
        for name, tick, values in items:
            codec.decode(codec.encode(name, tick, values))

    # The same classic-CAN layout by hand: 16-bit tick, then two's complement integers.
    layouts = {
        spec.name: [(c.resolution, signal_bits(c)) for c in spec.channels] for spec in codec.messages() if spec.channels
    }

    def by_hand() -> None:
        for name, tick, values in items:
            raw, shift = tick & 0xFFFF, 16
            for (resolution, bits), value in zip(layouts[name], values):
                raw |= (round(value / resolution) & ((1 << bits) - 1)) << shift
                shift += bits
            data = raw.to_bytes((shift + 7) // 8, "little")
            back, shift, decoded = int.from_bytes(data, "little"), 16, []
            for resolution, bits in layouts[name]:
                field = (back >> shift) & ((1 << bits) - 1)
                decoded.append((field - (1 << bits) if field >> (bits - 1) else field) * resolution)
                shift += bits

    ours_s, hand_s = best_of(repeat, ours), best_of(repeat, by_hand)
    return {
        "codec_frames_per_s": len(items) / ours_s,
        "codec_baseline_frames_per_s": len(items) / hand_s,
        "codec_ratio": hand_s / ours_s,
    }


def bare_payloads(frames, decoded) -> list[bytes]:
    """The records the recorder writes per frame (its /can/frames record and its decoded record),
    pre-serialized: the same number, with the same payload sizes."""
    payloads = []
    for i, (frame, d) in enumerate(zip(frames, decoded)):
        payloads.append(
            dumps(
                {
                    "tick": i,
                    "t": i * 0.01,
                    "seq": i,
                    "id": frame.arbitration_id,
                    "extended": False,
                    "fd": False,
                    "brs": False,
                    "dlc": len(frame.data),
                    "data": bytes(frame.data).hex(),
                    "sender": d.spec.sender,
                    "message": d.spec.name,
                }
            )
        )
        payloads.append(dumps({"tick": d.tick, **d.values}))
    return payloads


def write_bare(path: Path, payloads: list[bytes]) -> None:
    """The bare mcap writer: ``payloads`` on two channels, with the recorder's chunks and compression."""
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=512 * 1024, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channels = [writer.register_channel("/a", "json", schema), writer.register_channel("/b", "json", schema)]
        for i, payload in enumerate(payloads):
            writer.add_message(channels[i % 2], (i // 2) * 10_000_000, payload, (i // 2) * 10_000_000, i // 2)
        writer.finish()


def bench_logger(run: Run, items, repeat: int) -> dict[str, float]:
    """The recorder logging frames and their decoded records, against the bare writer."""
    codec = run.codec
    frames = [codec.encode(name, tick, values) for name, tick, values in items]
    decoded = [codec.decode(f) for f in frames]
    payloads = bare_payloads(frames, decoded)
    s = run.scenario
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"

        def ours() -> None:
            with McapLog(path) as log:
                recorder = RunRecorder(
                    log,
                    codec,
                    states=run.plan.state_names,
                    sensors=s.sensors,
                    actuators=s.actuators,
                    units=run.plan.units,
                )
                for i, (frame, d) in enumerate(zip(frames, decoded)):
                    recorder.frame(i, i * 0.01, i * 10_000_000, frame, d)

        ours_s, bare_s = best_of(repeat, ours), best_of(repeat, lambda: write_bare(path, payloads))
    return {
        "logger_frames_per_s": len(frames) / ours_s,
        "logger_baseline_frames_per_s": len(frames) / bare_s,
        "logger_ratio": bare_s / ours_s,
    }


def print_table(figures: dict[str, Any]) -> None:
    """The table: the codec and the logger against their baselines, and a whole run."""
    rows = [
        ("codec: encode + decode (DBC, compiled packers)", figures["codec_frames_per_s"], "frames/s"),
        ("  baseline: same layout packed by hand", figures["codec_baseline_frames_per_s"], "frames/s"),
        ("  ratio", figures["codec_ratio"], ""),
        ("logger: /can/frames + decoded record", figures["logger_frames_per_s"], "frames/s"),
        ("  baseline: bare mcap writer, same records", figures["logger_baseline_frames_per_s"], "frames/s"),
        ("  ratio", figures["logger_ratio"], ""),
        (f"cosim run {figures['scenario']} --interface virtual", figures["run_wall_s"], "s"),
        ("  ticks per second", figures["run_ticks_per_s"], "ticks/s"),
        ("  frames per second", figures["run_frames_per_s"], "frames/s"),
        ("  real-time factor", figures["run_realtime_factor"], "x"),
    ]
    width = max(len(r[0]) for r in rows)
    for label, value, unit in rows:
        print(f"{label:<{width}}  {value:>12,.2f} {unit}")


def main() -> None:
    parser = bench_parser(__doc__, repeat=3)
    parser.add_argument("--frames", type=int, default=20000, help="frames per codec/logger measurement")
    args = parser.parse_args()
    loaded = scenario.load()
    run = Run(loaded, os.devnull)
    items = workload(run, args.frames)
    figures = {"scenario": loaded.scenario.name, "frames": args.frames}
    figures |= bench_codec(run, items, args.repeat)
    figures |= bench_logger(run, items, args.repeat)
    figures |= bench_run(loaded, args.repeat)
    print_figures(figures, args.json, print_table)


if __name__ == "__main__":
    main()
