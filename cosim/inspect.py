"""Summaries of run logs: channels, counts, duration, scenario and estimation errors.

The estimation error of an estimator at tick k is e_k = |x_k − x̂_k| (Euclidean norm over all
state components), x_k from ``/truth/state`` and x̂_k from its decoded estimate messages of tick k.
``rms_pre_fault`` and ``rms_post_fault`` are sqrt(mean e_k²) over the ticks before and from the
first fault onset; ``final_error`` is e_k at the last tick. The log is streamed: memory stays
bounded whatever its length.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from cosim.log import LogReader
from cosim.recorder import EVENTS, FRAMES, STATE, message_topic


#: Ticks kept while waiting for the other half (truth or estimate) of a tick.
_WINDOW = 1000


def summarize(path: str | Path) -> dict[str, Any]:
    """The summary of a log as a JSON-ready dict (keys documented in the README)."""
    warnings: list[str] = []
    with LogReader(path) as reader:
        meta = reader.metadata()
        run = meta.get("cosim.run")
        result = meta.get("cosim.result", {})
        summary = reader.summary()
        if run is None:
            warnings.append("no cosim.run metadata: not a cosim log, or written by another program; estimator errors are unavailable")
        channels: dict[str, int] = {}
        if summary is not None and summary.statistics is not None:
            by_id = summary.channels
            channels = {by_id[cid].topic: count for cid, count in summary.statistics.channel_message_counts.items()}
            for channel in by_id.values():
                channels.setdefault(channel.topic, 0)
        report: dict[str, Any] = {
            "file": str(path),
            "scenario": run.get("scenario") if run else None,
            "source": run.get("source") if run else None,
            "seed": int(run["seed"]) if run else None,
            "status": result.get("status", "incomplete"),
            "sample_time": float(run["sample_time"]) if run else None,
        }
        estimation: dict[str, Any] = {}
        scanned: dict[str, int] = defaultdict(int)
        ticks = 0
        lost_events = 0
        if run is not None:
            estimation, ticks, lost_events = _estimation(reader, run, scanned, need_counts=not channels)
        elif not channels:
            for topic, _, _ in reader.messages():
                scanned[topic] += 1
        if not channels:
            channels = dict(scanned)
        if run is None:
            ticks = channels.get(STATE, 0)
    dt = report["sample_time"]
    report.update({
        "ticks": ticks,
        "duration_s": round(ticks * dt, 9) if dt else None,
        "channels": dict(sorted(channels.items())),
        "frames": {
            "total": int(result["frames_total"]) if "frames_total" in result else channels.get(FRAMES, 0),
            "lost": int(result["frames_lost"]) if "frames_lost" in result else lost_events,
        },
        "fault_onset": json.loads(run["fault_onset"]) if run else None,
        "estimators": estimation,
        "warnings": reader.warnings + warnings,
    })
    return report


def _estimation(reader: LogReader, run: dict[str, str], scanned: dict[str, int], need_counts: bool):
    states = json.loads(run["states"])
    ests = json.loads(run["estimators"])
    onset_tick = json.loads(run.get("fault_onset_tick", "null"))
    dt_ns = round(float(run["sample_time"]) * 1e9)
    topic_owner = {message_topic(m): name for name, e in ests.items() for m in e["messages"]}
    wanted = None if need_counts else [STATE, EVENTS, *topic_owner]
    # Truth and estimates of a tick may come in either order; a tick is scored once both are in.
    truth: dict[int, dict[str, float]] = {}
    partial: dict[int, dict[str, dict[str, float]]] = defaultdict(lambda: defaultdict(dict))
    sums = {name: {"pre": [0.0, 0], "post": [0.0, 0], "final": (-1, None)} for name in ests}
    ticks = lost = 0

    def score(k: int, name: str) -> None:
        x, x_hat = truth.get(k), partial[k].get(name, {})
        if x is None or any(x_hat.get(s) is None for s in states):
            return
        error = math.sqrt(math.fsum((x[s] - x_hat[s]) ** 2 for s in states))
        window = "post" if onset_tick is not None and k >= onset_tick else "pre"
        sums[name][window][0] += error * error
        sums[name][window][1] += 1
        if k > sums[name]["final"][0]:
            sums[name]["final"] = (k, error)
        del partial[k][name]

    for topic, log_time, msg in reader.messages(wanted):
        scanned[topic] += 1
        if topic in topic_owner:
            k, name = log_time // dt_ns, topic_owner[topic]
            partial[k][name].update({key.removeprefix("xhat_"): value for key, value in msg.items() if key.startswith("xhat_")})
            score(k, name)
        elif topic == STATE:
            k = msg["tick"]
            ticks = max(ticks, k + 1)
            truth[k] = msg
            for name in ests:
                score(k, name)
            for old in [t for t in truth if t < k - _WINDOW]:  # bounded memory
                del truth[old]
                partial.pop(old, None)
        elif topic == EVENTS and msg.get("event") == "frames_lost":
            lost += msg.get("count", 1)

    def rms(acc: list) -> float | None:
        return math.sqrt(acc[0] / acc[1]) if acc[1] else None

    estimation = {
        name: {
            "kind": ests[name]["kind"],
            "rms_pre_fault": rms(sums[name]["pre"]),
            "rms_post_fault": rms(sums[name]["post"]),
            "final_error": sums[name]["final"][1],
        }
        for name in ests
    }
    return estimation, ticks, lost
