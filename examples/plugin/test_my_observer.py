"""The plugin's own test: its observer runs in a short scenario, detects the bias and isolates x1."""

from pathlib import Path

from cosim import api

HERE = Path(__file__).resolve().parent


def test_my_observer_detects_and_isolates_the_bias(tmp_path):
    result = api.run(api.load_scenario(HERE / "my-observer.toml"), tmp_path / "run.mcap", in_process=True)
    assert result.status == "completed", result.error
    metrics = api.metrics(result.path)
    assert metrics["estimators"]["mine"]["final_error"] < 0.3
    diagnosis = metrics["diagnosis"]["mine"]
    (bias,) = diagnosis["faults"].values()
    assert bias["detected"] and bias["detection_delay"] < 0.5 and diagnosis["false_alarms"] == 0
    assert bias["isolated"] == ["x1"] and bias["isolation_correct"]
