"""The isolability map of docs/vessel-fdi.md, drawn from the campaigns vessel-isolability and
vessel-nominal: per thruster and sea state, the smallest abrupt loss of effectiveness and the
slowest fade that the COFD scheme isolates within 10 s of the onset in every seed, and the false
alarms per fault-free hour per sea state.

    cosim campaign vessel-isolability --out runs/isolability
    cosim campaign vessel-nominal --out runs/nominal
    .venv/bin/python bench/vessel_isolability.py runs/isolability/results.parquet runs/nominal/results.parquet \\
        [--out docs/figures/vessel-isolability.png] [--json]

A loss counts as isolated when the run completed and ``cosim inspect`` found the fault isolated, to
the right thruster, at most 10 s after its onset. The boundary is the smallest loss (slowest fade)
from which on every larger loss (faster fade) of the grid is isolated in every seed ("≤" when that
is the grid's smallest). Needs the ``campaign`` and ``plot`` extras.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tomllib
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' linear ship model

from cosim import scenario
from cosim.campaign.leaderboard import read_table
from cosim.campaign.scores import poisson_rate
from estimators import create
from estimators.allocation import pseudo_inverse_allocation
from estimators.isolation import isolate
from tests.linear_vessel import X0, D, G, W, model

WITHIN = 10.0  # s after the onset
THRUSTERS = ("T1", "T2", "T3", "T4", "T5")


def parse_loss(label: str) -> tuple[str, float]:
    """("abrupt", 0.2) for "abrupt 20 %", ("fade", 0.05) for "fade 0.05 /s"."""
    abrupt = re.fullmatch(r"abrupt ([\d.]+) %", label)
    if abrupt:
        return "abrupt", float(abrupt.group(1)) / 100.0
    fade = re.fullmatch(r"fade ([\d.]+) /s", label)
    if fade:
        return "fade", float(fade.group(1))
    raise ValueError(f"loss label {label!r}: expected 'abrupt N %' or 'fade R /s'")


def columns(path: Path) -> tuple[dict[str, list], dict[str, str]]:
    """A campaign's results table as its columns by name, and the table's metadata."""
    table = read_table(path)
    return {name: [row[name] for row in table.rows] for name in table.columns}, table.metadata


def outcomes(table: dict[str, list]) -> tuple[list[str], dict[tuple[str, str, str, float], list[bool]]]:
    """The sea states in table order, and per (sea state, thruster, kind, size) whether each seed's
    fault was isolated within 10 s."""
    seas: list[str] = []
    cells: dict[tuple[str, str, str, float], list[bool]] = defaultdict(list)
    for i, sea in enumerate(table["sea_state"]):
        if sea not in seas:
            seas.append(sea)
        kind, size = parse_loss(table["loss"][i])
        delay = table["isolation_delay_s"][i]
        cells[(sea, table["thruster"][i], kind, size)].append(
            table["status"][i] == "completed"
            and bool(table["isolated"][i])
            and bool(table["isolation_correct"][i])
            and delay is not None
            and delay <= WITHIN
        )
    return seas, cells


def boundary(cells, sea: str, thruster: str, kind: str) -> float | None:
    """The smallest size (loss, or fade rate) from which on every larger one is isolated in every
    seed; None: not even the largest."""
    sizes = sorted(size for (s, t, k, size) in cells if (s, t, k) == (sea, thruster, kind))
    edge: float | None = None
    for size in reversed(sizes):
        if not all(cells[(sea, thruster, kind, size)]):
            break
        edge = size
    return edge


def predicted(campaign_text: str) -> dict[str, dict[str, float | None]]:
    """Per sea state and thruster, the smallest loss L whose steady signature L·s_i at the cruise
    commands u0 = G⁺Dν0 (s_i = −c_iᵀF⁻¹R W_{cols(j)} u0_{cols(j)}) crosses the thresholds of that
    sea so that the fault is isolated (None: not even a total loss): the map as the signatures
    against the thresholds predict it, waves and closed loop aside."""
    campaign = tomllib.loads(campaign_text)
    base = scenario.load(campaign["scenario"]).scenario.estimators[0].params
    axis = next(a for a in campaign["axes"] if a.get("name") == "sea_state")
    u0 = pseudo_inverse_allocation(G, D @ X0[3:])
    groups = [(0, 1), (2, 3), (4, 5), (6,), (7,)]
    out: dict[str, dict[str, float | None]] = {}
    for label, (_, current, wave_force, wave_moment) in zip(axis["labels"], axis["values"]):
        declared = {**base, "current": current, "wave_force": wave_force, "wave_moment": wave_moment}
        declared.pop("rotating_frame", None)  # the linear model (23) has no rotating frame
        estimator = create("cofd", model(), declared, 0.1)
        thresholds = estimator.test.centred
        out[label] = {}
        for j, (thruster, group) in enumerate(zip(THRUSTERS, groups)):
            cols = list(group)
            steady = np.array([np.linalg.solve(o.F, o.R @ W[:, cols] @ u0[cols])[:3] for o in estimator.observers])
            crossings = sorted((thresholds / np.maximum(np.abs(steady), 1e-300)).ravel())
            found = [
                L
                for L in crossings
                if L <= 1.0
                and isolate(np.abs(L * (1 + 1e-9) * steady) > thresholds, estimator.signatures, estimator.hypotheses)
                == (j,)
            ]
            out[label][thruster] = min(found) if found else None
    return out


def false_alarms(table: dict[str, list]) -> dict[str, dict[str, float]]:
    """Per sea state: false alarms, fault-free hours, the rate per hour and its 95 % interval."""
    totals: dict[str, list[float]] = {}
    for i, sea in enumerate(table["sea_state"]):
        if table["status"][i] != "completed":
            continue
        alarms, seconds = totals.setdefault(sea, [0.0, 0.0])
        totals[sea] = [alarms + table["false_alarms"][i], seconds + table["fault_free_time_s"][i]]
    out = {}
    for sea, (alarms, seconds) in totals.items():
        hours = seconds / 3600.0
        low, high = poisson_rate(int(alarms), hours) or (0.0, float("inf"))
        out[sea] = {"false_alarms": int(alarms), "hours": hours, "rate_per_hour": alarms / hours, "high": high}
    return out


def figures(isolability: Path, nominal: Path) -> dict:
    """Every number of the map, as one JSON-able object."""
    table, metadata = columns(isolability)
    seas, cells = outcomes(table)
    result: dict = {"sea_states": seas, "abrupt": {}, "fade": {}, "misses_at_or_above_50": []}
    for thruster in THRUSTERS:
        for kind in ("abrupt", "fade"):
            result[kind][thruster] = {}
            for sea in seas:
                result[kind][thruster][sea] = boundary(cells, sea, thruster, kind)
        for sea in seas:
            for (s, t, k, size), isolated in cells.items():
                if (s, t, k) == (sea, thruster, "abrupt") and size >= 0.5 and not all(isolated):
                    result["misses_at_or_above_50"].append([sea, thruster, size, isolated.count(False)])
    result["seeds"] = min(len(v) for v in cells.values())
    result["grid"] = {kind: sorted({size for (_, _, k, size) in cells if k == kind}) for kind in ("abrupt", "fade")}
    pre = [table["false_alarms"][i] for i in range(len(table["run"])) if table["status"][i] == "completed"]
    result["false_alarms_before_onsets"] = int(sum(pre))
    result["hours_before_onsets"] = sum(table["fault_free_time_s"]) / 3600.0
    nominal_table, _ = columns(nominal)
    result["false_alarms"] = false_alarms(nominal_table)
    result["predicted"] = predicted(metadata["cosim.campaign"])
    return result


def draw_edges(ax, result: dict, kind: str, scale: float, label: str, note: str) -> None:
    """A panel of the smallest fault each thruster's isolation catches (``kind``: abrupt or fade) per sea
    state, below the grid's smallest shaded, with the prediction of the steady signature for losses."""
    seas = result["sea_states"]
    x = np.arange(len(seas))
    floor = result["grid"][kind][0] * scale if result["grid"][kind] else 0.0  # a grid may lack fades
    ax.axhspan(floor * 1e-3, floor, color="0.92", zorder=0)
    for number, thruster in enumerate(THRUSTERS):
        at = x + 0.06 * (number - 2)  # side by side where thrusters share a value
        shown = np.array([e * scale if e is not None else np.nan for e in (result[kind][thruster][s] for s in seas)])
        ax.semilogy(at, shown, color=f"C{number}", label=thruster)
        below = shown <= floor
        ax.semilogy(at[~below], shown[~below], "o", color=f"C{number}")
        ax.semilogy(at[below], shown[below], "v", color=f"C{number}")
        if kind == "abrupt":
            guess = [result["predicted"][s][thruster] for s in seas]
            ax.semilogy(x, [g * scale if g else np.nan for g in guess], color=f"C{number}", ls=":", lw=1)
    ax.plot([], [], "v", color="0.4", label="▼ at the grid's smallest: lies lower")
    if kind == "abrupt":
        ax.plot([], [], color="k", ls=":", lw=1, label="steady signature at u0 = threshold")
        ax.axhline(50.0, color="k", lw=0.8, ls="--", label="50 %: required in every sea")
        ax.set_ylim(3e-3, 150)
    else:
        ax.set_ylim(1e-3, 0.5)
    ax.set_xticks(x, seas)
    ax.set_xlabel("sea state: |b| ≤ current + waves")
    ax.set_ylabel(label)
    ax.set_title(note, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7.5, loc="lower right" if kind == "abrupt" else "upper left")


