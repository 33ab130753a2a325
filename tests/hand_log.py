"""A hand-made run log whose every metric is worked out by hand (tests/test_metrics.py), also cut
and damaged (tests/test_metrics_damaged_logs.py): two estimators and a diagnosis process over
100 ticks of 0.1 s, two faults, frames, deadline misses and the run's result."""

from __future__ import annotations

import json

from cosim.log.recorder import DEADLINE_MISSES, EVENTS, FAULTS, FRAMES, STATE
from cosim.log.writer import McapLog, object_schema

DT = 0.1
N = 100
SENSORS, ACTUATORS = ["y1", "y2"], ["T1x", "T1y", "T2x"]


def uniform_error(k):
    if k < 40:
        return 0.1
    if k < 70:
        return 3.0 if k == 45 else 1.0
    return 2.0


def good_error(k):
    if k < 20:
        return 0.1
    if k < 40:
        return 0.05
    if k < 50:
        return 0.5
    if k < 70:
        return 0.08
    return 0.09


def fdi_outputs(k):
    """alarm and isolation flags of the hand-made diagnosis process at tick k."""
    alarm = k in (10, 11, 12, 30, 67) or 43 <= k <= 65 or k >= 72
    flags = {"T1": k >= 80, "T2": k >= 75, "y1": 45 <= k <= 60}
    return alarm, flags


def active(k):
    return (["f1"] if 40 <= k < 60 else []) + (["f2"] if k >= 70 else [])


CLASSIC_ZERO = (53, 0)  # frame_bits(0x000, classic, no data)
FD_ZERO = (32, 109)  # frame_bits(0x100, FD + BRS, 8 zero bytes)


def write_hand_log(path, *, order_estimates_first: bool = True) -> None:
    estimators = {
        "uniform": {"kind": "pseudoinverse", "messages": ["EST_uniform"], "params": {"poles": [0.5, 0.6]}},
        "good": {"kind": "adaptive", "messages": ["EST_good"], "params": {}},
        "fdi": {
            "kind": "cofd",
            "messages": ["EST_fdi", "EST_fdi_1"],
            "params": {},
            "diagnostics": {
                "alarm": {"kind": "alarm"},
                **{f"isolated_{f}": {"kind": "isolation", "target": f} for f in ("T1", "T2", "y1")},
            },
            "isolates": {"isolated_T1": ["T1x", "T1y"], "isolated_T2": ["T2x"], "isolated_y1": ["y1"]},
        },
        "silent": {
            "kind": "uio",
            "messages": ["EST_silent"],
            "params": {},
            "diagnostics": {"alarm": {"kind": "alarm"}},
        },
    }
    with McapLog(path) as log:
        log.metadata(
            "cosim.run",
            {
                "scenario": "hand",
                "source": "test",
                "seed": "7",
                "sample_time": repr(DT),
                "ticks": str(N),
                "states": json.dumps(["x1", "x2"]),
                "sensors": json.dumps(SENSORS),
                "actuators": json.dumps(ACTUATORS),
                "estimators": json.dumps(estimators),
                "fault_onset": json.dumps(4.0),
                "fault_onset_tick": json.dumps(40),
                "faults": json.dumps(
                    [
                        {"label": "f1", "kind": "bias", "start": 4.0, "end": 6.0, "targets": ["y1"]},
                        {
                            "label": "f2",
                            "kind": "actuator_effectiveness",
                            "start": 7.0,
                            "end": None,
                            "targets": ["T1x"],
                        },
                    ]
                ),
                "bus": json.dumps({"interface": "virtual", "fd": True, "bitrate": 500000, "data_bitrate": 2000000}),
            },
        )
        log.metadata(
            "cosim.scenario",
            {
                "source": "test",
                "toml": "",
                "resolved": json.dumps(
                    {
                        "faults": [
                            {"name": "f1", "kind": "bias", "sensors": ["y1"]},
                            {"name": "f2", "kind": "actuator_effectiveness", "actuators": ["T1x"]},
                        ]
                    }
                ),
            },
        )
        any_schema = object_schema("any", {})
        ch = {
            topic: log.channel(topic, any_schema)
            for topic in (
                STATE,
                FAULTS,
                FRAMES,
                EVENTS,
                DEADLINE_MISSES,
                "/can/EST_uniform",
                "/can/EST_good",
                "/can/EST_fdi",
                "/can/EST_fdi_1",
                "/can/EST_silent",
            )
        }
        seq = 0
        for k in range(N):
            t_ns = round(k * DT * 1e9)
            estimates = [
                ("/can/EST_uniform", {"tick": k, "xhat_x1": 1.0 + uniform_error(k), "xhat_x2": -2.0}),
                ("/can/EST_fdi", {"tick": k, "xhat_x1": 1.0, "xhat_x2": -2.0}),
                ("/can/EST_silent", {"tick": k, "xhat_x1": 1.0, "xhat_x2": -2.0, "alarm": 0.0}),
            ]
            if k != 5:  # the good estimator's frame of tick 5 never came
                estimates.append(("/can/EST_good", {"tick": k, "xhat_x1": 1.0, "xhat_x2": -2.0 - good_error(k)}))
            alarm, flags = fdi_outputs(k)
            estimates.append(
                (
                    "/can/EST_fdi_1",
                    {"tick": k, "alarm": float(alarm), **{f"isolated_{f}": float(v) for f, v in flags.items()}},
                )
            )
            truth = [
                (STATE, {"tick": k, "t": k * DT, "x1": 1.0, "x2": -2.0}),
                (FAULTS, {"tick": k, "t": k * DT, "active": active(k), "dropped": []}),
            ]
            frames = [
                (
                    FRAMES,
                    {
                        "tick": k,
                        "t": k * DT,
                        "seq": seq,
                        "id": 0x000,
                        "extended": False,
                        "fd": False,
                        "brs": False,
                        "dlc": 0,
                        "length": 0,
                        "data": "",
                        "sender": "runner",
                        "message": "NMT",
                    },
                ),
                (
                    FRAMES,
                    {
                        "tick": k,
                        "t": k * DT,
                        "seq": seq + 1,
                        "id": 0x100,
                        "extended": False,
                        "fd": True,
                        "brs": True,
                        "dlc": 8,
                        "length": 8,
                        "data": "00" * 8,
                        "sender": "plant",
                        "message": "SENSOR_y1",
                    },
                ),
            ]
            if k == 50:
                frames.append((FRAMES, {**frames[0][1], "seq": seq + 2}))
            seq += len(frames)
            for topic, msg in frames + (estimates + truth if order_estimates_first or k % 2 else truth + estimates):
                log.write(ch[topic], t_ns, msg)
            if k in (3, 4):
                log.write(ch[DEADLINE_MISSES], t_ns, {"tick": k, "t": k * DT, "node": "fdi", "count": k - 2})
        log.metadata(
            "cosim.result",
            {
                "status": "completed",
                "ticks": str(N),
                "frames_total": str(seq),
                "frames_lost": "5",
                "deadline_misses": "2",
                "error": "",
                "senders": json.dumps({"fdi": {"frames": 1, "lost": 3, "runner_frames_missed": 2}}),
            },
        )
