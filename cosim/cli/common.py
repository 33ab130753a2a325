"""What the commands share: the console, argument types and option groups, progress display, and
how an output's default name is chosen and an existing file is kept."""

from __future__ import annotations

import argparse
import difflib
import signal
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

from cosim.errors import CosimError

if TYPE_CHECKING:
    from cosim.bus.transport import BusConfig
    from cosim.log.live import FoxgloveSink
    from cosim.run import Run
    from cosim.run.needs import Needs
    from cosim.run.outcome import Progress as RunProgress
    from cosim.run.outcome import RunResult
    from cosim.run.replay import Replay
    from cosim.scenario import LoadedScenario

LOG_HELP = "a run log, or 'latest': the newest runs/*.mcap"
#: The exit status of a run or replay that completed without an estimator that failed during it.
ESTIMATOR_FAILED = 4
SCENARIO_HELP = "a built-in scenario ('cosim scenarios' lists them) or a TOML file"


def console(stderr: bool = False, quiet: bool = False, wide: bool = False) -> Console:
    """The console commands talk on; ``quiet``: nothing but errors (``-q``); ``wide``: tables keep
    their rows whole when written to a file or a pipe (rich would wrap them at 80 columns)."""
    stream = sys.stderr if stderr else sys.stdout
    width = 250 if wide and not stream.isatty() else None
    return Console(stderr=stderr, highlight=False, soft_wrap=True, quiet=quiet, width=width)


def error_console() -> Console:
    return console(stderr=True)


def print_json(value: Any) -> None:
    import orjson

    sys.stdout.write(orjson.dumps(value, option=orjson.OPT_INDENT_2).decode() + "\n")


def warn(talk: Console, warnings: Iterable[str]) -> None:
    for warning in warnings:
        talk.print(f"[yellow]warning:[/yellow] {escape(warning)}")


def check_needs(talk: Console, needs: Needs) -> None:
    """Every extra a command needs, checked at once before it starts: one error line naming all
    that are missing, or the warning of a design's extra its runs would fail without."""
    warning = needs.check()
    if warning is not None:
        warn(talk, [warning])


def check_scenario_name(name: str | None) -> None:
    """A scenario argument that is neither a file nor a built-in scenario: the error says which
    built-in names are near it."""
    from cosim import scenario

    if name is None or Path(name).exists() or name in scenario.builtin_names():
        return
    near = difflib.get_close_matches(name, scenario.builtin_names(), n=3, cutoff=0.6)
    hint = f"did you mean {' or '.join(near)}? " if near else ""
    kind = "file" if name.endswith(".toml") or "/" in name else "built-in scenario"
    raise CosimError(f"no {kind} {name!r}: {hint}('cosim scenarios' lists the built-in ones)")


def load_scenario(
    name: str | None, settings: list[str] | None, seed: int | None = None, no_validate: bool = False
) -> LoadedScenario:
    """A scenario by name or file, with the command line's ``--set`` (and ``--seed``) applied;
    ``no_validate``: an FMU plant's modelDescription.xml is not checked against the FMI schema."""
    from cosim import scenario

    check_scenario_name(name)
    changes = [scenario.parse_setting(text) for text in settings or []]
    changes += [("seed", seed)] if seed is not None else []
    if no_validate:
        changes.insert(0, ("plant.fmu.validate", False))
    if any(key == "plant.fmu.validate" for key, _ in changes):  # applied before validating: that refuses the FMU
        return scenario.load_with(name, changes)
    return scenario.apply(scenario.load(name), changes)


def picked(args: argparse.Namespace, *names: str) -> dict[str, Any]:
    """The options ``names`` as given, to pass on as keyword arguments of the same names."""
    return {name: getattr(args, name) for name in names}