def draw_false_alarms(ax, result: dict) -> None:
    """The panel of false alarms per fault-free hour per sea state, with its 95 % upper bound."""
    seas = result["sea_states"]
    x = np.arange(len(seas))
    alarms = result["false_alarms"]
    rates = [alarms[sea]["rate_per_hour"] for sea in seas]
    highs = [alarms[sea]["high"] - alarms[sea]["rate_per_hour"] for sea in seas]
    ax.bar(list(x), rates, yerr=[[0.0] * len(seas), highs], color="C7", capsize=4)
    for i, sea in enumerate(seas):
        ax.annotate(
            f"{alarms[sea]['false_alarms']} in {alarms[sea]['hours']:.2g} h",
            (i, 0.0),
            textcoords="offset points",
            xytext=(0, 4),
            ha="center",
            fontsize=8,
        )
    ax.set_xticks(x, seas)
    ax.set_xlabel("sea state: |b| ≤ current + waves")
    ax.set_ylabel("false alarms per fault-free hour")
    ax.set_title("bars: rate; whiskers: 95 % upper bound (exact Poisson)", fontsize=9)


def draw(result: dict, out: Path) -> None:
    """The figure: the abrupt losses and the fades each isolated, and the false alarms, per sea state."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14.5, 4.6), constrained_layout=True)
    panels = (
        ("abrupt", 100.0, "smallest abrupt loss isolated ≤ 10 s [%]", "abrupt loss at 20 s; lower is better"),
        ("fade", 1.0, "slowest fade to 0 isolated ≤ 10 s [1/s]", "δ = e^(−rate (t − 20 s)); lower is better"),
    )
    for ax, (kind, scale, label, note) in zip(axes, panels):
        draw_edges(ax, result, kind, scale, label, note)
    draw_false_alarms(axes[2], result)
    fig.suptitle(f"COFD isolability on the MJCF ship ({result['seeds']} seeds per point; ε = 300 N)", fontsize=11)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def report(result: dict) -> None:
    """The map as the markdown tables of docs/vessel-fdi.md."""
    seas = result["sea_states"]

    def cell(edge: float | None, scale: float, unit: str, smallest: float) -> str:
        if edge is None:
            return "—"
        return f"{'≤ ' if edge <= smallest else ''}{edge * scale:g}{unit}"

    for kind, scale, unit, title in (
        ("abrupt", 100.0, " %", "smallest abrupt loss isolated within 10 s in every seed"),
        ("fade", 1.0, " /s", "slowest fade to 0 isolated within 10 s in every seed"),
    ):
        if not result["grid"][kind]:
            continue
        smallest = result["grid"][kind][0]  # isolated there: the boundary may lie lower
        print(f"\n{title}\n\n| thruster | " + " | ".join(seas) + " |\n|---|" + "---|" * len(seas))
        for thruster in THRUSTERS:
            row = [cell(result[kind][thruster][sea], scale, unit, smallest) for sea in seas]
            print(f"| {thruster} | " + " | ".join(row) + " |")
    print("\npredicted: the steady signature at u0 = G⁺Dν0 crosses the thresholds\n")
    print("| thruster | " + " | ".join(seas) + " |\n|---|" + "---|" * len(seas))
    for thruster in THRUSTERS:
        row = [result["predicted"][sea][thruster] for sea in seas]
        print(f"| {thruster} | " + " | ".join("—" if L is None else f"{100 * L:.2g} %" for L in row) + " |")
    print("\nfalse alarms per fault-free hour (vessel-nominal)\n\n| sea state | alarms | hours | rate [95 % upper] |")
    print("|---|---|---|---|")
    for sea in seas:
        a = result["false_alarms"][sea]
        print(f"| {sea} | {a['false_alarms']} | {a['hours']:.2f} | {a['rate_per_hour']:.3g} [{a['high']:.3g}] |")
    print(
        f"\nbefore the onsets of vessel-isolability: {result['false_alarms_before_onsets']} false alarms in "
        f"{result['hours_before_onsets']:.1f} h; abrupt losses ≥ 50 % missed: "
        f"{result['misses_at_or_above_50'] or 'none'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("isolability", type=Path, help="results.parquet of the vessel-isolability campaign")
    parser.add_argument("nominal", type=Path, help="results.parquet of the vessel-nominal campaign")
    parser.add_argument("--out", type=Path, default=Path("docs/figures/vessel-isolability.png"))
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = parser.parse_args()
    result = figures(args.isolability, args.nominal)
    draw(result, args.out)
    if args.json:
        print(json.dumps(result))
    else:
        report(result)
        print(f"\nfigure: {args.out}")


if __name__ == "__main__":
    main()
