"""K estimators of one design stepped together, with a leading run axis (the runs of a batch).

A batch (``cosim.campaign.batch``) steps the runs of a campaign that share a configuration in lockstep:
each run has its own estimator instance, built from the same design, with its own state. Where the
kind implements ``Estimator.batched``, the K instances become one object whose ``step`` takes
y of shape (K, p) and u of shape (K, m) and returns x̂ of shape (K, n) with each diagnostic of
shape (K,), in one call of NumPy's stacked kernels; anything else (a plugin written for one run)
is stepped instance by instance (``StepEach``): correct, no faster.

A batched step must give, run for run, exactly what the instance's own ``step`` gives: NumPy's
stacked ``matmul`` and ``linalg`` on C-contiguous (K, n, n) arrays call the same kernel per matrix
as the single-run calls, so the recursions below are written with them (never ``einsum`` or one
flattened product, which round differently). ``check_batched`` holds a kind's batched step against
its single step on given inputs.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

try:  # the gufuncs behind np.linalg, which take stacks (``lstsq_runs``)
    _umath_linalg: Any = importlib.import_module("numpy.linalg._umath_linalg")
except ImportError:  # pragma: no cover (every NumPy 1.x and 2.x has it)
    _umath_linalg = None

from estimators.base import Estimator
from estimators.model import OperatingPoint


@dataclass(frozen=True)
class BatchEstimate:
    """The estimates of K runs at one tick: ``x`` of shape (K, n) and each diagnostic of shape (K,)."""

    x: np.ndarray
    diagnostics: dict[str, np.ndarray]
    failed: dict[int, str] = field(default_factory=dict)
    """Runs whose estimator raised at this tick (or before), with what it raised: their rows are NaN."""


class BatchStep(Protocol):
    """K estimators stepped as one: y (K, p) and u (K, m) in, ``BatchEstimate`` out."""

    def step(self, y: np.ndarray, u: np.ndarray) -> BatchEstimate: ...


def mv(matrix: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``matrix @ v`` for each row v of ``vectors`` (K, n): the stacked product, bit for bit the
    single-run one (a (K, n) @ (n, p) product would be one gemm, rounded otherwise)."""
    return np.matmul(matrix, vectors[..., None])[..., 0]


