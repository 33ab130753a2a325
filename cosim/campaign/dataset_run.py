"""One run of a data set, read from its log: its frames, its signals as the receivers took them, its
truth, and its labels per frame, per tick and per fault, as columns.

Every label comes from the records the metrics score (``cosim.analysis.metrics``): a tick's faults
and attacks are the labels ``/truth/faults`` lists as ``active`` in it (the bus faults' too), and
the attacks whose frames are on the bus in it (a flood's last frame, queued in its window, may win
the wire in the tick after: its tick is the attack's as the frame is); what a bus fault did to
frames is ``/truth/bus_faults``, and a frame is an attack's when ``/cosim/foreign`` holds a record
naming its ``seq`` (every frame a simulated intruder sends has one, with its fault's label as
``source``). What a fault or attack is (its kind, targets, window) is the
log's ``cosim.run`` record; its class in the taxonomy of attacks, its kind's (``BusFault.attack``).

A frame's bytes are as on the bus but for the MACs a run draws anew (its key is random): the
control frames' (NMT, SYNC, heartbeats) and SecOC's are zeroed, so that a campaign gives the same
bytes every time it is run; in a genuine frame, or one a replay copied from one. An intruder's own
bytes are drawn from the run's seed and stay as sent (a fuzzing frame of 0xFF on a heartbeat's id).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.bus.codec import Codec, estimate_signal
from cosim.bus.dbc import control_mac_start
from cosim.bus.secoc import FV_BYTES, MAC_BYTES
from cosim.campaign.spec import RunSpec
from cosim.errors import LogError
from cosim.log.metadata import LogMetadata, RunRecord, logged_dbc
from cosim.log.reader import LogReader
from cosim.log.topics import BUS_FAULTS, FAULTS, FOREIGN, FRAMES, INPUTS, SENSORS, STATE, carried_tick

#: The splits of a data set, in order.
SPLITS = ("train", "validation", "test")


@dataclass(frozen=True)
class DatasetRun:
    """A run of a data set: its campaign, index, replicate, seed, settings columns, split and log."""

    campaign: str
    spec: RunSpec
    split: str
    log: Path

    @property
    def stem(self) -> str:
        return f"{self.campaign}-run-{self.spec.index:06d}"


NORMAL = "normal"
#: The events table's columns: every run's file has all of them, a run without a fault too (a
#: folder of files is one table only when their columns agree).
EVENT_COLUMNS = (
    "fault", "kind", "category", "attack_class", "targets", "start", "end",
    "onset_tick", "end_tick", "ticks_active", "frames_injected", "frames_lost",
)  # fmt: skip


@dataclass
class RunTables:
    """A run's columns, table by table (name → values, in row order)."""

    frames: dict[str, list[Any]]
    signals: dict[str, list[Any]]
    truth: dict[str, list[Any]]
    ticks: dict[str, list[Any]]
    events: dict[str, list[Any]]
    record: RunRecord
    duration: float


@dataclass
class _Reading:
    """What the log holds of one run, gathered in one pass."""

    frames: list[tuple[int, dict[str, Any]]] = field(default_factory=list)  # (log time ns, CanFrame message)
    intruders: dict[int, str] = field(default_factory=dict)  # seq -> fault label
    copies: Counter[tuple[str, int]] = field(default_factory=Counter)  # (column, tick) -> on-time frames
    values: dict[tuple[str, int], float] = field(default_factory=dict)
    truth: dict[int, dict[str, Any]] = field(default_factory=lambda: defaultdict(dict))
    active: dict[int, list[str]] = field(default_factory=dict)
    lost: Counter[tuple[int, str]] = field(default_factory=Counter)  # (tick, label) -> frames lost to it


def fault_classes(record: RunRecord) -> dict[str, tuple[str, str]]:
    """Each fault's label → (kind, attack class or "" for a fault no one causes on purpose)."""
    import faults as fm
    from cosim.kinds import KindError

    out = {}
    for fault in record.faults:
        kind = fault.kind or ""
        try:
            model = fm.FAULT_MODELS[kind]
            attack = getattr(model, "attack", "") if issubclass(model, fm.BusFault) else ""
        except KindError:  # a plugin's kind not installed here: a fault, as far as one can tell
            attack = ""
        out[fault.label] = (kind, attack)
    return out


def read_run(log: Path, estimates: bool = False) -> RunTables:
    """The tables of the run logged at ``log`` (a LogError if it is no cosim run log or lacks ticks)."""
    with LogReader(log) as reader:
        record = LogMetadata.read(reader.metadata()).run
        if record is None or not record.dt_ns:
            raise LogError(f"{log}: not the log of a cosim run (no cosim.run record with a sample time)")
        codec = Codec.from_dbc(logged_dbc(reader))
        columns = _decoded_columns(codec, record, estimates)
        reading = _read(reader, record.dt_ns, columns)
        if reader.warnings:  # a damaged log: what it lacks would be labelled as what did not happen
            raise LogError(f"{log}: {reader.warnings[0]}")
    ticks = sorted(reading.truth)
    if not ticks:
        raise LogError(f"{log}: the log holds no tick of truth (did the run start?)")
    classes = fault_classes(record)
    reading.active = _with_frames_on_the_bus(reading)
    return RunTables(
        frames=_frames(reading, codec, classes),
        signals=_signals(reading, ticks, record, columns),
        truth=_truth(reading, ticks),
        ticks=_tick_labels(reading, ticks, record, classes),
        events=_events(reading, ticks, record, classes),
        record=record,
        duration=len(ticks) * record.dt_ns / 1e9,
    )


