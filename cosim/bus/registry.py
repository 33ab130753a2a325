"""Where running co-simulations announce themselves, so that clients and monitors can find them.

``cosim run`` writes one small JSON file per run (its bus, its DBC, its sample time) into a
per-user directory and removes it when the run ends; ``Client.attach`` and ``cosim monitor`` read
it. Entries of runs whose process has gone are ignored and cleaned up.

The directory is private to its user (mode 0700, owned by the user; entries 0600): an entry holds
the run's bus address, its DBC and the specs of the nodes started by hand, which no other user
should read or plant. A directory that is not private is refused with the reason, never used.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from cosim.errors import CosimError


def directory() -> Path:
    base = os.environ.get("COSIM_RUNTIME_DIR") or os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"cosim-{os.getuid()}"


def private_directory(create: bool = True) -> Path:
    """The registry directory, created private, and checked to be this user's and private."""
    folder = directory()
    if create and not folder.exists():
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    if folder.exists():
        info = folder.lstat()
        if stat.S_ISLNK(info.st_mode) or not stat.S_ISDIR(info.st_mode):
            raise CosimError(
                f"the run registry {folder} is not a directory (a link?); remove it, cosim makes a new one"
            )
        if info.st_uid != os.getuid():
            raise CosimError(
                f"the run registry {folder} belongs to user {info.st_uid}, not to you ({os.getuid()}): "
                f"it could announce runs that are not yours; remove it, or set COSIM_RUNTIME_DIR"
            )
        if info.st_mode & 0o077:
            os.chmod(folder, 0o700)  # ours, but made with a lax umask by an earlier version: make it private
    return folder


class Registration:
    """A run's entry, present while the ``with`` block runs."""

    def __init__(self, run_id: str, info: dict[str, Any]) -> None:
        self.path = directory() / f"{run_id}.json"
        self.info = {"id": run_id, "pid": os.getpid(), **info}

    def __enter__(self) -> Registration:
        private_directory()
        temporary = self.path.with_suffix(".tmp")
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(descriptor, "w") as handle:
            handle.write(json.dumps(self.info))
        temporary.replace(self.path)  # readers never see a half-written file
        return self

    def __exit__(self, *exc: object) -> None:
        self.path.unlink(missing_ok=True)


def alive(pid: int) -> bool:
    """Whether a process of that id exists (this user's or not)."""
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
    folder = private_directory(create=False)
    for path in sorted(folder.glob("*.json"), key=lambda p: p.stat().st_mtime):
        try:
            if path.lstat().st_uid != os.getuid():
                continue  # not written by this user: never trusted
            info = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(info, dict) or not isinstance(info.get("pid"), int):
            continue
        if alive(info["pid"]):
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
