"""Log write, inspect and export rates against the bare ``mcap`` writer and reader on the same data.

The data: the log of the default scenario run for ``--seconds`` of simulated time on the
in-process bus (every record of it: frames, decoded messages, truth, events, metadata and
attachments). Every rate is in frames of that log (``/can/frames`` records) per second of wall
time, the best of ``--repeat`` timings, and each ratio is ours / bare, measured in the same run:

- ``write_ratio``: ``cosim.log.writer.McapLog`` writing every record of the log (JSON serialization
  included) / the bare ``mcap`` ``Writer`` with the same chunk size, zstd compression and indexes,
  serializing the same payloads with the same ``orjson`` call;
- ``inspect_ratio``: ``cosim inspect`` (``cosim.analysis.summary.summarize``) on the log / the bare ``mcap``
  reader reading and JSON-decoding every message of it in file order (``iter_messages(log_time_order=False)``,
  its fastest mode);
- ``export_<format>_ratio``: ``cosim export --to <format>`` / that same bare read, since an export
  reads the log and writes the file; ``export_ratio`` is the smallest of them (the slowest format).

Usage: python bench/log_io.py [--json] [--seconds S] [--repeat R]
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import orjson
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser, best_of  # noqa: E402
from cosim import __version__, scenario  # noqa: E402
from cosim.analysis.export import FORMATS, export  # noqa: E402
from cosim.analysis.summary import summarize  # noqa: E402
from cosim.log.reader import LogReader  # noqa: E402
from cosim.log.recorder import FRAMES  # noqa: E402
from cosim.log.writer import McapLog, dumps  # noqa: E402
from cosim.run import Run  # noqa: E402

CHUNK_SIZE = 512 * 1024  # McapLog's default


def record_log(folder: Path, seconds: float) -> Path:
    loaded = scenario.load()
    short = loaded.scenario.model_copy(update={"duration": seconds})
    path = folder / "recorded.mcap"
    Run(
        scenario.LoadedScenario(short, f"{loaded.source} ({seconds:g} s)", loaded.text), path, interface="virtual"
    ).execute()
    return path


def contents(path: Path):
    """Everything in the log: schemas by topic, messages (topic, time, payload), metadata, attachments."""
    with LogReader(path) as reader:
        return reader.schemas(), list(reader.messages()), reader.metadata(), reader.attachments()


def write_ours(path: Path, schemas, messages, metadata, attachments) -> None:
    with McapLog(path) as log:
        channels = {topic: log.channel(topic, schema) for topic, schema in schemas.items()}
        for topic, time_ns, payload in messages:
            log.write(channels[topic], time_ns, payload)
        for name, values in metadata.items():
            log.metadata(name, values)
        for name, data in attachments.items():
            log.attach(name, "application/octet-stream", data)


def write_bare(path: Path, schemas, messages, metadata, attachments) -> None:
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        writer.start(profile="", library=f"bare/{__version__}")
        channels, sequence = {}, {}
        for topic, schema in schemas.items():
            schema_id = writer.register_schema(
                name=schema.get("title", topic), encoding="jsonschema", data=json.dumps(schema).encode()
            )
            channels[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
            sequence[topic] = 0
        for topic, time_ns, payload in messages:
            writer.add_message(
                channels[topic], log_time=time_ns, data=dumps(payload), publish_time=time_ns, sequence=sequence[topic]
            )
            sequence[topic] += 1
        for name, values in metadata.items():
            writer.add_metadata(name, values)
        for name, data in attachments.items():
            writer.add_attachment(
                create_time=0, log_time=0, name=name, media_type="application/octet-stream", data=data
            )
        writer.finish()


def read_bare(path: Path) -> int:
    count = 0
    with open(path, "rb") as stream:
        for _, _, message in make_reader(stream).iter_messages(log_time_order=False):  # its fastest order
            orjson.loads(message.data)
            count += 1
    return count


def measure(seconds: float, repeat: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        data = contents(record_log(folder, seconds))
        frames = sum(1 for topic, _, _ in data[1] if topic == FRAMES)
        ours_log, bare_log = folder / "ours.mcap", folder / "bare.mcap"
        figures: dict[str, float] = {"frames": frames, "messages": len(data[1]), "ticks": round(seconds / 0.01)}
        write_s = best_of(repeat, lambda: write_ours(ours_log, *data))
        bare_write_s = best_of(repeat, lambda: write_bare(bare_log, *data))
        inspect_s = best_of(repeat, lambda: summarize(ours_log))
        read_s = best_of(repeat, lambda: read_bare(ours_log))
        rate = lambda s: frames / s  # noqa: E731
        figures.update(
            {
                "write_frames_per_s": rate(write_s),
                "bare_write_frames_per_s": rate(bare_write_s),
                "write_ratio": bare_write_s / write_s,
                "inspect_frames_per_s": rate(inspect_s),
                "bare_read_frames_per_s": rate(read_s),
                "inspect_ratio": read_s / inspect_s,
            }
        )
        for fmt in FORMATS:
            out = folder / f"out{FORMATS[fmt]}"
            export_s = best_of(repeat, lambda fmt=fmt, out=out: export(ours_log, fmt, out))
            figures[f"export_{fmt}_frames_per_s"] = rate(export_s)
            figures[f"export_{fmt}_ratio"] = read_s / export_s
        figures["export_ratio"] = min(figures[f"export_{fmt}_ratio"] for fmt in FORMATS)
        return figures


def table(f: dict[str, float]) -> str:
    rows = [
        (
            "write (McapLog)",
            f["write_frames_per_s"],
            "bare mcap Writer",
            f["bare_write_frames_per_s"],
            f["write_ratio"],
        ),
        (
            "inspect",
            f["inspect_frames_per_s"],
            "bare mcap read + JSON",
            f["bare_read_frames_per_s"],
            f["inspect_ratio"],
        ),
    ]
    rows += [
        (
            f"export --to {fmt}",
            f[f"export_{fmt}_frames_per_s"],
            "bare mcap read + JSON",
            f["bare_read_frames_per_s"],
            f[f"export_{fmt}_ratio"],
        )
        for fmt in FORMATS
    ]
    lines = [
        f"log of the default scenario: {f['ticks']:.0f} ticks, {f['frames']:.0f} frames, {f['messages']:.0f} messages",
        f"{'operation':<20} {'frames/s':>10}   {'baseline (same run)':<22} {'frames/s':>10}   {'ratio':>5}",
    ]
    lines += [
        f"{name:<20} {ours:>10,.0f}   {base_name:<22} {base:>10,.0f}   {ratio:>5.2f}"
        for name, ours, base_name, base, ratio in rows
    ]
    lines.append(f"export_ratio (slowest format) = {f['export_ratio']:.2f}")
    return "\n".join(lines)


def main() -> None:
    parser = bench_parser(__doc__, repeat=3)
    parser.add_argument(
        "--seconds", type=float, default=30.0, help="simulated seconds of the default scenario (default 30)"
    )
    args = parser.parse_args()
    figures = measure(args.seconds, args.repeat)
    print(json.dumps(figures) if args.json else table(figures))


if __name__ == "__main__":
    main()
