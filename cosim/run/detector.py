"""A key-less intrusion detector in the runner (``[bus] intrusion_detector = true``).

It sees what any receiver on the bus sees, every frame as the runner logs it (at its arrival time),
and holds no key. Per data id of the DBC it checks:

- ``period``: a frame arrives less than half a sample time after the previous one of its id and
  its tick counter is not the next one (every data message is sent once per tick; frames of
  consecutive ticks may come closer on a busy arbitrated wire);
- ``sequence``: its tick counter repeats the previous one of its id or goes back (a forward jump is
  a lost or replaced frame, not an intrusion);
- ``range``: a value outside its signal's range in the DBC (or not finite);
- ``unknown``: a frame on an id outside the run's DBC and its declared background traffic
  (``[[bus.traffic]]``, which a deployed detector would be configured with), one that cannot be
  one of its frames (another length), or one on the runner's own ids that the runner did not send
  (the echo check of ``cosim.run.traffic.Traffic``: the owner of an id sees a frame it did not
  send). On an arbitrated wire that includes a babbling node's frames.

It never uses what the simulation knows (which frames a fault injected): a fault's intruder sends
from the runner, so to the ``unknown`` check it is the owner. Each tick's verdict goes to
``/cosim/ids`` (``cosim.log.recorder.IDS``): raised or not, alarms per check and the ids involved,
scored by ``cosim.analysis.metrics`` like a diagnosis (detection delay, false alarms per hour).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import can
import numpy as np

from cosim.bus.codec import CLIENT, COMMAND, CONTROL, ESTIMATE, SENSOR, Codec, Decoded, MessageSpec
from cosim.log.recorder import IDS_CHECKS, RunRecorder

_DATA = (SENSOR, COMMAND, CONTROL, ESTIMATE, CLIENT)


def sequence_alarms(elapsed_ns: Any, counter: Any, previous: Any, dt_ns: int, codec: Codec) -> tuple[Any, Any]:
    """The ``period`` and ``sequence`` checks of a frame whose id's last frame in sequence came
    ``elapsed_ns`` before it with the tick counter ``previous``: each a bool, or, given arrays (the
    frames of K runs, ``cosim.campaign.batch_bus``), a bool array; one rule for both."""
    modulus = codec.tick_modulus
    step = (counter - previous) % modulus
    # Frames of consecutive ticks may come anywhere in their ticks (an arbitrated wire's jitter):
    # closer than half a period is a second sender only if the counters do not say they are consecutive.
    period = (elapsed_ns < dt_ns // 2) & (step != 1)
    sequence = (step == 0) | (step > modulus // 2)
    return period, sequence


def out_of_range(spec: MessageSpec, values: Mapping[str, float]) -> bool:
    """The ``range`` check: a value of the frame outside its signal's range in the DBC (or not finite)."""
    for channel, signal in zip(spec.channels, spec.signals):  # a loop: a frame has a signal or two
        if not channel.minimum <= values.get(signal, math.nan) <= channel.maximum:
            return True
    return False


def frame_checks(
    previous: tuple[int, int] | None, t_ns: int, counter: int, decoded: Decoded, dt_ns: int, codec: Codec
) -> tuple[list[str], bool]:
    """The checks a data frame arriving at ``t_ns`` with ``counter`` raises, its id's last frame in
    sequence having come at ``previous`` (ns, counter; None: it is the id's first), and whether it
    is in sequence (then the id's last)."""
    raised = []
    in_sequence = True
    # the next counter raises neither check (``sequence_alarms``): the check of nearly every frame
    if previous is not None and (counter - previous[1]) % codec.tick_modulus != 1:
        period, sequence = sequence_alarms(t_ns - previous[0], counter, previous[1], dt_ns, codec)
        if period:
            raised.append("period")
        if sequence:
            raised.append("sequence")
            in_sequence = False
    if out_of_range(decoded.spec, decoded.values):
        raised.append("range")
    return raised, in_sequence


class IntrusionDetector:
    """Per-id period, sequence and range checks and unknown senders, tick by tick."""

    def __init__(self, codec: Codec, dt_ns: int, traffic_ids: frozenset[int] = frozenset()) -> None:
        """``traffic_ids``: the ids of the bus's declared background traffic (known, not checked)."""
        self.codec, self.dt_ns, self.traffic_ids = codec, dt_ns, traffic_ids
        self._last: dict[int, tuple[int, int]] = {}  # id -> (arrival ns, tick counter) of its last frame
        self._alarms: defaultdict[int, defaultdict[str, set[int]]] = defaultdict(lambda: defaultdict(set))
        self.given = 0  # the ticks before this one have their verdicts given (in the log)
        self.alarms = 0

    def _raise(self, tick: int, check: str, frame_id: int) -> None:
        self._alarms[tick][check].add(frame_id)
        self.alarms += 1

    def frame(self, tick: int, t_ns: int, frame: can.Message, decoded: Decoded | None) -> None:
        """A frame as the runner logs it, at its arrival (tick, ns)."""
        if decoded is None:  # on the wire but in no message of the DBC: unknown unless declared traffic
            if frame.arbitration_id not in self.traffic_ids or frame.is_extended_id:
                self._raise(tick, "unknown", frame.arbitration_id if not frame.is_extended_id else -1)
            return
        if decoded.spec.role not in _DATA:
            return  # control frames are not checked
        frame_id = frame.arbitration_id
        counter = decoded.tick % self.codec.tick_modulus
        raised, in_sequence = frame_checks(self._last.get(frame_id), t_ns, counter, decoded, self.dt_ns, self.codec)
        for check in raised:
            self._raise(tick, check, frame_id)
        if in_sequence:  # a frame out of sequence does not say what comes next: the genuine sender's do
            self._last[frame_id] = (t_ns, counter)

    def foreign(self, tick: int, frame: can.Message) -> None:
        """A frame nobody in the run sent, as far as the runner can tell without keys."""
        self._raise(tick, "unknown", frame.arbitration_id if not frame.is_extended_id else -1)

    def publish(self, recorder: RunRecorder, until: int, dt: float) -> None:
        """Write the verdicts of the ticks before ``until`` (their frames are all logged)."""
        for tick, checks, ids in self.verdicts(until):
            recorder.ids(tick, tick * dt, tick * self.dt_ns, checks, ids)

    def verdicts(self, until: int) -> list[tuple[int, dict[str, int], list[int]]]:
        """The verdicts of the ticks before ``until`` not given yet, each (tick, the ids each of
        ``IDS_CHECKS`` raised on, counted; those ids): what ``publish`` writes (a batch's run, which
        logs nothing, scores them: ``cosim.campaign.batch_wire``)."""
        found = []
        for tick in range(self.given, until):
            alarms: dict[str, set[int]] = self._alarms.pop(tick, {})
            checks = {check: len(alarms.get(check, ())) for check in IDS_CHECKS}
            found.append((tick, checks, sorted({i for ids in alarms.values() for i in ids})))
        self.given = max(self.given, until)
        return found