def refuse(args: argparse.Namespace, flags: tuple[str, ...], why: str) -> None:
    """CosimError naming the first of ``flags`` the user gave, an option that would do nothing here."""
    for flag in flags:
        value = getattr(args, flag.removeprefix("--").replace("-", "_"))
        if value is not None and value is not False and value != [] and value != "":
            raise CosimError(f"{flag}: {why}")


def interrupted(talk: Console, interrupt: KeyboardInterrupt, where: str = "") -> int:
    """Ctrl-C (or SIGTERM, raised as KeyboardInterrupt with its signum): said, and the shell's exit code."""
    talk.print(f"[yellow]interrupted[/yellow]{where}")
    return exit_code(interrupt)


def exit_code(interrupt: KeyboardInterrupt) -> int:
    return 128 + getattr(interrupt, "signum", signal.SIGINT)


def say_failed(talk: Console, result: RunResult) -> None:
    """The estimators that failed during a run or replay, each in a line (status ``ESTIMATOR_FAILED``)."""
    for name, why in result.failed.items():
        talk.print(
            f"[yellow]  estimator {escape(name)} {escape(why)}; the run went on without it "
            "(its traceback: the log's /cosim/events)[/yellow]"
        )


def where_the_log_is(out: Path) -> str:
    return (
        f"the log up to that point is in {escape(str(out))}"
        if out.exists()
        else f"no log was written ({escape(str(out))} does not exist)"
    )


# -- outputs --------------------------------------------------------------------------------------


def new_output(given: str | None, default: Path, force: bool) -> Path:
    """Where a command writes: ``given`` (an existing file only with ``--force``), else ``default``,
    numbered (``-2``, ``-3``, ...) past the files that exist, so that two runs never share a log."""
    if given:
        return unused(Path(given), force)
    out, number = default, 1
    while out.exists():
        number += 1
        out = default.with_name(f"{default.stem}-{number}{default.suffix}")
    return out


def unused(out: Path, force: bool) -> Path:
    """``out``, which must not exist unless ``--force`` was given."""
    if out.exists() and not force and not out.is_dir():
        raise CosimError(f"{out} exists: choose another file, or pass --force to replace it")
    return out


def stamp() -> str:
    """The time in a default file name, to the second."""
    return time.strftime("%Y%m%d-%H%M%S")


def latest_log(name: str | None) -> str:
    """``latest`` (or nothing): the newest log under ``runs/``; anything else is a path."""
    if name not in (None, "latest"):
        return name
    logs = sorted(Path("runs").glob("*.mcap"), key=lambda p: p.stat().st_mtime)
    if not logs:
        raise CosimError("no logs in runs/ ('latest' is the newest runs/*.mcap): give the log's path")
    return str(logs[-1])


# -- argument types -------------------------------------------------------------------------------


def _integer(text: str, what: str = "an integer") -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None


def positive(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: give at least 1")
    return value


def seed(text: str) -> int:
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative; seeds are >= 0")
    return value


def port(text: str) -> int:
    value = _integer(text, "a port number")
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value}: ports are 0-65535 (0: a free one)")
    return value


def dpi(text: str) -> int:
    value = positive(text)
    if value > 2400:
        raise argparse.ArgumentTypeError(f"{value}: at most 2400 dots per inch")
    return value


# -- option groups --------------------------------------------------------------------------------

INTERFACES = ("udp_multicast", "socketcan", "virtual")


def bus_options(p: argparse.ArgumentParser, default: str) -> None:
    """--interface, --channel, --port: where the bus is."""
    p.add_argument("--interface", choices=INTERFACES, help=f"bus transport (default: {default})")
    p.add_argument(
        "--channel", help="bus channel: multicast group, CAN interface or virtual channel (default: a fresh one)"
    )
    p.add_argument("--port", type=port, help="udp_multicast port (default: a free one)")


def set_option(p: argparse.ArgumentParser, what: str | None = None) -> None:
    """--set KEY=VALUE, repeatable; ``what`` says what it changes (default: the scenario run)."""
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help=what
        or "change the scenario: KEY a path into it (duration, faults[0].value, estimators[1].params.epsilon, "
        'bus.fd), VALUE in TOML (5, [0.5, 0, 0], "text", true); repeat for several; validated like the file',
    )


