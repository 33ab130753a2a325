"""Cost of one MuJoCo step of the vessel (µs) with its body-frame damping installed per call (the
plant's mechanism) and as a process-wide callback (how the plant did it before), measured in the
same run; and the masses scenario's run after a vessel run, in this process, against its run in a
fresh process.

Vessel workload: ``--ticks`` ticks of 0.1 s (10 RK4 substeps of 10 ms each) from the cruise
keyframe, with a yaw moment on the cruise thrust and an environmental disturbance (the heading
turns, so the damping's rotation matters). A figure is the tick time divided by the substeps (the
tick's closing ``mj_forward`` included), best of ``--repeat``, the variants interleaved:

- ``scoped``: ``Plant.step``, the damping installed as ``mjcb_passive`` around the tick's calls;
- ``global``: the callback installed once for the process (``mjcf._body_damping.passive``, the old
  code), the same ``mj_step`` + ``mj_forward`` per tick;
- ``bare``: MuJoCo alone, without ΔD (wrong physics; the floor of any mechanism);
- ``held``: ΔD computed once per tick from the state and applied as ``qfrc_applied`` over the
  tick's substeps (no callback; changes the physics: its distance from ``scoped`` is reported).

Masses: ``masses-bias`` (``--masses-duration`` s) on the in-process bus; the figure is the run's
tick loop (``RunResult.loop_time``), best of ``--repeat``, interleaved. ``fresh``: in a new Python
process that never loaded the vessel (two runs in each, the first included; the best of the first
runs alone is reported too); ``after vessel``: in this process, each right after a
``vessel-fault-T1`` run of ``--vessel-duration`` s; ``old global``: the same with the old
process-wide callback installed, as loading the vessel used to leave it. The ratios are against
``fresh``.

The physics of a batch's runs (``cosim.plant.physics_batch``): µs per run and tick of ``--runs``
masses (0.01 s ticks) and three-tank (1 s ticks) plants from other initial states, each tick's
``state``, ``sensors`` and ``step`` of all of them, stepped one by one (``PlantsEach``, what the
runs do alone) and in one ``mujoco.batch.Batch`` call (``PhysicsBatch``), interleaved, best of
``--repeat``; ``--ticks`` // 4 ticks of the masses, // 40 of the three tanks. The vessel (a Python
callback) steps one by one in a batch too.

Usage: python bench/plant_step.py [--json] [--ticks N] [--repeat R] [--runs K] [--masses-duration S]
       [--vessel-duration S]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import mjcf  # noqa: E402
from bench.common import bench_parser  # noqa: E402
from cosim import scenario  # noqa: E402
from cosim.plant.physics import Plant  # noqa: E402
from cosim.plant.physics_batch import PhysicsBatch, PlantsEach  # noqa: E402
from cosim.run import run  # noqa: E402
from mjcf import _body_damping, vessel  # noqa: E402

VARIANTS = ("scoped", "global", "bare", "held")


def vessel_inputs(plant: Plant, ticks: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Cruise thrust plus 2e5 N on the bow azimuth's sway component, and b(t) of seed 0."""
    cruise = plant.data.ctrl[plant.actuator_index].copy()
    cruise[5] += 2e5
    b = vessel.EnvironmentDisturbance.random(0)
    return [(cruise, b(k * plant.sample_time)) for k in range(ticks)]


