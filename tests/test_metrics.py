"""Metrics of run logs (cosim.analysis.metrics): hand-made logs with known answers, the UIO's alarm,
a real scenario's log checked against a direct computation, saturated estimates, and the metrics
scored while a run writes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cosim import scenario
from cosim.analysis.metrics import BAND_FACTOR, DiagnosisMetrics, RunMetrics, compute_metrics, measure
from cosim.analysis.metrics.values import to_json
from cosim.log.reader import LogReader
from cosim.run import run
from estimators import ParameterError, create
from estimators.model import LinearModel
from tests.hand_log import CLASSIC_ZERO, DT, FD_ZERO, N, write_hand_log


@pytest.fixture(scope="module")
def hand_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("hand") / "hand.mcap"
    write_hand_log(path)
    return path


@pytest.fixture(scope="module")
def hand(hand_log):
    return compute_metrics(hand_log)


def test_hand_log_run_and_faults(hand):
    assert (hand["scenario"], hand["seed"], hand["status"], hand["ticks"], hand["duration_s"]) == (
        "hand",
        7,
        "completed",
        N,
        10.0,
    )
    assert hand["warnings"] == [] and hand["missing"] == []
    assert hand["faults"] == {
        "f1": {"kind": "bias", "targets": ["y1"], "start": 4.0, "end": 6.0, "onset": 4.0, "cleared": 6.0},
        "f2": {
            "kind": "actuator_effectiveness",
            "targets": ["T1x"],
            "start": 7.0,
            "end": None,
            "onset": 7.0,
            "cleared": None,
        },
    }
    assert json.loads(json.dumps(hand)) == hand  # JSON-able as is


def test_hand_log_estimation(hand):
    uniform, good = hand["estimators"]["uniform"], hand["estimators"]["good"]
    assert hand["baseline"] == "uniform"
    assert uniform["rms_pre_fault"] == pytest.approx(0.1, rel=1e-12)
    post = math.sqrt((29 * 1.0 + 9.0 + 30 * 4.0) / 60)
    assert uniform["rms_post_fault"] == pytest.approx(post, rel=1e-12)
    assert uniform["final_error"] == pytest.approx(2.0) and uniform["ticks_scored"] == N
    assert uniform["band"] == pytest.approx(BAND_FACTOR * 0.1)
    assert uniform["faults"]["f1"] == {
        "peak_error": pytest.approx(3.0),
        "peak_at": 0.5,
        "recovery_time": None,
        "recovered": False,
    }
    assert uniform["faults"]["f2"]["peak_error"] == pytest.approx(2.0) and uniform["faults"]["f2"]["recovered"] is False
    assert uniform["bias_rejection_ratio"] == 1.0
    # good: band 2 x 0.05; out of it until tick 49, so back at tick 50, 1.0 s after the onset at 40
    assert good["ticks_scored"] == N - 1 and good["band"] == pytest.approx(0.1)
    assert good["faults"]["f1"] == {
        "peak_error": pytest.approx(0.5),
        "peak_at": 0.0,
        "recovery_time": 1.0,
        "recovered": True,
    }
    assert good["faults"]["f2"] == {
        "peak_error": pytest.approx(0.09),
        "peak_at": 0.0,
        "recovery_time": 0.0,
        "recovered": True,
    }
    good_post = math.sqrt((10 * 0.25 + 20 * 0.0064 + 30 * 0.0081) / 60)
    assert good["rms_post_fault"] == pytest.approx(good_post, rel=1e-12)
    assert good["bias_rejection_ratio"] == pytest.approx(good_post / post, rel=1e-12)


def test_hand_log_detection_and_isolation(hand):
    fdi = hand["diagnosis"]["fdi"]
    assert fdi["kind"] == "cofd"
    assert fdi["isolation_flags"] == {"T1": ["T1x", "T1y"], "T2": ["T2x"], "y1": ["y1"]}
    # fault-free: ticks 0-39 and 60-69; alarm episodes starting there: at 10, 30 and 67 (60-65
    # continues the episode that began during f1)
    assert fdi["fault_free_time_s"] == 5.0 and fdi["false_alarms"] == 3
    assert fdi["false_alarm_rate_per_hour"] == pytest.approx(3 / (5.0 / 3600))
    assert fdi["missed_detections"] == 0
    assert fdi["faults"]["f1"] == {
        "detected": True,
        "detection_delay": 0.3,
        "alarm_before_onset": False,
        "isolable": True,
        "expected": ["y1"],
        "isolation_delay": 0.5,
        "isolated": ["y1"],
        "isolation_correct": True,
    }
    # f2 acts on T1x: T2 is raised first (at 75), T1 only at 80: isolated at 80, wrongly (T2 came first)
    assert fdi["faults"]["f2"] == {
        "detected": True,
        "detection_delay": 0.2,
        "alarm_before_onset": False,
        "isolable": True,
        "expected": ["T1"],
        "isolation_delay": 1.0,
        "isolated": ["T1", "T2"],
        "isolation_correct": False,
    }
    silent = hand["diagnosis"]["silent"]
    assert (
        silent["missed_detections"] == 2 and silent["false_alarms"] == 0 and silent["false_alarm_rate_per_hour"] == 0.0
    )
    assert silent["faults"]["f1"]["detection_delay"] is None and silent["faults"]["f1"]["isolation_correct"] is None
    assert set(hand["diagnosis"]) == {"fdi", "silent"}  # estimators without alarm are no diagnosis process


def test_hand_log_bus(hand):
    bus = hand["bus"]
    assert bus["by_id"] == {
        "0x000": {"message": "NMT", "frames": 101, "bits": 101 * 53},
        "0x100": {"message": "SENSOR_y1", "frames": 100, "bits": 100 * 141},
    }
    per_tick = (CLASSIC_ZERO[0] + FD_ZERO[0]) / 500000 + FD_ZERO[1] / 2000000
    assert bus["load"] == pytest.approx((100 * per_tick + 53 / 500000) / 10.0, rel=1e-12)
    assert bus["peak_tick_load"] == pytest.approx((per_tick + 53 / 500000) / DT, rel=1e-12)
    worst = (55 + 34) / 500000 + 113 / 2000000
    assert bus["load_worst_case"] == pytest.approx((100 * worst + 55 / 500000) / 10.0, rel=1e-12)
    assert (bus["lost"], bus["lost_by_sender"], bus["deadline_misses"], bus["deadline_misses_by_node"]) == (
        5,
        {"fdi": 5},
        2,
        {"fdi": 2},
    )
    assert hand["frames"] == {"total": 201, "lost": 5}


def test_the_metrics_are_a_typed_value_with_one_json_form(hand_log, hand):
    value = measure(hand_log)
    assert isinstance(value, RunMetrics) and value.to_json() == hand
    assert value.estimators["good"].faults["f1"].peak_error == hand["estimators"]["good"]["faults"]["f1"]["peak_error"]
    assert value.diagnosis["fdi"].faults["f2"].isolated == hand["diagnosis"]["fdi"]["faults"]["f2"]["isolated"]
    assert value.bus is not None and value.bus.by_id["0x100"].bits == 100 * 141
    assert RunMetrics.from_json(hand) == value  # the JSON form reads back
    assert json.dumps(RunMetrics.from_json(json.loads(json.dumps(hand))).to_json()) == json.dumps(hand)
    # fields left out where None: the bus's intrusion detection and SecOC rejections, a detector's kind
    assert "intrusion_detection" not in hand["bus"] and "secoc_rejected" not in hand["bus"]
    assert "kind" not in to_json(DiagnosisMetrics()) and to_json(DiagnosisMetrics(kind="uio"))["kind"] == "uio"


def test_the_order_of_messages_within_a_tick_does_not_matter(tmp_path, hand):
    write_hand_log(tmp_path / "shuffled.mcap", order_estimates_first=False)
    shuffled = compute_metrics(tmp_path / "shuffled.mcap")
    assert {k: v for k, v in shuffled.items() if k != "file"} == {k: v for k, v in hand.items() if k != "file"}


def test_isolation_flags_name_what_the_estimator_declares():
    """The flags' targets come from the estimator (its diagnostics' kinds and isolation_targets), not
    from their names: the cofd kind's isolated_T<j> names the inputs of thruster j."""
    from tests.linear_vessel import model

    cofd = create("cofd", model(), {}, 0.1)
    targets = cofd.isolation_targets()
    assert targets["isolated_T1"] == ["T1x", "T1y"] and targets["isolated_T4"] == ["T4"]
    assert (
        create(
            "uio",
            LinearModel(-np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)), None, ("a", "b"), ("u", "v"), ("y1", "y2")),
            {"poles": [-1.0, -2.0], "E": [[1.0], [0.0]]},
            0.1,
        ).isolation_targets()
        == {}
    )


