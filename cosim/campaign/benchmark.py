"""The standing benchmark: a versioned suite of campaigns in two tracks, run into one result bundle.

The suite (``scenarios/benchmark/suite.toml``) names its cases: a built-in campaign each, in the
*faults* track (sensor and actuator faults, fault-free hours) or the *attacks* track (attacks on the
bus), with a quick selection of its seeds and axis values for ``--quick``. ``cosim benchmark`` runs
every case on the campaign engine, with the schemes the user adds (``--estimator NAME=KIND``, a
built-in kind or a plugin's) beside each case's own, and writes a bundle:

    DIR/results.parquet   every case's table, with its ``case`` and ``track`` columns
    DIR/bundle.json       the suite's name, version and digest, quick or full, the schemes, versions
    DIR/cases/<case>/     each case's campaign folder (its parts, for --resume)

The digest is the SHA-256 of every run the suite makes (its seed, settings and base scenario text,
case by case, before the user's schemes): it changes whenever any run changes, and bundles merge
(``cosim leaderboard DIR DIR ...``) only when their digests are the same.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError

import scenarios
from cosim.campaign.coordinator import CampaignProgress, CampaignResult, check_batch, require_extras, run_campaigns
from cosim.campaign.engine import open_engine
from cosim.campaign.spec import Campaign, load_campaign
from cosim.errors import CosimError, ScenarioError
from cosim.log.metadata import versions
from cosim.scenario import apply
from cosim.scenario.tables import Strict, loads_toml, problem_message, problem_path

SUITE = Path(scenarios.__file__).resolve().parent / "benchmark" / "suite.toml"
BUNDLE = "bundle.json"
TRACKS = ("faults", "attacks")


class QuickSpec(Strict):
    seeds: int | None = Field(default=None, ge=1)
    only: dict[str, list[str]] = {}


class CaseSpec(Strict):
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9-]{0,63}$")
    track: Literal["faults", "attacks"]
    campaign: str
    quick: QuickSpec = QuickSpec()


class SuiteSpec(Strict):
    name: str
    version: int = Field(ge=1)
    description: str = ""
    cases: list[CaseSpec] = Field(min_length=1)


@dataclass(frozen=True)
class Scheme:
    """An estimator or diagnosis scheme the user adds to every case: ``kind`` a built-in kind or a
    plugin's (``package.module:Class`` or an entry point), ``params`` its parameters."""

    name: str
    kind: str
    params: dict[str, Any]

    def table(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "params": self.params}


def load_suite(path: str | Path = SUITE) -> SuiteSpec:
    """The suite file, validated (one line naming the field)."""
    path = Path(path)
    try:
        data = loads_toml(path.read_text())
    except OSError as error:
        raise CosimError(f"{path}: cannot read the suite ({error.strerror})") from None
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{path}: invalid TOML: {error}") from None
    try:
        return SuiteSpec.model_validate(data)
    except ValidationError as error:
        problems = [f"{problem_path(e['loc'], data)}: {problem_message(dict(e))}" for e in error.errors()]
        raise ScenarioError(f"{path}: " + "; ".join(problems)) from None


def case_campaign(case: CaseSpec, quick: bool, schemes: Sequence[Scheme] = ()) -> Campaign:
    """A case's campaign (its quick selection with ``quick``), with the user's schemes appended to
    every run's estimators."""
    seeds, only = (case.quick.seeds, case.quick.only) if quick else (None, {})
    campaign = load_campaign(case.campaign, seeds=seeds, only=only)
    if not schemes:
        return campaign
    present = apply(campaign.base, list(campaign.spec.set.items())).scenario.estimators
    taken = {e.name for e in present} & {s.name for s in schemes}
    if taken:
        raise CosimError(f"case {case.name}: its estimators already have the names {', '.join(sorted(taken))}")
    added = [(f"estimators[{len(present) + i}]", s.table()) for i, s in enumerate(schemes)]
    return load_campaign(case.campaign, seeds=seeds, only=only, settings=added)


def suite_digest(suite: SuiteSpec, quick: bool) -> str:
    """SHA-256 of every run of the suite (quick or full), case by case: seed, settings, base scenario."""
    sha = hashlib.sha256(f"{suite.name}/{suite.version}/{'quick' if quick else 'full'}".encode())
    for case in suite.cases:
        sha.update(f"\0case {case.name} {case.track}\0".encode())
        for run in case_campaign(case, quick).runs():
            sha.update(json.dumps([run.index, run.seed, run.settings, run.scenario_text], default=str).encode())
    return sha.hexdigest()


