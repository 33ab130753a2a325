"""ROAD's form of a data set, read as the published ROAD loaders read it: every attack capture that
ROAD's fields can express is labelled by ROAD's rule exactly as the data set labels it, the
attack-free runs sit apart in ``ambient/``, and the card names the captures the rule cannot label
(a replay) and why.

``road_loader_labels`` is not cosim's code: it applies the rule as published loaders of ROAD apply
it (read on GitHub, not copied): the capture's metadata from the ``capture_metadata.json`` beside
its log, by the log's file name; a line ``(time) channel ID#DATA`` and nothing after; the time from
the capture's first frame, rounded to microseconds, in ``injection_interval`` with both ends
included; the id the injection's unless it is ``"XXX"`` (compared both as a number and, as a loader
of ROAD's CSV conversion does, as the text ``injection_id[2:].upper().rjust(3, "0")``); the payload
upper-case, left-padded with zeros to 16 hex digits (``zfill(16)``, as ROAD's own
``make_can_df``), matching ``injection_data_str`` where it is not ``X``; a null field matching
anything (the strictest reading: ROAD writes none in an attack capture).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import can
import pandas as pd
import pytest

from cosim.campaign.dataset import build_dataset

pytestmark = pytest.mark.slow

#: dataset-attacks (docs/datasets.md) in 3 s runs, each attack from 1.0 to 2.0 s.
CAMPAIGN = """
name = "attacks-short"
description = "every attack of dataset-attacks on masses-pid-can, 1.0 to 2.0 s of 3 s"
scenario = "masses-pid-can"
seed = 7
seeds = 1
bus = "in-process"

[set]
duration = 3.0