class HeldForce:
    """ΔD's generalized force at a state, computed once (what the callback adds at that state)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model, self.scratch = model, mujoco.MjData(model)
        force = _body_damping.forces(model)
        assert force is not None
        self.force = force

    def __call__(self, data: mujoco.MjData) -> np.ndarray:
        s = self.scratch
        s.qpos[:], s.qvel[:], s.qfrc_passive[:] = data.qpos, data.qvel, 0.0
        self.force(self.model, s)
        return s.qfrc_passive


def vessel_run(variant: str, plant: Plant, inputs: list) -> tuple[float, np.ndarray]:
    """Seconds for the ticks, and the states after each tick."""
    plant.reset()
    m, d = plant.model, plant.data
    states = np.empty((len(inputs), m.nq + m.nv))
    nstep, held = plant.substeps, HeldForce(m)
    outer = mujoco.get_mjcb_passive()
    if variant == "global":
        mujoco.set_mjcb_passive(_body_damping.passive)
    try:
        start = time.perf_counter()
        for k, (u, b) in enumerate(inputs):
            if variant == "scoped":
                plant.step(u, b)
            else:
                d.ctrl[:8], d.ctrl[8:] = u, b
                if variant == "held":
                    d.qfrc_applied[:] = held(d)
                mujoco.mj_step(m, d, nstep=nstep)
                mujoco.mj_forward(m, d)
            states[k, : m.nq], states[k, m.nq :] = d.qpos, d.qvel
        elapsed = time.perf_counter() - start
    finally:
        mujoco.set_mjcb_passive(outer)
        d.qfrc_applied[:] = 0.0
    return elapsed, states


def vessel_figures(ticks: int, repeat: int) -> dict[str, float]:
    plant = Plant(mjcf.get("vessel"), 0.1)
    inputs = vessel_inputs(plant, ticks)
    best = dict.fromkeys(VARIANTS, np.inf)
    states: dict[str, np.ndarray] = {}
    for _ in range(repeat):
        for variant in VARIANTS:
            elapsed, states[variant] = vessel_run(variant, plant, inputs)
            best[variant] = min(best[variant], elapsed)
    per_step = {v: best[v] / (ticks * plant.substeps) * 1e6 for v in VARIANTS}
    ref = states["global"]
    return {
        "vessel_step_us": per_step["scoped"],
        "vessel_step_global_us": per_step["global"],
        "vessel_step_bare_us": per_step["bare"],
        "vessel_step_held_us": per_step["held"],
        "vessel_step_ratio": per_step["scoped"] / per_step["global"],
        "vessel_max_abs_diff": float(np.max(np.abs(states["scoped"] - ref))),
        "vessel_held_max_abs_diff": float(np.max(np.abs(states["held"] - ref))),
        "vessel_heading_range_rad": float(np.ptp(ref[:, 2])),
        "vessel_ticks": ticks,
        "vessel_substeps": plant.substeps,
    }


def batch_figures(ticks: int, repeat: int, runs: int) -> dict[str, float]:
    """µs per run and tick of the masses' and the three tanks' physics, one by one and batched."""
    figures: dict[str, float] = {}
    for name, sample_time, n in (("masses", 0.01, max(1, ticks // 4)), ("three_tank", 1.0, max(1, ticks // 40))):
        best = {PlantsEach: np.inf, PhysicsBatch: np.inf}
        for _ in range(repeat):
            for kind in best:
                plants = [Plant(mjcf.get(name), sample_time) for _ in range(runs)]
                for i, plant in enumerate(plants):
                    plant.set_state(plant.state() * (1.0 + 0.01 * i))
                physics = kind(plants)
                rows = np.arange(runs)
                u = np.stack([plant.data.ctrl[plant.actuator_index] for plant in plants])
                d = np.zeros((runs, len(plants[0].disturbance_index)))
                start = time.perf_counter()
                for _ in range(n):
                    physics.state(), physics.sensors()
                    physics.step(rows, u, d)
                best[kind] = min(best[kind], (time.perf_counter() - start) / (n * runs) * 1e6)
        figures[f"{name}_each_us"], figures[f"{name}_batched_us"] = best[PlantsEach], best[PhysicsBatch]
        figures[f"{name}_batched_ratio"] = best[PhysicsBatch] / best[PlantsEach]
    figures["batch_runs"] = runs
    return figures


def shortened(name: str, duration: float) -> scenario.LoadedScenario:
    """A built-in scenario with another duration (everything else as the file says)."""
    loaded = scenario.load(name)
    text = re.sub(r"(?m)^duration\s*=.*$", f"duration = {duration!r}", loaded.text, count=1)
    return scenario.LoadedScenario(scenario.parse(text, loaded.source), loaded.source, text)


def loop_time(name: str, duration: float) -> float:
    with tempfile.TemporaryDirectory() as folder:
        result = run(shortened(name, duration), Path(folder) / "run.mcap", 0, interface="virtual")
    if result.status != "completed":
        raise RuntimeError(f"{name}: {result.status} {result.error}")
    return result.loop_time


def masses_fresh(duration: float, runs: int) -> list[float]:
    """Loop times of ``runs`` masses-bias runs in a new process (the first, that process's first run)."""
    child = subprocess.run(
        [sys.executable, __file__, "--child-masses", str(duration), "--repeat", str(runs)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(child.stdout)


def masses_figures(duration: float, vessel_duration: float, repeat: int) -> dict[str, float]:
    """The three masses figures, interleaved: a new process per repeat (two runs there), then the
    runs after a vessel run here, with and without the old process-wide callback."""
    fresh: list[float] = []
    first: list[float] = []
    after: list[float] = []
    old: list[float] = []
    for _ in range(repeat):
        runs = masses_fresh(duration, 2)
        fresh += runs
        first.append(runs[0])
        loop_time("vessel-fault-T1", vessel_duration)
        after.append(loop_time("masses-bias", duration))
        outer = mujoco.get_mjcb_passive()
        mujoco.set_mjcb_passive(_body_damping.passive)  # what loading the vessel used to leave installed
        try:
            loop_time("vessel-fault-T1", vessel_duration)
            old.append(loop_time("masses-bias", duration))
        finally:
            mujoco.set_mjcb_passive(outer)
    best = min(fresh)
    return {
        "masses_fresh_s": best,
        "masses_fresh_first_s": min(first),
        "masses_after_vessel_s": min(after),
        "masses_after_vessel_ratio": min(after) / best,
        "masses_old_global_s": min(old),
        "masses_old_global_ratio": min(old) / best,
        "masses_ticks": round(duration / 0.01),
    }


def main() -> int:
    parser = bench_parser(__doc__, repeat=5)
    parser.add_argument("--ticks", type=int, default=2000, help="vessel ticks per timing (0.1 s each)")
    parser.add_argument("--masses-duration", type=float, default=30.0, help="s of masses-bias (its full 30 s)")
    parser.add_argument("--vessel-duration", type=float, default=30.0, help="s of the vessel run before it")
    parser.add_argument("--runs", type=int, default=16, help="plants in the physics batch")
    parser.add_argument("--child-masses", type=float, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_masses is not None:  # the fresh process of masses_fresh
        print(json.dumps([loop_time("masses-bias", args.child_masses) for _ in range(args.repeat)]))
        return 0
    figures = vessel_figures(args.ticks, args.repeat)
    figures |= masses_figures(args.masses_duration, args.vessel_duration, args.repeat)
    figures |= batch_figures(args.ticks, args.repeat, args.runs)
    if args.json:
        print(json.dumps({k: round(v, 6) if isinstance(v, float) else v for k, v in figures.items()}))
        return 0
    f = figures
    print(f"vessel: µs per mj_step (RK4, {f['vessel_substeps']} per 0.1 s tick), best of {args.repeat}")
    print(f"{'mechanism':<44}{'µs/step':>10}{'× global':>10}{'max |Δx|':>12}")
    rows = [
        ("scoped: installed per call (the plant)", "vessel_step_us", "vessel_max_abs_diff"),
        ("global: installed for the process (before)", "vessel_step_global_us", None),
        ("bare: MuJoCo alone, no ΔD (wrong physics)", "vessel_step_bare_us", None),
        ("held: ΔD as qfrc_applied once per tick", "vessel_step_held_us", "vessel_held_max_abs_diff"),
    ]
    for label, key, diff in rows:
        shown = f"{f[diff]:>12.3g}" if diff else f"{'':>12}"
        print(f"{label:<44}{f[key]:>10.2f}{f[key] / f['vessel_step_global_us']:>10.2f}{shown}")
    ticks, heading = f["vessel_ticks"], f["vessel_heading_range_rad"]
    print(f"(max |Δx|: against global, over {ticks} ticks; the heading ranges over {heading:.2f} rad)")
    print(f"\nmasses-bias, {f['masses_ticks']} ticks: tick loop (s), best of {args.repeat}{'× fresh':>19}")
    print(
        f"{'fresh process':<44}{f['masses_fresh_s']:>10.3f}{'':>10}  (first runs only: {f['masses_fresh_first_s']:.3f})"
    )
    for label, key in (
        ("after a vessel run, this process", "after_vessel"),
        ("same, old global callback", "old_global"),
    ):
        print(f"{label:<44}{f[f'masses_{key}_s']:>10.3f}{f[f'masses_{key}_ratio']:>10.3f}")
    print(f"\nthe physics of {f['batch_runs']} runs: µs per run and tick, best of {args.repeat}")
    print(f"{'plant':<20}{'one by one':>12}{'one Batch':>12}{'ratio':>10}")
    for name in ("masses", "three_tank"):
        print(
            f"{name:<20}{f[f'{name}_each_us']:>12.1f}{f[f'{name}_batched_us']:>12.1f}{f[f'{name}_batched_ratio']:>10.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