class DetectorRuns:
    """The intrusion detector of K runs on an ideal bus (a batch, ``cosim.campaign.batch_bus``):
    each run's last frame in sequence per data id as (K, ids) arrays; a tick's genuine frames, one
    per id and run at most, checked on arrays by ``sequence_alarms`` (``frames``), an intruder's
    frame of one run by ``frame_checks`` (``frame``), as ``IntrusionDetector.frame`` checks each;
    ``verdicts`` the checks each run raised in the tick."""

    def __init__(self, codec: Codec, dt_ns: int, runs: int, frame_ids: list[int]) -> None:
        self.codec, self.dt_ns = codec, dt_ns
        self.column = {frame_id: i for i, frame_id in enumerate(frame_ids)}
        self.last_ns = np.zeros((runs, len(frame_ids)), dtype=np.int64)
        self.last_counter = np.zeros((runs, len(frame_ids)), dtype=np.int64)
        self.known = np.zeros((runs, len(frame_ids)), dtype=bool)
        self.raised = np.zeros((runs, len(IDS_CHECKS)), dtype=bool)
        self._slices: dict[tuple[int, ...], slice | list[int]] = {}

    def frames(self, t_ns: int, counter: int, ids: list[int], arrived: np.ndarray, in_range: np.ndarray) -> None:
        """Each run's frames on ``ids`` (at ``t_ns`` with ``counter``) that ``arrived`` (K, ids),
        their values within their signals' ranges or not (``in_range``, K, ids)."""
        c = self._columns(ids)
        period, sequence = sequence_alarms(
            t_ns - self.last_ns[:, c], counter, self.last_counter[:, c], self.dt_ns, self.codec
        )
        checked = arrived & self.known[:, c]
        sequence &= checked
        self.raised[:, _PERIOD] |= (period & checked).any(axis=1)
        self.raised[:, _SEQUENCE] |= sequence.any(axis=1)
        self.raised[:, _RANGE] |= (arrived & ~in_range).any(axis=1)
        stored = arrived & ~sequence
        self.last_ns[:, c] = np.where(stored, t_ns, self.last_ns[:, c])
        self.last_counter[:, c] = np.where(stored, counter, self.last_counter[:, c])
        self.known[:, c] |= stored

    def _columns(self, ids: list[int]) -> slice | list[int]:
        """The columns of ``ids``: a slice where they follow each other (a view, not a copy)."""
        found = self._slices.get(tuple(ids))
        if found is None:
            columns = [self.column[i] for i in ids]
            contiguous = columns == list(range(columns[0], columns[0] + len(columns))) if columns else False
            found = self._slices[tuple(ids)] = slice(columns[0], columns[-1] + 1) if contiguous else columns
        return found

    def frame(self, r: int, t_ns: int, frame_id: int, decoded: Decoded) -> None:
        """One frame of run ``r`` (an intruder's, after the tick's genuine ones)."""
        c = self.column[frame_id]
        counter = decoded.tick % self.codec.tick_modulus
        previous = (int(self.last_ns[r, c]), int(self.last_counter[r, c])) if self.known[r, c] else None
        raised, in_sequence = frame_checks(previous, t_ns, counter, decoded, self.dt_ns, self.codec)
        for check in raised:
            self.raised[r, IDS_CHECKS.index(check)] = True
        if in_sequence:
            self.last_ns[r, c], self.last_counter[r, c], self.known[r, c] = t_ns, counter, True

    def verdicts(self) -> np.ndarray:
        """The tick's verdicts, (K, 1 + checks): whether any check was raised, then each of
        ``IDS_CHECKS``, as 0.0 or 1.0 (as the scores read ``/cosim/ids``); the next tick starts clear."""
        found = np.concatenate([self.raised.any(axis=1, keepdims=True), self.raised], axis=1).astype(float)
        self.raised[:] = False
        return found


_PERIOD, _SEQUENCE, _RANGE = (IDS_CHECKS.index(check) for check in ("period", "sequence", "range"))
