"""A run's capture in ROAD's form: its folder and its capture metadata, made so that ROAD's labelling
rule gives exactly the data set's label of every frame, and checked that it does.

ROAD (Verma et al., PLOS ONE 2024; the Real ORNL Automotive Dynamometer CAN data set) keeps the
captures without an attack in ``ambient/`` and those with one in ``attacks/``, each folder with a
``capture_metadata.json`` that names each capture (its log's file name without ``.log``) and, for an
attack, the injection: ``injection_interval`` (s, from the capture's first frame), ``injection_id``
(``"0xd0"``; ``"XXX"``: any id, as its fuzzing) and ``injection_data_str`` (16 hex digits, ``X`` for
any). The rule every published loader of ROAD applies: a frame is an attack's when its time from the
first frame lies in the interval (ends included), its id is the injection's and its payload, as 16
hex digits (a shorter one left-padded with zeros, as ROAD's own code pads it), matches the pattern.

A capture's injection is read off its attack's own frames: the interval from its first to its last
frame (each end half a microsecond further out, so that it holds them whatever rounding a loader's
arithmetic makes of the log's microseconds), its one id or ``"XXX"``, and the bytes that all of its
frames share (``XX`` for the others). An attack that sends nothing (a suspension) takes its target's
id and the ticks it was active, where no frame of that id is: the rule labels no frame, as the data
set. Then the rule is applied to the frames as the log holds them; where it does not give the data
set's labels (a replay: its frames are the genuine ones again), the metadata and the card say so.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from cosim.campaign.dataset_run import RunTables

AMBIENT, ATTACKS = "ambient", "attacks"
#: ROAD's metadata file, one per folder, keyed by capture.
METADATA = "capture_metadata.json"
#: A payload as the rule reads it: 8 bytes, 16 hex digits.
DIGITS = 16
ANY_ID = "XXX"
#: Beyond each end of an injection's interval: under the log's resolution (1 µs), over any float error.
MARGIN = 5e-7


def written_time(timestamp: float) -> float:
    """A frame's time as the log writes it (microseconds) and a loader reads it back."""
    return float(f"{timestamp:.6f}")


def payload_hex(data: bytes) -> str:
    """A payload as ROAD's rule reads it: upper-case hex, left-padded with zeros to 16 digits."""
    return data.hex().upper().zfill(DIGITS)


def road_rule(
    times: Sequence[float], ids: Sequence[int], payloads: Sequence[str], injection: dict[str, Any]
) -> list[bool]:
    """ROAD's label of each frame (times as the log holds them, payloads as ``payload_hex``) under a
    capture's ``injection`` fields; a field that is null matches anything."""
    if not times:
        return []
    interval = injection.get("injection_interval")
    target = injection.get("injection_id")
    pattern = injection.get("injection_data_str")
    wanted = None if target in (None, ANY_ID) else int(str(target), 16)
    first = times[0]
    out = []
    for t, frame_id, payload in zip(times, ids, payloads):
        since = round(t - first, 6)
        inside = interval is None or interval[0] <= since <= interval[1]
        matches = pattern is None or all(p in ("X", c) for p, c in zip(str(pattern).upper(), payload))
        out.append(inside and (wanted is None or frame_id == wanted) and matches)
    return out


def capture(tables: RunTables) -> tuple[str, dict[str, Any]]:
    """A run's ROAD folder (ambient or attacks) and its capture metadata."""
    events = [dict(zip(tables.events, row)) for row in zip(*tables.events.values())] if tables.events else []
    attacks = [e for e in events if e["category"] == "attack" and (e["frames_injected"] or e["onset_tick"] is not None)]
    described = "; ".join(f"{e['kind']} ({e['fault']}) on {', '.join(e['targets']) or 'the bus'}" for e in events)
    metadata: dict[str, Any] = {"description": described or "ambient: no fault, no attack"}
    metadata["elapsed_sec"] = tables.duration
    if not attacks:
        return AMBIENT, {**metadata, "events": events}
    frames = tables.frames
    times = [written_time(t) for t in frames["timestamp"]]
    payloads = [payload_hex(d) for d in frames["data"]]
    injection = _injection(tables, attacks[0], times, payloads)
    labelled = road_rule(times, frames["id"], payloads, injection)
    expected = [bool(label) for label in frames["label"]]
    check: dict[str, Any] = {
        "attack_frames": sum(expected),
        "road_rule_frames": sum(labelled),
        "road_rule_exact": labelled == expected,
    }
    if labelled != expected:
        check["road_rule_note"] = _why_not(attacks, check["attack_frames"], check["road_rule_frames"])
    return ATTACKS, {**metadata, **injection, "events": events, **check}