def quiet_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors and the result's path")


def force_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", "-f", action="store_true", help="replace the output file if it exists")


def foxglove_options(p: argparse.ArgumentParser, help: str) -> None:
    p.add_argument("--foxglove", nargs="?", const=8765, type=port, metavar="PORT", help=help)
    p.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="HOST",
        help="--foxglove: the address to serve on (default 127.0.0.1, this machine only; 0.0.0.0: every interface)",
    )


def joining(bus: BusConfig) -> str:
    """Where a bus is, and how another program joins it."""
    if bus.interface == "virtual":
        return f"{bus.describe()} (in this process: no other program can join it)"
    line = f"{bus.describe()}   join with: {escape(bus.python_can())}"
    mirror = bus.mirror_kwargs()
    if mirror is not None:
        args = ", ".join(f"{key}={value!r}" for key, value in mirror.items())
        line += f"\n  every frame mirrored for python-can's udp_multicast: {escape(f'can.Bus({args})')}"
    return line


def foxglove_sink(args: argparse.Namespace, feature: str, start_ns: int | None = None) -> FoxgloveSink:
    from cosim.log.live import FoxgloveSink

    return FoxgloveSink(args.foxglove, host=args.foxglove_host, start_ns=start_ns, feature=feature)


# -- progress -------------------------------------------------------------------------------------


#: Slow work is shown once a command has been busy this long (s) without showing anything else, ...
SILENT_FOR = 2.0
#: ... and, as plain lines, each step that has lasted this long (s).
STEP_LASTED = 1.0


class Preparation:
    """The steps of slow work (``cosim.progress``), shown once the command has been busy for
    ``SILENT_FOR``: on a terminal a spinner with the step and the time since the start; otherwise a
    line (time since the start, the step) for each step that lasts ``STEP_LASTED``; until ``stop``
    (the first tick's progress bar, or the end of the command)."""

    def __init__(self, talk: Console) -> None:
        from rich.live import Live
        from rich.spinner import Spinner

        self.talk = talk
        self.started = self.since = time.perf_counter()
        self.steps: tuple[str, ...] = ()
        self.said: tuple[str, ...] = ()  # the steps of the last plain line
        self.spinner = Spinner("dots", style="cyan")
        self.live = Live(self.spinner, console=talk, transient=True, refresh_per_second=8) if talk.is_terminal else None
        self._lock = threading.Lock()
        self._stopped = threading.Event()
        self._watcher = threading.Thread(target=self._watch, name="cosim-preparation", daemon=True)
        self._watcher.start()

    def __call__(self, steps: tuple[str, ...]) -> None:
        with self._lock:
            self.steps, self.since = steps, time.perf_counter()

    def _watch(self) -> None:
        while not self._stopped.wait(0.1):
            with self._lock:
                now = time.perf_counter()
                if self.steps and now - self.started >= SILENT_FOR:
                    self._show(now)

    def _show(self, now: float) -> None:
        what = ": ".join(self.steps)
        if self.live is not None:
            self.spinner.update(text=f"{escape(what)}  [dim]{now - self.started:.0f} s[/dim]")
            if not self.live.is_started:
                self.live.start()
        elif now - self.since >= STEP_LASTED and self.steps != self.said[: len(self.steps)]:  # not a step left
            self.talk.print(f"{self.since - self.started:6.1f} s  {escape(what)}")
            self.said = self.steps

    def stop(self) -> None:
        """Shows nothing more (and takes the spinner away)."""
        self._stopped.set()
        self._watcher.join()
        if self.live is not None and self.live.is_started:
            self.live.stop()


