"""The ``cosim`` command line."""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from cosim import __version__
from cosim.errors import CosimError

EXAMPLES = """\
examples:
  cosim run                          run the default scenario (masses-bias)
  cosim run masses-bias --seed 3     a built-in scenario with another seed
  cosim run my.toml --out my.mcap    a scenario file of your own
  cosim run vessel-nominal --mode realtime --foxglove   watch it in Foxglove (ws://127.0.0.1:8765)
  cosim run --json -q                a machine-readable summary of the run on standard output
  cosim run masses-bias --set duration=5 --set 'faults[0].value=[0.5, 0, 0]'
  cosim scenarios [--json]           list the built-in scenarios
  cosim campaign masses-bias-sweep --out runs/sweep   many runs on a local Dask cluster
  cosim leaderboard runs/sweep/results.parquet --html board.html
  cosim inspect runs/my.mcap --json  summarize a log for other tools
  cosim dbc --out bus.dbc            the CAN database, for candump/cantools/SavvyCAN
  cosim fmu masses-bias --out plant.fmu   the scenario's plant with its faults as an FMU
  cosim export runs/my.mcap --to mf4  the bus as an ASAM MDF4 log (also csv, parquet, blf, candump)
  cosim layout runs/my.mcap --out my-layout.json   a Foxglove layout for the log (or for a scenario)
  cosim plot runs/my.mcap --format pdf   the figures, for a paper (png, svg or pdf)
  cosim replay runs/my.mcap -e kalman  feed the log's bus traffic to one of its estimators again
  cosim report runs/my.mcap          one self-contained HTML page: scenario, metrics, figures
  cosim monitor                      watch the running co-simulation's signals live
  cosim replay runs/my.mcap --foxglove   play a log into Foxglove at its pace
"""


def _console(stderr: bool = False) -> Console:
    return Console(stderr=stderr, highlight=False, soft_wrap=True)


def _check_scenario_name(name: str | None) -> None:
    """A scenario argument that is neither a file nor a built-in scenario: the error says which
    built-in names are near it."""
    import difflib

    from cosim import scenario

    if name is None or Path(name).exists() or name in scenario.builtin_names():
        return
    near = difflib.get_close_matches(name, scenario.builtin_names(), n=3, cutoff=0.6)
    hint = f"did you mean {' or '.join(near)}? " if near else ""
    kind = "file" if name.endswith(".toml") or "/" in name else "built-in scenario"
    raise CosimError(f"no {kind} {name!r}: {hint}('cosim scenarios' lists the built-in ones)")


def _check_run_options(args: argparse.Namespace, s) -> None:
    """Options that would do nothing with the scenario as it runs are errors, not ignored."""
    mode = args.mode or s.timing.mode
    if args.speed is not None and mode != "realtime":
        raise CosimError(
            f"--speed {args.speed:g}: only in realtime mode (add --mode realtime); {s.name} runs in {mode}, "
            "as fast as its nodes answer"
        )
    interface = args.interface or s.bus.interface
    if args.port is not None and interface != "udp_multicast":
        raise CosimError(f"--port: only for the udp_multicast interface, not {interface}")


def _summary(result, out: Path, error: str = "") -> dict:
    """``cosim run --json``: the run's summary."""
    if result is None:
        return {"path": str(out) if out.exists() else None, "status": "error", "error": error}
    return {
        "path": str(result.path),
        "status": result.status,
        "ticks": result.ticks,
        "frames": result.frames,
        "lost": result.frames_lost,
        "deadline_misses": result.deadline_misses,
        "sim_time_s": result.sim_time,
        "wall_time_s": round(result.wall_time, 3),
        "realtime_factor": round(result.realtime_factor, 3),
        "error": result.error or error,
    }


def _print_json(value) -> None:
    import orjson

    sys.stdout.write(orjson.dumps(value, option=orjson.OPT_INDENT_2).decode() + "\n")


def _where_the_log_is(out: Path) -> str:
    return (
        f"the log up to that point is in {escape(str(out))}"
        if out.exists()
        else f"no log was written ({escape(str(out))} does not exist)"
    )


def _foxglove_sink(args: argparse.Namespace, feature: str, start_ns: int | None = None):
    from cosim.log.live import FoxgloveSink

    return FoxgloveSink(args.foxglove, host=args.foxglove_host, start_ns=start_ns, feature=feature)


