"""``cosim dataset``: a campaign into frames, signals, truth and labels, the labels checked against
the truth, split by seed, the same bytes twice, loadable by pandas and HuggingFace ``datasets``,
and the masquerade that timing cannot see and the physics can."""

from __future__ import annotations

import csv
import json

import can
import numpy as np
import pandas as pd
import pytest

from cosim.campaign.dataset import build_dataset, split_of
from cosim.campaign.spec import load_campaign
from cosim.cli import main
from cosim.errors import CosimError
from cosim.log.reader import LogReader

#: Two 3 s runs of the masses in closed loop on an arbitrated classic CAN bus (two seeds): a
#: masquerade of SENSOR_x2 (+0.2 m) from 1.0 to 1.6 s, then a bias on x1 from 2.0 to 2.5 s.
CAMPAIGN = """
name = "tiny"
description = "a masquerade and a sensor bias on masses-pid-can"
scenario = "masses-pid-can"
seed = 5
seeds = 2
bus = "in-process"

[set]
duration = 3.0
faults = [
  { name = "mq", kind = "masquerade", message = "SENSOR_x2", offset = 0.2, start = 1.0, end = 1.6 },
  { name = "bias", kind = "bias", sensors = ["x1"], value = 0.05, start = 2.0, end = 2.5 },
]
"""
SPLIT = (0.5, 0.5, 0.0)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The campaign run (its logs kept) and its data set, with the estimates."""
    root = tmp_path_factory.mktemp("dataset")
    (root / "tiny.toml").write_text(CAMPAIGN)
    card = build_dataset(
        [root / "tiny.toml"],
        root / "ds",
        fractions=SPLIT,
        estimates=True,
        campaigns_dir=root / "campaigns",
        engine="inline",
    )
    return root, card


def _table(root, name):
    return pd.read_parquet(root / "ds" / name).sort_values(["run", "tick"] if name != "frames" else ["run", "seq"])


def test_every_attack_frame_is_labelled_and_no_other(built):
    root, _ = built
    frames = pd.concat([pd.read_parquet(root / "ds" / "frames" / s) for s in ("train", "validation")])
    for run, group in frames.groupby("run"):
        with LogReader(root / "campaigns" / "tiny" / "logs" / f"run-{run:06d}.mcap") as reader:
            intruders = {m["seq"] for _, _, m in reader.messages(["/cosim/foreign"])}
        assert set(group.seq[group.label == 1]) == intruders
        x2 = group[group.message == "SENSOR_x2"]
        forged = x2[(x2.tick >= 100) & (x2.tick < 160)]
        assert len(x2) == 300 and len(forged) == 60  # one a tick: the masquerader's in the genuine slot
        assert (forged.label == 1).all() and (forged.attack == "masquerade").all() and (forged.fault == "mq").all()
        assert group.label.sum() == 60


def test_a_fault_is_labelled_on_exactly_the_ticks_between_its_onset_and_end(built):
    root, _ = built
    labels = pd.concat([pd.read_parquet(root / "ds" / "labels" / s) for s in ("train", "validation")])
    truth = pd.concat([pd.read_parquet(root / "ds" / "truth" / "tiny" / s) for s in ("train", "validation")])
    for run, ticks in labels.groupby("run"):
        ticks = ticks.set_index("tick")
        assert list(ticks.index[ticks["class"] == "masquerade"]) == list(range(100, 160))
        assert list(ticks.index[ticks["class"] == "bias"]) == list(range(200, 250))
        assert (ticks.label == (ticks["class"] != "normal")).all()
        bias = truth[truth.run == run].set_index("tick")["fault.x1"]
        assert list(bias.index[bias != 0]) == list(range(200, 250))  # the fault layer's own record
        assert (ticks.loc[100:159, "attack_class"] == "masquerade").all()
        assert (ticks.loc[200:249, "category"] == "fault").all()
    events = pd.concat([pd.read_parquet(root / "ds" / "events" / s) for s in ("train", "validation")])
    assert sorted(zip(events.fault, events.onset_tick, events.end_tick)) == [
        ("bias", 200, 250),
        ("bias", 200, 250),
        ("mq", 100, 160),
        ("mq", 100, 160),
    ]


def test_splits_go_by_replicate_and_share_no_run(built):
    _, card = built
    split = {(r["campaign"], r["run"]): r["split"] for r in card["runs"]}
    assert sorted(split.values()) == ["train", "validation"]
    assert card["splits"]["train"]["replicates"] == {"tiny": [0]}
    assert split_of(list(range(10))) == {
        **dict.fromkeys(range(6), "train"),
        6: "validation",
        7: "validation",
        8: "test",
        9: "test",
    }
    assert split_of([4, 9, 11], (1 / 3, 1 / 3, 1 / 3)) == {4: "train", 9: "validation", 11: "test"}
    with pytest.raises(CosimError, match="three shares that add up to 1"):
        split_of([1, 2], (0.5, 0.6, 0.1))


def test_the_same_campaign_gives_the_same_bytes(built, tmp_path):
    root, card = built
    again = build_dataset([root / "tiny.toml"], tmp_path / "ds", fractions=SPLIT, estimates=True, engine="inline")
    assert again["digest"] == card["digest"]
    for name in ("card.json", "README.md", *(f["path"] for f in card["files"])):
        assert (tmp_path / "ds" / name).read_bytes() == (root / "ds" / name).read_bytes(), name
    assert card["files"] and all(len(f["sha256"]) == 64 for f in card["files"])


def test_pandas_and_huggingface_datasets_load_it(built, tmp_path, monkeypatch):
    import datasets  # HuggingFace's (the test extra declares it)

    root, card = built
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    frames = datasets.load_dataset("parquet", data_dir=str(root / "ds" / "frames"), cache_dir=str(tmp_path))
    assert set(frames) == {"train", "validation"}
    assert frames["train"].num_rows + frames["validation"].num_rows == sum(
        len(pd.read_parquet(root / "ds" / "frames" / s)) for s in ("train", "validation")
    )
    labels = datasets.load_dataset(str(root / "ds"), "labels", cache_dir=str(tmp_path))
    assert labels["train"].num_rows == 300 and sum(labels["train"]["label"]) == 110
    signals = datasets.load_dataset(str(root / "ds"), "signals-tiny", cache_dir=str(tmp_path))
    assert "reading.x2" in signals["train"].features and "estimate.kalman.x2" in signals["train"].features
    assert card["balance"]["train"]["ticks"] == {"bias": 50, "masquerade": 60, "normal": 190}


def test_the_hcrl_and_road_forms_hold_the_same_frames(built):
    root, _ = built
    frames = _table(root, "frames")
    train = frames[frames.run == 0]
    with open(root / "ds" / "hcrl" / "train" / "tiny-run-000000.csv") as handle:
        rows = list(csv.reader(handle))
    assert len(rows) == len(train)
    assert [int(r[1], 16) for r in rows] == list(train.id)
    assert [bytes(int(b, 16) for b in r[3:-1]) for r in rows] == list(train.data)
    assert [r[-1] for r in rows] == ["T" if label else "R" for label in train.label]
    road = root / "ds" / "road" / "train" / "attacks"
    logged = list(can.LogReader(road / "tiny-run-000000.log"))
    assert [(m.arbitration_id, bytes(m.data)) for m in logged] == list(zip(train.id, train.data))
    assert [m.timestamp for m in logged] == pytest.approx(list(train.timestamp), abs=1e-6)
    capture = json.loads((road / "capture_metadata.json").read_text())["tiny-run-000000"]
    forged = train[train.label == 1].timestamp
    assert capture["injection_id"] == "0x101" and capture["road_rule_exact"] is True
    assert capture["injection_interval"] == [round(forged.min() - 5e-7, 7), round(forged.max() + 5e-7, 7)]
    assert 1.0 <= forged.min() and forged.max() < 1.6


def test_a_masquerade_moves_the_plant_unseen_by_timing_and_seen_in_the_residuals(built):
    """The masquerader sends SENSOR_x2 in its slot at its period with the next counter: the
    intrusion detector's period (and every other) check stays silent; the controller, fed x2 + 0.2 m,
    drives the true x2 away; the Kalman filter's residuals y − C x̂ jump."""
    root, _ = built
    campaign = load_campaign(root / "tiny.toml")
    signals, truth = _table(root, "signals/tiny/train"), _table(root, "truth/tiny/train")
    with LogReader(root / "campaigns" / "tiny" / "logs" / "run-000000.mcap") as reader:
        ids = [m for _, _, m in reader.messages(["/cosim/ids"])]
        arrivals = [t for _, t, m in reader.messages(["/can/frames"]) if m["message"] == "SENSOR_x2"]
    assert not any(v["alarm"] for v in ids)
    gaps = np.diff(arrivals) / 1e9
    assert gaps[99:160] == pytest.approx(0.01, abs=2e-4)  # the masquerader's period is the genuine one's
    before, during = slice(50, 100), slice(130, 160)
    forged = signals["reading.x2"].to_numpy() - truth["sensor.x2"].to_numpy()
    assert np.abs(forged[during] - 0.2).max() < 0.005  # what it sends: the true x2 + 0.2 m (+ noise)
    assert campaign.base.scenario.controller is not None
    c = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [1.0, -1.0, 0, 0]])
    states = ("x1", "x2", "v1", "v2")
    xhat = signals[[f"estimate.kalman.{s}" for s in states]].to_numpy()
    y = signals[["reading.x1", "reading.x2", "reading.x1_minus_x2"]].to_numpy()
    residual = np.abs(y - xhat @ c.T).max(axis=1)
    assert residual[during].min() > 10 * residual[before].max()


