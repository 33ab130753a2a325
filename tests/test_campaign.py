"""Campaigns: files validated like scenarios, runs derived from the file alone, a real local Dask
cluster giving the same table as one worker and as a killed-and-resumed coordinator, the leaderboard."""

from __future__ import annotations

import io
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import time
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from cosim.campaign.coordinator import run_campaign
from cosim.campaign.leaderboard import leaderboard
from cosim.campaign.results import NONDETERMINISTIC
from cosim.campaign.scores import poisson_rate, wilson
from cosim.campaign.spec import builtin_names, load_campaign
from cosim.campaign.verdicts import bootstrap_median
from cosim.cli import main
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from tests.conftest import ROOT

TINY = """
name = "tiny"
scenario = "masses-bias"
seed = 7
seeds = 2
[set]
duration = 1.5
"faults[0].start" = 0.5
"bus.fd" = true
[[axes]]
key = "faults[0].value"
values = [0.2, 0.5]
name = "bias"
[[sample]]
key = "noise[0].std"
distribution = "loguniform"
low = 0.0005
high = 0.005
"""


def write(tmp_path, text, name="campaign.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def metrics_table(path):
    """The table without its wall-clock column, and without the log paths (which follow --keep-logs)."""
    table = pq.read_table(path)
    return table.drop([c for c in (*NONDETERMINISTIC, "log") if c in table.column_names])


@pytest.fixture(scope="module")
def inline_table(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inline")
    campaign = load_campaign(write(folder, TINY))
    result = run_campaign(campaign, folder / "out", engine="inline", keep_logs="all")
    return result


@pytest.mark.slow
def test_every_builtin_campaign_loads_and_validates_every_grid_point():
    assert {"masses-bias-sweep", "uio-threshold-sweep", "vessel-thrusters", "vessel-nominal"} <= set(builtin_names())
    for name in builtin_names():
        campaign = load_campaign(name)
        assert campaign.size == len(campaign.runs()) > 0 and campaign.spec.description


@pytest.mark.parametrize(
    "change, message",
    [
        ("seeds = 0", "seeds"),
        ('[[axes]]\nkey = "faults[0].value"\nvalues = [1, 2]\nlabels = ["a"]', "labels has 1 entries for 2 values"),
        ('[[sample]]\nkey = "duration"\ndistribution = "gaussian"\nlow = 1\nhigh = 2', "sample[0].distribution"),
        ('[[sample]]\nkey = "duration"\ndistribution = "uniform"\nlow = 3\nhigh = 2', "low (3.0) must not exceed high"),
        ('[[axes]]\nkey = "faults[0].value"\nvalues = [[1, 2]]', "faults[0].value: has 2 values for 3 channels"),
        ('[[axes]]\nkey = "estimators[0].params.poles"\nvalues = ["fast"]', "estimators[0].params.poles: expected"),
        ('[[axes]]\nkey = "faults[4].value"\nvalues = [1]', "faults has 1 item; faults[4] is beyond its end"),
        ("bogus = 1", "unknown key 'bogus'"),
    ],
)
def test_bad_campaign_files_get_one_line_errors_naming_the_field(tmp_path, change, message):
    base = 'name = "bad"\nscenario = "masses-bias"\n'
    text = base + change + "\n" if not change.startswith("seeds") else base + change
    with pytest.raises(ScenarioError) as error:
        load_campaign(write(tmp_path, text))
    assert message in str(error.value) and "\n" not in str(error.value).strip()


def test_two_cells_that_differ_only_in_an_estimator_see_bit_identical_sensor_frames(tmp_path):
    """Common random numbers: the noise of replicate r is the same in every cell of the grid."""
    text = TINY.replace(
        'key = "faults[0].value"\nvalues = [0.2, 0.5]\nname = "bias"',
        ('key = "estimators[1].params.process_std"\nvalues = [1e-4, 1e-3]\nname = "q"'),
    )
    text = text.split("[[sample]]")[0]
    result = run_campaign(load_campaign(write(tmp_path, text)), tmp_path / "crn", engine="inline", keep_logs="all")
    rows = {(r["q"], r["replicate"]): r for r in pq.read_table(result.path).to_pylist()}

    def sensor_frames(row):
        with LogReader(tmp_path / "crn" / row["log"]) as reader:
            return [(t, m) for topic, t, m in reader.messages() if topic.startswith("/can/SENSOR_")]

    for replicate in (0, 1):
        cells = [sensor_frames(rows[(q, replicate)]) for q in (1e-4, 1e-3)]
        assert cells[0] and cells[0] == cells[1]
    assert sensor_frames(rows[(1e-4, 0)]) != sensor_frames(rows[(1e-4, 1)])  # replicates differ


def test_runs_are_derived_from_the_file_and_their_index_alone(tmp_path):
    campaign = load_campaign(write(tmp_path, TINY))
    runs = campaign.runs()
    assert [r.index for r in runs] == [0, 1, 2, 3] and [r.replicate for r in runs] == [0, 1, 0, 1]
    assert [dict(r.columns)["bias"] for r in runs] == [0.2, 0.2, 0.5, 0.5]
    seeds = [r.seed for r in runs]  # common random numbers: one seed per replicate, across the grid
    assert seeds[0] == seeds[2] and seeds[1] == seeds[3] and seeds[0] != seeds[1]
    std = [dict(r.columns)["noise[0].std"] for r in runs]
    assert all(0.0005 <= s <= 0.005 for s in std) and len(set(std)) == 4
    again = load_campaign(write(tmp_path, TINY, "again.toml")).runs()
    assert [(r.seed, r.settings) for r in again] == [(r.seed, r.settings) for r in runs]
    assert campaign.run(2, (1,), 0) == runs[2]  # one run, built alone, is the same run


def test_the_inline_engine_writes_one_row_per_run_and_estimator_with_units(inline_table):
    table = pq.read_table(inline_table.path)
    rows = table.to_pylist()
    assert inline_table.runs == 4 and inline_table.failed == 0 and len(rows) == 8
    assert {(r["run"], r["estimator"]) for r in rows} == {(i, e) for i in range(4) for e in ("uniform", "kalman")}
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}
    assert units["detection_delay_s"] == "s" and units["false_alarm_rate_per_hour"] == "1/h"
    assert units["rms_post_fault"] == "mixed units"  # the masses' state has m and m/s
    assert {r["fault_kind"] for r in rows} == {"bias"} and all(r["status"] == "completed" for r in rows)
    assert b"cosim.campaign" in table.schema.metadata and b"cosim.versions" in table.schema.metadata
    assert all(os.path.exists(inline_table.path.parent / r["log"]) for r in rows)  # keep_logs="all"


def test_a_failed_run_is_a_row_with_its_error_and_the_campaign_goes_on(tmp_path):
    text = TINY.replace('"bus.fd" = true', '"bus.fd" = false').replace("values = [0.2, 0.5]", "values = [0.2, 40.0]")
    result = run_campaign(load_campaign(write(tmp_path, text)), tmp_path / "out", engine="inline")
    rows = pq.read_table(result.path).to_pylist()
    failed = [r for r in rows if r["status"] != "completed"]
    assert result.failed == 2 and {r["run"] for r in failed} == {2, 3}
    assert all("outside its declared range" in r["error"] and r["fault_kind"] == "bias" for r in failed)
    assert all(os.path.exists(tmp_path / "out" / r["log"]) for r in failed)  # keep_logs="failed"
    assert all(r["log"] == "" for r in rows if r["status"] == "completed")


def test_a_folder_holding_a_campaign_is_not_overwritten_and_resume_needs_the_same_file(tmp_path, inline_table):
    campaign = load_campaign(write(tmp_path, TINY))
    folder = inline_table.path.parent
    with pytest.raises(ScenarioError.__mro__[1], match="holds a campaign already; add --resume"):
        run_campaign(campaign, folder, engine="inline")
    other = load_campaign(write(tmp_path, TINY.replace("seed = 7", "seed = 8"), "other.toml"))
    with pytest.raises(ScenarioError.__mro__[1], match="holds another campaign"):
        run_campaign(other, folder, engine="inline", resume=True)
    again = run_campaign(campaign, folder, engine="inline", resume=True)  # nothing left to run
    assert again.resumed == 4 and metrics_table(again.path).equals(metrics_table(inline_table.path))


def test_the_folder_keeps_the_campaign_with_its_options_and_a_scenario_file_found_from_there(tmp_path):
    from cosim.campaign.coordinator import _prepare, resume_command

    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "base.toml").write_text((ROOT / "scenarios" / "masses-bias.toml").read_text())
    path = write(tmp_path / "mine", "# my sweep\n" + TINY.replace('"masses-bias"', '"base.toml"'))
    options = {"seeds": 3, "settings": [("duration", 1.0)]}
    folder = tmp_path / "runs" / "sweep"
    _prepare(folder, load_campaign(path, **options), resume=False)
    kept = (folder / "campaign.toml").read_text()
    assert kept.startswith("# my sweep") and 'scenario = "../../mine/base.toml"' in kept and "seeds = 3" in kept
    copy = load_campaign(folder / "campaign.toml")
    assert copy.size == 6 and copy.base.scenario == load_campaign(path).base.scenario
    _prepare(folder, copy, resume=True)  # the copy is the campaign, and so is the file with the same options
    _prepare(folder, load_campaign(path, **options), resume=True)
    with pytest.raises(ScenarioError.__mro__[1], match="holds another campaign") as raised:
        _prepare(folder, load_campaign(path), resume=True)  # without --seeds, --set: another campaign
    assert resume_command(folder) in str(raised.value)