def cmd_run(args: argparse.Namespace) -> int:
    from cosim import scenario
    from cosim.run import Run

    _check_scenario_name(args.scenario)
    loaded = scenario.apply(scenario.load(args.scenario), [scenario.parse_setting(text) for text in args.set or []])
    seed = loaded.scenario.seed if args.seed is None else args.seed
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("runs") / f"{loaded.scenario.name}-seed{seed}-{stamp}.mcap"
    _check_run_options(args, loaded.scenario)
    run = Run(
        loaded,
        out,
        args.seed,
        interface=args.interface,
        channel=args.channel,
        port=args.port,
        mode=args.mode,
        speed=args.speed,
        allow_network=True if args.allow_network else None,
    )
    s = run.scenario
    console = _console(stderr=True)
    timing = "lockstep" if s.timing.mode == "lockstep" else f"realtime at {s.timing.speed:g}x"
    console.print(
        f"[bold]{escape(s.name)}[/bold]: {s.plant.model}, {s.ticks} ticks of {s.sample_time:g} s, seed {s.seed}, "
        f"{timing}; "
        f"estimators: {', '.join(run.estimators) or 'none'} ({'CAN FD' if s.bus.fd else 'classic CAN'})"
    )

    for warning in run.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")

    sink = _foxglove_sink(args, "cosim run --foxglove") if args.foxglove is not None else None

    def started(run) -> None:
        console.print(f"bus: {run.bus.describe()}   join with: {escape(run.bus.python_can())}")
        if sink is not None:
            wait = s.timing.join_timeout
            console.print(
                f"Foxglove: open connection {sink.url} (Foxglove WebSocket), or {sink.app_url()}; "
                f"waiting up to {wait:g} s for it to subscribe"
                + (
                    ""
                    if s.timing.mode == "realtime"
                    else " (lockstep runs faster than real time: --mode realtime paces it)"
                )
            )
            interrupts = run.session.interrupts
            if not sink.wait_for_viewer(wait, interrupted=lambda: interrupts.requested is not None):
                console.print("[yellow]no Foxglove client subscribed; running anyway[/yellow]")
        waiting = [c.name for c in s.clients]
        if waiting:
            console.print(
                f"waiting for client{'s' if len(waiting) > 1 else ''} {', '.join(waiting)} to join "
                f"(up to {s.timing.join_timeout:g} s)"
            )

    try:
        result = (
            run.execute(on_start=started, sink=sink) if args.quiet else _with_progress(run, console, started, sink=sink)
        )
    except KeyboardInterrupt as interrupt:
        r = getattr(run, "result", None)
        done = f" after {r.ticks} ticks (t = {r.sim_time:g} s)" if r else ""
        console.print(f"[yellow]interrupted{done}[/yellow]; {_where_the_log_is(out)}")
        if args.json:
            _print_json(_summary(r, out))
        return 128 + getattr(interrupt, "signum", signal.SIGINT)
    except CosimError as error:
        console.print(f"[red]error:[/red] {escape(str(error))}\n{_where_the_log_is(out)}")
        if args.json:
            _print_json(_summary(getattr(run, "result", None), out, str(error)))
        return 1
    finally:
        if sink is not None:
            sink.close()
    misses = f", {result.deadline_misses} deadline misses" if s.timing.mode == "realtime" else ""
    console.print(
        f"done: {result.ticks} ticks, {result.frames} frames ({result.frames_lost} lost{misses}) in "
        f"{result.wall_time:.2f} s "
        f"(real-time factor {result.realtime_factor:.1f})"
    )
    for name, counts in result.senders.items():
        if counts["lost"] or counts["runner_frames_missed"]:
            console.print(
                f"[yellow]  {name}: {counts['lost']} of its frames lost on the way to the runner, "
                f"{counts['runner_frames_missed']} of the runner's frames missed by it[/yellow]"
            )
    if args.json:
        _print_json(_summary(result, out))
    else:
        print(out)
    return 0


