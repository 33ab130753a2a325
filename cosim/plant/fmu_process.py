"""An FMU plant run in a process of its own (``cosim.plant.fmu_host``), seen from the runner.

``IsolatedFmuPlant`` has ``FmuPlant``'s interface; each call is one request to the host process
and one answer (a tick: one ``step``, which answers the new states and sensors). Why: an FMU is
foreign C code. In a process of its own

- a call that never returns (an FMU that loops) cannot make the run unstoppable: while it waits,
  the runner takes Ctrl-C and SIGTERM (``interrupted``), kills the host and stops the run in one
  line naming the FMU and the call under way (``FmuInterrupted``);
- a crash (a segfault) ends the host, not the runner: the run ends with one line naming the signal,
  the call and the FMU's last message (``FmuCallError``), and the runner finishes the log;
- what the FMU's C code prints (to file descriptors 1 and 2) goes to the host's pipes, which the
  runner reads into the plant's messages (``take_messages``): the run's log keeps them, the
  runner's own output stays its own (``cosim run --json`` stays JSON).

What it costs per tick was measured against the FMU in the runner: docs/fmi.md, "How the FMU is
isolated" (``bench/fmu_isolation.py``).

Host processes are kept for reuse (a run builds its plant more than once: the plan's linearization,
the run's): one per FMU file, or one per plant for an FMU that ``canBeInstantiatedOnlyOncePerProcess``;
at most ``IDLE_HOSTS`` idle ones stay. A host that failed is never reused.
"""

from __future__ import annotations

import atexit
import fcntl
import itertools
import mmap
import os
import pickle
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing import Pipe
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

import cosim
from cosim.blas import ONE_THREAD_ENV
from cosim.errors import Interruption, ModelError
from cosim.plant.fmu_calls import ANSWER, SLOT_SIZE, STEP, STEP_HEADER, FmuCallError, FmuMessage
from cosim.plant.fmu_model import FmuModel
from cosim.plant.fmu_plant_base import FmuPlantBase
from estimators.model import LinearModel

#: Idle host processes kept for reuse, at most.
IDLE_HOSTS = 4
#: How often a wait for the host looks at the interrupts (s).
POLL = 0.05
_F_SETPIPE_SZ = 1031


#: Ctrl-C or SIGTERM raised in a plant's ``__del__`` (its host's answer awaited), which Python would
#: drop: kept for the next wait on a host, so that the run still stops (a plan's plants come and go).
_DROPPED: list[KeyboardInterrupt] = []


class FmuInterrupted(Interruption):
    """Ctrl-C or SIGTERM while the FMU did not answer: the run stops, the host is killed."""


