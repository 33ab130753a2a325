"""Turn campaigns into a labelled data set: frames, signals, truth and labels, split by seed.

Make a data set for data-driven fault diagnosis and CAN intrusion detection from campaigns: every
frame on the bus (Parquet, and the HCRL car-hacking CSV and ROAD candump forms), the readings as the
receivers took them, the plant's true state (the physical effect of every fault and attack), and
labels per frame, per tick and per fault, from the records the testbed scores by. Runs are split
into train, validation and test by replicate (seed); the same campaigns give the same bytes, whose
SHA-256 the card (DIR/card.json, DIR/README.md) holds. A source is a campaign's folder (run with
--keep-logs all) or a campaign, which is run here with every log kept. Fields: docs/datasets.md.
"""

from __future__ import annotations

import argparse

from rich.markup import escape

from cosim.cli import common

EPILOG = """\
examples:
  cosim dataset dataset-attacks --out runs/ds-attacks
  cosim dataset dataset-faults-masses dataset-faults-three-tank dataset-faults-vessel --out runs/ds-faults
  cosim dataset runs/my-campaign --out runs/ds-mine --split 0.8,0.1,0.1 --estimates
  cosim dataset my-campaign.toml --seeds 200 --out runs/ds-big --address tcp://10.0.0.5:8786"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "sources",
        nargs="+",
        metavar="CAMPAIGN_OR_DIR",
        help="a campaign folder (cosim campaign --keep-logs all), a built-in campaign or a campaign file",
    )
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="the data set's folder (new or empty)")
    p.add_argument(
        "--split",
        default="0.6,0.2,0.2",
        metavar="TRAIN,VAL,TEST",
        help="shares of each campaign's replicates in train, validation and test (default 0.6,0.2,0.2)",
    )
    p.add_argument("--estimates", action="store_true", help="add the estimators' estimates to the signals")
    p.add_argument("--license", default="cc-by-4.0", help="the data set's licence in its card (default cc-by-4.0)")
    p.add_argument("--seeds", type=common.positive, metavar="N", help="campaigns run here: replicates 0 … N-1")
    common.set_option(p, "campaigns run here: change every run (duration=10)")
    p.add_argument(
        "--campaigns", metavar="DIR", help="campaigns run here go to DIR and stay (default: a temporary folder)"
    )
    common.cluster_options(p)  # where campaigns run here run
    common.quiet_option(p)


def main(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cosim import scenario
    from cosim.campaign.coordinator import engine_extras
    from cosim.campaign.dataset import build_dataset
    from cosim.campaign.spec import Campaign, load_campaign
    from cosim.errors import CosimError
    from cosim.run.needs import Needs

    try:
        fractions = [float(x) for x in args.split.split(",")]
    except ValueError:
        raise CosimError(f"--split {args.split}: give three numbers, e.g. 0.6,0.2,0.2") from None
    settings = [scenario.parse_setting(text) for text in args.set or []]
    talk = common.console(stderr=True, quiet=args.quiet)
    sources: list[str | Path | Campaign] = [
        source if Path(source).is_dir() else load_campaign(source, seeds=args.seeds, settings=settings)
        for source in args.sources
    ]
    to_run = [source for source in sources if isinstance(source, Campaign)]
    needs = Needs("cosim dataset", engine_extras(args.engine) if to_run else {"campaign": ["pyarrow"]})
    for campaign in to_run:
        needs.add_each(campaign.spec.name, campaign.point_scenarios())
    common.check_needs(talk, needs)

    def told(campaign: Campaign, running: bool) -> None:
        what = f"running its {campaign.size} runs with their logs" if running else "reading its logs"
        talk.print(f"[bold]{escape(campaign.spec.name)}[/bold]: {what}")

    def progress(run: object, i: int, total: int) -> None:
        if i % 10 == 0 or i == total - 1:
            talk.print(f"  run {i + 1} of {total}")

    card = build_dataset(
        sources,
        args.out,
        fractions=fractions,
        estimates=args.estimates,
        license=args.license,
        campaigns_dir=args.campaigns,
        engine=args.engine,
        workers=args.workers,
        address=args.address,
        on_campaign=told,
        on_run=progress,
        on_warning=lambda line: common.warn(talk, [line]),
    )
    splits = ", ".join(f"{s} {card['splits'][s]['runs']}" for s in ("train", "validation", "test"))
    talk.print(f"done: {len(card['runs'])} runs ({splits}), {len(card['files'])} files, digest {card['digest'][:16]}")
    common.warn(talk, (f"ROAD's form, {c['capture']}: {c['why']}" for c in card["road"]["not_exact"]))
    print(Path(args.out) / "card.json")
    return 0