@contextmanager
def preparing(talk: Console) -> Iterator[Preparation | None]:
    """Shows the steps of slow work done in the block (nothing when ``talk`` is quiet): the
    ``Preparation``, to stop when something else starts showing progress."""
    from cosim import progress

    if talk.quiet:
        yield None
        return
    shown = Preparation(talk)
    try:
        with progress.listening(shown):
            yield shown
    finally:
        shown.stop()


def with_progress(
    run: Run | Replay,
    talk: Console,
    started: Callable[[Any], None],
    preparation: Preparation | None = None,
    **execute: Any,
) -> RunResult:
    """``run.execute`` with a progress bar of its ticks (on ``talk``: none when it is quiet); the
    ``preparation`` shown until then stops at the first tick."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    if talk.quiet:
        return run.execute(on_start=started, **execute)
    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn("t = {task.fields[sim]:>7.2f} s"),
        TextColumn("{task.fields[rtf]:>6.1f}x real time"),
        TextColumn("{task.fields[frames]:>8d} frames"),
        TimeRemainingColumn(),
    )
    progress = Progress(*columns, console=talk, transient=False)
    task = progress.add_task("simulating", total=run.scenario.ticks, sim=0.0, rtf=0.0, frames=0)

    def update(p: RunProgress) -> None:
        if not progress.live.is_started:  # drawn from the first tick on: no empty bar before an error
            if preparation is not None:
                preparation.stop()
            progress.start()
        progress.update(task, completed=p.tick, sim=p.sim_time, rtf=p.realtime_factor, frames=p.frames)

    try:
        return run.execute(update, on_start=started, **execute)
    finally:
        if progress.live.is_started:
            progress.stop()


class ParagraphFormatter(argparse.RawDescriptionHelpFormatter):
    """Help text as paragraphs: each one filled to the terminal's width, except those with indented
    lines (a table of formats, examples), which are kept as they are written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = []
        for paragraph in textwrap.dedent(text).strip().split("\n\n"):
            if any(line.startswith(" ") for line in paragraph.splitlines()):
                paragraphs.append(textwrap.indent(paragraph, indent))
            else:
                paragraphs.append(
                    textwrap.fill(
                        " ".join(paragraph.split()),
                        width,
                        initial_indent=indent,
                        subsequent_indent=indent,
                        break_on_hyphens=False,
                    )
                )
        return "\n\n".join(paragraphs)


def command(sub: argparse._SubParsersAction, module: ModuleType) -> argparse.ArgumentParser:
    """The parser of a command module, named after it (or its ``NAME``): the docstring's first line is its help in
    ``cosim --help``, the rest its description; ``EPILOG`` (examples) and ``arguments`` (its
    options) where it has them; ``main`` runs it."""
    first, _, description = (module.__doc__ or "").partition("\n\n")
    help = first[0].lower() + first[1:].rstrip(".")
    name = getattr(module, "NAME", module.__name__.rpartition(".")[2])  # NAME: a command named by a keyword
    p = sub.add_parser(
        name,
        help=help,
        description=description.strip(),
        epilog=getattr(module, "EPILOG", None),
        formatter_class=ParagraphFormatter,
    )
    p.set_defaults(func=module.main)
    if hasattr(module, "arguments"):
        module.arguments(p)
    return p


def cluster_options(p: argparse.ArgumentParser) -> None:
    """--engine, --address and --workers: where a campaign's runs run."""
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
        "--workers", type=positive, metavar="N", help="local cluster: worker processes (default: one per core)"
    )


def engine_options(p: argparse.ArgumentParser, what: str) -> None:
    """``cluster_options``, --resume (of ``what``) and --batch: how a campaign's runs run."""
    cluster_options(p)
    p.add_argument("--resume", action="store_true", help=f"finish {what}: only the runs without results run")
    p.add_argument(
        "--batch",
        type=positive,
        metavar="K",
        help="runs of one configuration that differ in their seed step together, K at a time, in one process "
        "(default: chosen, up to 32; 1: one at a time); the results are the same bit for bit",
    )
