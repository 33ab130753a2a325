"""The metrics of one log: read once, in file order, scored (``scorer``), assembled into a
``RunMetrics`` (``values``)."""

from __future__ import annotations

import functools
from collections import defaultdict
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import orjson
from cantools.database.can import Database

from cosim.analysis import names
from cosim.analysis.metrics.facts import RunFacts
from cosim.analysis.metrics.scorer import Scorer
from cosim.analysis.metrics.values import (
    BusMetrics,
    DiagnosisMetrics,
    EstimationMetrics,
    FaultSpan,
    FrameCounts,
    RunMetrics,
)
from cosim.bus.dbc import SECOC_SIGNALS, estimated_state, load_dbc
from cosim.errors import CodecError, LogError
from cosim.log.metadata import DBC_ATTACHMENT, logged_dbc
from cosim.log.reader import LogReader
from cosim.log.topics import FAULTS, FRAMES, STATE, Record
from cosim.log.writer import read_back

MAC_SIGNAL = SECOC_SIGNALS[1]


class LiveMeasurement:
    """The metrics of a run scored while it goes: a sink that a run's log hands everything to, in
    the order a file gets it, and that feeds the same ``Scorer`` as ``measure`` with the same
    messages. ``result`` is then what ``measure`` of the finished log returns, field for field
    (tested on every built-in scenario), without reading a log; a campaign scores each run so.

    Two ways in, one scorer:

    - a ``cosim.log.writer.LogSink`` of a log written to a file (``McapLog``): each message's JSON
      bytes, decoded as the reader decodes them (those of topics the scores never read, not at
      all: ``Scorer.reads``);
    - a ``cosim.log.writer.RecordSink`` of a run that writes no file (``SinkLog``): the records
      themselves for the topics read as records (``Scorer.feed_record``: the fields a reader
      would read back, without the JSON between: the same ints, strings and floats, which JSON
      writes and reads back exactly), and each other payload through the JSON it would have been
      (``orjson`` both ways: NaN becomes null and numpy values plain ones, as in a file). Messages
      of topics the scores do not read are not even built: ``seen`` counts them and their time.

    The scorer starts at the run's first message, by when the runner has written its description
    (``cosim.run``) and its DBC; the outcome (``cosim.result``) is read at the end. Scoring never
    stops the run: should the scorer fail, it stops scoring, and ``result`` is None."""

    def __init__(self) -> None:
        self._meta: dict[str, dict[str, str]] = {}
        self._attachments: dict[str, bytes] = {}
        self._schemas: dict[str, dict[str, Any]] = {}
        self._counts: dict[str, int] = {}
        self._scorer: Scorer | None = None
        self.failure: str | None = None

    def _start(self) -> Scorer:
        run = _facts(self._meta)
        database = _parse_dbc(self._attachments.get(DBC_ATTACHMENT))
        self._scorer = Scorer(run, _estimate_bounds(database, run), _authenticated(database))
        return self._scorer

    def channel(self, topic: str, schema: dict[str, Any]) -> str:
        self._schemas[topic] = schema
        self._counts[topic] = 0
        return topic

    def reads(self, topic: str) -> bool:
        """Whether the scores read ``topic``; asked at a topic's first message, by when the run has
        written its description and its DBC (they come before any message)."""
        try:
            return (self._scorer or self._start()).reads(topic)
        except Exception as error:  # noqa: BLE001 (a scoring bug must not end the run it scores)
            self.failure = self.failure or f"{type(error).__name__}: {error}"
            return False

    def write(self, channel: str, time_ns: int, data: bytes) -> None:
        def feed(scorer: Scorer) -> None:
            if scorer.reads(channel):
                scorer.feed(channel, time_ns, orjson.loads(data))
            else:
                scorer.seen(time_ns)

        self._score(channel, feed)

    def message(self, channel: str, time_ns: int, payload: Any) -> None:
        def feed(scorer: Scorer) -> None:
            if isinstance(payload, Record) and scorer.records(channel):
                scorer.feed_record(channel, time_ns, payload)
            else:
                scorer.feed(channel, time_ns, read_back(payload))

        self._score(channel, feed)

    def _score(self, channel: str, feed: Callable[[Scorer], None]) -> None:
        """Count a message on ``channel`` and ``feed`` it to the scorer, until scoring has failed: a
        scoring bug stops the scoring, never the run it scores."""
        if self.failure is not None:
            return
        try:
            scorer = self._scorer or self._start()
            self._counts[channel] += 1
            feed(scorer)
        except Exception as error:  # noqa: BLE001 (a scoring bug must not end the run it scores)
            self.failure = f"{type(error).__name__}: {error}"

    def seen(self, channel: str, time_ns: int) -> None:
        if self.failure is not None:
            return
        try:
            self._counts[channel] += 1
            (self._scorer or self._start()).seen(time_ns)
        except Exception as error:  # noqa: BLE001 (a scoring bug must not end the run it scores)
            self.failure = f"{type(error).__name__}: {error}"

    def metadata(self, name: str, values: dict[str, str]) -> None:
        self._meta[name] = dict(values)

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        self._attachments[name] = data

    def result(self, path: str | Path | None) -> RunMetrics | None:
        """The run's metrics, once its log is closed (``path``: the log, as the metrics name it;
        None: the run wrote none, and ``file`` is empty); None if scoring failed on the way
        (``failure`` says how)."""
        if self.failure is not None:
            return None
        run = _facts(self._meta)
        return _finish("" if path is None else path, run, self._scorer or Scorer(run), self._counts, [], self._schemas)


