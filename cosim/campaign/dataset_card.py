"""A data set's card: what was generated, how, with which versions and seeds, its splits, its class
balance, its columns, its licence and the SHA-256 of every file: ``card.json`` (for programs) and
``README.md`` (a HuggingFace dataset card: its YAML header names each table's files per split, so
``datasets.load_dataset(DIR, "frames")`` finds them; ``load_dataset("parquet", data_dir=DIR/frames)``
finds them by their folders).

The digest is the SHA-256 of the list of every data file with its own SHA-256 (``path sha256``, one a
line, in path order): two data sets with the same digest hold the same bytes. The card itself is not
in it (it holds it).
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.campaign.dataset_road import AMBIENT, ATTACKS
from cosim.campaign.dataset_run import SPLITS, DatasetRun
from cosim.campaign.spec import Campaign
from cosim.log.metadata import versions


@dataclass
class Written:
    """What ``build_dataset`` wrote, for the card."""

    folder: Path
    campaigns: list[tuple[Campaign, Path]] = field(default_factory=list)
    runs: list[DatasetRun] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    balance: dict[str, dict[str, Counter[str]]] = field(default_factory=dict)
    plants: dict[str, dict[str, Any]] = field(default_factory=dict)
    road: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    """ROAD's folders (``<split>/ambient``, ``<split>/attacks``) → capture → its metadata."""
    warnings: list[str] = field(default_factory=list)


#: What each table's columns hold (docs/datasets.md says the same, with the forms side by side).
COLUMNS: dict[str, dict[str, str]] = {
    "frames": {
        "campaign, run": "the campaign and the run's index in it",
        "timestamp": "s, simulated time from the run's start at which the frame was on the bus (its delivery, on an "
        "arbitrated bus)",
        "tick, seq": "the runner's tick it was logged in; its position on the bus in the run",
        "id, extended, fd, brs, dlc": "arbitration id, 29-bit id, CAN FD, bit rate switch, data length code",
        "data": "payload bytes (the control frames' and SecOC's MACs zeroed: a run keys them anew)",
        "message, sender": "the DBC message of its id and the node that owns the id",
        "label": "1 for a frame an attack sent, 0 for a genuine one",
        "attack, fault": "the attack's kind and label (normal and empty for a genuine frame)",
    },
    "labels": {
        "campaign, run, tick, t": "the tick and its simulated time (s)",
        "label": "1 while a fault or an attack is active, else 0",
        "class": "the kinds active, joined with + (normal: none)",
        "category": "fault, attack, fault+attack or normal",
        "attack_class": "the taxonomy class of the attacks active: fabrication, suspension, masquerade, replay",
        "active, kinds, targets": "the labels, kinds and targets (sensors, actuators, messages, nodes) active",
        "frames_injected, frames_lost": "frames attacks sent in the tick; genuine frames bus faults kept off it",
    },
    "events": {
        "campaign, run, fault, kind": "one fault or attack of the run: its label and kind",
        "category, attack_class": "fault or attack; the attack's class in the taxonomy",
        "targets": "what it acts on",
        "start, end": "s, its window as the scenario sets it",
        "onset_tick, end_tick, ticks_active": "the first tick it was active, one past the last, and how many",
        "frames_injected, frames_lost": "frames it sent; genuine frames it kept off the bus",
    },
    "signals": {
        "campaign, run, tick, t": "the tick and its simulated time (s)",
        "reading.<sensor>": "the reading as the receivers took it: its one frame of the tick that came in time (NaN: "
        "none came, or two, which a receiver does not trust)",
        "command.<actuator>": "the command on the bus, the same way",
        "estimate.<estimator>.<state>": "an estimator's estimate (with --estimates)",
    },
    "truth": {
        "campaign, run, tick": "the tick",
        "state.<x>, sensor.<s>": "the plant's true state and true (fault-free, noise-free) sensors",
        "input.commanded.<a>, input.effective.<a>, input.disturbance.<d>": "inputs as commanded and as acting (after "
        "actuator faults), unknown inputs",
        "noise.<s>, fault.<s>, measured.<s>": "the noise and the faults' deviation added to each reading, and what "
        "was sent (NaN: not sent)",
        "effectiveness.<a>": "each actuator's effectiveness factor",
    },
}