def _with_progress(run, console: Console, started, **execute):
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn("t = {task.fields[sim]:>7.2f} s"),
        TextColumn("{task.fields[rtf]:>6.1f}x real time"),
        TextColumn("{task.fields[frames]:>8d} frames"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task("simulating", total=run.scenario.ticks, sim=0.0, rtf=0.0, frames=0)

        def update(p) -> None:
            progress.update(task, completed=p.tick, sim=p.sim_time, rtf=p.realtime_factor, frames=p.frames)

        return run.execute(update, on_start=started, **execute)


def cmd_node(args: argparse.Namespace) -> int:
    # A node never reads or writes MF4 files, but python-can's first import loads its MF4 support,
    # asammdf with pandas, where the export extra is installed: a second of every node's start-up.
    # Kept out of that import, python-can leaves MF4 out (as where asammdf is not installed);
    # asammdf itself stays importable afterwards (cosim's MF4 export uses it directly).
    hidden = "asammdf" not in sys.modules and "can" not in sys.modules
    if hidden:
        sys.modules["asammdf"] = None  # type: ignore[assignment]
    try:
        from cosim.run.node import load_spec, serve
    finally:
        if hidden and sys.modules.get("asammdf", False) is None:
            del sys.modules["asammdf"]

    if args.spec:
        spec = load_spec(args.spec)
        if spec.name != args.estimator:
            raise CosimError(f"{args.spec} is the spec of node {spec.name!r}, not {args.estimator!r}")
    else:
        from cosim.bus.monitor import find_run
        from cosim.run.node import NodeSpec

        info = find_run(args.run, f"cosim node {args.estimator}")
        if args.estimator not in info.get("nodes", {}):
            raise CosimError(
                f"the running co-simulation ({info['scenario']}) expects no external node {args.estimator!r}; "
                f"mark it 'external = true' in the scenario's [[estimators]] (or [controller]) to start it by hand"
            )
        spec = NodeSpec.from_json(info["nodes"][args.estimator])
    return serve(spec)


def cmd_monitor(args: argparse.Namespace) -> int:
    from cosim.bus.monitor import monitor

    return monitor(args.run, _console())


def cmd_scenarios(args: argparse.Namespace) -> int:
    from cosim import scenario

    listing: list[dict[str, Any]] = []
    for name in scenario.builtin_names():
        entry: dict[str, Any]
        try:
            s = scenario.load(name).scenario
            entry = {
                "name": name,
                "default": name == scenario.DEFAULT_SCENARIO,
                "description": s.description,
                "plant": s.plant.model,
                "duration_s": s.duration,
                "sample_time_s": s.sample_time,
                "estimators": [e.name for e in s.estimators],
                "bus": "CAN FD" if s.bus.fd else "classic CAN",
                "error": None,
            }
        except CosimError as error:
            entry = {"name": name, "default": name == scenario.DEFAULT_SCENARIO, "error": str(error)}
        listing.append(entry)
    if args.json:
        _print_json(listing)
        return 0
    table = Table(box=None, pad_edge=False, show_header=True, header_style="bold")
    table.add_column("name")
    table.add_column("description")
    for entry in listing:
        marker = " (default)" if entry["default"] else ""
        description = (
            entry["description"] if entry["error"] is None else f"[red]invalid: {escape(entry['error'])}[/red]"
        )
        table.add_row(entry["name"] + marker, description)
    _console().print(table)
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    import orjson

    from cosim.analysis.summary import render, summarize

    report = summarize(args.log)
    if args.json:
        sys.stdout.write(orjson.dumps(report, option=orjson.OPT_INDENT_2).decode() + "\n")
        return 0
    render(report, _console())
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from cosim.analysis.plot import plot

    log = Path(args.log)
    out = Path(args.out) if args.out else log.with_name(log.stem + "-plots")
    for path in plot(log, out, fmt=args.format, dpi=args.dpi):
        print(path)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from datetime import UTC, datetime

    from cosim.analysis.export import FRAME_FORMATS, export, parse_start_time

    start = None if args.start_time is None else parse_start_time(args.start_time)
    result = export(args.log, args.to, args.out, dbc=args.dbc, start_ns=start)
    console = _console(stderr=True)
    for warning in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    what = "rows (ticks)" if args.to in ("csv", "parquet") else "frames"
    stamped = ""
    if args.to in FRAME_FORMATS and result.start_ns is not None:
        when = datetime.fromtimestamp(result.start_ns / 1e9, UTC)
        stamped = f", tick 0 at {when.isoformat(timespec='milliseconds').replace('+00:00', 'Z')}"
    console.print(f"wrote {result.count} {what} as {args.to}{stamped}")
    print(result.path)
    return 0


def cmd_layout(args: argparse.Namespace) -> int:
    from cosim.analysis import layout

    target = args.target
    if target is not None and target.endswith(".mcap"):
        signals = layout.signals_of_log(target)
    else:
        from cosim import scenario
        from cosim.run.plan import RunPlan

        _check_scenario_name(target)
        plan = RunPlan.build(scenario.load(target))
        units = {name: unit for table in plan.units.values() for name, unit in table.items()}
        signals = layout.RunSignals.of(plan.run_record(), plan.codec, units)
    default = Path(target).with_suffix(".layout.json") if target and target.endswith(".mcap") else None
    out = Path(args.out) if args.out else default or Path(f"{signals.scenario}.layout.json")
    written = layout.write(layout.build(signals), out)
    _console(stderr=True).print(
        f"wrote the Foxglove layout of {escape(signals.scenario)}: Foxglove → Layouts → Import from file"
    )
    print(written)
    return 0


def _refuse(args: argparse.Namespace, flags: tuple[str, ...], why: str) -> None:
    """CosimError naming the first of ``flags`` the user gave, an option that would do nothing here."""
    for flag in flags:
        value = getattr(args, flag.removeprefix("--").replace("-", "_"))
        if value is not None and value is not False and value != [] and value != "":
            raise CosimError(f"{flag}: {why}")


def _interrupted(console: Console, interrupt: KeyboardInterrupt, where: str = "") -> int:
    """Ctrl-C (or SIGTERM, raised as KeyboardInterrupt with its signum): said, and the shell's exit code."""
    console.print(f"[yellow]interrupted[/yellow]{where}")
    return 128 + getattr(interrupt, "signum", signal.SIGINT)


def cmd_replay(args: argparse.Namespace) -> int:
    console = _console(stderr=True)
    if args.foxglove is not None:
        return _play_foxglove(args, console)
    if args.live:
        return _play(args, console)
    from cosim.run.replay import Replay, parse_params

    _refuse(args, ("--speed",), "only with --live (an estimator replay runs in lockstep, as fast as the node answers)")
    if not args.estimator:
        raise CosimError("replay needs --estimator NAME (one of the run's, or a new one with --kind), or --live")
    log = Path(args.log)
    out = Path(args.out) if args.out else log.with_name(f"{log.stem}-replay-{args.estimator}.mcap")
    replay = Replay(
        log,
        out,
        args.estimator,
        kind=args.kind,
        params=parse_params(args.param or []),
        interface=args.interface,
        channel=args.channel,
        port=args.port,
    )
    origin = "new, " if replay.new else ""
    console.print(
        f"replaying {replay.ticks} ticks of {escape(str(log))} into {escape(replay.name)} ({origin}{replay.kind})"
    )

    def started(run) -> None:
        console.print(f"bus: {run.bus.describe()}   join with: {escape(run.bus.python_can())}")

    try:
        result = replay.execute(on_start=started) if args.quiet else _with_progress(replay, console, started)
    except KeyboardInterrupt as interrupt:
        return _interrupted(console, interrupt, f"; the replay up to that point is in {escape(str(out))}")
    except CosimError as error:
        console.print(f"[red]error:[/red] {escape(str(error))}\nthe replay up to that point is in {escape(str(out))}")
        return 1
    console.print(
        f"done: {result.ticks} ticks, {result.frames} frames ({result.frames_lost} lost) in {result.wall_time:.2f} s"
    )
    print(out)
    return 0


def _play_foxglove(args: argparse.Namespace, console: Console) -> int:
    from cosim.log.live import log_start_ns, play

    _refuse(
        args,
        ("--estimator", "--kind", "--param", "--out", "--live", "--interface", "--channel", "--port"),
        "not with --foxglove, which serves the log's messages to Foxglove as they are",
    )
    speed = 1.0 if args.speed is None else args.speed
    with _foxglove_sink(args, "cosim replay --foxglove", log_start_ns(args.log)) as sink:
        console.print(
            f"Foxglove: open connection {sink.url} (Foxglove WebSocket), or {sink.app_url()}; "
            f"waiting up to {args.wait:g} s for it to subscribe, then playing {escape(args.log)} at "
            + ("full speed" if speed == 0 else f"{speed:g}x real time")
        )

        def ready(viewer: bool) -> None:
            if not viewer:
                console.print("[yellow]no Foxglove client subscribed; playing anyway[/yellow]")

        started = time.perf_counter()
        try:
            count, sim_time, warnings = play(args.log, sink, speed, wait=args.wait, on_ready=ready)
        except KeyboardInterrupt as interrupt:
            return _interrupted(console, interrupt)
    for warning in warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    console.print(
        f"served {count} messages ({sim_time:g} s of simulated time) in {time.perf_counter() - started:.2f} s"
    )
    return 0


def _play(args: argparse.Namespace, console: Console) -> int:
    from cosim.run.replay import play

    _refuse(
        args,
        ("--estimator", "--kind", "--param", "--out"),
        "not with --live, which plays the log's frames onto a bus as they are",
    )
    speed = 1.0 if args.speed is None else args.speed

    def started(bus) -> None:
        console.print(
            f"playing {escape(args.log)} onto {bus.describe()} at {speed:g}x real time\n"
            f"join with: {escape(bus.python_can())}"
        )

    try:
        result = play(args.log, args.interface or "udp_multicast", args.channel or "", args.port or 0, speed, started)
    except KeyboardInterrupt as interrupt:
        return _interrupted(console, interrupt)
    for warning in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    console.print(f"sent {result.frames} frames ({result.sim_time:g} s of simulated time) in {result.wall_time:.2f} s")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from cosim.analysis.report import report

    log = Path(args.log)
    print(report(log, Path(args.out) if args.out else log.with_suffix(".html")))
    return 0


def cmd_campaign(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from cosim.campaign.coordinator import require_extras, run_campaign
    from cosim.campaign.spec import load_campaign

    campaign = load_campaign(args.file)
    require_extras(args.engine)
    console = _console(stderr=True)
    spec = campaign.spec
    console.print(
        f"[bold]{escape(spec.name)}[/bold]: {campaign.size} runs of {escape(campaign.base.source)} "
        f"({len(campaign.grid)} settings × {len(spec.replicates)} replicates, {spec.bus} bus) into "
        f"{escape(str(args.out))}"
    )
    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[failed]} failed"),
        TextColumn("{task.fields[per_run]}"),
        TimeElapsedColumn(),
        TextColumn("ETA {task.fields[eta]}"),
    )
    with Progress(*columns, console=console, transient=False, disable=args.quiet) as progress:
        task = progress.add_task("runs", total=campaign.size, failed=0, per_run="", eta="-")

        def started(description: str, workers: int) -> None:
            console.print(f"engine: {escape(description)}")

        def update(p) -> None:
            eta = "-" if p.eta_s is None else time.strftime("%H:%M:%S", time.gmtime(p.eta_s))
            progress.update(task, completed=p.done, failed=p.failed, per_run=f"{p.mean_run_s:.2f} s/run", eta=eta)

        result = run_campaign(
            campaign,
            args.out,
            engine=args.engine,
            workers=args.workers,
            address=args.address,
            resume=args.resume,
            keep_logs=args.keep_logs,
            on_progress=update,
            on_start=started,
        )
    resumed = f" ({result.resumed} from an earlier session)" if result.resumed else ""
    console.print(
        f"done: {result.runs} runs{resumed}, {result.failed} failed, in {result.wall_time:.1f} s on "
        f"{escape(result.engine)}"
    )
    print(result.path)
    return 0


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
    _console().print(table)
    return 0