@pytest.mark.slow
def test_a_local_dask_cluster_of_two_workers_gives_the_same_table(tmp_path, inline_table):
    campaign = load_campaign(write(tmp_path, TINY))
    two = run_campaign(campaign, tmp_path / "two", engine="dask", workers=2, keep_logs="all")
    one = run_campaign(campaign, tmp_path / "one", engine="dask", workers=1, keep_logs="all")
    assert two.workers == 2 and "local Dask cluster" in two.engine
    assert metrics_table(two.path).equals(metrics_table(inline_table.path))
    assert metrics_table(one.path).equals(metrics_table(inline_table.path))


def session_ended(session: int, within: float) -> bool:
    """Whether every process of ``session`` is gone within ``within`` seconds (a loaded machine
    takes a while to schedule the workers' exits: their parent-pipe watchers see EOF at once)."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        if not subprocess.run(["pgrep", "-s", str(session)], capture_output=True, text=True).stdout.split():
            return True
        time.sleep(0.2)
    print(subprocess.run(["ps", "-o", "pid,etime,args", "-g", str(session)], capture_output=True, text=True).stdout)
    return False


@pytest.mark.slow
def test_resume_after_the_coordinator_is_killed_loses_nothing_and_duplicates_nothing(tmp_path, inline_table):
    path = write(tmp_path, TINY.replace("seeds = 2", "seeds = 6"))
    folder = tmp_path / "killed"
    # batches of 2, so that parts come in a few at a time (by default the 12 runs, alike but for their
    # faults and noise, are 2 batches of 6: killed after 3 parts, all 12 could be there)
    command = [sys.executable, "-m", "cosim.cli", "campaign", str(path), "--out", str(folder), "--workers", "2"]
    command += ["--batch", "2", "-q"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list((folder / "parts").glob("run-*.json"))) < 3:
        time.sleep(0.2)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    done = len(list((folder / "parts").glob("run-*.json")))
    assert 3 <= done < 12 and not (folder / "results.parquet").exists()
    assert session_ended(process.pid, within=30), "the cluster's workers outlived their coordinator"
    resumed = run_campaign(load_campaign(path), folder, engine="dask", workers=2, resume=True)
    fresh = run_campaign(load_campaign(path), tmp_path / "fresh", engine="inline")
    assert resumed.resumed == done and resumed.runs == 12
    table = metrics_table(resumed.path)
    assert table.num_rows == 24 and sorted(set(table.column("run").to_pylist())) == list(range(12))
    assert table.equals(metrics_table(fresh.path))


@pytest.mark.slow
def test_ctrl_c_stops_a_campaign_in_a_few_lines_and_the_command_it_prints_finishes_it(tmp_path, inline_table):
    """Ctrl-C in a terminal sends SIGINT to its whole foreground group, the local cluster's worker
    processes included: the campaign says it was interrupted (no Dask tracebacks) and prints the
    command that finishes it, which does as printed: the campaign was started with --seeds and --set,
    its scenario is a file next to the campaign's, and the shell is elsewhere."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "base.toml").write_text((ROOT / "scenarios" / "masses-bias.toml").read_text())
    write(tmp_path / "mine", TINY.replace('"masses-bias"', '"base.toml"').replace("duration = 1.5\n", ""))
    cosim = [sys.executable, "-m", "cosim.cli"]
    # one run at a time on one worker: three of the four runs are still to come when the first is
    # written (batched on two workers, the second batch could end before the SIGINT came: 1 in 8)
    options = ["--seeds", "2", "--set", "duration=1.5", "--workers", "1", "--batch", "1"]
    process = subprocess.Popen(
        [*cosim, "campaign", "mine/campaign.toml", "--out", "out put", *options],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        # a shell starts background jobs with SIGINT ignored, and children keep it so: a terminal's does not
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    folder = tmp_path / "out put"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list((folder / "parts").glob("run-*.json")):
        time.sleep(0.1)
    os.killpg(process.pid, signal.SIGINT)  # what the terminal does
    out, _ = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGINT
    assert "Traceback" not in out and "ERROR" not in out, out
    after = out.split("engine:", 1)[1].strip().splitlines()[1:]  # below the engine line and the progress
    assert len(after) <= 3, out
    assert "interrupted" in out
    printed = out.split("finish with: ", 1)[1].splitlines()[0]
    assert printed == "cosim campaign 'out put/campaign.toml' --out 'out put' --resume"
    finish = subprocess.run([*cosim, *shlex.split(printed)[1:]], cwd=tmp_path, capture_output=True, text=True)
    assert finish.returncode == 0, finish.stderr
    assert "from an earlier session" in finish.stderr
    assert metrics_table(folder / "results.parquet").equals(metrics_table(inline_table.path))


def synthetic_table(path, differences: dict[str, list[float]]) -> Path:
    """A results table of len(values) runs: estimator "base" with RMS 1 in every run, and each other
    estimator with RMS 1 + its difference in that run."""
    import pyarrow as pa

    runs = len(next(iter(differences.values())))
    rows = [
        {"run": i, "status": "completed", "estimator": name, "kind": "k", "fault_kind": "bias", "rms_post_fault": rms}
        for i in range(runs)
        for name, rms in [("base", 1.0), *((n, 1.0 + d[i]) for n, d in differences.items())]
    ]
    pq.write_table(pa.Table.from_pylist(rows), path)
    return path


def test_paired_differences_rank_apart_or_tie_with_holms_adjustment(tmp_path):
    rng = np.random.default_rng(4)
    worse = 0.05 + 0.01 * rng.standard_normal(20)  # worse than "base" in every run: ranked apart
    same = worse + 0.005 * rng.choice([-1.0, 1.0], 20)  # as often better as worse than "worse": tied
    table = synthetic_table(tmp_path / "t.parquet", {"worse": list(worse), "same": list(same)})
    (group,) = leaderboard(table)["groups"]
    ranking = {s["estimator"]: s for s in group["ranking"]}
    assert [s["estimator"] for s in group["ranking"]][0] == "base" and ranking["base"]["rank"] == 1
    first = ranking["base"]["vs_next"]
    assert first["pairs"] == 20 and first["p_holm"] < 0.001 and not first["tied"]
    low, high = first["median_difference_ci95"]
    assert 0.0 < low < 0.05 < high  # the true median difference is 0.05
    assert {ranking["worse"]["rank"], ranking["same"]["rank"]} == {2} and ranking["worse"]["tied"]


def test_schemes_that_only_diagnose_are_ranked_by_a_paired_sign_test_after_the_estimators(tmp_path):
    """An attack case: an estimator (an RMS error), and three schemes with no error of their own,
    ranked among themselves. "late" detects 0.5 s after "prompt" in 12 of 20 runs and like it in the
    rest: told apart (sign test, p = 2⁻¹¹); "twin" is "late" run by run, but 20 runs do not show that
    two schemes differ on fewer than 5 % of runs (0.95²⁰ = 0.36): not separated. The estimator and
    "prompt" share no measure: no comparison."""
    import pyarrow as pa

    def row(i: int, name: str, **columns) -> dict:
        empty = dict.fromkeys(("rms_post_fault", "detected", "missed_detections", "false_alarms", "detection_delay_s"))
        return (
            {"run": i, "status": "completed", "estimator": name, "kind": name, "fault_kind": "spoofing"}
            | empty
            | columns
        )

    def diagnosis(delay: float) -> dict:
        return {
            "diagnoses": True,
            "detected": True,
            "missed_detections": 0,
            "false_alarms": 0,
            "detection_delay_s": delay,
        }

    rows = []
    for i in range(20):
        delay = 0.5 if i < 12 else 0.0
        rows += [
            row(i, "kalman", rms_post_fault=1.0, diagnoses=False),
            row(i, "prompt", **diagnosis(0.0)),
            row(i, "late", **diagnosis(delay)),
            row(i, "twin", **diagnosis(delay)),
        ]
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "t.parquet")
    (group,) = leaderboard(tmp_path / "t.parquet")["groups"]
    ranking = {s["estimator"]: s for s in group["ranking"]}
    assert [s["estimator"] for s in group["ranking"]][:2] == ["kalman", "prompt"]
    assert "vs_next" not in ranking["kalman"] and ranking["kalman"]["rank"] == 1 and not ranking["kalman"]["settled"]
    assert ranking["prompt"]["rank"] == 1 and ranking["prompt"]["chain"] == "diagnosis" and ranking["prompt"]["settled"]
    versus = ranking["prompt"]["vs_next"]
    assert (versus["measure"], versus["pairs"], versus["worse"], versus["better"]) == ("diagnosis", 20, 12, 0)
    assert versus["p"] == pytest.approx(2.0**-11) and versus["verdict"] == "separated"
    twins = ranking["late"]["vs_next"]
    assert twins["verdict"] == "not separated" and twins["equivalence_p"] == pytest.approx(0.95**20)
    assert ranking["late"]["rank"] == ranking["twin"]["rank"] == 2 and not ranking["twin"]["settled"]


