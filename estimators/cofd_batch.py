"""Kind ``cofd`` (``estimators.cofd``) for K runs at once: its observers, residual test and
rotating-frame terms on arrays with a leading run axis, bit for bit each run's own step.

The observers' recursions, the thresholds' inertial allowance and the residual test are the same
arithmetic in every run (``estimators.batched.mv``, elementwise operations, NumPy's ``cos`` and
``sin`` on columns); what is each run's own logic stays per run, through the same calls as alone:
the norm of the inertial force (``np.linalg.norm`` of the run's vector), the constraint (24) on its
commands (a least-squares fit), the isolation of its fired components and the persistence before
it latches them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from estimators.allocation import FAULT_MASK, MAX_THRUSTERS
from estimators.batched import BatchEstimate, DeviationBatch, mv
from estimators.isolation import isolate

if TYPE_CHECKING:
    from estimators.cofd import COFDDiagnosis


class COFDBatch(DeviationBatch):
    """K ``COFDDiagnosis`` instances of one design (``COFDDiagnosis.batched``)."""

    def __init__(self, instances: Sequence[COFDDiagnosis]) -> None:
        super().__init__(instances)
        first = self.first = instances[0]
        self.z: list[np.ndarray] | None = None
        if any(e.z is not None for e in instances):
            states: list[Any] = [e.z for e in instances]
            self.z = [np.stack([z[h] for z in states]) for h in range(len(first.observers))]
        self.y_prev = np.stack([e.y_prev for e in instances])
        self.u_prev = np.stack([e.u_prev for e in instances])
        self.t = first.t
        self.candidate = [e.candidate for e in instances]
        self.candidate_since = [e.candidate_since for e in instances]
        self.isolated = np.stack([e.isolated for e in instances])
        test = first.test
        tests: list[Any] = [e.test for e in instances]
        self.total = np.stack([t.total for t in tests])
        self.count = test.count
        self.mean = None if test.mean is None else np.stack([t.mean for t in tests])
        allowances: list[Any] = [t.allowance for t in tests]
        if test.allowance is not None:
            self.q = [np.stack([a.q[h] for a in allowances]) for h in range(len(test.allowance.q))]
            self.a_prev = None if test.allowance.y_prev is None else np.stack([a.y_prev for a in allowances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        from estimators.cofd import (
            ALARM,
            COMPONENTS,
            CONSTRAINTS_MET,
            ISOLATED,
            MAX_COMPONENTS,
            MAX_OBSERVERS,
            RESIDUAL,
            THRESHOLD,
            THRUSTERS,
        )

        model, first = self.model, self.first
        runs = len(dy)
        y = np.where(np.isnan(dy), self.y_prev, dy)
        if self.z is None:
            x0 = mv(np.linalg.pinv(model.C), y) if first.x_init is None else first.x_init
            self.z = [x0 - mv(o.H, y) for o in first.observers]
        else:
            self.t += first.sample_time
            frame = self._frame(self.y_prev, y) if first.frame else [0.0] * len(self.z)
            self.z = [
                mv(Phi, z) + mv(Gu, self.u_prev) + mv(Gy0, self.y_prev) + mv(Gy1, y) + kinematics
                for z, (Phi, Gu, Gy0, Gy1), kinematics in zip(self.z, first.discrete, frame)
            ]
        x_hats = [z + mv(o.H, y) for z, o in zip(self.z, first.observers)]
        r = np.stack([(y - mv(model.C, x))[:, : first.ell] for x in x_hats], axis=1)
        residuals, thresholds = self._test(r, y)
        fired = np.abs(residuals) > thresholds
        met = np.zeros(runs)
        for k in range(runs):  # each run's own logic, as its step has it
            met[k] = constraints_met = first._constraints_met(self.u_prev[k] + model.u_op)
            found = isolate(fired[k], first.signatures, first.hypotheses) if constraints_met else None
            if found != self.candidate[k]:
                self.candidate[k], self.candidate_since[k] = found, self.t
            if found is not None and self.t - self.candidate_since[k] >= first.params.persistence - 1e-9:
                self.isolated[k, list(found)] = True
        self.y_prev, self.u_prev = y, du
        shown = np.zeros((runs, 2, MAX_OBSERVERS, MAX_COMPONENTS))
        shown[:, 0, : len(first.observers), : first.ell] = residuals
        shown[:, 1, : len(first.observers), : first.ell] = thresholds
        groups = self.isolated.shape[1]
        isolated = np.zeros((runs, MAX_THRUSTERS))
        isolated[:, :groups] = self.isolated
        flat = shown.reshape(runs, 2, -1)
        diagnostics = {RESIDUAL.named(c): flat[:, 0, i] for i, c in enumerate(COMPONENTS)}
        diagnostics |= {THRESHOLD.named(c): flat[:, 1, i] for i, c in enumerate(COMPONENTS)}
        diagnostics[ALARM.name] = fired.any(axis=(1, 2)).astype(float)
        diagnostics |= {ISOLATED.named(j): isolated[:, i] for i, j in enumerate(THRUSTERS)}
        diagnostics[FAULT_MASK.name] = (self.isolated * (1 << np.arange(groups))).sum(axis=1).astype(float)
        diagnostics[CONSTRAINTS_MET.name] = met
        return BatchEstimate(mv(first._measured, y), diagnostics)

    def _frame(self, y_prev: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
        """``FrameTerms.__call__`` for K runs."""
        frame = self.first.frame
        assert frame is not None
        before, after = _kinematic_terms(y_prev + frame.y_op), _kinematic_terms(y + frame.y_op)
        return [mv(G0, before) + mv(G1, after) for G0, G1 in frame.gains]

    def _test(self, r: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``ResidualTest.__call__`` for K runs: r of shape (K, observers, components)."""
        test = self.first.test
        extra = self._allowance(y) if test.allowance is not None else np.zeros_like(r)
        if test.centred is None:
            return r, test.flat + extra
        if self.mean is None and self.t >= test.end:
            self.mean = self.total / max(self.count, 1)
        if self.mean is None:
            if self.t >= test.start:
                self.total += np.stack((r, extra), axis=1)
                self.count += 1
            return r, test.flat + extra
        return r - self.mean[:, 0], test.centred + extra + self.mean[:, 1]

    def _allowance(self, y: np.ndarray) -> np.ndarray:
        """``InertialAllowance.__call__`` for K runs (each run's force norm as its own)."""
        allowance = self.first.test.allowance
        assert allowance is not None
        if self.a_prev is None:
            a = np.zeros(len(y))
        else:
            a = np.array([float(np.linalg.norm(row)) for row in mv(allowance.rate, y - self.a_prev)])
        self.a_prev = y
        self.q = [d * q + g * a[:, None] for q, d, g in zip(self.q, allowance.decay, allowance.step)]
        return np.stack([mv(w, q) for w, q in zip(allowance.weights, self.q)], axis=1)


def _kinematic_terms(y: np.ndarray) -> np.ndarray:
    """``rotating_frame.kinematic_terms`` of each row y = [x, y, ψ, u, v, r]."""
    psi, u, v, r = y[:, 2], y[:, 3], y[:, 4], y[:, 5]
    c, s = np.cos(psi), np.sin(psi)
    zero = np.zeros(len(y))
    return np.stack([(c - 1.0) * u - s * v, s * u + (c - 1.0) * v, zero, r * v, -r * u, zero], axis=1)