def _with_frames_on_the_bus(reading: _Reading) -> dict[int, list[str]]:
    """Each tick's active labels: those ``/truth/faults`` lists, and the attacks with a frame in it."""
    active = {k: list(labels) for k, labels in reading.active.items()}
    for _, m in reading.frames:
        source = reading.intruders.get(int(m["seq"]))
        labels = active.setdefault(int(m["tick"]), [])
        if source and source not in labels:
            labels.append(source)
    return active


def _decoded_columns(codec: Codec, record: RunRecord, estimates: bool) -> dict[str, dict[str, str]]:
    """Topic → (signal → the signals table's column) of the decoded messages it keeps."""
    topics: dict[str, dict[str, str]] = defaultdict(dict)
    for sensor in record.sensors:
        spec = codec.sensor(sensor)
        topics[f"/can/{spec.name}"][spec.signals[0]] = f"reading.{sensor}"
    for actuator in record.actuators:
        spec = codec.command(actuator)
        topics[f"/can/{spec.name}"][spec.signals[0]] = f"command.{actuator}"
    if estimates:
        for name, estimator in record.estimators.items():
            signals = {estimate_signal(state): state for state in estimator.states}
            for message in estimator.messages:
                for signal in codec.specs[message].signals:
                    if signal in signals:
                        topics[f"/can/{message}"][signal] = f"estimate.{name}.{signals[signal]}"
    return dict(topics)


def _read(reader: LogReader, dt_ns: int, columns: dict[str, dict[str, str]]) -> _Reading:
    reading = _Reading()
    truth_prefix = {STATE: "state", SENSORS: "sensor"}
    for topic, log_time, msg in reader.messages(
        [FRAMES, FOREIGN, STATE, SENSORS, INPUTS, FAULTS, BUS_FAULTS, *columns]
    ):
        if topic == FRAMES:
            reading.frames.append((log_time, msg))
        elif topic == FOREIGN:
            if msg.get("seq") is not None:
                reading.intruders[int(msg["seq"])] = str(msg.get("source") or "")
        elif topic in truth_prefix:
            row = reading.truth[int(msg["tick"])]
            row.update({f"{truth_prefix[topic]}.{k}": v for k, v in msg.items() if k not in ("tick", "t")})
        elif topic == INPUTS:
            row = reading.truth[int(msg["tick"])]
            for group in ("commanded", "effective", "disturbance"):
                row.update({f"input.{group}.{k}": v for k, v in (msg.get(group) or {}).items()})
        elif topic == FAULTS:
            k = int(msg["tick"])
            row = reading.truth[k]
            for group in ("noise", "fault", "measured", "effectiveness"):
                row.update({f"{group}.{k_}": v for k_, v in (msg.get(group) or {}).items()})
            reading.active[k] = list(msg.get("active") or [])
        elif topic == BUS_FAULTS:
            if msg.get("event") == "lost":
                reading.lost[(int(msg["tick"]), str(msg.get("label") or ""))] += 1
        else:
            logged = log_time // dt_ns
            k = carried_tick(logged, int(msg["tick"]))
            if k != logged:
                continue  # after its tick: its receivers had no use for it
            for signal, column in columns[topic].items():
                reading.copies[(column, k)] += 1
                reading.values[(column, k)] = float(msg[signal])
    return reading


def unsigned_data(codec: Codec, frame_id: int, data: bytes) -> bytes:
    """A frame's payload with the MACs a run keys anew zeroed (control frames, SecOC trailers)."""
    start = control_mac_start(frame_id)
    if start is not None:
        return data[:start] + bytes(len(data) - start)
    at = codec.secoc_trailers.get(frame_id)
    if at is not None and len(data) >= at + FV_BYTES + MAC_BYTES:
        end = at + FV_BYTES + MAC_BYTES
        return data[: at + FV_BYTES] + bytes(MAC_BYTES) + data[end:]
    return data


def _frames(reading: _Reading, codec: Codec, classes: dict[str, tuple[str, str]]) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = defaultdict(list)
    for log_time, m in reading.frames:
        seq = int(m["seq"])
        fault = reading.intruders.get(seq, "")
        data = bytes.fromhex(m["data"])
        copied = not fault or classes.get(fault, ("", ""))[1] == "replay"  # bytes a genuine sender signed
        if copied and not m.get("extended"):
            data = unsigned_data(codec, int(m["id"]), data)
        out["timestamp"].append(log_time / 1e9)
        out["tick"].append(int(m["tick"]))
        out["seq"].append(seq)
        out["id"].append(int(m["id"]))
        out["extended"].append(bool(m["extended"]))
        out["fd"].append(bool(m["fd"]))
        out["brs"].append(bool(m.get("brs")))
        out["dlc"].append(int(m["dlc"]))
        out["data"].append(data)
        out["message"].append(m.get("message"))
        out["sender"].append(str(m["sender"]))
        out["label"].append(1 if fault else 0)
        out["attack"].append(classes.get(fault, ("unknown", ""))[0] if fault else NORMAL)
        out["fault"].append(fault)
    return dict(out)


