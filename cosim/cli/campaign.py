"""``cosim campaign``, ``cosim campaigns`` and ``cosim leaderboard``: many runs, and their ranking."""

from __future__ import annotations

import argparse
import sys
import time

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from cosim.cli import common
from cosim.errors import CosimError

CAMPAIGN_DESCRIPTION = """\
Run a campaign: a base scenario over seeds, axes (a grid of settings) and sampled settings, every run
on a Dask cluster (a local one with a worker per core, or one joined with --address), into one table,
DIR/results.parquet: a row per run and estimator, every metric of 'cosim inspect' with units. A run that
fails is a row with its error; --resume after a kill or Ctrl-C redoes only the runs that did not finish.
Every cell of the grid sees the same noise and weather replicate by replicate (common random numbers).
The file's format is in docs/campaigns.md; 'cosim campaigns' lists the built-in ones."""

CAMPAIGN_EXAMPLES = """\
examples:
  cosim campaign masses-bias-sweep --out runs/sweep
  cosim campaign masses-bias-sweep --out runs/quick --seeds 2 --set duration=10
  cosim campaign my-campaign.toml --out runs/mine --workers 2 --keep-logs all
  cosim campaign my-campaign.toml --out runs/mine --resume
  cosim campaign my-campaign.toml --out runs/big --address tcp://10.0.0.5:8786"""


def register(sub) -> None:
    _register_campaign(sub)
    common.command(
        sub, "campaigns", cmd_campaigns, help="list the built-in campaigns", description="List the built-in campaigns."
    )
    _register_leaderboard(sub)


def _register_campaign(sub) -> None:
    p = common.command(
        sub,
        "campaign",
        cmd_campaign,
        help="run a campaign of many runs on a distributed engine",
        description=CAMPAIGN_DESCRIPTION,
        epilog=CAMPAIGN_EXAMPLES,
    )
    p.add_argument("file", metavar="FILE", help="a built-in campaign or a campaign TOML file")
    p.add_argument(
        "--out", "-o", required=True, metavar="DIR", help="the campaign's folder (new, or with --resume its own)"
    )
    p.add_argument("--seeds", type=common.positive, metavar="N", help="replicates 0 … N-1 instead of the file's seeds")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="change the base scenario of every run, as in the file's [set] (duration=10, 'faults[0].start=5.0'); "
        "repeat for several",
    )
    p.add_argument(
        "--engine",
        choices=("dask", "inline"),
        default="dask",
        help="dask (default): a Dask distributed cluster; inline: one run after the other in this process",
    )
    p.add_argument(
        "--address", metavar="ADDR", help="join the Dask scheduler at ADDR instead of starting a local cluster"
    )
    p.add_argument(
        "--workers", type=common.positive, metavar="N", help="local cluster: worker processes (default: one per core)"
    )
    p.add_argument(
        "--resume", action="store_true", help="finish the campaign in DIR: only the runs without results run"
    )
    p.add_argument(
        "--keep-logs",
        choices=("all", "failed", "none"),
        default="failed",
        help="which runs' MCAP logs stay in DIR/logs (default: those of failed runs)",
    )
    common.quiet_option(p)


def _register_leaderboard(sub) -> None:
    p = common.command(
        sub,
        "leaderboard",
        cmd_leaderboard,
        help="rank a campaign's estimators",
        description="Rank the estimators of a campaign's results table per group of runs (the fault kind by "
        "default) by their RMS error after onset: median with its 95 % interval, p90, final error, bias "
        "rejection, detection rate, missed detections, false alarms per hour, detection and isolation delays, "
        "isolation accuracy. Each estimator is compared with the next on their common runs (paired: median "
        "difference, Wilcoxon signed-rank p, Holm-adjusted); ranks it cannot tell apart share their number (=).",
    )
    p.add_argument("results", metavar="RESULTS.parquet", help="a campaign's DIR/results.parquet")
    p.add_argument("--by", nargs="+", metavar="COLUMN", help="group by these columns (default: fault_kind)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--html", metavar="FILE", help="also write a self-contained HTML page with figures and outliers")
    p.add_argument("--markdown", action="store_true", help="print the tables as Markdown (for documents)")


