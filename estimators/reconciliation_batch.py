"""K reconciliators of one design stepped together (IJC 2018, ``estimators.reconciliation``): the
batched step of a campaign's runs (``estimators.batched``), each run's numbers bit for bit what its
own step gives.

Every run's state is a row of arrays: γ̂, the UIO's x̂ and the previous tick's readings and inputs,
the window of the gain estimators (``SampleWindow`` with a run axis), the UIO's matrices at each
run's γ̂. A tick is K-run arithmetic (``estimators.reconciliation_runs``, the model window's
``window_gains_runs``, the gain test's ``window_tests``), each run's numbers those of the single
step's one-run forms, which it keeps (they cost it half its time at K = 1), held together by
tests/test_batched_reconciliation.py. What a run does apart from the others is done by its own
instance, its state lent to it for that tick (``_lend``, ``_take_back``), so that branch is written
once:

- the gain test of a run whose window rejects γ̂, or while it is identifying a change (the search
  over the window's splits, the replay of the samples since the change, coasting); the runs that
  search at one tick search together: the systems of their windows' splits are formed together
  (``split_systems``, which the single step calls with K = 1), every run's hypotheses on every one
  of its systems are searched in one stacked search (``searched_windows``, which the single step
  calls with one run), and each run's search is handed what it accepts;
- the model window of a run with a reading missing in its window (the projection is the run's own);
- a run whose γ̂ changed has its UIO matrices formed again (the products stacked, the pseudoinverse
  and the LPV gain's LAPACK solve run by run).

A run whose arithmetic raises (a singular LPV gain, a least squares that LAPACK cannot solve) is
out from then on, its row NaN, with what it raised in ``failed``; the others go on.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from estimators.batched import BatchEstimate, DeviationBatch, lstsq_runs, mv
from estimators.gain_identification import (
    search_systems,
    searched_windows,
    split_systems,
    window_equations,
    window_systems,
    window_tests,
)
from estimators.lmi import uio_matrices_runs
from estimators.model_window import window_gains_runs
from estimators.reconciliation_runs import (
    Uio,
    excitations,
    paper_gains,
    published_excitation,
    singular_values,
    uio_steps,
)
from estimators.sample_window import Sample, SampleWindow


def uio_runs(reconciliator: Any, gammas: np.ndarray, failed: dict[int, str] | None = None) -> Uio:
    """A ``UioReconciliator``'s UIO matrices (its ``_uio``'s) at each row of ``gammas`` (K, m), each
    run's bit for bit; ``failed`` as in its ``gains``."""
    Cbars = reconciliator.aug.Cbars(gammas)
    Q, T = uio_matrices_runs(reconciliator.aug, gammas, Cbars, form=reconciliator.form)
    return Uio(Q, T, Cbars, reconciliator.gains(gammas, failed))


def _why(error: Exception) -> str:
    return f"{type(error).__name__}: {error}"


class NoReconciliationBatch(DeviationBatch):
    """K ``NoReconciliation`` instances: ẑ = H_z y on arrays; x̂ = C_y⁺ y by each run's least squares,
    those of the runs with every reading one stacked call (``lstsq_runs``: each system its own gelsd,
    not one gelsd of several right-hand sides, which rounds otherwise), a run missing a reading by
    its own call."""

    def __init__(self, instances: Sequence[Any]) -> None:
        super().__init__(instances)
        first = instances[0]
        self.Hz, self.x_s = first.Hz, first.x_s
        self.failed: dict[int, str] = {}

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        point, C = self.operating_point, self.model.C
        y = dy + point.y
        available = ~np.isnan(y)
        z = np.matmul(np.where(available, y, 0.0)[:, None, :], self.Hz[:, None])[:, 0, 0]
        x = np.full((len(y), self.model.n), np.nan)
        every = available.all(axis=1)
        every[list(self.failed)] = False
        alone = np.ones(len(y), dtype=bool)  # the runs whose least squares are solved run by run
        if every.any():  # every reading there: C and y[r], the system of each such run, solved together
            try:
                x[every] = lstsq_runs(C, y[every]) + self.x_s
                alone[every] = False
            except np.linalg.LinAlgError:
                pass  # run by run below, to know which
        for r in np.flatnonzero(alone).tolist():
            if r in self.failed:
                continue
            seen = available[r]
            try:
                x[r] = np.linalg.lstsq(C[seen], y[r, seen], rcond=None)[0] + self.x_s if seen.any() else point.x
            except np.linalg.LinAlgError as error:
                self.failed[r] = _why(error)
        rows = list(self.failed)
        z[rows] = np.nan
        return BatchEstimate(x - point.x, {"zhat": z}, dict(self.failed))