def _signals(
    reading: _Reading, ticks: list[int], record: RunRecord, columns: dict[str, dict[str, str]]
) -> dict[str, list[Any]]:
    """Per tick, each reading, command (and estimate) as its receivers took it: the value of its one
    frame of the tick that came in time; NaN when none came, or two (receivers trust neither)."""
    dt = record.dt_ns / 1e9 if record.dt_ns else 0.0
    names = [column for signals in columns.values() for column in signals.values()]
    out: dict[str, list[Any]] = {"tick": list(ticks), "t": [k * dt for k in ticks]}
    for name in names:
        out[name] = [reading.values[(name, k)] if reading.copies[(name, k)] == 1 else float("nan") for k in ticks]
    return out


def _truth(reading: _Reading, ticks: list[int]) -> dict[str, list[Any]]:
    seen = dict.fromkeys(name for row in reading.truth.values() for name in row)  # the log's order
    names = sorted(seen, key=lambda name: _truth_order(name, list(seen)))
    out: dict[str, list[Any]] = {"tick": list(ticks)}
    for name in names:
        out[name] = [_number(reading.truth[k].get(name)) for k in ticks]
    return out


_TRUTH_GROUPS = ("state", "sensor", "input", "noise", "fault", "measured", "effectiveness")


def _truth_order(name: str, seen: list[str]) -> tuple[int, int]:
    """By group (``_TRUTH_GROUPS``), then as the log lists them (a plant's states in its order)."""
    group = name.split(".", 1)[0]
    return (_TRUTH_GROUPS.index(group) if group in _TRUTH_GROUPS else len(_TRUTH_GROUPS), seen.index(name))


def _number(value: Any) -> float:
    return float("nan") if value is None else float(value)


def _tick_labels(
    reading: _Reading, ticks: list[int], record: RunRecord, classes: dict[str, tuple[str, str]]
) -> dict[str, list[Any]]:
    """Per tick: what is active (labels, kinds, targets), its class, and what the bus faults did."""
    targets = {fault.label: fault.targets or [] for fault in record.faults}
    injected = Counter(int(m["tick"]) for _, m in reading.frames if int(m["seq"]) in reading.intruders)
    lost: Counter[int] = Counter()
    for (tick, _), n in reading.lost.items():
        lost[tick] += n
    dt = record.dt_ns / 1e9 if record.dt_ns else 0.0
    out: dict[str, list[Any]] = defaultdict(list)
    for k in ticks:
        active = sorted(reading.active.get(k, []))
        kinds = sorted({classes.get(label, ("unknown", ""))[0] for label in active})
        attacks = sorted({classes[label][1] for label in active if label in classes and classes[label][1]})
        faulty = [label for label in active if not classes.get(label, ("", ""))[1]]
        out["tick"].append(k)
        out["t"].append(k * dt)
        out["label"].append(int(bool(active)))
        out["class"].append("+".join(kinds) or NORMAL)
        out["category"].append("+".join(c for c, on in (("fault", faulty), ("attack", attacks)) if on) or NORMAL)
        out["attack_class"].append("+".join(attacks))
        out["active"].append(active)
        out["kinds"].append(kinds)
        out["targets"].append(sorted({t for label in active for t in targets.get(label, [])}))
        out["frames_injected"].append(injected[k])
        out["frames_lost"].append(lost[k])
    return dict(out)


def _events(
    reading: _Reading, ticks: list[int], record: RunRecord, classes: dict[str, tuple[str, str]]
) -> dict[str, list[Any]]:
    """One row per fault or attack of the run: what, where, its window as set and the ticks it was
    active (the first, and one past the last), the frames it added and took away."""
    dt = record.dt_ns / 1e9 if record.dt_ns else 0.0
    injected = Counter(reading.intruders.values())
    lost: Counter[str] = Counter()
    for (_, label), n in reading.lost.items():
        lost[label] += n
    out: dict[str, list[Any]] = {column: [] for column in EVENT_COLUMNS}
    for fault in record.faults:
        on = [k for k in ticks if fault.label in reading.active.get(k, ())]
        kind, attack = classes.get(fault.label, (fault.kind or "", ""))
        out["fault"].append(fault.label)
        out["kind"].append(kind)
        out["category"].append("attack" if attack else "fault")
        out["attack_class"].append(attack)
        out["targets"].append(list(fault.targets or []))
        out["start"].append(fault.start)
        out["end"].append(fault.end if fault.end is not None else len(ticks) * dt)
        out["onset_tick"].append(on[0] if on else None)
        out["end_tick"].append(on[-1] + 1 if on else None)
        out["ticks_active"].append(len(on))
        out["frames_injected"].append(injected.get(fault.label, 0))
        out["frames_lost"].append(lost.get(fault.label, 0))
    return out
