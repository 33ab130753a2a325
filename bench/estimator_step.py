"""Cost of one estimator step (µs), every estimator kind, against a plain Kalman filter step
measured in the same run on the same data (the baseline); and the Kalman step itself against
``numpy_kalman``, a bare numpy predict+update (Joseph form, as ``estimators.kalman``) on the same
matrices, without the estimator's interface (operating point, missing readings, its result type).

Workload: the coupled masses of TAC 2024 (Table I, τ = 0.01 s) with the sensors x1, x2, x1 − x2
(p = 3; ``--p4`` adds x2 − x1) and the constant bias [1, −1.5, 0.5], after the adaptation has
settled; the continuous-time observer of CDC 2016 runs on its own 3-state example with the fault
of Example 1 and output noise, at its scenarios' sample time 0.02 s; the IJC 2018 reconciliators run
on the paper's three-tank model (58)-(59) (T = 1 s) with a bias and the gain faults of its scenario:
LFT-UIO-SR with the paper's gain estimator (53), with the model window (N = 50) and with the gain
test, LPV-UIO-SR with (53) (its Theorem 1 design, about 8 s, is solved once), and no reconciliation;
the UIO of uio-fault-detection and the COFD diagnosis of vessel-nominal are taken as their scenarios'
plans build them (``scenario_case``), on readings about their operating point with sensor noise.
Each figure is the best of ``--repeat`` timings of ``--steps`` consecutive steps.

The plugin path: ``kalman_as_plugin`` is the Kalman filter as a user's file names it (``kind =
"plugin_kalman.py:PluginKalman"``, a subclass that only renames it), resolved and checked like any
plugin; its ratio to ``kalman`` is what a plugin costs per step over a built-in. ``residual_observer``
is the plugin template's observer (``examples/plugin``), for scale.

Batched: ``<kind>_batched_K`` is the cost per run of one step of K instances stepped together
(``estimators.batched.batch_of``: the kind's own batched step where it has one, else each instance
by itself), and ``<kind>_batched_over_single`` that over the kind's single step (goal at K = 32:
at most 1/3). The K runs see the same readings, each its own instance.

Usage: python bench/estimator_step.py [--json] [--steps N] [--repeat R] [--batch K]
"""

from __future__ import annotations

import copy
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# First: the tests package pins NumPy's kernels as the test suite's processes have them.
import tests  # noqa: E402, F401

# isort: split
import numpy as np  # noqa: E402

import estimators  # noqa: E402
from bench.common import bench_parser, print_figures  # noqa: E402
from cosim import api  # noqa: E402
from cosim.run.plan import RunPlan  # noqa: E402
from estimators import LinearModel  # noqa: E402
from estimators.batched import StepEach, batch_of  # noqa: E402
from estimators.design import zoh_discretize  # noqa: E402
from mjcf import three_tank  # noqa: E402
from tests.linear_masses import masses_model  # noqa: E402

SENSORS = ("x1", "x2", "x1_minus_x2")
ROOT = Path(__file__).resolve().parent.parent

PLUGIN_KALMAN = """
from estimators.kalman import KalmanFilter


class PluginKalman(KalmanFilter):
    \"\"\"The built-in Kalman filter under a plugin's name.\"\"\"

    kind = "plugin-kalman"
"""


def cdc_model() -> LinearModel:
    A = np.array([[-1.0, 3, 0], [0.1, -5, 0.4], [0, 0, -5]])
    C = np.array([[1.0, 1], [1, 0], [2, 1]]) @ np.array([[1.0, 0, 0], [0, 1, 0]])
    return LinearModel(
        A, np.array([[1.0], [0], [-1]]), C, np.zeros((3, 1)), None, ("x1", "x2", "x3"), ("u",), ("y1", "y2", "y3")
    )