def norms(vectors: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(v)`` of each row v of ``vectors`` (K, n), bit for bit: √(v·v), the dot
    product by the stacked (1, n) @ (n, 1) product, which calls the kernel of the single ``v.dot(v)``."""
    return np.sqrt(np.matmul(vectors[..., None, :], vectors[..., :, None])[..., 0, 0])


def _lstsq_failed(error: str, flag: int) -> None:
    raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")


def lstsq_runs(matrix: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``np.linalg.lstsq(matrix, b, rcond=None)[0]`` for each row b of ``vectors`` (K, m), bit for
    bit: NumPy's own least-squares gufunc (LAPACK's gelsd) over the K systems, each solved alone
    with the workspace the single call queries for its shape. (The public function takes one
    system; K right-hand sides in one gelsd call are rounded otherwise.) Raises LinAlgError as
    ``lstsq`` does, for all K: its caller then solves run by run to find which."""
    m, n = matrix.shape
    if _umath_linalg is None:  # a NumPy without the module: the same numbers, run by run
        return np.array([np.linalg.lstsq(matrix, b, rcond=None)[0] for b in vectors]).reshape(len(vectors), n)
    rcond = np.finfo(np.float64).eps * max(m, n)
    stacked = np.broadcast_to(matrix, (len(vectors), m, n))
    with np.errstate(call=_lstsq_failed, invalid="call", over="ignore", divide="ignore", under="ignore"):
        x = _umath_linalg.lstsq(stacked, vectors[:, :, None], rcond, signature="ddd->ddid")[0]
    return x[:, :, 0]


class StepEach:
    """Any estimator's K instances, each stepped by its own ``step``: the batch of a kind without
    a batched step (a user's plugin written for one run)."""

    def __init__(self, instances: Sequence[Estimator]) -> None:
        self.instances = list(instances)
        self.failed: dict[int, str] = {}
        model = self.instances[0].model
        self.signals = [d.name for d in type(self.instances[0]).diagnostic_channels(model.states, model.outputs)]

    def step(self, y: np.ndarray, u: np.ndarray) -> BatchEstimate:
        """Each instance's step; one that raises (or returns what is no estimate) is out from then
        on, its row NaN, and the others go on, as its run goes on alone without its node."""
        runs, n = len(self.instances), self.instances[0].model.n
        x = np.full((runs, n), np.nan)
        diagnostics = {name: np.full(runs, np.nan) for name in self.signals}
        for r, estimator in enumerate(self.instances):
            if r in self.failed:
                continue
            try:
                estimate = estimator.step(y[r], u[r])
                x[r] = np.asarray(estimate.x, dtype=float)
                for name in self.signals:
                    diagnostics[name][r] = float(estimate.diagnostics[name])
            except Exception as error:  # noqa: BLE001 (the estimator's own code, a plugin's maybe)
                self.failed[r] = f"{type(error).__name__}: {error}"
                x[r] = np.nan
        return BatchEstimate(x, diagnostics, dict(self.failed))


class DeviationBatch(ABC):
    """A kind's own batched step, written like ``Estimator._step`` in deviation coordinates about
    the model's operating point; ``step`` does what ``Estimator.step`` does around it. Rows that
    take a rare branch (a missing reading) may be handed to their instance's own ``_step``
    (``_each``), so that a branch is written once."""

    def __init__(self, instances: Sequence[Estimator]) -> None:
        self.instances = list(instances)
        self.model = self.instances[0].model
        self.operating_point = OperatingPoint(self.model, self.instances[0].sample_time)  # the same tick for every run

    def step(self, y: np.ndarray, u: np.ndarray) -> BatchEstimate:
        model, k = self.model, len(self.instances)
        y, u = np.asarray(y, dtype=float), np.asarray(u, dtype=float)
        if y.shape != (k, model.p) or u.shape != (k, model.m):
            raise ValueError(
                f"expected y of shape ({k}, {model.p}) and u of shape ({k}, {model.m}), got {y.shape} and {u.shape}"
            )
        point = self.operating_point
        estimate = self._step(y - point.y, u - model.u_op)
        x = estimate.x + point.x
        point.advance()
        return BatchEstimate(x, estimate.diagnostics, estimate.failed)

    @abstractmethod
    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        """One tick of K runs in deviation coordinates."""

    def _each(
        self,
        rows: np.ndarray,
        dy: np.ndarray,
        du: np.ndarray,
        load: Callable[[Any, int], None],
        store: Callable[[Any, int], None],
    ) -> np.ndarray:
        """Rows stepped by their instance's own ``_step``: ``load`` puts row r's state into the
        instance, ``store`` takes it back after; returns their estimates, (len(rows), n)."""
        found = []
        for r in rows:
            instance = self.instances[r]
            load(instance, r)
            found.append(instance._step(dy[r], du[r]).x)
            store(instance, r)
        return np.array(found).reshape(len(rows), self.model.n)


def batch_of(instances: Sequence[Estimator]) -> BatchStep:
    """K instances of one kind and design as one batched step: the kind's own (``Estimator.batched``)
    where it has one, else ``StepEach``."""
    kind = type(instances[0])
    if any(type(e) is not kind for e in instances):
        raise TypeError("a batch steps instances of one kind")
    return kind.batched(instances) or StepEach(instances)


def check_batched(make: Callable[[], Estimator], y: np.ndarray, u: np.ndarray) -> None:
    """Hold a kind's batched step against its single step: ``make`` builds one instance (the same
    design each time); y (T, K, p) and u (T, K, m) are T ticks of K runs' inputs. Raises
    AssertionError naming the first tick, run and value that differ in any bit (NaN equals NaN)."""
    y, u = np.asarray(y, dtype=float), np.asarray(u, dtype=float)
    ticks, runs = y.shape[:2]
    alone = [make() for _ in range(runs)]
    batch = batch_of([make() for _ in range(runs)])
    if isinstance(batch, StepEach):
        raise AssertionError(f"{type(alone[0]).__name__} has no batched step of its own (Estimator.batched)")
    for k in range(ticks):
        together = batch.step(y[k], u[k])
        for r, estimator in enumerate(alone):
            single = estimator.step(y[k, r], u[k, r])
            if not np.array_equal(together.x[r], single.x, equal_nan=True):
                raise AssertionError(
                    f"tick {k}, run {r}: x̂ {together.x[r].tolist()} batched, {single.x.tolist()} alone"
                )
            for name, value in single.diagnostics.items():
                batched = float(together.diagnostics[name][r])
                if not (batched == value or (batched != batched and value != value)):
                    raise AssertionError(f"tick {k}, run {r}: diagnostic {name} = {batched!r} batched, {value!r} alone")
