"""What the benchmark scripts share: their command line, their output (a table, or one JSON object of
their figures), and timing a workload as the best of several repetitions."""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    """The fastest of ``repeat`` timings of fn() in seconds (least disturbed by other load)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def best_run(loaded: Any, repeat: int, time_of: Callable[[Any], float]) -> Any:
    """The RunResult with the least ``time_of`` among ``repeat`` in-process runs of the loaded
    scenario (on the in-process bus, into a temporary log)."""
    from cosim.run import Run

    with tempfile.TemporaryDirectory() as tmp:
        results = [Run(loaded, Path(tmp) / "run.mcap", interface="virtual").execute() for _ in range(repeat)]
    return min(results, key=time_of)


def bench_parser(doc: str, repeat: int | None = None) -> argparse.ArgumentParser:
    """A benchmark's command line: described by the first line of its docstring, with ``--json``
    (one JSON object of its figures instead of the table) and, given its default, ``--repeat``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object of the figures")
    if repeat is not None:
        parser.add_argument(
            "--repeat", type=int, default=repeat, help=f"repetitions of each measurement; the best is kept ({repeat})"
        )
    return parser


def print_figures(figures: dict[str, Any], as_json: bool, table: Callable[[dict[str, Any]], object]) -> None:
    """A benchmark's output: its figures as one JSON object (``--json``, what tests and CI read), or
    the table ``table(figures)`` prints for a reader."""
    if as_json:
        print(json.dumps(figures))
    else:
        table(figures)