class TickScoring:
    """The scores of a run that logs nothing and hands them whole ticks (a batched run,
    ``cosim.campaign.batch``, through ``scorer.TickBatch``): the same ``Scorer`` as ``measure``'s, fed
    the values its log would have given it, from its metadata records and its DBC text."""

    def __init__(self, meta: dict[str, dict[str, str]], dbc: str) -> None:
        self._meta = dict(meta)
        run = _facts(self._meta)
        database = _parse_dbc(dbc.encode())
        self.scorer = Scorer(run, _estimate_bounds(database, run), _authenticated(database))

    def metrics(self, name: str, record: dict[str, str]) -> RunMetrics:
        """The metrics once every tick is in, with the run's last metadata record (its result)."""
        meta = {**self._meta, name: record}
        return _finish("", _facts(meta), self.scorer, {}, [], {})


def measure(path: str | Path) -> RunMetrics:
    """The metrics of one log (docs/metrics.md). Raises LogError only for a file that is not MCAP at
    all; damage and missing data become ``warnings`` and ``missing``."""
    with LogReader(path) as reader:
        run = _facts(reader.metadata())
        counts = reader.summary_counts()
        database = _database(reader)
        scorer = Scorer(run, _estimate_bounds(database, run), _authenticated(database))
        scanned: dict[str, int] = defaultdict(int)
        try:  # every message counted, those the scores read decoded (as LiveMeasurement does)
            for _, channel, message in reader.raw_messages():
                topic = channel.topic
                scanned[topic] += 1
                if not scorer.reads(topic):
                    scorer.seen(message.log_time)
                    continue
                try:
                    msg = orjson.loads(message.data)
                except orjson.JSONDecodeError as error:
                    reader.undecodable(topic, message.log_time, error)
                    continue
                scorer.feed(topic, message.log_time, msg)
        except (OSError, OverflowError, MemoryError) as error:  # a damaged index points outside the file
            where = "at its start" if scorer.last_ns is None else f"after t = {scorer.last_ns / 1e9:g} s"
            scorer.warnings.append(
                f"reading stopped {where}: the file's summary is damaged ({type(error).__name__}: {error}); "
                f"the {sum(scanned.values())} messages before were read"
            )
        return _finish(path, run, scorer, counts or dict(scanned), reader.warnings, reader.schemas())


def _finish(
    path: str | Path,
    run: RunFacts,
    scorer: Scorer,
    counts: dict[str, int],
    read_warnings: list[str],
    schemas: dict[str, dict[str, Any]],
) -> RunMetrics:
    """The metrics once every message is fed: ``counts`` per topic, the reader's warnings, the
    topics' schemas (their units)."""
    scorer.finish()
    warnings = read_warnings + run.warnings + scorer.warnings
    unit = norm_unit(names.units(schemas), run.states)
    return replace(_assemble(path, run, scorer, counts, warnings), error_unit=unit)


def norm_unit(units: dict[str, str], states: list[str]) -> str | None:
    """The unit of |x − x̂| over these states: their common unit, or ``mixes m, m/s`` where they
    differ (None without states; "" where none has a unit)."""
    if not states:
        return None
    found = list(dict.fromkeys(units.get(s, "") for s in states))
    return found[0] if len(found) == 1 else f"mixes {', '.join(u or '1' for u in found)}"


def compute_metrics(path: str | Path) -> dict[str, Any]:
    """The metrics of one log in their JSON form (``cosim inspect --json``'s object)."""
    return measure(path).to_json()


def _facts(meta: dict[str, dict[str, str]]) -> RunFacts:
    try:
        return RunFacts(meta)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as error:  # valid JSON, damaged content
        run = RunFacts({})
        run.warnings.insert(
            0, f"the cosim metadata is damaged ({type(error).__name__}: {error}); the log is read as a foreign one"
        )
        return run


def _database(reader: LogReader) -> Database | None:
    """The logged DBC; None without a readable one (reported elsewhere)."""
    try:
        text = logged_dbc(reader, missing_ok=True)
        return load_dbc(text) if text is not None else None
    except (LogError, CodecError):
        return None


@functools.lru_cache(maxsize=4)
def _parse_dbc(data: bytes | None) -> Database | None:
    """A DBC attachment's database; None without a readable one. The scores only read it, so the
    runs of a campaign worker, which log the same DBC, share one parse."""
    try:
        return load_dbc(data.decode()) if data is not None else None
    except (UnicodeDecodeError, CodecError):
        return None


def _authenticated(database: Database | None) -> list[str]:
    """The messages SecOC authenticates (those with its trailer in the logged DBC)."""
    return [m.name for m in database.messages if any(s.name == MAC_SIGNAL for s in m.signals)] if database else []


