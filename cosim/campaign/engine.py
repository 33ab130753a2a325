"""Where a campaign's runs execute: Dask distributed (a local cluster, or one joined by address), or
inline in this process (for debugging; the same results).

Dask, not Ray: the runs are independent, coarse (seconds each) Python tasks that need nothing but
a task queue with retries, results streamed back as they complete and a cluster a user can start
on other machines with one command (``dask scheduler`` / ``dask worker ADDRESS``). Dask
distributed is pure Python (a small install beside cosim's), its local cluster starts in about a
second and costs no core while idle; Ray's daemons (GCS, raylet, dashboard) and its several
hundred MB are more than a 2-core machine should give up for this.

``Engine.results`` submits at most a window of runs ahead of the completed ones, so the
coordinator's memory does not grow with the campaign; results arrive in completion order, each
with its run, and a worker that dies is reported as that run's failure.
"""

from __future__ import annotations

import logging
import os
from abc import abstractmethod
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager, ExitStack
from typing import Any

from cosim.errors import CosimError
from cosim.extras import require

ENGINES = ("dask", "inline")
#: Runs submitted ahead of the completed ones, per worker.
WINDOW_PER_WORKER = 4


class Engine(AbstractContextManager["Engine"]):
    """Runs ``function(item, *args)`` for items, yielding (item, result or exception)."""

    workers = 1
    description = ""

    @abstractmethod
    def results(self, function: Callable[..., Any], items: Iterable[Any], *args: Any) -> Iterator[tuple[Any, Any]]:
        """(item, result) as each finishes, in any order; a result is an exception if it raised."""

    def __exit__(self, *exc: object) -> None:
        return None


class InlineEngine(Engine):
    """Every run in this process, one after the other."""

    description = "inline (this process)"

    def results(self, function: Callable[..., Any], items: Iterable[Any], *args: Any) -> Iterator[tuple[Any, Any]]:
        for item in items:
            try:
                yield item, function(item, *args)
            except Exception as error:  # the worker function reports failures itself; this is a bug
                yield item, error


class DaskEngine(Engine):
    """A Dask distributed cluster: a local one with ``workers`` single-threaded worker processes
    (default: one per core), started and stopped here, or the one at ``address``."""

    def __init__(self, workers: int | None = None, address: str | None = None) -> None:
        distributed = require("distributed", "cosim campaign --engine dask", "campaign")
        Client, LocalCluster = distributed.Client, distributed.LocalCluster
        self._stack = ExitStack()
        self._local = not address
        if address:
            try:
                self.client = self._stack.enter_context(Client(address, timeout=15))
            except (OSError, TimeoutError) as error:
                raise CosimError(
                    f"--address {address}: no Dask scheduler answers there ({error}); start one with "
                    f"'dask scheduler' and workers with 'dask worker {address}'"
                ) from None
            self.workers = max(1, sum(w.get("nthreads", 1) for w in self.client.scheduler_info()["workers"].values()))
            self.description = f"Dask cluster at {address} ({self.workers} worker threads)"
        else:
            self.workers = workers or os.cpu_count() or 1
            cluster = self._stack.enter_context(
                LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":0",  # a free port: 8787 may be another cluster's
                    silence_logs=40,  # logging.ERROR: a worker's chatter would scroll the progress display away
                )
            )
            self.client = self._stack.enter_context(Client(cluster))
            self.description = (
                f"local Dask cluster, {self.workers} worker processes (dashboard: {cluster.dashboard_link})"
            )
        from cosim.campaign.worker import ignore_interrupts, preload

        self.client.run(preload)  # every worker imports the runner now, not during its first run
        if not address:  # workers of the user's own cluster keep their Ctrl-C
            self.client.run(ignore_interrupts)

    def results(self, function: Callable[..., Any], items: Iterable[Any], *args: Any) -> Iterator[tuple[Any, Any]]:
        from distributed import as_completed

        queue = iter(items)
        window = WINDOW_PER_WORKER * self.workers
        running = as_completed()
        by_key: dict[str, Any] = {}

        def submit(count: int) -> None:
            for item in queue:
                future = self.client.submit(function, item, *args, pure=False, retries=1)
                by_key[future.key] = item
                running.add(future)
                count -= 1
                if count == 0:
                    return

        submit(window)
        for future in running:
            item = by_key.pop(future.key)
            try:
                yield item, future.result()
            except Exception as error:  # the worker died (KilledWorker) or the task could not run
                yield item, error
            finally:
                future.release()
            submit(1)

    def __exit__(self, *exc: object) -> None:
        if isinstance(exc[1] if len(exc) > 1 else None, KeyboardInterrupt):
            # Stopping a cluster in the middle of its tasks makes Dask log every cancelled
            # coroutine; the user asked for the stop, and the coordinator says what was kept.
            quiet_logs()
            if self._local:  # and so should the workers, busy in a batch, whose heartbeat outlives the scheduler
                try:
                    self.client.run(quiet_logs)
                except Exception:  # noqa: BLE001 (a worker already gone has nothing more to say)
                    pass
        self._stack.close()


def quiet_logs() -> None:
    """Silence Dask's loggers (and those of its event loop) in this process."""
    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def open_engine(name: str, workers: int | None = None, address: str | None = None) -> Engine:
    """The engine by name: "dask" (local cluster or ``address``) or "inline"."""
    if name == "dask":
        return DaskEngine(workers, address)
    if name == "inline":
        if address:
            raise CosimError("--address joins a Dask cluster: use it with --engine dask")
        return InlineEngine()
    raise CosimError(f"--engine {name}: unknown engine; use one of {', '.join(ENGINES)}")