def write_card(written: Written, fractions: Sequence[float], estimates: bool, license: str) -> dict[str, Any]:
    """Write ``card.json`` and ``README.md`` of the data set in ``written.folder``; returns the card."""
    folder = written.folder
    files = [
        {"path": path.relative_to(folder).as_posix(), "bytes": path.stat().st_size, "sha256": _sha256(path)}
        for path in sorted(p for p in folder.rglob("*") if p.is_file() and p.name not in ("card.json", "README.md"))
    ]
    listing = "".join(f"{f['path']} {f['sha256']}\n" for f in files)
    card = {
        "name": "+".join(campaign.spec.name for campaign, _ in written.campaigns),
        "generator": {"tool": "cosim dataset", "versions": versions(), "estimates": estimates},
        "license": license,
        "digest": hashlib.sha256(listing.encode()).hexdigest(),
        "splits": _splits(written, fractions),
        "campaigns": [
            _campaign(campaign, written.plants.get(campaign.spec.name, {})) for campaign, _ in written.campaigns
        ],
        "runs": [
            {
                "campaign": run.campaign,
                "run": run.spec.index,
                "replicate": run.spec.replicate,
                "seed": run.spec.seed,
                "split": run.split,
                "settings": dict(run.spec.columns),
            }
            for run in written.runs
        ],
        "skipped": written.skipped,
        "warnings": written.warnings,
        "road": _road(written),
        "balance": {
            split: {group: dict(sorted(counts.items())) for group, counts in written.balance[split].items()}
            for split in SPLITS
            if split in written.balance
        },
        "tables": _tables(written),
        "columns": COLUMNS,
        "files": files,
    }
    (folder / "card.json").write_text(json.dumps(card, indent=2) + "\n")
    (folder / "README.md").write_text(readme(card))
    return card


def _sha256(path: Path) -> str:
    sha = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def _splits(written: Written, fractions: Sequence[float]) -> dict[str, Any]:
    out: dict[str, Any] = {"by": "replicate", "fractions": list(fractions)}
    for split in SPLITS:
        runs = [run for run in written.runs if run.split == split]
        out[split] = {
            "runs": len(runs),
            "replicates": {c: sorted({r.spec.replicate for r in runs if r.campaign == c}) for c in _names(written)},
        }
    return out


def _road(written: Written) -> dict[str, Any]:
    """How ROAD's form holds the runs: how many captures in each folder, and which ones ROAD's rule
    does not label as the data set does (and why)."""
    captures = {kind: 0 for kind in (AMBIENT, ATTACKS)}
    inexact = []
    for where, metadata in sorted(written.road.items()):
        split, kind = where.split("/")
        captures[kind] += len(metadata)
        for name, capture in sorted(metadata.items()):
            if kind == ATTACKS and not capture["road_rule_exact"]:
                kinds = sorted({e["kind"] for e in capture["events"] if e["category"] == "attack"})
                inexact.append(
                    {"capture": f"road/{where}/{name}.log", "attacks": kinds, "why": capture["road_rule_note"]}
                )
    return {
        "rule": "a frame is an attack's when its time from the capture's first frame is in injection_interval (ends "
        "included), its id is injection_id (XXX: any) and its payload, 16 hex digits left-padded with zeros, matches "
        "injection_data_str (X: any)",
        "captures": captures,
        "exact": captures[ATTACKS] - len(inexact),
        "not_exact": inexact,
    }


def _names(written: Written) -> list[str]:
    return [campaign.spec.name for campaign, _ in written.campaigns]


def _campaign(campaign: Any, plant: dict[str, Any]) -> dict[str, Any]:
    spec = campaign.spec
    return {
        "name": spec.name,
        "description": spec.description,
        "scenario": spec.scenario,
        "seed": spec.seed,
        "replicates": spec.replicates,
        "runs": campaign.size,
        "campaign_toml": campaign.text,
        "scenario_sha256": hashlib.sha256(campaign.base.text.encode()).hexdigest(),
        **plant,
    }


def _tables(written: Written) -> dict[str, dict[str, str]]:
    """Each table (a HuggingFace config) and the files of each of its splits, as glob patterns."""
    present = {run.split for run in written.runs}
    tables: dict[str, dict[str, str]] = {}
    for table in ("frames", "labels", "events"):
        tables[table] = {split: f"{table}/{split}/*.parquet" for split in SPLITS if split in present}
    for name in _names(written):
        splits = {run.split for run in written.runs if run.campaign == name}
        for table in ("signals", "truth"):
            tables[f"{table}-{name}"] = {
                split: f"{table}/{name}/{split}/*.parquet" for split in SPLITS if split in splits
            }
    return tables