def run_benchmark(
    out: str | Path,
    *,
    quick: bool = False,
    schemes: Sequence[Scheme] = (),
    suite_path: str | Path = SUITE,
    engine: str = "dask",
    workers: int | None = None,
    address: str | None = None,
    resume: bool = False,
    on_case: Callable[[CaseSpec, Campaign], None] | None = None,
    on_progress: Callable[[CaseSpec, CampaignProgress], None] | None = None,
    on_case_done: Callable[[CaseSpec, CampaignResult], None] | None = None,
    batch: int | None = None,
) -> dict[str, Any]:
    """Run every case of the suite into the bundle ``out``; returns the bundle's record. The cases
    share one engine and follow each other without a gap (``run_campaigns``): a case's last batches
    run beside the next case's first, so ``on_case`` (a case starts) may come before the previous
    case's last ``on_progress`` and its ``on_case_done``."""
    suite = load_suite(suite_path)
    folder = Path(out).resolve()
    if folder.exists() and any(folder.iterdir()) and not resume:
        raise CosimError(f"{folder} is not empty: choose a new folder, or pass --resume to finish this bundle")
    campaigns = [(case, case_campaign(case, quick, schemes)) for case in suite.cases]  # every case checked first
    require_extras(engine)
    check_batch(batch)
    cases = [case for case, _ in campaigns]
    members = [
        (c, folder / "cases" / case.name, resume and (folder / "cases" / case.name).exists()) for case, c in campaigns
    ]
    with open_engine(engine, workers, address) as pool:  # one cluster for every case: it starts once
        found = run_campaigns(
            members,
            pool,
            batch=batch,
            on_begin=None if on_case is None else lambda i: on_case(*campaigns[i]),
            on_progress=None if on_progress is None else lambda i, p: on_progress(cases[i], p),
            on_done=None if on_case_done is None else lambda i, r: on_case_done(cases[i], r),
        )
    results = {case.name: result for case, result in zip(cases, found)}
    bundle = {
        "suite": suite.name,
        "version": suite.version,
        "quick": quick,
        "digest": suite_digest(suite, quick),
        "cases": {case.name: {"track": case.track, "campaign": case.campaign} for case in suite.cases},
        "schemes": [scheme.table() for scheme in schemes],
        "runs": sum(r.runs for r in results.values()),
        "failed": sum(r.failed for r in results.values()),
        "versions": versions(),
    }
    bundle["units"] = {name: _rms_unit(result.path) for name, result in results.items()}
    bundle["failures"] = {
        name: why for name, result in results.items() if result.failed and (why := failures(result.path)) is not None
    }
    merge_tables(
        [(case.name, case.track, results[case.name].path) for case in suite.cases], folder / "results.parquet", bundle
    )
    (folder / BUNDLE).write_text(json.dumps(bundle, indent=2) + "\n")
    return bundle


def failures(path: Path) -> dict[str, Any] | None:
    """A campaign table's failed runs: how many of how many, and why in the words of the most
    frequent error (and how many other errors); None where every run completed."""
    import pyarrow.parquet as pq

    rows = pq.read_table(path, columns=["run", "status", "error"]).to_pylist()
    runs = {row["run"] for row in rows}
    errors = {row["run"]: row["error"] or row["status"] for row in rows if row["status"] != "completed"}
    if not errors:
        return None
    counts = Counter(errors.values())
    why, _ = counts.most_common(1)[0]
    return {"failed": len(errors), "runs": len(runs), "why": why, "other_errors": len(counts) - 1}


def _rms_unit(path: Path) -> str:
    import pyarrow.parquet as pq

    field = pq.read_schema(path).field("rms_post_fault")
    return (field.metadata or {}).get(b"unit", b"").decode()


def merge_tables(parts: Sequence[tuple[str, str, Path]], target: Path, bundle: dict[str, Any]) -> Path:
    """One table of the cases' tables, each row with its ``case`` and ``track`` (columns a case
    lacks are null); the bundle's record in its metadata."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    tables = []
    for name, track, path in parts:
        table = pq.read_table(path)
        rows = table.num_rows
        table = table.add_column(0, pa.field("track", pa.string()), pa.array([track] * rows, pa.string()))
        table = table.add_column(0, pa.field("case", pa.string()), pa.array([name] * rows, pa.string()))
        tables.append(table)
    merged = pa.concat_tables(tables, promote_options="permissive")
    metadata = dict(tables[0].schema.metadata or {}) | {b"cosim.benchmark": json.dumps(bundle).encode()}
    metadata.pop(b"cosim.campaign", None)
    metadata[b"cosim.campaign.name"] = f"{bundle['suite']} v{bundle['version']}".encode()
    pq.write_table(merged.replace_schema_metadata(metadata), target)
    return target


def read_bundles(paths: Sequence[str | Path]) -> tuple[dict[str, Any], list[Path]]:
    """The bundles' common record and their tables; a bundle of another suite, version or
    selection (its digest) is refused in one line."""
    records: list[dict[str, Any]] = []
    tables: list[Path] = []
    for path in paths:
        folder = Path(path)
        try:
            record = json.loads((folder / BUNDLE).read_text())
        except FileNotFoundError:
            raise CosimError(f"{folder}: no {BUNDLE}: not a bundle of cosim benchmark") from None
        except (OSError, json.JSONDecodeError) as error:
            raise CosimError(f"{folder / BUNDLE}: not a readable bundle record ({error})") from None
        if records and (record.get("digest") != records[0].get("digest")):
            first = records[0]
            raise CosimError(
                f"{folder}: suite {record.get('suite')} v{record.get('version')} "
                f"({'quick' if record.get('quick') else 'full'}, digest {str(record.get('digest'))[:12]}) is not "
                f"{paths[0]}'s ({first.get('suite')} v{first.get('version')}, "
                f"{'quick' if first.get('quick') else 'full'}, digest {str(first.get('digest'))[:12]}): "
                f"results of different suites are not comparable; run the same suite again"
            )
        records.append(record)
        tables.append(folder / "results.parquet")
    return records[0], tables