# -- the UIO's alarm ----------------------------------------------------------------------------


def uio_model():
    A = np.array([[0.0, 1.0, 0.0], [-2.0, -3.0, 0.0], [0.0, 0.0, -2.0]])
    B = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 1.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return LinearModel(
        A,
        B,
        C,
        np.zeros((2, 2)),
        None,
        ("x1", "x2", "x3"),
        ("u1", "u2"),
        ("y1", "y2"),
        E=np.array([[2.0], [0.0], [0.5]]),
        disturbances=("d",),
    )


def test_uio_alarm_parameters():
    model = uio_model()
    uio = create("uio", model, {"poles": [-1.0, -2.0, -3.0]}, 0.01)
    assert uio.arm_time == pytest.approx(5.0) and uio.params.threshold == 0.05
    with pytest.raises(ParameterError, match=r"^threshold: expected a positive number"):
        create("uio", model, {"poles": [-1.0, -2.0, -3.0], "threshold": 0.0}, 0.01)
    with pytest.raises(ParameterError, match=r"^arm_time: expected a time >= 0"):
        create("uio", model, {"poles": [-1.0, -2.0, -3.0], "arm_time": -1.0}, 0.01)
    # a wrong initial estimate: |r| is large at first, but the alarm waits for arm_time
    uio = create("uio", model, {"poles": [-1.0, -2.0, -3.0], "arm_time": 0.05, "threshold": 0.5}, 0.01)
    alarms = [uio.step(np.array([1.0, 1.0]), np.zeros(2)).diagnostics["alarm"] for _ in range(8)]
    assert alarms[:5] == [0.0] * 5 and alarms[5:] == [1.0] * 3