def cmd_leaderboard(args: argparse.Namespace) -> int:
    import orjson

    from cosim.campaign.leaderboard import leaderboard

    board = leaderboard(args.results, args.by)
    if args.html:
        from cosim.campaign.page import write_page

        _console(stderr=True).print(f"wrote {escape(str(write_page(board, args.html)))}")
    if args.json:
        sys.stdout.write(orjson.dumps(board, option=orjson.OPT_INDENT_2).decode() + "\n")
        return 0
    _render_leaderboard(board, _console(), markdown=args.markdown)
    return 0


def _leaderboard_rows(group: dict, unit: str) -> tuple[list[str], list[list[str]]]:
    """The headers and rows of one group of a leaderboard, as text."""

    def num(value) -> str:
        return "-" if value is None else f"{value:.4g}"

    def pct(value) -> str:
        return "-" if value is None else f"{100 * value:.1f} %"

    diagnosis = any(s["diagnoses"] for s in group["ranking"])
    headers = ["#", "estimator", "kind", "runs", f"RMS p50 [{unit}]" if unit else "RMS p50", "p90", "rejection"]
    if diagnosis:
        headers += ["detected", "missed", "false alarms/h", "delay p50 [s]", "isolation p50 [s]", "isolated right"]
    rows = []
    for s in group["ranking"]:
        cells = [
            str(s["rank"]),
            s["estimator"],
            s["kind"],
            f"{s['runs']}" + (f" +{s['failed']}!" if s["failed"] else ""),
            num(s["rms_post_fault_median"]),
            num(s["rms_post_fault_p90"]),
            num(s["bias_rejection_median"]),
        ]
        if diagnosis:
            cells += [
                pct(s["detection_rate"]),
                str(s["missed_detections"] if s["missed_detections"] is not None else "-"),
                num(s["false_alarms_per_hour"]),
                num(s["detection_delay_median_s"]),
                num(s["isolation_delay_median_s"]),
                pct(s["isolation_accuracy"]),
            ]
        rows.append(cells)
    return headers, rows


