"""Data sets: campaigns turned into labelled tables of frames, signals, truth and labels, split by seed.

``build_dataset`` takes campaign folders (``cosim campaign --keep-logs all``), or campaigns that it
runs itself with every log kept, and writes, per run, under ``DIR``:

- ``frames/<split>/<campaign>-run-<i>.parquet``: every frame on the bus in bus order, as CAN
  intrusion detection works on them: timestamp, id, dlc, data, label (1: an attack's frame), the
  attack's kind and label (``cosim.campaign.dataset_run``);
- ``hcrl/<split>/...csv`` and ``road/<split>/{ambient,attacks}/...log`` with each folder's
  ``capture_metadata.json``: the same frames as the HCRL car-hacking CSV and as ROAD's candump
  logs, labelled by ROAD's rule exactly as here where ROAD's fields can say it
  (``cosim.campaign.dataset_formats``, ``cosim.campaign.dataset_road``);
- ``signals/<campaign>/<split>/run-<i>.parquet``: per tick, the readings and commands as their
  receivers took them (and the estimates, with ``estimates``);
- ``truth/<campaign>/<split>/...``: per tick, the plant's states, true sensors, inputs, and what the
  faults added: the physical effect of every fault and attack;
- ``labels/<split>/...``: per tick, what is active (labels, kinds, targets, class);
  ``events/<split>/...``: per fault or attack, its kind, targets, onset and end;
- ``card.json`` and ``README.md``: the data set's card (``cosim.campaign.dataset_card``), with the
  SHA-256 of every file and of all of them.

Splits go by replicate (a seed of the campaign): every run of a replicate is in one split, so no
noise realization is in two. The same campaign gives the same bytes: nothing in the files depends
on when, where or how fast the runs ran.
"""

from __future__ import annotations

import json
import tempfile
from collections import Counter
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from cosim.campaign.dataset_card import Written, write_card
from cosim.campaign.dataset_run import SPLITS, DatasetRun, RunTables, read_run
from cosim.campaign.spec import Campaign, load_campaign
from cosim.errors import CosimError
from cosim.extras import require

#: The default shares of the replicates in each split.
FRACTIONS = (0.6, 0.2, 0.2)
#: Parquet files are written with these settings (the same bytes for the same table).
PARQUET = {"compression": "zstd", "compression_level": 9, "use_dictionary": True, "write_statistics": True}


def split_of(replicates: Sequence[int], fractions: Sequence[float] = FRACTIONS) -> dict[int, str]:
    """Each replicate's split: the replicates in their order, cut at the cumulative shares
    (rounded), so that the first share of them trains, the next validates, the rest tests."""
    if len(fractions) != 3 or any(f < 0 for f in fractions) or abs(sum(fractions) - 1.0) > 1e-9:
        raise CosimError(f"--split {','.join(map(str, fractions))}: give three shares that add up to 1")
    n = len(replicates)
    cuts = [round(n * fractions[0]), round(n * (fractions[0] + fractions[1]))]
    return {r: SPLITS[(i >= cuts[0]) + (i >= cuts[1])] for i, r in enumerate(replicates)}


def empty_splits(replicates: int, fractions: Sequence[float] = FRACTIONS) -> list[str]:
    """The splits with a share that ``replicates`` replicates leave without a run."""
    taken = set(split_of(list(range(replicates)), fractions).values())
    return [split for split, share in zip(SPLITS, fractions) if share > 0 and split not in taken]


def split_warning(campaign: Campaign, fractions: Sequence[float]) -> str | None:
    """One line when a campaign's replicates leave a split empty: which, and how many fill every one."""
    empty = empty_splits(len(campaign.spec.replicates), fractions)
    if not empty:
        return None
    enough = next(n for n in range(1, 10_000) if not empty_splits(n, fractions))
    count = len(campaign.spec.replicates)
    return (
        f"{campaign.spec.name}: {' and '.join(empty)} will be empty: {count} replicate{'' if count == 1 else 's'} "
        f"cut at the shares {','.join(f'{f:g}' for f in fractions)}; --seeds {enough} or more fills every split"
    )


