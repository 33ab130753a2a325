"""The leaderboard of a campaign: estimators ranked per group of runs, with confidence intervals.

``leaderboard(results, by)`` reads a results table (``cosim campaign``'s ``results.parquet``) and,
per group (by default every axis the campaign swept; ``by`` groups by other columns and pools the
rest, which the group names) and estimator, scores:

- estimation: the median and 90th percentile of the RMS error after onset, with a 95 % bootstrap
  interval of the median (2000 resamples, seeded: the same table gives the same interval); the
  median final and peak errors with theirs, the recovery time (median, p90) and the median bias
  rejection ratio;
- detection (estimators that publish an alarm): the detection rate over the runs with a fault
  (95 % Wilson interval), missed detections, false alarms per fault-free hour pooled over the runs
  (95 % exact Poisson interval), the median and 90th percentile of the detection and isolation
  delays, and the isolation accuracy (Wilson interval);
- failed runs, which are counted, never scored.

Estimators are ranked by the median RMS error after onset; schemes without one (a fault-free
group, or a scheme that only diagnoses: the intrusion detector, SecOC) after them, by detection
rate, false alarms per hour, isolation accuracy and detection delay. ``outliers`` lists the runs
whose error lies beyond Q3 + 3 IQR of their estimator's group: where to look first.

Each estimator is compared with the next on the runs both took part in (paired: the same noise,
faults and weather), and so is each scheme that only diagnoses with the next such scheme; an
estimator and a scheme that only diagnoses have no common measure and are not compared.
``cosim.campaign.verdicts`` gives each comparison its verdict (separated, tied within a margin,
or not separated) and what its runs could tell. A scheme's rank in its chain (the estimators, or
the schemes that only diagnose) is 1 + the number of schemes shown better; a benchmark track's
mean rank counts a case only where the comparisons that place the scheme are conclusive.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.campaign import ranking
from cosim.campaign.results import Row
from cosim.campaign.scores import Entry, append_finite, finite_number
from cosim.campaign.verdicts import MARGIN
from cosim.errors import CosimError
from cosim.extras import require


@dataclass
class ResultsTable:
    """A results table as read: its rows (every column by name), the unit of each column, the
    table's metadata, and the columns of its campaign's axes and samples (per case in a bundle:
    the key is the case, None for a campaign's table)."""

    rows: list[dict[str, Any]]
    columns: list[str]
    units: dict[str, str]
    metadata: dict[str, str]
    design: dict[str | None, Design] = field(default_factory=dict)

    def pooled(self, rows: list[dict[str, Any]], by: Sequence[str]) -> list[dict[str, Any]]:
        """The axes and samples that ``rows`` (a group) take more than one value of and ``by`` does
        not group by, each with its number of values: what the group pools."""
        found: dict[str, dict[str, Any]] = {}
        for case in dict.fromkeys(row.get("case") for row in rows):
            design = self.design.get(case, Design())
            for column in (*design.axes, *design.samples):
                if column in by:
                    continue
                values = len({repr(row.get(column)) for row in rows if row.get("case") == case})
                if values > 1 and values > found.get(column, {}).get("values", 0):
                    found[column] = {"column": column, "values": values, "sampled": column in design.samples}
        return list(found.values())


@dataclass(frozen=True)
class Design:
    """A campaign's grid: the columns of its axes and of its sampled settings."""

    axes: tuple[str, ...] = ()
    samples: tuple[str, ...] = ()

    @classmethod
    def of(cls, metadata: dict[str, str]) -> Design:
        """The design of the campaign file a table's metadata holds (``cosim.campaign``; none in a
        table written by other means)."""
        import tomllib

        try:
            document = tomllib.loads(metadata.get("cosim.campaign", ""))
        except tomllib.TOMLDecodeError:
            return cls()

        def column(item: dict[str, Any]) -> str:
            key = item.get("key", "")
            return str(item.get("name") or (key if isinstance(key, str) else "+".join(map(str, key))))

        return cls(tuple(map(column, document.get("axes", []))), tuple(map(column, document.get("sample", []))))


def default_groups(table: ResultsTable) -> list[str]:
    """A campaign's groups: every axis it swept (more than one value in the table), and the fault
    kind first where the axes leave it varying (or where there is no axis)."""
    design = table.design.get(None, Design())
    swept = [c for c in design.axes if len({repr(row.get(c)) for row in table.rows}) > 1]
    kinds: dict[tuple[Any, ...], set[Any]] = defaultdict(set)
    for row in table.rows:
        kinds[tuple(row.get(c) for c in swept)].add(row.get("fault_kind"))
    varies = any(len(found) > 1 for found in kinds.values())
    return ["fault_kind", *swept] if varies or not swept else swept


def read_table(path: str | Path) -> ResultsTable:
    """A results table (``cosim campaign``'s ``results.parquet``)."""
    pq = require("pyarrow.parquet", "cosim leaderboard", "campaign")
    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise CosimError(f"{path}: no such file (a campaign writes DIR/results.parquet)") from None
    except (OSError, ValueError) as error:
        raise CosimError(f"{path}: not a readable Parquet table ({error})") from None
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}
    metadata = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    return ResultsTable(table.to_pylist(), table.column_names, units, metadata, {None: Design.of(metadata)})


