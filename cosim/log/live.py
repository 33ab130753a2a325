"""The live view: a log's channels and messages served over the Foxglove WebSocket protocol.

``FoxgloveSink`` is a ``cosim.log.writer.LogSink`` backed by foxglove-sdk's WebSocket server (the
``live`` extra): handed to a run's log (``cosim run --foxglove``), it advertises every topic the log
registers, with the same JSON Schema, and publishes every message the log writes, so Foxglove
(Open connection → Foxglove WebSocket, ``ws://127.0.0.1:8765``) shows the run while it goes.
``play`` serves a finished log the same way, message by message at its simulated time over
``speed`` (``cosim replay LOG --foxglove``).

Messages are stamped at ``start_ns`` plus their simulated time: the run's wall-clock start, so
Foxglove's clock shows the time of day the run happened. What the log writes before a viewer has
subscribed (the run's start event, say) is held and published once one has (``wait_for_viewer``),
so a viewer the run waited for misses nothing. Each sink has a foxglove ``Context`` of
its own, so two servers in one process do not mix their channels. The server keeps up to
``BACKLOG`` messages per client; a client slower than the run loses the oldest (the log loses
nothing).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cosim.extras import require
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader
from cosim.log.writer import dumps

DEFAULT_PORT = 8765
#: Messages the server holds per client before it drops the oldest (foxglove-sdk's default is 1024).
BACKLOG = 1 << 16


class FoxgloveSink:
    """A Foxglove WebSocket server fed by a log (``McapLog(..., sink=FoxgloveSink())``)."""

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        host: str = "127.0.0.1",
        name: str = "cosim",
        start_ns: int | None = None,
        feature: str = "--foxglove",
    ) -> None:
        foxglove = require("foxglove", feature)
        from foxglove.websocket import ServerListener

        self._foxglove = foxglove
        self.start_ns = time.time_ns() if start_ns is None else start_ns
        self.context = foxglove.Context()
        self._subscribed = threading.Event()
        self.subscriptions: set[str] = set()
        subscribed, subscriptions = self._subscribed, self.subscriptions

        class Listener(ServerListener):
            def on_subscribe(self, client, channel) -> None:
                subscriptions.add(channel.topic)
                subscribed.set()

        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                context=self.context,
                server_listener=Listener(),
                message_backlog_size=BACKLOG,
            )
        except RuntimeError as error:  # the port is taken, say
            from cosim.errors import CosimError

            raise CosimError(f"--foxglove: cannot serve on {host}:{port}: {error}") from None
        self.host = host
        self.port = self.server.port
        self._channels: list[Any] = []
        # What the log writes before a viewer has subscribed (the run's start event, warnings) is
        # held and published once one has, so that a viewer that was waited for misses nothing.
        self._held: list[tuple[Any, int, Any]] | None = []

    @property
    def url(self) -> str:
        """The WebSocket address to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def app_url(self) -> str | None:
        """The Foxglove web app's link that opens this server."""
        return self.server.app_url()

    # -- LogSink ---------------------------------------------------------------------------------

    def channel(self, topic: str, schema: dict[str, Any]) -> Any:
        """Advertise ``topic`` with its JSON Schema (named by its title, as the log names it)."""
        foxglove = self._foxglove
        channel = foxglove.Channel(
            topic,
            schema=foxglove.Schema(
                name=schema.get("title", topic), encoding="jsonschema", data=json.dumps(schema).encode()
            ),
            message_encoding="json",
            context=self.context,
        )
        self._channels.append(channel)
        return channel

    def write(self, channel: Any, time_ns: int, payload: Any) -> None:
        """Publish one message at the run's start plus its simulated time ``time_ns``."""
        if self._held is not None:
            if not self._subscribed.is_set():
                self._held.append((channel, time_ns, payload))
                return
            self._release()
        if channel.has_sinks():
            channel.log(dumps(payload), log_time=self.start_ns + time_ns)

    def _release(self) -> None:
        held, self._held = self._held or [], None
        for channel, time_ns, payload in held:
            self.write(channel, time_ns, payload)

    # -- the viewer ------------------------------------------------------------------------------

    def wait_for_viewer(
        self, timeout: float, settle: float = 0.5, interrupted: Callable[[], bool] | None = None
    ) -> bool:
        """Wait up to ``timeout`` seconds for a client to subscribe to a channel, then ``settle``
        seconds more for the rest of its subscriptions; True if one did."""
        deadline = time.monotonic() + timeout
        while not self._subscribed.wait(min(0.1, max(0.0, deadline - time.monotonic()))):
            if time.monotonic() >= deadline or (interrupted is not None and interrupted()):
                self._release()
                return False
        time.sleep(settle)
        self._release()
        return True

    def close(self, linger: float = 0.5) -> None:
        """Stop serving: after ``linger`` seconds for subscribed clients to take what the server
        still holds for them, close the channels (clients see them go) and the server."""
        if self.subscriptions and linger > 0:
            time.sleep(linger)
        for channel in self._channels:
            channel.close()
        self._channels.clear()
        self.server.stop()

    def __enter__(self) -> FoxgloveSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def log_start_ns(path: str | Path) -> int | None:
    """The wall-clock start a log records (``cosim.run`` ``start_time_ns``), or None."""
    with LogReader(path) as reader:
        run = LogMetadata.read(reader.metadata()).run
    return None if run is None else run.start_time_ns


def play(
    path: str | Path,
    sink: FoxgloveSink,
    speed: float = 1.0,
    wait: float = 0.0,
    on_ready: Callable[[bool], None] | None = None,
) -> tuple[int, float, list[str]]:
    """Serve every message of the log ``path`` through ``sink`` at its simulated time over ``speed``
    (0: as fast as possible), once its channels are advertised and a viewer has subscribed (waited
    for up to ``wait`` seconds; ``on_ready`` is told whether one did); returns (messages, simulated
    seconds, the reader's warnings)."""
    with LogReader(path) as reader:
        schemas = reader.schemas()
        channels = {topic: sink.channel(topic, schema) for topic, schema in schemas.items()}
        viewer = sink.wait_for_viewer(wait) if wait > 0 else False
        if on_ready is not None:
            on_ready(viewer)
        count, first, last = 0, None, 0
        started = time.perf_counter()
        for topic, log_time, message in reader.messages():
            if first is None:
                first = log_time
            if speed > 0:
                delay = (log_time - first) / 1e9 / speed - (time.perf_counter() - started)
                if delay > 0:
                    time.sleep(delay)
            if topic not in channels:  # a topic the summary did not list (a cut log)
                channels[topic] = sink.channel(topic, {"title": topic})
            sink.write(channels[topic], log_time, message)
            count, last = count + 1, log_time
        return count, (last - (first or 0)) / 1e9, reader.warnings
