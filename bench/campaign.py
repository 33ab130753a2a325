"""Campaign throughput on the local Dask cluster: runs per hour batched and one at a time, the
speedup of batching, of 2 workers over 1, and the engine's overhead per run, in one invocation.

Workload: ``--scenario`` (default ``masses-bias``), ``--duration`` simulated seconds (default 30),
on the in-process bus, ``--runs`` replicates; or ``--campaign NAME``, a built-in campaign (its
grid and seeds, ``--duration`` set on every run, ``--runs`` ignored), e.g. a fault sweep. The same
campaign runs batched (``--batch``, default chosen: ``cosim.campaign.coordinator.batches``) on all
workers, one at a time (``--batch 1``) on all workers, and batched on one worker; each time the
loop time is taken from the first run submitted to the last result (the cluster's start-up,
reported apart, is paid once per campaign). Figures:

- ``runs_per_hour``: runs / loop time, batched, all workers, × 3600; ``runs_per_hour_unbatched``:
  the same one at a time; ``batch_speedup``: their ratio; ``batch``: the runs per batch (largest);
  ``batched_runs``: how many ran in a batch;
- ``identical``: the three tables' metrics columns are equal (batched, one at a time, one worker);
- ``workers``; ``speedup``: batched loop time with 1 worker / with all;
- ``overhead_per_run_s``: (loop time × workers − the runs' own wall times) / runs, one at a time:
  what the engine costs per run beyond the run itself; ``overhead_fraction``: that over the mean run;
- ``startup_s``: time to start the local cluster (all workers);
- ``logged_run_s``: the scenario run once in this process, in-process bus, writing its log and not
  scored, the median of ``--logged`` runs after one to warm up; ``campaign_run_cost_s``: a batched
  campaign run's cost per worker, loop time × workers / runs, and ``cost_over_logged_run``: that
  over ``logged_run_s``.

With ``--sweep 1,8,32,64`` it also times the batch alone in this process (``cosim.campaign.batch``, no
engine) at each K and reports ``sweep``: K → runs per hour of one process.

With ``--memory-runs N`` it also runs a campaign of N runs of 0.05 s (so that the engine, not the
runs, is what grows) and reports the coordinator's resident memory after the first tenth of the
runs and at the end (``memory_rss_mb_at_10pct``, ``memory_rss_mb_at_end``, ``memory_runs``).

Usage: python bench/campaign.py [--json] [--scenario NAME | --campaign NAME] [--runs N] [--duration S] [--workers N]
       [--batch K] [--logged N] [--sweep K,K,...] [--memory-runs N]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser, print_figures  # noqa: E402
from cosim.campaign.coordinator import run_campaign  # noqa: E402
from cosim.campaign.spec import load_campaign  # noqa: E402


def campaign_file(folder: Path, runs: int, duration: float, scenario: str = "masses-bias") -> Path:
    path = folder / "bench.toml"
    path.write_text(
        f'name = "bench"\nscenario = "{scenario}"\nseed = 1\nseeds = {runs}\nbus = "in-process"\n'
        f"[set]\nduration = {duration}\n"
    )
    return path


def seconds(value: float) -> float:
    """A time in seconds to four significant digits: a run of a fraction of a second keeps its
    precision (three decimals left a 0.009 s run with one digit and its ratios off by a tenth)."""
    return float(f"{value:.4g}")


def rss_mb() -> float:
    """This process's resident memory now (Linux /proc)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def logged_run(folder: Path, duration: float, count: int, scenario: str) -> float:
    """Median wall time of ``count`` logged in-process runs of the campaign's scenario (one more first, to warm up)."""
    import time

    from cosim import api
    from cosim.scenario import apply

    loaded = apply(api.load(scenario), [("duration", duration)])
    times = []
    for i in range(count + 1):
        start = time.perf_counter()
        api.run(loaded, folder / f"logged-{i}.mcap", seed=i, in_process=True)
        times.append(time.perf_counter() - start)
    return sorted(times[1:])[count // 2]


def sweep(sizes: list[int], duration: float, scenario: str) -> dict[str, float]:
    """Runs per hour of one process stepping batches of each size (no engine)."""
    import time

    from cosim import api
    from cosim.campaign.batch import run_batch
    from cosim.scenario import apply

    loaded = apply(api.load(scenario), [("duration", duration)])
    found = {}
    for size in sizes:
        start = time.perf_counter()
        runs = run_batch(loaded, list(range(size))) if size > 1 else None
        if runs is None:
            api.run(loaded, None, seed=0, in_process=True, measure=True)
        found[str(size)] = round(3600 * size / (time.perf_counter() - start), 1)
    return found


def memory(folder: Path, runs: int, workers: int) -> dict[str, float]:
    """Coordinator memory over a campaign of many tiny runs."""
    campaign = load_campaign(campaign_file(folder, runs, 0.05))
    seen: dict[str, float] = {}

    def sample(progress) -> None:
        if progress.done >= runs // 10 and "at_10pct" not in seen:
            seen["at_10pct"] = rss_mb()

    run_campaign(campaign, folder / "memory", engine="dask", workers=workers, keep_logs="none", on_progress=sample)
    return {
        "memory_runs": runs,
        "memory_rss_mb_at_10pct": round(seen["at_10pct"], 1),
        "memory_rss_mb_at_end": round(rss_mb(), 1),
    }


def parser() -> argparse.ArgumentParser:
    """The benchmark's command line (the workload, the clusters, and the optional figures)."""
    parser = bench_parser(__doc__)
    parser.add_argument("--scenario", default="masses-bias", help="the built-in scenario (default masses-bias)")
    parser.add_argument("--campaign", help="a built-in campaign instead (its grid and seeds; --duration set)")
    parser.add_argument("--runs", type=int, default=16, help="runs per campaign (default 16)")
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run (default 30)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 2, help="workers of the larger cluster")
    parser.add_argument("--batch", type=int, default=None, help="runs per batch (default: chosen)")
    parser.add_argument("--logged", type=int, default=3, help="logged in-process runs to compare with (default 3)")
    parser.add_argument("--sweep", default="", help="also time batches of these sizes in one process: 1,8,32,64")
    parser.add_argument(
        "--memory-runs", type=int, default=0, help="also measure the coordinator over this many tiny runs"
    )
    return parser


