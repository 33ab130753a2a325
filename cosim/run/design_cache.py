"""A cache of estimator designs that are slow to compute (the LMI solutions of IJC 2018).

An estimator's ``design_params()`` rebuild it without redoing its design; the runner stores them
here under a hash of the estimator kind, the parameters its design depends on (all but the
kind's ``design_free`` ones) and its design model, so that the next
run of the same scenario (or any scenario with the same design problem) skips the solve. The
stored values are exactly what the nodes receive, so a cached run logs the same content as a
fresh one. Location: $COSIM_CACHE_DIR, else $XDG_CACHE_HOME/cosim/designs, else
~/.cache/cosim/designs; ``COSIM_CACHE_DIR=off`` disables it. An unreadable or unwritable cache is
ignored (the design is then computed).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import estimators
from estimators import LinearModel


def directory() -> Path | None:
    configured = os.environ.get("COSIM_CACHE_DIR")
    if configured == "off":
        return None
    if configured:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cosim" / "designs"


def key(kind: str, params: dict[str, Any], model: LinearModel) -> str:
    free = estimators.ESTIMATORS[kind].design_free if kind in estimators.ESTIMATORS else frozenset()
    params = {name: value for name, value in params.items() if name not in free}
    text = json.dumps({"kind": kind, "params": params, "model": model.to_dict()}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def load(kind: str, params: dict[str, Any], model: LinearModel) -> dict[str, Any] | None:
    folder = directory()
    if folder is None:
        return None
    try:
        return json.loads((folder / f"{key(kind, params, model)}.json").read_text())
    except (OSError, ValueError):
        return None


def store(kind: str, params: dict[str, Any], model: LinearModel, design: dict[str, Any]) -> None:
    folder = directory()
    if folder is None or not design:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=folder, suffix=".tmp", delete=False) as handle:
            json.dump(design, handle)
        os.replace(handle.name, folder / f"{key(kind, params, model)}.json")
    except OSError:
        pass
