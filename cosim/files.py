"""Files cosim writes: created without following a link planted at their name, and temporaries
under unpredictable names beside them.

Another user of the host who can write in a folder cosim writes to could plant a symbolic link at
a log's name (or at a temporary name a run would use) that points at a file of the user's, which
the write would then destroy. So outputs are opened with ``O_NOFOLLOW`` (a link at the name is an
error, never followed) and temporaries are created with ``O_EXCL`` under a random name
(``tempfile.mkstemp``), then renamed into place (a rename replaces a link, never writes through it).
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO, TypeVar

from cosim.errors import CosimError

T = TypeVar("T")


def open_output(path: str | Path, *, replace: bool = True) -> BinaryIO:
    """``path`` opened for writing from empty; a CosimError in one line if it is a symbolic link,
    or (``replace`` false) if it exists."""
    path = Path(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC | (0 if replace else os.O_EXCL)
    try:
        descriptor = os.open(path, flags, 0o644)
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise CosimError(
                f"{path} is a symbolic link: cosim does not write through one (remove it, or choose another file)"
            ) from None
        if error.errno == errno.EEXIST:
            raise CosimError(f"{path} exists: choose another file, or pass --force to replace it") from None
        raise
    return os.fdopen(descriptor, "wb")


def temporary_beside(path: str | Path, suffix: str = "") -> Path:
    """A new, empty file (mode 0600) in ``path``'s folder under an unpredictable name starting with
    ``.<name>.``, for output that is renamed to ``path`` once complete."""
    path = Path(path)
    descriptor, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        os.fchmod(descriptor, 0o644)  # what an output gets, once renamed (mkstemp makes it 0600)
    finally:
        os.close(descriptor)
    return Path(name)


def once_per_version(
    cache: dict[tuple[Any, ...], T], path: Path, table: Any, missing: Exception, read: Callable[[Path, Any], T]
) -> T:
    """``read(path, table)``, done once per version of the file (its modification time and size)
    and of ``table`` (a pydantic model of the scenario's settings for it), kept in ``cache``: a file
    edited between two runs is read again. ``missing`` is raised if there is no such file."""
    try:
        stat = path.stat()
    except OSError:
        raise missing from None
    key = (path, stat.st_mtime_ns, stat.st_size, table.model_dump_json())
    if key not in cache:
        cache[key] = read(path, table)
    return cache[key]
