"""What a campaign writes with each ``--keep-logs``: a run whose log is not kept writes none (it is
scored as it goes, to the same rows), and with ``failed`` a run that fails is run again with its log."""

from __future__ import annotations

import pyarrow.parquet as pq
import pytest

import cosim.run.session
from cosim.campaign.coordinator import run_campaign
from cosim.campaign.results import NONDETERMINISTIC
from cosim.campaign.spec import load_campaign
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader

CAMPAIGN = """
name = "logs"
scenario = "masses-bias"
seed = 3
seeds = 1
[set]
duration = 1.0
"faults[0].start" = 0.5
[[axes]]
key = "faults[0].value"
values = [0.2, 40.0]   # 40 m is outside the sensor's bus range: the run stops with an error at 0.5 s
name = "bias"
"""


@pytest.fixture
def opened(monkeypatch):
    """The paths of every MCAP file a run opens."""
    paths = []
    real = cosim.run.session.McapLog

    def recording(path, **kwargs):
        paths.append(path)
        return real(path, **kwargs)

    monkeypatch.setattr(cosim.run.session, "McapLog", recording)
    return paths


def run(tmp_path, keep_logs):
    path = tmp_path / "logs.toml"
    path.write_text(CAMPAIGN)
    result = run_campaign(load_campaign(path), tmp_path / keep_logs, engine="inline", keep_logs=keep_logs)
    return result, pq.read_table(result.path)


def metrics(table):
    return table.drop([c for c in (*NONDETERMINISTIC, "log") if c in table.column_names]).to_pylist()


def test_with_failed_a_completed_run_writes_no_log_and_a_failed_one_runs_again_with_it(tmp_path, opened):
    result, table = run(tmp_path, "failed")
    rows = {r["run"]: r for r in table.to_pylist()}
    assert result.failed == 1 and rows[0]["status"] == "completed" and rows[1]["status"] == "error"
    assert "outside" in rows[1]["error"] and rows[0]["log"] == ""
    log = tmp_path / "failed" / rows[1]["log"]
    assert opened == [log]  # the completed run opened no file; the failed one, on its second run only
    with LogReader(log) as reader:
        outcome = LogMetadata.read(reader.metadata()).result
    assert outcome is not None and outcome.status == "error" and "outside" in outcome.error


def test_with_none_no_run_writes_a_log_and_the_rows_are_those_of_logged_runs(tmp_path, opened):
    _, unlogged = run(tmp_path, "none")
    assert opened == [] and not (tmp_path / "none" / "logs").exists()
    _, logged = run(tmp_path, "all")
    assert len(opened) == 2 and all(path.exists() for path in opened)
    assert metrics(unlogged) == metrics(logged)
