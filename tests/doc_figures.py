"""The figures that docs/three-tank.md, docs/tac2024.md and the scenario table (docs/scenarios.md) state, computed
from a run of the built-in scenario they come from.

    python -m tests.doc_figures three-tank-reconciliation [--log FILE.mcap]
    python -m tests.doc_figures cdc2016-ex1 cdc2016-ex2

runs each scenario at seed 0 (or reads its log) and prints the figures as the docs round them. The
tests that run these scenarios (tests/test_three_tank_reconciliation.py, tests/test_reproductions.py)
check the run's figures against ``DOCUMENTED`` within ``TOLERANCE``, and that each documented value
is printed in its document, so a figure in the docs can only change with the command's output.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
HZ = np.array([1 / 3, 1 / 3, 0.0, 1 / 3])

# The three-tank scenario: the fault profile (Fig. 7 and the bias of Fig. 6) and the windows of the
# results table.
THREE_TANK_WINDOWS = {
    "bias": (300, 400),
    "gamma1": (450, 700),
    "both": (750, 1500),
    "onset1": (400, 450),
    "onset2": (700, 750),
}
THREE_TANK_ESTIMATORS = ("lft", "lpv", "lft_model", "lpv_model", "lft_test", "lpv_test")


def three_tank_true_gains(tick: int) -> np.ndarray:
    return np.array([0.6 if tick >= 400 else 1.0, 0.75 if tick >= 700 else 1.0, 1.0, 1.0])


def three_tank_figures(path: str | Path) -> dict[str, float]:
    """RMS of ẑ − z per window and estimator (z = H_z y, the fault-free virtual output), and of γ̂:
    the largest deviation from 1 before the first gain fault once the window has filled (50-400 s),
    the largest |γ̂ − γ| from one window after each onset on (450-700 s, 750-1500 s), γ̂ at 1500 s."""
    from cosim.analysis.series import load
    from cosim.log.reader import LogReader

    with LogReader(path) as reader:
        z = {
            msg["tick"]: float(HZ @ np.array([msg[f"y{i}"] for i in (1, 2, 3, 4)]))
            for _, _, msg in reader.messages(["/truth/sensors"])
        }
    estimates = load(path).estimators
    figures: dict[str, float] = {}
    for name in (*THREE_TANK_ESTIMATORS, "raw"):
        values = estimates[name].values
        for window, (start, end) in THREE_TANK_WINDOWS.items():
            errors = [values[k]["zhat"] - z[k] for k in range(start, end)]
            figures[f"{name}.rms.{window}"] = float(np.sqrt(np.mean(np.square(errors))))
        if name == "raw":
            continue
        gamma = np.array([[values[k][f"gamma_y{i}"] for i in (1, 2, 3, 4)] for k in range(1500)])
        error = np.abs(gamma - np.array([three_tank_true_gains(k) for k in range(1500)]))
        figures[f"{name}.gamma.healthy"] = float(error[50:400].max())
        figures[f"{name}.gamma.faulty"] = float(max(error[450:700].max(), error[750:].max()))
        for i in range(4):
            figures[f"{name}.gamma{i + 1}.final"] = float(gamma[-1, i])
    return figures


def reproduction_figures(series: Any) -> dict[str, float]:
    """docs/tac2024.md's table from a loaded log (``cosim.analysis.plot.load``): per estimator, the
    final error (RMS of |x − x̂| over the last second) and, for the CDC 2016 scenarios, the final
    weights Γ."""
    from estimators.base import DiagnosticKind

    figures: dict[str, float] = {}
    for name, estimator in series.estimators.items():
        t, error = series.error(name)
        figures[f"{name}.final"] = float(np.sqrt(np.mean(error[t >= t[-1] - 1.0] ** 2)))
        if estimator.kind == "adaptive-ct":
            weights = series.diagnostic(name, DiagnosticKind.WEIGHT)[1][-1]
            for i, w in enumerate(weights):
                figures[f"{name}.gamma{i + 1}"] = float(w)
    return figures


# What the docs state, as they print it. Tolerance: the runs are deterministic at seed 0, so a figure
# is off only by its rounding, half a unit of its last printed digit; plus 2 % of the value for what
# the solvers (Clarabel, the Rosenbrock integrator's error control) and BLAS may move across machines.
DOCUMENTED: dict[str, dict[str, str]] = {
    "three-tank-reconciliation": {
        "raw.rms.bias": "2.00",
        "raw.rms.gamma1": "1.52",
        "raw.rms.both": "1.72",
        "lft.rms.bias": "0.014",
        "lpv.rms.bias": "0.032",
        "lft.rms.gamma1": "2.73",
        "lpv.rms.gamma1": "2.82",
        "lft.rms.both": "1.71",
        "lpv.rms.both": "1.97",
        "lft_model.rms.bias": "0.027",
        "lpv_model.rms.bias": "0.027",
        "lft_model.rms.gamma1": "0.035",
        "lpv_model.rms.gamma1": "0.030",
        "lft_model.rms.both": "0.049",
        "lpv_model.rms.both": "0.049",
        "lft_test.rms.bias": "0.0009",
        "lpv_test.rms.bias": "0.0005",
        "lft_test.rms.gamma1": "0.0040",
        "lpv_test.rms.gamma1": "0.0041",
        "lft_test.rms.both": "0.0025",
        "lpv_test.rms.both": "0.0027",
        "lft_model.rms.onset1": "1.68",
        "lft_model.rms.onset2": "0.16",
        "lft_test.rms.onset1": "0.051",
        "lpv_test.rms.onset1": "0.050",
        "lft_test.rms.onset2": "0.27",
        "lpv_test.rms.onset2": "0.27",
        **{f"lft.gamma{i}.final": v for i, v in ((1, "0.853"), (3, "0.933"), (4, "0.932"))},
        **{f"lpv.gamma{i}.final": v for i, v in ((1, "0.926"), (2, "0.994"), (3, "0.987"), (4, "0.961"))},
        **{f"{n}.gamma{i}.final": v for n in ("lft_model", "lpv_model") for i, v in ((1, "0.5973"), (2, "0.7466"))},
        **{f"{n}.gamma{i}.final": v for n in ("lft_test", "lpv_test") for i, v in ((1, "0.5997"), (2, "0.7496"))},
        "lft_model.gamma.healthy": "0.028",
        "lft_model.gamma.faulty": "0.030",
        "lft_test.gamma.healthy": "0",
        "lpv_test.gamma.healthy": "0",
        "lft_test.gamma.faulty": "0.0004",
        "lpv_test.gamma.faulty": "0.0004",
    },
    "cdc2016-ex1": {
        "L1_k0.final": "3.56",
        "L1_k1.final": "0.0049",
        "L1_k10.final": "0.0008",
        "L2_k0.final": "6.28",
        "L2_k1.final": "0.012",
        "L2_k10.final": "0.0011",
        **{
            f"{n}.gamma{i}": w
            for n in ("L1_k1", "L1_k10", "L2_k1", "L2_k10")
            for i, w in ((1, "0.15"), (2, "0.88"), (3, "0.45"))
        },
    },
    "cdc2016-ex2": {
        "L1_k0.final": "5.77",
        "L1_k1.final": "0.0025",
        "L2_k0.final": "10.2",
        "L2_k1.final": "0.0089",
        "L1_k1.gamma2": "0.0050",
        "L2_k1.gamma2": "0.0050",
        **{f"{n}.gamma{i}": w for n in ("L1_k1", "L2_k1") for i, w in ((1, "0.76"), (3, "0.65"))},
    },
}


DOCUMENTS = {
    "three-tank-reconciliation": "docs/three-tank.md",
    "cdc2016-ex1": "docs/tac2024.md",
    "cdc2016-ex2": "docs/tac2024.md",
}


# The figures the scenario table (docs/scenarios.md, once the README's) states, in the scenario's row.
SCENARIO_TABLE = "docs/scenarios.md"
README_ROW = {
    "three-tank-reconciliation": (
        "lft_test.gamma.faulty",
        "lft_test.rms.both",
        "lpv_test.rms.both",
        "raw.rms.both",
        "lft_model.gamma.faulty",
        "lft_model.rms.both",
        "lft_model.gamma.healthy",
    )
}


def undocumented(name: str) -> list[str]:
    """The ``DOCUMENTED`` values of scenario ``name`` that its document does not print, and those of
    ``README_ROW`` that the scenario table's row of the scenario does not."""
    text = (ROOT / DOCUMENTS[name]).read_text()
    missing = [f"{key} = {printed}" for key, printed in DOCUMENTED[name].items() if printed not in text]
    table = (ROOT / SCENARIO_TABLE).read_text().splitlines()
    rows = [line for line in table if line.startswith(f"| `{name}` |")]
    row = rows[0] if rows else ""
    return missing + [
        f"{SCENARIO_TABLE}: {key} = {DOCUMENTED[name][key]}"
        for key in README_ROW.get(name, ())
        if DOCUMENTED[name][key] not in row
    ]