def throughput(campaign, folder: Path, args: argparse.Namespace, logged: float) -> dict[str, Any]:
    """The campaign batched on all workers, one at a time on all workers, and batched on one worker:
    its rates, speedups, the engine's overhead per run, and whether the three tables agree."""
    import pyarrow.parquet as pq

    from cosim.campaign.coordinator import batches

    ways = (("batched", args.workers, args.batch), ("alone", args.workers, 1), ("one", 1, args.batch))
    many, alone, one = (
        run_campaign(campaign, folder / key, engine="dask", workers=workers, keep_logs="none", batch=batch)
        for key, workers, batch in ways
    )
    tables = [pq.read_table(r.path).drop(["wall_time_s"]) for r in (many, alone, one)]
    mean_run = alone.run_time / alone.runs
    overhead = (alone.loop_time * alone.workers - alone.run_time) / alone.runs
    largest = max(len(b) for b in batches(campaign.runs(), args.batch, args.workers))
    return {
        "scenario": args.scenario,
        "campaign": args.campaign or "",
        "runs_per_hour": round(3600 * many.runs / many.loop_time, 1),
        "runs_per_hour_unbatched": round(3600 * alone.runs / alone.loop_time, 1),
        "batch_speedup": round(alone.loop_time / many.loop_time, 3),
        "batch": largest,
        "batched_runs": many.batched,
        "identical": tables[0].equals(tables[1]) and tables[0].equals(tables[2]),
        "workers": many.workers,
        "speedup": round(one.loop_time / many.loop_time, 3),
        "overhead_per_run_s": round(overhead, 4),
        "overhead_fraction": round(overhead / mean_run, 4),
        "mean_run_s": seconds(mean_run),
        "startup_s": round(many.startup_time, 2),
        "logged_run_s": seconds(logged),
        "campaign_run_cost_s": seconds(many.loop_time * many.workers / many.runs),
        "campaign_run_cost_1w_s": seconds(one.loop_time / one.runs),
        "cost_over_logged_run": round(many.loop_time * many.workers / many.runs / logged, 3),
        "runs": many.runs,
        "failed": one.failed + many.failed + alone.failed,
    }


def print_table(figures: dict[str, Any], args: argparse.Namespace) -> None:
    """The figures for a reader: a row each, its value and what it means."""
    print(
        f"campaign of {figures['runs']} {args.scenario} runs ({args.duration:g} s each), in-process bus, local Dask "
        "cluster"
    )
    rows = [
        (
            "runs per hour",
            f"{figures['runs_per_hour']:.0f}",
            f"batched (K up to {figures['batch']}), {figures['workers']} workers",
        ),
        ("  one at a time", f"{figures['runs_per_hour_unbatched']:.0f}", "--batch 1"),
        (
            "batch speedup",
            f"{figures['batch_speedup']:.2f}",
            f"{figures['batched_runs']} of {figures['runs']} runs batched",
        ),
        ("speedup", f"{figures['speedup']:.2f}", f"{figures['workers']} workers against 1, batched"),
        ("mean run", f"{figures['mean_run_s']:.2f} s", "one at a time, as the workers measure it"),
        (
            "overhead per run",
            f"{figures['overhead_per_run_s'] * 1000:.1f} ms",
            f"{100 * figures['overhead_fraction']:.1f} % of a run (one at a time)",
        ),
        ("cluster start-up", f"{figures['startup_s']:.2f} s", "once per campaign"),
        ("logged run", f"{figures['logged_run_s']:.2f} s", "in this process, in-process bus, log written, not scored"),
        (
            "campaign run cost",
            f"{figures['campaign_run_cost_s']:.2f} s",
            f"per worker, batched ({figures['campaign_run_cost_1w_s']:.2f} s with 1): "
            f"{figures['cost_over_logged_run']:.2f} × the logged run",
        ),
        ("tables identical", str(figures["identical"]), "batched, one at a time, one worker: metrics columns"),
    ]
    for size, rate in figures.get("sweep", {}).items():
        rows.append((f"  K = {size}", f"{rate:.0f}", "runs per hour of one process (no engine)"))
    for name, value, note in rows:
        print(f"{name:<20}{value:>14}   {note}")


def main() -> int:
    args = parser().parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if args.campaign:
            campaign = load_campaign(args.campaign, settings=[("duration", args.duration)])
            args.scenario = campaign.spec.scenario
        else:
            campaign = load_campaign(campaign_file(folder, args.runs, args.duration, args.scenario))
        figures = throughput(campaign, folder, args, logged_run(folder, args.duration, args.logged, args.scenario))
        if args.sweep:
            figures["sweep"] = sweep([int(k) for k in args.sweep.split(",")], args.duration, args.scenario)
        if args.memory_runs:
            figures |= memory(folder, args.memory_runs, args.workers)
    print_figures(figures, args.json, lambda figures: print_table(figures, args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
