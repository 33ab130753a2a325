"""The standing benchmark: its suite and digest, the schemes it adds, bundles merged and ranked."""

from __future__ import annotations

import html
import json
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from cosim.campaign.benchmark import BUNDLE, Scheme, case_campaign, load_suite, merge_tables, read_bundles, suite_digest
from cosim.campaign.leaderboard import leaderboard
from cosim.campaign.spec import BUILTIN_DIR
from cosim.cli import main
from cosim.errors import CosimError, ScenarioError


def small_suite(tmp_path: Path, seed: int = 11, duration: float = 2.0) -> Path:
    """A suite of one case: masses-attacks shortened, from a campaign file of its own."""
    campaign = (BUILTIN_DIR / "masses-attacks.toml").read_text().replace("seed = 11", f"seed = {seed}")
    campaign += f'\n[set]\nduration = {duration}\n"faults[0].start" = 0.5\n"faults[0].end" = 1.0\n'
    campaign += '"faults[1].start" = 1.2\n"faults[1].end" = 1.8\n'
    (tmp_path / "attacks.toml").write_text(campaign)
    suite = tmp_path / "suite.toml"
    suite.write_text(
        'name = "small"\nversion = 1\n\n[[cases]]\nname = "attacks"\ntrack = "attacks"\n'
        f'campaign = "{tmp_path / "attacks.toml"}"\nquick = {{ seeds = 1, only = {{ ids = ["off"] }} }}\n'
    )
    return suite


def test_the_builtin_suite_has_both_tracks_and_every_case_loads_quick_and_full():
    suite = load_suite()
    assert {case.track for case in suite.cases} == {"faults", "attacks"}
    for case in suite.cases:
        quick, full = case_campaign(case, True), case_campaign(case, False)
        assert 0 < quick.size < full.size, case.name


def test_the_digest_changes_when_any_run_changes(tmp_path):
    first = suite_digest(load_suite(small_suite(tmp_path)), quick=False)
    assert first == suite_digest(load_suite(small_suite(tmp_path)), quick=False)  # the same runs: the same digest
    assert first != suite_digest(load_suite(small_suite(tmp_path)), quick=True)
    assert first != suite_digest(load_suite(small_suite(tmp_path, seed=12)), quick=False)  # other seeds
    assert first != suite_digest(load_suite(small_suite(tmp_path, duration=3.0)), quick=False)  # a setting


def test_added_schemes_join_every_run_of_a_case_and_may_not_take_a_name():
    case = next(c for c in load_suite().cases if c.name == "masses-bias")
    mine = Scheme("mine", "kalman", {"measurement_std": 1e-3, "process_std": 1e-4})
    campaign = case_campaign(case, True, [mine])
    for run in campaign.runs():
        added = [value for key, value in run.settings if key.startswith("estimators[")]
        assert mine.table() in added
    with pytest.raises(CosimError, match="already have the names kalman"):
        case_campaign(case, True, [Scheme("kalman", "kalman", {})])


def test_a_bad_suite_is_one_line_naming_the_field(tmp_path):
    bad = tmp_path / "suite.toml"
    bad.write_text('name = "x"\nversion = 1\n[[cases]]\nname = "a"\ntrack = "weather"\ncampaign = "masses-attacks"\n')
    with pytest.raises(ScenarioError) as error:
        load_suite(bad)
    assert "cases[0].track" in str(error.value) and "\n" not in str(error.value)


def bundle(folder: Path, digest: str, rows: list[dict]) -> Path:
    """A bundle of one case ("c") with these rows, and another ("d") where the same schemes score
    the other way round."""
    folder.mkdir()
    parts = []
    for case in ("c", "d"):
        table = folder / f"{case}.parquet"
        flipped = [dict(r, rms_post_fault=3.0 - r["rms_post_fault"]) if case == "d" else r for r in rows]
        pq.write_table(pa.Table.from_pylist(flipped), table)
        parts.append((case, "faults", table))
    record = {"suite": "s", "version": 1, "quick": False, "digest": digest, "units": {"c": "m", "d": "cm"}}
    merge_tables(parts, folder / "results.parquet", record)
    (folder / BUNDLE).write_text(json.dumps(record))
    return folder


def rows_of(names: dict[str, list[float]]) -> list[dict]:
    return [
        {"run": i, "status": "completed", "estimator": name, "kind": "k", "fault_kind": "bias", "rms_post_fault": rms}
        for name, values in names.items()
        for i, rms in enumerate(values)
    ]