def tank_model() -> LinearModel:
    return LinearModel(
        three_tank.PAPER_A,
        three_tank.PAPER_B,
        three_tank.PAPER_C,
        np.zeros((4, 2)),
        1.0,
        ("h1", "h2", "h3"),
        ("Q1", "Q2"),
        ("y1", "y2", "y3", "y4"),
        E=three_tank.PAPER_E,
        disturbances=("v",),
    )


def tank_workload(model: LinearModel, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Readings y = Δ(γ) C x + 2 of the linear three-tank plant under square-wave inflows, with
    γ = (0.6, 0.75, 1, 1): the reconciliators' estimates of γ settle after the first window."""
    x = np.zeros(3)
    gamma = np.array([0.6, 0.75, 1.0, 1.0])
    ys, us = np.empty((steps, 4)), np.empty((steps, 2))
    for k in range(steps):
        us[k] = 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150, k / 97 + 0.16])))
        ys[k] = gamma * (model.C @ x) + 2.0
        x = model.A @ x + model.B @ us[k] + model.E[:, 0] * 0.02 * np.sin(2 * np.pi * k / 90)
    return ys, us


class NumpyKalman:
    """The bare Kalman recursion on the matrices the ``kalman`` estimator builds by default: the
    floor its step is measured against."""

    def __init__(self, model: LinearModel) -> None:
        self.A, self.B, self.C, self.D = model.A, model.B, model.C, model.D
        self.Q = np.eye(model.n) * 1e-4**2
        self.R = np.eye(model.p) * 1e-3**2
        self.P = np.eye(model.n)
        self.x = np.zeros(model.n)
        self.I = np.eye(model.n)

    def step(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        A, B, C, D, P, R = self.A, self.B, self.C, self.D, self.P, self.R
        CP = C @ P
        K = np.linalg.solve(CP @ C.T + R, CP).T
        x = self.x + K @ (y - C @ self.x - D @ u)
        I_KC = self.I - K @ C
        P = I_KC @ P @ I_KC.T + K @ R @ K.T
        self.x = A @ x + B @ u
        self.P = A @ P @ A.T + self.Q
        return x


def workload(
    model: LinearModel, phi: np.ndarray, steps: int, noise: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Measurements and inputs of ``steps`` ticks of the plant (1) with the bias φ."""
    rng = np.random.default_rng(seed)
    Ad, Bd = (model.A, model.B) if model.dt is not None else zoh_discretize(model.A, model.B, 0.02)
    x = np.array([0.2, -0.1, 0.0, 0.0][: model.n])
    ys, us = np.empty((steps, model.p)), np.empty((steps, model.m))
    for k in range(steps):
        u = np.array([np.sin(0.0314 * k)])
        ys[k] = model.C @ x + phi + noise * rng.uniform(-1, 1, model.p)
        us[k] = u
        x = Ad @ x + Bd @ u
    return ys, us


def scenario_case(scenario: str, name: str, steps: int, noise: float):
    """Estimator ``name`` as ``scenario``'s plan builds it (design included, once), and ``steps``
    readings about its model's operating point with white noise of ``noise`` times its scale, at the
    operating point's inputs: a steady state, every reading arriving."""
    estimator = RunPlan.build(api.load(scenario), 0, interface="virtual").estimators[name]
    model, rng = estimator.model, np.random.default_rng(0)
    scale = np.maximum(np.abs(model.y_op), 1.0)
    ys = model.y_op + noise * scale * rng.standard_normal((steps, model.p))
    us = np.repeat(np.atleast_2d(model.u_op), steps, axis=0)
    return (lambda: copy.deepcopy(estimator)), ys, us


#: A timed case: a factory of fresh instances, the readings and the inputs of its steps.
Case = tuple[Callable[[], Any], np.ndarray, np.ndarray]


def time_steps(make, ys: np.ndarray, us: np.ndarray, warmup: int, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        e = make()
        for k in range(warmup):
            e.step(ys[k], us[k])
        start = time.perf_counter()
        for k in range(warmup, len(ys)):
            e.step(ys[k], us[k])
        best = min(best, (time.perf_counter() - start) / (len(ys) - warmup))
    return best * 1e6


def time_batched(make, ys: np.ndarray, us: np.ndarray, warmup: int, size: int) -> tuple[float, bool]:
    """µs per run of one batched step of ``size`` instances (the kind's own batched step?)."""
    batch = batch_of([make() for _ in range(size)])
    Y = np.repeat(ys[:, None, :], size, axis=1)
    U = np.repeat(us[:, None, :], size, axis=1)
    for k in range(warmup):
        batch.step(Y[k], U[k])
    start = time.perf_counter()
    for k in range(warmup, len(ys)):
        batch.step(Y[k], U[k])
    return (time.perf_counter() - start) / (len(ys) - warmup) / size * 1e6, not isinstance(batch, StepEach)


def masses_and_cdc_cases(steps: int, plugins: Path) -> dict[str, Case]:
    """The estimators of the coupled masses (TAC 2024; the Kalman baseline, its plugin twin written
    into ``plugins``, the plugin template) and the continuous-time observer on the CDC 2016 example."""
    m3 = masses_model(SENSORS)
    m4 = masses_model(SENSORS + ("x2_minus_x1",))
    ys3, us3 = workload(m3, np.array([1.0, -1.5, 0.5]), steps, 1e-4)
    ys4, us4 = workload(m4, np.array([1.0, -1.5, 0.5, 0.15]), steps, 1e-4)
    cdc = cdc_model()
    ysc, usc = workload(cdc, np.array([3.0, 0.5, -1.0]), steps, 0.01)
    gain = [[6.0, 2.7], [-0.2, -1.0], [-0.2, -5.1]]
    Y = [[1.0, 1.0], [1.0, 0.0], [2.0, 1.0]]
    (plugins / "plugin_kalman.py").write_text(PLUGIN_KALMAN)
    as_plugin = f"{plugins / 'plugin_kalman.py'}:PluginKalman"
    template = f"{ROOT / 'examples' / 'plugin' / 'my_observer.py'}:ResidualObserver"
    return {
        "numpy_kalman": (lambda: NumpyKalman(m3), ys3, us3),
        "kalman": (lambda: estimators.create("kalman", m3), ys3, us3),
        "kalman_as_plugin": (lambda: estimators.create(as_plugin, m3), ys3, us3),
        "residual_observer": (lambda: estimators.create(template, m3), ys3, us3),
        "pseudoinverse": (lambda: estimators.create("pseudoinverse", m3), ys3, us3),
        "injection": (lambda: estimators.create("injection", m3), ys3, us3),
        "adaptive": (lambda: estimators.create("adaptive", m3), ys3, us3),
        "adaptive_filtered": (lambda: estimators.create("adaptive", m3, {"filter": 1e-4, "eps_phi": 1e4}), ys3, us3),
        "adaptive_injection_p4": (lambda: estimators.create("adaptive", m4, {"injection": True}), ys4, us4),
        "adaptive-ct": (
            lambda: estimators.create("adaptive-ct", cdc, {"gain": gain, "Y": Y, "kappa": 1.0}, 0.02),
            ysc,
            usc,
        ),
    }


def three_tank_cases(steps: int) -> dict[str, Case]:
    """The IJC 2018 reconciliators on the paper's three-tank model: LFT-UIO-SR with (53), the model
    window and the gain test, LPV-UIO-SR with (53), and no reconciliation; their designs made once."""
    tank = tank_model()
    yst, ust = tank_workload(tank, steps)
    base = {"Hz": [1 / 3, 1 / 3, 0.0, 1 / 3], "design_gamma_min": 0.5}
    L = estimators.create("lft-uio-sr", tank, base).L.tolist()  # Theorem 2 once, 0.1 s
    GY = estimators.create("lpv-uio-sr", tank, base).design_params()  # Theorem 1
    lft = {
        "lft-uio-sr_eq53": {},
        "lft-uio-sr_model": {"gain_estimator": "model"},
        "lft-uio-sr_test": {"gain_estimator": "test", "noise_std": 0.01},
    }
    cases: dict[str, Case] = {
        name: (lambda extra=extra: estimators.create("lft-uio-sr", tank, base | {"L": L} | extra), yst, ust)
        for name, extra in lft.items()
    }
    cases["lpv-uio-sr_eq53"] = (lambda: estimators.create("lpv-uio-sr", tank, base | GY), yst, ust)
    cases["no-reconciliation"] = (lambda: estimators.create("no-reconciliation", tank, {"Hz": base["Hz"]}), yst, ust)
    return cases


def single_steps(cases: dict[str, Case], warmup: int, repeat: int) -> dict[str, float]:
    """µs per step of each case, the best of ``repeat`` rounds."""
    figures = dict.fromkeys(cases, np.inf)
    for _ in range(repeat):  # round by round: a load that comes and goes slows every estimator alike
        for name, (make, ys, us) in cases.items():
            figures[name] = min(figures[name], time_steps(make, ys, us, warmup, 1))
    return figures


def batched_steps(
    cases: dict[str, Case], warmup: int, size: int, repeat: int = 1
) -> tuple[dict[str, float], dict[str, bool]]:
    """µs per run of a batched step of ``size`` instances of each kind, the best of ``repeat``
    rounds (as the single steps), and whether the kind has its own batched step (the bare numpy
    filter is no kind: left out)."""
    batched: dict[str, float] = {}
    native: dict[str, bool] = {}
    for _ in range(repeat):
        for name, (make, ys, us) in cases.items():
            if name != "numpy_kalman":
                us_per_run, native[name] = time_batched(make, ys[: warmup + 300], us[: warmup + 300], warmup, size)
                batched[name] = min(batched.get(name, np.inf), us_per_run)
    return batched, native


def print_table(names, figures, ratios, batched, native, size: int) -> None:
    """The table: µs per step of each case, against the Kalman step, batched and against single."""
    base = figures["kalman"]
    print(f"{'estimator':<24}{'µs/step':>10}{'× kalman':>10}{f'batched K={size}':>16}{'× single':>10}")
    for name in names:
        us = figures[name]
        if name in batched:
            how = "" if native[name] else " (each)"
            print(f"{name:<24}{us:>10.1f}{us / base:>10.2f}{batched[name]:>10.1f}{how:>6}{batched[name] / us:>10.2f}")
        else:
            print(f"{name:<24}{us:>10.1f}{us / base:>10.2f}")
    print(f"kalman / numpy_kalman (target <= 1.5): {ratios['kalman_over_numpy_kalman']:.2f}")


def main() -> int:
    parser = bench_parser(__doc__, repeat=3)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--batch", type=int, default=32, help="instances stepped together (default 32)")
    args = parser.parse_args()
    plugins = tempfile.TemporaryDirectory(prefix="cosim-bench-plugin-")  # removed at exit
    cases = masses_and_cdc_cases(args.steps, Path(plugins.name)) | three_tank_cases(args.steps)
    cases["uio"] = scenario_case("uio-fault-detection", "uio", args.steps, 1e-3)
    cases["cofd"] = scenario_case("vessel-nominal", "fdi", args.steps, 1e-4)
    warmup = args.steps // 3
    figures = single_steps(cases, warmup, args.repeat)
    batched, native = batched_steps(cases, warmup, args.batch, args.repeat)
    base = figures["kalman"]
    ratios = {
        f"{name}_over_kalman": us / base for name, us in figures.items() if name not in ("kalman", "numpy_kalman")
    }
    ratios["kalman_over_numpy_kalman"] = base / figures["numpy_kalman"]
    for name, us in batched.items():
        figures[f"{name}_batched_{args.batch}"] = us
        ratios[f"{name}_batched_over_single"] = us / figures[name]
    rounded = {name: round(v, 2) for name, v in figures.items()} | {k: round(v, 3) for k, v in ratios.items()}
    print_figures(rounded, args.json, lambda _: print_table(list(cases), figures, ratios, batched, native, args.batch))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