def test_holm_is_the_textbook_step_down():
    from cosim.campaign.verdicts import holm

    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])  # 3·0.01, max(2·0.03, .03), max(.04, .06)
    assert holm([0.5, 0.9]) == [1.0, 1.0] and holm([]) == []


def test_intervals_are_the_textbook_ones():
    low, high = wilson(8, 10)  # Wilson 95 %, 8 of 10: [0.4902, 0.9433]
    assert math.isclose(low, 0.49016, abs_tol=1e-4) and math.isclose(high, 0.94331, abs_tol=1e-4)
    assert wilson(0, 0) is None and wilson(0, 5)[0] == 0.0
    low, high = poisson_rate(2, 1.0)  # Garwood: [0.2422, 7.2247]
    assert math.isclose(low, 0.24224, abs_tol=1e-4) and math.isclose(high, 7.22467, abs_tol=1e-4)
    assert poisson_rate(0, 2.0)[0] == 0.0 and math.isclose(poisson_rate(0, 2.0)[1], 3.68888 / 2, abs_tol=1e-4)
    values = list(np.random.default_rng(3).normal(10.0, 1.0, 200))
    interval = bootstrap_median(values)
    assert interval == bootstrap_median(values) and interval[0] < np.median(values) < interval[1]
    assert interval[1] - interval[0] < 0.5 and bootstrap_median(values[:4]) is None


