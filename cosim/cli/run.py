"""Run a scenario and log it to MCAP.

Run a scenario: simulate the plant, inject faults, carry readings and estimates over CAN, and write
everything to an MCAP log.

Exit status: 0 when the run completed; 4 when it completed but an estimator failed during it (its
step raised: the run went on without it, and 'failed' in --json, the log's /cosim/events and
'cosim inspect' say why); 3 when it completed with contested ticks (another program sent on the
runner's own ids, so estimates may rest on forged frames), unless 4 applies; 1 on an error; 130 or
143 when interrupted (Ctrl-C, SIGTERM): the log holds everything up to then.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

from cosim import progress
from cosim.cli import common
from cosim.errors import CosimError

#: The exit status of a run that completed with contested ticks (and no estimator failed).
CONTESTED = 3

if TYPE_CHECKING:
    from cosim.log.live import FoxgloveSink
    from cosim.run import Run
    from cosim.run.outcome import RunResult
    from cosim.scenario import Scenario


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", metavar="SCENARIO", help=f"{common.SCENARIO_HELP} (default: masses-bias)")
    p.add_argument(
        "--out",
        "-o",
        metavar="FILE.mcap",
        help="where to write the log (default: runs/<scenario>-seed<N>-<time>.mcap, numbered if it exists)",
    )
    common.force_option(p)
    p.add_argument(
        "--seed", type=common.seed, metavar="N", help="random seed for noise and faults, >= 0 (default: the scenario's)"
    )
    common.bus_options(p, "the scenario's, udp_multicast unless it says otherwise")
    p.add_argument(
        "--allow-network",
        action="store_true",
        help="udp_multicast: allow a --channel whose frames leave this host (link-local or wider group)",
    )
    p.add_argument(
        "--mirror",
        action="store_true",
        help="udp_multicast: also send every frame alone to a second group, for programs that can only open "
        "python-can's udp_multicast (printed at the start; [bus] mirror)",
    )
    p.add_argument("--mode", choices=("lockstep", "realtime"), help="timing (default: the scenario's, lockstep)")
    p.add_argument("--speed", type=float, metavar="X", help="realtime: simulated seconds per wall-clock second")
    common.set_option(p)
    p.add_argument(
        "--no-validate",
        action="store_true",
        help="an FMU plant: run it even if its modelDescription.xml breaks the FMI schema "
        "([plant.fmu] validate = false)",
    )
    common.quiet_option(p)
    p.add_argument(
        "--json",
        action="store_true",
        help="print the run's summary as JSON on standard output (path, status, ticks, frames, lost, "
        "real-time factor, ...) instead of the log's path",
    )
    common.foxglove_options(
        p,
        "serve the run live over the Foxglove WebSocket protocol on PORT (default 8765; 0: a free "
        "one) and wait up to [timing] join_timeout for Foxglove to subscribe before tick 0 (not counted in the "
        "run's timing)",
    )


def main(args: argparse.Namespace) -> int:
    from cosim.run.interrupts import terminate_like_ctrl_c

    talk = common.console(stderr=True, quiet=args.quiet)
    with common.preparing(talk) as preparation, terminate_like_ctrl_c():
        try:
            run, out = _prepared(args)
        except KeyboardInterrupt as interrupt:  # Ctrl-C or SIGTERM before the run's session
            return _interrupted_while_preparing(interrupt, args.json)
        return _run(args, run, out, talk, preparation)


def _interrupted_while_preparing(interrupt: KeyboardInterrupt, json: bool) -> int:
    """One line (with the call an FMU was in, if it hung), nothing else: no log was begun."""
    detail = getattr(interrupt, "detail", "")
    why = f": {escape(detail)}" if detail else ""
    common.error_console().print(f"[yellow]interrupted while preparing the run[/yellow]{why}; no log was written")
    if json:
        common.print_json({"path": None, "status": "interrupted", "error": detail})
    return common.exit_code(interrupt)


def _prepared(args: argparse.Namespace) -> tuple[Run, Path]:
    """The run as the arguments ask (its plan made) and where it will write its log."""
    from cosim.extras import EXTRAS
    from cosim.run import Run
    from cosim.run.needs import Needs

    # not a progress step: a bad file's error stays one line, however slow the imports
    loaded = common.load_scenario(args.scenario, args.set, no_validate=args.no_validate)
    needs = Needs("cosim run", {"live": list(EXTRAS["live"])} if args.foxglove is not None else {})
    needs.add(loaded.scenario.name, loaded.scenario)
    needs.check()  # every missing extra at once where one the run cannot start without is among them
    seed = loaded.scenario.seed if args.seed is None else args.seed
    default = Path("runs") / f"{loaded.scenario.name}-seed{seed}-{common.stamp()}.mcap"
    out = common.new_output(args.out, default, args.force)
    _check_options(args, loaded.scenario)
    run = Run(
        loaded,
        out,
        args.seed,
        **common.picked(args, "interface", "channel", "port", "mode", "speed"),
        allow_network=True if args.allow_network else None,
        mirror=True if args.mirror else None,
    )
    return run, out


def _run(args: argparse.Namespace, run: Run, out: Path, talk: Console, preparation: common.Preparation | None) -> int:
    s = run.scenario
    timing = "lockstep" if s.timing.mode == "lockstep" else f"realtime at {s.timing.speed:g}x"
    talk.print(
        f"[bold]{escape(s.name)}[/bold]: {s.plant.model}, {s.ticks} ticks of {s.sample_time:g} s, seed {s.seed}, "
        f"{timing}; estimators: {', '.join(run.estimators) or 'none'} ({'CAN FD' if s.bus.fd else 'classic CAN'})"
    )
    if run.plan.operating_point:
        talk.print(f"design model: {escape(run.plan.operating_point)}")
    common.warn(common.error_console() if args.quiet else talk, run.warnings)
    sink = common.foxglove_sink(args, "cosim run --foxglove") if args.foxglove is not None else None
    try:
        result = common.with_progress(run, talk, lambda run: _started(run, talk, sink), preparation, sink=sink)
    except KeyboardInterrupt as interrupt:
        r = run.result
        done = f" after {r.ticks} ticks (t = {r.sim_time:g} s)" if r else ""
        detail = getattr(interrupt, "detail", "")
        why = f": {escape(detail)}" if detail else ""
        common.error_console().print(f"[yellow]interrupted{done}[/yellow]{why}; {common.where_the_log_is(out)}")
        _said(run, talk)
        if args.json:
            common.print_json(summary(r, out, detail))
        return common.exit_code(interrupt)
    except CosimError as error:
        common.error_console().print(f"[red]error:[/red] {escape(str(error))}; {common.where_the_log_is(out)}")
        _said(run, talk)
        if args.json:
            common.print_json(summary(run.result, out, str(error)))
        return 1
    finally:
        if sink is not None:
            sink.close()
    _report(result, s, talk)
    _said(run, talk)
    if args.json:
        common.print_json(summary(result, out))
    else:
        print(out)
    return common.ESTIMATOR_FAILED if result.failed else CONTESTED if result.contested_ticks else 0


def _said(run: Run, talk: Console) -> None:
    """What an FMU plant logged and printed, in one line (each message is in the log)."""
    if run.plant_said:
        talk.print(f"  {escape(run.plant_said)} (each in the log's /plant/fmu)")


def _check_options(args: argparse.Namespace, s: Scenario) -> None:
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


def summary(result: RunResult | None, out: Path, error: str = "") -> dict[str, Any]:
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
        "failed": result.failed,
        "late_ticks": result.late_ticks,
        "contested_ticks": result.contested_ticks,
        "kernel_dropped": result.kernel_dropped,
        "error": result.error or error,
    }


def _started(run: Run, talk: Console, sink: FoxgloveSink | None) -> None:
    """Said once the nodes are started: where the bus is, and what the run waits for."""
    s = run.scenario
    talk.print(f"run {run.run_id} on {common.joining(run.bus)}")
    if sink is not None:
        wait = s.timing.join_timeout
        pace = "" if s.timing.mode == "realtime" else " (lockstep runs faster than real time: --mode realtime paces it)"
        talk.print(
            f"Foxglove: open connection {sink.url} (Foxglove WebSocket), or {sink.app_url()}; "
            f"waiting up to {wait:g} s for it to subscribe{pace}"
        )
        interrupts = run.session.interrupts
        with progress.step("waiting for a Foxglove client to subscribe"):
            subscribed = sink.wait_for_viewer(wait, interrupted=lambda: interrupts.requested is not None)
        if not subscribed:
            talk.print("[yellow]no Foxglove client subscribed; running anyway[/yellow]")
    external = [c.name for c in s.clients] + [e.name for e in s.estimators if e.external]
    external += ["controller"] if s.controller is not None and s.controller.external else []
    if external:
        talk.print(
            f"waiting up to {s.timing.join_timeout:g} s for {', '.join(external)} to join "
            f"(cosim node NAME --run {run.run_id}, or your client)"
        )


def _report(result: RunResult, s: Scenario, talk: Console) -> None:
    misses = f", {result.deadline_misses} deadline misses" if s.timing.mode == "realtime" else ""
    talk.print(
        f"done: {result.ticks} ticks, {result.frames} frames ({result.frames_lost} lost{misses}) in "
        f"{result.wall_time:.2f} s (real-time factor {result.realtime_factor:.1f})"
    )
    for warning in result.warnings:
        if any(what in warning for what in ("fell behind", "contested ticks", "kernel dropped")):
            talk.print(f"[yellow]  {escape(warning)}[/yellow]")
    common.say_failed(talk, result)
    for name, counts in result.senders.items():
        if counts["lost"] or counts["runner_frames_missed"]:
            talk.print(
                f"[yellow]  {name}: {counts['lost']} of its frames lost on the way to the runner, "
                f"{counts['runner_frames_missed']} of the runner's frames missed by it[/yellow]"
            )
