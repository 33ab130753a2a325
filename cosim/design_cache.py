"""A cache of estimator designs that are slow to compute (the LMI solutions of IJC 2018, pole placements,
the COFD diagnosis's thresholds).

An estimator's ``node_params()`` rebuild it without redoing its design (``design_params()``, e.g. an
LMI solution, and what spares a design redone to the same numbers, e.g. a placed observer gain, whose
``scipy.signal`` import alone takes a second); the runner stores them here under a hash of the
estimator kind, the parameters its design depends on (all but the kind's ``design_free`` ones), its
design model and the code that solves it (``design_code``), so that the next run of the same
scenario (or any scenario with the same design problem) skips the solve. The stored values are
exactly what the nodes receive, so a cached run logs the same content as a fresh one. Location:
$COSIM_CACHE_DIR, else $XDG_CACHE_HOME/cosim/designs, else ~/.cache/cosim/designs;
``COSIM_CACHE_DIR=off`` disables it. An unreadable or unwritable cache is ignored (the design is then
computed).

A design is computed on one BLAS thread (``cosim.blas.one_thread``): the same numbers whatever the
machine's core count.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import os
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any

import estimators
from cosim import progress
from cosim.blas import one_thread
from estimators import Estimator, LinearModel


def directory() -> Path | None:
    configured = os.environ.get("COSIM_CACHE_DIR")
    if configured == "off":
        return None
    if configured:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cosim" / "designs"


def key(kind: str, params: dict[str, Any], model: LinearModel) -> str:
    cls = estimators.ESTIMATORS[kind] if kind in estimators.ESTIMATORS else None
    free = cls.design_free if cls is not None else frozenset()
    params = {name: value for name, value in params.items() if name not in free}
    inputs = {"kind": kind, "params": params, "model": model.to_dict(), "code": design_code(cls)}
    text = json.dumps(inputs, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


@functools.cache
def design_code(cls: type | None) -> str:
    """What a design depends on beside its kind, parameters and model: the code that solves it (the
    ``estimators`` package's sources, and a plugin kind's own module) and the solvers' versions. A
    design cached by other code is not the one this code would solve (an LMI has many solutions; a
    solver release or a changed formulation picks another), and a cached run must log what a fresh
    one logs."""
    digest = hashlib.sha256(_package_code().encode())
    own = inspect.getsourcefile(cls) if cls is not None else None
    if own is not None and Path(own).parent != Path(estimators.__file__).parent:
        digest.update(Path(own).read_bytes())
    return digest.hexdigest()


@functools.cache
def _package_code() -> str:
    digest = hashlib.sha256()
    for path in sorted(Path(estimators.__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + path.read_bytes())
    for library in ("numpy", "scipy", "cvxpy", "clarabel"):
        try:
            digest.update(f"{library} {metadata.version(library)}".encode())
        except metadata.PackageNotFoundError:
            digest.update(f"{library} -".encode())
    return digest.hexdigest()


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


def create(kind: str, model: LinearModel, params: dict[str, Any], sample_time: float | None = None) -> Estimator:
    """``estimators.create`` through the cache: with the stored design if there is one, else
    designed and stored. What the runner, a replay and the plots build their estimators with."""
    cached = load(kind, params, model)
    with one_thread():
        if cached is not None:
            return estimators.create(kind, model, {**params, **cached}, sample_time)
        with progress.step("designing (not in the design cache)"):
            estimator = estimators.create(kind, model, params, sample_time)
            design = estimator.node_params()
    if any(name not in params for name in design):  # else the parameters carry it already
        store(kind, params, model, design)
    return estimator
