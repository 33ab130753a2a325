"""The bus of a batch (cosim.campaign.batch_bus): attacks and bus faults on an ideal bus, SecOC and the
intrusion detector, stepped together for K runs, give each run exactly the metrics row it gives alone;
the detector's K-run form raises exactly what the single detector raises, frame for frame."""

from __future__ import annotations

import numpy as np
import pytest

from cosim import api
from cosim.bus.codec import Decoded
from cosim.campaign.batch import run_batch, run_together
from cosim.campaign.coordinator import run_campaign
from cosim.campaign.results import rows_of
from cosim.campaign.spec import load_campaign
from cosim.errors import CodecError
from cosim.log.topics import IDS_CHECKS
from cosim.run.detector import DetectorRuns, IntrusionDetector
from cosim.run.plan import RunPlan
from cosim.scenario import apply

SEEDS = [3, 4, 5]

# masses-spoofing's attacks moved into 1.4 s: a spoofed x1, then x2 replayed 0.3 s late
ATTACKS = [
    {"name": "spoof_x1", "kind": "spoofing", "message": "SENSOR_x1", "value": 0.5, "start": 0.2, "end": 0.5},
    {"name": "replay_x2", "kind": "replay", "message": "SENSOR_x2", "lag": 0.3, "start": 0.7, "end": 1.1},
]
LOSS = {"kind": "frame_loss", "messages": ["SENSOR_x2"], "probability": 0.4, "burst_length": 3.0}
FAULTS = {
    "spoofing-replay": ATTACKS,
    "suspension": [{"name": "silenced", "kind": "suspension", "messages": ["SENSOR_x2"], "start": 0.3, "end": 0.8}],
    "masquerade": [
        {"name": "drift", "kind": "masquerade", "message": "SENSOR_x1", "offset": 0.2, "rate": 0.5, "start": 0.3},
        {"name": "fixed", "kind": "masquerade", "message": "SENSOR_x2", "value": 0.1, "start": 0.6, "end": 0.9},
    ],
    # lost frames before and while a replay (its record has gaps: what it resends comes from further back)
    "loss-replay": [
        {**LOSS, "name": "loss", "start": 0.1, "end": 1.3},
        {"name": "replay", "kind": "replay", "message": "SENSOR_x2", "lag": 0.25, "start": 0.9, "end": 1.3},
    ],
    # a reading dropped for 0.5 s, then replayed from before the gap; then spoofed where it is missing
    "dropout-replay": [
        {"name": "gone", "kind": "dropout", "sensors": ["x2"], "probability": 1.0, "start": 0.1, "end": 0.6},
        {"name": "replay", "kind": "replay", "message": "SENSOR_x2", "lag": 0.3, "start": 0.7, "end": 1.0},
        {"name": "lone", "kind": "spoofing", "message": "SENSOR_x2", "value": -0.3, "start": 0.3, "end": 0.5},
    ],
    # replayed within SecOC's window (5 ticks) while the reading comes and goes: a replayed frame
    # whose genuine one is missing is refused only because the receivers accepted the frames since
    "dropout-quick-replay": [
        {"name": "gone", "kind": "dropout", "sensors": ["x2"], "probability": 1.0, "start": 0.68, "end": 0.74},
        {"name": "flaky", "kind": "dropout", "sensors": ["x2"], "probability": 0.5, "start": 0.8, "end": 1.2},
        {"name": "replay", "kind": "replay", "message": "SENSOR_x2", "lag": 0.05, "start": 0.7, "end": 1.0},
    ],
}


def attacked(faults, authentication="none", detector=True):
    return apply(
        api.load("masses-spoofing"),
        [
            ("duration", 1.4),
            ("faults", faults),
            ("bus.authentication", authentication),
            ("bus.intrusion_detector", detector),
        ],
    )


def alone(loaded, seed):
    return rows_of(api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics)


def assert_batched_as_alone(loaded, seeds=SEEDS):
    """Each run's row, and what its bus's schemes said beyond the row (every check of the detector,
    SecOC's rejections by id and reason), exactly as alone."""
    runs = run_batch(loaded, seeds)
    assert [run.left for run in runs] == [""] * len(seeds)
    for seed, run in zip(seeds, runs):
        single = api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics
        assert rows_of(run.metrics) == rows_of(single), seed  # exact: every float, every count
        assert (run.metrics.contested_ticks, run.metrics.frames.lost) == (single.contested_ticks, single.frames.lost)
        schemes = [
            (m.bus.intrusion_detection, m.bus.secoc_detection, m.bus.secoc_rejected) for m in (run.metrics, single)
        ]
        assert schemes[0] == schemes[1], seed


def test_spoofing_and_replay_batched_give_each_runs_row_alone_with_the_detector_and_secoc():
    for authentication in ("none", "secoc"):
        loaded = attacked(ATTACKS, authentication)
        assert_batched_as_alone(loaded)
    rows = alone(attacked(ATTACKS, "secoc"), 3)  # the rows say what the attacks did: not a vacuous equality
    assert {row["estimator"] for row in rows} == {"uniform", "kalman", "intrusion-detector", "secoc"}
    assert all(row["detected"] for row in rows if row["estimator"] in ("intrusion-detector", "secoc"))
    assert alone(attacked(ATTACKS), 3)[0]["contested_ticks"] == 70  # 30 spoofed ticks, 40 replayed


