"""Where running co-simulations announce themselves, so that clients and monitors can find them.

``cosim run`` writes one small JSON file per run (its bus, its DBC, its sample time) into a
per-user directory and removes it when the run ends; ``Client.attach`` and ``cosim monitor`` read
it. Entries of runs whose process has gone are ignored and cleaned up.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from cosim.errors import CosimError


def directory() -> Path:
    base = os.environ.get("COSIM_RUNTIME_DIR") or os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"cosim-{os.getuid()}"


class Registration:
    """A run's entry, present while the ``with`` block runs."""

    def __init__(self, run_id: str, info: dict[str, Any]) -> None:
        self.path = directory() / f"{run_id}.json"
        self.info = {"id": run_id, "pid": os.getpid(), **info}

    def __enter__(self) -> Registration:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_suffix(".tmp")
        temporary.write_text(json.dumps(self.info))
        temporary.replace(self.path)  # readers never see a half-written file
        return self

    def __exit__(self, *exc: object) -> None:
        self.path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def active() -> list[dict[str, Any]]:
    """The registered runs whose process is alive, oldest first."""
    runs = []
    for path in sorted(directory().glob("*.json"), key=lambda p: p.stat().st_mtime):
        try:
            info = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if _alive(int(info.get("pid", -1))):
            runs.append(info)
        else:
            path.unlink(missing_ok=True)
    return runs


def find(run: str | None = None) -> dict[str, Any]:
    """The run whose id starts with ``run``, or the only running one."""
    runs = active()
    if run is not None:
        runs = [info for info in runs if info["id"].startswith(run)]
    if not runs:
        which = f" with id {run!r}" if run else ""
        raise CosimError(f"no co-simulation{which} is running on this machine (start one with 'cosim run')")
    if len(runs) > 1:
        listing = "; ".join(
            f"{info['id']} ({info['scenario']}, {info['bus']['interface']} {info['bus']['channel']})" for info in runs
        )
        raise CosimError(f"{len(runs)} co-simulations are running: {listing}; choose one by id")
    return runs[0]
