"""Foxglove: a run served live over the Foxglove WebSocket protocol, a log played the same way, and
the layouts of ``cosim layout``, whose every message path is resolved against real logs.

The live tests are a WebSocket client of the protocol (the ``websockets`` package, in the test
extra): they connect, subscribe to every channel the server advertises, and compare what arrives
with the log the run wrote: the same topics, schemas, messages and payloads.
"""

from __future__ import annotations

import json
import re
import socket
import struct
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest

from cosim.analysis import layout as layouts
from cosim.cli import main
from cosim.log.reader import LogReader
from cosim.run import Run
from cosim.scenario import LoadedScenario, builtin_names, load

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")  # today's Foxglove app; Lichtblick and older apps


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Viewer(threading.Thread):
    """A Foxglove WebSocket client: subscribes to every advertised channel, collects the messages."""

    def __init__(self, port: int, timeout: float = 120.0, subprotocol: str = SUBPROTOCOLS[0]) -> None:
        super().__init__(daemon=True)
        self.port, self.timeout, self.subprotocol = port, timeout, subprotocol
        self.channels: dict[int, dict] = {}  # channel id -> its advertisement
        self.messages: dict[str, list[tuple[int, dict]]] = defaultdict(list)  # topic -> (log time, payload)
        self.error: BaseException | None = None
        self.closed = threading.Event()

    def run(self) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect

        deadline = time.monotonic() + self.timeout
        try:
            while True:  # the server starts when the command has loaded its scenario
                try:
                    ws = connect(f"ws://127.0.0.1:{self.port}", subprotocols=[self.subprotocol], open_timeout=2)
                    assert ws.subprotocol == self.subprotocol
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.1)
            subscriptions: dict[int, int] = {}  # subscription id -> channel id
            gone: set[int] = set()
            with ws:
                while time.monotonic() < deadline:
                    try:
                        data = ws.recv(timeout=1)
                    except TimeoutError:
                        continue
                    except ConnectionClosed:
                        break
                    if isinstance(data, str):
                        op = json.loads(data)
                        if op["op"] == "advertise":
                            new = []
                            for channel in op["channels"]:
                                self.channels[channel["id"]] = channel
                                subscriptions[len(subscriptions)] = channel["id"]
                                new.append({"id": len(subscriptions) - 1, "channelId": channel["id"]})
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                        elif op["op"] == "unadvertise":
                            gone.update(op["channelIds"])
                            if gone >= set(self.channels):
                                break  # the server closed every channel: the run is over
                    elif data[0] == 1:  # message data: opcode, subscription id, log time, payload
                        _, subscription, log_time = struct.unpack_from("<BIQ", data)
                        topic = self.channels[subscriptions[subscription]]["topic"]
                        self.messages[topic].append((log_time, json.loads(data[13:])))
        except BaseException as error:  # reported by the test
            self.error = error
        finally:
            self.closed.set()


def logged(path: Path) -> tuple[dict[str, list[tuple[int, dict]]], dict[str, dict]]:
    messages: dict[str, list[tuple[int, dict]]] = defaultdict(list)
    with LogReader(path) as reader:
        for topic, log_time, message in reader.messages():
            messages[topic].append((log_time, message))
        return messages, reader.schemas()


def check_served(viewer: Viewer, log: Path, start_ns: int) -> None:
    """The viewer got every topic of the log with its schema, every message, in order, at the
    run's start plus its simulated time."""
    assert viewer.closed.wait(30) and viewer.error is None, viewer.error
    messages, schemas = logged(log)
    advertised = {c["topic"]: c for c in viewer.channels.values()}
    assert set(advertised) == set(schemas)  # every topic of the log, the empty ones too
    for topic, channel in advertised.items():
        assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
        assert json.loads(channel["schema"]) == schemas[topic] and channel["schemaName"] == schemas[topic]["title"]
    assert {t for t, m in viewer.messages.items() if m} == {t for t, m in messages.items() if m}
    for topic, entries in messages.items():
        got = viewer.messages[topic]
        assert len(got) == len(entries), topic
        assert [payload for _, payload in got] == [message for _, message in entries], topic
        assert [t - start_ns for t, _ in got] == [t for t, _ in entries], topic


@pytest.mark.slow
def test_a_live_run_serves_every_topic_to_a_foxglove_client(tmp_path, capsys):
    port, log = free_port(), tmp_path / "live.mcap"
    viewer = Viewer(port)
    viewer.start()
    before = time.time_ns()
    args = ["run", "--interface", "virtual", "--set", "duration=2", "-q", "--json", "--out", str(log)]
    assert main([*args, "--foxglove", str(port)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "completed" and summary["path"] == str(log)
    first = min(t for entries in viewer.messages.values() for t, _ in entries)
    assert before <= first <= time.time_ns()  # stamped with the wall clock of the run's start
    check_served(viewer, log, first)


@pytest.mark.slow
@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
def test_replay_plays_a_log_into_foxglove(subprotocol, tmp_path, capsys):
    log = tmp_path / "run.mcap"
    scenario = load("masses-faults-fd").scenario.model_copy(update={"duration": 1.0})
    Run(LoadedScenario(scenario, "masses-faults-fd (1 s)", ""), log, interface="virtual").execute()
    with LogReader(log) as reader:
        start = json.loads(reader.metadata()["cosim.run"]["start_time_ns"])
    port = free_port()
    viewer = Viewer(port, subprotocol=subprotocol)
    viewer.start()
    assert main(["replay", str(log), "--foxglove", str(port), "--speed", "0", "--wait", "60"]) == 0
    check_served(viewer, log, start)
    assert "served" in capsys.readouterr().err


def test_a_viewer_asking_for_neither_name_of_the_protocol_is_refused():
    from websockets.exceptions import InvalidHandshake
    from websockets.sync.client import connect

    from cosim.log.live import FoxgloveSink

    with FoxgloveSink(port=0) as sink:
        with pytest.raises(InvalidHandshake):
            connect(sink.url, subprotocols=["foxglove.websocket.v2"], open_timeout=5)
        with connect(sink.url, subprotocols=["foxglove.websocket.v1"], open_timeout=5) as ws:
            hello = json.loads(ws.recv(timeout=5))
        assert hello["op"] == "serverInfo" and sink.app_url().endswith(f"%3A{sink.port}")


def test_foxglove_options_that_do_nothing_are_errors(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "x.mcap"), "--foxglove", "0", "--estimator", "kalman"]) == 1
    assert "--estimator: not with --foxglove" in capsys.readouterr().err


