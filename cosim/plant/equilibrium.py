"""Where a plant's design model is taken when the plant does not start at rest.

A plant linearized at a point where its derivative f₀ = f(x₀, u₀) is not zero (a spring
stretched, a mass moving) leaves that point at once. A linear model x⁺ = A δx + B δu about it drops
the drift f₀, and an estimator designed on it is then wrong by as much as the plant moves, without a
word. This module holds what the plants share about it:

- ``at_rest``: whether f₀ is negligible, i.e. the point is an equilibrium of the held inputs. Each
  component must be at most ``DRIFT_TOL`` times its rate scale Σⱼ |∂fᵢ/∂xⱼ| sⱼ + Σₖ |∂fᵢ/∂uₖ| wₖ,
  how fast xᵢ moves when every state and input is off by its own scale (sⱼ = max(|xⱼ|, nominalⱼ),
  wₖ = max(|uₖ|, 1)). A point that passes changes nothing: the model is the plain linearization.
- ``search``: an equilibrium near the start, f(x, u₀) = 0 solved from x₀ by SciPy's trust-region
  least squares (``least_squares``, method "trf") on the derivatives weighted by their rate scales,
  with the plant's own Jacobian. Its steps are least-norm where the Jacobian is singular (a mass
  with a damper and no spring: every position is an equilibrium, the one reached keeps x₀'s
  position). "Near" is that box: each state within ``NEAR`` times its scale of its start value.
- ``drift_model``: the affine term of a model that stays at a point which is no equilibrium
  (``LinearModel.drift``): f₀ in continuous time, ∫₀^dt exp(A s) ds f₀ in discrete time.
- the sentences that say which was done, for the run's output and the log (``RunPlan.operating_point``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from estimators.design import zoh_discretize

#: A derivative is negligible below this fraction of its rate scale (see the module's docstring).
DRIFT_TOL = 1e-9
#: How far from its start value, in its own scale, the search looks for an equilibrium.
NEAR = 100.0
#: The most evaluations of the derivatives (and as many of their Jacobian) the search makes.
MAX_EVALUATIONS = 100


def scales(values: np.ndarray, nominal: np.ndarray | float = 1.0) -> np.ndarray:
    """Each value's scale: its magnitude, at least its nominal value."""
    return np.maximum(np.abs(values), nominal)


def rate_scales(F_x: np.ndarray, F_u: np.ndarray, x_scale: np.ndarray, u_scale: np.ndarray) -> np.ndarray:
    """How fast each state moves when every state and input is off by its scale."""
    return np.abs(F_x) @ x_scale + np.abs(F_u) @ u_scale


def at_rest(f: np.ndarray, F_x: np.ndarray, F_u: np.ndarray, x: np.ndarray, u: np.ndarray, nominal: Any = 1.0) -> bool:
    """Whether the derivative ``f`` at (x, u), with Jacobians F_x, F_u there, is negligible."""
    rates = rate_scales(F_x, F_u, scales(x, nominal), scales(u))
    return bool(np.all(np.abs(f) <= DRIFT_TOL * rates))


def search(
    f: Callable[[np.ndarray], np.ndarray],
    jacobian: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    rates: np.ndarray,
    nominal: Any = 1.0,
) -> np.ndarray:
    """Where the least-squares iteration from ``x0`` toward f(x) = 0 ends (within the box of
    ``NEAR``): an equilibrium if ``at_rest`` says so there, else the nearest the plant comes to
    one. ``rates``: the derivatives' rate scales at x0, their weights."""
    from scipy.optimize import least_squares

    x_scale = scales(x0, nominal)
    weight = 1.0 / np.maximum(np.maximum(rates, np.abs(f(x0))), np.finfo(float).tiny)
    result = least_squares(
        lambda x: weight * f(x),
        x0,
        jac=lambda x: weight[:, None] * jacobian(x),
        bounds=(x0 - NEAR * x_scale, x0 + NEAR * x_scale),
        method="trf",
        x_scale=x_scale,
        ftol=1e-15,
        xtol=1e-15,
        gtol=1e-15,
        max_nfev=MAX_EVALUATIONS,
    )
    return np.asarray(result.x, dtype=float)