def test_it_refuses_what_it_cannot_make_in_one_line(built, tmp_path, capsys):
    root, _ = built
    folder = tmp_path / "no-logs"
    (folder / "parts").mkdir(parents=True)
    (folder / "campaign.toml").write_text(CAMPAIGN)
    for i in (0, 1):
        part = {"rows": [{"run": i, "status": "completed", "log": ""}]}
        (folder / "parts" / f"run-{i:06d}.json").write_text(json.dumps(part))
    assert main(["dataset", str(folder), "--out", str(tmp_path / "ds")]) == 1
    assert "run 0 kept no log" in capsys.readouterr().err
    assert main(["dataset", str(root / "campaigns" / "tiny"), "--out", str(root / "ds")]) == 1
    assert "is not empty" in capsys.readouterr().err
    assert main(["dataset", str(root / "campaigns" / "tiny"), "--out", str(tmp_path / "x"), "--split", "1,1"]) == 1
    assert "three shares" in capsys.readouterr().err


def test_a_split_left_empty_is_said_before_the_runs_are_read_and_kept_in_the_card(built, tmp_path, capsys):
    root, _ = built
    assert main(["dataset", str(root / "campaigns" / "tiny"), "--out", str(tmp_path / "ds")]) == 0
    said = "tiny: test will be empty: 2 replicates cut at the shares 0.6,0.2,0.2; --seeds 4 or more fills every split"
    err = capsys.readouterr().err
    assert f"warning: {said}" in " ".join(err.split()) and err.index("warning") < err.index("run 1 of 2")
    card = json.loads((tmp_path / "ds" / "card.json").read_text())
    assert card["warnings"] == [said] and card["splits"]["test"]["runs"] == 0
    assert f"- **warning**: {said}" in (tmp_path / "ds" / "README.md").read_text()