def test_the_leaderboard_ranks_per_group_and_writes_a_page(tmp_path, inline_table):
    board = leaderboard(inline_table.path, ["bias"])
    assert [g["group"] for g in board["groups"]] == [{"bias": 0.2}, {"bias": 0.5}]
    for group in board["groups"]:
        ranking = group["ranking"]
        assert [s["rank"] for s in ranking] == [1, 1] and not any(s["settled"] for s in ranking)  # 2 pairs tell nothing
        versus = ranking[0]["vs_next"]
        assert versus["pairs"] == 2 and versus["p_holm"] >= 0.05 and versus["verdict"] == "not separated"
        assert versus["detectable"] is None and versus["needed"] >= 6  # a signed-rank test needs 6 pairs at 0.05
        assert group["pooled"] == [{"column": "noise[0].std", "values": 2, "sampled": True}]
        medians = [s["rms_post_fault_median"] for s in ranking]
        assert medians == sorted(medians) and all(s["runs"] == 2 for s in ranking)
        # per run the peak after onset is at least the final error, so are their medians
        assert all(s["peak_error_median"] >= s["final_error_median"] > 0 for s in ranking)
        assert all(s["recovery_time_median_s"] is None or s["recovery_time_median_s"] >= 0 for s in ranking)
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["leaderboard", str(inline_table.path), "--json", "--html", str(tmp_path / "board.html")]) == 0
    assert json.loads(out.getvalue())["groups"][0]["group"] == {"bias": 0.2}  # every axis swept, by default
    page = (tmp_path / "board.html").read_text()
    assert page.count("data:image/png;base64,") >= 1 and "http" not in page.replace("http-equiv", "")
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["leaderboard", str(inline_table.path), "--by", "bias", "--markdown"]) == 0
    tables = [line for line in out.getvalue().splitlines() if line.startswith(("| 1 |", "| 2 |", "| ~1 |", "| ~2 |"))]
    ranked = [s["estimator"] for g in board["groups"] for s in g["ranking"]]
    assert [line.split(" | ")[1].split(" (")[0] for line in tables] == ranked
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["leaderboard", str(inline_table.path)]) == 0
    assert "RMS p50 [95 %] [mixed units]" in out.getvalue()  # the unit of the table (the masses: m and m/s)