def cmd_campaign(args: argparse.Namespace) -> int:
    from cosim import scenario
    from cosim.campaign.coordinator import require_extras, run_campaign
    from cosim.campaign.spec import load_campaign

    settings = [scenario.parse_setting(text) for text in args.set or []]
    campaign = load_campaign(args.file, seeds=args.seeds, settings=settings)
    require_extras(args.engine)
    talk = common.console(stderr=True, quiet=args.quiet)
    spec = campaign.spec
    talk.print(
        f"[bold]{escape(spec.name)}[/bold]: {campaign.size} runs of {escape(campaign.base.source)} "
        f"({len(campaign.grid)} settings × {len(spec.replicates)} replicates, {spec.bus} bus) into "
        f"{escape(str(args.out))}"
    )
    progress = _progress(talk, campaign.size)
    try:
        with progress:
            result = run_campaign(
                campaign,
                args.out,
                engine=args.engine,
                workers=args.workers,
                address=args.address,
                resume=args.resume,
                keep_logs=args.keep_logs,
                on_progress=progress.update_campaign,
                on_start=lambda description, workers: talk.print(f"engine: {escape(description)}"),
            )
    except KeyboardInterrupt as interrupt:
        done = progress.tasks[0].completed if progress.tasks else 0
        return common.interrupted(
            common.error_console(),
            interrupt,
            f" after {done:.0f} of {campaign.size} runs: their results are kept in {escape(str(args.out))}; "
            f"finish with: cosim campaign {escape(args.file)} --out {escape(str(args.out))} --resume",
        )
    resumed = f" ({result.resumed} from an earlier session)" if result.resumed else ""
    talk.print(
        f"done: {result.runs} runs{resumed}, {result.failed} failed, in {result.wall_time:.1f} s on "
        f"{escape(result.engine)}"
    )
    print(result.path)
    return 0