# -- a real scenario ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def uio_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("uio") / "uio.mcap"
    result = run(scenario.load("uio-fault-detection"), path, interface="virtual")
    assert result.status == "completed"
    return path


def direct_errors(path):
    """(ticks, errors per estimator, active faults per tick, uio alarm per tick) read whole."""
    x, est, act, alarm = {}, {"uio": {}, "kalman": {}}, {}, {}
    with LogReader(path) as reader:
        for topic, _, msg in reader.messages(["/truth/state", "/truth/faults", "/can/EST_uio", "/can/EST_kalman"]):
            if topic == "/truth/state":
                x[msg["tick"]] = np.array([msg[s] for s in ("x1", "x2", "x3")])
            elif topic == "/truth/faults":
                act[msg["tick"]] = msg["active"]
            else:
                name = topic.removeprefix("/can/EST_")
                est[name][msg["tick"]] = np.array([msg[f"xhat_{s}"] for s in ("x1", "x2", "x3")])
                if name == "uio":
                    alarm[msg["tick"]] = msg["alarm"]
    ticks = sorted(x)
    errors = {name: np.array([np.linalg.norm(x[k] - e[k]) for k in ticks]) for name, e in est.items()}
    return np.array(ticks), errors, act, alarm


@pytest.mark.slow
def test_real_scenario_metrics_agree_with_a_direct_computation(uio_run):
    report = compute_metrics(uio_run)
    assert report["warnings"] == [] and report["missing"] == []
    ticks, errors, act, alarm = direct_errors(uio_run)
    assert report["ticks"] == len(ticks) == 4000
    for name, e in errors.items():
        m = report["estimators"][name]
        assert m["rms_pre_fault"] == pytest.approx(np.sqrt(np.mean(e[:1000] ** 2)), rel=1e-12)
        assert m["rms_post_fault"] == pytest.approx(np.sqrt(np.mean(e[1000:] ** 2)), rel=1e-12)
        band = BAND_FACTOR * e[500:1000].max()
        assert m["band"] == pytest.approx(band, rel=1e-12)
        for label, (start, stop) in {"sensor_y2": (1000, 3000), "actuator_u1": (3000, 4000)}.items():
            segment = e[start:stop]
            assert m["faults"][label]["peak_error"] == pytest.approx(segment.max(), rel=1e-12)
            out = np.flatnonzero(segment > band)
            recovered = segment[-1] <= band
            assert m["faults"][label]["recovered"] == recovered
            if recovered:
                assert m["faults"][label]["recovery_time"] == pytest.approx(0.01 * (out[-1] + 1 if out.size else 0))
    # the UIO flags the sensor fault at its first sample and the actuator fault 0.27 s after onset
    # (docs/uio.md), and, armed after 5 s, raises no alarm without a fault
    uio = report["diagnosis"]["uio"]
    assert uio["faults"]["sensor_y2"]["detection_delay"] == 0.0
    assert uio["faults"]["actuator_u1"]["detection_delay"] == pytest.approx(0.27)
    assert uio["false_alarms"] == 0 and uio["missed_detections"] == 0 and uio["fault_free_time_s"] == 20.0
    assert uio["isolation_flags"] == {} and uio["faults"]["sensor_y2"]["isolation_correct"] is None
    assert all(alarm[k] == 0.0 for k in range(4000) if not act[k] and k < 2000)
    bus = report["bus"]
    assert (
        sum(e["frames"] for e in bus["by_id"].values())
        == report["frames"]["total"]
        == report["channels"]["/can/frames"]
    )
    assert 0 < bus["load"] <= bus["load_worst_case"] < 1 and bus["load"] <= bus["peak_tick_load"]
    assert bus["lost"] == 0 and bus["deadline_misses"] == 0