def test_bundles_of_one_suite_merge_into_one_standing_table_and_others_are_refused(tmp_path):
    rng = np.random.default_rng(1)
    base = 1.0 + 0.01 * rng.standard_normal(20)
    ours = bundle(tmp_path / "ours", "abc", rows_of({"paper": list(base), "baseline": list(base + 0.2)}))
    mine = base + 0.2 + 1e-3 * rng.choice([-1.0, 1.0], 20)  # as often better as worse than the baseline
    theirs = bundle(tmp_path / "theirs", "abc", rows_of({"paper": list(base), "mine": list(mine)}))
    board = leaderboard([ours, theirs])
    assert board["by"] == ["track", "case"] and board["benchmark"]["bundles"] == 2
    (c, d) = board["groups"]
    assert [g["group"] for g in (c, d)] == [{"track": "faults", "case": "c"}, {"track": "faults", "case": "d"}]
    assert (c["unit"], d["unit"]) == ("m", "cm")
    ranking = {s["estimator"]: s for s in c["ranking"]}
    assert ranking["paper"]["rank"] == 1 and ranking["paper"]["runs"] == 20  # counted once, not once per bundle
    assert ranking["paper"]["vs_next"]["pairs"] == 20 and not ranking["paper"]["vs_next"]["tied"]
    assert ranking["baseline"]["rank"] == ranking["mine"]["rank"] == 2 and ranking["mine"]["tied"]
    track = {s["estimator"]: s for s in board["tracks"]["faults"]}
    assert track["paper"]["cases"] == 2 and track["paper"]["mean_rank"] == pytest.approx((1 + 3) / 2)
    other = bundle(tmp_path / "other", "abd", rows_of({"paper": list(base)}))
    with pytest.raises(CosimError) as refused:
        read_bundles([ours, other])
    assert "is not" in str(refused.value) and "not comparable" in str(refused.value)
    assert "\n" not in str(refused.value)


@pytest.mark.slow
def test_cosim_benchmark_writes_a_bundle_that_the_leaderboard_ranks(tmp_path, capsys):
    suite = small_suite(tmp_path)
    out = tmp_path / "bundle"
    args = ["benchmark", "--quick", "--suite", str(suite), "--out", str(out), "--engine", "inline", "-q"]
    assert main([*args, "--estimator", "extra=kalman", "--params", "extra={measurement_std = 0.001}"]) == 0
    record, tables = read_bundles([out])
    assert record["suite"] == "small" and record["quick"] and record["runs"] == 2 and record["failed"] == 0
    assert record["digest"] == suite_digest(load_suite(suite), quick=True)
    names = {row["estimator"] for row in pq.read_table(tables[0]).to_pylist()}
    assert names == {"uniform", "kalman", "extra", "secoc"}  # SecOC ranked with the estimators' diagnoses
    capsys.readouterr()
    assert main(["leaderboard", str(out), "--json"]) == 0
    board = json.loads(capsys.readouterr().out)
    (group,) = board["groups"]
    assert group["group"] == {"track": "attacks", "case": "attacks"} and len(group["ranking"]) == 4
    page = tmp_path / "board.html"  # the page: the same tables, the tracks, the confusion matrices, the digest
    assert main(["leaderboard", str(out), "--html", str(page)]) == 0
    html = page.read_text()
    assert board["benchmark"]["digest"][:12] in html
    assert "Tracks: mean rank over the cases that place each scheme" in html
    assert "secoc</strong>: confusion matrix" in html and html.count("<img") == 2
    assert main(["benchmark", "--suite", str(suite), "--out", str(out)]) == 1  # not empty: refused


def test_the_leaderboard_counts_a_confusion_matrix_of_isolated_against_true_targets(tmp_path):
    rows = [
        {
            "run": i,
            "status": "completed",
            "estimator": "fdi",
            "kind": "cofd",
            "fault_kind": "loss_of_effectiveness",
            "rms_post_fault": 1.0,
            "diagnoses": True,
            "isolation_correct": found == true,
            "isolation_expected": true,
            "isolation_result": found,
        }
        for i, (true, found) in enumerate([("T4", "T4"), ("T4", "T4"), ("T5", "T4+T5"), ("T5", "T5"), ("T5", "none")])
    ]
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "t.parquet")
    (group,) = leaderboard(tmp_path / "t.parquet")["groups"]
    (score,) = group["ranking"]
    assert score["confusion"] == {"T4": {"T4": 2}, "T5": {"T4+T5": 1, "T5": 1, "none": 1}}
    assert score["isolation_accuracy"] == pytest.approx(3 / 5)


def test_the_intrusion_detector_is_a_scheme_of_its_own_in_the_table(tmp_path):
    from cosim import api, scenario
    from cosim.analysis.metrics import measure
    from cosim.campaign.results import INTRUSION_DETECTOR, rows_of

    loaded = scenario.apply(scenario.load("masses-spoofing"), {"bus.intrusion_detector": True, "duration": 8.0})
    api.run(loaded, tmp_path / "ids.mcap", seed=0, in_process=True)
    rows = {row["estimator"]: row for row in rows_of(measure(tmp_path / "ids.mcap"))}
    detector = rows[INTRUSION_DETECTOR]
    assert detector["diagnoses"] and detector["detected"] and detector["detection_delay_s"] == 0.0
    assert detector["false_alarms"] == 0 and detector["rms_post_fault"] is None
    assert {"uniform", "kalman"} <= rows.keys()


