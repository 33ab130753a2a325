"""The kinematic terms of a planar vessel's body frame that the linear design model (23) drops,
added to the COFD observers: they are known from the measurements, so they leave no model error.

Cristofaro & Johansen (shared/papers/003), Sec. 4, linearize the ship at a heading ψ̄ = 0. The
outputs are y = [x, y, ψ, u, v, r] (earth-frame position and heading, body-frame velocities,
C = I), and the exact kinematics of a frame that turns with the hull are

    ẋ, ẏ = P(ψ) (u, v),        (u̇, v̇) = Pᵀ(ψ) (ẍ, ÿ) + r (v, −u),

where (23) has (u, v) and Pᵀ(ψ)(ẍ, ÿ) = M⁻¹(τ − D ν + Pᵀ b) (the plant's earth-frame dynamics,
``mjcf/vessel.xml``). So ẏ = A y + W u + E b + φ(y) with

    φ(y) = [(P(ψ) − I)(u, v), 0, r v, −r u, 0],

and an observer ż = F z + R W u + K y + R φ(y) keeps the error equation of Sec. 3,
ė = F e + R W (Δ − I) u + R E b, on the plant itself, not only on (23): φ depends on y alone
(C = I). Without it a thruster fault that turns the ship by 1.6·10⁻⁵ rad (T5 losing half its
thrust) moves the residual components that T5 cannot move by up to 10³ N·s, the centripetal
term r u of the cruise speed (docs/vessel-fdi.md). Between samples φ is linear in t, like y.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from estimators.base import ParameterError
from estimators.uio import UIODesign, discretize

if TYPE_CHECKING:
    from estimators.cofd_design import COFDObserver
    from estimators.model import LinearModel

OUTPUTS = ("x", "y", "psi", "u", "v", "r")
"""The outputs, in order, that the terms are written for (C = I)."""


def kinematic_terms(y: np.ndarray) -> np.ndarray:
    """φ(y) = [(P(ψ) − I)(u, v), 0, r v, −r u, 0] for y = [x, y, ψ, u, v, r]."""
    psi, u, v, r = y[2], y[3], y[4], y[5]
    c, s = np.cos(psi), np.sin(psi)
    return np.array([(c - 1.0) * u - s * v, s * u + (c - 1.0) * v, 0.0, r * v, -r * u, 0.0])


def sampled_gains(H: np.ndarray, R: np.ndarray, F: np.ndarray, sample_time: float) -> tuple[np.ndarray, np.ndarray]:
    """(Γ_0, Γ_1): over one sample, R φ enters z as Γ_0 φ(y_{k−1}) + Γ_1 φ(y_k), φ linear in t
    (``estimators.uio.discretize`` with R in the place of K)."""
    _, _, before, after = discretize(UIODesign(H, R, F, R, np.zeros_like(R)), np.zeros((F.shape[0], 0)), sample_time)
    return before, after


class FrameTerms:
    """What R φ(y) adds to each observer's z over a sample (kind ``cofd``, ``rotating_frame``)."""

    def __init__(self, model: LinearModel, observers: Sequence[COFDObserver], sample_time: float) -> None:
        if tuple(model.outputs) != OUTPUTS or not np.allclose(model.C, np.eye(len(OUTPUTS))):
            raise ParameterError(
                "rotating_frame",
                f"needs the vessel's outputs {', '.join(OUTPUTS)} with C = I; the model has {', '.join(model.outputs)}",
            )
        if model.affine:
            raise ParameterError(
                "rotating_frame",
                "the body frame's terms are added to the linearization at an equilibrium (the vessel at rest); this "
                "model's operating point is none (it has a drift)",
            )
        self.y_op = np.asarray(model.y_op, dtype=float)
        self.gains = [sampled_gains(o.H, o.R, o.F, sample_time) for o in observers]

    def __call__(self, y_prev: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
        """Γ_0 φ(y_{k−1}) + Γ_1 φ(y_k) per observer, from the deviations y − y_op the node steps."""
        before, after = kinematic_terms(y_prev + self.y_op), kinematic_terms(y + self.y_op)
        return [G0 @ before + G1 @ after for G0, G1 in self.gains]
