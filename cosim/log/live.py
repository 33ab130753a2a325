"""The live view: a log's channels and messages served over the Foxglove WebSocket protocol.

``FoxgloveSink`` is a ``cosim.log.writer.LogSink`` backed by foxglove-sdk's WebSocket server (the
``live`` extra): handed to a run's log (``cosim run --foxglove``), it advertises every topic the log
registers, with the same JSON Schema, and publishes every message the log writes, so Foxglove
(Open connection → Foxglove WebSocket, ``ws://127.0.0.1:8765``) shows the run while it goes.
``play`` serves a finished log the same way, message by message at its simulated time over
``speed`` (``cosim replay LOG --foxglove``).

Two names for one protocol: foxglove-sdk's server accepts only the subprotocol
``foxglove.sdk.v1``, while Lichtblick and Foxglove app versions before the SDK speak
``foxglove.websocket.v1``, the same protocol under its former name. So the SDK's server listens on a
private loopback port and ``SubprotocolBridge`` serves the address the user asked for, accepting
either name and relaying every WebSocket message both ways unchanged.

Messages are stamped at ``start_ns`` plus their simulated time: the run's wall-clock start, so
Foxglove's clock shows the time of day the run happened. What the log writes before a viewer has
subscribed (the run's start event, say) is held and published once one has (``wait_for_viewer``),
so a viewer the run waited for misses nothing. Each sink has a foxglove ``Context`` of
its own, so two servers in one process do not mix their channels. The server keeps up to
``BACKLOG`` messages per client; a client slower than the run loses the oldest (the log loses
nothing).
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.extras import require
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader
from cosim.log.writer import dumps

if TYPE_CHECKING:
    from foxglove.websocket import ChannelView, Client

DEFAULT_PORT = 8765
#: The protocol's names: the SDK's, and the one Lichtblick and older Foxglove apps ask for.
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
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
        require("websockets", feature)
        from foxglove.websocket import ServerListener

        self._foxglove = foxglove
        self.start_ns = time.time_ns() if start_ns is None else start_ns
        self.context = foxglove.Context()
        self._subscribed = threading.Event()
        self.subscriptions: set[str] = set()
        subscribed, subscriptions = self._subscribed, self.subscriptions

        class Listener(ServerListener):
            def on_subscribe(self, client: Client, channel: ChannelView) -> None:
                subscriptions.add(channel.topic)
                subscribed.set()

        self.server = foxglove.start_server(
            name=name,
            host="127.0.0.1",
            port=0,
            context=self.context,
            server_listener=Listener(),
            message_backlog_size=BACKLOG,
        )
        try:
            self.bridge = SubprotocolBridge(host, port, self.server.port)
        except BaseException:
            self.server.stop()
            raise
        self.host = host
        self.port = self.bridge.port
        self._channels: list[Any] = []
        # What the log writes before a viewer has subscribed (the run's start event, warnings) is
        # held and published once one has, so that a viewer that was waited for misses nothing.
        self._held: list[tuple[Any, int, Any]] | None = []

    @property
    def url(self) -> str:
        """The WebSocket address to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def app_url(self) -> str:
        """The Foxglove web app's link that opens this server."""
        return "https://app.foxglove.dev?" + urllib.parse.urlencode({"ds": "foxglove-websocket", "ds.url": self.url})

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

    def write(self, channel: Any, time_ns: int, data: bytes) -> None:
        """Publish one message (its JSON bytes) at the run's start plus its simulated time ``time_ns``."""
        if self._held is not None:
            if not self._subscribed.is_set():
                self._held.append((channel, time_ns, data))
                return
            self._release()
        if channel.has_sinks():
            channel.log(data, log_time=self.start_ns + time_ns)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """Metadata is not streamed: a viewer gets the run's description from its topics."""

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        """Attachments are not streamed."""

    def _release(self) -> None:
        held, self._held = self._held or [], None
        for channel, time_ns, data in held:
            self.write(channel, time_ns, data)

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
        self.server.stop()  # first: the bridge's relays end with the connections they relay
        self.bridge.close()

    def __enter__(self) -> FoxgloveSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SubprotocolBridge:
    """A WebSocket server on ``host:port`` (0: a free port) that accepts a viewer speaking either
    of ``SUBPROTOCOLS`` and relays each message, text or binary, unchanged between it and the
    foxglove-sdk server on the loopback port ``inner``. It runs its own event loop in a thread."""

    def __init__(self, host: str, port: int, inner: int) -> None:
        from websockets.asyncio.server import serve
        from websockets.typing import Subprotocol

        self.inner = inner
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="foxglove-bridge", daemon=True)
        self._thread.start()

        async def listen() -> Any:
            names = [Subprotocol(name) for name in SUBPROTOCOLS]
            return await serve(self._relay, host, port, subprotocols=names, compression=None, close_timeout=1)

        try:
            self._server = asyncio.run_coroutine_threadsafe(listen(), self._loop).result()
        except OSError as error:  # the port is taken, or the host is not this machine's
            from cosim.errors import CosimError

            self._stop_loop()
            raise CosimError(f"--foxglove: cannot serve on {host}:{port}: {error.strerror or error}") from None
        self.port: int = self._server.sockets[0].getsockname()[1]

    async def _relay(self, viewer: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed
        from websockets.typing import Subprotocol

        async with connect(
            f"ws://127.0.0.1:{self.inner}",
            subprotocols=[Subprotocol(SUBPROTOCOLS[0])],
            compression=None,
            max_size=None,
            close_timeout=1,
        ) as server:

            async def pipe(source: Any, target: Any) -> None:
                try:
                    async for message in source:
                        await target.send(message)
                except ConnectionClosed:
                    pass
                await target.close()

            await asyncio.gather(pipe(viewer, server), pipe(server, viewer))

    def close(self, timeout: float = 2.0) -> None:
        """Stop listening and close the viewers' connections (those that do not finish their
        closing handshake within ``timeout`` seconds are dropped)."""

        async def shut() -> None:
            self._server.close()
            try:
                await asyncio.wait_for(self._server.wait_closed(), timeout)
            except TimeoutError:
                pass
            for task in asyncio.all_tasks() - {asyncio.current_task()}:
                task.cancel()

        asyncio.run_coroutine_threadsafe(shut(), self._loop).result()
        self._stop_loop()

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        self._loop.close()


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
            sink.write(channels[topic], log_time, dumps(message))
            count, last = count + 1, log_time
        return count, (last - (first or 0)) / 1e9, reader.warnings
