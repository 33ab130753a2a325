"""Frame digests of the built-in scenarios: the contract that a refactoring changes no frame.

For a run of a built-in scenario at seed 0, the digest is the SHA-256 of its participant frames
(every ``SENSOR_*``, ``EST_*`` and ``COMMAND_*`` frame: arbitration id, payload, tick) in log
order. The recorded digests live in ``tests/data/frame_digests.json``; regenerate them, after a
change that alters frames on purpose, with ``python -m tests.frame_digests --update`` and say
why in the commit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

DIGESTS = Path(__file__).resolve().parent / "data" / "frame_digests.json"
ROLES = ("SENSOR_", "EST_", "COMMAND_")


def unsigned(frame_id: int, data: str) -> str:
    """A logged frame's data (hex) with a control frame's MAC zeroed: what two runs of a seed share
    (each run signs its control frames with its own key)."""
    from cosim.bus.dbc import control_mac_start

    start = control_mac_start(frame_id)
    return data if start is None else data[: 2 * start] + "0" * (len(data) - 2 * start)


def log_digest(path: str | Path) -> tuple[str, int]:
    """The digest of a log's participant frames and how many there are."""
    from cosim.log.reader import LogReader

    sha, count = hashlib.sha256(), 0
    with LogReader(path) as reader:
        for _, _, msg in reader.messages(["/can/frames"]):
            if (msg.get("message") or "").startswith(ROLES):
                sha.update(f"{msg['id']:x}:{msg['data']}:{msg['tick']};".encode())
                count += 1
    return sha.hexdigest(), count


def run_digest(name: str, interface: str = "virtual") -> tuple[str, int]:
    """Run a built-in scenario at seed 0 and digest its log."""
    from cosim import scenario
    from cosim.run import run

    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / f"{name}.mcap"
        result = run(scenario.load(name), out, 0, interface=interface)
        if result.status != "completed":
            raise RuntimeError(f"{name}: {result.status} {result.error}")
        return log_digest(out)


def recorded() -> dict[str, dict[str, object]]:
    return json.loads(DIGESTS.read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", action="store_true", help="write the digests of this version")
    parser.add_argument("--interface", default="virtual")
    parser.add_argument("names", nargs="*")
    args = parser.parse_args(argv)
    from cosim import scenario

    names = args.names or scenario.builtin_names()
    found = recorded() if DIGESTS.exists() else {}
    status = 0
    for name in names:
        digest, count = run_digest(name, args.interface)
        before = found.get(name, {}).get("sha256")
        mark = "new" if before is None else ("same" if before == digest else "CHANGED")
        status |= mark == "CHANGED"
        print(f"{name:28s} {count:8d} frames  {digest[:16]}  {mark}", flush=True)
        found[name] = {"sha256": digest, "frames": count}
    if args.update:
        DIGESTS.write_text(json.dumps(dict(sorted(found.items())), indent=2) + "\n")
    return 0 if args.update else status


if __name__ == "__main__":
    sys.exit(main())