def readme(card: dict[str, Any]) -> str:
    """The data set's README.md: a HuggingFace dataset card (YAML header) and what it holds, in words."""
    lines = ["---", f"license: {card['license']}", f"pretty_name: {card['name']} (cosim)", "tags:"]
    lines += [f"- {tag}" for tag in ("can-bus", "intrusion-detection", "fault-diagnosis", "time-series", "cosim")]
    lines += ["task_categories:", "- tabular-classification", "configs:"]
    for table, splits in card["tables"].items():
        lines += [f"- config_name: {table}", *(["  default: true"] if table == "frames" else []), "  data_files:"]
        for split, pattern in splits.items():
            lines += [f"  - split: {split}", f'    path: "{pattern}"']
    lines += ["---", "", f"# {card['name']}", ""]
    lines += [
        "A labelled data set made by `cosim dataset` from the co-simulation campaigns below: every CAN frame of every",
        "run, the readings as the receivers took them, the plant's true state (the physical effect of every fault",
        "and attack) and the labels of every frame, tick and fault, from the records the testbed scores its schemes",
        "by. docs/datasets.md of cosim explains every field.",
        "",
        f"- digest (SHA-256 of every file's SHA-256): `{card['digest']}`",
        f"- generated by cosim {card['generator']['versions'].get('cosim', '?')} "
        f"({', '.join(f'{k} {v}' for k, v in card['generator']['versions'].items() if k != 'cosim')})",
        f"- licence: {card['license']}",
        f"- splits by replicate (seed), shares {card['splits']['fractions']}: "
        + ", ".join(f"{s} {card['splits'][s]['runs']} runs" for s in SPLITS),
        "",
        *(f"- **warning**: {warning}" for warning in card["warnings"]),
        "",
        *_road_section(card["road"]),
        "## Campaigns",
        "",
    ]
    for campaign in card["campaigns"]:
        lines += [
            f"- **{campaign['name']}** ({campaign['runs']} runs, campaign seed {campaign['seed']}, replicates "
            f"{campaign['replicates']}): {campaign['description']}"
        ]
    lines += [
        "",
        "## Class balance (ticks per class, frames per attack)",
        "",
        "| split | ticks | frames |",
        "|---|---|---|",
    ]
    for split, balance in card["balance"].items():
        ticks = ", ".join(f"{k} {v}" for k, v in balance["ticks"].items())
        frames = ", ".join(f"{k} {v}" for k, v in balance["frames"].items())
        lines.append(f"| {split} | {ticks} | {frames} |")
    lines += ["", "## Loading", "", "```python", "import pandas as pd", "from datasets import load_dataset", ""]
    lines += [
        'frames = load_dataset("parquet", data_dir="frames")           # splits from the folders',
        'labels = load_dataset(".", "labels")                          # a config of this card',
        'ticks = pd.read_parquet("labels/train")',
        "```",
        "",
    ]
    return "\n".join(lines)


def _road_section(road: dict[str, Any]) -> list[str]:
    """The README's words on ROAD's form: its layout, its rule, and where the rule is not exact."""
    counts = road["captures"]
    lines = [
        "## ROAD's form",
        "",
        f"`road/<split>/ambient/` holds the {_captures(counts[AMBIENT])} without an attack, `road/<split>/attacks/` "
        f"the {_captures(counts[ATTACKS])} with one, each folder with ROAD's `capture_metadata.json`. ROAD's rule "
        f"({road['rule']}) "
        f"gives exactly this data set's frame labels on {road['exact']} of the {counts[ATTACKS]} attack captures.",
        "",
    ]
    if road["not_exact"]:
        lines += ["Where it does not, take the labels of the Parquet (`frames/`) or HCRL (`hcrl/`) form:", ""]
        lines += [f"- `{c['capture']}` ({', '.join(c['attacks'])}): {c['why']}" for c in road["not_exact"]]
        lines.append("")
    return lines


def _captures(n: int) -> str:
    return f"{n} capture{'' if n == 1 else 's'}"