def leaderboard(
    path: str | Path | Sequence[str | Path],
    by: list[str] | None = None,
    exclude_contested: bool = False,
    margin: float = MARGIN,
) -> dict[str, Any]:
    """The ranking of a results table per group, or of ``cosim benchmark`` bundles (folders) merged
    into one standing table, per track and case. A campaign's groups are by default every axis it
    swept (and the fault kind where the axes do not fix it); ``by`` groups by these columns instead
    and pools the rest, which each group names (``pooled``). ``exclude_contested``: without the runs
    in which another program sent on the runner's ids; ``margin``: the equivalence margin of the
    verdicts (``cosim.campaign.verdicts``)."""
    paths = [path] if isinstance(path, (str, Path)) else list(path)
    table, bundle = load_results(paths)
    if by:
        for column in by:
            if column not in table.columns:
                raise CosimError(f"--by {column}: the table has no such column (it has: {', '.join(table.columns)})")
    else:
        by = ["track", "case"] if bundle is not None else default_groups(table)
    groups, members = _grouped(table, by, exclude_contested)
    keys = sorted(groups, key=lambda k: tuple(str(v) for v in k))
    chains = {key: ranking.chains(groups[key]) for key in keys}
    verdicts = ranking.judged(chains, margin)
    ranked: list[dict[str, Any]] = []
    for key in keys:
        scores = [score for chain in chains[key] for score, _ in chain]
        ranking.place(scores)
        ranked.append({"group": dict(zip(by, key)), "pooled": table.pooled(members[key], by), "ranking": scores})
    for key, why in _not_run(table.rows, by, groups).items():
        ranked.append({"group": dict(zip(by, key)), "pooled": [], "ranking": [], "not_run": why})
    ranked.sort(key=lambda g: tuple(str(v) for v in g["group"].values()))
    case_units = (bundle or {}).get("units", {})
    for group in ranked:
        case = group["group"].get("case")
        group["unit"] = case_units.get(case, "") if case is not None else table.units.get("rms_post_fault", "")
    runs = {(row.get("case"), row["run"]) for row in table.rows}
    board: dict[str, Any] = {
        "format": FORMAT,
        "table": ", ".join(map(str, paths)),
        "sources": [str(p) for p in paths],
        "campaign": table.metadata.get("cosim.campaign.name"),
        "by": by,
        "runs": len(runs),
        "failed_runs": len({(row.get("case"), row["run"]) for row in table.rows if row.get("status") != "completed"}),
        "units": {"rms_post_fault": table.units.get("rms_post_fault", "") if bundle is None else ""},
        "verdicts": verdicts,
        "indicative": None,
        "groups": ranked,
        "outliers": outliers(table.rows, by),
    }
    if bundle is not None:
        board["benchmark"] = {k: bundle[k] for k in ("suite", "version", "quick", "digest")} | {"bundles": len(paths)}
        board["tracks"] = ranking.track_ranks(ranked)
        if bundle["quick"]:
            board["indicative"] = (
                f"the quick selection has too few runs per case for verdicts ({verdicts['not_separated']} of "
                f"{verdicts['comparisons']} comparisons not separated); rank with the full suite"
            )
    return board


def _grouped(
    table: ResultsTable, by: list[str], exclude_contested: bool
) -> tuple[dict[tuple[Any, ...], dict[tuple[str, str], Entry]], dict[tuple[Any, ...], list[dict[str, Any]]]]:
    """The schemes of each group (by the values of ``by``), scored over their rows, and its rows."""
    groups: dict[tuple[Any, ...], dict[tuple[str, str], Entry]] = defaultdict(dict)
    members: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for values in table.rows:
        row = Row.of(values)
        if not row.estimator:  # a run that failed before it had estimators
            continue
        if exclude_contested and row.contested_ticks:
            continue
        key = (row.estimator, row.kind or "")
        values_by = tuple(values.get(c) for c in by)
        groups[values_by].setdefault(key, Entry(*key)).add(row, values.get("case"))
        members[values_by].append(values)
    return groups, members