# -- layouts ----------------------------------------------------------------------------------------


def run_short(name: str, duration: float, out: Path) -> Path:
    scenario = load(name).scenario.model_copy(update={"duration": duration})
    Run(LoadedScenario(scenario, f"{name} ({duration:g} s)", ""), out, interface="virtual").execute()
    return out


def resolve(layout: dict, log: Path) -> list[str]:
    """What does not resolve: each message path of the layout against the log's schemas and its
    first message on that topic; the errors' paths against the user script that writes them."""
    messages, schemas = logged(log)
    script = layout["userNodes"].get("cosim-errors", {}).get("sourceCode", "")
    problems = []
    if script:
        inputs = json.loads(re.search(r"export const inputs = (\[.*\]);", script).group(1))
        table = json.loads(re.search(r"const ESTIMATES: .* = (\{.*\});", script).group(1))
        problems += [f"script input {t} is not a topic of the log" for t in inputs if t not in schemas]
        written = {f"{estimator}.{state}" for entries in table.values() for _, state, estimator in entries}
    for path in layouts.paths(layout):
        topic, _, field = path.partition(".")
        if topic == layouts.ERRORS_TOPIC:
            if field not in written:
                problems.append(f"{path}: the errors script does not write {field}")
            continue
        if topic not in schemas:
            problems.append(f"{path}: no topic {topic}")
            continue
        schema = schemas[topic]
        for key in field.split("."):
            schema = schema.get("properties", {}).get(key)
            if schema is None:
                break
        if schema is None or not {"number", "integer", "boolean"} & set(
            [schema["type"]] if isinstance(schema.get("type"), str) else schema.get("type", [])
        ):
            problems.append(f"{path}: no number {field} in the schema of {topic}")
            continue
        if messages.get(topic):
            value = messages[topic][0][1]
            for key in field.split("."):
                value = value.get(key) if isinstance(value, dict) else None
            nullable = "null" in (schema.get("type") or [])
            if not (isinstance(value, (int, float)) or (value is None and nullable)):
                problems.append(f"{path}: the first message of {topic} has {value!r}")
    return problems


def panels(layout: dict) -> list[str]:
    """The panels the layout's tabs lay out."""

    def leaves(node) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    return [leaf for tab in layout["configById"][layout["layout"]]["tabs"] for leaf in leaves(tab["layout"])]


def test_the_layouts_of_the_default_and_the_can_fd_scenario_resolve_in_their_logs(tmp_path):
    for name in ("masses-bias", "masses-faults-fd"):
        log = run_short(name, 0.3, tmp_path / f"{name}.mcap")
        out = tmp_path / f"{name}.json"
        assert main(["layout", name, "--out", str(out)]) == 0
        from_scenario = json.loads(out.read_text())
        from_log = layouts.build(layouts.signals_of_log(log))
        assert from_scenario == from_log
        assert sorted(panels(from_log)) == sorted(k for k in from_log["configById"] if k != from_log["layout"])
        assert resolve(from_log, log) == []
        paths = layouts.paths(from_log)
        assert "/truth/state.x1" in paths and f"{layouts.ERRORS_TOPIC}.kalman.x1" in paths
        tabs = [tab["title"] for tab in from_log["configById"][from_log["layout"]]["tabs"]]
        assert tabs[:3] == ["estimates", "errors", "faults"]
        labels = [p["label"] for c in from_log["configById"].values() for p in c.get("paths", [])]
        assert "kalman.xhat_x1" in labels and not any(label.startswith("EST_") for label in labels)
    # the FD scenario's estimates are on /can/EST_kalman, the default's on /can/EST_kalman_0
    assert "/can/EST_kalman.xhat_x1" in layouts.paths(from_log)


@pytest.mark.slow
@pytest.mark.parametrize("name", builtin_names())
def test_every_path_of_the_layout_of_every_builtin_scenario_resolves_in_its_log(name, tmp_path):
    log = run_short(name, 3.0 if name == "three-tank-reconciliation" else 0.5, tmp_path / f"{name}.mcap")
    out = tmp_path / "layout.json"
    assert main(["layout", str(log), "--out", str(out)]) == 0
    layout = json.loads(out.read_text())
    assert resolve(layout, log) == []
    assert layout == layouts.build(layouts.signals_of_log(log))
    if name.startswith("vessel"):
        tabs = [tab["title"] for tab in layout["configById"][layout["layout"]]["tabs"]]
        assert {"diagnosis", "trajectory"} <= set(tabs)
        assert layout["configById"]["Plot!trajectory-xy"]["xAxisPath"]["value"] == "/truth/state.x"