def _render_leaderboard(board: dict, console: Console, markdown: bool = False) -> None:
    unit = board["units"].get("rms_post_fault") or ""
    name = str(board.get("campaign") or board["table"])
    summary = f"{board['runs']} runs, {board['failed_runs']} failed; ranked per {', '.join(board['by'])}"
    if markdown:  # for documents: plain GitHub tables, one per group
        lines = [f"**{name}**: {summary}", ""]
        for group in board["groups"]:
            headers, rows = _leaderboard_rows(group, unit)
            lines += [", ".join(f"{k} = {v}" for k, v in group["group"].items()), ""]
            lines += ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
            lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
        sys.stdout.write("\n".join(lines))
        return
    console.print(f"[bold]{escape(name)}[/bold]: {summary}")
    for group in board["groups"]:
        title = ", ".join(f"{k} = {v}" for k, v in group["group"].items())
        table = Table(title=escape(title), title_justify="left", box=None, header_style="bold")
        headers, rows = _leaderboard_rows(group, unit)
        for i, header in enumerate(headers):
            table.add_column(header, justify="left" if 0 < i < 3 else "right")
        for row in rows:
            table.add_row(*map(escape, row))
        console.print(table)
    if board["outliers"]:
        console.print(f"{len(board['outliers'])} outliers and failed runs: see --json or --html")


def cmd_recover(args: argparse.Namespace) -> int:
    from cosim.log.recover import recover

    result = recover(args.log, args.out)
    console = _console(stderr=True)
    console.print(
        f"recovered {result.messages} messages on {result.channels} channels, {result.metadata} metadata records and "
        f"{result.attachments} attachments (to t = {(result.last_time_ns or 0) / 1e9:g} s)"
    )
    if result.damage:
        console.print(f"[yellow]{escape(result.damage)}[/yellow]")
    for warning in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    print(result.path)
    return 0


def cmd_dbc(args: argparse.Namespace) -> int:
    from cosim import scenario

    _check_scenario_name(args.scenario)
    text = scenario.load(args.scenario).scenario.codec().dbc
    if args.out:
        Path(args.out).write_text(text)
        _console(stderr=True).print(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def cmd_fmu(args: argparse.Namespace) -> int:
    from cosim import scenario
    from cosim.run.fmu_export import export

    _check_scenario_name(args.scenario)
    settings = [scenario.parse_setting(text) for text in args.set or []]
    settings += [("seed", args.seed)] if args.seed is not None else []
    loaded = scenario.apply(scenario.load(args.scenario), settings)
    _console(stderr=True).print(f"wrote {export(loaded, Path(args.out))}")
    return 0


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: give at least 1")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative; seeds are >= 0")
    return value


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value}: ports are 0-65535 (0: a free one)")
    return value


def _dpi(text: str) -> int:
    value = _positive(text)
    if value > 2400:
        raise argparse.ArgumentTypeError(f"{value}: at most 2400 dots per inch")
    return value