def test_run_takes_settings_from_the_command_line(tmp_path):
    out = tmp_path / "set.mcap"
    assert (
        main(
            [
                "run",
                "masses-bias",
                "-q",
                "--interface",
                "virtual",
                "--set",
                "duration=0.5",
                "--set",
                "faults[0].value=[0.5, 0, 0]",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    from cosim.log.metadata import LogMetadata
    from cosim.log.reader import LogReader

    with LogReader(out) as reader:
        meta = LogMetadata.read(reader.metadata())
    assert meta.run.ticks == 50 and json.loads(meta.scenario.settings) == [
        ["duration", 0.5],
        ["faults[0].value", [0.5, 0, 0]],
    ]
    assert main(["run", "masses-bias", "-q", "--set", "faults[0].value=[1, 2]", "--out", str(out)]) == 1


def test_docs_define_every_column_of_the_table():
    from cosim.campaign.results import COLUMNS

    docs = (Path(__file__).resolve().parent.parent / "docs" / "campaigns.md").read_text(encoding="utf-8")
    rows = [[cell.strip() for cell in line.split("|")[1:-1]] for line in docs.splitlines() if line.startswith("| `")]
    defined = {row[0].strip("`"): row[1:3] for row in rows}
    for name, (kind, unit, _) in COLUMNS.items():
        assert defined.get(name) == [kind, "state" if unit == "state" else unit], f"docs/campaigns.md: {name}"


def test_seeds_and_settings_from_the_command_line_change_the_stored_file(tmp_path):
    path = write(tmp_path, "# my sweep\n" + TINY)
    campaign = load_campaign(path, seeds=3, settings=[("duration", 0.5), ("faults[0].start", 0.2)])
    assert campaign.spec.replicates == [0, 1, 2] and campaign.size == 2 * 3
    assert campaign.spec.set["duration"] == 0.5 and campaign.spec.set["faults[0].start"] == 0.2
    assert campaign.text.startswith("# my sweep\n") and "seeds = 3" in campaign.text
    assert load_campaign(write(tmp_path, campaign.text, "again.toml")).spec == campaign.spec
    with pytest.raises(ScenarioError, match="duration"):
        load_campaign(path, settings=[("duration", -1.0)])


def test_the_leaderboard_can_leave_out_the_runs_with_contested_ticks(tmp_path):
    import pyarrow as pa

    table = synthetic_table(tmp_path / "t.parquet", {"other": [0.1, 0.2, 0.3, 0.4]})
    rows = pq.read_table(table).to_pylist()
    contested = pa.Table.from_pylist([row | {"contested_ticks": 7 if row["run"] == 0 else 0} for row in rows])
    pq.write_table(contested, table)
    runs = {s["estimator"]: s["runs"] for s in leaderboard(table)["groups"][0]["ranking"]}
    kept = {s["estimator"]: s["runs"] for s in leaderboard(table, exclude_contested=True)["groups"][0]["ranking"]}
    assert runs == {"base": 4, "other": 4} and kept == {"base": 3, "other": 3}


def test_the_text_leaderboard_fits_100_columns_and_says_each_verdict(tmp_path, capsys):
    rng = np.random.default_rng(4)
    worse = 0.05 + 0.01 * rng.standard_normal(20)
    same = worse + 0.005 * rng.choice([-1.0, 1.0], 20)  # within ±0.5 % of "worse" in every run
    long = "an_estimator_with_a_name_longer_than_the_column"
    table = synthetic_table(tmp_path / "t.parquet", {"worse": list(worse), "same": list(same), long: list(worse + 1)})
    assert main(["leaderboard", str(table)]) == 0
    out = capsys.readouterr().out
    assert max(map(len, out.splitlines())) <= 100
    assert "RMS p50 [95 %]" in out and "final" in out and "peak" in out and "recovery" in out
    rows = {line.split()[1]: line for line in out.splitlines() if line.strip()[:2] in ("1 ", "=2", "4 ")}
    assert rows["base"].lstrip().startswith("1 ") and rows["worse"].lstrip().startswith("=2")
    assert rows["same"].lstrip().startswith("=2")
    # 20 pairs all one way: exact p 2⁻¹⁹, times 3 comparisons (Holm)
    assert "> same: error +4.8 % [+4.2 %, +5.5 %], p 5.7e-06: separated; detectable ≥ 0.98 %" in out
    assert "= worse: error +0.0035 % [−0.0025 %, +0.48 %]: tied within ±5 %" in out
    assert f"\n 4 {long} (k)\n" in out  # a long name on a line of its own, above its numbers
    assert "2 separated, 1 tied within ±5 %, 0 not separated" in out.replace("\n  ", " ")
