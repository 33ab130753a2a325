"""Run the standing benchmark: a fixed, versioned suite of faults and attacks, into a result bundle.

Run the benchmark suite (docs/benchmark.md): sensor and actuator faults on the masses, the three
tanks and the ship, fault-free hours for false alarms (the faults track), and attacks on the bus
(the attacks track), every case a campaign on the campaign engine with its seeds fixed by the
suite's version. Add your own estimators or diagnosis schemes with --estimator (a built-in kind or
a plugin's); each runs beside the suite's schemes on the same runs, so that every comparison is
paired. The bundle (DIR/results.parquet, DIR/bundle.json with the suite's version and digest) is
what 'cosim leaderboard DIR [DIR ...]' ranks, merged with other bundles of the same suite.
"""

from __future__ import annotations

import argparse
import tomllib
from typing import TYPE_CHECKING, Any

from rich.markup import escape

from cosim.cli import common

if TYPE_CHECKING:
    from collections.abc import Callable

    from rich.progress import Progress

    from cosim.campaign.benchmark import CaseSpec, Scheme, SuiteSpec
    from cosim.campaign.coordinator import CampaignProgress
    from cosim.campaign.spec import Campaign
    from cosim.run.needs import Needs

EPILOG = """\
examples:
  cosim benchmark --quick --out runs/bench-quick
  cosim benchmark --out runs/bench --estimator mine=mypackage.estimators:Mine --params 'mine={q = 0.1}'
  cosim leaderboard runs/bench runs/bench-of-a-colleague"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out", "-o", required=True, metavar="DIR", help="the bundle's folder (new, or with --resume its own)"
    )
    p.add_argument("--quick", action="store_true", help="each case's quick selection: a few minutes on two cores")
    p.add_argument(
        "--estimator",
        action="append",
        default=[],
        metavar="NAME=KIND",
        help="add an estimator or diagnosis scheme to every case (a built-in kind, package.module:Class or an "
        "entry point's name); repeat for several",
    )
    p.add_argument(
        "--params",
        action="append",
        default=[],
        metavar="NAME={...}",
        help="an added scheme's parameters, as a TOML inline table: 'mine={q = 0.1, poles = [0.5, 0.6]}'",
    )
    p.add_argument("--suite", metavar="FILE", help="another suite file (default: the built-in suite)")
    common.engine_options(p, "the bundle in DIR")
    common.quiet_option(p)


def schemes(estimators: list[str], params: list[str]) -> list[Scheme]:
    """The added schemes of --estimator NAME=KIND and --params NAME={...}."""
    from cosim.campaign.benchmark import Scheme
    from cosim.errors import CosimError
    from cosim.scenario.tables import loads_toml

    given: dict[str, dict[str, object]] = {}
    for text in params:
        name, _, table = text.partition("=")
        try:
            given[name.strip()] = loads_toml(f"params = {table.strip()}")["params"]
        except (tomllib.TOMLDecodeError, KeyError) as error:
            raise CosimError(f"--params {text}: not NAME={{key = value, ...}} ({error})") from None
    out = []
    for text in estimators:
        name, _, kind = text.partition("=")
        if not name.strip() or not kind.strip():
            raise CosimError(f"--estimator {text}: give NAME=KIND, e.g. mine=kalman")
        out.append(Scheme(name.strip(), kind.strip(), given.pop(name.strip(), {})))
    if given:
        raise CosimError(f"--params {', '.join(given)}: no --estimator of that name")
    return out


def main(args: argparse.Namespace) -> int:
    from cosim.campaign.benchmark import SUITE, load_suite, run_benchmark
    from cosim.cli.campaign import progress_display

    added = schemes(args.estimator, args.params)
    suite = load_suite(args.suite or SUITE)
    talk = common.console(stderr=True, quiet=args.quiet)
    common.check_needs(talk, suite_needs(suite, args.quick, added, args.engine))
    selection = "quick" if args.quick else "full"
    talk.print(
        f"[bold]{escape(suite.name)} v{suite.version}[/bold] ({selection}): {len(suite.cases)} cases into "
        f"{escape(str(args.out))}" + (f"; added: {', '.join(s.name for s in added)}" if added else "")
    )
    # one display, a line per case: a case's last runs finish while the next case's first run
    displays: dict[str, Callable[[CampaignProgress], None]] = {}
    shown: list[Progress] = []

    def on_case(case: CaseSpec, campaign: Campaign) -> None:
        name = escape(campaign.spec.name)
        talk.print(f"{escape(case.track)} / [bold]{escape(case.name)}[/bold]: {campaign.size} runs of {name}")
        progress, displays[case.name] = progress_display(
            talk, campaign.size, escape(case.name), shown[0] if shown else None
        )
        if not shown:
            progress.start()
            shown.append(progress)

    try:
        bundle = run_benchmark(
            args.out,
            quick=args.quick,
            schemes=added,
            suite_path=args.suite or SUITE,
            **common.picked(args, "engine", "workers", "address", "resume", "batch"),
            on_case=on_case,
            on_progress=lambda case, p: displays[case.name](p),
        )
    except KeyboardInterrupt as interrupt:
        return common.interrupted(
            common.error_console(),
            interrupt,
            f": the finished runs are kept in {escape(str(args.out))}; finish with the same command and --resume",
        )
    finally:
        for progress in shown:
            progress.stop()
    common.warn(talk, failed_cases(bundle))
    talk.print(
        f"done: {bundle['runs']} runs, {bundle['failed']} failed; digest {bundle['digest'][:12]}; "
        f"rank with: cosim leaderboard {escape(str(args.out))}"
        + (" (the quick selection: its verdicts are indicative only)" if args.quick else "")
    )
    print(args.out)
    return 0


def suite_needs(suite: SuiteSpec, quick: bool, added: list[Scheme], engine: str) -> Needs:
    """What the suite's runs need of the extras: the engine's, and every case's (its plants, its designs)."""
    from cosim.campaign.benchmark import case_campaign
    from cosim.campaign.coordinator import engine_extras
    from cosim.run.needs import Needs

    needs = Needs("cosim benchmark", engine_extras(engine))
    for case in suite.cases:
        needs.add_each(case.name, case_campaign(case, quick, added).point_scenarios())
    return needs


def failed_cases(bundle: dict[str, Any]) -> list[str]:
    """A line per case with failed runs: how many, and why (its most frequent error)."""
    lines = []
    for case, failed in bundle["failures"].items():
        others = failed["other_errors"]
        more = f" (and {others} other error{'s' if others > 1 else ''}: cosim leaderboard lists them)" if others else ""
        lines.append(f"{case}: {failed['failed']} of {failed['runs']} runs failed: {failed['why']}{more}")
    return lines