def _foxglove_options(p: argparse.ArgumentParser, help: str) -> None:
    p.add_argument("--foxglove", nargs="?", const=8765, type=_port, metavar="PORT", help=help)
    p.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="HOST",
        help="--foxglove: the address to serve on (default 127.0.0.1, this machine only; 0.0.0.0: every interface)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cosim",
        description="Co-simulation testbed for fault-tolerant state estimation: a MuJoCo plant, injected "
        "faults, sensor readings and estimates as CAN frames, everything logged to MCAP.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"cosim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "run",
        help="run a scenario and log it to MCAP",
        description="Run a scenario: simulate the plant, "
        "inject faults, carry readings and estimates over CAN, and write everything to an MCAP log.",
    )
    p.add_argument(
        "scenario",
        nargs="?",
        metavar="SCENARIO",
        help="built-in scenario name or path to a TOML file (default: masses-bias)",
    )
    p.add_argument(
        "--out", "-o", metavar="FILE.mcap", help="where to write the log (default: runs/<scenario>-seed<N>-<time>.mcap)"
    )
    p.add_argument(
        "--seed", type=_seed, metavar="N", help="random seed for noise and faults, >= 0 (default: the scenario's)"
    )
    p.add_argument(
        "--interface",
        choices=("udp_multicast", "socketcan", "virtual"),
        help="bus transport (default: the scenario's, udp_multicast unless it says otherwise)",
    )
    p.add_argument(
        "--channel", help="bus channel: multicast group, CAN interface or virtual channel (default: a fresh one)"
    )
    p.add_argument("--port", type=int, help="udp_multicast port (default: a free one)")
    p.add_argument(
        "--allow-network",
        action="store_true",
        help="udp_multicast: allow a --channel whose frames leave this host (link-local or wider group)",
    )
    p.add_argument("--mode", choices=("lockstep", "realtime"), help="timing (default: the scenario's, lockstep)")
    p.add_argument("--speed", type=float, metavar="X", help="realtime: simulated seconds per wall-clock second")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="change the scenario: KEY a path into it (duration, faults[0].value, estimators[1].params.epsilon, "
        'bus.fd), VALUE in TOML (5, [0.5, 0, 0], "text", true); repeat for several; validated like the file',
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")
    p.add_argument(
        "--json",
        action="store_true",
        help="print the run's summary as JSON on standard output (path, status, ticks, frames, lost, "
        "real-time factor, ...) instead of the log's path",
    )
    _foxglove_options(
        p,
        "serve the run live over the Foxglove WebSocket protocol on PORT (default 8765; 0: a free "
        "one) and wait up to [timing] join_timeout for Foxglove to subscribe before tick 0",
    )
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "node",
        help="run one estimator (or the controller) as a CAN node",
        description="Run one estimator, "
        "or the controller of a closed-loop scenario (NAME 'controller'), as a node on a co-simulation's bus. "
        "'cosim run' starts its nodes this way (with --spec). Without --spec the node joins the running "
        "co-simulation, whose scenario marks it 'external = true' (to run it by hand, e.g. in a debugger).",
    )
    p.add_argument("estimator", metavar="NAME", help="the estimator's name in the scenario, or 'controller'")
    p.add_argument("--spec", metavar="FILE.json", help="the node spec written by 'cosim run'")
    p.add_argument("--run", metavar="ID", help="which running co-simulation (default: the only one)")
    p.set_defaults(func=cmd_node)

    p = sub.add_parser(
        "monitor",
        help="show a running co-simulation's signals live",
        description="Attach to a running co-simulation and show its decoded signals live, message by message.",
    )
    p.add_argument("--run", metavar="ID", help="which running co-simulation (default: the only one)")
    p.set_defaults(func=cmd_monitor)

    p = sub.add_parser("scenarios", help="list the built-in scenarios", description="List the built-in scenarios.")
    p.add_argument(
        "--json",
        action="store_true",
        help="print a JSON list: name, default, description, plant, duration_s, sample_time_s, estimators, bus, "
        "error (null unless the file is invalid)",
    )
    p.set_defaults(func=cmd_scenarios)

    p = sub.add_parser(
        "inspect",
        help="summarize a log",
        description="Summarize a run log: channels and message counts, "
        "duration, scenario, frame counts, and per estimator the RMS of |x - x̂| before and after the first fault.",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--json", action="store_true", help="print one JSON object (stable keys, for other tools)")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser(
        "plot",
        help="draw a log's figures (PNG, SVG or PDF)",
        description="Draw the figures of a run log: the state against every estimate, estimation errors per "
        "estimator, the injected faults, and what the estimators publish (pseudoinverse weights s, z or Γ, the "
        "fault's effect |h_Γ|, |Γ|, bias estimates φ̂ against the true fault, residuals, gain estimates, COFD "
        "residuals, the trajectory of a closed loop). Axes carry units; text is in the figure (nothing clipped).",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--out", "-o", metavar="DIR", help="output directory (default: FILE-plots next to the log)")
    p.add_argument(
        "--format",
        choices=("png", "svg", "pdf"),
        default="png",
        help="png (default; raster at --dpi), svg or pdf (vector, text as text: for papers)",
    )
    p.add_argument("--dpi", type=_dpi, default=150, metavar="N", help="dots per inch of PNG figures (default 150)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser(
        "export",
        help="export a log for other tools (CSV, Parquet, BLF, MF4, candump)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Export a run log for the tools engineers already use. The log is streamed: any length fits in "
        "memory.\n\n"
        "tables, one row per tick, columns tick, 't [s]' (simulated time), then '<topic>.<field> [unit]' for the\n"
        "truth and the decoded bus signals (state.x1 [m], faults.measured.x2 [m], EST_kalman.xhat_v1 [m/s], ...):\n"
        "  csv       text; floats as the shortest decimal that reads back exactly\n"
        "  parquet   columnar, units and source topic in each field's metadata\n"
        "raw CAN frames, every frame on the bus, timestamped with simulated time:\n"
        "  blf       Vector binary log (CANalyzer, CANoe, python-can)\n"
        "  mf4       ASAM MDF4 bus log, CAN_DataFrame layout, the DBC attached (asammdf, CANalyzer)\n"
        "  candump   text log of 'candump -L': (t) can0 ID#DATA, ID##<flags>DATA for CAN FD (can-utils,\n"
        "            SavvyCAN, cantools, python-can)\n\n"
        "Decode frames with the DBC from 'cosim dbc SCENARIO' (the MF4 file carries it).",
        epilog="examples:\n  cosim export runs/my.mcap --to csv\n  cosim export runs/my.mcap --to mf4 --out bus.mf4",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--to", required=True, choices=("csv", "parquet", "blf", "mf4", "candump"), help="output format")
    p.add_argument(
        "--out",
        "-o",
        metavar="PATH",
        help="output file (default: FILE.csv, .parquet, .blf, .mf4 or .log next to the log)",
    )
    p.add_argument(
        "--dbc", metavar="FILE.dbc", help="mf4 only: the DBC to attach, for a log that has none (default: the log's)"
    )
    p.add_argument(
        "--start-time",
        metavar="WHEN",
        help="blf, mf4, candump: the wall-clock time of tick 0, an ISO 8601 date and time (2025-06-01T12:00:00Z; UTC "
        "without a zone) or seconds since the Unix epoch; 0: the epoch (t = 0 s) (default: when the run started, "
        "to the millisecond)",
    )
    p.set_defaults(func=cmd_export)

    p = sub.add_parser(
        "layout",
        help="write a Foxglove layout for a log or a scenario",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Write a Foxglove layout for a run: estimates against the truth per state, estimation errors "
        "(a user\nscript), the injected faults, diagnosis flags and residuals, and the trajectory of a planar "
        "plant. Every message\npath is a topic and field of the run's log. Open the log in Foxglove, then Layouts → "
        "Import from file.",
        epilog="examples:\n  cosim layout runs/my.mcap --out my-layout.json\n"
        "  cosim layout masses-faults-fd --out fd-layout.json   (for the scenario's logs and its live runs)",
    )
    p.add_argument(
        "target",
        nargs="?",
        metavar="LOG|SCENARIO",
        help="a run log (FILE.mcap), or a built-in scenario or TOML file (default: masses-bias)",
    )
    p.add_argument(
        "--out",
        "-o",
        metavar="FILE.json",
        help="output file (default: FILE.layout.json next to the log, or <scenario>.layout.json)",
    )
    p.set_defaults(func=cmd_layout)

    p = sub.add_parser(
        "replay",
        help="feed a log's bus traffic to an estimator, or play it onto a live bus",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Replay a run log without simulating the plant again.\n\n"
        "With --estimator: the frames the runner put on the bus (SYNC, sensor and command frames, tick by tick, as\n"
        "the bus delivered them: frames a dropout kept off the bus stay off) go to one estimator, a 'cosim node'\n"
        "process on a bus of its own, in lockstep. The new log holds the original truth, those frames, the\n"
        "estimator's answers, and 'cosim.replay' metadata. An estimator of the run, unchanged, reproduces its\n"
        "logged frames bit for bit (its design is taken from the log); --param changes its parameters (and\n"
        "designs it again); --kind makes a new one, designed on the linear model the log records.\n\n"
        "With --live: every frame of the log goes onto a bus at its simulated time over --speed, like canplayer,\n"
        "for external tools and clients (decode with 'cosim dbc').\n\n"
        "With --foxglove: every message of the log (every topic) goes to Foxglove over its WebSocket protocol, at\n"
        "its simulated time over --speed, stamped at the run's start plus simulated time.",
        epilog="examples:\n"
        "  cosim replay runs/my.mcap --estimator kalman --out kalman-again.mcap\n"
        "  cosim replay runs/my.mcap --estimator kalman --param measurement_std=0.01 --out kf-0.01.mcap\n"
        "  cosim replay runs/my.mcap --estimator kf2 --kind kalman --param 'x0=[0, 0, 0, 0]'\n"
        "  cosim replay runs/my.mcap --live --speed 0.5\n"
        "  cosim replay runs/my.mcap --live --interface socketcan --channel vcan0\n"
        "  cosim replay runs/my.mcap --foxglove --speed 2",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument(
        "--estimator",
        "-e",
        metavar="NAME",
        help="the estimator to feed: one of the run's, or the name of a new one (with --kind)",
    )
    p.add_argument(
        "--kind", metavar="KIND", help="a new estimator of this kind (pseudoinverse, kalman, adaptive, uio, ...)"
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help='an estimator parameter, VALUE in TOML syntax (0.5, [0.8, 0.9], "text"); repeat for several',
    )
    p.add_argument(
        "--out", "-o", metavar="NEW.mcap", help="where to write the replay's log (default: FILE-replay-NAME.mcap)"
    )
    p.add_argument("--live", action="store_true", help="play every frame of the log onto a bus in real time instead")
    p.add_argument(
        "--speed",
        type=float,
        metavar="X",
        help="--live, --foxglove: simulated seconds per wall-clock second (default 1)",
    )
    p.add_argument(
        "--interface", choices=("udp_multicast", "socketcan", "virtual"), help="bus transport (default: udp_multicast)"
    )
    p.add_argument("--channel", help="bus channel: multicast group or CAN interface (default: a fresh group)")
    p.add_argument("--port", type=int, help="udp_multicast port (default: a free one)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")
    _foxglove_options(
        p,
        "serve every message of the log over the Foxglove WebSocket protocol on PORT (default 8765; 0: a free one), "
        "at its simulated time over --speed (0: at once), once Foxglove has subscribed",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=60.0,
        metavar="S",
        help="--foxglove: how long to wait for Foxglove to subscribe before playing (default 60 s)",
    )
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser(
        "report",
        help="write a self-contained HTML report of a log",
        description="Write one HTML page about a run log: the scenario and its settings, the metrics "
        "of 'cosim inspect' as tables, and the figures of 'cosim plot'. The page is self-contained "
        "(figures inlined, no network needed) and reads on a laptop and on a phone.",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--out", "-o", metavar="REPORT.html", help="output file (default: FILE.html next to the log)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser(
        "campaign",
        help="run a campaign of many runs on a distributed engine",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run a campaign: a base scenario over seeds, axes (a grid of settings) and sampled settings, "
        "every run\non a Dask cluster (a local one with a worker per core, or one joined with --address), into "
        "one table,\nDIR/results.parquet: a row per run and estimator, every metric of 'cosim inspect' with units. "
        "A run that\nfails is a row with its error; --resume after a kill redoes only the runs that did not finish.\n"
        "The file's format is in docs/campaigns.md; 'cosim campaigns' lists the built-in ones.",
        epilog="examples:\n  cosim campaign masses-bias-sweep --out runs/sweep\n"
        "  cosim campaign my-campaign.toml --out runs/mine --workers 2 --keep-logs all\n"
        "  cosim campaign my-campaign.toml --out runs/mine --resume\n"
        "  cosim campaign my-campaign.toml --out runs/big --address tcp://10.0.0.5:8786",
    )
    p.add_argument("file", metavar="FILE", help="a built-in campaign or a campaign TOML file")
    p.add_argument(
        "--out", "-o", required=True, metavar="DIR", help="the campaign's folder (new, or with --resume its own)"
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
        "--workers", type=_positive, metavar="N", help="local cluster: worker processes (default: one per core)"
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
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")
    p.set_defaults(func=cmd_campaign)

    p = sub.add_parser("campaigns", help="list the built-in campaigns", description="List the built-in campaigns.")
    p.set_defaults(func=cmd_campaigns)

    p = sub.add_parser(
        "leaderboard",
        help="rank a campaign's estimators",
        description="Rank the estimators of a campaign's results table per group of runs (the fault kind by default): "
        "RMS error after onset (median, p90, bootstrap interval), bias rejection, detection rate, missed detections, "
        "false alarms per hour, detection and isolation delays, isolation accuracy, with 95 % intervals.",
    )
    p.add_argument("results", metavar="RESULTS.parquet", help="a campaign's DIR/results.parquet")
    p.add_argument("--by", nargs="+", metavar="COLUMN", help="group by these columns (default: fault_kind)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--html", metavar="FILE", help="also write a self-contained HTML page with figures and outliers")
    p.add_argument("--markdown", action="store_true", help="print the tables as Markdown (for documents)")
    p.set_defaults(func=cmd_leaderboard)

    p = sub.add_parser(
        "recover",
        help="rebuild a log whose writer died (summary, indexes)",
        description="Rebuild the summary and indexes of a log whose writer died (a runner killed with SIGKILL, a "
        "full disk): its records are read in order, CRCs checked, up to the first damaged one, and written into a "
        "complete MCAP file that every reader opens (mcap's make_reader, @mcap/core, Foxglove). A record "
        "'cosim.recovered' says what was found. Without --out the log is replaced, once the new file is complete.",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--out", "-o", metavar="FIXED.mcap", help="write the recovered log here instead of replacing FILE")
    p.set_defaults(func=cmd_recover)

    p = sub.add_parser(
        "dbc",
        help="write the CAN database of a scenario",
        description="Write the DBC database of a scenario's bus, so that external tools can decode its frames.",
    )
    p.add_argument(
        "scenario", nargs="?", metavar="SCENARIO", help="built-in scenario name or TOML path (default: masses-bias)"
    )
    p.add_argument("--out", "-o", metavar="FILE.dbc", help="output file (default: standard output)")
    p.set_defaults(func=cmd_dbc)

    p = sub.add_parser(
        "fmu",
        help="export a scenario's plant with its faults as an FMU",
        description="Package the scenario's plant with its sensor and actuator faults, noise and disturbances "
        "(seeded) as an FMI 3.0 co-simulation FMU (docs/fmi.md).",
    )
    p.add_argument("scenario", metavar="SCENARIO", help="built-in scenario name or TOML path")
    p.add_argument("--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write")
    p.add_argument("--seed", type=int, metavar="N", help="the seed of its noise, faults and disturbances")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="change a scenario field (repeatable)")
    p.set_defaults(func=cmd_fmu)
    return parser


def _feature(args: argparse.Namespace) -> str:
    """The command as the user gave it, for messages: ``cosim export --to mf4``."""
    feature = f"cosim {args.command}"
    if getattr(args, "to", None):
        feature += f" --to {args.to}"
    if getattr(args, "foxglove", None) is not None:
        feature += " --foxglove"
    return feature


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except CosimError as error:
        _console(stderr=True).print(f"[red]error:[/red] {escape(str(error))}")
        return 1
    except ImportError as error:  # a package of an optional extra that is not installed
        from cosim.extras import missing_extra

        missing = missing_extra(error, _feature(args))
        if missing is None:
            raise
        _console(stderr=True).print(f"[red]error:[/red] {escape(str(missing))}")
        return 1
    except OSError as error:  # the log or DBC cannot be written, a path is a directory, ...
        _console(stderr=True).print(f"[red]error:[/red] {escape(str(error))}")
        return 1
    except KeyboardInterrupt as interrupt:
        return 128 + getattr(interrupt, "signum", signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