def _not_run(rows: list[dict[str, Any]], by: list[str], scored: Any) -> dict[tuple[Any, ...], dict[str, Any]]:
    """The groups no scheme was scored in: every run failed before its schemes ran (a missing extra,
    a scenario that cannot start). Each with its runs and why, in the words of its most frequent error."""
    errors: dict[tuple[Any, ...], dict[Any, str]] = defaultdict(dict)
    for values in rows:
        key = tuple(values.get(c) for c in by)
        if key not in scored:
            errors[key][(values.get("case"), values.get("run"))] = str(values.get("error") or values.get("status"))
    out = {}
    for key, by_run in errors.items():
        counts = Counter(by_run.values())
        why, _ = counts.most_common(1)[0]
        others = len(counts) - 1
        more = f" (and {others} other error{'s' if others > 1 else ''}: see the outliers)" if others else ""
        out[key] = {"runs": len(by_run), "why": why + more}
    return out


FORMAT = 2
"""The leaderboard's JSON format: 2 added the verdicts (separated, tied within a margin, not
separated, with what the runs could tell), ranks per comparison chain, mean ranks over the placed
cases, the pooled axes of each group and the indicative label of a quick selection."""


def load_results(paths: Sequence[str | Path]) -> tuple[ResultsTable, dict[str, Any] | None]:
    """A campaign's results table (one ``results.parquet``), or ``cosim benchmark`` bundles (one or
    more folders) merged into one table, with their common record (None for a campaign's)."""
    if len(paths) > 1 or Path(paths[0]).is_dir():
        from cosim.campaign.benchmark import read_bundles

        bundle, tables = read_bundles(paths)
        merged = _merged([read_table(t) for t in tables])
        merged.design = {case: _case_design(tables, case) for case in bundle.get("cases", {})}
        return merged, bundle
    return read_table(paths[0]), None


def _case_design(tables: Sequence[Path], case: str) -> Design:
    """A bundle's case's design, from its campaign's table beside the bundle's (the first bundle that
    has it; none where no bundle kept its cases)."""
    import pyarrow.parquet as pq

    for table in tables:
        path = table.parent / "cases" / case / "results.parquet"
        if path.is_file():
            metadata = pq.read_schema(path).metadata or {}
            return Design.of({k.decode(): v.decode() for k, v in metadata.items()})
    return Design()


def _merged(tables: list[ResultsTable]) -> ResultsTable:
    """Bundles' tables as one: a run and estimator in several (the suite's own schemes) counted once;
    one name for two kinds is an error."""
    seen: dict[tuple[Any, Any, Any], str] = {}
    rows, columns = [], list(tables[0].columns)
    for table in tables:
        columns += [c for c in table.columns if c not in columns]
        for row in table.rows:
            key = (row.get("case"), row.get("run"), row.get("estimator"))
            if key in seen:
                if seen[key] != row.get("kind"):
                    raise CosimError(
                        f"estimator {row.get('estimator')!r} is {seen[key]} in one bundle and {row.get('kind')} in "
                        f"another: rename one (--estimator NEWNAME=KIND)"
                    )
                continue
            seen[key] = str(row.get("kind"))
            rows.append(row)
    return ResultsTable(rows, columns, tables[0].units, tables[0].metadata)


def outliers(rows: list[dict[str, Any]], by: list[str], factor: float = 3.0) -> list[dict[str, Any]]:
    """Completed runs whose RMS error after onset lies beyond Q3 + factor·IQR of their group and
    estimator, worst first; then each failed run once."""
    typed = [(Row.of(values), tuple(values.get(c) for c in by)) for values in rows]
    errors: dict[tuple[Any, ...], list[float]] = defaultdict(list)
    for row, group in typed:
        if row.status == "completed":
            append_finite(errors[(*group, row.estimator)], row.rms_post_fault)
    found = []
    for row, group in typed:
        found_errors = errors[(*group, row.estimator)]
        value = finite_number(row.rms_post_fault)
        if row.status != "completed" or value is None or len(found_errors) < 4:
            continue
        q1, q3 = np.percentile(found_errors, [25, 75])
        threshold = float(q3 + factor * (q3 - q1))
        if value > threshold and value > q3:
            found.append(_outlier(row, dict(zip(by, group)), value, threshold, ""))
    failed = {
        row.run: _outlier(row, dict(zip(by, group)), None, None, row.error or "")
        for row, group in typed
        if row.status != "completed"
    }
    return sorted(found, key=lambda o: -o["rms_post_fault"]) + list(failed.values())


def _outlier(
    row: Row, group: dict[str, Any], value: float | None, threshold: float | None, error: str
) -> dict[str, Any]:
    return {
        "run": row.run,
        "seed": row.seed,
        "estimator": row.estimator or "",
        "rms_post_fault": value,
        "threshold": threshold,
        "error": error,
        "log": row.log or "",
        **group,
    }
