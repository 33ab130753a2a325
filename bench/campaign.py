"""Campaign throughput on the local Dask cluster: runs per hour, the speedup of 2 workers over 1,
and the engine's overhead per run, measured in one invocation on the same campaign.

Workload: the default scenario (``masses-bias``, 30 s of simulated time, two estimators) on the
in-process bus, ``--runs`` replicates. The same campaign runs once on a local cluster of one worker
and once on all workers (default: one per core); each time the loop time is taken from the first
run submitted to the last result (the cluster's start-up, reported apart, is paid once per
campaign). Figures:

- ``runs_per_hour``: runs / loop time with all workers, × 3600;
- ``workers``: the workers of that cluster;
- ``speedup``: loop time with 1 worker / loop time with all;
- ``overhead_per_run_s``: (loop time × workers − the runs' own wall times) / runs: what the
  engine costs per run beyond the run itself (submission, transfer, writing the run's part);
- ``overhead_fraction``: that over the mean run time;
- ``startup_s``: time to start the local cluster (all workers);
- ``identical``: the two tables' metrics columns are equal;
- ``logged_run_s``: the same scenario run once in this process, in-process bus, writing its log and
  not scored (``cosim run --in-process``'s work, start-up of the interpreter aside), the median of
  ``--logged`` runs after one to warm up, measured before the campaigns;
- ``campaign_run_cost_s``: a campaign run's cost per worker, loop time × workers / runs (with all
  workers; ``campaign_run_cost_1w_s`` with one), and ``cost_over_logged_run``: that over
  ``logged_run_s`` (a campaign run writes no log and is scored as it goes).

With ``--memory-runs N`` it also runs a campaign of N runs of 0.05 s (so that the engine, not the
runs, is what grows) and reports the coordinator's resident memory after the first tenth of the
runs and at the end (``memory_rss_mb_at_10pct``, ``memory_rss_mb_at_end``, ``memory_runs``).

Usage: python bench/campaign.py [--json] [--runs N] [--duration S] [--workers N] [--logged N] [--memory-runs N]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser  # noqa: E402
from cosim.campaign.coordinator import run_campaign  # noqa: E402
from cosim.campaign.spec import load_campaign  # noqa: E402


def campaign_file(folder: Path, runs: int, duration: float) -> Path:
    path = folder / "bench.toml"
    path.write_text(
        f'name = "bench"\nscenario = "masses-bias"\nseed = 1\nseeds = {runs}\n[set]\nduration = {duration}\n'
    )
    return path


def rss_mb() -> float:
    """This process's resident memory now (Linux /proc)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def logged_run(folder: Path, duration: float, count: int) -> float:
    """Median wall time of ``count`` logged in-process runs of the campaign's scenario (one more first, to warm up)."""
    import time

    from cosim import api
    from cosim.scenario import apply

    loaded = apply(api.load("masses-bias"), [("duration", duration)])
    times = []
    for i in range(count + 1):
        start = time.perf_counter()
        api.run(loaded, folder / f"logged-{i}.mcap", seed=i, in_process=True)
        times.append(time.perf_counter() - start)
    return sorted(times[1:])[count // 2]


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


def main() -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--runs", type=int, default=16, help="runs per campaign (default 16)")
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run (default 30)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 2, help="workers of the larger cluster")
    parser.add_argument("--logged", type=int, default=3, help="logged in-process runs to compare with (default 3)")
    parser.add_argument(
        "--memory-runs", type=int, default=0, help="also measure the coordinator over this many tiny runs"
    )
    args = parser.parse_args()
    import pyarrow.parquet as pq

    with tempfile.TemporaryDirectory() as folder:
        logged = logged_run(Path(folder), args.duration, args.logged)
        campaign = load_campaign(campaign_file(Path(folder), args.runs, args.duration))
        results = {}
        for workers in (1, args.workers):
            results[workers] = run_campaign(
                campaign, Path(folder) / f"w{workers}", engine="dask", workers=workers, keep_logs="none"
            )
        one, many = results[1], results[args.workers]
        tables = [pq.read_table(r.path).drop(["wall_time_s"]) for r in (one, many)]
        mean_run = many.run_time / many.runs
        overhead = (many.loop_time * many.workers - many.run_time) / many.runs
        figures = {
            "runs_per_hour": round(3600 * many.runs / many.loop_time, 1),
            "workers": many.workers,
            "speedup": round(one.loop_time / many.loop_time, 3),
            "overhead_per_run_s": round(overhead, 4),
            "overhead_fraction": round(overhead / mean_run, 4),
            "mean_run_s": round(mean_run, 3),
            "startup_s": round(many.startup_time, 2),
            "logged_run_s": round(logged, 3),
            "campaign_run_cost_s": round(many.loop_time * many.workers / many.runs, 3),
            "campaign_run_cost_1w_s": round(one.loop_time / one.runs, 3),
            "cost_over_logged_run": round(many.loop_time * many.workers / many.runs / logged, 3),
            "runs": many.runs,
            "failed": one.failed + many.failed,
            "identical": tables[0].equals(tables[1]),
        }
        if args.memory_runs:
            figures |= memory(Path(folder), args.memory_runs, args.workers)
    if args.json:
        print(json.dumps(figures))
        return 0
    print(
        f"campaign of {figures['runs']} default-scenario runs ({args.duration:g} s each), in-process bus, local Dask "
        "cluster"
    )
    rows = [
        ("runs per hour", f"{figures['runs_per_hour']:.0f}", f"{figures['workers']} workers"),
        ("speedup", f"{figures['speedup']:.2f}", f"{figures['workers']} workers against 1"),
        ("mean run", f"{figures['mean_run_s']:.2f} s", "as the workers measure it"),
        (
            "overhead per run",
            f"{figures['overhead_per_run_s'] * 1000:.1f} ms",
            f"{100 * figures['overhead_fraction']:.1f} % of a run",
        ),
        ("cluster start-up", f"{figures['startup_s']:.2f} s", "once per campaign"),
        ("logged run", f"{figures['logged_run_s']:.2f} s", "in this process, in-process bus, log written, not scored"),
        (
            "campaign run cost",
            f"{figures['campaign_run_cost_s']:.2f} s",
            f"per worker ({figures['campaign_run_cost_1w_s']:.2f} s with 1): "
            f"{figures['cost_over_logged_run']:.2f} × the logged run",
        ),
        ("tables identical", str(figures["identical"]), "1 worker against all, metrics columns"),
    ]
    if args.memory_runs:
        rows += [
            (
                "coordinator memory",
                f"{figures['memory_rss_mb_at_10pct']:.0f} → {figures['memory_rss_mb_at_end']:.0f} MB",
                f"after {args.memory_runs // 10} and {args.memory_runs} tiny runs",
            )
        ]
    for name, value, note in rows:
        print(f"{name:<20}{value:>14}   {note}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
