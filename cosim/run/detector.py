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

import can

from cosim.bus.codec import CLIENT, COMMAND, CONTROL, ESTIMATE, SENSOR, Codec, Decoded
from cosim.log.recorder import IDS_CHECKS, RunRecorder

_DATA = (SENSOR, COMMAND, CONTROL, ESTIMATE, CLIENT)


class IntrusionDetector:
    """Per-id period, sequence and range checks and unknown senders, tick by tick."""

    def __init__(self, codec: Codec, dt_ns: int, traffic_ids: frozenset[int] = frozenset()) -> None:
        """``traffic_ids``: the ids of the bus's declared background traffic (known, not checked)."""
        self.codec, self.dt_ns, self.traffic_ids = codec, dt_ns, traffic_ids
        self._last: dict[int, tuple[int, int]] = {}  # id -> (arrival ns, tick counter) of its last frame
        self._alarms: defaultdict[int, defaultdict[str, set[int]]] = defaultdict(lambda: defaultdict(set))
        self._published = 0  # ticks before this one have their verdict in the log
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
        previous = self._last.get(frame_id)
        counter = decoded.tick % self.codec.tick_modulus
        in_sequence = True
        if previous is not None:
            step = (counter - previous[1]) % self.codec.tick_modulus
            # Frames of consecutive ticks may come anywhere in their ticks (an arbitrated wire's
            # jitter): closer than half a period is a second sender only if the counters do not
            # say they are consecutive.
            if t_ns - previous[0] < self.dt_ns // 2 and step != 1:
                self._raise(tick, "period", frame_id)
            if step == 0 or step > self.codec.tick_modulus // 2:
                self._raise(tick, "sequence", frame_id)
                in_sequence = False
        spec = decoded.spec
        for channel, signal in zip(spec.channels, spec.signals):
            if not channel.minimum <= decoded.values.get(signal, math.nan) <= channel.maximum:
                self._raise(tick, "range", frame_id)
                break
        if in_sequence:  # a frame out of sequence does not say what comes next: the genuine sender's do
            self._last[frame_id] = (t_ns, counter)

    def foreign(self, tick: int, frame: can.Message) -> None:
        """A frame nobody in the run sent, as far as the runner can tell without keys."""
        self._raise(tick, "unknown", frame.arbitration_id if not frame.is_extended_id else -1)

    def publish(self, recorder: RunRecorder, until: int, dt: float) -> None:
        """Write the verdicts of the ticks before ``until`` (their frames are all logged)."""
        for tick in range(self._published, until):
            alarms: dict[str, set[int]] = self._alarms.pop(tick, {})
            recorder.ids(
                tick,
                tick * dt,
                tick * self.dt_ns,
                {check: len(alarms.get(check, ())) for check in IDS_CHECKS},
                sorted({i for ids in alarms.values() for i in ids}),
            )
        self._published = max(self._published, until)