def drift_model(A: np.ndarray, f0: np.ndarray, dt: float | None) -> np.ndarray:
    """The drift of a model about a point with derivative ``f0``: f0 in continuous time (``dt``
    None), its exact zero-order hold ∫₀^dt exp(A s) ds f₀ over ``dt`` otherwise."""
    if dt is None:
        return np.array(f0, dtype=float)
    return zoh_discretize(A, np.asarray(f0, dtype=float)[:, None], dt)[1][:, 0]


def values(names: Sequence[str], x: np.ndarray) -> str:
    """``name = value`` for each, in a line; below 1e-12 (a solver's rounding), 0."""
    return ", ".join(f"{name} = {value if abs(value) >= 1e-12 else 0.0:.6g}" for name, value in zip(names, x))


def stability(A: np.ndarray) -> str:
    """What a reader needs to know about an equilibrium with the continuous-time A: that the plant
    leaves it (an eigenvalue in the right half-plane), or that it is one of many (A singular: a
    mass with a damper and no spring rests anywhere); "" otherwise."""
    eigenvalues = np.linalg.eigvals(A) if A.size else np.zeros(0)
    largest = float(np.abs(eigenvalues).max(initial=0.0))
    growing = float(eigenvalues.real.max(initial=0.0))
    if growing > 1e-6 * largest:
        return f"; it is unstable (an eigenvalue with real part {growing:.3g}/s): the plant leaves it unless controlled"
    if eigenvalues.size and float(np.abs(eigenvalues).min()) <= 1e-9 * largest:
        return "; one of a continuum (A is singular there): the plant may come to rest at another"
    return ""


def declared(
    plant: Any,
    change: np.ndarray,
    A: np.ndarray,
    BE: np.ndarray,
    x: np.ndarray | None,
    u: np.ndarray,
    dt: float | None,
    *,
    stepped: bool = False,
) -> np.ndarray | None:
    """The drift of an MJCF plant's model about its declared operating point (its keyframe), None
    where that is an equilibrium of its inputs or the plant leaves the drift out
    (``PlantInfo.drift_left_out``); ``plant.operating_point`` says which. ``change``: ẋ there, with
    A, [B E] the continuous-time Jacobians (``dt``: the model's sample time, None for a continuous
    model); or, ``stepped``, the change over one simulated step of dt, A and [B E] the step's.
    ``x``: the point (None where it has no vector of its own: MuJoCo's quaternions, 0 in the
    tangent space)."""
    x = np.zeros(len(change)) if x is None else x
    if stepped:
        assert dt is not None
        f0, F_x, F_u = change / dt, (A - np.eye(len(A))) / dt, BE / dt
    else:
        f0, F_x, F_u = change, A, BE
    plant.operating_point = ""
    if at_rest(f0, F_x, F_u, x, u):
        return None
    names = plant.state_names if len(plant.state_names) == len(x) else tuple(f"dx{i}" for i in range(len(x)))
    said = (
        f"{plant.info.model_file}: its operating point ({values(names, x)}) is no equilibrium of its inputs "
        f"(the derivatives there: {values(rates_of(names), f0)})"
    )
    if plant.info.drift_left_out:
        plant.operating_point = f"{said}; the design model leaves that drift out: {plant.info.drift_left_out}"
        return None
    plant.operating_point = f"{said}: affine model with drift {values(rates_of(names), f0)} about it"
    return change if stepped else drift_model(A, change, dt)


def rates_of(names: Sequence[str]) -> list[str]:
    """The derivatives' names: dx/dt for x."""
    return [f"d{name}/dt" for name in names]