[[axes]]
key = "faults"
name = "attack"
labels = ["none", "flooding", "injection", "fuzzing", "suspension", "masquerade", "replay"]
values = [
  [],
  [{ name = "flooding", kind = "babbling_node", id = 0x000, period = 0.00025, start = 1.0, end = 2.0 }],
  [{ name = "injection", kind = "spoofing", message = "SENSOR_x2", value = 0.8, start = 1.0, end = 2.0 }],
  [{ name = "fuzzing", kind = "fuzzing", period = 0.0005, payload = "FFFFFFFFFFFFFFFF", start = 1.0, end = 2.0 }],
  [{ name = "suspension", kind = "suspension", messages = ["SENSOR_x2"], start = 1.0, end = 2.0 }],
  [{ name = "masquerade", kind = "masquerade", message = "SENSOR_x2", offset = 0.2, start = 1.0, end = 2.0 }],
  [{ name = "replay", kind = "replay", message = "SENSOR_x2", lag = 0.5, start = 1.0, end = 2.0 }],
]
"""
#: A line of ROAD's logs: nothing after the data (no direction flag).
LINE = re.compile(r"^\((?P<time>\d+\.\d{6})\) can0 (?P<id>[0-9A-F]{3}|[0-9A-F]{8})#(?P<data>(?:[0-9A-F]{2})*)$")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("road")
    (root / "attacks.toml").write_text(CAMPAIGN)
    warnings: list[str] = []
    card = build_dataset(
        [root / "attacks.toml"], root / "ds", fractions=(1.0, 0.0, 0.0), engine="inline", on_warning=warnings.append
    )
    return root / "ds", card, warnings


def road_loader_labels(log):
    """Each frame's label by ROAD's rule, as a published loader derives it from the log and the
    metadata beside it."""
    metadata = json.loads((log.parent / "capture_metadata.json").read_text())[log.stem]
    interval = metadata.get("injection_interval")
    target = metadata.get("injection_id")
    pattern = metadata.get("injection_data_str")
    lines = log.read_text().splitlines()
    parsed = [LINE.match(line) for line in lines]
    assert all(parsed), [line for line, match in zip(lines, parsed) if not match][:3]
    first = float(parsed[0]["time"])
    labels = []
    for match in parsed:
        since = round(float(match["time"]) - first, 6)
        inside = interval is None or interval[0] <= since <= interval[1]
        if target is None or target == "XXX":
            same_id = True
        else:
            same_id = int(match["id"], 16) == int(target, 16)
            assert same_id == (match["id"] == target[2:].upper().rjust(3, "0"))
        payload = match["data"].zfill(16)
        same_data = pattern is None or all(p == "X" or p == c for p, c in zip(pattern, payload))
        labels.append(int(inside and same_id and same_data))
    return labels


def test_every_attack_that_roads_fields_can_express_is_labelled_exactly_by_roads_rule(built):
    ds, card, _ = built
    frames = pd.read_parquet(ds / "frames" / "train").sort_values(["run", "seq"])
    attacks = json.loads((ds / "road" / "train" / "attacks" / "capture_metadata.json").read_text())
    assert len(attacks) == 6
    inexact = {c["capture"]: c for c in card["road"]["not_exact"]}
    for name, capture in sorted(attacks.items()):
        run = frames[frames.run == int(name.rsplit("-", 1)[1])]
        kind = next(e["kind"] for e in capture["events"])
        labels = road_loader_labels(ds / "road" / "train" / "attacks" / f"{name}.log")
        assert len(labels) == len(run)
        assert sum(labels) == capture["road_rule_frames"] and run.label.sum() == capture["attack_frames"], name
        if kind == "replay":  # its frames are genuine payloads on the genuine id: no pattern tells them apart
            assert sum(labels) > run.label.sum() > 0
            assert capture["road_rule_exact"] is False
            assert "replay resends genuine payloads" in capture["road_rule_note"]
            assert inexact.pop(f"road/train/attacks/{name}.log")["attacks"] == ["replay"]
        else:
            assert labels == list(run.label), (kind, sum(labels), run.label.sum())
            assert capture["road_rule_exact"] is True
    assert not inexact  # the card names the replay alone
    assert card["road"]["captures"] == {"ambient": 1, "attacks": 6} and card["road"]["exact"] == 5
    readme = (ds / "README.md").read_text()
    assert "on 5 of the 6 attack captures" in readme and "(replay): ROAD's rule labels" in readme


def test_roads_conventions_fuzzing_any_id_suspension_no_frame_ambient_apart(built):
    ds, _, _ = built
    attacks = json.loads((ds / "road" / "train" / "attacks" / "capture_metadata.json").read_text())
    by_kind = {next(e["kind"] for e in c["events"]): c for c in attacks.values()}
    assert by_kind["fuzzing"]["injection_id"] == "XXX" and by_kind["fuzzing"]["injection_data_str"] == "F" * 16
    assert by_kind["babbling_node"]["injection_id"] == "0x0"
    assert by_kind["spoofing"]["injection_id"] == "0x101" and "X" in by_kind["spoofing"]["injection_data_str"]
    suspension = by_kind["suspension"]
    assert suspension["injection_id"] == "0x101" and suspension["road_rule_frames"] == 0
    assert 0.99 <= suspension["injection_interval"][0] < suspension["injection_interval"][1] <= 2.01
    for capture in attacks.values():
        assert all(capture[field] is not None for field in ("injection_id", "injection_interval", "injection_data_str"))
        assert len(capture["injection_data_str"]) == 16
    ambient = json.loads((ds / "road" / "train" / "ambient" / "capture_metadata.json").read_text())
    (name, capture), *others = ambient.items()
    assert not others and capture["description"] == "ambient: no fault, no attack" and capture["elapsed_sec"] == 3.0
    assert not {"injection_id", "injection_interval", "injection_data_str"} & set(capture)
    assert sorted(p.name for p in (ds / "road" / "train" / "ambient").iterdir()) == [
        "attacks-short-run-000000.log",
        "capture_metadata.json",
    ]


def test_roads_logs_are_candump_lines_without_a_flag_that_python_can_and_can_utils_read(built, tmp_path):
    ds, _, _ = built
    frames = pd.read_parquet(ds / "frames" / "train").sort_values(["run", "seq"])
    fuzzed = frames[frames.run == 3]
    log = ds / "road" / "train" / "attacks" / "attacks-short-run-000003.log"
    assert not any(line.endswith((" R", " T")) for line in log.read_text().splitlines())
    read = list(can.LogReader(log))
    assert [(m.arbitration_id, bytes(m.data)) for m in read] == list(zip(fuzzed.id, fuzzed.data))
    assert [m.timestamp for m in read] == pytest.approx(list(fuzzed.timestamp), abs=1e-6)
    log2asc = shutil.which("log2asc")
    if log2asc is None:
        pytest.skip("can-utils' log2asc is not installed (apt-get install can-utils)")
    asc = subprocess.run([log2asc, "-I", str(log), "can0"], capture_output=True, text=True, check=True).stdout
    rows = [line.split() for line in asc.splitlines() if " Rx " in line]  # time, channel, id, Rx, d, dlc, data
    assert [(int(r[2], 16), bytes.fromhex("".join(r[6:]))) for r in rows] == list(zip(fuzzed.id, fuzzed.data))


def test_an_attack_frame_on_the_bus_after_its_window_labels_its_tick_too(built):
    """A flood's last frames, queued before the window ends, win the wire in the next tick: that
    tick is the attack's as its frames are, in the labels and the events alike."""
    ds, _, _ = built
    frames = pd.read_parquet(ds / "frames" / "train")
    ticks = pd.read_parquet(ds / "labels" / "train").set_index(["run", "tick"])
    attacked = frames[frames.label == 1]
    assert (attacked.timestamp > 2.0).any()  # the flood's frames outlast its window
    for (run, tick), group in attacked.groupby(["run", "tick"]):
        row = ticks.loc[(run, tick)]
        assert row.label == 1 and set(group.fault) <= set(row.active), (run, tick)
    events = pd.read_parquet(ds / "events" / "train").set_index("run")
    flood = events[events.index == 1].iloc[0]
    assert flood.end_tick == attacked[attacked.run == 1].tick.max() + 1


def test_an_empty_split_is_said_when_the_campaign_is_read_and_kept_in_the_card(built):
    _, card, warnings = built
    assert warnings == card["warnings"] == []  # shares 1, 0, 0: nothing is missing
    from cosim.campaign.dataset import split_warning
    from cosim.campaign.spec import load_campaign

    one = load_campaign("dataset-attacks", seeds=1)
    assert split_warning(one, (0.6, 0.2, 0.2)) == (
        "dataset-attacks: validation and test will be empty: 1 replicate cut at the shares 0.6,0.2,0.2; "
        "--seeds 4 or more fills every split"
    )
    assert split_warning(load_campaign("dataset-attacks", seeds=4), (0.6, 0.2, 0.2)) is None