class Host:
    """One host process (``cosim.plant.fmu_host``) and its pipes: requests, answers, the FMU's output."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.open = 0
        self.failed = False
        self.lock = threading.Lock()
        self.pending: list[FmuMessage] = []
        self._partial = {"stdout": b"", "stderr": b""}
        self._slot_file = tempfile.TemporaryFile()
        self._slot_file.truncate(SLOT_SIZE)
        self.slot = mmap.mmap(self._slot_file.fileno(), SLOT_SIZE)
        ours, theirs = Pipe()
        root = str(Path(cosim.__file__).resolve().parent.parent)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])]))
        env.update(ONE_THREAD_ENV)  # cosim.blas
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cosim.plant.fmu_host",
                str(theirs.fileno()),
                str(self._slot_file.fileno()),
                str(os.getpid()),
            ],
            pass_fds=(theirs.fileno(), self._slot_file.fileno()),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        theirs.close()
        self.connection: Connection = ours
        self._answered = select.poll()  # one system call a wait, not multiprocessing's selector per call
        self._answered.register(ours.fileno(), select.POLLIN)
        self._outputs = {"stdout": self.process.stdout, "stderr": self.process.stderr}
        self._printed = select.poll()  # whether the host printed anything: one system call a tick
        for stream in self._outputs.values():
            assert stream is not None
            os.set_blocking(stream.fileno(), False)
            self._printed.register(stream.fileno(), select.POLLIN)
            try:
                fcntl.fcntl(stream.fileno(), _F_SETPIPE_SZ, 1 << 20)  # a chatty call does not block on a full pipe
            except OSError:
                pass

    def call(self, op: str, key: int, args: tuple[Any, ...], t: float, interrupted: Callable[[], None] | None) -> Any:
        """The answer of one request; the FMU's messages meanwhile go to ``pending``."""
        return self._exchange(pickle.dumps((op, key, args)), t, interrupted)[1]

    def step(
        self, key: int, u: np.ndarray, d: np.ndarray, t: float, interrupted: Callable[[], None] | None
    ) -> np.ndarray:
        """One tick: the new states, then the sensors."""
        request = STEP + STEP_HEADER.pack(key, len(u)) + u.tobytes() + d.tobytes()
        values: np.ndarray = self._exchange(request, t, interrupted)[1]
        return values

    def _exchange(self, request: bytes, t: float, interrupted: Callable[[], None] | None) -> Any:
        with self.lock:
            if self.failed:
                raise ModelError(f"{self.name}: its process has failed before; build the plant again")
            self.connection.send_bytes(request)
            answer = self._answer(t, interrupted)
        if answer[0] in ("ok", "step"):
            return answer
        self.failed = True
        self.kill()
        if answer[0] == "error":
            raise ModelError(answer[1])
        raise RuntimeError(f"the FMU's host process failed: {answer[1]}\n{answer[2]}")

    def _answer(self, t: float, interrupted: Callable[[], None] | None) -> tuple[Any, ...]:
        started = time.monotonic()
        try:
            while True:
                if not self._answered.poll(POLL * 1000):  # the FMU is slow, chatty or hangs
                    if _DROPPED:  # a Ctrl-C that came while a plant was freed by the garbage collector
                        raise _DROPPED.pop()
                    self.read_output()
                    if interrupted is not None:
                        interrupted()
                    continue
                try:
                    data = self.connection.recv_bytes()
                except EOFError:
                    raise self._crashed(t) from None
                if data[:1] == ANSWER:
                    self.read_output()
                    return ("step", np.frombuffer(data, dtype=float, offset=1))
                message = pickle.loads(data)
                if message[0] != "log":
                    self.read_output()
                    return tuple(message)
                self.pending.append(message[1])
        except KeyboardInterrupt as stop:
            call = self.call_under_way()
            self.failed = True
            self.kill()
            raise FmuInterrupted(
                getattr(stop, "signum", signal.SIGINT),
                f"{self.name} was in {call} at t = {t:g} s ({time.monotonic() - started:.1f} s without an answer); "
                "its process was killed",
            ) from None

    def _crashed(self, t: float) -> FmuCallError:
        """The error of a host process that ended in a call (a segfault in the FMU, usually)."""
        call = self.call_under_way()
        self.failed = True
        try:
            code = self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self.kill()
            code = self.process.returncode
        self.read_output(final=True)
        how = f"crashed ({signal.Signals(-code).name})" if code is not None and code < 0 else f"exited ({code})"
        logged = [m for m in self.pending if m.source == "logger"]
        said = f"its last message: {logged[-1]}" if logged else "it logged no message"
        printed = [m for m in self.pending if m.source != "logger"]
        if printed:
            said += f"; it last printed: {printed[-1].text}"
        return FmuCallError(f"{self.name} {how} in {call} at t = {t:g} s; {said}")

    def call_under_way(self) -> str:
        name = bytes(self.slot[:SLOT_SIZE]).split(b"\0", 1)[0].decode(errors="replace")
        return name or "no FMI call (cosim's code around the FMU)"

    def read_output(self, final: bool = False) -> None:
        """What the host printed since the last read, as one message per line (a last partial line
        waits for its end, unless ``final``)."""
        if not final and not self._printed.poll(0):
            return
        for source, stream in self._outputs.items():
            assert stream is not None
            chunks = []
            while True:
                try:
                    chunk = os.read(stream.fileno(), 1 << 16)
                except BlockingIOError:
                    break
                if not chunk:
                    break
                chunks.append(chunk)
            data = self._partial[source] + b"".join(chunks)
            lines = data.split(b"\n")
            self._partial[source] = b"" if final else lines.pop()
            self.pending += [
                FmuMessage(source, "", "", line.decode("utf-8", "replace").rstrip()) for line in lines if line.strip()
            ]

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.connection.close()

    def close(self) -> None:
        """End the host: its FMUs are freed as the process ends."""
        try:
            self.connection.close()
            self.process.wait(timeout=2.0)
        except (OSError, subprocess.TimeoutExpired):
            self.kill()


class _Hosts:
    """The host processes of this process, for reuse."""

    def __init__(self) -> None:
        self.by_fmu: dict[str, list[Host]] = {}
        self.lock = threading.Lock()
        atexit.register(self.close_all)

    def acquire(self, model: FmuModel) -> Host:
        key = str(model.path)
        once = (
            model.description.modelExchange is not None
            and model.description.modelExchange.canBeInstantiatedOnlyOncePerProcess
        )
        once = once or (
            model.description.coSimulation is not None
            and model.description.coSimulation.canBeInstantiatedOnlyOncePerProcess
        )
        with self.lock:
            hosts = [h for h in self.by_fmu.get(key, []) if not h.failed and h.process.poll() is None]
            free = [h for h in hosts if not once or h.open == 0]
            host = free[0] if free else Host(model.path.name)
            if not free:
                hosts.append(host)
            self.by_fmu[key] = hosts
            host.open += 1
            return host

    def release(self, host: Host) -> None:
        with self.lock:
            host.open -= 1
            if host.failed:
                for hosts in self.by_fmu.values():
                    if host in hosts:
                        hosts.remove(host)
            idle = [h for hosts in self.by_fmu.values() for h in hosts if h.open == 0]
            for extra in idle[: max(0, len(idle) - IDLE_HOSTS)]:
                for hosts in self.by_fmu.values():
                    if extra in hosts:
                        hosts.remove(extra)
                extra.close()

    def close_all(self) -> None:
        for hosts in self.by_fmu.values():
            for host in hosts:
                host.close()
        self.by_fmu.clear()