def test_the_baselines_train_on_its_splits_and_enter_a_run_as_plugins(built, tmp_path):
    """python -m cosim.baselines.train fits both baselines on the train split (limits on the validation
    split); named by module path, they run beside the estimators, publish an alarm and no estimate,
    and the metrics score them as diagnosis schemes."""
    from cosim.analysis.metrics import compute_metrics
    from cosim.baselines.train import main as train
    from cosim.run import run

    root, _ = built
    assert train([str(root / "ds"), "--out", str(tmp_path / "models")]) == 0
    fitted = json.loads((tmp_path / "models" / "pca.json").read_text())["models"]
    assert [m["sensors"] for m in fitted] == [["x1", "x2", "x1_minus_x2"]] and fitted[0]["ticks"] == 100
    schemes = [
        ("pca", "cosim.baselines.pca:PcaMonitor", "pca.json"),
        ("oc", "cosim.baselines.one_class:OneClassMonitor", "one_class.json"),
    ]
    settings = [
        ("duration", 3.0),
        (
            "faults",
            [{"name": "mq", "kind": "masquerade", "message": "SENSOR_x2", "offset": 0.2, "start": 1.5, "end": 2.5}],
        ),
    ]
    for i, (name, kind, file) in enumerate(schemes, start=2):
        settings.append(
            (f"estimators[{i}]", {"name": name, "kind": kind, "params": {"model": str(tmp_path / "models" / file)}})
        )
    loaded = scenario_apply(settings)
    out = tmp_path / "run.mcap"
    assert run(loaded, out, 11, interface="virtual").status == "completed"
    metrics = compute_metrics(out)
    for name, _, _ in schemes:
        assert metrics["estimators"][name]["rms_post_fault"] is None
        found = metrics["diagnosis"][name]["faults"]["mq"]
        assert found["detected"] and found["detection_delay"] <= 0.05, (name, found)


def scenario_apply(settings):
    from cosim import scenario

    return scenario.apply(scenario.load("masses-pid-can"), settings)


def test_the_docs_loading_example_runs_with_the_extra_the_docs_name(built, tmp_path, monkeypatch):
    """docs/datasets.md tells a user to install the dataset extra; its loading example, run as printed
    on a data set, imports nothing that extra does not bring."""
    import re
    import tomllib

    from tests.conftest import ROOT

    docs = (ROOT / "docs" / "datasets.md").read_text()
    assert "pip install '.[dataset]'" in docs
    code = re.search(r"### Loading\n.*?```python\n(.*?)```", docs, re.S).group(1)
    imported = set(re.findall(r"^(?:import|from) (\w+)", code, re.M))
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    brought = {re.split(r"[<>=\[ ]", r)[0] for r in extras["dataset"] + extras["campaign"]}
    assert imported == {"pandas", "datasets"} and imported <= brought
    root, _ = built
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_CACHE", str(tmp_path / "hf"))
    here = str(root / "ds")
    code = code.replace("/abs/path/runs/ds-attacks", here).replace("runs/ds-attacks", here)
    names: dict[str, object] = {}
    exec(code.replace("signals-dataset-attacks", "signals-tiny"), names)  # the docs' own example, as printed
    assert len(names["frames"]) and len(names["ticks"]) == 600 and names["labels"]["train"].num_rows == 300