def _estimate_bounds(database: Database | None, run: RunFacts) -> dict[str, dict[str, tuple[float, float]]]:
    """Each estimator's estimate signals with their bus range shrunk by half a quantum (a decoded
    value outside it sits at the bound), from the logged DBC; {} without one."""
    bounds: dict[str, dict[str, tuple[float, float]]] = {}
    for message in database.messages if database is not None else ():
        sender = message.senders[0] if message.senders else ""
        for signal in message.signals if sender in run.estimators else ():
            if estimated_state(signal.name) is not None and signal.minimum is not None and signal.maximum is not None:
                half = 0.0 if signal.is_float else 0.5 * float(signal.scale)
                bounds.setdefault(sender, {})[signal.name] = (signal.minimum + half, signal.maximum - half)
    return bounds


def _assemble(
    path: str | Path, run: RunFacts, scorer: Scorer, channels: dict[str, int], warnings: list[str]
) -> RunMetrics:
    dt = run.sample_time
    ticks = scorer.ticks if run.known else channels.get(STATE, 0)
    if run.result_ticks is not None:  # the ticks the run completed (a stopped run logs the truth of one more)
        ticks = min(ticks, run.result_ticks) if ticks else run.result_ticks
    lost = run.frames_lost if run.frames_lost is not None else scorer.lost_events
    span = (
        None
        if scorer.first_ns is None or scorer.last_ns is None  # set together
        else round((scorer.last_ns - scorer.first_ns) / 1e9, 9)
    )
    return RunMetrics(
        file=str(path),
        scenario=run.record.scenario,
        source=run.record.source,
        seed=run.seed,
        status=run.status,
        contested_ticks=run.contested_ticks,
        sample_time=dt,
        ticks=ticks,
        duration_s=round(ticks * dt, 9) if dt else None,
        time_span_s=span,
        channels=dict(sorted(channels.items())),
        frames=FrameCounts(run.frames_total if run.frames_total is not None else channels.get(FRAMES, 0), lost),
        fault_onset=run.onset,
        faults=_faults(run, scorer),
        estimators=_estimators(run, scorer),
        baseline=run.baseline,
        diagnosis=_diagnosis(run, scorer),
        bus=_bus(run, scorer, ticks, lost) if run.known else None,
        missing=_missing(run, scorer, channels),
        warnings=warnings,
    )


def _faults(run: RunFacts, scorer: Scorer) -> dict[str, FaultSpan]:
    """The run's faults with their onset and clearance; a fault active in the truth but absent from
    the metadata too."""
    found = {
        label: replace(span, onset=run.seconds(scorer.onsets.get(label)), cleared=run.seconds(scorer.ends.get(label)))
        for label, span in run.faults.items()
    }
    for label in scorer.onsets.keys() - found.keys():
        found[label] = FaultSpan(onset=run.seconds(scorer.onsets[label]), cleared=run.seconds(scorer.ends.get(label)))
    return found


def _estimators(run: RunFacts, scorer: Scorer) -> dict[str, EstimationMetrics]:
    baseline = scorer.estimators.get(run.baseline) if run.baseline else None
    return {
        name: replace(
            score.metrics(run.estimators[name].kind, baseline),
            kind_name=run.estimators[name].declared or None,
            failed=run.failed.get(name),
        )
        for name, score in scorer.estimators.items()
    }


def _diagnosis(run: RunFacts, scorer: Scorer) -> dict[str, DiagnosisMetrics]:
    dt = run.sample_time
    if scorer.diagnosis:
        assert dt is not None, "diagnosis is scored at ticks, and ticks are scored only with a sample time"
    return {
        name: replace(
            verdict.metrics(dt or 0.0, run.estimators[name].kind), kind_name=run.estimators[name].declared or None
        )
        for name, verdict in scorer.diagnosis.items()
    }


def _bus(run: RunFacts, scorer: Scorer, ticks: int, lost: int | None) -> BusMetrics:
    dt = run.sample_time
    # only where the run had the intrusion detector (/cosim/ids)
    ids = {check: verdict.metrics(dt) for check, verdict in scorer.ids.items()} if scorer.ids and dt else None
    secoc = scorer.secoc.metrics(dt) if scorer.secoc is not None and dt else None
    return scorer.bus.metrics(ticks, lost, run.deadline_misses, (run.lost_by_sender, run.late_by_sender), ids, secoc)


def _missing(run: RunFacts, scorer: Scorer, channels: dict[str, int]) -> list[str]:
    """What the log lacks, and the metrics it costs."""
    missing = list(run.missing)
    if run.known:
        for topic, what in (
            (STATE, "estimation errors"),
            (FAULTS, "per-fault onsets, detection and isolation"),
            (FRAMES, "frames per id and bus load"),
        ):
            if not channels.get(topic):
                missing.append(f"{topic} messages: no {what}")
        if scorer.bus.frames and not scorer.bus.bitrate:
            missing.append("the bus bit rate (cosim.run.bus): no bus load")
    return missing