def build_dataset(
    sources: Sequence[str | Path | Campaign],
    out: str | Path,
    *,
    fractions: Sequence[float] = FRACTIONS,
    estimates: bool = False,
    license: str = "cc-by-4.0",
    campaigns_dir: str | Path | None = None,
    engine: str = "dask",
    workers: int | None = None,
    address: str | None = None,
    on_campaign: Callable[[Campaign, bool], None] | None = None,
    on_run: Callable[[DatasetRun, int, int], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write the data set of ``sources`` (campaign folders; campaigns, built-in or files, to run) into
    ``out``; returns its card. A campaign to run goes into ``campaigns_dir`` (kept) or a temporary
    folder. What the data set will lack (an empty split) goes to ``on_warning`` as soon as it is
    known, and into the card."""
    require("pyarrow.parquet", "cosim dataset", "campaign")
    folder = Path(out).resolve()
    if folder.exists() and any(folder.iterdir()):
        raise CosimError(f"--out {folder}: the folder is not empty; choose a new or empty folder")
    with ExitStack() as stack:
        where = Path(campaigns_dir) if campaigns_dir else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        warnings: list[str] = []

        def told(campaign: Campaign, running: bool) -> None:
            warning = split_warning(campaign, fractions)
            if warning is not None:
                warnings.append(warning)
                if on_warning is not None:
                    on_warning(warning)
            if on_campaign is not None:
                on_campaign(campaign, running)

        campaigns = [_campaign_folder(source, where, engine, workers, address, told) for source in sources]
        names = [campaign.spec.name for campaign, _ in campaigns]
        if len(set(names)) != len(names):
            raise CosimError(f"two sources are the same campaign ({', '.join(names)}): give each once")
        written = Written(folder, campaigns, warnings=warnings)
        runs = [run for campaign, path in campaigns for run in _runs(campaign, path, fractions, written)]
        folder.mkdir(parents=True, exist_ok=True)
        for i, run in enumerate(runs):
            if on_run is not None:
                on_run(run, i, len(runs))
            _write_run(folder, run, read_run(run.log, estimates), written)
            written.runs.append(run)
    from cosim.campaign.dataset_formats import write_road_metadata

    for road_folder, captures in written.road.items():
        write_road_metadata(folder / "road" / road_folder, captures)

    return write_card(written, fractions, estimates, license)


def _campaign_folder(
    source: str | Path | Campaign,
    where: Path,
    engine: str,
    workers: int | None,
    address: str | None,
    on_campaign: Callable[[Campaign, bool], None] | None,
) -> tuple[Campaign, Path]:
    """A campaign and its folder: the folder given, or the campaign run into ``where`` with its logs."""
    path = Path(source) if not isinstance(source, Campaign) else None
    if path is not None and path.is_dir():
        if not (path / "campaign.toml").exists():
            raise CosimError(f"{path}: not a campaign folder (it has no campaign.toml)")
        campaign = load_campaign(path / "campaign.toml")
        if on_campaign is not None:
            on_campaign(campaign, False)
        return campaign, path
    from cosim.campaign.coordinator import run_campaign

    campaign = source if isinstance(source, Campaign) else load_campaign(source)
    target = where / campaign.spec.name
    if on_campaign is not None:
        on_campaign(campaign, True)
    resume = (target / "campaign.toml").exists()
    run_campaign(campaign, target, engine=engine, workers=workers, address=address, resume=resume, keep_logs="all")
    return campaign, target


def _runs(campaign: Campaign, folder: Path, fractions: Sequence[float], written: Written) -> list[DatasetRun]:
    """The campaign's runs that completed, each with its split and log; those that did not are
    listed in the card; a completed run without its log is an error (the data set would lack it)."""
    splits = split_of(campaign.spec.replicates, fractions)
    out = []
    for spec in campaign.runs():
        part_file = folder / "parts" / f"run-{spec.index:06d}.json"
        if not part_file.exists():
            raise CosimError(f"{folder}: run {spec.index} has not run (finish the campaign with --resume)")
        rows = json.loads(part_file.read_text())["rows"]
        status = rows[0].get("status")
        if status != "completed":
            written.skipped.append({"campaign": campaign.spec.name, "run": spec.index, "status": status})
            continue
        log = rows[0].get("log") or ""
        if not log or not (folder / log).exists():
            raise CosimError(
                f"{folder}: run {spec.index} kept no log; a data set reads every run's log: run the campaign "
                f"with --keep-logs all"
            )
        out.append(DatasetRun(campaign.spec.name, spec, splits[spec.replicate], folder / log))
    return out


def _write_run(folder: Path, run: DatasetRun, tables: RunTables, written: Written) -> None:
    """Every file of one run, and its share of the class balance."""
    from cosim.campaign.dataset_formats import write_hcrl, write_road_log
    from cosim.campaign.dataset_road import capture

    keys = {"campaign": run.campaign, "run": run.spec.index}
    split, stem = run.split, run.stem
    _parquet(folder / "frames" / split / f"{stem}.parquet", {**_repeat(keys, tables.frames), **tables.frames})
    _parquet(folder / "labels" / split / f"{stem}.parquet", {**_repeat(keys, tables.ticks), **tables.ticks})
    _parquet(folder / "events" / split / f"{stem}.parquet", {**_repeat(keys, tables.events), **tables.events})
    per_campaign = f"run-{run.spec.index:06d}.parquet"
    _parquet(
        folder / "signals" / run.campaign / split / per_campaign, {**_repeat(keys, tables.signals), **tables.signals}
    )
    _parquet(folder / "truth" / run.campaign / split / per_campaign, {**_repeat(keys, tables.truth), **tables.truth})
    write_hcrl(folder / "hcrl" / split / f"{stem}.csv", tables.frames)
    kind, metadata = capture(tables)
    write_road_log(folder / "road" / split / kind / f"{stem}.log", tables.frames)
    written.road.setdefault(f"{split}/{kind}", {})[stem] = metadata
    balance = written.balance.setdefault(split, {"ticks": Counter(), "frames": Counter(), "runs": Counter()})
    balance["ticks"].update(tables.ticks["class"])
    balance["frames"].update(tables.frames["attack"])
    balance["runs"][run.campaign] += 1
    written.plants.setdefault(
        run.campaign,
        {
            "plant": tables.record.plant,
            "sample_time": tables.record.sample_time,
            "states": tables.record.states,
            "sensors": tables.record.sensors,
            "actuators": tables.record.actuators,
            "bus": tables.record.bus,
        },
    )


def _repeat(keys: dict[str, Any], columns: dict[str, list[Any]]) -> dict[str, list[Any]]:
    rows = len(next(iter(columns.values()), []))
    return {name: [value] * rows for name, value in keys.items()}


def _parquet(path: Path, columns: dict[str, list[Any]]) -> None:
    """One table, written the same way every time."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.table({name: pa.array(values, type=_arrow_type(name, values)) for name, values in columns.items()})
    pq.write_table(table, path, **PARQUET)


def _arrow_type(name: str, values: list[Any]) -> Any:
    """The column's type: small integers where the values are, text, lists of text, bytes, floats."""
    import pyarrow as pa

    fixed = {
        "run": pa.int32(),
        "tick": pa.int32(),
        "seq": pa.int32(),
        "id": pa.int32(),
        "dlc": pa.int8(),
        "label": pa.int8(),
        "onset_tick": pa.int32(),
        "end_tick": pa.int32(),
        "ticks_active": pa.int32(),
        "frames_injected": pa.int32(),
        "frames_lost": pa.int32(),
        "data": pa.binary(),
        "start": pa.float64(),
        "end": pa.float64(),
        "active": pa.list_(pa.string()),
        "kinds": pa.list_(pa.string()),
        "targets": pa.list_(pa.string()),
    }
    if name in fixed:
        return fixed[name]
    sample = next((v for v in values if v is not None), None)
    if isinstance(sample, bool):
        return pa.bool_()
    if isinstance(sample, str) or sample is None:
        return pa.string()
    return pa.float64()