def test_secoc_is_a_scheme_of_its_own_detecting_and_isolating_by_the_rejected_message(tmp_path):
    from cosim import api, scenario
    from cosim.analysis.metrics import measure
    from cosim.campaign.results import SECOC, rows_of

    spoofing = scenario.load("masses-spoofing")  # spoof x1 from 5 to 10 s, replay x2 from 12 to 17 s
    for authentication in ("secoc", "none"):
        loaded = scenario.apply(spoofing, {"bus.authentication": authentication, "duration": 13.0})
        api.run(loaded, tmp_path / f"{authentication}.mcap", seed=0, in_process=True)
    metrics = measure(tmp_path / "secoc.mcap")
    rows = {row["estimator"]: row for row in rows_of(metrics)}
    secoc = rows[SECOC]
    assert secoc["diagnoses"] and secoc["detected"] and secoc["detection_delay_s"] == 0.0
    assert secoc["isolated"] and secoc["isolation_correct"] and secoc["isolation_delay_s"] == 0.0
    assert (secoc["isolation_expected"], secoc["isolation_result"]) == ("SENSOR_x1", "SENSOR_x1")
    assert secoc["false_alarms"] == 0 and secoc["rms_post_fault"] is None
    faults = metrics.bus.secoc_detection.faults
    assert faults["replay_x2"].isolated == ["SENSOR_x2"] and faults["replay_x2"].detection_delay == 0.0
    # 5 s of spoofing and 1 s of replay, one forged frame a tick: the alarm is up exactly then
    assert metrics.bus.secoc_detection.alarm_time_s == pytest.approx(6.0)
    assert SECOC not in {row["estimator"] for row in rows_of(measure(tmp_path / "none.mcap"))}


def test_without_the_lmi_extra_its_case_is_named_at_once_failed_with_why_and_on_the_board_as_not_run(
    tmp_path, capsys, monkeypatch
):
    """A new user without the lmi extra: cosim benchmark says before it runs which case needs it, each
    failed run says the extra in one line, and the leaderboard shows the case as not run and why."""
    suite = small_suite(tmp_path)
    suite.write_text(
        suite.read_text()
        + '\n[[cases]]\nname = "three-tank-gains"\ntrack = "faults"\ncampaign = "three-tank-gains"\n'
        + 'quick = { only = { gain = ["0.6"], onset_s = ["400.0"] } }\n'
    )
    for module in ("cvxpy", "clarabel"):  # as if the lmi extra were not installed
        monkeypatch.setitem(sys.modules, module, None)
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path / "cache"))  # no design made before
    out = tmp_path / "bundle"
    assert main(["benchmark", "--quick", "--suite", str(suite), "--out", str(out), "--engine", "inline"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    needs = "pip install 'cosim[lmi]'"
    assert (
        "warning: three-tank-gains (lpv-uio-sr, lft-uio-sr) needs the 'lmi' extra (cvxpy, clarabel are not "
        f"installed): {needs}" in err
    )
    assert err.index("needs the 'lmi' extra") < err.index("faults / three-tank-gains")
    why = "builtin:three-tank-reconciliation: estimators[0] (lpv, lpv-uio-sr) needs the 'lmi' extra"
    assert f"warning: three-tank-gains: 4 of 4 runs failed: {why} (clarabel is not installed): {needs}" in err
    record, _ = read_bundles([out])
    assert record["failures"]["three-tank-gains"]["failed"] == 4 and "attacks" not in record["failures"]
    assert main(["leaderboard", str(out), "--json"]) == 0
    board = json.loads(capsys.readouterr().out)
    by_case = {g["group"]["case"]: g for g in board["groups"]}
    assert set(by_case) == {"attacks", "three-tank-gains"} and by_case["attacks"]["ranking"]
    assert by_case["three-tank-gains"]["ranking"] == [] and by_case["three-tank-gains"]["not_run"]["runs"] == 4
    assert main(["leaderboard", str(out)]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"track = faults, case = three-tank-gains not run: its 4 runs failed before any scheme ran: {why}" in text
    page = tmp_path / "board.html"
    assert main(["leaderboard", str(out), "--html", str(page)]) == 0
    assert f"<strong>not run: its 4 runs failed before any scheme ran: {why}" in html.unescape(page.read_text())


def test_every_case_of_a_benchmark_runs_on_one_engine_started_once(tmp_path, monkeypatch):
    """A cluster takes seconds to start (its workers import the runner): the benchmark starts one
    and gives it to each case, which leaves it open."""
    from cosim.campaign import benchmark, coordinator, engine

    suite = small_suite(tmp_path, duration=0.5)
    suite.write_text(
        suite.read_text() + suite.read_text().split("\n\n", 1)[1].replace('name = "attacks"', 'name = "again"')
    )
    opened: list[engine.Engine] = []

    def counted(name: str, workers: int | None = None, address: str | None = None) -> engine.Engine:
        opened.append(engine.open_engine(name, workers, address))
        return opened[-1]

    monkeypatch.setattr(benchmark, "open_engine", counted)
    monkeypatch.setattr(coordinator, "open_engine", counted)
    record = benchmark.run_benchmark(tmp_path / "bundle", quick=True, suite_path=suite, engine="inline")
    assert sorted(record["cases"]) == ["again", "attacks"] and record["runs"] == 4 and record["failed"] == 0
    assert len(opened) == 1