_HOSTS = _Hosts()
_KEYS = itertools.count()


class IsolatedFmuPlant(FmuPlantBase):
    """An FMU plant whose FMU runs in a host process; ``FmuPlant``'s interface.

    ``interrupted`` is called while a call waits for the host (every ``POLL`` s): it raises to stop
    the run (the session's ``interrupts.check``)."""

    def __init__(
        self,
        model: FmuModel,
        sample_time: float,
        duration: float,
        sensors: Sequence[str] | None = None,
        *,
        design: Any = None,
        tolerance: float | None = None,
        interrupted: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(model, sample_time, duration, sensors, design)
        self.interrupted = interrupted
        self.messages: list[FmuMessage] = []
        self._key = next(_KEYS)
        self._host: Host | None = _HOSTS.acquire(model)
        arguments = {
            "sample_time": sample_time,
            "duration": duration,
            "sensors": self.sensor_names,
            "tolerance": tolerance,
        }
        self._x, self._y = self._call("open", str(model.path), model.settings, arguments)

    def _call(self, op: str, *args: Any) -> Any:
        host = self._host
        if host is None:
            raise ModelError(f"{self.model.path.name}: the plant is closed")
        try:
            if op == "step":
                u, d = args
                return host.step(self._key, u, d, self.time, self.interrupted)
            return host.call(op, self._key, args, self.time, self.interrupted)
        finally:
            self.messages += host.pending
            host.pending = []
            if host.failed:
                self._release()

    def _release(self) -> None:
        if self._host is not None:
            host, self._host = self._host, None
            _HOSTS.release(host)

    def reset(self, initial: dict[str, float] | None = None) -> None:
        self._k = 0
        self._x, self._y = self._call("reset", initial)

    def state(self) -> np.ndarray:
        return self._x

    def sensors(self) -> np.ndarray:
        return self._y

    def set_state(self, x: np.ndarray) -> None:
        self._x, self._y = self._call("set_state", np.asarray(x, dtype=float))

    def step(self, ctrl: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        d = np.zeros(len(self.disturbance_names)) if disturbance is None else np.asarray(disturbance, dtype=float)
        values = self._call("step", np.ascontiguousarray(ctrl, dtype=float), np.ascontiguousarray(d, dtype=float))
        self._x, self._y = values[: self.nx], values[self.nx :]
        self._k += 1

    def linearize(
        self, x: np.ndarray | None = None, u: np.ndarray | None = None, *, continuous: bool = False, method: str = "zoh"
    ) -> LinearModel:
        """As ``FmuPlant.linearize``; what the check of its derivatives found goes to ``warnings``."""
        if self.design is not None:
            return self.design.linearize(continuous=continuous)
        if method != "zoh":
            raise ValueError(f"an FMU plant is linearized by the zero-order hold only, not {method!r}")
        model, warnings, self.operating_point = self._call("linearize", x, u, continuous)
        self.warnings += [w for w in warnings if w not in self.warnings]
        return model

    def take_messages(self) -> list[FmuMessage]:
        """What the FMU logged or printed since the last take."""
        taken, self.messages = self.messages, []
        return taken

    def close(self) -> None:
        """Free the FMU instance (its host stays for reuse)."""
        if self._host is not None and not self._host.failed:
            try:
                self._call("close")
            except ModelError:
                pass
        self._release()

    def __del__(self) -> None:
        try:
            self.close()
        except KeyboardInterrupt as stop:  # Python drops what __del__ raises: the next wait raises it
            _DROPPED.append(stop)
        except Exception:  # noqa: BLE001 (interpreter shutdown)
            pass


def _python_interpreter() -> bool:
    """Whether this process can start a Python like itself: not so in Python embedded in another
    program (an exported cosim FMU inside a C tool, where ``sys.executable`` is that tool)."""
    return Path(sys.executable).name.startswith("python")


def fmu_plant(s: Any, interrupted: Callable[[], None] | None = None) -> Any:
    """The FMU plant of a validated scenario: in a process of its own, or in this one with
    ``[plant.fmu] isolation = "none"`` (and in Python embedded in another program, which has no
    interpreter to start)."""
    from cosim.plant.fmu import FmuPlant

    model = s.fmu_model()
    tolerance = model.settings.get("tolerance")
    design = s.plant.state_space
    if model.settings.get("isolation") == "none" or not _python_interpreter():
        return FmuPlant(model, s.sample_time, s.duration, s.sensors, design=design, tolerance=tolerance)
    return IsolatedFmuPlant(
        model, s.sample_time, s.duration, s.sensors, design=design, tolerance=tolerance, interrupted=interrupted
    )