def _injection(tables: RunTables, attack: dict[str, Any], times: list[float], payloads: list[str]) -> dict[str, Any]:
    """ROAD's injection fields of one attack, from its frames (or, sending none, from its target's)."""
    frames = tables.frames
    first = times[0] if times else 0.0
    own = [i for i, fault in enumerate(frames["fault"]) if fault == attack["fault"]]
    if own:
        ids = sorted({frames["id"][i] for i in own})
        start, end = min(times[i] for i in own) - first, max(times[i] for i in own) - first
        return {
            "injection_id": f"0x{ids[0]:x}" if len(ids) == 1 else ANY_ID,
            "injection_interval": [round(start - MARGIN, 7), round(end + MARGIN, 7)],
            "injection_data_str": shared_bytes([payloads[i] for i in own]),
        }
    return _silence(tables, attack, times)


def _silence(tables: RunTables, attack: dict[str, Any], times: list[float]) -> dict[str, Any]:
    """An attack that sends nothing: its target's id over the ticks it was active, narrowed past any
    frame of that id there (one queued before it began, delivered after): the rule labels none."""
    frames = tables.frames
    targets = set(attack["targets"])
    ids = sorted({i for i, m, s in zip(frames["id"], frames["message"], frames["sender"]) if {m, s} & targets})
    dt = tables.record.dt_ns / 1e9 if tables.record.dt_ns else 0.0
    first = times[0] if times else 0.0
    start, end = attack["onset_tick"] * dt - first, attack["end_tick"] * dt - first
    if not ids:
        return {"injection_id": ANY_ID, "injection_interval": [start, end], "injection_data_str": "X" * DIGITS}
    middle = (start + end) / 2
    for t, frame_id in zip(times, frames["id"]):
        since = t - first
        if frame_id == ids[0] and start <= since <= end:
            start, end = (
                (max(start, since + 2 * MARGIN), end) if since < middle else (start, min(end, since - 2 * MARGIN))
            )
    return {
        "injection_id": f"0x{ids[0]:x}",
        "injection_interval": [round(start, 7), round(end, 7)],
        "injection_data_str": "X" * DIGITS,
    }


def shared_bytes(payloads: Sequence[str]) -> str:
    """The pattern of payloads (16 hex digits each): each byte they all share, ``XX`` for the others."""
    out = []
    for j in range(0, DIGITS, 2):
        values = {p[j : j + 2] for p in payloads}
        out.append(values.pop() if len(values) == 1 else "XX")
    return "".join(out)


def _why_not(attacks: list[dict[str, Any]], expected: int, labelled: int) -> str:
    """Why ROAD's rule does not give the data set's labels of a capture, in one sentence."""
    counts = f"ROAD's rule labels {labelled} frames, the data set {expected}"
    if len(attacks) > 1:
        names = ", ".join(f"{a['kind']} ({a['fault']})" for a in attacks)
        return (
            f"{counts}: the run has {len(attacks)} attacks ({names}) and ROAD's fields hold one; "
            "use the Parquet or HCRL labels"
        )
    if attacks[0]["attack_class"] == "replay":
        return (
            f"{counts}: a replay resends genuine payloads on the genuine id, so no interval, id and payload "
            "pattern tells its frames from the genuine ones; use the Parquet or HCRL labels"
        )
    return (
        f"{counts}: genuine frames share the attack's id and payload bytes in its interval; "
        "use the Parquet or HCRL labels"
    )
