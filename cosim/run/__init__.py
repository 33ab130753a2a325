"""Running a scenario: the plan it is built from, the session that supervises its participants,
the tick loop, the nodes, replay, and the runner that puts them together.

``from cosim.run import Run, run`` is the entry point; the names are imported on first use, so
that a node process (``cosim.run.node``) does not pay for the runner's imports.
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "Run": "cosim.run.runner",
    "run": "cosim.run.runner",
    "RunResult": "cosim.run.session",
    "Progress": "cosim.run.session",
    "Replay": "cosim.run.replay",
    "RunPlan": "cosim.run.plan",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'cosim.run' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(_EXPORTS[name]), name)