class UioReconciliationBatch(DeviationBatch):
    """K ``UioReconciliator`` instances of one design (LPV or LFT; (53), the model window or the gain
    test): see the module's docstring."""

    instances: list[Any]  # UioReconciliators (this module does not import their kind: it imports this)

    def __init__(self, instances: Sequence[Any]) -> None:
        super().__init__(instances)
        first = self.first = instances[0]
        self.window, self.n = first.params.window, self.model.n
        self.x_bar0 = first.x_bar0
        for instance in instances[1:]:  # one design: its windows' cached bases serve every run
            instance.gain_test, instance.model_window = first.gain_test, first.model_window
        self._take_state(instances)
        self.uio: Uio = uio_runs(first, self.gamma)
        self.uio_gamma = self.gamma.copy()
        self.failed: dict[int, str] = {}
        self.retired: set[int] = set()

    def _take_state(self, instances: Sequence[Any]) -> None:
        """Each instance's state as a row of the batch's arrays; its window becomes a view of its
        rows of the batch's window."""
        first = instances[0]
        self.gamma = np.stack([e.gamma for e in instances])
        self.fresh = np.array([e.x_hat is None or e.previous is None for e in instances])
        self.x_hat = np.stack([self.x_bar0 if e.x_hat is None else e.x_hat for e in instances])
        none = (np.zeros(self.model.p), np.zeros(first.aug.B.shape[1]))  # a fresh run's, never read
        self.y_prev, self.u_prev = (np.stack(rows) for rows in zip(*(e.previous or none for e in instances)))
        self.pe = np.array([e.pe for e in instances], dtype=float)
        self.fit = np.array([e.fit for e in instances], dtype=float)
        self.tracking = np.array([e.reference is not None for e in instances])
        self.reference = np.stack([e.gamma if e.reference is None else e.reference for e in instances])
        self.episode = np.array([e.episode for e in instances])
        self.unexplained = np.array([e.unexplained for e in instances])
        history = first.history
        if any((e.history.start, e.history.count) != (history.start, history.count) for e in instances):
            raise ValueError("a batch steps runs that are at the same tick")
        y, x_p, b, measured, u = (array.shape[-1] for array in history.arrays)
        self.history = SampleWindow(history.capacity, (y, x_p, b, measured, u), runs=len(instances))
        self.history.start, self.history.count = history.start, history.count
        for r, instance in enumerate(instances):
            for mine, theirs in zip(self.history.arrays, instance.history.arrays, strict=True):
                mine[r] = theirs
            instance.history = self.history.run(r)

    # -- a run's own instance, for what it does apart ----------------------------------------------

    def _lend(self, r: int) -> Any:
        """Run r's instance, holding run r's state."""
        instance = self.instances[r]
        instance.gamma = self.gamma[r].copy()
        if self.fresh[r]:
            instance.x_hat, instance.previous = None, None
        else:
            instance.x_hat, instance.previous = self.x_hat[r].copy(), (self.y_prev[r].copy(), self.u_prev[r].copy())
        instance.history.start, instance.history.count = self.history.start, self.history.count
        instance.pe, instance.fit = float(self.pe[r]), float(self.fit[r])
        instance.reference = self.reference[r].copy() if self.tracking[r] else None
        instance.episode, instance.unexplained = int(self.episode[r]), int(self.unexplained[r])
        return instance

    def _take_back(self, r: int) -> None:
        """Run r's state from its instance, after it stepped."""
        instance = self.instances[r]
        self.gamma[r] = instance.gamma
        self.fresh[r] = instance.x_hat is None or instance.previous is None
        if not self.fresh[r]:
            self.x_hat[r], (self.y_prev[r], self.u_prev[r]) = instance.x_hat, instance.previous
        self.pe[r], self.fit[r] = instance.pe, instance.fit
        self.tracking[r] = instance.reference is not None
        if instance.reference is not None:
            self.reference[r] = instance.reference
        self.episode[r], self.unexplained[r] = instance.episode, instance.unexplained

    def _apart(self, rows: np.ndarray, work: Callable[[Any, int], None]) -> None:
        """``work(instance, r)`` on each of ``rows`` by its own instance; a run that raises is out."""
        for r in map(int, rows):
            if r in self.failed:
                continue
            try:
                work(self._lend(r), r)
            except Exception as error:  # noqa: BLE001 (as its run alone: its node fails)
                self.failed[r] = _why(error)
            else:
                self._take_back(r)

    def _retire(self) -> None:
        """The rows of the runs that are out since the last tick set to a harmless state (the start,
        γ̂ = 1, an empty window), which the arrays go on computing and nothing reads."""
        for r in self.failed.keys() - self.retired:
            self.gamma[r], self.uio_gamma[r], self.fresh[r], self.tracking[r] = 1.0, np.nan, True, False
            self.x_hat[r], self.y_prev[r], self.u_prev[r] = self.x_bar0, 0.0, 0.0
            for array in self.history.arrays:
                array[r] = 0.0
            self.retired.add(r)

    # -- one tick ----------------------------------------------------------------------------------

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        # Gain faults act on the readings as transmitted: work on y and u themselves.
        point, model = self.operating_point, self.model
        self._retire()
        y, u = dy + point.y, du + model.u_op
        u_bar = np.concatenate((u, np.ones((len(u), 1))), axis=1)
        with np.errstate(all="ignore"):  # the rows of runs that are out compute what they compute
            if self.first.gain_test is not None:
                self._tested_step(y, u_bar)
            else:
                self.history.append(self._observe(y, u_bar))  # with γ̂(t−1)
                if len(self.history) == self.window:
                    if self.first.model_window is not None:
                        self._estimate_gamma_on_the_model()
                    else:
                        self._estimate_gamma()
        return self._estimate(point.x)

    def _estimate(self, x_op: np.ndarray) -> BatchEstimate:
        """Each run's x̂, γ̂, b̂, ẑ (eq. (6)), pe and fit, NaN for a run that is out."""
        n, first = self.n, self.first
        x_p, b = self.x_hat[:, :n], self.x_hat[:, n:]
        z = np.matmul(mv(self.model.C, x_p)[:, None, :], first.Hz[:, None])[:, 0, 0]  # eq. (6)
        diagnostics = {name: self.gamma[:, j] for j, name in enumerate(first.gamma_names)}
        diagnostics |= {name: b[:, j] for j, name in enumerate(first.bias_names)}
        diagnostics |= {"zhat": z, "pe": self.pe.copy(), "fit": np.minimum(self.fit, 999.0)}
        x = x_p + first.x_s - x_op
        if self.failed:
            rows = list(self.failed)
            x[rows] = np.nan
            for values in diagnostics.values():
                values[rows] = np.nan
        return BatchEstimate(x, diagnostics, dict(self.failed))

    def _observe(self, y: np.ndarray, u_bar: np.ndarray, rows: np.ndarray | None = None) -> Sample:
        """One step of the UIO (10) in every run (``uio_steps``), with its matrices at its γ̂; the
        state is kept for ``rows`` only (default all): the others stepped apart."""
        self._refresh_uio()
        previous = (self.x_hat, self.y_prev, self.u_prev)
        coast = np.zeros(len(y), dtype=bool)  # a run that coasts steps apart
        x_hat, used = uio_steps(self.uio, self.first.Abar, self.first.Bbar, self.x_bar0, previous, self.fresh, y, coast)
        keep = slice(None) if rows is None else rows
        self.x_hat[keep], self.y_prev[keep], self.u_prev[keep] = x_hat[keep], used[keep], u_bar[keep]
        self.fresh[keep] = False
        n = self.n
        return Sample(used, x_hat[:, :n], x_hat[:, n:], y, u_bar)

    def _refresh_uio(self) -> None:
        """The UIO's matrices of the runs whose γ̂ changed since they were formed (each run's own bits)."""
        changed = (self.gamma.view(np.int64) != self.uio_gamma.view(np.int64)).any(axis=1)
        if self.failed:
            changed[list(self.failed)] = False
        rows = np.flatnonzero(changed)
        if not len(rows):
            return
        every = len(rows) == len(changed)  # as with (53), whose γ̂ moves every tick
        failed: dict[int, str] = {}
        try:
            formed = uio_runs(self.first, self.gamma if every else self.gamma[rows], failed)
        except Exception:  # noqa: BLE001 (one run's: find which, run by run)
            for r in rows:
                self._refresh_row(int(r))
            return
        if every:
            self.uio, self.uio_gamma = formed, self.gamma.copy()
        else:
            for matrix, new in zip(self.uio, formed, strict=True):
                matrix[rows] = new
            self.uio_gamma[rows] = self.gamma[rows]
        self.failed |= {int(rows[k]): why for k, why in failed.items()}

    def _refresh_row(self, r: int) -> None:
        failed: dict[int, str] = {}
        try:
            formed = uio_runs(self.first, self.gamma[r : r + 1], failed)
        except Exception as error:  # noqa: BLE001
            self.failed[r] = _why(error)
            return
        if failed:
            self.failed[r] = failed[0]
            return
        for matrix, new in zip(self.uio, formed, strict=True):
            matrix[r] = new[0]
        self.uio_gamma[r] = self.gamma[r]

    # -- the gain estimators -----------------------------------------------------------------------

    def _estimate_gamma(self) -> None:
        """The QP (53) over each run's window (``paper_gains``) and condition (55)."""
        ys, xs, bs = (self.history.field(name) for name in ("y", "x_p", "b"))
        first = self.first
        self.gamma, self.fit = paper_gains(ys, xs, bs, self.model.C, first.F, self.gamma, first.lower, first.upper)
        self.pe = excitations(singular_values(xs), self.n, first.params.pe_tol)

    def _estimate_gamma_on_the_model(self) -> None:
        """γ̂ from each run's window through the model (``window_gains_runs``); a run with a reading
        missing in its window by its own instance."""
        first = self.first
        ys, us = self.history.field("measured"), self.history.field("u")
        missing = np.isnan(ys).any(axis=(1, 2))
        skipped = dict.fromkeys(map(int, np.flatnonzero(missing)), "") | self.failed
        failed = dict(skipped)
        gamma, sv, fit = window_gains_runs(first.model_window, ys, us, first.lower, first.upper, failed)
        self.failed |= {r: why for r, why in failed.items() if r not in skipped}
        pe = excitations(sv, self.model.p, first.params.pe_tol)
        kept = ~missing
        self.pe[kept], self.fit[kept] = pe[kept], fit[kept]
        moved = kept & (pe > 0.0) & (fit <= first.params.fit_tol)
        self.gamma[moved] = gamma[moved]

        def alone(instance: Any, r: int) -> None:
            instance.gamma = instance._estimate_gamma_on_the_model()

        self._apart(np.flatnonzero(missing), alone)

    def _shared_search(self, apart: np.ndarray, ys: np.ndarray, us: np.ndarray) -> dict[int, list[Any]]:
        """The hypotheses that the gain test of each run among ``apart`` that searches at this tick
        accepts (an episode under way, begun at least min_window samples ago, every reading of the
        window arrived), by run: every run's whole window and splits (these formed together,
        ``split_systems``) searched together (``searched_windows``). Should the stacked search raise,
        each run searches alone, so that what raises is its own run's."""
        first, N = self.first, self.window
        test, p = first.gain_test, first.params
        since = self.episode + 1
        search = apart & self.tracking & (since >= p.min_window) & ~np.isnan(ys).any(axis=(1, 2))
        search[list(self.failed)] = False
        rows = np.flatnonzero(search)
        if not len(rows):
            return {}
        previous = 1.0 / self.reference[rows]
        split = rows[since[rows] < N]  # the splits only while the change can be in the window
        equations = [window_equations(test, ys[r], us[r]) for r in split]
        formed = split_systems(test, equations, 1.0 / self.reference[split]) if len(split) else []
        splits = dict(zip(split.tolist(), formed, strict=True))
        fulls = window_systems(test, ys[rows], us[rows])
        searches = [
            (*search_systems(test, full, splits.get(r, [])), before)
            for r, full, before in zip(rows.tolist(), fulls, previous, strict=True)
        ]
        try:
            found = searched_windows(searches, p.alpha, 1.0 / first.upper, 1.0 / first.lower)
        except Exception:  # noqa: BLE001 (one run's: each searches alone)
            return {}
        return dict(zip(rows.tolist(), found, strict=True))

    def _tested_step(self, y: np.ndarray, u_bar: np.ndarray) -> None:
        """``UioReconciliator._tested_step`` in K runs: the test of γ̂ on each run's whole window on
        arrays (``window_tests``); a run whose window rejects it, has a reading missing, or is
        identifying a change goes on by its own instance (``_test_gamma``, ``_follow``)."""
        runs, n, q = len(y), self.n, self.first.aug.q
        self.history.append(Sample(y, np.zeros((runs, n)), np.zeros((runs, q)), y, u_bar))
        if len(self.history) < self.window:
            self.history[-1] = self._observe(y, u_bar)
            return
        N, first = self.window, self.first
        ys, us = self.history.field("measured", N), self.history.field("u", N)
        p = first.params
        statistic, excitation = window_tests(first.gain_test, ys, us, self.gamma, p.alpha, p.se_tol)
        consistent = ~self.tracking & ~np.isnan(ys).any(axis=(1, 2)) & (statistic <= 1.0)
        consistent[list(self.failed)] = False

        every = consistent.all()
        if not every:
            searched = self._shared_search(~consistent, ys, us)

            def alone(instance: Any, r: int) -> None:
                instance._follow(instance._test_gamma(searched.get(r)), y[r], u_bar[r])

            self._apart(np.flatnonzero(~consistent), alone)
        # γ̂ kept (``_test_gamma``'s bookkeeping of a consistent verdict, ``_follow``'s plain step)
        self.episode[consistent] += 1
        self.pe[consistent] = published_excitation(excitation)[consistent]
        self.fit[consistent] = statistic[consistent]
        self.unexplained[consistent] = 0
        if every:
            self.history[-1] = self._observe(y, u_bar)
        else:
            sample = self._observe(y, u_bar, consistent)
            self.history.set_rows(-1, consistent, Sample(*(field[consistent] for field in sample)))
