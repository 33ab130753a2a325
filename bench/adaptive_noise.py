"""The TAC 2024 adaptive observer under measurement noise (docs/tac2024.md, "Under measurement noise"):
a noise sweep on masses-bias's setup, offline (the estimators' own numpy code on the exact linear
plant, no bus), for the paper's setting, the settings that keep it stable, and the uniform weights.

    .venv/bin/python bench/adaptive_noise.py [--seeds 5] [--out docs/figures/tac2024-noise.png] [--json]

The setup is masses-bias's: the coupled masses of Table I sampled at τ = 0.01 s, sensors x1, x2,
x1 − x2 (eq. (3)), 1 N · sin(2π 0.5 t) on the second mass, x(0) = (0.2, −0.1, 0, 0), every
estimator from 0, the bias φ = [1, −1.5, 0.5] of Sec. VII-A from t = 5 s, 30 s; the noise is
Gaussian of the given standard deviation on every sensor (seed per run). Per run: the peak and
RMS of |x − x̂| from the onset, and the settled error, its RMS over the last 10 s. A setting
*breaks* at the smallest noise where its median settled error exceeds the uniform-weight
observer's (the paper's baseline, whose steady error the bias sets). About 10 minutes with 5
seeds on two busy cores; ``--rows`` redraws a sweep printed with ``--json``. Needs the ``plot``
extra for the figure.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' linear masses model

from estimators import create
from tests.linear_masses import masses_model

DURATION, ONSET, SETTLED = 30.0, 5.0, 10.0  # s: the run, the bias onset, the settled window at the end
PHI = np.array([1.0, -1.5, 0.5])  # m, Sec. VII-A
X0 = (0.2, -0.1, 0.0, 0.0)
LEVELS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)  # m, the noise's standard deviation
TUNED = {"bias_poles": [0.99, 0.99, 0.99, 0.99], "epsilon": 0.1}
TUNED_LABEL = "tuned: bias poles 0.99, ε = 0.1"

#: label -> (kind, parameters). The paper's are Sec. VII-A's: σ(A − LH) = {0.75, 0.8, 0.85, 0.9},
#: σ(A − MH) = {0, 0, 0.01, 0.01}, ε = 0.01 (the kind's defaults).
SETTINGS: dict[str, tuple[str, dict[str, Any]]] = {
    "paper (Sec. VII-A)": ("adaptive", {}),
    "paper, ε = 0.1": ("adaptive", {"epsilon": 0.1}),
    "bias poles 0.99": ("adaptive", {"bias_poles": TUNED["bias_poles"]}),
    "Algorithm 1, τ = 1e-4": ("adaptive", {"filter": 1e-4, "eps_phi": 1e4}),
    TUNED_LABEL: ("adaptive", TUNED),
    "tuned + dead zone δ = 0.02": ("adaptive", TUNED | {"dead_zone": 0.02}),
    "uniform weights": ("pseudoinverse", {}),
}
BASELINE = "uniform weights"
TRACES = ("paper (Sec. VII-A)", TUNED_LABEL, "tuned + dead zone δ = 0.02", BASELINE)


def simulate(kind: str, params: dict[str, Any], std: float, seed: int, duration: float = DURATION) -> np.ndarray:
    """|x_k − x̂_k| at every tick of one run of the setup above."""
    model = masses_model()
    estimator = create(kind, model, params)
    rng = np.random.default_rng(seed)
    x = np.array(X0)
    ticks = round(duration / model.dt)
    onset = round(ONSET / model.dt)
    errors = np.empty(ticks)
    for k in range(ticks):
        u = np.array([math.sin(2 * math.pi * 0.5 * k * model.dt)])
        y = model.C @ x + (PHI if k >= onset else 0.0) + std * rng.standard_normal(model.p)
        errors[k] = np.linalg.norm(x - estimator.step(y, u).x)
        x = model.A @ x + model.B @ u
    return errors


def bias_noise_gain(bias_poles: list[float] | tuple[float, ...]) -> float:
    """RMS of |φ̂| per unit of noise standard deviation on every sensor, in steady state: the H₂ norm
    of y ↦ φ̂ of the bias estimator (7a)–(7c),

        ξ⁺ = (A − M H) ξ + M ℙ_Y y,   φ̂ = −G H ξ + (G ℙ_Y + I − Y ℙ_Y) y,   G = Y (I + H (I − A)⁻¹ M),

    from the discrete Lyapunov equation X = (A − MH) X (A − MH)ᵀ + M ℙ_Y ℙ_Yᵀ Mᵀ."""
    import scipy.linalg

    from estimators.design import assumption2_factorization, observer_gain

    model = masses_model()
    A, n, p = model.A, model.n, model.p
    Y, H, _ = assumption2_factorization(model.C)
    M = observer_gain(A, H, bias_poles)
    P_Y = np.linalg.solve(Y.T @ Y, Y.T)
    G = Y @ (np.eye(Y.shape[1]) + H @ np.linalg.solve(np.eye(n) - A, M))
    X = scipy.linalg.solve_discrete_lyapunov(A - M @ H, M @ P_Y @ P_Y.T @ M.T)
    direct = G @ P_Y + np.eye(p) - Y @ P_Y
    return float(np.sqrt(np.trace(G @ H @ X @ H.T @ G.T + direct @ direct.T)))


def forcing_bound(epsilon: float, samples: int = 20000) -> float:
    """sup |Π(s) φ| over the selector's set 𝒮_ε (15), sampled: what drives e in (20) at worst, so
    that |e| ≤ Σₖ |(A − LH)ᵏ L| · this (Theorem 2's bound on the error, whatever the noise)."""
    from estimators.design import assumption2_factorization, weighted_pseudoinverse

    Y, _, _ = assumption2_factorization(masses_model().C)
    s = np.random.default_rng(0).standard_normal((samples, Y.shape[0]))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    inside = [w for w in s if abs(np.linalg.det((Y.T * w) @ Y)) >= epsilon]
    return max(float(np.linalg.norm(weighted_pseudoinverse(Y, w) @ PHI)) for w in inside)


def mechanism() -> dict[str, float]:
    """The two gains that set the error under noise: φ̂'s noise per unit of measurement noise for the
    paper's bias poles and the tuned ones, and the worst forcing over 𝒮_ε for ε = 0.01 and 0.1, with
    the observer's ℓ₁ gain Σₖ |(A − LH)ᵏ L| that turns it into a bound on |e|."""
    from estimators.design import assumption2_factorization, observer_gain

    model = masses_model()
    _, H, _ = assumption2_factorization(model.C)
    L = observer_gain(model.A, H, (0.75, 0.8, 0.85, 0.9))
    closed = model.A - L @ H
    l1 = sum(float(np.linalg.norm(np.linalg.matrix_power(closed, k) @ L, 2)) for k in range(2000))
    return {
        "noise_gain_paper": bias_noise_gain((0.0, 0.0, 0.01, 0.01)),
        "noise_gain_tuned": bias_noise_gain(TUNED["bias_poles"]),
        "forcing_eps_0.01": forcing_bound(0.01),
        "forcing_eps_0.1": forcing_bound(0.1),
        "observer_l1_gain": l1,
    }


def measure(errors: np.ndarray, dt: float = 0.01) -> dict[str, float]:
    """Peak and RMS of the error from the onset on, and its RMS over the last ``SETTLED`` seconds."""
    after = errors[round(ONSET / dt) :]
    settled = errors[-round(SETTLED / dt) :]
    return {
        "peak": float(after.max()),
        "rms": float(np.sqrt(np.mean(after**2))),
        "settled": float(np.sqrt(np.mean(settled**2))),
    }


def sweep(seeds: int, levels: tuple[float, ...] = LEVELS) -> list[dict[str, Any]]:
    """One row per setting, noise level and seed."""
    rows = []
    for label, (kind, params) in SETTINGS.items():
        for std in levels:
            for seed in range(seeds):
                rows.append({"setting": label, "std": std, "seed": seed} | measure(simulate(kind, params, std, seed)))
    return rows


def medians(rows: list[dict[str, Any]], metric: str) -> dict[str, dict[float, float]]:
    """Per setting and noise level, the median of ``metric`` over the seeds."""
    table: dict[str, dict[float, list[float]]] = {}
    for row in rows:
        table.setdefault(row["setting"], {}).setdefault(row["std"], []).append(row[metric])
    return {s: {std: float(np.median(v)) for std, v in by.items()} for s, by in table.items()}


def breaking_levels(rows: list[dict[str, Any]]) -> dict[str, float | None]:
    """Per setting, the smallest noise at which its median settled error exceeds the uniform
    weights' (None: not in the sweep)."""
    settled = medians(rows, "settled")
    baseline = settled[BASELINE]
    return {
        label: next((std for std in sorted(by) if by[std] > baseline[std]), None)
        for label, by in settled.items()
        if label != BASELINE
    }


def draw(rows: list[dict[str, Any]], traces: dict[str, np.ndarray], out: Path) -> None:
    """(a) the settled error and (b) the peak error from the onset against the noise (median, band
    over the seeds); (c) |x − x̂| over time at 1 mm of noise, seed 0."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    marks = [("-", "o"), ("--", "s"), ("-.", "^"), (":", "v"), ("-", "D"), ("--", "P"), ("-", "x")]
    styles = {label: (*mark, f"C{i}") for i, (label, mark) in enumerate(zip(SETTINGS, marks))}
    fig, axes = plt.subplot_mosaic([["a", "b"], ["c", "c"]], figsize=(12.5, 8.6), constrained_layout=True)
    _against_noise(axes["a"], rows, "settled", styles)
    axes["a"].set_ylabel("settled error: RMS |x − x̂|, last 10 s")
    axes["a"].set_title("(a) settled error (the three with bias poles 0.99 coincide)")
    axes["a"].legend(fontsize=8, loc="upper left")
    _against_noise(axes["b"], rows, "peak", styles)
    axes["b"].set_ylabel("peak |x − x̂| from the onset")
    axes["b"].set_title("(b) peak error (median, band: min–max over seeds)")
    right = axes["c"]
    t = np.arange(next(iter(traces.values())).size) * 0.01
    for label, errors in traces.items():
        ls, _, color = styles[label]
        right.semilogy(t, errors, ls=ls, color=color, label=label, lw=0.9, alpha=0.6 if label == TRACES[0] else 1.0)
    right.axvline(ONSET, color="0.5", lw=0.8, ls=":")
    right.text(ONSET, 2e-5, " bias onset", color="0.4", fontsize=8)
    right.set_xlabel("time [s]")
    right.set_ylabel("|x − x̂| (m and m/s mixed)")
    right.set_title("(c) |x − x̂| under 1 mm of noise, seed 0")
    right.set_ylim(1e-5, 1e3)
    right.grid(True, which="major", alpha=0.3)
    right.legend(fontsize=8, loc="upper right", ncols=2)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def _against_noise(ax: Any, rows: list[dict[str, Any]], metric: str, styles: dict[str, tuple[str, str, str]]) -> None:
    for label, (ls, marker, color) in styles.items():
        by: dict[float, list[float]] = {}
        for row in rows:
            if row["setting"] == label:
                by.setdefault(row["std"], []).append(row[metric])
        levels = sorted(by)
        ax.loglog(levels, [np.median(by[s]) for s in levels], ls=ls, marker=marker, color=color, label=label, ms=4)
        low, high = [min(by[s]) for s in levels], [max(by[s]) for s in levels]
        ax.fill_between(levels, low, high, color=color, alpha=0.15, lw=0)
    ax.set_xlabel("measurement noise, standard deviation per sensor [m]")
    ax.grid(True, which="major", alpha=0.3)


def report(rows: list[dict[str, Any]], gains: dict[str, float]) -> None:
    print("why (docs/tac2024.md):")
    for name, value in gains.items():
        print(f"  {name:20s} {value:.3g}")
    levels = sorted({row["std"] for row in rows})
    for metric in ("settled", "rms", "peak"):
        table = medians(rows, metric)
        print(f"\nmedian {metric} error over seeds")
        print(f"{'setting':34s}" + "".join(f"{std:>10.0e}" for std in levels))
        for label, by in table.items():
            print(f"{label:34s}" + "".join(f"{by[std]:>10.3g}" for std in levels))
    print("\nbreaks (settled error above the uniform weights') from a noise of:")
    for label, level in breaking_levels(rows).items():
        print(f"  {label:34s} {'not in the sweep' if level is None else f'{level:.0e} m'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("docs/figures/tac2024-noise.png"))
    parser.add_argument("--json", action="store_true", help="print the rows and the breaking levels as JSON")
    parser.add_argument("--rows", type=Path, help="the JSON this printed before: draw and report it without sweeping")
    args = parser.parse_args()
    rows = json.loads(args.rows.read_text())["rows"] if args.rows else sweep(args.seeds)
    traces = {label: simulate(*SETTINGS[label], 1e-3, 0) for label in TRACES}
    draw(rows, traces, args.out)
    gains = mechanism()
    if args.json:
        print(json.dumps({"rows": rows, "breaks": breaking_levels(rows), "mechanism": gains}))
    else:
        report(rows, gains)
        print(f"\nfigure: {args.out}")


if __name__ == "__main__":
    main()
