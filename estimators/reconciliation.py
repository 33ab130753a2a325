"""Fault-tolerant sensor reconciliation with unknown input observers (IJC 2018, Behzad et al.).

The virtual sensor of Fig. 2: a UIO estimates the plant state and the sensor bias, x = [x_p; b]
(eq. (7)–(8)), with gains designed by LMIs (``estimators.lmi``); a windowed constrained
least-squares estimator (50)–(53) estimates the sensor gains γ; the reconciliator returns the
virtual output ẑ = H_z C_y x̂_p (eq. (6)), free of the faults that corrupt y = Δ(γ) C_y x_p + F b.

- ``lpv-uio-sr``: Algorithm 1, the gain scheduled on ρ̂(γ̂) over the vertices of Γ (Theorem 1);
- ``lft-uio-sr``: Algorithm 2, one constant gain (Theorem 2);
- ``no-reconciliation``: the baseline ẑ = H_z y (and x̂ = C_y⁺ y), what Figure 9 calls falsified.

Coordinates. Gain faults scale what a sensor transmits, so the model (2), y = Δ(γ) C_y x_p + F b,
holds in the coordinates where the healthy readings are linear in the state without offset:
x_p = x − x_s with C x_s = −(y_op − C x_op) (x_s = 0 for sensors that read absolute values; the
operating point for transmitters zeroed there, like the three-tank's y1…y4, which makes x_p the
paper's deviation state). The linearization about (x_op, u_op) is then the affine model
x_p⁺ = A x_p + B u + c, c = (I − A)(x_op − x_s) − B u_op (plus the model's drift where x_op is no
equilibrium), a known input; x̂ = x̂_p + x_s is published.

Algorithm 1 step 5 and Algorithm 2 step 4 print Q_γ̂(t) next to T_γ̂(t−1); γ̂(t) is computed only
later (step 6), and T Ē = 0 needs T and Q at the same γ̂, so both use γ̂(t−1), as in eq. (10).
Step 8 returns H_z ŷ with ŷ = C̄_γ̂ x̂, which contains the estimated faults; the reconciled
virtual output of the problem statement is eq. (6), ẑ = H_z C_y x̂_p, and that is what is returned
(``zhat``). See docs/errata.md.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import lapack

from estimators.base import Diagnostic, DiagnosticKind, Estimate, Estimator, ParameterError
from estimators.gain_hypotheses import GainHypothesis
from estimators.gain_identification import GainDecision, GainTestWindow, decide_gains, gain_test_window
from estimators.lft_design import LftDesign, lft_uio_design
from estimators.lmi import DesignError, SensorFaultModel, box_coordinates, box_coordinates_runs, uio_matrices
from estimators.lpv_design import LpvDesign, lpv_uio_design
from estimators.model import LinearModel
from estimators.model_window import model_window, window_gains
from estimators.reconciliation_batch import NoReconciliationBatch, UioReconciliationBatch
from estimators.reconciliation_runs import matrices, scheduled_gains
from estimators.sample_window import Sample, SampleWindow

Matrix = tuple[tuple[float, ...], ...]
_ONE = np.ones(1)  # the affine term's input, u_bar = [u; 1]


@dataclass(frozen=True)
class ReconciliationParams:
    Hz: tuple[float, ...] | None = None
    """The virtual output z = H_z C_y x_p, one weight per sensor (Sec. 4: [1/3, 1/3, 0, 1/3])."""
    F: tuple[float, ...] | None = None
    """Bias direction, one entry per sensor (eq. (2)); default all ones (eq. (59)-(60))."""
    gamma_min: float = 0.01
    """Lower corner γ̲ of the box Γ (Sec. 4: 0.01)."""
    gamma_max: float = 1.0
    """Upper corner γ̄ of Γ (Sec. 4: 1)."""
    design_gamma_min: float | None = None
    """γ̲ of the box the LMI design covers, if narrower than Γ (the LFT design of Theorem 2 is
    infeasible on the paper's full box: docs/three-tank.md); γ̂ is clipped to it."""
    window: int = 50
    """Horizon N of the parameter estimator (Sec. 4: 50)."""
    solver: str = "CLARABEL"
    """The SDP solver cvxpy uses for the LMIs."""
    x0: tuple[float, ...] | None = None
    """Initial plant-state estimate (absolute); None starts at the operating point."""
    pe_tol: float = 1e-6
    """Smallest σ_min/σ_max of the window's regressor for the excitation condition to count as met
    (``gain_estimator = "paper"``: of X̂_p, condition (55); ``"model"``: of the projected regressor);
    below it the ``pe`` diagnostic reads 0."""
    gain_estimator: str = "paper"
    """How γ̂ is estimated over the window: ``"paper"``, the QP (53) that regresses y on the UIO's own
    x̂_p (certainty equivalence, eq. (50)–(53)); ``"model"``, the consistency equations (50) with
    x_p constrained by the plant model (1) over the window, solved for 1/γ every tick (ours: with four
    sensors for three levels and one bias the UIO's x̂ fits any γ̂, docs/three-tank.md); ``"test"``,
    the same equations whitened by ``noise_std``, with γ̂ changed only when a χ² test rejects it
    (``decide_gains``)."""
    noise_std: float | tuple[float, ...] | None = None
    """``gain_estimator = "test"``: the standard deviation σ_j of each sensor's white measurement
    noise, in the sensor's unit (one number: the same for all), added before the gain. Required by the
    test: its threshold follows from it. On a plant the linear model does not match exactly (the
    MJCF three-tank), it must also cover the model's error (docs/three-tank.md)."""
    alpha: float = 1e-6
    """``gain_estimator = "test"``: the false-alarm probability of each window's χ² test, the
    probability that a window whose gains did not change rejects them."""
    min_window: int = 10
    """``gain_estimator = "test"``: the fewest samples after a change that may identify new gains."""
    se_tol: float = 0.05
    """``gain_estimator = "test"``: the largest standard error of a gain estimate, 1/‖P⊥ D Y_j‖, for a
    window to count as exciting: a window that resolves some gain worse than this identifies none
    (the ``pe`` diagnostic reads 0) and γ̂ is kept."""
    fit_tol: float = 0.05
    """``gain_estimator = "model"``: the largest relative residual of the window's equations for γ̂
    to be updated. Above it (a fault changed inside the window, or the inputs did not excite it) the
    previous γ̂ is kept. In the three-tank scenario consistent windows fit to 0.003 (median; 99 %
    below 0.048, the linearization's error), windows across a fault's onset to 0.065-2.5. Noise
    raises the floor (0.06 for 0.01 cm at N = 50, 0.015 at N = 200): set it to about twice the floor."""
    L: Matrix | None = None
    """lft-uio-sr: a precomputed gain (skips Theorem 2); the runner passes it to its nodes."""
    G: Matrix | None = None
    """lpv-uio-sr: precomputed G_i of Theorem 1, stacked by rows (l·(n+q) × (n+q))."""
    Y: Matrix | None = None
    """lpv-uio-sr: precomputed Y_i of Theorem 1, stacked by rows (l·(n+q) × m)."""
    multiplier: str = "scalar"
    """lft-uio-sr: the S-procedure multiplier of Theorem 2, "scalar" (eq. (42)) or "diagonal"."""


def _vector(value: tuple[float, ...] | None, size: int, name: str, default: float | None = None) -> np.ndarray:
    if value is None:
        if default is None:
            raise ParameterError(name, f"required: give {size} values, one per sensor")
        return np.full(size, default)
    array = np.asarray(value, dtype=float)
    if array.shape != (size,):
        raise ParameterError(name, f"expected {size} values (one per sensor), got {array.size}")
    return array


class _Reconciliator(Estimator):
    """What the three reconciliators share: H_z, F, the affine model in absolute coordinates."""

    Params = ReconciliationParams

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        p = model.p
        self.Hz = _vector(params.Hz, p, "Hz")
        self.F = _vector(params.F, p, "F", 1.0)[:, None]
        offset = model.y_op - model.C @ model.x_op
        self.x_s = -np.linalg.lstsq(model.C, offset, rcond=None)[0]
        if np.max(np.abs(model.C @ self.x_s + offset)) > 1e-6 * (1.0 + np.max(np.abs(offset))) or np.any(model.D):
            raise ParameterError(
                "model", "sensor reconciliation needs sensors affine in the state with an offset in Im(C), and D = 0"
            )
        shifted = model.x_op - self.x_s
        self.c = shifted - model.A @ shifted - model.B @ model.u_op  # x_p⁺ = A x_p + B u + c
        if model.affine:  # an operating point that is no equilibrium: its drift is part of c
            self.c = self.c + model.drift

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [Diagnostic("zhat", "", "virtual output estimate ẑ (eq. (6))", 1e4, 1e-4, DiagnosticKind.VIRTUAL_OUTPUT)]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        # Gain faults act on the readings as transmitted: work on y and u themselves.
        point = self.operating_point
        estimate = self._absolute_step(dy + point.y, du + self.model.u_op)
        return Estimate(estimate.x - point.x, estimate.diagnostics)

    @abstractmethod
    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        """One tick on the transmitted readings y and inputs u; returns the absolute estimate."""


class NoReconciliation(_Reconciliator):
    """The uncorrected virtual output ẑ = H_z y, and x̂ = C_y⁺ y (least squares on the raw readings)."""

    kind = "no-reconciliation"

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        self.C_pinv = np.linalg.pinv(model.C)

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> NoReconciliationBatch:
        return NoReconciliationBatch(instances)

    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        available = ~np.isnan(y)
        y0 = np.where(available, y, 0.0)
        x = (
            np.linalg.lstsq(self.model.C[available], y[available], rcond=None)[0] + self.x_s
            if available.any()
            else self.operating_point.x
        )
        return Estimate(x, {"zhat": float(self.Hz @ y0)})


class UioReconciliator(_Reconciliator):
    """UIO (10)–(14) + parameter estimator (50)–(53) + reconciliator (6): Algorithms 1 and 2."""

    form = "pinv"
    design_free = frozenset(
        {"Hz", "window", "x0", "pe_tol", "gain_estimator", "fit_tol", "noise_std", "alpha", "min_window", "se_tol"}
    )

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        n, p = model.n, model.p
        if model.E.shape[1] == 0:
            raise ParameterError(
                "model",
                "the plant declares no unknown input: a UIO needs E (plant disturbances or [plant.state_space] E)",
            )
        if not 0.0 < params.gamma_min < params.gamma_max <= 1.0:
            raise ParameterError(
                "gamma_min", f"Γ = [{params.gamma_min}, {params.gamma_max}]^m needs 0 < γ̲ < γ̄ ≤ 1 (eq. (5))"
            )
        design_min = params.gamma_min if params.design_gamma_min is None else params.design_gamma_min
        if not params.gamma_min <= design_min < params.gamma_max:
            raise ParameterError(
                "design_gamma_min", f"must lie in [gamma_min, gamma_max) = [{params.gamma_min}, {params.gamma_max})"
            )
        if params.window < 2:
            raise ParameterError("window", "the parameter estimator needs N ≥ 2 samples")
        if params.gain_estimator not in ("paper", "model", "test"):
            raise ParameterError(
                "gain_estimator", f'{params.gain_estimator!r}: use "paper" (eq. (53)), "model" or "test"'
            )
        self.aug = SensorFaultModel(model.A, np.hstack([model.B, self.c[:, None]]), model.E, model.C, self.F)
        self.lower, self.upper = np.full(p, design_min), np.full(p, params.gamma_max)
        self.Abar, self.Bbar = self.aug.Abar, self.aug.Bbar
        self._design()
        x0 = model.x_op if params.x0 is None else np.asarray(params.x0, dtype=float)
        if x0.shape != (n,):
            raise ParameterError("x0", f"expected {n} values ({', '.join(model.states)}), got {x0.size}")
        self.x_bar0 = np.concatenate([x0 - self.x_s, np.zeros(self.aug.q)])
        self.gamma_names = [f"gamma_{name}" for name in model.outputs]
        self.bias_names = self._bias_names(self.aug.q)
        self.model_window = (
            model_window(model.A, self.aug.B, model.E, model.C, params.window)
            if params.gain_estimator == "model"
            else None
        )
        self.gain_test = self._gain_test_window() if params.gain_estimator == "test" else None
        self.reset()

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> UioReconciliationBatch:
        return UioReconciliationBatch(instances)

    def _gain_test_window(self) -> GainTestWindow:
        """The whitened model window of ``gain_estimator = "test"``, its parameters checked."""
        params, p = self.params, self.model.p
        if params.noise_std is None:
            raise ParameterError(
                "noise_std", 'gain_estimator = "test" needs the readings\' noise level, one σ per sensor'
            )
        sigma = (
            np.broadcast_to(np.asarray(params.noise_std, dtype=float), (p,))
            if np.ndim(params.noise_std) == 0
            else (np.asarray(params.noise_std, dtype=float))
        )
        if sigma.shape != (p,) or not np.all(sigma > 0):
            raise ParameterError(
                "noise_std", f"expected one positive σ, or {p} (one per sensor), got {params.noise_std}"
            )
        if not 0.0 < params.alpha < 1.0:
            raise ParameterError("alpha", f"a false-alarm probability in (0, 1), got {params.alpha}")
        if not params.se_tol > 0.0:
            raise ParameterError("se_tol", f"must be positive, got {params.se_tol}")
        if params.gamma_max != 1.0:
            raise ParameterError("gamma_max", 'gain_estimator = "test" tests γ = 1: the box Γ must contain it (γ̄ = 1)')
        if not 2 <= params.min_window <= params.window:
            raise ParameterError("min_window", f"must lie in [2, window] = [2, {params.window}]")
        window = gain_test_window(
            self.model.A, self.aug.B, self.model.E, self.model.C, sigma, params.window, params.min_window
        )
        dof = params.min_window * p - window.bases[0].shape[1]
        if dof <= p:
            raise ParameterError(
                "min_window",
                f"{params.min_window} samples leave {dof} equations beyond the model's unknowns, "
                f"not more than the {p} gains: take more",
            )
        return window

    def reset(self) -> None:
        self.gamma = np.ones(self.model.p)  # Algorithm 1/2, initialization step 3: Δ(γ̂) = I
        self.x_hat: np.ndarray | None = None
        self.previous: tuple[np.ndarray, np.ndarray] | None = None  # (y, u) of the previous tick
        # The gain test keeps one sample more: the UIO's state before a sub-window of N samples.
        n, m, q = self.model.n, self.model.p, self.aug.q
        sizes = (m, n, q, m, self.aug.B.shape[1])  # y, x_p, b, measured, u of a Sample
        self.history = SampleWindow(self.params.window + (self.gain_test is not None), sizes)
        self.uio_gamma = b""  # the γ̂ of ``uio``, as bytes
        self.pe = 0.0
        self.fit = 0.0
        self.decision: GainDecision | None = None
        self.reference: np.ndarray | None = None  # the gain test: γ̂ before the change it is identifying
        self.episode = 0  # the gain test: ticks since it rejected the settled γ̂
        self.unexplained = 0  # the gain test: ticks in a row whose window no identified gains explain

    # -- design ---------------------------------------------------------------------------------

    @abstractmethod
    def _design(self) -> None:
        """Solve (or take from the parameters) the LMI design of the observer gain."""

    @abstractmethod
    def gain(self, gamma: np.ndarray) -> np.ndarray:
        """The observer gain L at γ̂, shape (n + q, m)."""

    @abstractmethod
    def gains(self, gammas: np.ndarray, failed: dict[int, str] | None = None) -> np.ndarray:
        """``gain`` at each row of ``gammas`` (K, m), shape (K, n + q, m), each run's bit for bit (a
        batch's). With ``failed``, a row whose gain cannot be formed is recorded there (by its index,
        with why) and left NaN; without, it raises."""

    def _solve(self, design: Callable[..., Any], **kwargs: Any) -> Any:
        try:
            return design(self.aug, self.lower, self.upper, solver=self.params.solver, **kwargs)
        except DesignError as error:
            raise ParameterError("model", f"{error} (the box the design covers is set by design_gamma_min)") from None

    # -- the on-line phase --------------------------------------------------------------------

    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        u_bar = np.concatenate((u, _ONE))
        if self.gain_test is not None:
            self._tested_step(y, u_bar)
        else:
            self.history.append(self._observe(y, u_bar, self.gamma))  # with γ̂(t−1)
            if len(self.history) == self.params.window:
                if self.model_window is not None:
                    self.gamma = self._estimate_gamma_on_the_model()
                else:
                    self.gamma = self._estimate_gamma()
        n = self.model.n
        assert self.x_hat is not None
        x_p, b = self.x_hat[:n], self.x_hat[n:]
        z = float(self.Hz.dot(self.model.C.dot(x_p)))  # eq. (6)
        diagnostics = dict(zip(self.gamma_names, self.gamma.tolist())) | dict(zip(self.bias_names, b.tolist()))
        diagnostics |= {"zhat": z, "pe": self.pe, "fit": min(self.fit, 999.0)}
        return Estimate(x_p + self.x_s, diagnostics)

    def _observe(self, y: np.ndarray, u_bar: np.ndarray, gamma: np.ndarray, coast: bool = False) -> Sample:
        """One step of the UIO (10) with T, Q and L at ``gamma`` (Algorithm 1 step 5, Algorithm 2
        step 4): x̂(t) = T x̄(t) + L (y(t−1) − C̄ x̂(t−1)) + Q y(t), x̄(t) = Ā x̂(t−1) + B̄ u(t−1).
        A reading that did not arrive is replaced by its prediction C̄ x̄(t); with ``coast`` all
        are, and x̂(t) is the model's prediction x̄(t) (eq. (11): T + Q C̄ = I)."""
        Q, T, Cbar, L = self._uio(gamma)
        if self.x_hat is None or self.previous is None:  # t = 0: the UIO's own reconstruction from y(0) about x̂₀
            prior = self.x_bar0
            x_next = T.dot(prior)
        else:
            y_prev, u_prev = self.previous
            prior = self.Abar.dot(self.x_hat) + self.Bbar.dot(u_prev)
            x_next = T.dot(prior) + L.dot(y_prev - Cbar.dot(self.x_hat))  # eq. (10)
        missing = np.isnan(y)
        used = np.where(missing | coast, Cbar.dot(prior), y) if coast or missing.any() else y
        self.x_hat = x_next + Q.dot(used)
        self.previous = (used, u_bar)
        n = self.model.n
        return Sample(used, self.x_hat[:n], self.x_hat[n:], y, u_bar)

    def _uio(self, gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Q, T (eq. (11)–(14)), C̄ and L at γ̂, computed again only when γ̂ changes."""
        key = gamma.tobytes()
        if key != self.uio_gamma:
            Cbar = self.aug.Cbar(gamma)
            Q, T = uio_matrices(self.aug, gamma, form=self.form, Cbar=Cbar)
            self.uio_matrices, self.uio_gamma = (Q, T, Cbar, self.gain(gamma)), key
        return self.uio_matrices

    def _tested_step(self, y: np.ndarray, u_bar: np.ndarray) -> None:
        """One tick with ``gain_estimator = "test"``. The gain test runs first, on the window up to
        this tick (``decide_gains``). If it identifies the gains, with a change L samples ago, the UIO
        runs again over those samples with them, from its estimate before them. If it rejects γ̂
        without identifying new gains (a change under way), the UIO does not use this tick's readings,
        since the data reject its sensor model (``_observe`` with ``coast``); they are used by the
        replay once the gains are identified. After N ticks without identification the window no
        longer holds the change, and the UIO goes on with γ̂ as it is."""
        self.history.append(Sample(y, np.zeros(self.model.n), np.zeros(self.aug.q), y, u_bar))
        if len(self.history) < self.params.window:
            self.history[-1] = self._observe(y, u_bar, self.gamma)
            return
        self._follow(self._test_gamma(), y, u_bar)

    def _follow(self, decision: GainDecision, y: np.ndarray, u_bar: np.ndarray) -> None:
        """What the gain test's ``decision`` makes of this tick (``_tested_step``): replay the
        samples since an identified change with the new gains, or step the UIO (coasting while the
        window is unexplained)."""
        self.unexplained = 0 if decision.verdict in ("consistent", "identified") else self.unexplained + 1
        if decision.verdict == "identified":
            self.gamma = decision.gamma
            start = len(self.history) - decision.samples
            if start >= 1:
                before = self.history[start - 1]
                self.x_hat, self.previous = np.concatenate([before.x_p, before.b]), (before.y, before.u)
            else:
                self.x_hat, self.previous = None, None
            for i in range(start, len(self.history)):
                self.history[i] = self._observe(self.history[i].measured, self.history[i].u, self.gamma)
        else:
            coast = 0 < self.unexplained <= self.params.window
            self.history[-1] = self._observe(y, u_bar, self.gamma, coast)

    def _estimate_gamma(self) -> np.ndarray:
        """The QP (53) over the window (51)–(52).

        φ(t) stacks X(t−i) = diag(C_y⁽ʲ⁾ x̂_p(t−i)), so φᵀφ is diagonal and (53) separates into one
        scalar problem per sensor, min Σ_i (r_ij − γ_j s_ij)² over γ̲ ≤ γ_j ≤ γ̄, with
        s_ij = C_y⁽ʲ⁾ x̂_p(t−i) and r_ij = y_j(t−i) − F⁽ʲ⁾ b̂(t−i); each is solved exactly by
        clipping its unconstrained minimizer. A sensor whose regressor column is zero (rank φ < m,
        condition (54)) keeps its previous estimate.
        """
        ys, xs, bs = (self.history.field(name) for name in ("y", "x_p", "b"))
        s = xs.dot(self.model.C.T)  # (N, m)
        r = ys - bs.dot(self.F.T)
        energy = np.einsum("ij,ij->j", s, s)
        gamma = np.divide(np.einsum("ij,ij->j", r, s), energy, out=self.gamma.copy(), where=energy > 0.0)
        gamma = np.minimum(np.maximum(gamma, self.lower), self.upper)  # clipped to Γ
        misfit = r - gamma * s
        size = float(np.einsum("ij,ij", r, r))
        self.fit = float(np.sqrt(np.einsum("ij,ij", misfit, misfit) / size)) if size > 0 else 0.0
        # Condition (55): rank X̂_p = n, as the ratio of extreme singular values.
        sv = lapack.dgesvd(xs, compute_uv=0)[1]  # as np.linalg.svd, without its checks' cost every tick
        self.pe = self._excitation(sv, self.model.n)
        return gamma

    def _estimate_gamma_on_the_model(self) -> np.ndarray:
        """γ̂ from the window through the model (``window_gains``), within Γ. A window that does not
        excite the gains (σ ratio below ``pe_tol``) or that no single γ explains (relative residual
        above ``fit_tol``) keeps the previous estimate."""
        assert self.model_window is not None
        ys, us = self.history.field("measured"), self.history.field("u")
        gamma, sv, self.fit = window_gains(self.model_window, ys, us, self.lower, self.upper)
        self.pe = self._excitation(sv, self.model.p)
        return gamma if self.pe > 0.0 and self.fit <= self.params.fit_tol else self.gamma

    def _test_gamma(self, searched: Sequence[GainHypothesis] | None = None) -> GainDecision:
        """The χ² test of the last N samples (``decide_gains``): γ̂ is kept unless they reject it.
        ``searched``: the hypotheses the window and its splits accept, where a batch searched them
        with other runs'."""
        assert self.gain_test is not None
        N = self.params.window
        ys, us = self.history.field("measured", N), self.history.field("u", N)
        self.decision = decide_gains(
            self.gain_test,
            ys,
            us,
            self.gamma,
            self.params.alpha,
            self.lower,
            self.upper,
            self.params.se_tol,
            self.reference,
            1 if self.reference is None else self.episode + 1,  # samples since the episode began
            searched,
        )
        if self.reference is None and self.decision.verdict != "consistent":
            self.reference, self.episode = self.gamma, 0  # an episode begins: the gains before the change
        self.episode += 1
        if self.episode >= self.params.window:
            self.reference = None  # the change is older than the window: γ̂ is tested as it is from now
        # se_tol over the largest standard error: ≥ 1 when the window resolves every gain; published
        # up to 2, the channel's declared range (a well-excited window reads 2, not its exact margin).
        self.pe = min(self.decision.excitation, 2.0) if self.decision.excitation >= 1.0 else 0.0
        self.fit = self.decision.statistic
        return self.decision

    def _excitation(self, sv: np.ndarray, rank: int) -> float:
        """σ_min/σ_max of a regressor that must have ``rank`` columns' worth of excitation; 0 when
        that ratio is below ``pe_tol`` (the condition fails)."""
        ratio = float(sv[-1] / sv[0]) if len(sv) >= rank and sv[0] > 0 else 0.0
        return ratio if ratio >= self.params.pe_tol else 0.0

    @staticmethod
    def _bias_names(q: int) -> list[str]:
        return ["bhat"] if q == 1 else [f"bhat{i + 1}" for i in range(q)]

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [
            *[
                Diagnostic(
                    f"gamma_{name}",
                    "",
                    f"estimated effectiveness γ̂ of sensor {name} (eq. (53))",
                    2.0,
                    1e-6,
                    DiagnosticKind.GAIN_ESTIMATE,
                    name,
                )
                for name in outputs
            ],
            Diagnostic(
                "bhat", "", "estimated sensor bias b̂ (augmented state, eq. (7))", 1e4, 1e-4, DiagnosticKind.BIAS
            ),
            *super().diagnostic_channels(states, outputs),
            Diagnostic(
                "pe",
                "",
                "persistence of excitation σ_min/σ_max of the window's regressor (condition (55); gain test: se_tol"
                " over the largest standard error of a gain, up to 2); 0: not met",
                2.0,
                1e-9,
                DiagnosticKind.EXCITATION,
            ),
            Diagnostic(
                "fit",
                "",
                "relative residual of the window's equations for γ̂ ((53), or the model window; gain test: the χ²"
                " statistic of γ̂ over its threshold, ≤ 1: accepted)",
                1e3,
                1e-6,
                DiagnosticKind.FIT,
            ),
        ]


class LpvUioReconciliator(UioReconciliator):
    """Algorithm 1 (LPV-UIO-SR): L(ρ̂) = G(ρ̂)⁻¹ Y(ρ̂) from Theorem 1, T and Q from eq. (14)."""

    kind = "lpv-uio-sr"
    form = "pinv"
    design_extras = ("lmi",)

    @classmethod
    def needs_extras(cls, params: dict[str, Any]) -> tuple[str, ...]:
        return () if params.get("G") is not None and params.get("Y") is not None else cls.design_extras

    def _design(self) -> None:
        p = self.params
        if p.G is not None and p.Y is not None:
            nx, l = self.aug.n + self.aug.q, 2**self.model.p
            G, Y = np.asarray(p.G, dtype=float), np.asarray(p.Y, dtype=float)
            if G.shape != (l * nx, nx) or Y.shape != (l * nx, self.model.p):
                raise ParameterError("G", f"precomputed G and Y must be {l * nx}×{nx} and {l * nx}×{self.model.p}")
            self.G_vertices, self.Y_vertices, self.design = G.reshape(l, nx, nx), Y.reshape(l, nx, self.model.p), None
        else:
            design: LpvDesign = self._solve(lpv_uio_design)
            self.design, self.G_vertices, self.Y_vertices = design, design.G, design.Y

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        rho = box_coordinates(gamma, self.lower, self.upper)
        l, nx, m = self.Y_vertices.shape
        G = rho.dot(self.G_vertices.reshape(l, nx * nx)).reshape(nx, nx)  # Σ ρ_i G_i
        # LAPACK directly: numpy.linalg.solve's checks cost as much as the 5 × 5 solve
        lu, pivots, L, info = lapack.dgesv(G, rho.dot(self.Y_vertices.reshape(l, nx * m)).reshape(nx, m))
        if info != 0:
            raise np.linalg.LinAlgError(f"G(ρ̂) is singular at γ̂ = {gamma.tolist()} (Theorem 1 makes it invertible)")
        return L

    def gains(self, gammas: np.ndarray, failed: dict[int, str] | None = None) -> np.ndarray:
        rho = box_coordinates_runs(gammas, self.lower, self.upper)
        return scheduled_gains(rho, self.G_vertices, self.Y_vertices, gammas, failed)

    def design_params(self) -> dict[str, Any]:
        l, nx = self.G_vertices.shape[:2]
        return {"G": self.G_vertices.reshape(l * nx, nx).tolist(), "Y": self.Y_vertices.reshape(l * nx, -1).tolist()}


class LftUioReconciliator(UioReconciliator):
    """Algorithm 2 (LFT-UIO-SR): the constant gain L of Theorem 2, Q = Ē G⁺ Δ⁻¹(γ̂) of eq. (60)."""

    kind = "lft-uio-sr"
    form = "lft"
    design_extras = ("lmi",)

    @classmethod
    def needs_extras(cls, params: dict[str, Any]) -> tuple[str, ...]:
        return () if params.get("L") is not None else cls.design_extras

    def _design(self) -> None:
        if self.params.L is not None:
            self.L, self.design = np.asarray(self.params.L, dtype=float), None
            nx = self.aug.n + self.aug.q
            if self.L.shape != (nx, self.model.p):
                raise ParameterError("L", f"expected a {nx}×{self.model.p} gain, got {self.L.shape}")
        else:
            if self.params.multiplier not in ("scalar", "diagonal"):
                raise ParameterError("multiplier", f'{self.params.multiplier!r}: use "scalar" (eq. (42)) or "diagonal"')
            design: LftDesign = self._solve(lft_uio_design, multiplier=self.params.multiplier)
            self.design, self.L = design, design.L

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        return self.L

    def gains(self, gammas: np.ndarray, failed: dict[int, str] | None = None) -> np.ndarray:
        gains = matrices(len(gammas), self.L.shape, fortran=self.L.flags.f_contiguous and not self.L.flags.c_contiguous)
        gains[...] = self.L
        return gains

    def design_params(self) -> dict[str, Any]:
        return {"L": self.L.tolist()}