def tolerance(printed: str) -> float:
    """Half a unit of the printed value's last digit, plus 2 % of it."""
    decimals = len(printed.split(".")[1]) if "." in printed else 0
    return 0.5 * 10.0**-decimals + 0.02 * abs(float(printed))


def check(name: str, figures: dict[str, float]) -> list[str]:
    """The documented figures of scenario ``name`` that the run's ``figures`` do not reproduce."""
    return [
        f"{key}: documented {printed}, the run gives {figures[key]:.4g}"
        for key, printed in DOCUMENTED[name].items()
        if abs(figures[key] - float(printed)) > tolerance(printed)
    ]


def figures_of(name: str, path: str | Path) -> dict[str, float]:
    from cosim.analysis.series import load

    return three_tank_figures(path) if name == "three-tank-reconciliation" else reproduction_figures(load(path))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="+", choices=sorted(DOCUMENTED))
    parser.add_argument("--log", help="read this log of the (one) scenario instead of running it")
    args = parser.parse_args(argv)
    status = 0
    for name in args.names:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(args.log) if args.log else Path(folder) / f"{name}.mcap"
            if not args.log:
                from cosim import scenario
                from cosim.run import run

                result = run(scenario.load(name), path, 0, interface="virtual")
                if result.status != "completed":
                    raise RuntimeError(f"{name}: {result.status} {result.error}")
            figures = figures_of(name, path)
        for key, value in figures.items():
            printed = DOCUMENTED[name].get(key)
            print(f"{name} {key:28s} {value:10.4g}" + (f"   documented {printed}" if printed else ""))
        for problem in check(name, figures):
            print(f"{name}: {problem}")
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