@pytest.mark.parametrize("authentication", ["none", "secoc"])
@pytest.mark.parametrize("name", sorted(set(FAULTS) - {"spoofing-replay"}))
def test_the_other_attacks_and_frame_loss_batched_give_each_runs_row_alone(name, authentication):
    assert_batched_as_alone(attacked(FAULTS[name], authentication, detector=authentication == "none"))


def test_lost_frames_and_a_replay_through_gaps_batched_give_each_runs_row_alone():
    assert_batched_as_alone(attacked(FAULTS["loss-replay"], "secoc"), [3, 4])
    assert_batched_as_alone(attacked(FAULTS["dropout-replay"]), [3, 4])
    assert_batched_as_alone(attacked(FAULTS["dropout-quick-replay"], "secoc"), [3, 4])


def test_a_run_whose_intruder_forges_what_its_frame_cannot_carry_leaves_the_batch_and_ends_as_alone():
    spoofed = attacked(ATTACKS, "secoc")
    out_of_range = attacked([{**ATTACKS[0], "value": 50.0, "start": 0.4}, ATTACKS[1]], "secoc")
    members = [(spoofed, 3), (out_of_range, 4), (spoofed, 5)]
    runs = run_together(members)
    assert not any(run.refused for run in runs)
    assert runs[1].metrics is None and runs[1].left.startswith("tick 40: ")
    for (loaded, seed), run in zip(members[::2], runs[::2]):
        assert not run.left and rows_of(run.metrics) == alone(loaded, seed)
    with pytest.raises(CodecError, match="SENSOR_x1.x1 at tick 40 = 50 m is outside"):  # alone: its error
        api.run(out_of_range, None, seed=4, in_process=True, measure=True)
    assert "SENSOR_x1.x1 at tick 40 = 50 m is outside" in runs[1].left


def test_the_masses_attacks_campaign_runs_batched_and_gives_the_table_of_its_runs_one_at_a_time(tmp_path):
    campaign = load_campaign("masses-attacks", seeds=2)
    text = campaign.text.replace('bus = "in-process"', 'bus = "in-process"\n[set]\nduration = 1.4\n')
    spoofing, replay = ATTACKS
    text += f"\n[[set.faults]]\n{_toml(spoofing)}\n[[set.faults]]\n{_toml(replay)}\n"
    (tmp_path / "attacks.toml").write_text(text)
    campaign = load_campaign(tmp_path / "attacks.toml", seeds=2)
    tables = {
        b: run_campaign(campaign, tmp_path / f"b{b}", engine="inline", keep_logs="none", batch=b) for b in (1, None)
    }
    assert tables[None].batched == tables[None].runs == 8 and tables[1].batched == 0
    assert metrics(tables[1].path).equals(metrics(tables[None].path))


def _toml(table):
    return "\n".join(f"{key} = {value!r}".replace("'", '"') for key, value in table.items())


def metrics(path):
    import pyarrow.parquet as pq

    from cosim.campaign.results import NONDETERMINISTIC

    table = pq.read_table(path).to_pandas()
    return table.drop(columns=list(NONDETERMINISTIC))


@pytest.mark.parametrize("scenario", ["masses-spoofing", "masses-bias"])  # CAN FD's tick counter, classic CAN's
def test_the_detectors_k_run_form_raises_what_the_single_detector_raises_frame_for_frame(scenario):
    plan = RunPlan.build(apply(api.load(scenario), [("duration", 1.0)]), 0, interface="virtual")
    codec, dt_ns = plan.codec, plan.scenario.dt_ns
    specs = [codec.sensor(name) for name in plan.scenario.sensors]
    ids = [spec.frame_id for spec in specs]
    runs, rng = 6, np.random.default_rng(7)
    single = [IntrusionDetector(codec, dt_ns) for _ in range(runs)]
    batched = DetectorRuns(codec, dt_ns, runs, ids)
    modulus = codec.tick_modulus
    for k in range(300):
        t_ns, counter = k * dt_ns, k % modulus
        arrived = rng.random((runs, len(ids))) < 0.8
        inside = rng.random((runs, len(ids))) < 0.95
        forged = [
            [
                (
                    int(rng.integers(len(ids))),
                    int(rng.choice([k, k - 1, k - 100, k + 1, k + 2, k + 3, k - 200])) % modulus,
                )
                for _ in range(n)
            ]
            for n in rng.integers(0, 3, runs) * (rng.random(runs) < 0.3)
        ]
        for r in range(runs):
            for i, spec in enumerate(specs):
                if arrived[r, i]:
                    single[r].frame(k, t_ns, _frame(spec), _decoded(spec, counter, 0.1 if inside[r, i] else 99.0))
            for i, tick in forged[r]:
                single[r].frame(k, t_ns, _frame(specs[i]), _decoded(specs[i], tick, 0.2))
        batched.frames(t_ns, counter, ids, arrived, inside)
        for r in range(runs):
            for i, tick in forged[r]:
                batched.frame(r, t_ns, ids[i], _decoded(specs[i], tick, 0.2))
        verdicts = batched.verdicts()
        for r in range(runs):
            raised = single[r]._alarms.pop(k, {})
            expected = [float(bool(raised.get(check))) for check in IDS_CHECKS]
            assert verdicts[r].tolist() == [float(any(expected)), *expected], (k, r)
    assert single[0].alarms > 0


def _frame(spec):
    import can

    return can.Message(arbitration_id=spec.frame_id, data=b"", is_extended_id=False)


def _decoded(spec, tick, value):
    return Decoded(spec, tick, {signal: value for signal in spec.signals})