def _progress(talk: Console, total: int):
    """A progress display of a campaign's runs, with ``update_campaign(CampaignProgress)``."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

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
    task = progress.add_task("runs", total=total, failed=0, per_run="", eta="-")

    def update(p) -> None:
        eta = "-" if p.eta_s is None else time.strftime("%H:%M:%S", time.gmtime(p.eta_s))
        progress.update(task, completed=p.done, failed=p.failed, per_run=f"{p.mean_run_s:.2f} s/run", eta=eta)

    progress.update_campaign = update  # type: ignore[attr-defined]
    return progress


def cmd_campaigns(args: argparse.Namespace) -> int:
    from cosim.campaign.spec import builtin_names, load_campaign

    table = Table(box=None, pad_edge=False, show_header=True, header_style="bold")
    for column in ("name", "runs", "description"):
        table.add_column(column)
    for name in builtin_names():
        try:
            campaign = load_campaign(name)
            table.add_row(name, str(campaign.size), campaign.spec.description)
        except CosimError as error:
            table.add_row(name, "-", f"[red]invalid: {escape(str(error))}[/red]")
    common.console().print(table)
    return 0


def cmd_leaderboard(args: argparse.Namespace) -> int:
    from cosim.campaign.leaderboard import leaderboard

    board = leaderboard(args.results, args.by)
    if args.html:
        from cosim.campaign.page import write_page

        common.error_console().print(f"wrote {escape(str(write_page(board, args.html)))}")
    if args.json:
        common.print_json(board)
        return 0
    render_leaderboard(board, common.console(wide=True), markdown=args.markdown)
    return 0


def _number(value) -> str:
    return "-" if value is None else f"{value:.4g}"


def _percent(value) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _interval(bounds) -> str:
    return "-" if not bounds or bounds[0] is None else f"[{bounds[0]:.3g}, {bounds[1]:.3g}]"


def _versus(score: dict) -> str:
    """How an estimator compares with the next in its ranking, on their common runs."""
    comparison = score.get("vs_next")
    if not comparison or comparison.get("median_difference") is None:
        return ""
    sign = "=" if comparison["tied"] else ">"
    return f"{sign} {comparison['median_difference']:+.3g} p {comparison['p_holm']:.2g} ({comparison['pairs']})"


def leaderboard_rows(group: dict, unit: str) -> tuple[list[str], list[list[str]]]:
    """The headers and rows of one group of a leaderboard, as text."""
    diagnosis = any(s["diagnoses"] for s in group["ranking"])
    rms = f"RMS p50 [{unit}]" if unit else "RMS p50"
    headers = ["#", "estimator", "kind", "runs", rms, "95 % interval", "p90", "final p50", "rejection", "vs next"]
    if diagnosis:
        headers += ["detected", "missed", "false alarms/h", "delay p50 [s]", "isolation p50 [s]", "isolated right"]
    rows = []
    for s in group["ranking"]:
        cells = [
            f"{'=' if s.get('tied') else ''}{s['rank']}",
            s["estimator"],
            s["kind"],
            f"{s['runs']}" + (f" +{s['failed']}!" if s["failed"] else ""),
            _number(s["rms_post_fault_median"]),
            _interval(s.get("rms_post_fault_median_ci95")),
            _number(s["rms_post_fault_p90"]),
            _number(s.get("final_error_median")),
            _number(s["bias_rejection_median"]),
            _versus(s),
        ]
        if diagnosis:
            cells += [
                _percent(s["detection_rate"]),
                str(s["missed_detections"] if s["missed_detections"] is not None else "-"),
                _number(s["false_alarms_per_hour"]),
                _number(s["detection_delay_median_s"]),
                _number(s["isolation_delay_median_s"]),
                _percent(s["isolation_accuracy"]),
            ]
        rows.append(cells)
    return headers, rows


LEGEND = (
    "RMS of the estimation error after the first fault's onset, median over runs with its 95 % bootstrap interval; "
    "final: the error at the last tick; vs next: > told apart from the next (=: not), the next estimator's median "
    "paired excess over this one on their common runs, Holm-adjusted Wilcoxon p and the number of pairs; =2: a "
    "shared rank"
)


def render_leaderboard(board: dict, talk: Console, markdown: bool = False) -> None:
    unit = board["units"].get("rms_post_fault") or ""
    name = str(board.get("campaign") or board["table"])
    summary = f"{board['runs']} runs, {board['failed_runs']} failed; ranked per {', '.join(board['by'])}"
    if markdown:  # for documents: plain GitHub tables, one per group
        lines = [f"**{name}**: {summary}", ""]
        for group in board["groups"]:
            headers, rows = leaderboard_rows(group, unit)
            lines += [", ".join(f"{k} = {v}" for k, v in group["group"].items()), ""]
            lines += ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
            lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
        sys.stdout.write("\n".join([*lines, LEGEND, ""]))
        return
    talk.print(f"[bold]{escape(name)}[/bold]: {summary}")
    for group in board["groups"]:
        title = ", ".join(f"{k} = {v}" for k, v in group["group"].items())
        table = Table(title=escape(title), title_justify="left", box=None, header_style="bold")
        headers, rows = leaderboard_rows(group, unit)
        for i, header in enumerate(headers):
            table.add_column(escape(header), justify="left" if 0 < i < 3 or header == "vs next" else "right")
        for row in rows:
            table.add_row(*map(escape, row))
        talk.print(table)
    talk.print(f"[dim]{escape(LEGEND)}[/dim]")
    if board["outliers"]:
        talk.print(f"{len(board['outliers'])} outliers and failed runs: see --json or --html")
