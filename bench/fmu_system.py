"""A scenario as a system of FMI 2.0 FMUs (``cosim fmu --system``) run by the Open Simulation
Platform's libcosim, against the testbed's own run of it: the figure of docs/fmi.md and its numbers.

    .venv/bin/python bench/fmu_system.py [SCENARIO] [--duration S] [--figure FILE.png] [--json]

runs the scenario (default ``vessel-fault-T1``, 60 s: the thruster T1 fades from 20 s, in closed
loop) in-process, exports it with ``cosim fmu --system --fmi 2``, runs the SSP archive in libcosim
(libcosimpy) and compares every estimator's every output at every tick with what its node logged.
It prints the number of ticks and signals, at how many (tick, signal) pairs they differ and by how
much at most, and the wall times of each part; with ``--figure``, draws the OSP run over the
testbed's: the heading estimate, the first residual of the COFD family with its threshold, and
the largest difference over all signals per tick. Needs the ``fmi`` and ``plot`` extras and
libcosimpy.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.osp_systems
import tests  # noqa: F401, I001 (first: it pins NumPy's kernels, as in the test suite, before NumPy loads)
import numpy as np

from cosim import scenario
from cosim.run import fmu_ssp, run
from tests.osp_systems import logged_estimates, run_libcosim


def compare(name: str, duration: float, folder: Path) -> dict:
    """Run, export and run in libcosim; what each gives and costs."""
    loaded = scenario.apply(scenario.load(name), [("duration", duration)])
    s, log, system = loaded.scenario, folder / "run.mcap", folder / "system"
    started = time.perf_counter()
    assert run(loaded, log, interface="virtual").status == "completed"
    ran = time.perf_counter()
    fmu_ssp.export(loaded, system, 2)
    exported = time.perf_counter()
    logged = logged_estimates(log)
    steps = 2 if s.controller is not None else 1
    computed = run_libcosim(system / f"{s.name}.ssp", s.ticks, steps, {e: list(v) for e, v in logged.items()})
    simulated = time.perf_counter()
    gaps = {
        e: np.array(
            [
                np.where(np.isnan(v) & np.isnan(computed[e][g]), 0.0, np.abs(computed[e][g] - v))
                for g, v in signals.items()
            ]
        )
        for e, signals in logged.items()
    }
    return {
        "scenario": name,
        "ticks": s.ticks,
        "signals": sum(len(v) for v in logged.values()),
        "differing": int(sum(np.count_nonzero(g) for g in gaps.values())),
        "largest_difference": float(max(np.nanmax(g) for g in gaps.values())),
        "seconds": {"run": ran - started, "export": exported - ran, "libcosim": simulated - exported},
        "logged": logged,
        "computed": computed,
        "gaps": gaps,
        "sample_time": s.sample_time,
    }


def figure(found: dict, out: Path) -> None:
    """The OSP run (markers) over the testbed's (lines)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    name = next(iter(found["logged"]))
    logged, computed = found["logged"][name], found["computed"][name]
    t = (np.arange(found["ticks"]) + 1) * found["sample_time"]  # the answer to tick k, at t_k+1
    first = next(iter(logged))
    residual = next((g for g in logged if g.startswith("r1_")), first)
    threshold = next((g for g in logged if g == "thr" + residual[1:]), None)
    shown = [s for s in (next((g for g in logged if g == "xhat_psi"), first), residual)]
    fig, axes = plt.subplots(len(shown) + 1, 1, figsize=(7.0, 6.0), sharex=True)
    every = max(1, len(t) // 60)
    for ax, signal in zip(axes, shown):
        ax.plot(t, logged[signal], color="0.6", lw=2.2, label=f"testbed (cosim run): {name}.{signal}")
        ax.plot(
            t[::every], computed[signal][::every], "o", ms=3.5, mfc="none", color="#0072B2", label="OSP (libcosim, SSP)"
        )
        if signal == residual and threshold is not None:
            ax.plot(t, logged[threshold], "--", color="#D55E00", lw=1, label=f"threshold {threshold}")
        ax.legend(loc="best", fontsize=7)
        ax.set_ylabel(signal)
    largest = np.max(np.concatenate([g for g in found["gaps"].values()]), axis=0)
    axes[-1].plot(t, largest, color="#009E73")
    axes[-1].set_ylabel("max |OSP - testbed|")
    axes[-1].set_xlabel("t (s)")
    axes[-1].set_title(
        f"every output of every estimator ({found['signals']} signals, {found['ticks']} ticks): "
        f"{found['differing']} differences",
        fontsize=8,
    )
    fig.suptitle(f"{found['scenario']} as a system of FMI 2.0 FMUs in libcosim vs the testbed", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=130)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="vessel-fault-T1")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--figure", type=Path)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        found = compare(args.scenario, args.duration, Path(folder))
    if args.figure is not None:
        figure(found, args.figure)
    summary = {k: v for k, v in found.items() if k not in ("logged", "computed", "gaps")}
    if args.json:
        print(json.dumps(summary))
    else:
        seconds = ", ".join(f"{k} {v:.1f} s" for k, v in summary["seconds"].items())
        print(
            f"{summary['scenario']}: {summary['ticks']} ticks x {summary['signals']} signals, "
            f"{summary['differing']} differ (largest {summary['largest_difference']:g}); {seconds}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