def test_a_frames_tick_is_its_counter_unwrapped_against_the_tick_it_was_logged_at():
    from cosim.log.recorder import carried_tick

    assert carried_tick(10, 10) == 10  # on time
    assert carried_tick(12, 10) == 10  # logged two ticks late (realtime)
    assert carried_tick(70_000, 70_000 % 65_536) == 70_000  # classic CAN: k mod 2^16
    assert carried_tick(70_003, 70_000 % 65_536) == 70_000
    assert carried_tick(70_003, 70_000) == 70_000  # CAN FD: the full k


def test_a_diverging_estimate_is_saturated_on_the_bus_and_counted_not_the_runs_end(tmp_path):
    """A fault large enough to drive the estimates out of their declared bus range (±8 m/s for the
    masses' velocities): the node sends them at the bound, the run completes, and the metrics count
    the saturated ticks from the fault's onset, with a warning that says so."""
    from cosim import api

    path = tmp_path / "big.mcap"
    loaded = api.load_scenario("masses-bias", {"faults[0].value": 2.0, "duration": 8.0})
    result = api.run(loaded, path, in_process=True)
    assert result.status == "completed"
    measured = api.metrics(path)
    uniform = measured["estimators"]["uniform"]
    assert uniform["saturated"] and all(s["ticks"] > 0 and s["first_at"] >= 5.0 for s in uniform["saturated"].values())
    for signal in uniform["saturated"]:  # the fault starts at 5 s
        assert any(w.startswith(f"uniform: {signal} at its bus range's bound") for w in measured["warnings"])
    with LogReader(path) as reader:  # the frames carry the bound itself
        signals = [msg for topic, _, msg in reader.messages() if topic.startswith("/can/EST_uniform")]
    carried = [v for msg in signals for name, v in msg.items() if name.startswith("xhat_")]
    assert max(abs(v) for v in carried) == pytest.approx(8.0, abs=1e-3)


def test_an_estimate_inside_its_range_is_never_counted_as_saturated(tmp_path):
    from cosim import api

    path = tmp_path / "small.mcap"
    api.run(api.load_scenario("masses-bias", {"duration": 8.0}), path, in_process=True)
    estimates = api.metrics(path)["estimators"].values()
    assert all(e["saturated"] == {} for e in estimates)


@pytest.mark.parametrize(
    ("name", "settings"),
    [
        ("masses-bias", {"duration": 8.0}),  # estimation, a bias from 5 s, the uniform baseline
        ("masses-bus-overload", {"duration": 12.0}),  # the arbitrated wire: latency, late frames, load
        ("masses-spoofing", {"duration": 14.0}),  # SecOC's rejections, scored as a diagnosis
        ("masses-spoofing", {"duration": 14.0, "bus.intrusion_detector": True}),  # the detector's checks
        ("uio-fault-detection", {"duration": 20.0}),  # alarms: detection, isolation, false alarms
    ],
)
def test_metrics_scored_while_the_run_writes_are_those_of_its_log(name, settings, tmp_path):
    """``run(..., measure=True)`` feeds the scorer what the log gets, as it gets it: its metrics are,
    field for field, those ``measure`` reads back from the finished file."""
    from cosim import api

    loaded = api.load_scenario(name, settings)
    result = api.run(loaded, tmp_path / "run.mcap", seed=4, in_process=True, measure=True)
    assert result.status == "completed" and result.metrics is not None
    assert result.metrics.to_json() == measure(result.path).to_json()


def test_a_failing_live_scorer_leaves_the_run_alone(tmp_path, monkeypatch):
    """Scoring during a run never ends it: a scorer that raises stops scoring, the run completes
    with its whole log, and the result carries no metrics (a campaign then reads the log)."""
    from cosim import api
    from cosim.analysis.metrics import scorer

    def broken(self, topic, log_time, msg):
        raise RuntimeError("a bug in scoring")

    monkeypatch.setattr(scorer.Scorer, "feed", broken)
    loaded = api.load_scenario("masses-bias", {"duration": 1.0})
    result = api.run(loaded, tmp_path / "run.mcap", seed=1, in_process=True, measure=True)
    assert result.status == "completed" and result.metrics is None
    with LogReader(result.path) as reader:
        assert sum(1 for _ in reader.messages()) > 100
