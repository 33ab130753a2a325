"""Run a campaign of many runs on a distributed engine.

Run a campaign: a base scenario over seeds, axes (a grid of settings) and sampled settings, every
run on a Dask cluster (a local one with a worker per core, or one joined with --address), into one
table, DIR/results.parquet: a row per run and estimator, every metric of 'cosim inspect' with units.
A run that fails is a row with its error; --resume after a kill or Ctrl-C redoes only the runs that
did not finish (Ctrl-C prints the command: the folder's campaign.toml keeps --seeds and --set).
Every cell of the grid sees the same noise and weather replicate by replicate (common random
numbers). The file's format is in docs/campaigns.md; 'cosim campaigns' lists the built-in ones.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.markup import escape
from rich.progress import Progress

from cosim.cli import common

if TYPE_CHECKING:
    from cosim.campaign.coordinator import CampaignProgress

EPILOG = """\
examples:
  cosim campaign masses-bias-sweep --out runs/sweep
  cosim campaign masses-bias-sweep --out runs/quick --seeds 2 --set duration=10
  cosim campaign my-campaign.toml --out runs/mine --workers 2 --keep-logs all
  cosim campaign runs/mine/campaign.toml --out runs/mine --resume
  cosim campaign my-campaign.toml --out runs/big --address tcp://10.0.0.5:8786"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="a built-in campaign or a campaign TOML file")
    p.add_argument(
        "--out", "-o", required=True, metavar="DIR", help="the campaign's folder (new, or with --resume its own)"
    )
    p.add_argument("--seeds", type=common.positive, metavar="N", help="replicates 0 … N-1 instead of the file's seeds")
    common.set_option(
        p,
        "change the base scenario of every run, as in the file's [set] (duration=10, 'faults[0].start=5.0'); "
        "repeat for several",
    )
    common.engine_options(p, "the campaign in DIR")
    p.add_argument(
        "--keep-logs",
        choices=("all", "failed", "none"),
        default="failed",
        help="which runs' MCAP logs stay in DIR/logs (default: those of failed runs)",
    )
    common.quiet_option(p)


def main(args: argparse.Namespace) -> int:
    from cosim import scenario
    from cosim.campaign.coordinator import engine_extras, resume_command, run_campaign
    from cosim.campaign.spec import load_campaign
    from cosim.run.needs import Needs

    settings = [scenario.parse_setting(text) for text in args.set or []]
    campaign = load_campaign(args.file, seeds=args.seeds, settings=settings)
    talk = common.console(stderr=True, quiet=args.quiet)
    needs = Needs("cosim campaign", engine_extras(args.engine))
    needs.add_each(campaign.spec.name, campaign.point_scenarios())
    common.check_needs(talk, needs)
    spec = campaign.spec
    talk.print(
        f"[bold]{escape(spec.name)}[/bold]: {campaign.size} runs of {escape(campaign.base.source)} "
        f"({len(campaign.grid)} settings × {len(spec.replicates)} replicates, {spec.bus} bus) into "
        f"{escape(str(args.out))}"
    )
    progress, update = progress_display(talk, campaign.size)
    try:
        with progress:
            result = run_campaign(
                campaign,
                args.out,
                **common.picked(args, "engine", "workers", "address", "resume", "keep_logs", "batch"),
                on_progress=update,
                on_start=lambda description, workers: talk.print(f"engine: {escape(description)}"),
            )
    except KeyboardInterrupt as interrupt:
        done = progress.tasks[0].completed if progress.tasks else 0
        return common.interrupted(
            common.error_console(),
            interrupt,
            f" after {done:.0f} of {campaign.size} runs: their results are kept in {escape(str(args.out))}; "
            f"finish with: {escape(resume_command(Path(args.out)))}"
            if (Path(args.out) / "campaign.toml").exists()
            else " before the campaign started",
        )
    resumed = f" ({result.resumed} from an earlier session)" if result.resumed else ""
    ran = result.runs - result.resumed
    talk.print(
        f"done: {result.runs} runs{resumed}, {result.failed} failed, in {result.wall_time:.1f} s on "
        f"{escape(result.engine)}; {result.batched} of {ran} ran batched"
        + "".join(f"\n  {count} alone: {escape(why)}" for why, count in list(result.alone.items())[:3])
    )
    print(result.path)
    return 0


def progress_display(
    talk: Console, total: int, description: str = "runs", progress: Progress | None = None
) -> tuple[Progress, Callable[[CampaignProgress], None]]:
    """A progress display of a campaign's runs, and the function that updates it: a line of its
    own in ``progress`` (several campaigns at once: the benchmark's cases), or of a new display."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    if progress is None:
        columns = (
            TextColumn("[progress.description]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[failed]} failed"),
            TextColumn("{task.fields[per_run]}"),
            TimeElapsedColumn(),
            TextColumn("ETA {task.fields[eta]}"),
        )
        progress = Progress(*columns, console=talk, transient=False, disable=talk.quiet)
    task = progress.add_task(description, total=total, failed=0, per_run="", eta="-")

    def update(p: CampaignProgress) -> None:
        eta = "-" if p.eta_s is None else time.strftime("%H:%M:%S", time.gmtime(p.eta_s))
        progress.update(task, completed=p.done, failed=p.failed, per_run=f"{p.mean_run_s:.2f} s/run", eta=eta)

    return progress, update
